"""Hostile inputs to sweeps and the job files: only regular files read, scheduler connections that time out and
say what answered, interrupts and kills that leave nothing behind, full disks named by file and role.

docs/hostile-inputs.md, "Round 8", lists each case with its test.  The sweeps are real (the first 0.3 s of the
paper scenario); the peers that are no Dask scheduler listen on 127.0.0.1 for the length of one test.
"""
from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

from analysis.jobs.files import MAX_JOB_FILE_BYTES
from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import SweepError, load_sweep
from analysis.sweep.summary import _remove_stale_stages, write_summary
from analysis.tune.spec import TuneError, load_tuning

GRID = '[grid]\n"gains.kp" = [{}]\n[outputs]\nmetrics = ["rms_position_error", "max_tool_position_error_mm"]\n'


@pytest.fixture()
def short_file(tmp_path):
    return write_short_scenario(tmp_path, t_final=0.3)


# ---------------------------------------------------------------------------------------------------------------
# every file a job reads is a regular file
# ---------------------------------------------------------------------------------------------------------------
def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_device_or_a_fifo_as_results_file_is_refused_before_anything_runs(tmp_path, short_file, capsys):
    # before: /dev/zero was read line by line until memory ran out ("out of memory within the memory budget ...
    # finished runs are kept"); a FIFO blocked for ever
    sweep = load_sweep(write_sweep(tmp_path, GRID.format("150")))
    for results in (Path("/dev/zero"), _fifo(tmp_path / "r.jsonl")):
        with pytest.raises(SweepError, match=rf"results file '{results}' is not a regular file \(a device, pipe or "
                                             r"socket\); give the path of a file"):
            run_sweep(sweep, results, workers=1, progress=False)
    assert not Path("/dev/zero.lock").exists() and not (tmp_path / "r.jsonl.lock").exists()
    folder = tmp_path / "folder.jsonl"
    folder.mkdir()
    assert run_sweep_command(["sweep", str(tmp_path / "s.toml"), "--results", str(folder), "--no-progress"]) == 2
    assert "is not a regular file (a folder)" in capsys.readouterr().err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_device_a_fifo_or_a_huge_file_as_sweep_or_tuning_file_is_refused_without_reading_it(tmp_path, short_file):
    for path in (Path("/dev/zero"), _fifo(tmp_path / "s.toml")):
        with pytest.raises(SweepError, match=rf"sweep file '{path}' is not a regular file \(a device, pipe or socket"):
            load_sweep(path)
        with pytest.raises(TuneError, match=rf"tuning file '{path}' is not a regular file \(a device, pipe or socket"):
            load_tuning(path)
    # the size bound at both sides: a comment pads the file
    text = 'scenario = "short.toml"\n' + GRID.format("150")
    exact = tmp_path / "exact.toml"
    exact.write_text(text + "#" * (MAX_JOB_FILE_BYTES - len(text) - 1) + "\n", encoding="utf-8")
    assert exact.stat().st_size == MAX_JOB_FILE_BYTES and len(load_sweep(exact).runs) == 1
    over = tmp_path / "over.toml"
    over.write_text(text + "#" * (MAX_JOB_FILE_BYTES - len(text)) + "\n", encoding="utf-8")
    with pytest.raises(SweepError, match=rf"sweep file '{over}' has more than {MAX_JOB_FILE_BYTES:,} bytes"):
        load_sweep(over)


# ---------------------------------------------------------------------------------------------------------------
# scheduler connections: bounded in time, and what answered is said
# ---------------------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def _peer(reply: bytes | None):
    """A server on 127.0.0.1 that accepts connections and then says nothing (``reply`` None) or ``reply``."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    server.settimeout(0.2)
    held, stop = [], threading.Event()

    def serve():
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except (TimeoutError, OSError):
                continue
            held.append(conn)
            if reply is not None:
                with contextlib.suppress(OSError):
                    conn.settimeout(2.0)
                    conn.recv(4096)
                    conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        server.close()


def test_a_scheduler_that_accepts_and_never_answers_times_out_naming_the_address(tmp_path, short_file):
    # before: dobkit sweep --scheduler waited without end, silently (Dask's handshake read has no time-out)
    pytest.importorskip("distributed")
    sweep = load_sweep(write_sweep(tmp_path, GRID.format("150")))
    results = tmp_path / "r.jsonl"
    with _peer(None) as address:
        started = time.monotonic()
        with pytest.raises(SweepError, match=rf"the Dask scheduler at '{address}' did not answer within 1 s of "
                                             r"accepting the connection"):
            run_sweep(sweep, results, scheduler=address, progress=False, scheduler_timeout=1.0)
        assert time.monotonic() - started < 30
    assert not results.exists()


def test_a_peer_of_another_protocol_is_not_reported_as_out_of_memory(tmp_path, short_file):
    # before: "out of memory within the memory budget of 4.0 GiB" (its reply's first bytes read as a frame length)
    pytest.importorskip("distributed")
    sweep = load_sweep(write_sweep(tmp_path, GRID.format("150")))
    with _peer(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n") as address:
        with pytest.raises(SweepError, match=rf"the Dask scheduler at '{address}' answered with something other "
                                             r"than Dask's protocol") as err:
            run_sweep(sweep, tmp_path / "r.jsonl", scheduler=address, progress=False, scheduler_timeout=2.0)
    assert "memory" not in str(err.value)


@pytest.mark.parametrize("address", ["tls://127.0.0.1:8786", "ucx://127.0.0.1:8786", "inproc://x"])
def test_schemes_other_than_tcp_are_refused_by_name(tmp_path, short_file, address):
    # before: raw library errors (tls: no certificates; ucx: UCX not installed)
    pytest.importorskip("distributed")
    sweep = load_sweep(write_sweep(tmp_path, GRID.format("150")))
    scheme = address.split("://")[0]
    with pytest.raises(SweepError, match=rf"--scheduler '{address}': dobkit connects to a Dask scheduler over tcp:// "
                                         rf"only \({scheme}://"):
        run_sweep(sweep, tmp_path / "r.jsonl", scheduler=address, progress=False, scheduler_timeout=1.0)


# ---------------------------------------------------------------------------------------------------------------
# SIGTERM while a worker sends its batch's result
# ---------------------------------------------------------------------------------------------------------------
# A worker of the sweep's own pool writes what a worker terminated mid-send leaves in the result pipe (a message's
# length and its first bytes) and stops there; the pool is then ended as an interrupted sweep ends it.
_HALF_SENT = """
import os, struct, sys, time
from pathlib import Path
from analysis.sweep.runner import _end_now
from blocks.plumbing.workers import worker_pool

def half_sent(marker):
    frame = sys._getframe()
    while frame.f_code.co_name != "_process_worker":
        frame = frame.f_back
    writer = frame.f_locals["result_queue"]._writer
    os.write(writer.fileno(), struct.pack("!i", 1 << 20) + b"\\x80\\x04" + b"x" * 30)
    Path(marker).write_text("sent")
    time.sleep(300)

if __name__ == "__main__":
    started = time.monotonic()
    pool = worker_pool(2)
    pool.submit(half_sent, sys.argv[1])
    while not Path(sys.argv[1]).exists():
        time.sleep(0.05)
    time.sleep(0.3)                  # the pool's reader is now waiting for the rest of the message
    sent = time.monotonic()
    _end_now(pool)
    print(f"ended: sent after {sent - started:.1f} s, ended in {time.monotonic() - sent:.1f} s", flush=True)
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the worker function lives in the script (fork start method)")
def test_ending_a_pool_whose_worker_died_mid_message_does_not_hang(tmp_path):
    # before: pool.shutdown(wait=True) waited in result_reader.recv() for good (SIGTERM to dobkit sweep --workers 2
    # while a worker sent its result: the command hung, its workers dead)
    script = tmp_path / "half_sent.py"
    script.write_text(_HALF_SENT, encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                                       os.environ.get("PYTHONPATH", "")]))
    log = tmp_path / "log"
    with log.open("w") as out:          # a file, not a pipe: the test waits for the process, not for its pipe
        child = subprocess.Popen([sys.executable, str(script), str(tmp_path / "sent")], stdout=out, stderr=out,
                                 env=env)
        try:
            child.wait(timeout=120)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
            pytest.fail("ending the pool hung (waiting for the rest of a message its terminated worker never sent)")
    assert child.returncode == 0 and "ended" in log.read_text(), log.read_text()[-2000:]


# ---------------------------------------------------------------------------------------------------------------
# what kill -9 of a summary writer left behind
# ---------------------------------------------------------------------------------------------------------------
def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.slow              # a sweep and its summary's figures
def test_a_summary_staging_folder_left_by_kill_9_is_removed_by_the_next_complete_run(tmp_path, short_file):
    # before: .NAME-summary.partial-<pid> stayed beside the results for good (FMU extractions are swept once
    # their process is gone; summaries were not)
    sweep = load_sweep(write_sweep(tmp_path, GRID.format("150")))
    results = tmp_path / "s-results.jsonl"
    run_sweep(sweep, results, workers=1, progress=False)
    out = tmp_path / "s-summary"
    dead = tmp_path / f".s-summary.partial-{_dead_pid()}"
    dead.mkdir()
    (dead / "fig.png").write_bytes(b"half a figure")
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = tmp_path / f".s-summary.partial-{alive.pid}"     # another writer at work: left alone
        live.mkdir()
        write_summary(results, out, spec=sweep)
        assert (out / "summary.json").is_file() and not dead.exists() and live.is_dir()
    finally:
        alive.kill()
        alive.wait()
    # killed between the two renames: the previous summary waits as .NAME.old-<pid> and no summary is in place
    out.rename(tmp_path / f".s-summary.old-{_dead_pid()}")
    assert len(_remove_stale_stages(out)) == 2 and (out / "summary.json").is_file()     # put back; live gone now


# ---------------------------------------------------------------------------------------------------------------
# a full disk, named with the file and its role
# ---------------------------------------------------------------------------------------------------------------
def _can_mount() -> bool:
    import shutil
    if shutil.which("unshare") is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        return False
    return subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True).returncode == 0


@pytest.mark.slow                      # two sweeps in a mount namespace
@pytest.mark.skipif(not _can_mount(), reason="needs root and mount namespaces (unshare -m) for a real small tmpfs")
def test_a_full_disk_under_the_results_file_is_named_with_the_file_and_its_role(tmp_path, short_file):
    # before: "dobkit sweep: error: [Errno 28] No space left on device" (no file, no role, no remedy)
    write_sweep(tmp_path, GRID.format("150"))
    mount = tmp_path / "mnt"
    mount.mkdir()
    sweep = f"{sys.executable} -m dobkit sweep s.toml --results {mount}/r.jsonl --no-progress --workers 1"
    # a 64 KiB tmpfs filled up; then one page (4 KiB) left: the lock takes it and the first row finds none
    shell = (f"mount -t tmpfs -o size=64k tmpfs {mount} && (dd if=/dev/zero of={mount}/fill bs=1k count=100 "
             f"2>/dev/null; {sweep}; echo rc=$?; rm {mount}/fill; dd if=/dev/zero of={mount}/fill bs=1k count=60 "
             f"2>/dev/null; {sweep}; echo rc=$?; ls -A {mount})")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    run = subprocess.run(["unshare", "-m", "sh", "-c", shell], capture_output=True, text=True, env=env,
                         timeout=600, cwd=tmp_path)
    said = f"dobkit sweep: results file '{mount}/r.jsonl' cannot be written: the disk is full (no space left); " \
           "free space, or give this one another --results file; "
    assert run.stderr.splitlines() == [said + "nothing was run", said + "nothing was written"], run.stderr
    assert run.stdout.split() == ["rc=2", "rc=2", "fill"]       # no results file, lock or staging file left
