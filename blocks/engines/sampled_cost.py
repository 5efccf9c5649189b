"""The wall time of a numpy sampled run, estimated before it starts: the cost of a tick, measured, times the ticks.

The numpy sampled engine's cost per tick is the blocks' tick plus one or more steps of the continuous part
(:mod:`blocks.engines.tick_stepper`), and it grows with the arm: a few tens of microseconds for the paper's RRPR,
milliseconds for a 6- or 7-joint URDF arm whose model runs as Python.  No count of steps says that, so the
cost is measured on the run's own loop, solver and tolerances: a few ticks run first (the generated
functions made on the way), then :data:`CALIBRATION_TICKS` more are timed.  The estimate is their time per
tick times the run's ticks, ``t_final x sample_rate``.

:func:`check_sampled_time` refuses a run whose estimate exceeds the wall-time budget (``--max-seconds``,
``DOBKIT_MAX_SECONDS``), naming ``controller.sample_rate``, and warns (:class:`SlowSampledRunWarning`) before a
run estimated at more than :data:`WARN_SECONDS` when no budget is set.
"""
from __future__ import annotations

import math
import time
import warnings

import numpy as np

from blocks.engines.budget import ENVIRONMENT, Budget, BudgetError

__all__ = ["CALIBRATION_TICKS", "WARN_SECONDS", "SampledTime", "SlowSampledRunWarning", "estimate_sampled_time",
           "check_sampled_time"]

#: Ticks timed to measure the cost of one (after two that make the generated functions and warm the caches).
CALIBRATION_TICKS = 10
#: A run estimated at more than this many seconds (and no wall-time budget) is warned about before it starts.
WARN_SECONDS = 60.0
# runs of fewer ticks than this are not estimated: the measurement would be most of the run
_MIN_TICKS = 4 * CALIBRATION_TICKS


class SlowSampledRunWarning(UserWarning):
    """A numpy sampled run is estimated to take long (the message says how long and what would be faster)."""


class SampledTime:
    """An estimate of a numpy sampled run's wall time.

    Attributes
    ----------
    seconds : float
        The estimate (s).
    per_tick : float
        The measured cost of one tick (s).
    ticks : int
        The run's ticks.
    """

    def __init__(self, seconds: float, per_tick: float, ticks: int) -> None:
        self.seconds, self.per_tick, self.ticks = seconds, per_tick, ticks

    def reason(self, scenario) -> str:
        """How the estimate comes about, in words."""
        c = scenario.controller
        return (f"{_duration(self.per_tick)} per tick x {self.ticks:,} ticks: {scenario.simulation.t_final:g} s at "
                f"{c.sample_rate:g} Hz on the {scenario.robot.joints.count}-joint arm, measured on its first ticks")


def _duration(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.3g} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.3g} ms"
    if seconds < 120.0:
        return f"{seconds:.3g} s"
    if seconds < 7200.0:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"


def estimate_sampled_time(loop, x0: np.ndarray, scenario) -> SampledTime | None:
    """The wall time of the scenario's numpy sampled run of ``loop`` from ``x0``, or None for a short run.

    Runs the loop (:meth:`blocks.engines.hybrid.HybridSystem.simulate`, the scenario's method and tolerances) over its
    first ticks: two to make the generated functions, then :data:`CALIBRATION_TICKS` timed.  A run that cannot
    get through those ticks (it diverges at once) is not estimated: the run itself says why; nor is a loop with
    a block without kernels (an FMU, whose instance a trial run would advance).
    """
    from blocks.diagram.contract import contract_of
    sim, Ts = scenario.simulation, loop.base_period
    ticks = int(math.floor(sim.t_final / Ts * (1 + 1e-12)))
    if ticks < _MIN_TICKS:
        return None
    if any(contract_of(block).kernels is None for block in loop.syslist):
        return None         # a block of its own (an FMU's instance) may keep state: only the run itself runs it
    opts = dict(rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step)
    try:
        loop.simulate(x0, np.array([0.0, 2 * Ts]), sim.method, **opts)
        start = time.perf_counter()
        loop.simulate(x0, np.array([0.0, CALIBRATION_TICKS * Ts]), sim.method, **opts)
        elapsed = time.perf_counter() - start
    except (ArithmeticError, RuntimeError, ValueError):
        return None
    per_tick = elapsed / CALIBRATION_TICKS
    return SampledTime(per_tick * ticks, per_tick, ticks)


def check_sampled_time(loop, x0: np.ndarray, scenario, budget: Budget, what: str,
                       compiled_reason: str | None = None) -> SampledTime | None:
    """Refuse or warn about a numpy sampled run by its estimated wall time (:func:`estimate_sampled_time`).

    Parameters
    ----------
    loop, x0, scenario
        The run.
    budget : Budget
        Its :attr:`~blocks.engines.budget.Budget.seconds` is the wall-time budget (None: none).
    what : str
        The run, for the message (``"scenario 'z1' (sampled at 1000 Hz)"``).
    compiled_reason : str, optional
        Why the compiled sampled engine cannot run it (None: it could), for the advice.

    Raises
    ------
    blocks.engines.budget.BudgetError
        When the estimate exceeds the wall-time budget; its ``key`` is ``controller.sample_rate``.
    """
    estimate = estimate_sampled_time(loop, x0, scenario)
    if estimate is None:
        return None
    advice = ("the compiled sampled engine (engine 'compiled' or 'auto') runs it in a fraction of that"
              if compiled_reason is None else f"the compiled sampled engine would run it faster, but {compiled_reason}")
    if budget.seconds is not None and estimate.seconds > budget.seconds:
        raise BudgetError(
            f"{what} needs about {_duration(estimate.seconds)} of wall time with the numpy sampled engine "
            f"({estimate.reason(scenario)}; set by 'controller.sample_rate' and 'simulation.t_final'), over the "
            f"wall-time budget of {budget.seconds:g} s; {advice}; or lower the rate or the time, or raise the budget "
            f"with --max-seconds or {ENVIRONMENT['seconds']}", None, "controller.sample_rate", "seconds")
    if budget.seconds is None and estimate.seconds > WARN_SECONDS:
        warnings.warn(SlowSampledRunWarning(
            f"{what} will take about {_duration(estimate.seconds)} with the numpy sampled engine "
            f"({estimate.reason(scenario)}, set by 'controller.sample_rate'); {advice}"), stacklevel=3)
    return estimate
