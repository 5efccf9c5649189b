"""Running a tuning: differential evolution polished by Nelder-Mead, every evaluation logged, resumable.

::

    from analysis.tune.spec import load_tuning
    from analysis.tune.runner import run_tune
    result = run_tune(load_tuning("paper-tune"), "paper-tune-out")      # a TuneResult; files in the folder

The search
    1. The linear constraints (torque noise, stability margin, damping, the
       observer bandwidth ratio) are checked on a Latin hypercube sample of
       the bounds, then, if no sample meets them,
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
    5. The answer is the best evaluation of all (:mod:`analysis.tune.evaluate`
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
    tuning runs, ``evaluations.jsonl.lock`` keeps a second one out.  Rows are
    checksummed, and two rows of one candidate that differ are refused: the
    log is a job log of :mod:`analysis.jobs.files`, as a sweep's results file is.

Outputs (written when the search ends)
    ``tune.json`` (:class:`TuneResult`), the tuned scenario ``<scenario>-tuned.toml``
    (the base scenario with the tuned gains; ``dobkit simulate --scenario`` runs
    it, and evaluating it on the set gives the reported objective), and the
    figures (:mod:`analysis.tune.report`).  Every constraint is reported with
    its margin (:meth:`analysis.tune.evaluate.Evaluator.margins`), and with a
    damping constraint, what it costs: the tuned objective against the best
    evaluation of the same search that meets every other constraint
    (:func:`unconstrained_best`).  With ``constraint_costs`` the search is run
    again without each active constraint in turn, and each one's cost is
    reported (:mod:`analysis.tune.costs`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import shutil
import time
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution, minimize
from scipy.stats import qmc

from analysis.jobs.cluster import dask_session
from analysis.jobs.files import JobLog, LogKind, write_lines_atomically
from analysis.tune.costs import constraint_costs as measure_costs
from analysis.tune.costs import costed_constraints, without
from analysis.tune.evaluate import DAMPING_CONSTRAINTS, Evaluation, Evaluator, check_seconds, evaluation_estimate, gains_key
from analysis.tune.results import (
    RESULT_NAME,
    PointResult,
    TuneFigure,
    TuneHistory,
    TuneResult,
    excess_text,
    numbers_text,
    objective_text,
)
from analysis.tune.spec import HEADER_PARTS, METRIC_WORDS, TuneError, TuneSpec, damping_for_overshoot, load_tuning
from blocks.engines.budget import Budget
from blocks.figure2.batch import simulate_batch
from blocks.plumbing.outputs import interrupts_held
from blocks.plumbing.progress import ProgressCallback, StageProgress

__all__ = ["run_tune", "TuneResult", "PointResult", "TuneHistory", "TuneFigure", "read_log", "LOG_NAME",
           "RESULT_NAME", "FEASIBILITY_SAMPLES", "DE_TOL", "EVALUATION_LOG"]

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
#: The evaluation log as a job log (:mod:`analysis.jobs.files`): its words, its header and its row ids.
EVALUATION_LOG = LogKind(header_key="tune", id_key="key", error=TuneError, what="evaluation log", job="tuning",
                         elsewhere="another --out folder", parts=HEADER_PARTS, volatile=("seconds", "phase"))


def _row_problem(record: dict) -> str:
    missing = [k for k in _ROW_KEYS if k not in record]
    if missing:
        return f"missing {', '.join(missing)}"
    if record["key"] != gains_key(record["gains"]):
        return "its key does not match its gains"
    return ""


def read_log(path: str | Path) -> tuple[dict | None, dict, list[str]]:
    """The header, the rows by candidate key, and the unusable lines of an evaluation log.

    A last line cut off by a kill is not a row (that candidate is simulated again); checksums, repeats and
    bytes that are not UTF-8 as :class:`analysis.jobs.files.JobLog` reads them.

    Raises
    ------
    TuneError
        On two rows of one candidate with different values, or bytes that are not UTF-8.
    """
    log = JobLog(Path(path), EVALUATION_LOG)
    rows = {row["key"]: row for row in log.rows(_row_problem)}
    return log.header(), rows, list(log.problems)


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
    limits = spec.limits
    if all(v is None for v in (limits.torque_noise_rms, limits.stability_margin, limits.min_damping_ratio,
                                limits.max_overshoot, limits.min_observer_bandwidth_ratio, limits.sampled_margin)):
        return
    n = len(spec.parameters)

    def violations(gains) -> dict:
        return evaluator.linear_violations(*evaluator.linear(gains), *evaluator.design(gains))

    def violation(u) -> float:
        return float(sum(violations(spec.gains(u)).values()))

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
    zeta, ratio, _ = evaluator.design(gains)
    missed = violations(gains)
    misses = []
    if limits.torque_noise_rms is not None and np.any(noise > limits.torque_noise_rms):
        j = int(np.argmax(noise / limits.torque_noise_rms))
        paper = spec.base.robot.paper is not None   # the paper's message as it was; any other arm's units and names
        unit = "N m" if paper else f"({', '.join(spec.joints.force_units)})"
        joint = f"joint {j + 1}" if paper else f"joint {j + 1}, {spec.joints.names[j]},"
        misses.append(f"torque noise {numbers_text(noise)} against the budget "
                      f"{numbers_text(limits.torque_noise_rms, unit)} ({joint} "
                      f"{excess_text(noise[j], limits.torque_noise_rms[j])})")
    if limits.stability_margin is not None and abscissa > -limits.stability_margin:
        misses.append(f"slowest pole at {abscissa:.4g} 1/s, not <= -{limits.stability_margin:g} 1/s "
                      "(constraints.stability_margin)")
    if missed.get("min_damping_ratio", 0) > 0 or missed.get("max_overshoot", 0) > 0:
        what = (f">= {limits.min_damping_ratio:g} (constraints.min_damping_ratio)" if limits.min_damping_ratio
                is not None else f">= {damping_for_overshoot(limits.max_overshoot):.3g} (constraints.max_overshoot = "
                f"{limits.max_overshoot:g})")
        misses.append(f"damping ratios {np.round(zeta, 3).tolist()}, not all {what}")
    if missed.get("sampled_margin", 0) > 0:
        sampled = evaluator.sampled_loop(gains)
        misses.append(f"Ts lambda_max(Y M^-1) = {sampled['ts_lambda_max']:.4g} against the sampled loop's limit "
                      f"{sampled['ts_lambda_limit']:.4g}, more than {1 - limits.sampled_margin:g} of it "
                      f"(constraints.sampled_margin = {limits.sampled_margin:g})")
    if missed.get("min_observer_bandwidth_ratio", 0) > 0:
        misses.append(f"observer bandwidth ratio {ratio:.3g}, not >= {limits.min_observer_bandwidth_ratio:g} "
                      "(constraints.min_observer_bandwidth_ratio)")
    raise TuneError(f"{spec.source}: the constraints cannot be met within the [search] bounds: no gains found among "
                    f"{FEASIBILITY_SAMPLES + len(extra)} sampled and {found.nfev} searched meet the linear "
                    f"constraints ({', '.join(missed)}). The closest, {_describe(gains)}, has " + "; ".join(misses)
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
             engine: str = "auto", figures: bool = True, compare_unconstrained: bool = False,
             scheduler: str | None = None, scheduler_timeout: float = 10.0,
             constraint_costs: bool = False) -> TuneResult:
    """Tune the gains (see the module docstring) and write the results into ``out_dir``.

    Parameters
    ----------
    spec : TuneSpec or path or built-in name
    out_dir : path
        Folder of the evaluation log and the outputs; created when missing.  The same folder resumes.
    workers : int, optional
        Threads (compiled engine) or processes of each batch; default: all cores.
    progress : bool or callable
        True: a :class:`blocks.plumbing.progress.StageProgress` on standard error; a callable is called as
        ``progress(stage, fraction)``.
    restart : bool
        Move an evaluation log of another definition aside instead of refusing it.
    budget : Budget, optional
        Memory, steps and wall time (default: the tuning's).  When the wall time runs out the finished
        evaluations are kept and :class:`~blocks.engines.budget.BudgetError` is raised: run again to go on.
    engine : str
        :func:`blocks.figure2.batch.simulate_batch`'s engine.
    figures : bool
        Write the figures.
    compare_unconstrained : bool
        With a damping (or overshoot) constraint: after the search, run the same search without it (its
        evaluations go to the same log) and measure the constraint's cost against that search's answer,
        rather than against the best of the constrained search's own evaluations.  About doubles the time.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``, or a ``LocalCluster``'s
        ``scheduler_address``), or ``local[:N]`` to start a cluster of N worker processes (default: one per core)
        on 127.0.0.1 for this tuning and close it at the end: each generation's candidates are simulated in
        batches spread over its workers (:mod:`analysis.jobs.cluster`); the search, the log and the outputs
        stay in this process.  A worker lost mid-batch has its batch run again elsewhere by Dask; rows are
        written only for finished batches, so the log holds every evaluation once, and the result is the one of
        a local tuning.  Needs ``dask[distributed]``; the connection is made before the output folder is touched.
    scheduler_timeout : float
        Seconds to wait for the Dask scheduler to answer.
    constraint_costs : bool
        After the search, run the same search once without each active constraint of
        :data:`analysis.tune.costs.COSTED` (their evaluations go to the same log) and report what each costs
        (:attr:`TuneResult.constraint_costs`); the search without the damping constraint also serves as
        ``compare_unconstrained``'s.  Up to five times the time, less where the log holds the candidates.

    Returns
    -------
    TuneResult
        Also written as ``tune.json``.

    Raises
    ------
    TuneError
        On a log of another definition, or constraints that no gains within the bounds meet (before anything runs).
    blocks.engines.budget.BudgetError
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
            if scheduler is not None:         # connect before writing anything: a failed connection leaves nothing
                evaluator.client = stack.enter_context(dask_session(scheduler, scheduler_timeout, TuneError))
            out.mkdir(parents=True, exist_ok=True)
            log = JobLog(out / LOG_NAME, EVALUATION_LOG)
            stack.enter_context(log.lock())
            log.prepare(spec.header()["tune"], spec.name, restart)
            _, rows, problems = read_log(log.path)
            writer = log.writer(spec.header()["tune"])
            stack.callback(writer.close)
            search = _Search(spec, evaluator, report, budget, started)
            evaluator.log_rows, evaluator.record = rows, writer.write
            evaluator.after_batch = search.after_batch
            result = search.run()
            dropped = costed_constraints(spec.limits) if constraint_costs else \
                [k for k in DAMPING_CONSTRAINTS if compare_unconstrained and getattr(spec.limits, k) is not None]
            searched = {key: _search_without(spec, key, evaluator, log.path, writer, report, budget, started)
                        for key in dropped}
            free = next(((ev, count) for key, (ev, count, _) in searched.items() if key in DAMPING_CONSTRAINTS),
                        None)
            result = _finish(spec, evaluator, search, result, out, started, figures, report, problems, free,
                             searched if constraint_costs else None)
    except BaseException:
        if display is not None:         # an interrupted or failed stage says "stopped after", not "done"
            display.close(failed=True)
            display = None
        raise
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
def _point(ev: Evaluation, nominal: float | None, evaluator: Evaluator) -> PointResult:
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
        diverged=int(ev.diverged), damping_ratio=[float(v) for v in ev.damping_ratio],
        bandwidth_ratio=fin(ev.bandwidth_ratio), margins=evaluator.margins(ev),
        sampled_loop=evaluator.sampled_loop(ev.gains))


def unconstrained_best(evaluator: Evaluator) -> Evaluation | None:
    """The best simulated evaluation that meets every constraint but the damping (or overshoot) one, or None."""
    limits = evaluator.spec.limits
    if limits.min_damping_ratio is None and limits.max_overshoot is None:
        return None
    pool = [e for e in evaluator.history if e.simulated and math.isfinite(e.objective)
            and all(v == 0 for k, v in e.violations.items() if k not in DAMPING_CONSTRAINTS)]
    return min(pool, key=lambda e: e.objective, default=None)


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
    result = simulate_batch(scenario, [{}], observer=True, metrics=[metric], workers=workers, engine=engine,
                            method="RK4")
    value = float(result.metrics[metric][0])
    return value if math.isfinite(value) else None


#: How the progress display names a search without one constraint.
_WITHOUT_WORDS = {"min_damping_ratio": "without damping", "max_overshoot": "without damping",
                  "min_observer_bandwidth_ratio": "without the bandwidth ratio",
                  "sampled_margin": "without the sampled margin", "torque_noise_rms": "without the noise budget"}


def _search_without(spec: TuneSpec, key: str, evaluator: Evaluator, log: Path, writer, report, budget: Budget,
                    started: float) -> tuple[Evaluation, int, list[Evaluation]]:
    """The same search without the constraint ``key`` (:func:`analysis.tune.costs.without`): its answer (with
    the violations of every constraint, its feasibility without that one), the candidates it simulated and its
    evaluations.  An evaluation's row does not depend on the constraints, so the searches share the log's rows."""
    free_spec = dataclasses.replace(spec, limits=without(spec.limits, key))
    free = Evaluator(free_spec, workers=evaluator.workers, engine=evaluator.engine, log_rows=read_log(log)[1],
                     record=writer.write, client=evaluator.client)
    words = _WITHOUT_WORDS[key]
    search = _Search(free_spec, free, lambda stage, f: report(stage.replace("tuning:", f"{words}:"), f),
                     budget, started)
    free.after_batch = search.after_batch
    best = search.run()
    best.violations = evaluator.judged(best).violations
    return best, free.simulated_now, free.history


def _finish(spec: TuneSpec, evaluator: Evaluator, search: _Search, best: Evaluation, out: Path, started: float,
            figures: bool, report, problems: list[str], searched: tuple[Evaluation, int] | None = None,
            without_each: dict | None = None) -> TuneResult:
    from analysis.tune.report import write_figures

    base = search.base
    # the objective of the best point, feasible or not: the tuned file says what stdout and tune.json say
    scenario = tuned_scenario(spec, best.gains, best.feasible, best.objective if math.isfinite(best.objective) else None)
    engine, workers = evaluator.engine, evaluator.workers
    base_point = _point(base, nominal_metric(spec.base, spec.metric, workers, engine), evaluator)
    tuned_point = _point(best, nominal_metric(scenario, spec.metric, workers, engine), evaluator)
    # the unconstrained search's answer counts when it meets every other constraint (feasible without damping)
    free = unconstrained_best(evaluator) if searched is None else searched[0] if searched[0].feasible else None
    free_point = None if free is None else _point(free, None, evaluator)
    if free_point is not None:                # feasible as the tuning counts it: it misses the damping constraint
        free_point = _replace(free_point, feasible=not any(v > 0 for v in free_point.violations.values()))
    cost = None if free is None or not best.feasible else max(0.0, float(best.objective - free.objective))
    counts = {"search": sum(e.phase == "search" for e in evaluator.history),
              "polish": sum(e.phase == "polish" for e in evaluator.history),
              "simulated": evaluator.simulated_now,
              "from_log": len({e.key for e in evaluator.history if e.from_log}),
              "linear_only": sum(not e.simulated for e in evaluator.history),
              "unconstrained_simulated": 0 if searched is None else searched[1]}
    costs = None
    if without_each is not None:
        costs = measure_costs(evaluator, [evaluator.history] + [h for _, _, h in without_each.values()],
                              {key: count for key, (_, count, _) in without_each.items()}, tuned_point.margins)
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
        seconds=0.0, scenario_file=file_name, log_problems=list(problems), unconstrained=free_point,
        damping_cost=cost, unconstrained_from=None if free is None else "evaluations" if searched is None
        else "search", joints=list(spec.joints.names), force_units=list(spec.joints.force_units),
        constraint_costs=costs)
    report("tuning: writing results", 0.0)
    # staged: an interrupt or failure leaves the previous results whole (or none), never a tuned file and some
    # figures without tune.json, or new figures beside an old tune.json
    for stale in out.glob(f"{_STAGE_PREFIX}*"):          # a killed run's (this tuning holds the log's lock)
        shutil.rmtree(stale, ignore_errors=True)
    stage = out / f"{_STAGE_PREFIX}{os.getpid()}"
    try:
        stage.mkdir()
        write_lines_atomically(stage / file_name, [scenario.to_toml()])
        if figures:
            designs = {label: evaluator.error_dynamics(point.gains) for label, point in
                       (("base gains", base_point), ("tuned gains", tuned_point))}
            made = write_figures(result, stage / "figures", designs=designs, joints=spec.base.robot.joints)
            result = _replace(result, figures=[TuneFigure(file=p, caption=c) for p, c in made])
        result = _replace(result, seconds=round(time.perf_counter() - started, 3))
        write_lines_atomically(stage / RESULT_NAME, [result.to_json()])
        _results_into_place(stage, out, [file_name] + (["figures"] if figures else []) + [RESULT_NAME])
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    report("tuning: writing results", 1.0)
    return result


#: The hidden folder a tuning's results are written into before they are moved into the output folder.
_STAGE_PREFIX = ".results-partial-"


def _results_into_place(stage: Path, out: Path, names: list[str]) -> None:
    """Move the staged results into ``out``, ``tune.json`` last, with Ctrl-C and SIGTERM held until all are in.

    The old ``tune.json`` goes first, so that no moment shows it beside new files; the old figures folder goes
    into the stage (removed with it)."""
    with interrupts_held():
        (out / RESULT_NAME).unlink(missing_ok=True)
        for name in names:
            target = out / name
            if target.is_dir() and not target.is_symlink():
                target.rename(stage / f"old-{name}")
            os.replace(stage / name, target)


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
