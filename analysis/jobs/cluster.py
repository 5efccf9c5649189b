"""Running a job's batches on a Dask cluster: what a sweep and a tuning share.

A job (a sweep's chunks of runs, a tuning's chunks of candidates) hands this
module picklable payloads and a module-level function that simulates one.  The
batches go to the cluster's workers, at most two per worker thread in flight
(memory stays bounded), and each result is taken as it finishes.  A worker
lost mid-batch (killed, out of memory) is Dask's to handle: the scheduler
runs that batch again on another worker, and since results are only taken
once a batch has finished, no row is lost or written twice.

Engine notes (:class:`blocks.loop.EngineFallbackWarning`) raised on a worker
come back with the result and are printed once per command, not once per
worker.
"""
from __future__ import annotations

import functools
import itertools
import warnings
from collections.abc import Callable, Iterator

__all__ = ["dask_client", "dask_threads", "run_on_dask", "call_with_notes", "take_with_notes"]


def _distributed(error: type[Exception]):
    try:
        import distributed
    except ImportError:
        raise error("--scheduler needs Dask: pip install 'dask[distributed]' (the 'cluster' extra)") from None
    return distributed


def dask_client(address: str, timeout: float, error: type[Exception]):
    """A Dask client of the scheduler at ``address`` (``tcp://host:8786``).

    Raises
    ------
    error
        When Dask is not installed, or the scheduler does not answer within ``timeout`` seconds.
    """
    distributed = _distributed(error)
    try:
        return distributed.Client(address, timeout=f"{timeout}s")
    except (OSError, TimeoutError, ValueError) as err:
        raise error(f"cannot reach the Dask scheduler at {address!r}: {err}; nothing was run or written") from None


def dask_threads(client) -> int:
    """Worker threads of the cluster now (at least 1)."""
    return max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))


def call_with_notes(function: Callable, payload) -> tuple[object, list[str]]:
    """``function(payload)`` and the engine notes it would have printed, for the command to print once.
    Other warnings pass as they are."""
    from blocks.loop import EngineFallbackWarning
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", EngineFallbackWarning)
        result = function(payload)
    notes = []
    for w in caught:
        if issubclass(w.category, EngineFallbackWarning):
            notes.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return result, notes


#: Engine notes this process has printed for its workers (once per command, not once per worker).
_notes_shown: set[str] = set()


def take_with_notes(outcome: tuple[object, list[str]], take: Callable) -> None:
    """Print a worker's engine notes that this command has not printed yet, then ``take`` its result."""
    from blocks.loop import EngineFallbackWarning
    result, notes = outcome
    for note in notes:
        if note not in _notes_shown:
            _notes_shown.add(note)
            warnings.warn(note, EngineFallbackWarning, stacklevel=2)
    take(result)


def run_on_dask(client, function: Callable, payloads: Iterator, take: Callable, threads: int | None = None,
                error: type[Exception] = RuntimeError) -> None:
    """Run ``function`` on every payload on the cluster and call ``take(result)`` as each finishes.

    Parameters
    ----------
    client : distributed.Client
    function : callable
        Module-level (picklable) function of one payload.
    payloads : iterator
        Made as they are needed: at most ``2 * threads`` are in flight.
    take : callable
        Called in this process with each result, in the order they finish.
    threads : int, optional
        Worker threads of the cluster (default: asked of the scheduler).
    """
    distributed = _distributed(error)
    threads = dask_threads(client) if threads is None else max(1, int(threads))
    task = functools.partial(call_with_notes, function)
    futures = distributed.as_completed([client.submit(task, p, pure=False)
                                        for p in itertools.islice(payloads, 2 * threads)])
    for fut in futures:
        take_with_notes(fut.result(), take)
        nxt = next(payloads, None)
        if nxt is not None:
            futures.add(client.submit(task, nxt, pure=False))
