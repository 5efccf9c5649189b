"""How long a report's simulations take, estimated before they start, and refused beyond a wall-time budget.

Most of a report's time on an arm read from a URDF is its closed-loop simulations: the gain studies, the
observer study with its torque-noise runs and the design check, each a full nonlinear run of the arm.  On a
big arm each right-hand side is a recursive Newton-Euler pass, and the generated loop of an arm with more
than a few joints is too long for numba to compile in the run (``engine='auto'`` then takes the numpy
engine: its note says so), so a run costs seconds per simulated second -- an SO-101 or Z1 report spent
most of its minutes there.  The pace is measured, not guessed: the report simulates the scenario with the
observer first, and that run's wall time per simulated second times the simulated seconds still to come
(shared by the workers) is the estimate.  The linear analyses and figures are not in it (seconds).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from blocks.engines.budget import ENVIRONMENT, BudgetError

__all__ = ["StudyRuns", "study_runs", "ReportEstimate", "estimate_report", "check_report_time"]


@dataclass(frozen=True)
class StudyRuns:
    """The simulations of one stage: how many runs and the simulated seconds of each."""

    stage: str
    runs: int
    seconds_each: float

    @property
    def simulated_s(self) -> float:
        return self.runs * self.seconds_each


def _length(value, t_final: float, step: float) -> float:
    """A study run's length: ``value`` on the output grid, at most the scenario's (None: the scenario's)."""
    if value is None:
        return float(t_final)
    return min(max(round(float(value) / step), 1) * step, float(t_final))


def study_runs(scenario, settings) -> list[StudyRuns]:
    """The closed-loop simulations :func:`~analysis.report.build.run_analysis` makes, stage by stage.

    Counts follow the settings: 2 design-check runs; ``len(kp_values) x len(kd_values)`` runs with and as many
    without the observer; the observer study's run without the observer, one per gain (its
    ``observer_values``, the scenario's own when it is not among them, the designed one), and a clean and a
    noisy run per gain of ``noise_t_final``.  The digital study is not counted (it runs without the nonlinear
    arm's engine).
    """
    t_final, step = scenario.simulation.t_final, scenario.simulation.output_step
    study = _length(settings.study_t_final, t_final, step)
    gains = 1 + len(settings.observer_values) + 1 + 1          # none, v I (or v M^), the scenario's, designed
    noise = _length(settings.noise_t_final, study, step)
    grid = len(settings.kp_values) * len(settings.kd_values)
    return [StudyRuns("observer gain design: simulation", 2, _length(settings.design_t_final, t_final, step)),
            StudyRuns("gain study with observer", grid, study),
            StudyRuns("gain study without observer", grid, study),
            StudyRuns("observer gain and noise study", gains, study),
            StudyRuns("observer gain and noise study (torque noise)", 2 * gains, noise)]


@dataclass(frozen=True)
class ReportEstimate:
    """The estimated wall time of a report's remaining simulations.

    Attributes
    ----------
    seconds : float
        Wall-clock seconds (s).
    pace_s_per_s : float
        Wall seconds per simulated second, measured on the scenario's own run.
    simulated_s : float
        Simulated seconds still to run, all stages.
    runs : int
        Their number.
    workers : int
        Processes sharing them.
    largest : StudyRuns
        The stage with the most simulated seconds.
    """

    seconds: float
    pace_s_per_s: float
    simulated_s: float
    runs: int
    workers: int
    largest: StudyRuns

    def text(self) -> str:
        return (f"about {self.seconds:.0f} s for {self.runs} closed-loop runs ({self.simulated_s:.3g} simulated s at "
                f"{self.pace_s_per_s:.3g} s per simulated s, measured on the scenario's own run, over "
                f"{self.workers} worker(s); the most in '{self.largest.stage}': {self.largest.runs} runs of "
                f"{self.largest.seconds_each:g} s)")


def estimate_report(scenario, settings, measured_wall_s: float, measured_sim_s: float) -> ReportEstimate:
    """:class:`ReportEstimate` from one measured run (``measured_wall_s`` of wall time for ``measured_sim_s``
    simulated seconds).  A stage's runs share ``settings.workers`` processes; a stage with fewer runs than
    workers takes as long as one run."""
    if not (measured_sim_s > 0 and math.isfinite(measured_wall_s) and measured_wall_s >= 0):
        raise ValueError(f"a measured run of {measured_sim_s!r} simulated s in {measured_wall_s!r} s gives no pace")
    pace = measured_wall_s / measured_sim_s
    stages = study_runs(scenario, settings)
    workers = max(1, int(settings.workers or 1))
    wall = sum(pace * math.ceil(st.runs / workers) * st.seconds_each for st in stages)
    return ReportEstimate(seconds=wall, pace_s_per_s=pace, simulated_s=sum(st.simulated_s for st in stages),
                          runs=sum(st.runs for st in stages), workers=workers,
                          largest=max(stages, key=lambda st: st.simulated_s))


def check_report_time(estimate: ReportEstimate, budget_seconds: float | None, spent_s: float, what: str) -> None:
    """Refuse the rest of a report whose estimate, added to the ``spent_s`` seconds already spent, exceeds the
    wall-time budget (None: no limit), naming the estimate and the keys that set it."""
    if budget_seconds is None or spent_s + estimate.seconds <= budget_seconds:
        return
    raise BudgetError(f"{what}: the studies need {estimate.text()}, {spent_s:.0f} s already spent, over the "
                      f"wall-time budget of {budget_seconds:g} s; use --quick (shorter and fewer study runs), a "
                      f"shorter 'simulation.t_final', or raise the budget with --max-seconds or "
                      f"{ENVIRONMENT['seconds']}", None, "simulation.t_final", "seconds")
