"""How the co-simulation error falls with the communication step ``h``.

:func:`cosim_convergence` co-simulates a scenario against a plant FMU at
several steps ``h`` (:func:`fmu.cosimulate`) and compares each run
with the monolithic all-Python loop (:func:`blocks.simulate`,
integrated with DOP853 at tight tolerances, so that its own error is far
below the co-simulation's).  Both use the scenario's true plant: the FMU is
given the scenario's parameters (``parameters="scenario"``).

The error per joint is ``max_t |q_cosim(t) - q_mono(t)|`` over a common
output grid (the largest ``h``, which every other ``h`` must divide); the
order is the least-squares slope of ``log(error)`` against ``log(h)``,
common to the four joints (each joint keeps its own intercept, so their
different units do not matter), and per joint.

:func:`analysis.simulation.figures.convergence_figure` plots the result.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from blocks.engines.budget import Budget
from blocks.engines.monitor import Monitor
from blocks.scenarios.scenario import Scenario, load_scenario

from .archive import ExtractionLimits, open_extracted
from .master import CoSimulationError, validated_time

__all__ = ["cosim_convergence", "fit_order", "DEFAULT_STEPS", "REFERENCE"]

DEFAULT_STEPS = (0.004, 0.002, 0.001, 0.0005)
# the monolithic reference: tight enough that its error is negligible next to h = 0.5 ms coupling errors
REFERENCE = {"method": "DOP853", "rtol": 1e-10, "atol": 1e-12}


def fit_order(steps, errors) -> tuple[float, list[float]]:
    """Order of convergence from errors at several steps.

    Parameters
    ----------
    steps : sequence of float
        Steps ``h`` (s), at least two different ones.
    errors : array_like, shape (len(steps), n_series)
        Errors (any unit per column) at each step.

    Returns
    -------
    (float, list of float)
        The slope of ``log(error)`` over ``log(h)`` common to all series (one
        intercept each), and the slope of each series alone.  NaN where a
        series has fewer than two positive errors.
    """
    h = np.log(np.asarray(steps, dtype=float))
    e = np.asarray(errors, dtype=float).reshape(len(h), -1)
    rows, rhs, per = [], [], []
    n = e.shape[1]
    for j in range(n):
        ok = e[:, j] > 0
        if ok.sum() < 2:
            per.append(float("nan"))
            continue
        per.append(float(np.polyfit(h[ok], np.log(e[ok, j]), 1)[0]))
        for i in np.flatnonzero(ok):
            row = np.zeros(n + 1)
            row[0], row[1 + j] = h[i], 1.0
            rows.append(row)
            rhs.append(np.log(e[i, j]))
    if not rows:
        return float("nan"), per
    coef, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return float(coef[0]), per


def _common_grid(steps, t_final: float) -> float:
    coarse = max(steps)
    for h in steps:
        k = coarse / h
        if abs(k - round(k)) > 1e-9 * k:
            raise CoSimulationError(f"every step must divide the largest one ({coarse:g} s), so that all runs share "
                                    f"its output grid; h = {h:g} s does not")
    n = t_final / coarse
    if n < 1 or abs(n - round(n)) > 1e-9 * n:
        raise CoSimulationError(f"t_final = {t_final:g} s is not a whole number of the largest step {coarse:g} s")
    return coarse


def cosim_convergence(fmu_path, scenario: Scenario | str = "paper", steps=DEFAULT_STEPS,
                      t_final: float | None = None, observer: bool = True, side_substeps: int = 1,
                      coupling: str | None = None, budget: Budget | None = None,
                      limits: ExtractionLimits | None = None, extract_to=None,
                      progress: Callable[[str, float], None] | None = None) -> dict:
    """Co-simulation error against the monolithic loop at several communication steps.

    Parameters
    ----------
    fmu_path : str, pathlib.Path or ExtractedFMU
        Plant Co-Simulation FMU (e.g. from :func:`~fmu.export_plant`).
    scenario : Scenario or str
        Scenario or its name/path (default ``paper``).
    steps : sequence of float
        Communication steps ``h`` (s), at least two; each must divide the largest.
    t_final : float, optional
        Simulated time (s); default the scenario's.  A whole number of the
        largest step.  It replaces the scenario's ``simulation.t_final`` for
        both runs: a shorter one is the start of the same path (the path
        keeps its own ``trajectory.duration``).
    observer : bool
        With or without the disturbance observer.
    side_substeps : int
        RK4 steps of the Python side per communication step.
    coupling : {"zoh", "linear"}, optional
        Coupling of every run (:mod:`fmu.coupling`); default the best the FMU supports.
    budget : Budget, optional
        Limits on the steps of each run and the wall time of the whole study.
    limits, extract_to :
        Archive limits and extraction parent (the FMU is extracted once for all runs).
    progress : callable, optional
        Called as ``progress(stage, fraction)``.

    Returns
    -------
    dict
        JSON-ready: ``steps`` (s, ascending), ``errors`` (joint name -> list,
        one per step, in ``units``), ``order`` (common fitted slope),
        ``order_per_joint``, ``output_step`` (s, the common grid), ``t_final``
        (s), ``reference`` (solver of the monolithic run), ``definition``,
        ``scenario``, ``fmu``, ``fmi_version``, ``observer``, ``side_substeps``,
        ``coupling``.

    Raises
    ------
    CoSimulationError
        If fewer than two steps are given or the steps do not share a grid.
    """
    from blocks.figure2.loop import simulate

    from .cosim import cosimulate

    steps = sorted({float(h) for h in steps})
    if len(steps) < 2 or not all(np.isfinite(h) and h > 0 for h in steps):
        raise CoSimulationError(f"need at least two different finite steps > 0 s, got {steps}")
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    t_end = s.simulation.t_final if t_final is None else validated_time(t_final, "t_final")
    grid = _common_grid(steps, t_end)
    budget = Budget.from_env() if budget is None else budget
    budget.check_steps(t_end / min(steps) * side_substeps, "convergence study",
                       f"t_final = {t_end:g} s / smallest step h = {min(steps):g} s")
    deadline = Monitor.for_job("convergence study", budget)
    s = s.replace(simulation={"t_final": t_end, "output_step": grid})
    report = progress or (lambda stage, fraction: None)

    report("monolithic reference", 0.0)
    ref = simulate(s.replace(simulation=dict(REFERENCE)), observer=observer,
                   progress=lambda f: report("monolithic reference", f))
    labels = list(ref.output_labels)
    names = s.robot.joints.signal_names("q")
    rows = [labels.index(name) for name in names]
    q_ref = np.asarray(ref.outputs)[rows]

    errors = np.empty((len(steps), len(names)))
    extracted, owned = open_extracted(fmu_path, limits=limits, parent=extract_to)
    try:
        for k, h in enumerate(steps):
            stage = f"co-simulation h = {h:g} s"
            deadline.check_time(where=f"before the run at h = {h:g} s")
            resp = cosimulate(extracted, s, step=h, observer=observer, side_substeps=side_substeps,
                              parameters="scenario", coupling=coupling, error_estimate=False, budget=budget,
                              progress=lambda f, st=stage: report(st, f))
            if resp.time.shape != ref.time.shape or np.max(np.abs(resp.time - ref.time)) > 1e-9:
                raise CoSimulationError(f"h = {h:g} s: the co-simulation grid differs from the reference grid")
            got = np.asarray(resp.outputs)[[list(resp.output_labels).index(name) for name in names]]
            errors[k] = np.max(np.abs(got - q_ref), axis=1)
            info = resp.cosim
    finally:
        if owned:
            extracted.cleanup()
    order, per_joint = fit_order(steps, errors)
    return {
        "scenario": s.name,
        "fmu": info["fmu"],
        "fmi_version": info["fmi_version"],
        "observer": observer,
        "side_substeps": side_substeps,
        "coupling": info["coupling"],
        "t_final": t_end,
        "output_step": grid,
        "steps": steps,
        "errors": {n: errors[:, i].tolist() for i, n in enumerate(names)},
        "units": dict(zip(names, s.robot.joints.position_units)),
        "order": order,
        "order_per_joint": dict(zip(names, per_joint)),
        "reference": dict(REFERENCE, engine="blocks.simulate (monolithic Python loop)"),
        "definition": ("error = max over the output grid of |q_cosim - q_monolithic| per joint; order = "
                       "least-squares slope of log(error) against log(h), common to all joints (one intercept "
                       "per joint); the zero-order hold is first order (order ~ 1), the linear coupling second "
                       "order (order ~ 2)"),
    }
