"""Worker processes end with the process that started them, even when it is killed outright."""
from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from blocks.plumbing.workers import worker_pool


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                          # a zombie is gone for our purpose
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.slow
@pytest.mark.parametrize("method", multiprocessing.get_all_start_methods())
def test_pool_runs_work_with_every_start_method(method):
    # with "forkserver" a worker's parent is the fork server, not this process: it must not take that for an exit
    with worker_pool(2, multiprocessing.get_context(method)) as pool:
        assert list(pool.map(abs, [-1, -2, 3])) == [1, 2, 3]
        time.sleep(1.5)                             # three parent checks
        assert list(pool.map(abs, [-4])) == [4]


def test_bad_pool_size():
    with pytest.raises(ValueError, match="max_workers"):
        worker_pool(0)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_exit_when_their_parent_is_killed(tmp_path):
    pid_file = tmp_path / "pids"
    parent = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import os, time
        from blocks.plumbing.workers import worker_pool
        def pid_after(delay):
            time.sleep(delay)
            return os.getpid()
        pool = worker_pool(2)
        pids = set()
        while len(pids) < 2:                    # both workers have run something
            pids |= set(pool.map(pid_after, [0.3] * 4))
        open({str(pid_file)!r}, "w").write(" ".join(map(str, pids)))
        time.sleep(60)
    """)])
    try:
        deadline = time.monotonic() + 60
        while not (pid_file.exists() and pid_file.read_text().strip()):
            assert time.monotonic() < deadline, "the parent did not start its workers"
            assert parent.poll() is None, "the parent ended early"
            time.sleep(0.1)
        workers = [int(p) for p in pid_file.read_text().split()]
        assert len(workers) == 2 and all(_alive(p) for p in workers)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers), "workers outlived their killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()
        for pid in (int(p) for p in (pid_file.read_text().split() if pid_file.exists() else [])):
            if _alive(pid):                     # only when the test failed: do not leave them behind
                os.kill(pid, signal.SIGKILL)
