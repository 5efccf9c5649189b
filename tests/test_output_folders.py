"""Output folders (blocks.plumbing.outputs): checked before the work, filled in place when empty, never mixed between two
runs, nothing left by a failure; a file system that is read-only, full or over quota is named with the file's
role and path (docs/hostile-inputs.md, "Output folders" and "Round 3")."""
from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys

import pytest

from blocks.plumbing.outputs import file_error, staged_output


def _fill(target) -> None:
    with staged_output(target) as stage:
        (stage / "result.txt").write_text("done")


def test_an_empty_folder_or_a_link_to_one_is_filled_in_place(tmp_path):
    volume = tmp_path / "volume"                # like a container's mounted volume: it exists, empty, and stays
    volume.mkdir()
    _fill(volume)
    assert sorted(p.name for p in volume.iterdir()) == ["result.txt"]
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real)
    _fill(link)
    assert link.is_symlink() and (real / "result.txt").read_text() == "done"


def test_unusable_folders_are_refused_before_the_work(tmp_path):
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="symbolic link.*which does not exist"):
        staged_output(dangling)
    full = tmp_path / "full"
    full.mkdir()
    (full / "old.txt").write_text("old")
    with pytest.raises(FileExistsError, match="exists and is not empty"):
        staged_output(full)
    if os.geteuid() != 0:                        # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        with pytest.raises(PermissionError, match="cannot be written"):
            staged_output(locked)


def test_a_second_run_for_the_same_folder_is_refused_at_once_and_a_killed_runs_lock_is_cleared(tmp_path):
    target = tmp_path / "out"
    first = staged_output(target)
    with pytest.raises(FileExistsError, match=f"being written by another dobkit run \\(process {os.getpid()}\\)"):
        staged_output(target)
    del first                                    # the work failed before writing: the reservation goes
    assert not target.exists()
    target.mkdir()
    (target / ".dobkit-writing").write_text("999999999")                   # no such process
    (target / ".partial-left").mkdir()
    _fill(target)
    assert sorted(p.name for p in target.iterdir()) == ["result.txt"]


def test_a_failure_leaves_nothing_and_the_umask_is_honoured(tmp_path):
    target = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with staged_output(target) as stage:
            (stage / "half.txt").write_text("half")
            raise RuntimeError("the run failed")
    assert not target.exists()
    old = os.umask(0o027)
    try:
        _fill(target)
    finally:
        os.umask(old)
    assert (target.stat().st_mode & 0o777) == 0o750


@pytest.mark.parametrize("code, words", [(errno.EROFS, "the file system is read-only"),
                                         (errno.ENOSPC, "the disk is full"), (errno.EDQUOT, "quota")])
@pytest.mark.parametrize("role", ["output folder", "results file", "cache folder"])
def test_file_errors_name_the_path_and_the_role(code, words, role):
    err = file_error(OSError(code, os.strerror(code)), "/data/run-1", role)
    assert str(err) == f"{role} '/data/run-1' cannot be written: {DISK_WORDS[code]}; choose another --out"
    assert words in str(err) and err.errno == code and "Errno" not in str(err)


DISK_WORDS = {errno.EROFS: "the file system is read-only", errno.ENOSPC: "the disk is full (no space left)",
              errno.EDQUOT: "the disk quota is used up"}


def _can_mount() -> bool:
    if shutil.which("unshare") is None or os.geteuid() != 0:
        return False
    return subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True).returncode == 0


@pytest.mark.skipif(not _can_mount(), reason="needs root and mount namespaces (unshare -m) for a real small tmpfs")
def test_a_read_only_or_full_file_system_is_named_with_the_output_folder(tmp_path):
    mount = tmp_path / "mnt"
    mount.mkdir()
    script = tmp_path / "fill.py"
    script.write_text(
        "import sys\nfrom pathlib import Path\nfrom blocks.plumbing.outputs import staged_output\n"
        "target = Path(sys.argv[1])\n"
        "try:\n"
        "    with staged_output(target) as stage:\n"
        "        (stage / 'timeseries.csv').write_bytes(b'0' * 200_000)\n"
        "except OSError as err:\n"
        "    print(err)\n"
        "print(sorted(p.name for p in target.parent.rglob('*')))\n")
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    shell = (f"mount -t tmpfs -o size=64k tmpfs {mount} && {sys.executable} {script} {mount}/full; "
             f"mount -o remount,ro {mount} && {sys.executable} -m dobkit simulate --out {mount}/ro")
    run = subprocess.run(["unshare", "-m", "sh", "-c", shell], capture_output=True, text=True, env=env, timeout=600)
    full, left, *_ = run.stdout.splitlines()
    assert full == (f"output folder '{mount}/full' cannot be written: the disk is full (no space left); free space "
                    "or choose another --out; nothing was kept")
    assert left == "[]"                          # no staging folder, lock or folder left on the full disk
    assert run.returncode == 2
    assert run.stderr.strip() == (f"dobkit simulate: error: output folder '{mount}/ro' cannot be written: the file "
                                  "system is read-only; choose another --out")
