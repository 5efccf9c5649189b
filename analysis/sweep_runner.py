"""Running a sweep: batches on this machine's cores or on a Dask cluster, one results row per run, resumable.

::

    from analysis.sweep import load_sweep
    from analysis.sweep_runner import run_sweep
    outcome = run_sweep(load_sweep("robustness.toml"), "robustness-results.jsonl")

Results go to a JSON-lines file: a header line describing the sweep, then one
line per finished run, appended as batches finish and flushed to disk --
``run_id``, ``index``, ``values`` (by sweep key), ``status`` (``ok`` or
``diverged``), ``metrics``, ``engine``, ``seconds``.  Running the same sweep
again skips every run whose id the file already holds, so a sweep stopped half
way completes without repeating or losing finished runs; a line cut off by a
kill is dropped and that run is done again.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import time
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from blocks.batch import Variants, noise_breakpoints, simulate_batch
from blocks.progress import ProgressCallback, count_progress
from blocks.scenario import Scenario, scenario_from_dict
from blocks.workers import worker_pool
from .sweep import Run, SweepError, SweepSpec, json_default, load_sweep, split_changes

__all__ = ["run_sweep", "read_results", "SweepOutcome", "simulate_chunk"]


def read_results(path: str | Path) -> tuple[dict | None, list[dict]]:
    """The header and the run rows of a results file; a truncated last line (a killed writer) is ignored."""
    path = Path(path)
    if not path.exists():
        return None, []
    header, rows = None, []
    with path.open("r", encoding="utf-8") as fh:
        for line in fh:
            if not line.endswith("\n"):
                break                      # cut off mid-write: that run was not finished
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if "sweep" in record and header is None:
                header = record["sweep"]
            elif "run_id" in record:
                rows.append(record)
    return header, rows


def _repair(path: Path) -> None:
    """Cut a partial last line left by a writer that was killed mid-line."""
    if not path.exists() or path.stat().st_size == 0:
        return
    with path.open("rb+") as fh:
        data = fh.read()
        if not data.endswith(b"\n"):
            fh.truncate(data.rfind(b"\n") + 1)


class _Writer:
    """Appends rows to the results file; every batch is flushed and synced so a kill loses nothing finished."""

    def __init__(self, path: Path, header: dict) -> None:
        _repair(path)
        new = not path.exists() or path.stat().st_size == 0
        path.parent.mkdir(parents=True, exist_ok=True)
        self.fh = path.open("a", encoding="utf-8")
        if new:
            self.write([header])

    def write(self, rows: Iterable[dict]) -> None:
        self.fh.write("".join(json.dumps(r, default=json_default) + "\n" for r in rows))
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def close(self) -> None:
        self.fh.close()


@dataclass
class SweepOutcome:
    """Counts of a :func:`run_sweep` call: runs in the sweep, found finished, run now, and diverged now."""

    total: int
    skipped: int
    ran: int
    diverged: int
    results: Path
    seconds: float


def simulate_chunk(payload: dict) -> list[dict]:
    """Run one chunk of a sweep and return its rows (picklable in and out: used by processes and Dask).

    ``payload``: ``scenario`` (data dict) and ``source``, ``observer``, ``engine``, ``substeps``,
    ``noise`` (step on the noise sample times), ``metrics``, and ``runs`` as a list of
    ``{run_id, index, values, draw, member}`` where ``member`` holds the run's per-member scenario keys.
    """
    base = scenario_from_dict(payload["scenario"], source=payload["source"])
    runs = payload["runs"]
    t0 = time.perf_counter()
    rows = []
    if payload["engine"] == "batch":
        result = simulate_batch(None, Variants(base, [r["member"] for r in runs]), observer=payload["observer"],
                                metrics=payload["metrics"], substeps=payload["substeps"],
                                breakpoints=noise_breakpoints(base) if payload.get("noise") else ())
        seconds = (time.perf_counter() - t0) / len(runs)
        for i, r in enumerate(runs):
            ok = bool(result.ok[i])
            rows.append(_row(r, "ok" if ok else "diverged", result.member_metrics(i) if ok else {},
                             None if ok else float(result.failed_at[i]), seconds, "batch"))
        return rows
    from blocks.loop import SimulationError, simulate
    from blocks.metrics import tracking_metrics
    for r in runs:
        t1 = time.perf_counter()
        try:
            response = simulate(base.with_changes(r["member"]), observer=payload["observer"])
        except SimulationError as err:
            rows.append(_row(r, "diverged", {}, None, time.perf_counter() - t1, "fast", str(err)))
            continue
        metrics = tracking_metrics(response)
        rows.append(_row(r, "ok", {m: metrics[m] for m in payload["metrics"]}, None, time.perf_counter() - t1, "fast"))
    return rows


def _row(run: dict, status: str, metrics: dict, failed_at, seconds: float, engine: str, message: str = "") -> dict:
    row = {"run_id": run["run_id"], "index": run["index"], "values": run["values"], "status": status,
           "metrics": metrics, "engine": engine, "seconds": round(seconds, 6)}
    if run.get("draw") is not None:
        row["draw"] = run["draw"]
    if failed_at is not None:
        row["failed_at"] = failed_at
    if message:
        row["message"] = message
    return row


def _chunks(spec: SweepSpec, pending: list[Run], workers: int) -> list[dict]:
    """Payloads: runs grouped by their shared scenario, cut into batches (smaller when that keeps all workers busy)."""
    groups: dict[str, tuple[Scenario, list]] = {}
    for run in pending:
        structural, member = split_changes(run.values)
        gkey = json.dumps(structural, sort_keys=True, default=json_default)
        if gkey not in groups:
            groups[gkey] = (spec.base.with_changes(structural), [])
        groups[gkey][1].append({"run_id": run.run_id, "index": run.index, "values": run.values, "draw": run.draw,
                                "member": member})
    size = spec.batch_size if spec.engine == "batch" else max(1, min(spec.batch_size, 8))
    size = max(1, min(size, math.ceil(len(pending) / max(1, workers))))
    payloads = []
    for gkey, (base, runs) in groups.items():
        schedule = spec.schedules.get(gkey, {"substeps": spec.substeps, "noise": False})
        for start in range(0, len(runs), size):
            payloads.append({"scenario": base.data, "source": base.source, "observer": spec.observer,
                             "engine": spec.engine, "substeps": schedule["substeps"], "noise": schedule["noise"],
                             "metrics": list(spec.metrics), "runs": runs[start:start + size]})
    return payloads


def run_sweep(spec: SweepSpec | str | Path, results: str | Path, scheduler: str | None = None,
              workers: int | None = None, progress: bool | ProgressCallback = True,
              on_rows: Callable[[list[dict]], None] | None = None) -> SweepOutcome:
    """Run the sweep's unfinished runs and append their rows to ``results``.

    Parameters
    ----------
    spec : SweepSpec or path
        A validated sweep or the path of a sweep file.
    results : path
        The JSON-lines results file; runs whose id it already holds are skipped.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``); the
        batches run on its workers.  Needs ``dask[distributed]``.
    workers : int, optional
        Local worker processes (default: all cores); 1 runs in this process.
    progress : bool or callable
        True: show the finished runs on standard error (see
        :class:`blocks.progress.CountProgress`); a callable is called as
        ``progress("sweep", finished / total)`` at the start and after every batch.
    on_rows : callable, optional
        Called with each batch's rows after they are written.

    Returns
    -------
    SweepOutcome
    """
    spec = spec if isinstance(spec, SweepSpec) else load_sweep(spec)
    results = Path(results)
    header, rows = read_results(results)
    if header is not None and header.get("name") != spec.name:
        raise SweepError(f"results file '{results}' belongs to sweep '{header.get('name')}', not '{spec.name}'; "
                         "choose another results file")
    finished = {r["run_id"] for r in rows if r.get("status") in ("ok", "diverged")}
    pending = [run for run in spec.runs if run.run_id not in finished]
    skipped = len(spec.runs) - len(pending)
    workers = (os.cpu_count() or 1) if workers is None else max(1, int(workers))
    t0 = time.perf_counter()
    bar = count_progress(progress, len(spec.runs), skipped, label="sweep")
    writer = _Writer(results, spec.header())
    ran = diverged = 0

    def take(new_rows: list[dict]) -> None:
        nonlocal ran, diverged
        writer.write(new_rows)
        ran += len(new_rows)
        diverged += sum(r["status"] == "diverged" for r in new_rows)
        bar.update(len(new_rows))
        if on_rows is not None:
            on_rows(new_rows)

    try:
        if pending and scheduler is not None:
            _run_dask(spec, pending, scheduler, take)
        elif pending:
            payloads = _chunks(spec, pending, workers)
            if workers == 1 or len(payloads) == 1:
                for payload in payloads:
                    take(simulate_chunk(payload))
            else:
                _run_processes(payloads, workers, take)
    finally:
        writer.close()
        bar.close()
    return SweepOutcome(total=len(spec.runs), skipped=skipped, ran=ran, diverged=diverged, results=results,
                        seconds=time.perf_counter() - t0)


def _run_processes(payloads: list[dict], workers: int, take) -> None:
    with worker_pool(min(workers, len(payloads))) as pool:
        todo = iter(payloads)
        running = {pool.submit(simulate_chunk, p) for p in itertools.islice(todo, workers)}
        while running:            # keep at most one batch per worker in flight: memory stays bounded
            done, running = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                take(fut.result())
                nxt = next(todo, None)
                if nxt is not None:
                    running.add(pool.submit(simulate_chunk, nxt))


def _dask():
    try:
        import distributed
    except ImportError:
        raise SweepError("--scheduler needs Dask: pip install 'dask[distributed]' (the 'cluster' extra)") from None
    return distributed


def _run_dask(spec: SweepSpec, pending: list[Run], address: str, take) -> None:
    distributed = _dask()
    with distributed.Client(address, timeout="10s") as client:
        threads = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
        futures = [client.submit(simulate_chunk, p, pure=False) for p in _chunks(spec, pending, max(1, threads))]
        for fut in distributed.as_completed(futures):
            take(fut.result())
