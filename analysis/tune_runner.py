"""Running a tuning: differential evolution polished by Nelder-Mead, every evaluation logged, resumable.

::

    from analysis.tune import load_tuning
    from analysis.tune_runner import run_tune
    result = run_tune(load_tuning("paper-tune"), "paper-tune-out")      # a TuneResult; files in the folder

The search
    1. The linear constraints (torque noise, stability margin) are checked on
       a Latin hypercube sample of the bounds, then, if no sample meets them,
       by a Nelder-Mead search for the smallest violation: when no gains within
       the bounds meet them, the tuning is refused before anything is simulated,
       naming the closest gains found and what they miss by.
    2. The base scenario's own gains are evaluated (the reference).
    3. :func:`scipy.optimize.differential_evolution` searches the unit box
       (log10 of each gain between its bounds) with a population of
       ``search.population`` (a Latin hypercube, its first member the base gains
       when they lie within the bounds), seeded by ``search.seed``; every
       generation is one call, so its candidates are simulated in a few large
       batches.
    4. :func:`scipy.optimize.minimize` (Nelder-Mead, within the bounds) polishes
       the best candidate with at most ``search.polish_evaluations`` evaluations.
    5. The answer is the best evaluation of all (:mod:`analysis.tune_eval`
       ranks them): the feasible one with the lowest objective, else -- named
       as infeasible -- the one closest to feasible.

The evaluation log (``evaluations.jsonl`` in the output folder)
    A header line with the tuning's *definition* (a hash of everything that
    decides which gains are evaluated and what an evaluation gives), then one
    line per simulated candidate, written and flushed as each batch finishes.
    The search is deterministic, so running the same tuning again replays it:
    each candidate found in the log is taken from there instead of being
    simulated, and the search continues where it stopped -- a killed or
    interrupted tuning resumes and ends with the same result as an
    uninterrupted one.  A log of another definition is refused (``restart``
    moves it aside); only the name, description and evaluation budget may
    change (raising ``max_evaluations`` continues a finished tuning).  While a
    tuning runs, ``evaluations.jsonl.lock`` keeps a second one out.

Outputs (written when the search ends)
    ``tune.json`` (:class:`TuneResult`), the tuned scenario ``<scenario>-tuned.toml``
    (the base scenario with the tuned gains; ``dobkit simulate --scenario`` runs
    it, and evaluating it on the set gives the reported objective), and the
    figures (:mod:`analysis.tune_report`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution, minimize
from scipy.stats import qmc

from blocks.batch import simulate_batch
from blocks.budget import Budget
from blocks.progress import ProgressCallback, StageProgress

from .job_files import cut_partial_last_line, exclusive_lock, move_aside, write_lines_atomically
from .sweep import json_default
from .tune import METRIC_WORDS, TuneError, TuneSpec, differences, load_tuning
from .tune_eval import Evaluation, Evaluator, check_seconds, evaluation_estimate, gains_key
from .tune_results import (
    RESULT_NAME,
    PointResult,
    TuneFigure,
    TuneHistory,
    TuneResult,
    excess_text,
    numbers_text,
    objective_text,
)

__all__ = ["run_tune", "TuneResult", "PointResult", "TuneHistory", "TuneFigure", "read_log", "LOG_NAME",
           "RESULT_NAME", "FEASIBILITY_SAMPLES", "DE_TOL"]

LOG_NAME = "evaluations.jsonl"
#: Points of the bounds at which the linear constraints are tried before the search.
FEASIBILITY_SAMPLES = 128
#: Relative spread of the population's scores at which differential evolution stops early.
DE_TOL = 1e-3
_FEASIBILITY_POLISH = 400




# --------------------------------------------------------------------------------------------
# The evaluation log
# --------------------------------------------------------------------------------------------
_ROW_KEYS = ("key", "gains", "values", "peak_torque", "diverged", "substeps", "seconds")


def read_log(path: str | Path) -> tuple[dict | None, dict, list[str]]:
    """The header, the rows by candidate key, and the unusable lines of an evaluation log.

    A last line cut off by a kill is not a row (that candidate is simulated again).
    """
    path = Path(path)
    header, rows, problems = None, {}, []
    if not path.exists():
        return None, rows, problems
    with path.open("r", encoding="utf-8") as fh:
        for number, line in enumerate(fh, start=1):
            if not line.endswith("\n"):
                break
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as err:
                problems.append(f"line {number}: not JSON ({err.msg})")
                continue
            if number == 1 and isinstance(record, dict) and isinstance(record.get("tune"), dict):
                header = record["tune"]
                continue
            missing = [k for k in _ROW_KEYS if not isinstance(record, dict) or k not in record]
            if missing:
                problems.append(f"line {number}: missing {', '.join(missing)}")
                continue
            if record["key"] != gains_key(record["gains"]):
                problems.append(f"line {number}: its key does not match its gains")
                continue
            rows[record["key"]] = record
    return header, rows, problems


def _prepare_log(spec: TuneSpec, log: Path, restart: bool) -> Path | None:
    """Make the log the tuning's own: refuse (or with ``restart`` move aside) one of another definition; rewrite
    the header when only the name, description or budget changed.  Returns where an old log was moved."""
    header, _, _ = read_log(log)
    if header is None:
        if log.exists() and log.stat().st_size > 0:
            if not restart:
                raise TuneError(f"evaluation log '{log}' does not start with a tuning header, so it is not a log of "
                                "this tuning; choose another --out folder, or --restart to move it aside")
            return move_aside(log, "unknown")
        return None
    new = spec.header()["tune"]
    if header.get("definition") != spec.definition:
        if restart:
            return move_aside(log, str(header.get("definition") or "undefined"))
        what = ", ".join(differences(header, new)) or "the tuning definition"
        raise TuneError(f"evaluation log '{log}' belongs to tuning '{header.get('name')}' of definition "
                        f"{header.get('definition')}, not to this definition of '{spec.name}' ({spec.definition}): "
                        f"{what} differ(s). Its evaluations would mix with this tuning's. Give this tuning another "
                        "--out folder, or --restart to move the old log aside and start anew")
    if header != new:
        cut_partial_last_line(log)
        with log.open("r", encoding="utf-8") as fh:
            fh.readline()
            rest = fh.readlines()
        write_lines_atomically(log, [json.dumps({"tune": new}, default=json_default) + "\n"] + rest)
    return None


class _LogWriter:
    """Appends rows to the log (header first when new); every batch written whole, flushed and synced."""

    def __init__(self, path: Path, header: dict) -> None:
        self.path, self.header, self.fh = path, header, None

    def write(self, rows: list[dict]) -> None:
        text = "".join(json.dumps(r, default=json_default, allow_nan=False) + "\n" for r in rows)
        if self.fh is None:
            cut_partial_last_line(self.path)
            if not self.path.exists() or self.path.stat().st_size == 0:
                text = json.dumps(self.header, default=json_default) + "\n" + text
            self.fh = self.path.open("a", encoding="utf-8")
        self.fh.write(text)
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def close(self) -> None:
        if self.fh is not None:
            self.fh.close()
            cut_partial_last_line(self.path)


# --------------------------------------------------------------------------------------------
# Before the search: can the linear constraints be met at all?
# --------------------------------------------------------------------------------------------
def check_linear_feasibility(spec: TuneSpec, evaluator: Evaluator) -> None:
    """Refuse a tuning whose torque-noise and stability constraints no gains within the bounds meet.

    Raises
    ------
    TuneError
        Naming the closest gains found and what they miss by.
    """
    if spec.limits.torque_noise_rms is None and spec.limits.stability_margin is None:
        return
    n = len(spec.parameters)

    def violation(u) -> float:
        noise, abscissa = evaluator.linear(spec.gains(u))
        return float(sum(evaluator.linear_violations(noise, abscissa).values()))

    sample = qmc.LatinHypercube(d=n, rng=np.random.default_rng(spec.seed)).random(FEASIBILITY_SAMPLES)
    extra = [np.zeros(n), np.ones(n)] + ([spec.base_point()] if spec.base_point() is not None else [])
    best_u, best_v = None, math.inf
    for u in extra + list(sample):
        v = violation(u)
        if v == 0:
            return
        if v < best_v:
            best_u, best_v = u, v
    found = minimize(violation, best_u, method="Nelder-Mead", bounds=[(0.0, 1.0)] * n,
                     options={"maxfev": _FEASIBILITY_POLISH, "xatol": 1e-4, "fatol": 0.0})
    if found.fun == 0:
        return
    u = found.x if found.fun < best_v else best_u
    gains = spec.gains(u)
    noise, abscissa = evaluator.linear(gains)
    limits, misses = spec.limits, []
    if limits.torque_noise_rms is not None and np.any(noise > limits.torque_noise_rms):
        j = int(np.argmax(noise / limits.torque_noise_rms))
        misses.append(f"torque noise {numbers_text(noise)} against the budget "
                      f"{numbers_text(limits.torque_noise_rms, 'N m')} (joint {j + 1} "
                      f"{excess_text(noise[j], limits.torque_noise_rms[j])})")
    if limits.stability_margin is not None and abscissa > -limits.stability_margin:
        misses.append(f"slowest pole at {abscissa:.4g} 1/s, not <= -{limits.stability_margin:g} 1/s "
                      "(constraints.stability_margin)")
    raise TuneError(f"{spec.source}: the constraints cannot be met within the [search] bounds: no gains found among "
                    f"{FEASIBILITY_SAMPLES + len(extra)} sampled and {found.nfev} searched meet the torque-noise and "
                    f"stability constraints. The closest, {_describe(gains)}, has " + "; ".join(misses)
                    + ". Widen the bounds or loosen [constraints]; nothing was simulated")


def _describe(gains: dict) -> str:
    def fmt(v):
        return f"{v:.6g}" if not isinstance(v, list) else "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
    return ", ".join(f"{k} = {fmt(v)}" for k, v in gains.items())


# --------------------------------------------------------------------------------------------
# The search
# --------------------------------------------------------------------------------------------
def run_tune(spec: TuneSpec | str | Path, out_dir: str | Path, workers: int | None = None,
             progress: bool | ProgressCallback = True, restart: bool = False, budget: Budget | None = None,
             engine: str = "auto", figures: bool = True) -> TuneResult:
    """Tune the gains (see the module docstring) and write the results into ``out_dir``.

    Parameters
    ----------
    spec : TuneSpec or path or built-in name
    out_dir : path
        Folder of the evaluation log and the outputs; created when missing.  The same folder resumes.
    workers : int, optional
        Threads (compiled engine) or processes of each batch; default: all cores.
    progress : bool or callable
        True: a :class:`blocks.progress.StageProgress` on standard error; a callable is called as
        ``progress(stage, fraction)``.
    restart : bool
        Move an evaluation log of another definition aside instead of refusing it.
    budget : Budget, optional
        Memory, steps and wall time (default: the tuning's).  When the wall time runs out the finished
        evaluations are kept and :class:`~blocks.budget.BudgetError` is raised: run again to go on.
    engine : str
        :func:`blocks.batch.simulate_batch`'s engine.
    figures : bool
        Write the figures.

    Returns
    -------
    TuneResult
        Also written as ``tune.json``.

    Raises
    ------
    TuneError
        On a log of another definition, or constraints that no gains within the bounds meet (before anything runs).
    blocks.budget.BudgetError
        When an evaluation exceeds the memory or step budget (before anything runs) or the wall time runs out.
    """
    spec = spec if isinstance(spec, TuneSpec) else load_tuning(spec)
    budget = spec.budget if budget is None else budget
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise TuneError(f"workers must be a whole number >= 1, got {workers!r}")
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise TuneError(f"output folder '{out}' is a file")
    started = time.perf_counter()
    evaluation_estimate(spec)
    display = StageProgress() if progress is True else None
    report = display if display is not None else (progress if callable(progress) else (lambda s, f: None))
    try:
        with contextlib.ExitStack() as stack:
            # the linear check needs no files: an infeasible tuning leaves nothing behind
            evaluator = Evaluator(spec, workers=workers, engine=engine)
            check_linear_feasibility(spec, evaluator)
            out.mkdir(parents=True, exist_ok=True)
            log = out / LOG_NAME
            stack.enter_context(exclusive_lock(log, TuneError, "evaluation log", "tuning", "another --out folder"))
            _prepare_log(spec, log, restart)
            _, rows, problems = read_log(log)
            writer = _LogWriter(log, spec.header())
            stack.callback(writer.close)
            search = _Search(spec, evaluator, report, budget, started)
            evaluator.log_rows, evaluator.record = rows, writer.write
            evaluator.after_batch = search.after_batch
            result = search.run()
            result = _finish(spec, evaluator, search, result, out, started, figures, report, problems)
    finally:
        if display is not None:
            display.close()
    return result


class _Search:
    """Differential evolution and the polish over one evaluator, with progress and the wall-time budget."""

    def __init__(self, spec: TuneSpec, evaluator: Evaluator, report, budget: Budget, started: float) -> None:
        self.spec, self.evaluator, self.report, self.budget, self.started = spec, evaluator, report, budget, started
        self.points: dict[str, np.ndarray] = {}
        self.stage, self.done, self.total = "", 0, 1

    def after_batch(self, n: int) -> None:
        check_seconds(self.budget, self.started, self.spec.name)

    def _evaluate(self, us: list[np.ndarray], phase: str) -> list[Evaluation]:
        gains = [self.spec.gains(u) for u in us]
        for g, u in zip(gains, us):
            self.points.setdefault(gains_key(g), np.asarray(u, dtype=float).copy())
        evs = self.evaluator.evaluate(gains, phase)
        self.done += len(us)
        self.report(self.stage, min(1.0, self.done / self.total))
        return evs

    def run(self) -> Evaluation:
        spec, n = self.spec, len(self.spec.parameters)
        self._begin("tuning: the base gains", 1)
        base = self.evaluator.evaluate([spec.gains_of_base()], "base", force=True)[0]
        self.report(self.stage, 1.0)
        init = qmc.LatinHypercube(d=n, rng=np.random.default_rng(spec.seed)).random(spec.population)
        point = spec.base_point()
        if point is not None:
            init[0] = point
        self._begin("tuning: differential evolution", spec.population * (spec.generations + 1))

        def energies(U: np.ndarray) -> np.ndarray:
            return np.array([e.energy for e in self._evaluate([U[:, k] for k in range(U.shape[1])], "search")])

        differential_evolution(energies, [(0.0, 1.0)] * n, maxiter=spec.generations, init=init, polish=False,
                               updating="deferred", vectorized=True, rng=spec.seed, tol=DE_TOL, atol=0.0)
        if spec.polish_evaluations > 0:
            start = self._best(search_only=True)
            u0 = self.points[start.key]
            self._begin("tuning: local polish (Nelder-Mead)", spec.polish_evaluations)
            step = np.where(u0 + 0.05 <= 1.0, 0.05, -0.05)
            simplex = np.vstack([u0] + [u0 + step[i] * np.eye(n)[i] for i in range(n)])
            minimize(lambda u: self._evaluate([u], "polish")[0].energy, u0, method="Nelder-Mead",
                     bounds=[(0.0, 1.0)] * n,
                     options={"maxfev": spec.polish_evaluations, "initial_simplex": simplex, "xatol": 1e-4,
                              "fatol": 0.0})
        best = self._best()
        if not best.simulated:
            best = self.evaluator.evaluate([best.gains], "final", force=True)[0]
        self.base = base
        return best

    def _begin(self, stage: str, total: int) -> None:
        self.stage, self.done, self.total = stage, 0, max(1, total)
        self.report(stage, 0.0)

    def _best(self, search_only: bool = False) -> Evaluation:
        """The best evaluation so far: feasible with the lowest objective, else the least infeasible."""
        pool = [e for e in self.evaluator.history if e.phase != "base" and (not search_only or e.phase == "search")]
        return min(pool, key=lambda e: (e.energy, not e.simulated))


# --------------------------------------------------------------------------------------------
# The outputs
# --------------------------------------------------------------------------------------------
def _point(ev: Evaluation, nominal: float | None) -> PointResult:
    values = ev.values if ev.values is not None else None
    finite = values[np.isfinite(values)] if values is not None else np.array([])
    fin = lambda v: float(v) if v is not None and math.isfinite(v) else None              # noqa: E731
    return PointResult(
        gains=ev.gains, objective=fin(ev.objective), worst=fin(finite.max()) if finite.size else None,
        mean=fin(finite.mean()) if finite.size else None,
        values=None if values is None else [fin(v) for v in values], nominal=fin(nominal),
        torque_noise_rms=[float(v) for v in ev.torque_noise_rms],
        peak_torque=None if ev.peak_torque is None else [float(v) for v in ev.peak_torque],
        spectral_abscissa=float(ev.spectral_abscissa), violations=dict(ev.violations), feasible=bool(ev.feasible),
        diverged=int(ev.diverged))


def tuned_scenario(spec: TuneSpec, gains: dict, feasible: bool, objective: float | None):
    """The base scenario with the tuned gains, named and described for its file."""
    what = f"{spec.objective} {spec.metric} over the {spec.runs}-run set"
    value = objective_text(objective)
    note = "" if feasible else "INFEASIBLE (the best point found misses a constraint): "
    return spec.base.with_changes(dict(gains) | {
        "name": f"{spec.base.name}-tuned",
        "description": f"{note}gains tuned by dobkit tune '{spec.name}' (definition {spec.definition}): {what} "
                       f"{value}"})


def nominal_metric(scenario, metric: str, workers: int = 1, engine: str = "auto") -> float | None:
    """The metric of one scenario alone (batch RK4, the set's integration), mm."""
    result = simulate_batch(scenario, [{}], observer=True, metrics=[metric], workers=workers, engine=engine)
    value = float(result.metrics[metric][0])
    return value if math.isfinite(value) else None


def _finish(spec: TuneSpec, evaluator: Evaluator, search: _Search, best: Evaluation, out: Path, started: float,
            figures: bool, report, problems: list[str]) -> TuneResult:
    from .tune_report import write_figures

    base = search.base
    # the objective of the best point, feasible or not: the tuned file says what stdout and tune.json say
    scenario = tuned_scenario(spec, best.gains, best.feasible, best.objective if math.isfinite(best.objective) else None)
    engine, workers = evaluator.engine, evaluator.workers
    base_point = _point(base, nominal_metric(spec.base, spec.metric, workers, engine))
    tuned_point = _point(best, nominal_metric(scenario, spec.metric, workers, engine))
    counts = {"search": sum(e.phase == "search" for e in evaluator.history),
              "polish": sum(e.phase == "polish" for e in evaluator.history),
              "simulated": evaluator.simulated_now,
              "from_log": len({e.key for e in evaluator.history if e.from_log}),
              "linear_only": sum(not e.simulated for e in evaluator.history)}
    message = _message(spec, base_point, tuned_point)
    history = TuneHistory(phase=[e.phase for e in evaluator.history],
                          objective=[e.objective if e.simulated and math.isfinite(e.objective) else None
                                     for e in evaluator.history],
                          feasible=[e.feasible for e in evaluator.history],
                          simulated=[e.simulated for e in evaluator.history])
    file_name = f"{scenario.name}.toml"
    result = TuneResult(
        name=spec.name, source=spec.source, description=spec.description, definition=spec.definition,
        scenario=spec.base.name, objective=spec.objective, metric=spec.metric, runs=spec.runs,
        parameters=[p.name for p in spec.parameters], units=[p.unit for p in spec.parameters],
        bounds=[[p.low, p.high] for p in spec.parameters], limits=spec.limits.as_dict(), base=base_point,
        tuned=tuned_point, feasible=bool(best.feasible), message=message, history=history, evaluations=counts,
        seconds=0.0, scenario_file=file_name, log_problems=list(problems))
    report("tuning: writing results", 0.0)
    write_lines_atomically(out / file_name, [scenario.to_toml()])
    if figures:
        made = write_figures(result, out / "figures")
        result = _replace(result, figures=[TuneFigure(file=p, caption=c) for p, c in made])
    result = _replace(result, seconds=round(time.perf_counter() - started, 3))
    write_lines_atomically(out / RESULT_NAME, [result.to_json()])
    report("tuning: writing results", 1.0)
    return result


def _replace(result: TuneResult, **changes) -> TuneResult:
    return dataclasses.replace(result, **changes)


def _message(spec: TuneSpec, base: PointResult, tuned: PointResult) -> str:
    what = f"{spec.objective} {METRIC_WORDS[spec.metric]} over {spec.runs} runs"
    def fmt(point: PointResult) -> str:
        return objective_text(point.objective, point.diverged, spec.runs)
    if not tuned.feasible:
        missed = ", ".join(k for k, v in tuned.violations.items() if v > 0) or "a run diverged"
        return (f"No feasible gains found: the best point, named here as INFEASIBLE, misses {missed}; its {what} is "
                f"{fmt(tuned)} (base gains: {fmt(base)})")
    return f"Tuned gains: {what} {fmt(tuned)} (base gains: {fmt(base)})"
