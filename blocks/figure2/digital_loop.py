"""The Figure-2 loop with the digital controller of :mod:`blocks.diagram.digital`: building it and running it.

The continuous plant and trajectory (and the sensor, with measurement
noise) run in continuous time; the encoder, controller, actuator and
observer are sampled at ``controller.sample_rate``.  See
:mod:`blocks.engines.hybrid` for how such a diagram is simulated.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import control as ct
import numpy as np

from blocks.engines.budget import Budget
from blocks.engines.hybrid import HybridSystem
from blocks.engines.monitor import Monitor, SimulationError
from blocks.engines.sampled_cost import check_sampled_time
from blocks.figure2.derived import loop_response
from blocks.figure2.physical_bounds import cached_state_bounds
from blocks.figure2.run_limits import check_run
from blocks.figure2.sampled_blocks import SAMPLED_SIGNALS, sampled_initial_state, sampled_loop

__all__ = ["sampled_loop", "sampled_initial_state", "simulate_sampled", "check_observer_rate",
           "SAMPLED_SIGNALS"]

def check_observer_rate(scenario, samples: int = 201) -> None:
    """Refuse, before a run, an observer gain that the sampled loop cannot keep stable.

    The loop is linearized at the configurations of the reference path on
    the nominal model and its one-sample map -- the plant under the held
    torque, the controller, the observer's update (``euler`` or ``zoh``), the
    velocity estimate and the delay -- must have spectral radius below 1
    (:func:`blocks.figure2.digital_stability.scenario_stability`).  Only forward
    Euler with measured velocity has the closed form ``Ts lambda_max(Y M^-1)
    < 2``; the others are computed (``docs/model.md``, "Digital observer").

    Raises
    ------
    blocks.scenarios.scenario.ScenarioError
        Naming ``gains.observer`` and ``controller.sample_rate`` (and the
        discretization, velocity and delay keys), with the computed limit on
        ``Ts lambda_max(Y M^-1)``, the largest stable scale of the gain and
        the lowest stable rate; naming ``gains.kp`` and ``gains.kd`` when no
        observer gain is stable at this rate.
    """
    from blocks.figure2.digital_stability import scenario_stability
    from blocks.scenarios.scenario import ScenarioError
    s, settings = scenario, scenario.controller
    verdict = scenario_stability(s, samples, limit=False)
    if verdict.stable:
        return
    verdict = scenario_stability(s, samples)
    used = (f"controller.observer_discretization = \"{settings.observer_discretization}\", "
            f"controller.velocity = \"{settings.velocity}\"")
    if settings.velocity_cutoff is not None:
        used += f", controller.velocity_cutoff = {settings.velocity_cutoff:g} Hz"
    used += f", controller.delay = {settings.delay}"
    where = (f"{s.source}: at 'controller.sample_rate' = {settings.sample_rate:g} Hz ({used}) the sampled loop is "
             f"unstable: its linearized one-sample map has spectral radius {verdict.spectral_radius:.4g} > 1 at "
             f"q = {np.round(verdict.q_worst, 4).tolist()} (the check freezes the arm at each configuration of "
             f"the path and takes the worst one, so on a moving path it is conservative: a run may stay bounded a "
             f"little past the limit)")
    scale = verdict.largest_stable_scale
    if not scale > 0:
        raise ScenarioError(f"{where} for any 'gains.observer': the controller alone is unstable at this rate; "
                            f"lower 'gains.kp' / 'gains.kd' or raise 'controller.sample_rate'")
    text = (f"{where}. With 'gains.observer' Ts lambda_max(Y M^-1) = {verdict.ts_lambda_max:.4g}; the computed "
            f"limit for these settings is Ts lambda_max(Y M^-1) < {_down(verdict.ts_lambda_limit)}, i.e. at most "
            f"{_down(scale)} x gains.observer (for a scalar gain: "
            f"{_down(scale * float(np.max(np.diag(s.observer_gain))))})")
    rate = _lowest_stable_rate(s, samples)
    if rate is not None:
        text += f"; or raise 'controller.sample_rate' to {rate:.4g} Hz"
    others = {"observer_discretization": "zoh" if settings.observer_discretization == "euler" else "euler",
              "velocity": "measured" if settings.velocity == "difference" else None,
              "delay": 0 if settings.delay else None}
    stable_with = []
    for key, value in others.items():
        if value is None:
            continue
        change = {key: value} | ({"velocity_cutoff": None} if key == "velocity" else {})
        if scenario_stability(s, samples, limit=False, **change).stable:
            shown = f'"{value}"' if isinstance(value, str) else f"{value}"
            stable_with.append(f"'controller.{key}' = {shown}")
    if stable_with:
        text += f". The gain is stable with {' or '.join(stable_with)}"
    raise ScenarioError(text)


def _down(value: float, digits: int = 4) -> str:
    """A limit to ``digits`` significant digits, rounded down so that the number shown is not past the limit.

    The bisection returns the stable end of its bracket, up to ``1e-7`` below the limit; it is nudged up by
    ``1e-6`` first so that a limit that is a round number (Euler's 2) shows as itself.
    """
    if not math.isfinite(value) or value == 0:
        return f"{value:g}"
    value *= 1.0 + 1e-6
    step = 10.0 ** (math.floor(math.log10(abs(value))) - digits + 1)
    return f"{math.floor(value / step) * step:.{digits}g}"


def _lowest_stable_rate(scenario, samples: int, rtol: float = 1e-4) -> float | None:
    """The lowest sample rate (Hz) at which the scenario's gains are stable (bisection; None past 1000x)."""
    from blocks.figure2.digital_stability import scenario_stability
    rate = scenario.controller.sample_rate
    lo, hi = rate, 2.0 * rate

    def stable(r: float) -> bool:
        return scenario_stability(scenario, samples, limit=False, sample_rate=r).stable
    while not stable(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 1000.0 * rate:
            return None
    while hi > lo * (1.0 + rtol):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if stable(mid) else (mid, hi)
    return hi


def simulate_sampled(scenario, observer: bool = True, plant=None,
                     progress: Callable[[float], None] | None = None, engine: str = "auto") -> ct.TimeResponseData:
    """Simulate the digital loop of a scenario on its output grid (see :func:`blocks.simulate`).

    ``engine="compiled"`` runs the loop's generated, numba-compiled module
    (:class:`blocks.engines.compiled.sampled.SampledEngine`), ``"fast"`` (and
    ``"python-control"``) the numpy hybrid engine
    (:meth:`blocks.engines.hybrid.HybridSystem.simulate`); ``"auto"`` takes the
    compiled one when it can run the loop (:func:`blocks.figure2.loop.select_engine`).

    Raises
    ------
    blocks.scenarios.scenario.ScenarioError
        Before the run, if the observer is unstable at this rate (:func:`check_observer_rate`).
    blocks.engines.budget.BudgetError
        Before the loop is built, if the run's estimate (ticks, the delay buffer, the output grid) exceeds the
        budget; before the numpy engine's run, if its wall time (the cost of a tick, measured, times the ticks:
        :func:`blocks.engines.sampled_cost.check_sampled_time`) exceeds the wall-time budget (a run over a minute without
        one is warned about); during the run, if the wall-time budget runs out.
    blocks.engines.monitor.SimulationError
        If a physical signal leaves its bound (:mod:`blocks.engines.divergence`): the signal, the bound and the time named.
    blocks.engines.compiled.CompiledUnavailable
        If ``engine="compiled"`` cannot run this loop (the message says why).
    """
    s = scenario
    sim = s.simulation
    # the estimate first: a huge delay or rate must be refused before anything is sized by it
    budget = check_run(s, observer, Budget.from_env(), what=f"scenario '{s.name}' (sampled at "
                                                            f"{s.controller.sample_rate:g} Hz)")
    if observer:
        check_observer_rate(s)
    loop = sampled_loop(s, observer=observer, plant_system=plant)
    x0 = sampled_initial_state(loop, s)
    chosen = _sampled_engine(loop, sim.method, engine)
    if chosen != "compiled":
        # its cost per tick, measured, times the ticks: refused over the wall-time budget, warned when long
        from blocks.engines.compiled.sampled import sampled_unavailable_reason
        check_sampled_time(loop, x0, s, budget, f"scenario '{s.name}' (sampled at {s.controller.sample_rate:g} Hz)",
                           sampled_unavailable_reason(loop, sim.method))
    monitor = Monitor(f"scenario '{s.name}'", cached_state_bounds(loop, s), x0, budget, sim.t_final, progress,
                      sim.method)
    t_grid = sim.time_grid
    if chosen == "compiled":
        states, outputs = _simulate_compiled(loop, x0, s, monitor)
    else:
        states, outputs = loop.simulate(x0, t_grid, sim.method, rtol=sim.rtol, atol=sim.atol,
                                        max_step=sim.max_step, monitor=monitor)
    monitor.report(sim.t_final, final=True)
    rate = s.controller.sample_rate
    title = f"{s.name}: {'with' if observer else 'without'} disturbance observer, sampled at {rate:g} Hz"
    return loop_response(t_grid, outputs, states, loop.output_labels, loop.state_labels, s, observer, title,
                         loop.name)


def _sampled_engine(loop: HybridSystem, method: str, engine: str) -> str:
    """``"compiled"`` or the numpy hybrid engine for a requested ``engine`` (see :func:`blocks.figure2.loop.select_engine`)."""
    from blocks.engines.engine_choice import select_engine
    if engine not in ("auto", "compiled"):
        select_engine(engine, None)             # refuses an unknown name
        return "fast"
    from blocks.engines.compiled.sampled import sampled_unavailable_reason
    return select_engine(engine, sampled_unavailable_reason(loop, method))


def _simulate_compiled(loop: HybridSystem, x0: np.ndarray, s, monitor: Monitor) -> tuple[np.ndarray, np.ndarray]:
    """States and outputs of the compiled sampled engine, held by the run's :class:`~blocks.engines.monitor.Monitor`."""
    from blocks.engines.compiled.sampled import SampledEngine
    from blocks.engines.integrate import DivergenceError, SolverFailure
    sim = s.simulation
    try:
        return SampledEngine(loop).simulate(x0, sim.time_grid, sim.rtol, sim.atol, sim.max_step, monitor=monitor)
    except DivergenceError as err:
        raise monitor.diverged(err.time, err.state) from None
    except SolverFailure as err:
        raise SimulationError(f"scenario '{s.name}': the solver stopped at t = {err.time:.6g} s of "
                              f"{sim.t_final:g} s: {err.reason}", time=err.time) from None
