"""Ctrl-C or SIGTERM at each moment of writing an output folder: nothing partial is left, nothing whole is lost.

The command-line test (tests/test_cli_interrupts.py) sends SIGTERM once the
staging folder exists, which lands in one of these windows by chance; here
each window is hit on purpose.
"""
from __future__ import annotations

import gc
import os
import signal
import tempfile
from pathlib import Path

import pytest

from blocks.plumbing.outputs import staged_output


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("new", [True, False], ids=["folder it makes", "user's empty folder"])
def test_a_signal_while_the_folder_is_reserved_leaves_no_lock(tmp_path, monkeypatch, new):
    # the lock was made and its removal not yet registered: a signal then left '.dobkit-writing' (and the folder)
    target = tmp_path / "out"
    if not new:
        target.mkdir()
    real_fdopen = os.fdopen

    def fdopen(fd, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)            # arrives with the lock made, before its pid is written
        return real_fdopen(fd, *args, **kwargs)
    monkeypatch.setattr(os, "fdopen", fdopen)
    try:
        staged_output(target)
    except KeyboardInterrupt:
        pass                                           # the unreturned reservation goes with the exception
    else:
        pytest.fail("the interrupt was lost")
    monkeypatch.undo()
    gc.collect()
    assert (_names(target) == []) if not new else not target.exists()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("made", ["folder made, name not yet returned", "folder made, permissions not yet set"])
def test_an_interrupt_while_the_staging_folder_is_made_leaves_the_folder_as_it_was(tmp_path, monkeypatch, made):
    target = tmp_path / "out"
    target.mkdir()                                     # the user's empty folder stays, empty
    staging = staged_output(target)
    assert _names(target) == [".dobkit-writing"]
    if made.startswith("folder made, name"):
        real = tempfile.mkdtemp

        def mkdtemp(**kwargs):
            real(**kwargs)                             # the folder exists; its name is lost with the interrupt
            raise KeyboardInterrupt
        monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    else:
        def chmod(self, mode):
            raise KeyboardInterrupt
        monkeypatch.setattr(Path, "chmod", chmod)
    with pytest.raises(KeyboardInterrupt):
        with staging:
            pytest.fail("the body must not run")
    assert _names(target) == []


def test_an_interrupt_while_a_folder_it_made_is_reserved_removes_that_folder(tmp_path, monkeypatch):
    target = tmp_path / "new" / "out"
    staging = staged_output(target)
    monkeypatch.setattr(Path, "chmod", lambda self, mode: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        with staging:
            pass
    assert not target.exists()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_results_are_moved_in_waits_for_the_last_file(tmp_path, monkeypatch, signum):
    target = tmp_path / "out"
    raised: list[type] = []

    def terminate(got, frame):
        raise KeyboardInterrupt(f"signal {got}")
    previous = signal.signal(signal.SIGTERM, terminate)     # what dobkit.signals installs while a command runs
    real_replace, moved = os.replace, []

    def replace(src, dst):
        if not moved:
            os.kill(os.getpid(), signum)               # arrives between the first file and the rest
        real_replace(src, dst)
        moved.append(Path(dst).name)
    monkeypatch.setattr(os, "replace", replace)
    try:
        with pytest.raises(KeyboardInterrupt) as caught:
            with staged_output(target) as stage:
                for name in ("a.json", "b.csv", "c.png"):
                    (stage / name).write_text(name)
        raised.append(type(caught.value))
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert moved == ["a.json", "b.csv", "c.png"]       # every file, then the interrupt
    assert _names(target) == ["a.json", "b.csv", "c.png"]      # no lock, no staging folder
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGTERM) is previous


def test_without_a_signal_the_handlers_are_the_callers_after_the_move(tmp_path):
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with staged_output(tmp_path / "out") as stage:
        (stage / "metrics.json").write_text("{}")
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert _names(tmp_path / "out") == ["metrics.json"]


# --- default folder names: two runs started in the same second ---------------------------------------------------
class _FrozenClock:
    """``datetime`` with ``now()`` held at one second: every default name of the test is asked in the same second."""

    @staticmethod
    def now():
        import datetime
        return datetime.datetime(2026, 12, 2, 8, 5, 7)


def test_two_runs_in_the_same_second_get_two_default_folders_and_a_failed_one_leaves_none(tmp_path, monkeypatch):
    import blocks.plumbing.outputs as outputs
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(outputs, "datetime", _FrozenClock)
    first, second = outputs.default_out_dir(), outputs.default_out_dir()
    assert (first.name, second.name) == ("dobkit-run-20261202-080507", "dobkit-run-20261202-080507-1")
    assert first.is_dir() and second.is_dir()             # made at once: the name is this run's
    with staged_output(second) as stage:                   # the second run's results go into its own folder
        (stage / "metrics.json").write_text("{}")
    with pytest.raises(RuntimeError):
        with staged_output(first):                         # the first fails: its folder goes with it
            raise RuntimeError("diverged")
    assert _names(tmp_path) == ["dobkit-run-20261202-080507-1"]
    assert _names(second) == ["metrics.json"]


def test_a_default_folder_no_run_used_is_removed_at_exit_unless_something_was_put_in_it(tmp_path):
    import subprocess
    import sys
    code = ("from blocks.plumbing.outputs import default_out_dir\n"
            "unused, kept = default_out_dir('unused'), default_out_dir('kept')\n"
            "(kept / 'notes.txt').write_text('the user put this here')\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert [p.name.split("-")[0] for p in tmp_path.iterdir()] == ["kept"]
