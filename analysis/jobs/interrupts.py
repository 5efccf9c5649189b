"""Ctrl-C while a job starts worker processes: what the local pool and the local Dask cluster share.

A terminal sends Ctrl-C to the whole process group.  A job's worker processes
(and the threads that start more of them) are started with SIGINT blocked, so
that only the process that started them handles it: it ends them, keeps every
finished row and says one line.  Blocked, not ignored: a Ctrl-C that arrives
while they start reaches that process right after.

The worker processes of a local Dask cluster are started anew (spawned), so
they do not keep a blocked mask: :func:`dask_setup`, their preload, makes them
ignore Ctrl-C instead.
"""
from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["sigint_held", "dask_setup"]


@contextlib.contextmanager
def sigint_held():
    """SIGINT blocked in this thread while the block runs (threads and processes started in it inherit the block);
    nothing outside the main thread, where Python does not handle signals."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def dask_setup(worker) -> None:
    """Preload of a local Dask cluster's worker processes (``--scheduler local[:N]``): Ctrl-C is left to the job's
    process, which ends the job in one line and closes the cluster (otherwise each worker prints a traceback)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
