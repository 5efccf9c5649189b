"""How much work one simulation may take: estimated before it starts, enforced while it runs.

An explicit solver (RK45, RK23, DOP853) takes steps no longer than about
``STABILITY_SPAN / lambda`` for the loop's fastest rate ``lambda`` (1/s), so a
very stiff loop -- a huge gain, a tiny friction velocity -- asks for millions of
steps.  Before a run, :func:`check_run` estimates the right-hand-side
evaluations from the fastest rates (:func:`blocks.batch.schedule.rates_by_source`)
and from the measurement-noise samples (every sample is a kink the solver must
step to), and refuses a run above the limit with the estimate and the key
that causes it.  During the run the same limits stop the solver
(:func:`blocks.integrate.integrate_on_grid`'s ``max_evaluations`` and ``deadline``).

Limits (:class:`RunLimits`): right-hand-side evaluations per simulated second
and wall time per run, with defaults; the environment variables
``DOBKIT_MAX_EVALUATIONS_PER_SECOND`` and ``DOBKIT_MAX_WALL_SECONDS`` raise them.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

from .scenario import Scenario

__all__ = ["RunLimits", "RunLimitError", "evaluation_estimate", "check_run", "EXPLICIT_METHODS"]

#: Methods whose step is limited by the fastest rate (the others are implicit).
EXPLICIT_METHODS = ("RK45", "RK23", "DOP853")
#: ``h lambda`` an explicit Runge-Kutta step stays stable below (about 3.3 for RK45 on the real axis).
STABILITY_SPAN = 3.0
#: Right-hand-side evaluations per step (RK45 uses six; DOP853 twelve, RK23 three).
EVALUATIONS_PER_STEP = {"RK45": 6, "RK23": 3, "DOP853": 12}


class RunLimitError(ValueError):
    """A run would exceed (or has exceeded) its limits; the message gives the estimate and the key that causes it."""


@dataclass(frozen=True)
class RunLimits:
    """Limits of one simulation run.

    Parameters
    ----------
    evaluations_per_second : float
        Right-hand-side evaluations per simulated second (the paper's run needs about 500).
    wall_seconds : float
        Wall time of one run (s).
    """

    evaluations_per_second: float = 200_000.0
    wall_seconds: float = 900.0

    @classmethod
    def from_environment(cls) -> "RunLimits":
        """The defaults, raised (or lowered) by ``DOBKIT_MAX_EVALUATIONS_PER_SECOND`` / ``DOBKIT_MAX_WALL_SECONDS``."""
        values = {}
        for field, name in (("evaluations_per_second", "DOBKIT_MAX_EVALUATIONS_PER_SECOND"),
                            ("wall_seconds", "DOBKIT_MAX_WALL_SECONDS")):
            text = os.environ.get(name)
            if text is not None:
                try:
                    value = float(text)
                except ValueError:
                    value = math.nan
                if not (math.isfinite(value) and value > 0):
                    raise RunLimitError(f"environment variable {name} must be a number > 0, got {text!r}")
                values[field] = value
        return cls(**values)

    def max_evaluations(self, t_final: float) -> int:
        """The evaluations a run of ``t_final`` s may use."""
        return int(self.evaluations_per_second * max(t_final, 1e-3))

    def deadline(self) -> float:
        """The :func:`time.monotonic` time a run starting now must end by."""
        return time.monotonic() + self.wall_seconds


def evaluation_estimate(scenario: Scenario, observer: bool = True) -> tuple[float, str, float]:
    """``(evaluations, key, rate)``: the right-hand-side evaluations a run is expected to need, the scenario key
    that sets that number, and the rate (1/s) it comes from.  Implicit methods are estimated from the noise alone."""
    from .batch.schedule import rates_by_source
    from .batch.variants import Variants
    s = scenario
    method, t_final = s.simulation.method, s.simulation.t_final
    per_step = EVALUATIONS_PER_STEP.get(method, 6)
    candidates = []
    if method in EXPLICIT_METHODS:
        for key, rates in rates_by_source(Variants(s, [{}]), observer).items():
            rate = float(rates.max())
            candidates.append((per_step * t_final * rate / STABILITY_SPAN, key, rate))
    if s.noise is not None:         # the interpolated noise has a kink at every sample
        rate = 1.0 / s.noise.sample_period
        candidates.append((per_step * t_final * rate, "noise.sample_period", rate))
    if not candidates:
        return 0.0, "", 0.0
    return max(candidates)


def check_run(scenario: Scenario, observer: bool = True, limits: RunLimits | None = None) -> RunLimits:
    """Refuse a run whose estimated work exceeds the limits; return the limits to enforce during the run.

    Raises
    ------
    RunLimitError
        With the estimate, the key that causes it and what to do.
    """
    limits = RunLimits.from_environment() if limits is None else limits
    s = scenario
    allowed = limits.max_evaluations(s.simulation.t_final)
    estimate, key, rate = evaluation_estimate(s, observer)
    if estimate > allowed:
        if key == "noise.sample_period":
            cause = f"'noise.sample_period' puts {rate:.3g} noise samples per second in the run"
            advice = "Use a longer noise.sample_period, or raise the limit"
        else:
            cause = f"'{key}' makes the loop's fastest rate about {rate:.3g} 1/s"
            advice = "Use an implicit method (simulation.method = \"Radau\" or \"BDF\"), or raise the limit"
        raise RunLimitError(
            f"scenario '{s.name}': {cause}, so {s.simulation.method} would need about {estimate:.3g} right-hand-side "
            f"evaluations over {s.simulation.t_final:g} s; the limit is {allowed:.3g} "
            f"({limits.evaluations_per_second:.3g} per simulated second). {advice} with "
            f"DOBKIT_MAX_EVALUATIONS_PER_SECOND if the run is meant")
    return limits
