"""Ctrl-C while a job starts worker processes: what the local pool and the local Dask cluster share.

A terminal sends Ctrl-C to the whole process group.  A job's worker processes
(and the threads that start more of them) are started with SIGINT blocked, so
that only the process that started them handles it: it ends them, keeps every
finished row and says one line.  Blocked, not ignored: a Ctrl-C that arrives
while they start reaches that process right after.
"""
from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["sigint_held"]


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
