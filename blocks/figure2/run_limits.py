"""How much work one simulation may take: estimated before it starts, enforced while it runs.

A single run is held to the same :class:`~blocks.engines.budget.Budget` as a batch
or a sweep (integrator steps per run, memory, wall time; defaults, the
``DOBKIT_MAX_STEPS`` / ``DOBKIT_MAX_MEMORY`` / ``DOBKIT_MAX_SECONDS``
variables, and the commands' flags).

An explicit solver (RK45, RK23, DOP853) takes steps no longer than about
``STABILITY_SPAN / lambda`` for the loop's fastest rate ``lambda`` (1/s), so a
very stiff loop -- a huge gain, a tiny friction velocity -- asks for millions of
steps; interpolated measurement noise has a kink at every sample, which the
solver must step to; ``simulation.max_step`` caps every step; a sampled
controller restarts the solver at every tick.  :func:`estimate_run` counts
the steps from those (:func:`blocks.figure2.batch.schedule.rates_by_source`) and the
memory from the output grid, the noise table and the actuator's delay buffer,
naming the scenario key behind each; :func:`check_run` refuses a run over
budget before it starts (before the loop is even built).  During the run the
:class:`~blocks.engines.monitor.Monitor` holds every engine to the step budget (as
right-hand-side evaluations) and the wall-time budget.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections import OrderedDict

import numpy as np

from blocks.engines.budget import ENVIRONMENT, Budget, BudgetError, Estimate
from blocks.scenarios.scenario import Scenario

__all__ = ["estimate_run", "check_run", "path_estimate", "prepare_reference", "arm_rates",
           "forget_inertias", "EXPLICIT_METHODS", "STABILITY_SPAN"]

#: Methods whose step is limited by the fastest rate (the others are implicit).
EXPLICIT_METHODS = ("RK45", "RK23", "DOP853")
#: ``h lambda`` an explicit Runge-Kutta step stays stable below (about 3.3 for RK45 on the real axis).
STABILITY_SPAN = 3.0
# Bytes per output grid point: states and outputs of the response, and the engine's copies of them.
_GRID_POINT_BYTES = 4 * 8 * 80
#: Bytes per number of a sampled loop's state or output at an output grid point: the response's states and
#: outputs, the engine's copies and the per-tick temporaries.
SAMPLED_VALUE_BYTES = 4 * 8
#: Bytes per slot of the actuator's delay buffer beside its values on the grid: its state label and the
#: interconnection's index entries (measured: about 150).
BUFFER_SLOT_BYTES = 256


def estimate_run(scenario: Scenario, observer: bool = True) -> Estimate:
    """The steps and memory one run of ``scenario`` needs, with the keys that drive them."""
    from blocks.figure2.batch.schedule import rates_by_source
    from blocks.figure2.batch.variants import Variants
    s = scenario
    t_final = s.simulation.t_final
    candidates = []
    if s.controller is not None:
        rate = s.controller.sample_rate
        candidates.append((t_final * rate, "controller.sample_rate",
                           f"one integrator step at least per controller tick: {t_final:g} s at {rate:g} Hz"))
    elif s.simulation.method in EXPLICIT_METHODS:
        with np.errstate(over="ignore", invalid="ignore"):     # gains near 1e308: the rate is inf, said below
            by_source = rates_by_source(Variants(s, [{}]), observer) if s.robot.stacks_constants else \
                arm_rates(s, observer)
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
    if math.isfinite(s.simulation.max_step):
        candidates.append((t_final / s.simulation.max_step, "simulation.max_step",
                           f"steps no longer than {s.simulation.max_step:g} s over {t_final:g} s"))
    if s.noise is not None:
        candidates.append((t_final / s.noise.sample_period, "noise.sample_period",
                           f"one step at least per noise sample, every {s.noise.sample_period:g} s"))
    steps, key, reason = max(candidates) if candidates else (0.0, "", "")
    grid = int(round(t_final / s.simulation.output_step)) + 1
    parts = {"output grid": grid * _GRID_POINT_BYTES}
    keys = {"steps": key, "output grid": "simulation.output_step"}
    reasons = {"steps": reason, "output grid": f"{grid:,} points"}
    if s.controller is not None and s.controller.delay:
        slots = s.controller.delay * s.robot.joints.count
        parts["the actuator's delay buffer"] = slots * (BUFFER_SLOT_BYTES + SAMPLED_VALUE_BYTES * grid)
        keys["the actuator's delay buffer"] = "controller.delay"
        reasons["the actuator's delay buffer"] = (f"{s.controller.delay:,} samples of {s.robot.joints.count} torques, "
                                                  f"kept at {grid:,} output points")
    if s.noise is not None:
        parts["noise table"] = s.noise.table.nbytes
        keys["noise table"] = "noise.sample_period"
        reasons["noise table"] = f"{s.noise.table.shape[1]:,} samples"
    # the step count as estimated, however large (the message's numbers must agree); the largest float when it is not
    # a number at all
    steps = int(min(steps, sys.float_info.max))
    seconds = 0.0
    path = path_estimate(s)
    if path is not None:            # a task-space path still to solve by IK: its table, and the time it takes
        parts["the path's IK samples"] = path.memory
        keys["the path's IK samples"] = keys["seconds"] = path.seconds_key
        reasons["the path's IK samples"] = reasons["seconds"] = path.seconds_reason
        seconds = path.seconds
    return Estimate(memory=sum(parts.values()), steps=steps, parts=parts, keys=keys, reasons=reasons,
                    seconds=seconds)


def path_estimate(scenario: Scenario) -> Estimate | None:
    """What solving the scenario's task-space path by IK still takes (:meth:`blocks.scenarios.tool_path.ToolPath.estimate`:
    the per-sample cost measured when the path was made, times its samples), or None when there is nothing to
    solve."""
    trajectory = scenario.trajectory
    if getattr(trajectory, "solved", True):
        return None
    return trajectory.estimate()


def prepare_reference(scenario: Scenario, budget: Budget, progress=None) -> Budget:
    """Solve the scenario's task-space path (if still to do) before its run is built: refused over ``budget``'s
    wall time with the estimate and the key, with progress, stopped when the budget runs out
    (:meth:`blocks.scenarios.tool_path.ToolPath.solve`).  Returns the budget left for the run (its wall time less the
    solve's)."""
    if path_estimate(scenario) is None:
        return budget
    budget.check(estimate_run(scenario), f"scenario '{scenario.name}'")
    started = time.monotonic()
    scenario.trajectory.solve(budget=budget, progress=progress)
    if budget.seconds is None:
        return budget
    left = budget.seconds - (time.monotonic() - started)
    if not left > 0:
        raise BudgetError(f"scenario '{scenario.name}': the wall-time budget of {budget.seconds:g} s ran out solving "
                          f"its path; raise it with --max-seconds or {ENVIRONMENT['seconds']}", None,
                          "trajectory.sample_period", "seconds")
    return dataclasses.replace(budget, seconds=left)


def arm_rates(s: Scenario, observer: bool = True, samples: int = 9) -> dict[str, np.ndarray]:
    """Upper estimates (1/s) of a run's fastest rates by the key that sets them, for any arm: the rules of
    :func:`blocks.figure2.batch.schedule.rates_by_source` (PD poles times the model mismatch ``lambda_max(M^-1 M^)``, the
    observer's ``Y M^-1``, the friction's ``M^-1 (F_c / v_s + F_v)``) with the inertia taken along the reference
    (``samples`` times over the run) instead of the RRPR's ``cos(theta2) = -1, 0, 1``.  Each value has shape (1,).
    The inertias along the reference are kept for the latest 16 arms and paths (:func:`forget_inertias`)."""
    M_inv, M_hat_inv, mismatch = _inverse_inertias_along(s.robot, s.nominal, s.trajectory, s.simulation.t_final,
                                                         samples)
    kp, kd = np.diag(s.kp), np.diag(s.kd)
    disc = kd ** 2 - 4 * kp
    pd = np.where(disc >= 0, 0.5 * (kd + np.sqrt(np.abs(disc))), np.sqrt(kp)).max()
    rates = {"gains.kp": np.array([pd * max(mismatch, 1.0)])}
    if observer:
        key = "gains.observer_bandwidth" if "observer_bandwidth" in s.data["gains"] else "gains.observer"
        rates[key] = np.array([max(np.abs(np.linalg.eigvals(s.observer_gain @ inv)).max() for inv in (M_inv, M_hat_inv))])
    if "friction" in s.disturbance.kinds:
        dist = s.disturbance
        damping = np.asarray(dist.coulomb) / dist.friction_velocity + np.asarray(dist.viscous)
        rates["disturbance.friction_velocity"] = np.array([np.abs(np.linalg.eigvals(M_inv * damping)).max()])
    return rates


_inverses: OrderedDict = OrderedDict()
_inverses_lock = threading.Lock()
# Arms, paths and windows whose inverse inertias are kept: a sweep over gains, noise or disturbance sizes asks for
# the same ones run after run (arms and trajectories are immutable and hashable)
_KEPT_INVERSES = 16


def _inverse_inertias_along(robot, nominal, trajectory, t_final: float, samples: int):
    """``M^-1``, ``M^^-1`` (read-only, (m, n, n)) at ``samples`` reference points over ``[0, t_final]`` and the
    largest ``|lambda(M^-1 M^)|``, kept for the latest arms and paths."""
    key = (robot, nominal, trajectory, float(t_final), int(samples))
    try:
        hash(key)
    except TypeError:               # a user's own arm or trajectory that cannot be a key: computed every time
        key = None
    with _inverses_lock:
        found = _inverses.get(key) if key is not None else None
        if found is not None:
            _inverses.move_to_end(key)
            return found
    times = np.linspace(0.0, t_final, samples)
    # a task-space path not yet solved: the IK of its points (an estimate), not the solve the estimate is for
    near = getattr(trajectory, "positions_near", None)
    q = np.asarray(trajectory.evaluate(times)[0] if near is None else near(times), dtype=float)
    M, M_hat = _inertia_along(robot, q), _inertia_along(nominal, q)                      # (m, n, n)
    M_inv, M_hat_inv = np.linalg.inv(M), np.linalg.inv(M_hat)
    mismatch = float(np.abs(np.linalg.eigvals(M_inv @ M_hat)).max())
    M_inv.setflags(write=False)
    M_hat_inv.setflags(write=False)
    found = (M_inv, M_hat_inv, mismatch)
    if key is None:
        return found
    with _inverses_lock:
        _inverses[key] = found
        while len(_inverses) > _KEPT_INVERSES:
            _inverses.popitem(last=False)
    return found


def forget_inertias() -> None:
    """Forget the inverse inertias kept by :func:`arm_rates` (the next run computes them again)."""
    with _inverses_lock:
        _inverses.clear()


def _inertia_along(arm, q: np.ndarray) -> np.ndarray:
    """``M`` of ``arm`` at the states ``q`` (m, n) in one call, shape (m, n, n): compiled for a chain arm where
    that pays (:func:`blocks.figure2.physical_bounds.evaluation_kernels`), else ``arm.inertia``."""
    from blocks.figure2.physical_bounds import evaluation_kernels
    kernels = evaluation_kernels(arm)
    if kernels is arm.kernels:
        return arm.inertia(q)
    return np.asarray(kernels.inertia_matrix(arm.kernel_params(), q.T))


def check_run(scenario: Scenario, observer: bool = True, budget: Budget | None = None,
              estimate: Estimate | None = None, what: str | None = None) -> Budget:
    """Refuse a run whose estimate exceeds the budget; return the budget to enforce during the run.

    ``estimate`` is :func:`estimate_run`'s (computed here when not given); ``what`` names the run in the
    message (default ``scenario 'name' (method)``).

    Raises
    ------
    blocks.engines.budget.BudgetError
        With the estimate, the key that causes it and how to raise the budget.
    """
    budget = Budget.from_env() if budget is None else budget
    estimate = estimate_run(scenario, observer) if estimate is None else estimate
    budget.check(estimate, what or f"scenario '{scenario.name}' ({scenario.simulation.method})")
    return budget
