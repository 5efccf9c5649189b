"""Running a job's batches on a Dask cluster: what a sweep and a tuning share.

A job (a sweep's chunks of runs, a tuning's chunks of candidates) hands this
module picklable payloads and a module-level function that simulates one.  The
batches go to the cluster's workers, at most two per worker thread in flight
(memory stays bounded), and each result is taken as it finishes.  A worker
lost mid-batch (killed, out of memory) is Dask's to handle: the scheduler
runs that batch again on another worker, and since results are only taken
once a batch has finished, no row is lost or written twice.

Engine notes (:class:`blocks.figure2.loop.EngineFallbackWarning`) raised on a worker
come back with the result and are printed once per command, not once per
worker.

The scheduler is an address (``tcp://host:8786``) or ``local[:N]``: a Dask
``LocalCluster`` of N worker processes (default: one per core) started on
127.0.0.1 for the job and closed when it ends, however it ends.  An address is
asked who it is before a client is made, within the time-out: Dask's client
waits without end for a peer that accepts the connection and never answers,
and reads a peer of another protocol as a frame of exabytes.
"""
from __future__ import annotations

import asyncio
import contextlib
import functools
import itertools
import logging
import os
import warnings
from collections.abc import Callable, Iterator

from analysis.jobs.interrupts import sigint_held

__all__ = ["dask_session", "local_workers", "dask_threads", "run_on_dask", "call_with_notes", "take_with_notes",
           "LOCAL", "MAX_LOCAL_WORKERS_PER_CORE", "probe_scheduler"]

#: The scheduler "address" that starts a cluster on this machine for the job: ``local`` or ``local:N``.
LOCAL = "local"
#: Local worker processes per core at most: each worker imports the whole stack (a few hundred MB), and more
#: processes than cores only wait for them, so ``local:100000`` is refused rather than started.
MAX_LOCAL_WORKERS_PER_CORE = 4


def _distributed(error: type[Exception], address: str = ""):
    try:
        import distributed
    except ImportError:
        raise error(f"--scheduler {address or 'ADDRESS'} needs Dask: pip install 'dobkit[cluster]' (the 'cluster' "
                    "extra, dask[distributed])") from None
    return distributed


def local_workers(address: str, error: type[Exception] = ValueError) -> int | None:
    """The worker processes ``local[:N]`` asks for (``local``: one per core), or None for another address.

    Raises
    ------
    error
        When N is not a whole number >= 1.

    Examples
    --------
    >>> local_workers("local:3"), local_workers("tcp://127.0.0.1:8786")
    (3, None)
    """
    if address != LOCAL and not address.startswith(LOCAL + ":"):
        return None
    count = address[len(LOCAL) + 1:] if address != LOCAL else str(os.cpu_count() or 1)
    if not (count.isascii() and count.isdigit() and int(count) >= 1):     # '²' is a digit int() refuses
        raise error(f"--scheduler {address!r}: the number of local worker processes must be a whole number >= 1 "
                    "(local or local:N, e.g. local:2)")
    most = MAX_LOCAL_WORKERS_PER_CORE * (os.cpu_count() or 1)
    if int(count) > most:
        raise error(f"--scheduler {address!r}: {int(count)} local worker processes on {os.cpu_count() or 1} core(s); "
                    f"at most {most} ({MAX_LOCAL_WORKERS_PER_CORE} per core: each imports the whole stack, and more "
                    "processes than cores only wait for them)")
    return int(count)


#: The address schemes dobkit connects to (a bare ``host:port`` is TCP to Dask as well).
_SCHEMES = ("tcp",)


def _check_scheme(address: str, error: type[Exception]) -> None:
    scheme = address.split("://", 1)[0].lower() if "://" in address else "tcp"
    if scheme not in _SCHEMES:
        raise error(f"--scheduler {address!r}: dobkit connects to a Dask scheduler over tcp:// only ({scheme}:// "
                    "needs settings dobkit does not take: certificates for tls://, UCX for ucx://); give "
                    "tcp://HOST:PORT or local[:N]; nothing was run or written")


async def _identity(distributed, address: str, timeout: float):
    # Dask's connect retries for up to `timeout`, then raises OSError (nothing reached); the handshake read after
    # it has no time-out of its own: this one's second `timeout` is the peer's time to answer
    comm = await asyncio.wait_for(distributed.comm.connect(address, timeout=timeout), 2 * timeout)
    try:
        await asyncio.wait_for(comm.write({"op": "identity"}), timeout)
        return await asyncio.wait_for(comm.read(), timeout)
    finally:
        comm.abort()


def probe_scheduler(address: str, timeout: float, error: type[Exception]) -> None:
    """Ask the scheduler at ``address`` who it is, all within ``timeout`` seconds.

    Raises
    ------
    error
        When nothing listens there, the peer does not answer in time (Dask's own client would wait for ever),
        or it answers with something other than a Dask scheduler's identity (another protocol's bytes read as a
        frame length were an allocation of exabytes, reported as out of memory).
    """
    distributed = _distributed(error, address)
    _check_scheme(address, error)
    where = f"the Dask scheduler at {address!r}"
    try:
        answer = asyncio.run(_identity(distributed, address, timeout))
    except TimeoutError:
        raise error(f"{where} did not answer within {timeout:g} s of accepting the connection (something "
                    "listens there: is it a Dask scheduler, and is it running?); nothing was run or written") from None
    except (OSError, ValueError) as err:
        raise error(f"cannot reach {where}: {err}; nothing was run or written") from None
    except (Exception, MemoryError) as err:   # noqa: BLE001 - what a peer of another protocol makes Dask's reader do
        raise error(f"{where} answered with something other than Dask's protocol ({type(err).__name__} reading its "
                    "reply); give a Dask scheduler's address (tcp://HOST:8786); nothing was run or written") \
            from None
    if not (isinstance(answer, dict) and answer.get("type") == "Scheduler"):
        kind = answer.get("type") if isinstance(answer, dict) else type(answer).__name__
        raise error(f"{where} is not a Dask scheduler (it says it is {kind!r}); give a scheduler's address; nothing "
                    "was run or written")


@contextlib.contextmanager
def dask_session(address: str, timeout: float, error: type[Exception]):
    """A Dask client of the scheduler at ``address`` (``tcp://host:8786``), or of a ``LocalCluster`` started
    here for ``local[:N]`` (N worker processes of one thread on 127.0.0.1, no dashboard); the client, and the
    cluster it started, are closed when the ``with`` block ends, on an error or Ctrl-C too.

    Raises
    ------
    error
        When Dask is not installed (naming the ``cluster`` extra), ``local:N`` is not a whole number >= 1, the
        address is not ``tcp://`` or the scheduler does not answer within ``timeout`` seconds
        (:func:`probe_scheduler`).
    """
    workers = local_workers(address, error)
    distributed = _distributed(error, address)
    with contextlib.ExitStack() as stack:
        if workers is not None:
            with sigint_held():        # the cluster's loop thread and worker processes leave Ctrl-C to us
                cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                   host="127.0.0.1", dashboard_address=None,
                                                   silence_logs=logging.CRITICAL,
                                                   preload=["analysis.jobs.interrupts"],
                                                   # its health page on a free port, not 8787 (maybe in use)
                                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
            stack.callback(cluster.close)
            target = cluster
        else:
            probe_scheduler(address, timeout, error)
            target = address
        try:
            client = distributed.Client(target, timeout=f"{timeout}s")
        except (OSError, TimeoutError, ValueError) as err:
            raise error(f"cannot reach the Dask scheduler at {address!r}: {err}; nothing was run or written") \
                from None
        stack.callback(client.close)
        yield client


def dask_threads(client) -> int:
    """Worker threads of the cluster now (at least 1)."""
    return max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))


def call_with_notes(function: Callable, payload) -> tuple[object, list[str]]:
    """``function(payload)`` and the engine notes it would have printed, for the command to print once.
    Other warnings pass as they are."""
    from blocks.figure2.loop import EngineFallbackWarning
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
    from blocks.figure2.loop import EngineFallbackWarning
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
