"""SIGTERM ends a command the way Ctrl-C does.

``kill PID``, a container stop or a batch scheduler's time limit send SIGTERM,
whose default action ends the process at once: the output folder would keep
its reservation (``.dobkit-writing``) and its half-written staging folder
(``.partial-*``).  While a command runs, SIGTERM raises :class:`Terminated`
in the main thread instead.  It is a :class:`KeyboardInterrupt`, so every
clean-up written for Ctrl-C runs (staged outputs removed, whole result rows
kept, worker pools shut down) and the command says its one line; the exit
status is then 143 (128 + SIGTERM), as a shell reports a terminated process,
where Ctrl-C gives 130.

A second SIGTERM during the clean-up is ignored, so that the clean-up is not
cut short; SIGKILL still ends the process at once.
"""
from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable

__all__ = ["Terminated", "run_with_signals", "INTERRUPTED", "TERMINATED"]

#: Exit status of a command ended by Ctrl-C (128 + SIGINT).
INTERRUPTED = 128 + signal.SIGINT
#: Exit status of a command ended by SIGTERM (128 + SIGTERM).
TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM while a command ran (handled like Ctrl-C)."""


def run_with_signals(command: Callable[..., int], *args) -> int:
    """Run ``command(*args)`` with SIGTERM raising :class:`Terminated`; return its exit status.

    Parameters
    ----------
    command : callable
        Returns an exit status; it handles :class:`KeyboardInterrupt` (and so
        :class:`Terminated`) itself, returning :data:`INTERRUPTED`.

    Returns
    -------
    int
        The command's status, or :data:`TERMINATED` when SIGTERM ended it.
        Outside the main thread (where Python cannot handle signals) the
        command runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        return command(*args)
    received: list[int] = []

    def terminate(signum, frame):
        signal.signal(signum, signal.SIG_IGN)       # the clean-up that follows runs to its end
        received.append(signum)
        raise Terminated(f"received signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        status = command(*args)
    except Terminated:                              # before the command could handle it (while starting)
        print("dobkit: terminated (SIGTERM)", file=sys.stderr)
        return TERMINATED
    finally:
        signal.signal(signal.SIGTERM, previous)
    return TERMINATED if received and status == INTERRUPTED else status
