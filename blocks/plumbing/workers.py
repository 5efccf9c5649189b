"""Process pools whose workers end with the process that started them.

A sweep, a study or a batch split over processes uses a
:class:`concurrent.futures.ProcessPoolExecutor`.  When the parent is killed
outright (``kill -9``, the machine's out-of-memory killer) it cannot shut the
pool down, and its workers would wait for work forever.  Each worker of
:func:`worker_pool` watches its parent and exits within about a second of the
parent's end.
"""
from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor

__all__ = ["worker_pool", "PARENT_CHECK_PERIOD"]

#: How often (s) a worker checks that the process that started it is still there.
PARENT_CHECK_PERIOD = 0.5


def _exit_with_parent(parent_pid: int) -> None:
    # a process whose parent ended is re-parented, so its parent PID changes
    while os.getppid() == parent_pid:
        time.sleep(PARENT_CHECK_PERIOD)
    os._exit(1)


def _watch_parent() -> None:
    # A forked worker inherits the command's SIGTERM handler (dobkit.signals), which would print a traceback when
    # the pool ends its workers: a worker ends on SIGTERM as a process does by default.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # The parent is whoever started this worker: the pool's process with "fork" and "spawn", the
    # multiprocessing fork server with "forkserver" (which itself ends when the pool's process does).
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), name="dobkit-parent-watch",
                     daemon=True).start()


def worker_pool(max_workers: int, mp_context=None) -> ProcessPoolExecutor:
    """A :class:`~concurrent.futures.ProcessPoolExecutor` of ``max_workers`` (>= 1) processes that end with this one.

    Parameters
    ----------
    max_workers : int
        Number of worker processes.
    mp_context : multiprocessing context, optional
        Start method (``multiprocessing.get_context("spawn")``, ...); default: Python's.
    """
    if max_workers < 1:
        raise ValueError(f"max_workers must be >= 1, got {max_workers}")
    return ProcessPoolExecutor(max_workers=max_workers, mp_context=mp_context, initializer=_watch_parent)
