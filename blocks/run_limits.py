"""How much work one simulation may take: estimated before it starts, enforced while it runs.

A single run is held to the same :class:`~blocks.budget.Budget` as a batch
or a sweep (integrator steps per run, memory, wall time; defaults, the
``DOBKIT_MAX_STEPS`` / ``DOBKIT_MAX_MEMORY`` / ``DOBKIT_MAX_SECONDS``
variables, and the commands' flags).

An explicit solver (RK45, RK23, DOP853) takes steps no longer than about
``STABILITY_SPAN / lambda`` for the loop's fastest rate ``lambda`` (1/s), so a
very stiff loop -- a huge gain, a tiny friction velocity -- asks for millions of
steps; interpolated measurement noise has a kink at every sample, which the
solver must step to.  :func:`estimate_run` counts the steps from those rates
(:func:`blocks.batch.schedule.rates_by_source`) and the memory from the output
grid and the noise table, naming the scenario key behind each;
:func:`check_run` refuses a run over budget before it starts.  During the run
the step budget (as right-hand-side evaluations) and the wall-time budget
stop the solver (:func:`blocks.integrate.integrate_on_grid`).
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

from .budget import Budget, Estimate
from .scenario import Scenario

__all__ = ["estimate_run", "check_run", "solver_limits", "EXPLICIT_METHODS", "STABILITY_SPAN"]

#: Methods whose step is limited by the fastest rate (the others are implicit).
EXPLICIT_METHODS = ("RK45", "RK23", "DOP853")
#: ``h lambda`` an explicit Runge-Kutta step stays stable below (about 3.3 for RK45 on the real axis).
STABILITY_SPAN = 3.0
#: Right-hand-side evaluations per step (RK45 uses six; DOP853 twelve, RK23 three; implicit methods vary).
EVALUATIONS_PER_STEP = {"RK45": 6, "RK23": 3, "DOP853": 12}
# Bytes per output grid point: states and outputs of the response, and the engine's copies of them.
_GRID_POINT_BYTES = 4 * 8 * 80


def estimate_run(scenario: Scenario, observer: bool = True) -> Estimate:
    """The steps and memory one run of ``scenario`` needs, with the keys that drive them."""
    from .batch.schedule import rates_by_source
    from .batch.variants import Variants
    s = scenario
    t_final = s.simulation.t_final
    candidates = []
    if s.simulation.method in EXPLICIT_METHODS:
        with np.errstate(over="ignore", invalid="ignore"):     # gains near 1e308: the rate is inf, said below
            by_source = rates_by_source(Variants(s, [{}]), observer)
        for key, rates in by_source.items():
            rate = float(rates.max())
            steps = t_final * rate / STABILITY_SPAN
            if not math.isfinite(steps):
                candidates.append((math.inf, key, f"its fastest rate is beyond what a float holds (over "
                                                  f"{sys.float_info.max:.3g} 1/s), so no explicit "
                                                  f"{s.simulation.method} step is small enough"))
                continue
            candidates.append((steps, key, f"its fastest rate, about {rate:.3g} 1/s, limits an explicit "
                                           f"{s.simulation.method} step to {STABILITY_SPAN / rate:.3g} s, "
                                           f"{t_final:g} s / {STABILITY_SPAN / rate:.3g} s"))
    if s.noise is not None:
        candidates.append((t_final / s.noise.sample_period, "noise.sample_period",
                           f"one step at least per noise sample, every {s.noise.sample_period:g} s"))
    steps, key, reason = max(candidates) if candidates else (0.0, "", "")
    grid = int(round(t_final / s.simulation.output_step)) + 1
    parts = {"output grid": grid * _GRID_POINT_BYTES}
    keys = {"steps": key, "output grid": "simulation.output_step"}
    reasons = {"steps": reason, "output grid": f"{grid:,} points"}
    if s.noise is not None:
        parts["noise table"] = s.noise.table.nbytes
        keys["noise table"] = "noise.sample_period"
        reasons["noise table"] = f"{s.noise.table.shape[1]:,} samples"
    # the step count as estimated, however large (the message's numbers must agree); the largest float when it is not
    # a number at all
    steps = int(min(steps, sys.float_info.max))
    return Estimate(memory=sum(parts.values()), steps=steps, parts=parts, keys=keys, reasons=reasons)


def check_run(scenario: Scenario, observer: bool = True, budget: Budget | None = None) -> Budget:
    """Refuse a run whose estimate exceeds the budget; return the budget to enforce during the run.

    Raises
    ------
    blocks.budget.BudgetError
        With the estimate, the key that causes it and how to raise the budget.
    """
    budget = Budget.from_env() if budget is None else budget
    budget.check(estimate_run(scenario, observer), f"scenario '{scenario.name}' ({scenario.simulation.method})")
    return budget


def solver_limits(budget: Budget, method: str) -> dict:
    """``max_evaluations`` and ``deadline`` for :func:`blocks.integrate.integrate_on_grid` from a budget."""
    limits = {"max_evaluations": budget.steps * EVALUATIONS_PER_STEP.get(method, 6)}
    if budget.seconds is not None:
        limits["deadline"] = time.monotonic() + budget.seconds
    return limits
