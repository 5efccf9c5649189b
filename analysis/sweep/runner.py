"""Running a sweep: batches on this machine's cores or on a Dask cluster, one results row per run, resumable.

::

    from analysis.sweep.spec import load_sweep
    from analysis.sweep.runner import run_sweep
    outcome = run_sweep(load_sweep("robustness.toml"), "robustness-results.jsonl")

Results go to a JSON-lines file: a header line describing the sweep (with its
*definition*, the hash of everything that decides its runs and rows), then one
line per finished run, appended as batches finish and flushed to disk --
``run_id``, ``index``, ``values`` (by sweep key), ``status`` (``ok`` or
``diverged``), ``metrics``, ``engine``, ``substeps`` (batch engine),
``seconds``.  Running the same sweep again skips every run whose id the file
already holds, so a sweep stopped half way (killed, interrupted with Ctrl-C,
or out of its wall-time budget) completes without repeating or losing finished
runs; a line cut off by a kill is dropped and that run is done again.

One file, one sweep
    A results file whose header records another definition (an edited grid,
    other metrics, another base scenario) is refused with what differs;
    ``restart=True`` (``--restart``) moves it aside, under a name that says
    which definition it held, and starts a new file.  Only the name,
    description and worst-case settings may change: the header is then
    rewritten in place.
One writer
    While a sweep runs, ``<results>.lock`` is locked (``flock``); a second
    ``run_sweep`` on the same file is refused with the first one's process id,
    host and start time.  The lock ends with the process, however it ends.
Integrity
    Every row carries a checksum of its contents; a row changed after it was
    written is left out (its run is done again).  Two rows of one run that
    differ in more than the time they took are refused, naming both lines and
    the fields, and so are bytes that are not UTF-8 (file, line, and
    ``--restart`` as the remedy).  The results file is a job log of
    :mod:`analysis.jobs.files`, as the tuning's evaluation log is.
"""
from __future__ import annotations

import contextlib
import itertools
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.jobs.cluster import call_with_notes, dask_session, dask_threads, run_on_dask, take_with_notes
from analysis.jobs.files import JobLog, LogKind
from analysis.jobs.interrupts import sigint_held
from analysis.sweep.spec import BATCH_ENGINES, HEADER_PARTS, SweepError, SweepSpec, load_sweep, run_schedule, split_changes
from blocks.engines.budget import Budget, BudgetError, largest_batch
from blocks.figure2.batch import Variants, simulate_batch
from blocks.plumbing.progress import ProgressCallback, count_progress
from blocks.plumbing.workers import worker_pool
from blocks.scenarios.scenario import Scenario, scenario_from_dict

__all__ = ["run_sweep", "read_results", "read_header", "ResultsFile", "SweepOutcome", "simulate_chunk",
           "results_lock", "ROW_STATUSES", "RESULTS_LOG"]

#: Statuses of a finished run.
ROW_STATUSES = ("ok", "diverged")


# --------------------------------------------------------------------------------------------
# Reading the results file
# --------------------------------------------------------------------------------------------
def row_problem(record) -> str:
    """Why a parsed line is not a usable run row ('' if it is)."""
    if not isinstance(record, dict):
        return "not a JSON object"
    missing = [k for k in ("run_id", "index", "values", "status", "metrics") if k not in record]
    if missing:
        return f"missing {', '.join(missing)}"
    if not isinstance(record["run_id"], str) or not record["run_id"]:
        return f"run_id {record['run_id']!r} is not text"
    if isinstance(record["index"], bool) or not isinstance(record["index"], int) or record["index"] < 0:
        return f"index {record['index']!r} is not a whole number >= 0"
    if not isinstance(record["values"], dict):
        return "values is not an object"
    if record["status"] not in ROW_STATUSES:
        return f"status {record['status']!r} is not one of {list(ROW_STATUSES)}"
    if not isinstance(record["metrics"], dict):
        return "metrics is not an object"
    for name, value in record["metrics"].items():
        values = value if isinstance(value, list) else [value]
        if not all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values):
            return f"metric {name!r} is not a number or a list of numbers"
    return ""


#: The results file as a job log (:mod:`analysis.jobs.files`): its words, its header and its row ids.
RESULTS_LOG = LogKind(header_key="sweep", id_key="run_id", error=SweepError, what="results file", job="sweep",
                      elsewhere="another --results file", parts=HEADER_PARTS)


class ResultsFile(JobLog):
    """A results file read line by line: its header, its usable rows, and the lines it could not use.

    A :class:`analysis.jobs.files.JobLog` of :data:`RESULTS_LOG` (checksums, repeats, bytes that are not UTF-8).

    Attributes
    ----------
    header : dict or None
        The sweep header (first line), None for a missing or empty file.
    problems : list of str
        One entry per line that is not a usable row (``"line 7: missing values"``).
    repeated : int
        Rows that repeat an earlier row of the same run with the same values (counted once).
    """

    def __init__(self, path: Path, header: dict | None = None) -> None:
        super().__init__(Path(path), RESULTS_LOG)
        self.header = header

    def rows(self, problem=row_problem) -> Iterator[dict]:
        """The usable run rows, in file order, each run once; a truncated last line (a killed writer) is not a row.

        Raises
        ------
        SweepError
            On two rows of one run with different values, or bytes that are not UTF-8 (file, line and remedy).
        """
        return super().rows(problem)


def read_header(path: str | Path) -> dict | None:
    """The sweep header of a results file (its first line), or None when the file is missing or has none."""
    return JobLog(Path(path), RESULTS_LOG).header()


def read_results(path: str | Path) -> tuple[dict | None, list[dict]]:
    """The header and the usable run rows of a results file (see :class:`ResultsFile` for the lines left out)."""
    results = ResultsFile(Path(path), read_header(path))
    return results.header, list(results.rows())


def results_lock(results: Path):
    """Hold ``<results>.lock`` while the block runs (:func:`analysis.jobs.files.exclusive_lock`).

    Raises
    ------
    SweepError
        When another process holds it; the message says which (process id, host, since when).
    """
    return JobLog(Path(results), RESULTS_LOG).lock()


def _strict(value):
    """A metric value with non-finite numbers as None (strict JSON; the summary reads None as not finite)."""
    if isinstance(value, list):
        return [_strict(v) for v in value]
    return value if value is None or math.isfinite(value) else None


# --------------------------------------------------------------------------------------------
# Simulating a chunk (in this process, a worker process or on a Dask worker)
# --------------------------------------------------------------------------------------------
@dataclass
class SweepOutcome:
    """What a :func:`run_sweep` call did.

    Attributes
    ----------
    total, skipped, ran, diverged : int
        Runs in the sweep, found finished in the results file, run now, and diverged now.
    results : pathlib.Path
    seconds : float
    moved_to : pathlib.Path or None
        Where an old results file of another definition was moved (``restart=True``).
    problems : list of str
        Lines of the results file that are not usable rows (their runs are done again).
    """

    total: int
    skipped: int
    ran: int
    diverged: int
    results: Path
    seconds: float
    moved_to: Path | None = None
    problems: list = field(default_factory=list)


def simulate_chunk(payload: dict) -> list[dict]:
    """Run one chunk of a sweep and return its rows (picklable in and out: used by processes and Dask).

    ``payload``: ``scenario`` (data dict) and ``source``, ``observer``, ``engine``, ``substeps``,
    ``metrics``, and ``runs`` as a list of ``{run_id, index, values, draw, member}`` where ``member``
    holds the run's per-member scenario keys.
    """
    base = scenario_from_dict(payload["scenario"], source=payload["source"])
    runs = payload["runs"]
    t0 = time.perf_counter()
    rows = []
    if payload["engine"] in BATCH_ENGINES:
        engine = "cuda" if payload["engine"] == "cuda" else "auto"
        result = simulate_batch(None, Variants(base, [r["member"] for r in runs]), observer=payload["observer"],
                                metrics=payload["metrics"], substeps=payload["substeps"], engine=engine)
        seconds = (time.perf_counter() - t0) / len(runs)
        for i, r in enumerate(runs):
            ok = bool(result.ok[i])
            rows.append(_row(r, "ok" if ok else "diverged", result.member_metrics(i) if ok else {},
                             None if ok else float(result.failed_at[i]), seconds, payload["engine"],
                             substeps=result.substeps))
        return rows
    from blocks.figure2.loop import SimulationError, simulate
    from blocks.figure2.metrics import tracking_metrics
    for r in runs:
        t1 = time.perf_counter()
        try:
            response = simulate(base.with_changes(r["member"]), observer=payload["observer"])
        except SimulationError as err:
            rows.append(_row(r, "diverged", {}, None, time.perf_counter() - t1, "fast", message=str(err)))
            continue
        metrics = tracking_metrics(response)
        rows.append(_row(r, "ok", {m: metrics[m] for m in payload["metrics"]}, None, time.perf_counter() - t1, "fast"))
    return rows


def _chunk_in_worker(payload: dict) -> tuple[list[dict], list[str]]:
    """:func:`simulate_chunk` in a worker process, with its engine notes
    (:func:`analysis.jobs.cluster.call_with_notes`); the worker leaves Ctrl-C to the process that started it, and ends
    quietly when the pool is shut down with SIGTERM (the command's own SIGTERM handler is not a worker's)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return call_with_notes(simulate_chunk, payload)


def _row(run: dict, status: str, metrics: dict, failed_at, seconds: float, engine: str, message: str = "",
         substeps: int | None = None) -> dict:
    row = {"run_id": run["run_id"], "index": run["index"], "values": run["values"], "status": status,
           "metrics": {k: _strict(v) for k, v in metrics.items()}, "engine": engine, "seconds": round(seconds, 6)}
    if substeps is not None:
        row["substeps"] = int(substeps)
    if run.get("draw") is not None:
        row["draw"] = run["draw"]
    if failed_at is not None and math.isfinite(failed_at):
        row["failed_at"] = failed_at
    if message:
        row["message"] = message
    return row


def _payloads(spec: SweepSpec, pending: np.ndarray, workers: int, budget: Budget) -> Iterator[dict]:
    """Payloads, made as they are needed: pending runs grouped by shared scenario, substeps and noise, cut
    into batches of at most ``batch.size`` runs, fewer when the memory budget (shared by ``workers``
    batches at a time) asks for it or when that keeps all workers busy."""
    plan = spec.plan
    order = pending[np.lexsort((pending, plan.noise[pending], plan.substeps[pending], plan.group[pending]))]
    keys = np.stack([plan.group[order], plan.substeps[order], plan.noise[order].astype(np.int64)], axis=1)
    bounds = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1 if order.size else []
    size = spec.batch_size if spec.engine in BATCH_ENGINES else max(1, min(spec.batch_size, 8))
    size = max(1, min(size, math.ceil(len(pending) / max(1, workers))))
    share = budget.share(workers)
    base_for: dict[int, Scenario] = {}
    for members in np.split(order, bounds):
        if members.size == 0:
            continue
        first = int(members[0])
        g, substeps, noisy = int(plan.group[first]), int(plan.substeps[first]), bool(plan.noise[first])
        if g not in base_for:
            base_for.clear()             # keep one shared scenario at a time
            base_for[g] = spec.base.with_changes(plan.shared[g])
        base = base_for[g]
        n = size
        if spec.engine in BATCH_ENGINES:
            schedule = run_schedule(base, substeps, noisy)
            fits = largest_batch(share.memory, steps=schedule.steps, grid_points=schedule.grid_points, noise=noisy,
                                 noise_samples=schedule.noise_samples, joints=base.robot.n)
            if fits < 1:
                raise BudgetError(f"{spec.name}: one run of {schedule.steps:.3g} steps does not fit in the memory "
                                  f"budget of {workers} workers running at a time ({share.memory / 2 ** 20:.0f} MiB "
                                  "each); use fewer --workers or raise --max-memory", key="workers", limit="memory")
            n = min(n, fits)
        for start in range(0, members.size, n):
            runs = []
            for i in members[start:start + n].tolist():
                run = spec.runs[i]
                runs.append({"run_id": run.run_id, "index": run.index, "values": run.values, "draw": run.draw,
                             "member": split_changes(run.values)[1]})
            yield {"scenario": base.data, "source": base.source, "observer": spec.observer, "engine": spec.engine,
                   "substeps": substeps, "metrics": list(spec.metrics), "runs": runs}


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------
def check_workers(workers) -> int:
    """The number of local worker processes: None is all cores; anything but a whole number >= 1 is refused."""
    if workers is None:
        return os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise SweepError(f"workers must be a whole number >= 1, got {workers!r}")
    return int(workers)


def run_sweep(spec: SweepSpec | str | Path, results: str | Path, scheduler: str | None = None,
              workers: int | None = None, progress: bool | ProgressCallback = True,
              on_rows: Callable[[list[dict]], None] | None = None, restart: bool = False,
              budget: Budget | None = None, scheduler_timeout: float = 10.0) -> SweepOutcome:
    """Run the sweep's unfinished runs and append their rows to ``results``.

    Parameters
    ----------
    spec : SweepSpec or path
        A validated sweep or the path of a sweep file.
    results : path
        The JSON-lines results file; runs whose id it already holds are skipped.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``), or
        ``local[:N]`` to start a cluster of N worker processes (default: one
        per core) on 127.0.0.1 for this sweep and close it at the end; the
        batches run on its workers.  Needs ``dask[distributed]``.  The
        connection is made before the results file is touched.
    workers : int, optional
        Local worker processes (default: all cores); 1 runs in this process.
    progress : bool or callable
        True: show the finished runs on standard error (see
        :class:`blocks.plumbing.progress.CountProgress`); a callable is called as
        ``progress("sweep", finished / total)`` at the start and after every batch.
    on_rows : callable, optional
        Called with each batch's rows after they are written.
    restart : bool
        Move a results file of another sweep definition aside (see
        :attr:`SweepOutcome.moved_to`) instead of refusing it.
    budget : Budget, optional
        Memory (shared by the batches in flight) and wall time; default: the
        one the sweep was checked against.
    scheduler_timeout : float
        Seconds to wait for the Dask scheduler to answer.

    Returns
    -------
    SweepOutcome

    Raises
    ------
    SweepError
        On a results file of another definition, a results file in use, or bad ``workers``.
    BudgetError
        When the wall-time budget runs out (finished runs are kept: run again to go on).
    """
    spec = spec if isinstance(spec, SweepSpec) else load_sweep(spec)
    budget = spec.budget if budget is None else budget
    workers = check_workers(workers)
    if spec.engine == "cuda" and scheduler is None:
        workers = 1             # one device: its batches run one after another here, the kernel compiled once
    results = Path(results)
    t0 = time.perf_counter()
    log = ResultsFile(results)
    with log.lock():
        moved = log.prepare(spec.header()["sweep"], spec.name, restart)
        stored = ResultsFile(results, read_header(results))
        finished = {row["run_id"] for row in stored.rows()}
        pending = np.array([i for i in range(len(spec.runs)) if spec.runs.run_id(i) not in finished], dtype=np.int64)
        skipped = len(spec.runs) - pending.size
        del finished
        outcome = SweepOutcome(total=len(spec.runs), skipped=skipped, ran=0, diverged=0, results=results, seconds=0.0,
                               moved_to=moved, problems=list(stored.problems))
        if pending.size == 0:
            count_progress(progress, len(spec.runs), skipped, label="sweep").close()
            outcome.seconds = time.perf_counter() - t0
            return outcome
        # connect before writing anything: a failed connection leaves no results file
        session = contextlib.ExitStack()
        client = session.enter_context(dask_session(scheduler, scheduler_timeout, SweepError)) \
            if scheduler is not None else None
        with contextlib.ExitStack() as opening:        # the cluster closed if the results file cannot be opened
            opening.push(session)
            writer = log.writer(spec.header()["sweep"])
            bar = count_progress(progress, len(spec.runs), skipped, label="sweep")
            opening.pop_all()

        def take(new_rows: list[dict]) -> None:
            writer.write(new_rows)
            outcome.ran += len(new_rows)
            outcome.diverged += sum(r["status"] == "diverged" for r in new_rows)
            bar.update(len(new_rows))
            if on_rows is not None:
                on_rows(new_rows)
            if budget.seconds is not None and time.perf_counter() - t0 > budget.seconds:
                raise BudgetError(f"{spec.name}: the wall-time budget of {budget.seconds:g} s ran out after "
                                  f"{outcome.ran} runs ({skipped + outcome.ran} of {len(spec.runs)} finished, kept in "
                                  f"'{results}'); run the same command again to go on, or raise --max-seconds",
                                  key="seconds", limit="seconds")

        try:
            if client is not None:
                threads = dask_threads(client)
                run_on_dask(client, simulate_chunk, _payloads(spec, pending, threads, budget), take, threads,
                            SweepError)
            else:
                payloads = _payloads(spec, pending, workers, budget)
                if workers == 1:
                    for payload in payloads:
                        take(simulate_chunk(payload))
                else:
                    _run_processes(payloads, workers, take)
        finally:
            writer.close()
            bar.close()
            session.close()
    outcome.seconds = time.perf_counter() - t0
    return outcome


def _run_processes(payloads: Iterator[dict], workers: int, take) -> None:
    pool = worker_pool(workers)
    try:
        with sigint_held():
            running = {pool.submit(_chunk_in_worker, p) for p in itertools.islice(payloads, workers)}
        while running:            # keep at most one batch per worker in flight: memory stays bounded
            done, running = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                take_with_notes(fut.result(), take)
                nxt = next(payloads, None)
                if nxt is not None:
                    with sigint_held():
                        running.add(pool.submit(_chunk_in_worker, nxt))
    except BaseException:
        _end_now(pool)
        raise
    pool.shutdown(wait=True)


#: Seconds to wait for each terminated worker and for the pool's thread when a pool is ended now.
_END_WAIT = 5.0


def _end_now(pool) -> None:
    """End an interrupted or failed pool now rather than wait for its batches: its workers terminated, then
    its threads joined, so that nothing is left for the interpreter's exit to wait on (where another Ctrl-C
    would print a concurrent.futures traceback)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(_END_WAIT)
    # taken before shutdown, which forgets them
    manager = getattr(pool, "_executor_manager_thread", None)
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
    try:
        pool.shutdown(wait=False, cancel_futures=True)
        if manager is not None:
            manager.join(1.0)            # it sees the workers' ends at once, unless it is stuck in a read
            if manager.is_alive() and writer is not None:
                # a worker terminated while it sent its batch's result leaves the pool's reader waiting for the rest
                # of that message (it hung here for good, and at exit): this process's own copy of the pipe's
                # writing end is all that keeps it open; closed, the read ends (EOF) and the pool ends as broken
                with contextlib.suppress(Exception):
                    writer.close()
                manager.join(_END_WAIT)
    except BaseException:         # noqa: BLE001 -- a second Ctrl-C while the threads end: the first one is reported
        pool.shutdown(wait=False, cancel_futures=True)
