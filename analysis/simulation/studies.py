"""Gain and noise studies from nonlinear simulations: what Kp, Kd and the observer gain buy, and what they cost.

The experiment (a disturbance step on a held arm)
    Every point of a study is one run of :func:`blocks.simulate` on the
    scenario's arm, models and solver settings with other gains, the arm held at
    ``q_hold`` (the scenario's reference at t = 0) by a constant reference, and
    a constant disturbance step ``f_r`` (the paper's Eq. 4, with the scenario's
    ``disturbance.f_r``) acting from t = 0 in place of the scenario's
    disturbance models.  The arm starts at ``q_hold`` at rest with
    ``d_hat(0) = 0``.  A held arm has a well-defined final state (the loop's
    equilibrium, computed with :func:`analysis.linear.loop.equilibrium`), so
    "settling" and "steady state" mean what they say; on a moving path they
    would mix the response to the disturbance with the response to the path.

Metrics, per run, for each joint error ``e = q_ref - q`` (rad, m) and for the
tool-tip position error ``|p(q_ref) - p(q)|`` (mm):

``final_value``
    The error at the loop's equilibrium (where the held arm comes to rest).
``steady_state_error``
    ``|final_value|``.
``settling_time_s``
    :func:`settling_definition` (the words the report, its figures and the
    README use): the first time from which ``|x - final| <= settle_fraction *
    max_t |x - final|`` holds to the end of the run (2 % of the largest
    deviation from the final value).  None ("not settled") unless the signal
    is inside the band for the whole last ``final_window`` fraction (10 %) of
    the run.
``peak_error``, ``rms_error``
    ``max|x|`` and the root mean square over the run (Eq. 13).

The noise study repeats a short run with measurement noise on ``q`` and ``q'``
and reports the torque noise ``rms(tau_noisy - tau_clean)`` per joint (N m, N):
the price of a faster observer, whose ``d_hat = Y q' + z`` passes velocity
noise through ``Y``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from analysis.linear.loop import equilibrium, hold_scenario
from analysis.results import JsonResult, omitted_if_none
from blocks import SimulationError, closed_loop, simulate
from blocks.figure2.metrics import signal
from blocks.model.joints import JointSpace
from blocks.plumbing.workers import worker_pool
from blocks.scenarios.scenario import Scenario, ScenarioError, default_arm

__all__ = ["DEFAULT_NOISE", "SETTLE_FRACTION", "FINAL_WINDOW", "SignalMetrics", "RunMetrics", "StudyRun",
           "GainGridStudy", "ObserverGainStudy", "Studies", "default_noise", "step_scenario", "run_metrics", "signal_metrics",
           "gain_grid_study", "observer_gain_study", "settling_definition"]

# Used when the scenario has no [noise] section: an encoder of about 0.01 deg (2e-4 rad, 20 um) and
# velocities from differentiated positions (5e-3 rad/s, 0.5 mm/s).  Assumed values, not from the paper.
_NOISE_BY_KIND = {"revolute": (2e-4, 5e-3), "prismatic": (2e-5, 5e-4)}


def default_noise(joints: JointSpace) -> dict:
    """The ``[noise]`` table the studies use when a scenario has none, per joint by its kind (rad or m)."""
    return {"q_std": [_NOISE_BY_KIND[k][0] for k in joints.kinds],
            "dq_std": [_NOISE_BY_KIND[k][1] for k in joints.kinds], "seed": 1, "sample_period": 0.001}


#: :func:`default_noise` of the default scenario's arm.
DEFAULT_NOISE = default_noise(default_arm().joints)

SETTLE_FRACTION = 0.02     # settling band: this fraction of the largest deviation from the final value
FINAL_WINDOW = 0.1         # "settled" needs the signal inside the band over this last fraction of the run


def settling_definition(settle_fraction: float = SETTLE_FRACTION, final_window: float = FINAL_WINDOW) -> str:
    """The one wording of the settling time, used by the report, its figures and the README.

    Examples
    --------
    >>> settling_definition().split(" of its largest")[0]
    'settling time: the time after which the error stays within 2 %'
    """
    return (f"settling time: the time after which the error stays within {100 * settle_fraction:g} % of its "
            "largest deviation from its final value (where the held arm comes to rest) to the end of the run; "
            f'"not settled" if it leaves that band anywhere in the last {100 * final_window:g} % of the run')


@dataclass(frozen=True)
class SignalMetrics(JsonResult):
    """Settling, steady state, peak and RMS of one error signal (units of the signal; time in s).

    ``settling_time_s`` is None when the signal has not settled within the run ("not settled").
    """

    final_value: float
    steady_state_error: float
    settling_time_s: float | None
    settled: bool
    peak_error: float
    rms_error: float


@dataclass(frozen=True)
class RunMetrics(JsonResult):
    """Study metrics of one run: per joint (``joints``, rad or m) and for the tool tip (``tool_mm``, mm)."""

    joints: list[SignalMetrics]
    tool_mm: SignalMetrics


@dataclass(frozen=True)
class StudyRun(JsonResult):
    """One point of a study.

    Attributes
    ----------
    ok : bool
        False when the run failed (then only ``error`` is set).
    error : str or None
        Why it failed.
    joints, tool_mm
        The clean run's metrics (see :class:`RunMetrics`).
    torque_noise_rms : list of float or None
        Observer study only: RMS torque difference between the noisy and the clean short run (N m or N per joint).
    noisy, clean_short : RunMetrics or None
        Observer study only: metrics of the short runs.
    noise_t_final_s : float or None
        Observer study only: their length (s).

    Keys that are None are left out of the JSON.
    """

    ok: bool
    error: str | None = omitted_if_none()
    joints: list[SignalMetrics] | None = omitted_if_none()
    tool_mm: SignalMetrics | None = omitted_if_none()
    torque_noise_rms: list[float] | None = omitted_if_none()
    noisy: RunMetrics | None = omitted_if_none()
    clean_short: RunMetrics | None = omitted_if_none()
    noise_t_final_s: float | None = omitted_if_none()


@dataclass(frozen=True)
class GainGridStudy(JsonResult):
    """Disturbance-step runs over a grid of scalar ``Kp`` (1/s^2) and ``Kd`` (1/s).

    ``runs[i][j]`` is the run with ``kp[i]`` and ``kd[j]``.  The experiment: the
    arm held at ``q_hold`` (rad or m per joint; the paper arm: rad, rad, m, rad) under the step ``f_r`` (N m, N m,
    N, N m) for ``t_final_s``; settling band ``settle_fraction`` of the largest
    deviation, checked over the last ``final_window`` of the run.
    """

    kp: list[float]
    kd: list[float]
    observer: bool
    q_hold: list[float]
    f_r: list[float]
    t_final_s: float
    settle_fraction: float
    final_window: float
    runs: list[list[StudyRun]]

    def cells(self) -> list[tuple[float, float, StudyRun]]:
        """``(kp, kd, run)`` for every grid point, ``kp`` varying slowest."""
        return [(kp, kd, self.runs[i][j]) for i, kp in enumerate(self.kp) for j, kd in enumerate(self.kd)]


@dataclass(frozen=True)
class ObserverGainStudy(JsonResult):
    """Disturbance-step runs with each observer gain and one without the observer, and their torque noise.

    Attributes
    ----------
    noise : dict or None
        The ``[noise]`` table of the noisy runs; None when the scenario's arm takes no ``[noise]`` table
        (then no noisy runs are made and ``noise_unavailable`` says why).
    labels : list of str
        ``"none"`` first (no observer), then one per gain.
    gains : list
        The gains as given (None for ``"none"``; a number, n numbers or n x n; kg m^2/s).
    q_hold, f_r, t_final_s, settle_fraction, final_window
        The experiment, as in :class:`GainGridStudy`.
    noise_t_final_s : float
        Length of the clean and noisy short runs (s).
    runs : list of StudyRun
        Per label.
    slowest_mode_rad_s : list of (float or None) or None
        Per label, the slowest observer mode over the workspace (rad/s; None for ``"none"``), when computed.
    noise_unavailable : str or None
        Why the torque noise was not measured (left out of the JSON when it was).
    """

    noise: dict | None
    labels: list[str]
    gains: list
    q_hold: list[float]
    f_r: list[float]
    t_final_s: float
    settle_fraction: float
    final_window: float
    noise_t_final_s: float
    runs: list[StudyRun]
    slowest_mode_rad_s: list[float | None] | None = omitted_if_none()
    noise_unavailable: str | None = omitted_if_none()


@dataclass(frozen=True)
class Studies(JsonResult):
    """The Kp x Kd study with and without the observer, and the observer gain study."""

    gains_with_dob: GainGridStudy
    gains_without_dob: GainGridStudy
    observer: ObserverGainStudy


def signal_metrics(t, x, final: float | None = None, settle_fraction: float = SETTLE_FRACTION,
                   final_window: float = FINAL_WINDOW) -> SignalMetrics:
    """Settling time, steady-state, peak and RMS of one signal ``x(t)`` (units of ``x``; time in s).

    Parameters
    ----------
    t, x : array_like
        Time (s) and signal.
    final : float, optional
        The signal's final value, when known (for a held arm: its value at the
        loop's equilibrium).  Default: the mean over the last ``final_window``
        fraction of the run, an estimate that is only meaningful if the signal
        has come to rest.
    settle_fraction, final_window : float
        See the module docstring.

    Returns
    -------
    SignalMetrics
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    start = min(len(x) - 1, int(np.floor((1.0 - final_window) * (len(x) - 1))))
    final = float(np.mean(x[start:])) if final is None else float(final)
    dev = np.abs(x - final)
    band = settle_fraction * float(dev.max())
    outside = np.nonzero(dev > band)[0]
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] >= start:
        settling = None
    else:
        settling = float(t[outside[-1] + 1])
    return SignalMetrics(final_value=final, steady_state_error=abs(final), settling_time_s=settling,
                         settled=settling is not None, peak_error=float(np.max(np.abs(x))),
                         rms_error=float(np.sqrt(np.mean(x ** 2))))


def _tip_error_mm(q_ref, q, robot) -> np.ndarray:
    """Tool-tip distance (mm) between configurations ``q_ref`` and ``q``, shape (samples, n) each."""
    return 1e3 * np.linalg.norm(robot.tool_position(q_ref) - robot.tool_position(q), axis=-1)


def run_metrics(response, final_q=None, settle_fraction: float = SETTLE_FRACTION,
                final_window: float = FINAL_WINDOW) -> RunMetrics:
    """Study metrics of one run: per joint (``joints``, rad or m) and for the tool tip (``tool_mm``, mm).

    Parameters
    ----------
    response : control.TimeResponseData
        From :func:`blocks.simulate` (with ``response.scenario``).
    final_q : array_like, shape (n,), optional
        Where the arm comes to rest (a held arm's equilibrium); its errors are
        the final values.  Default: estimated from the end of the run.
    """
    t = np.asarray(response.time)
    q_ref, q = signal(response, "q_ref"), signal(response, "q")
    e = q_ref - q
    robot = response.scenario.robot
    if final_q is not None:
        final_q = np.asarray(final_q, dtype=float)
        e_final = q_ref[:, -1] - final_q
        tip_final = float(_tip_error_mm(q_ref[:, -1], final_q, robot))
    else:
        e_final, tip_final = [None] * len(e), None
    return RunMetrics(joints=[signal_metrics(t, e[i], e_final[i], settle_fraction, final_window)
                              for i in range(len(e))],
                      tool_mm=signal_metrics(t, _tip_error_mm(q_ref.T, q.T, robot), tip_final, settle_fraction,
                                             final_window))


def step_scenario(scenario: Scenario, t_final: float | None = None, **sections) -> Scenario:
    """The study experiment: the arm held at the scenario's reference at t = 0, a constant step ``f_r``.

    Parameters
    ----------
    scenario : Scenario
    t_final : float, optional
        Length of the held run (s); default the scenario's.
    **sections : dict
        Further changes, merged (e.g. ``gains={"kp": 90.0}``).
    """
    q_hold = np.asarray(scenario.trajectory.evaluate(0.0)[0], dtype=float)
    if t_final is not None:
        sections["simulation"] = {**sections.get("simulation", {}), "t_final": float(t_final)}
    return hold_scenario(scenario, q_hold, disturbance={"kind": "paper"}, **sections)


def _rest(variant: Scenario, observer: bool) -> np.ndarray:
    """Where the held arm of ``variant`` comes to rest (its loop's equilibrium), shape (n,)."""
    loop = closed_loop(variant, observer=observer)
    x_eq = equilibrium(loop, 0.0)
    labels = list(loop.state_labels)
    return np.array([x_eq[labels.index(f"plant_q[{i}]")] for i in range(variant.nominal.n)])


def _run(job) -> StudyRun:
    """One study point (runs in a worker process): clean run, and a short clean and noisy pair when asked."""
    variant, observer, noise, noise_t_final = job
    try:
        clean = simulate(variant, observer=observer)
        metrics = run_metrics(clean, final_q=_rest(variant, observer))
        if noise is None:
            return StudyRun(ok=True, joints=metrics.joints, tool_mm=metrics.tool_mm)
        # The noise is linear between samples; steps no longer than a sample keep the solver from rejecting
        # steps at every kink (the torques come out the same).  Both runs use the same settings.
        sim = {"t_final": noise_t_final, "max_step": float(noise["sample_period"])}
        short = variant.replace(simulation=sim)
        clean_short = simulate(short, observer=observer)
        noisy = simulate(short.replace(noise=noise), observer=observer)
        diff = signal(noisy, "tau") - signal(clean_short, "tau")
        return StudyRun(ok=True, joints=metrics.joints, tool_mm=metrics.tool_mm,
                        torque_noise_rms=np.sqrt(np.mean(diff ** 2, axis=1)).tolist(),
                        noisy=run_metrics(noisy), clean_short=run_metrics(clean_short),
                        noise_t_final_s=float(noise_t_final))
    except (SimulationError, RuntimeError) as err:
        return StudyRun(ok=False, error=str(err))


def _map(jobs, workers: int, progress: Callable[[float], None] | None = None) -> list:
    """``_run`` over the jobs, in order; ``progress(fraction of jobs done)`` after each."""
    out = []
    if progress:
        progress(0.0)
    if workers <= 1 or len(jobs) <= 1:
        results = map(_run, jobs)
        for r in results:
            out.append(r)
            if progress:
                progress(len(out) / len(jobs))
        return out
    with worker_pool(min(workers, len(jobs))) as pool:
        for r in pool.map(_run, jobs):         # yields in job order, as each finishes
            out.append(r)
            if progress:
                progress(len(out) / len(jobs))
    return out


def _describe(variant: Scenario) -> dict:
    """The experiment of a study (the shared fields of :class:`GainGridStudy` and :class:`ObserverGainStudy`)."""
    return {"q_hold": [float(v) for v in variant.trajectory.offset],
            "f_r": [float(v) for v in variant.disturbance.f_r],
            "t_final_s": float(variant.simulation.t_final), "settle_fraction": SETTLE_FRACTION,
            "final_window": FINAL_WINDOW}


def gain_grid_study(scenario: Scenario, kp_values, kd_values, observer: bool = True, t_final: float | None = None,
                    workers: int = 1, progress: Callable[[float], None] | None = None) -> GainGridStudy:
    """Disturbance-step runs (see the module docstring) over a grid of scalar ``Kp`` (1/s^2) and ``Kd`` (1/s).

    Parameters
    ----------
    scenario : Scenario
        Its models, observer gain and solver settings are used (noise removed).
    kp_values, kd_values : sequence of float
        Grid values, > 0; the same on every joint.
    observer : bool
        With or without the disturbance observer.
    t_final : float, optional
        Length of the held runs (s); default the scenario's ``t_final``.
    workers : int
        Processes to use (results do not depend on it).
    progress : callable, optional
        ``progress(fraction)``: the fraction of the runs finished, after each.

    Returns
    -------
    GainGridStudy
    """
    kp_values, kd_values = [float(v) for v in kp_values], [float(v) for v in kd_values]
    if not kp_values or not kd_values or min(kp_values + kd_values) <= 0:
        raise ValueError(f"gain grids must be non-empty and > 0, got kp={kp_values}, kd={kd_values}")
    variants = [step_scenario(scenario, t_final, gains={"kp": kp, "kd": kd}) for kp in kp_values for kd in kd_values]
    flat = _map([(v, observer, None, None) for v in variants], workers, progress)
    runs = [flat[i * len(kd_values):(i + 1) * len(kd_values)] for i in range(len(kp_values))]
    return GainGridStudy(kp=kp_values, kd=kd_values, observer=bool(observer), **_describe(variants[0]), runs=runs)


def observer_gain_study(scenario: Scenario, gains, noise: dict | None = None, t_final: float | None = None,
                        noise_t_final: float = 1.0, workers: int = 1,
                        progress: Callable[[float], None] | None = None) -> ObserverGainStudy:
    """Disturbance-step runs with each observer gain and one without the observer, plus their torque noise.

    Parameters
    ----------
    scenario : Scenario
    gains : sequence of (str, gain)
        Labels and observer gains (scalar, n numbers or n x n; kg m^2/s).
    noise : dict, optional
        A complete ``[noise]`` table (default: the scenario's, else :func:`default_noise` of its arm).
    t_final : float, optional
        Length of the held (clean) runs (s); default the scenario's.
    noise_t_final : float
        Length of the clean and noisy runs that measure the torque noise (s).
    workers : int
        Processes to use.
    progress : callable, optional
        ``progress(fraction)``: the fraction of the gains finished, after each.

    Returns
    -------
    ObserverGainStudy
        ``noise_t_final_s`` rounded to the output grid; ``slowest_mode_rad_s`` left None.
    """
    fallback = default_noise(scenario.nominal.joints)
    if noise is None:
        noise = dict(scenario.data["noise"]) if scenario.noise is not None else dict(fallback)
    noise = {**fallback, **noise}
    labels, specs, variants = ["none"], [None], [step_scenario(scenario, t_final)]
    for label, gain in gains:
        g = np.asarray(gain, dtype=float)
        labels.append(str(label))
        specs.append(g.tolist())
        variants.append(step_scenario(scenario, t_final, gains={"observer": g.tolist() if g.ndim else float(g)}))
    step = variants[0].simulation.output_step
    noise_t_final = min(max(round(float(noise_t_final) / step), 1) * step, variants[0].simulation.t_final)
    unavailable = None
    try:                                     # some arms take no [noise] table yet: then clean runs only
        variants[0].replace(noise=noise)
    except ScenarioError as err:
        unavailable = str(err)
    jobs = [(v, k > 0, None if unavailable else noise, noise_t_final) for k, v in enumerate(variants)]
    return ObserverGainStudy(noise=None if unavailable else noise, labels=labels, gains=specs,
                             **_describe(variants[0]), noise_t_final_s=float(noise_t_final),
                             runs=_map(jobs, workers, progress), noise_unavailable=unavailable)
