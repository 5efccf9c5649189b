"""All analyses of a scenario in one place: ``analysis.json``, their figures, and a self-contained HTML report.

:func:`run_analysis` computes every analysis (pure, no files);
:func:`analyze` writes ``analysis.json`` and the figures; :func:`write_report`
also simulates the paper's experiment (Figures 4-8, Table 3) and writes one
``report.html`` (numbers and statements in :mod:`analysis.report.view`,
laid out by the templates of :mod:`analysis.report.html`) with every figure
embedded as base64 PNG and a plain-language summary computed from the
numbers.  Nothing in the output depends on the time of day or the number of
worker processes, so the same scenario and settings give the same numbers.

The result is an :class:`AnalysisResult` (typed results, see
:mod:`analysis.results`); ``analysis.json`` is its
:meth:`~analysis.results.JsonResult.to_json` text and reads back with
:meth:`AnalysisResult.from_json`.  JSON files are strict JSON: a value that is
not a finite number (NaN, infinity) is written as ``null``; where infinity has
a meaning (an unlimited critical speed) the result carries a flag saying so.
"""
from __future__ import annotations

import contextlib
import copy
from dataclasses import dataclass, field, replace
from pathlib import Path

import control as ct
import numpy as np

from analysis.linear import figures as figs
from analysis.linear.bandwidth import BandwidthSurvey, along_trajectory, bandwidth_survey, observer_modes, workspace_grid
from analysis.linear.digital import DigitalAnalysis, digital_analysis
from analysis.linear.digital_figures import digital_figures
from analysis.linear.frequency import FrequencyAnalysis, arm_frequency_analysis, frequency_analysis
from analysis.linear.gain_design import (
    ObserverDesign,
    confirm_by_simulation,
    convergence_certificate,
    critical_speed,
    design_observer_gain,
)
from analysis.linear.loop import (
    MismatchLoop,
    MismatchStudy,
    OperatingPoint,
    arm_mismatch_analysis,
    mismatch_sweep,
    operating_point_analysis,
    stability_boundaries,
)
from analysis.report.html import render_html
from analysis.report.settings import QUICK_SETTINGS, AnalysisSettings
from analysis.report.view import plain_summary
from analysis.results import JsonResult, omitted_if_none, strict_json
from analysis.simulation.figures import joint_signals
from analysis.simulation.studies import Studies, gain_grid_study, observer_gain_study
from blocks import __version__, load_scenario
from blocks.diagram.control_compat import PythonControlChanged
from blocks.diagram.gains import validated_gain
from blocks.model.joints import JointSpace
from blocks.plumbing.outputs import metrics_json, staged_output
from blocks.plumbing.progress import ProgressCallback as Progress
from blocks.scenarios.scenario import Scenario, scenario_from_dict

__all__ = ["AnalysisSettings", "QUICK_SETTINGS", "ScenarioInfo", "AnalysisResult", "run_analysis", "write_figures",
           "gain_label", "observer_gains", "bandwidth_gains", "ANALYSIS_FIGURE_COUNT",
           "analyze", "write_report", "plain_summary", "render_html", "json_text", "experiment_metrics"]

# The design check and the studies replace the scenario's disturbance models by the constant step f_r (Eq. 4,
# with the scenario's f_r): the convergence certificate is about a constant or slowly varying disturbance, and a
# step on a held arm is what settling times are defined for.
STEP_DISTURBANCE = {"kind": "paper"}


@contextlib.contextmanager
def _stage(progress: Progress | None, name: str):
    """Report a stage's start (fraction 0) and, when it completes, its end (fraction 1).

    Yields ``step(fraction)``, for a stage that can say how far it has got.
    """
    def step(fraction: float) -> None:
        if progress is not None:
            progress(name, fraction)
    step(0.0)
    yield step
    step(1.0)


def _t_final(value, scenario: Scenario):
    """A run length no longer than the scenario's, on its output grid (None: the scenario's)."""
    if value is None:
        return None
    step = scenario.simulation.output_step
    return min(max(round(float(value) / step), 1) * step, scenario.simulation.t_final)


@dataclass(frozen=True)
class ScenarioInfo(JsonResult):
    """The scenario an analysis ran on: its name, where it came from, its description and complete TOML text."""

    name: str
    source: str
    description: str
    toml: str
    perfect_model: bool


@dataclass(frozen=True)
class AnalysisResult(JsonResult):
    """Every analysis of a scenario (what ``analysis.json`` holds).

    Attributes
    ----------
    dobkit_version, python_control_version : str
    scenario : ScenarioInfo
    settings : AnalysisSettings
        Written without ``workers`` (it does not change results).
    observer_bandwidth : BandwidthSurvey
        With ``along_trajectory`` set.
    operating_points : list of OperatingPoint
        The reference at t = 0 and at mid-run, and where the slowest observer
        mode is slowest and fastest over the workspace.
    mismatch : MismatchStudy
        At the reference at t = 0.
    observer_design : ObserverDesign
    frequency : FrequencyAnalysis
        At the reference at t = 0.
    studies : Studies
        ``observer.slowest_mode_rad_s`` set.
    digital : DigitalAnalysis or None
        The digital implementation (scenarios with a ``[controller]`` section;
        the key is absent otherwise).
    figures : list of str
        The figure files written with the result (by :func:`analyze` or
        :func:`write_report`); empty from :func:`run_analysis`, which writes nothing.
    not_done : list of str
        One line per analysis that could not be made for a reason of the arm
        (no resting position of the held arm near a configuration, ...): what,
        where and why.  The rest of the result stands; ``frequency`` is None
        when its analysis is one of them, and an operating point that failed
        is left out of ``operating_points``.
    """

    dobkit_version: str
    python_control_version: str
    scenario: ScenarioInfo
    settings: AnalysisSettings
    observer_bandwidth: BandwidthSurvey
    operating_points: list[OperatingPoint]
    mismatch: MismatchStudy
    observer_design: ObserverDesign
    frequency: FrequencyAnalysis | None
    studies: Studies
    figures: list[str] = field(default_factory=list)
    not_done: list[str] = field(default_factory=list)
    digital: DigitalAnalysis | None = omitted_if_none()


def gain_label(Y) -> str:
    """How a person reads an observer gain: ``Y = 10 I``, ``Y = diag(1, 2, 3, 4)`` or ``matrix Y`` (kg m^2/s)."""
    Y = np.atleast_2d(np.asarray(Y, dtype=float))
    if Y.shape == (1, 1):
        return f"Y = {Y[0, 0]:g} I"
    if np.allclose(Y, np.diag(np.diag(Y)), rtol=0, atol=0):
        d = np.diag(Y)
        return f"Y = {d[0]:g} I" if np.all(d == d[0]) else "Y = diag(" + ", ".join(f"{v:g}" for v in d) + ")"
    return "matrix Y"


def observer_gains(scenario_gain, values, designed) -> list[tuple[str, np.ndarray]]:
    """The observer study's gains: ``Y = v I`` for each value, the scenario's gain (marked "(scenario)") in order of
    ``v`` when it is ``v I`` (first otherwise), and the designed gain last.

    Examples
    --------
    >>> [label for label, _ in observer_gains(10 * np.eye(4), (3.0, 30.0), np.eye(4))]
    ['Y = 3 I', 'Y = 10 I (scenario)', 'Y = 30 I', 'designed Y']
    """
    Y_s = np.asarray(scenario_gain, dtype=float)
    gains = [(f"Y = {v:g} I" + (" (scenario)" if np.allclose(v * np.eye(len(Y_s)), Y_s) else ""), v)
             for v in values]
    if not any(label.endswith("(scenario)") for label, _ in gains):
        d = np.diag(Y_s)
        scalar = np.array_equal(Y_s, np.diag(d)) and np.all(d == d[0])
        # a scenario gain v I takes its place among the others by v; any other gain comes first
        at = sum(1 for v in values if v < d[0]) if scalar else 0
        gains.insert(at, (f"{gain_label(Y_s)} (scenario)", Y_s))
    gains.append(("designed Y", np.asarray(designed, dtype=float)))
    return gains


def bandwidth_gains(scenario_gain, values, designed, M0) -> list[tuple[str, np.ndarray]]:
    """The observer study's gains for an arm other than the paper's: ``Y = v M^(q0)`` for each ``v`` (rad/s).

    A gain ``v I`` means a rate of ``v`` divided by each joint's inertia, which on an arm with a light wrist joint
    makes that joint's observer mode far faster than any solver step; ``v M^(q0)`` gives every mode the rate
    ``v`` at the held configuration (the scenario's ``observer_bandwidth``).  The scenario's gain is marked
    "(scenario)" (in its place by ``v`` when it is ``v M^(q0)``, first otherwise), the designed gain last.

    Examples
    --------
    >>> M0 = np.diag([2.0, 1e-6])
    >>> [label for label, _ in bandwidth_gains(10 * M0, (3.0, 30.0), np.eye(2), M0)]
    ['Y = 3 M^(q0)', 'Y = 10 M^(q0) (scenario)', 'Y = 30 M^(q0)', 'designed Y']
    """
    Y_s, M0 = np.asarray(scenario_gain, dtype=float), np.asarray(M0, dtype=float)
    gains = [(f"Y = {v:g} M^(q0)" + (" (scenario)" if np.allclose(v * M0, Y_s, rtol=1e-12, atol=0) else ""),
              float(v) * M0) for v in values]
    if not any(label.endswith("(scenario)") for label, _ in gains):
        # the scenario's own v when its gain is v M^(q0), for its place among the others
        v = float(np.trace(Y_s @ np.linalg.inv(M0))) / len(M0)
        own = np.allclose(v * M0, Y_s, rtol=1e-12, atol=0)
        at = sum(1 for w in values if w < v) if own else 0
        gains.insert(at, ((f"Y = {v:g} M^(q0)" if own else gain_label(Y_s)) + " (scenario)", Y_s))
    gains.append(("designed Y", np.asarray(designed, dtype=float)))
    return gains


def _is_paper_arm(s: Scenario) -> bool:
    """Whether the scenario's true and nominal arms are the paper's (:attr:`blocks.model.arm.ArmModel.paper`: its own
    survey grid, observer-study gains and routes, as the paper made them)."""
    return s.robot.paper is not None and s.nominal.paper is not None


def _explicit_observer_gain(s: Scenario) -> Scenario:
    """The scenario with ``gains.observer_bandwidth`` (``Y = omega M^(q0)``) written out as its matrix ``Y``.

    The studies and the design check give other observer gains by ``gains.observer``; a scenario cannot have
    both keys, and its own gain is the matrix made at its start, which the held runs keep.
    """
    gains = s.user_data.get("gains", {})
    if "observer_bandwidth" not in gains:
        return s
    data = copy.deepcopy(dict(s.user_data))
    data["gains"] = {k: v for k, v in data["gains"].items() if k != "observer_bandwidth"}
    data["gains"]["observer"] = np.asarray(s.observer_gain, dtype=float).tolist()
    if "arm" in data or _is_paper_arm(s):
        return scenario_from_dict(data, source=s.source)
    return scenario_from_dict(data, source=s.source, arm=s.robot, nominal=s.nominal)


def _rest_disturbance(s: Scenario) -> np.ndarray:
    """The constant disturbance (N m, N) on the held arm at rest: the Eq. 4 step ``f_r`` when the scenario has it
    (friction is zero at rest), else zero."""
    dist = s.disturbance
    return np.asarray(dist.f_r, dtype=float) if "paper" in dist.kinds else np.zeros(s.robot.n)


def _paper_mismatch(s: Scenario, q_start, settings: AnalysisSettings, step) -> MismatchStudy:
    """The paper arm's mismatch study on the scenario's own loop (the nominal parameters scaled)."""
    loops = {}
    for k, (observer, key) in enumerate(((True, "with_dob"), (False, "without_dob"))):
        sweep = mismatch_sweep(s, q_start, settings.mismatch_factors, observer)
        step((2 * k + 1) / 4)
        loops[key] = MismatchLoop(sweep=sweep, boundaries=stability_boundaries(
            s, q_start, observer, *settings.boundary_range, points=settings.boundary_points))
        step((2 * k + 2) / 4)
    return MismatchStudy(q0=q_start.tolist(), **loops)


def run_analysis(scenario: Scenario | str = "paper", settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None) -> AnalysisResult:
    """Every analysis of the issue "Analysis and reports", for any arm model.

    The paper's RRPR keeps its own routes (its survey ranges, the mismatch study
    on the scenario's loop with the nominal parameters scaled, the closed-form
    frequency check, ``Y = v I`` in the observer study).  Any other arm (a URDF
    arm) takes the arm route: the workspace grid within its joint limits
    (:meth:`AnalysisSettings.workspace_points_for`), the slice and the critical
    speed along the joint the observer modes change most along, the mismatch
    study by :func:`~analysis.linear.loop.arm_mismatch_analysis` (``M^ = a M``), the
    frequency responses by :func:`~analysis.linear.frequency.arm_frequency_analysis`
    (both held at the reference at t = 0 under the Eq. 4 step, when the
    scenario has it), the observer study with ``Y = v M^(q0)``
    (:func:`bandwidth_gains`), and no torque-noise runs when the arm takes no
    ``[noise]`` table.  JSON keys keep their names (``theta2`` is the slice's
    values, ``critical_theta2_speed_*`` the critical speed along the slice joint).

    Parameters
    ----------
    scenario : Scenario or str
    settings : AnalysisSettings
    progress : callable, optional
        ``progress(stage, fraction)``: each stage reports 0 when it starts and 1 when it is done.

    Returns
    -------
    AnalysisResult
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    paper = _is_paper_arm(s)
    joints = s.nominal.joints
    points = settings.workspace_points if paper else settings.workspace_points_for(joints)
    q_grid, _ = workspace_grid(points) if paper else workspace_grid(points, arm=s.nominal)
    info = ScenarioInfo(name=s.name, source=s.source, description=s.data.get("description", ""), toml=s.to_toml(),
                        perfect_model=s.nominal == s.robot)
    s = _explicit_observer_gain(s)

    with _stage(progress, "observer bandwidth"):
        survey = replace(bandwidth_survey(s, points=points), along_trajectory=along_trajectory(s))
    slice_index = list(joints.names).index(survey.slice_joint_name)

    with _stage(progress, "linearized loop") as step:
        q_start = np.asarray(s.trajectory.evaluate(0.0)[0], dtype=float)
        q_mid = np.asarray(s.trajectory.evaluate(s.simulation.t_final / 2.0)[0], dtype=float)
        points_of_interest = [("reference at t = 0", q_start), ("reference at mid-run", q_mid),
                              ("slowest observer mode (workspace)", np.array(survey.slowest_rad_s.q_at_min)),
                              ("slowest observer mode at its fastest (workspace)",
                               np.array(survey.slowest_rad_s.q_at_max))]
        operating_points, not_done = operating_points_of(s, points_of_interest, step)

    with _stage(progress, "inertia mismatch") as step:
        if paper:
            mismatch = _paper_mismatch(s, q_start, settings, step)
        else:
            mismatch = arm_mismatch_analysis(s.robot, s.kp, s.kd, s.observer_gain, q_start,
                                             settings.mismatch_factors, d=_rest_disturbance(s),
                                             low=settings.boundary_range[0], high=settings.boundary_range[1],
                                             points=settings.boundary_points)

    with _stage(progress, "observer gain design") as step:
        t_ref = np.linspace(0.0, s.simulation.t_final, 2001)
        speed = np.max(np.abs(s.trajectory.evaluate(t_ref)[1]), axis=0)
        min_speed = settings.min_speed if paper else settings.min_speed_for(joints)
        bound = np.maximum(settings.speed_margin * speed, min_speed)
        Y_s = s.observer_gain
        # lift the scenario's gain when it is symmetric positive semidefinite (then no mode gets slower)
        base = Y_s if np.allclose(Y_s, Y_s.T) and np.linalg.eigvalsh((Y_s + Y_s.T) / 2).min() >= 0 else None
        design = design_observer_gain(s.nominal, settings.observer_target_rad_s, q_grid, base=base)
        Y_design = design.Y
        step(0.2)
        # the critical speed along the slice joint (theta2 for the paper's arm)
        direction = np.eye(joints.count)[slice_index]
        certificates = {}
        for k, (key, Y) in enumerate((("designed", Y_design), ("scenario_gain", s.observer_gain))):
            certificates[f"certificate_{key}"] = convergence_certificate(s.nominal, Y, q_grid, bound)
            certificates[f"critical_theta2_speed_{key}"] = critical_speed(s.nominal, Y, q_grid, direction)
            step(0.2 + 0.35 * (k + 1))
        designed_survey = (bandwidth_survey(s, Y=Y_design, points=points) if paper else
                           bandwidth_survey(s, Y=Y_design, points=points, slice_joint=slice_index))
        designed = dict(
            target_rad_s=settings.observer_target_rad_s, base_is_scenario_gain=base is not None,
            Y=Y_design.tolist(), base=design.base.tolist(), M_ref=design.M_ref.tolist(), c_per_s=design.c_per_s,
            slowest_rad_s=design.slowest_rad_s, fastest_rad_s=design.fastest_rad_s,
            speed_bound=bound.tolist(), reference_speed_max=speed.tolist(),
            certificate_designed=certificates["certificate_designed"],
            certificate_scenario_gain=certificates["certificate_scenario_gain"],
            critical_theta2_speed_designed=certificates["critical_theta2_speed_designed"],
            critical_theta2_speed_scenario_gain=certificates["critical_theta2_speed_scenario_gain"],
            bandwidth_designed=designed_survey.overview(),
        )
    with _stage(progress, "observer gain design: simulation"):
        simulation = confirm_by_simulation(
            s, [("scenario gain", s.observer_gain), ("designed", Y_design)],
            t_final=_t_final(settings.design_t_final, s), disturbance=STEP_DISTURBANCE)
    observer_design = ObserverDesign(**designed, simulation=simulation)

    with _stage(progress, "frequency responses"):
        frequency = _for_the_arm(
            lambda: (frequency_analysis(s, q_start) if paper else
                     arm_frequency_analysis(s.robot, s.kp, s.kd, s.observer_gain, q_start, d=_rest_disturbance(s),
                                            nominal=s.nominal)),
            "frequency responses at the reference at t = 0", not_done)

    grids = {}
    for observer, key in ((True, "gains_with_dob"), (False, "gains_without_dob")):
        with _stage(progress, f"gain study {'with' if observer else 'without'} observer") as step:
            grids[key] = gain_grid_study(s, settings.kp_values, settings.kd_values, observer, settings.study_t_final,
                                         settings.workers, progress=step)
    with _stage(progress, "observer gain and noise study") as step:
        gains = (observer_gains(s.observer_gain, settings.observer_values, Y_design) if paper else
                 bandwidth_gains(s.observer_gain, settings.observer_values, Y_design, s.nominal.inertia(q_start)))
        obs = observer_gain_study(s, gains, t_final=settings.study_t_final, noise_t_final=settings.noise_t_final,
                                  workers=settings.workers, progress=step)
        slowest = [None] + [
            float(np.real(observer_modes(s.nominal, validated_gain(g, "observer", joints),
                                         q_grid)[0][:, 0]).min())
            for _, g in gains]
    digital = None
    if s.controller is not None:
        with _stage(progress, "digital implementation"):
            digital = digital_analysis(s, rates_hz=settings.digital_rates_hz,
                                       configurations=[q_start] if settings.quick else None,
                                       simulate_noise=not settings.quick)
    return AnalysisResult(
        dobkit_version=__version__, python_control_version=ct.__version__, scenario=info, settings=settings,
        observer_bandwidth=survey, operating_points=operating_points, mismatch=mismatch,
        observer_design=observer_design, frequency=frequency,
        studies=Studies(**grids, observer=replace(obs, slowest_mode_rad_s=slowest)), digital=digital,
        not_done=not_done)


def operating_points_of(s: Scenario, points, step=None) -> tuple[list[OperatingPoint], list[str]]:
    """:func:`~analysis.linear.loop.operating_point_analysis` at each ``(label, q)`` of ``points``.

    A configuration where the held arm has no resting position (without the
    observer an arm with a light, gravity-loaded joint may sag by radians, or
    nowhere near) is left out with one line ``"linearized loop at LABEL: why"``
    in the second list.  The first point is the one the mismatch and frequency
    analyses and the summary rest on: when it fails, :class:`ArmAnalysisError`
    says why.  ``step(fraction)`` is called after each point.
    """
    operating_points, not_done = [], []
    for k, (label, q) in enumerate(points):
        point = _for_the_arm(lambda: operating_point_analysis(s, q, label=label), f"linearized loop at {label}",
                             not_done)
        if point is None and k == 0:
            raise ArmAnalysisError(not_done[0])
        if point is not None:
            operating_points.append(point)
        if step is not None:
            step((k + 1) / len(points))
    return operating_points, not_done


class ArmAnalysisError(RuntimeError):
    """An analysis that cannot be made for a reason of the arm (the message says which and why, in one line)."""


def _for_the_arm(analysis, what: str, not_done: list):
    """``analysis()``, or None with one line ``"what: why"`` appended to ``not_done`` when it fails for a reason of
    the arm: the held arm has no resting position near the configuration (RuntimeError of the equilibrium
    search), or a matrix of the arm there is singular.  Budget and interrupts still stop the whole run."""
    try:
        return analysis()
    except (RuntimeError, np.linalg.LinAlgError, ArithmeticError) as err:
        if isinstance(err, PythonControlChanged):      # not the arm: the installed python-control
            raise
        not_done.append(f"{what}: " + " ".join(str(err).split()))
        return None


def _figure_writers(result: AnalysisResult, joints: JointSpace) -> list:
    """One ``write(out_dir) -> paths`` per analysis figure, in the report's order."""
    design = result.observer_design
    return [
        lambda out: figs.pole_figure(result.operating_points, out),
        lambda out: figs.mismatch_figure(result.mismatch, out),
        lambda out: figs.bandwidth_figure(result.observer_bandwidth, design.bandwidth_designed,
                                          result.operating_points[0].pd_slowest_analytic_rad_s(), out, joints),
        lambda out: figs.design_figure(design.simulation, out, joints),
    ] + ([] if result.frequency is None else [
        lambda out: figs.bode_figure(result.frequency, out, "tracking", joints),
        lambda out: figs.bode_figure(result.frequency, out, "estimation", joints),
    ]) + [
        lambda out: figs.gain_study_figure(result.studies.gains_with_dob, result.studies.gains_without_dob, out),
        lambda out: figs.observer_study_figure(result.studies.observer, out, joints),
    ] + ([lambda out: digital_figures(result.digital, out, joints)] if result.digital is not None else [])


#: Number of analysis figures :func:`write_figures` writes (each as PNG and SVG).
ANALYSIS_FIGURE_COUNT = 8


def write_figures(result: AnalysisResult, out_dir, joints: JointSpace, progress=None) -> list[Path]:
    """Write every analysis figure of a :func:`run_analysis` result into ``out_dir`` (PNG and SVG).

    ``progress(fraction)``, if given, is called after each figure with the fraction written; ``joints`` are the
    arm's joints, which name the per-joint panels.
    """
    writers = _figure_writers(result, joints)
    files = []
    for k, write in enumerate(writers):
        files += write(out_dir)
        if progress is not None:
            progress((k + 1) / len(writers))
    return files


def json_text(result) -> str:
    """Strict JSON text of a result or of plain data: NaN and infinities written as null, never as non-standard
    constants."""
    return strict_json(result)


def analyze(scenario: Scenario | str = "paper", out_dir=None, settings: AnalysisSettings = AnalysisSettings(),
            progress: Progress | None = None) -> tuple[AnalysisResult, list[Path]]:
    """Run every analysis and write ``out_dir/analysis.json`` and the figures (PNG and SVG).

    Parameters
    ----------
    scenario : Scenario or str
    out_dir : path
        Output folder; must not exist or be empty.
    settings : AnalysisSettings
    progress : callable, optional
        ``progress(stage, fraction)``.

    Returns
    -------
    (AnalysisResult, list of pathlib.Path)
        The result (as written to ``analysis.json``, with ``figures`` set) and the files written.
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    target = Path(out_dir)
    staging = staged_output(target)          # refuses a non-empty folder before any work is done
    result = run_analysis(s, settings, progress)
    with staging as stage:
        with _stage(progress, "writing figures") as step:
            result = replace(result, figures=[p.name for p in write_figures(result, stage, s.robot.joints, step)])
        (stage / "analysis.json").write_text(result.to_json())
    return result, sorted(target.iterdir())


def experiment_metrics(experiment) -> dict:
    """The experiment's metrics plus what the report's statements need.

    Adds ``duration_s``; per run, ``time_of_max_abs_position_error`` (s, per
    joint); and, on a path with a skin plane (``trajectory.skin_height``),
    ``max_depth_below_skin_mm``: how far the tool tip goes below the skin at
    most, planned (``reference``) and in each run (mm, 0 if it stays above).
    """
    metrics = copy.deepcopy(experiment.metrics)
    skin = getattr(experiment.scenario.trajectory, "skin_height", None)
    robot = experiment.scenario.robot
    depth = {}
    for key in ("with_dob", "without_dob"):
        run = getattr(experiment, key)
        t = np.asarray(run.time)
        n = experiment.scenario.robot.n
        q_ref, q = joint_signals(run, "q_ref", n), joint_signals(run, "q", n)
        metrics[key]["time_of_max_abs_position_error"] = t[np.argmax(np.abs(q_ref - q), axis=1)].tolist()
        metrics["duration_s"] = float(t[-1])
        if skin is not None:
            depth["reference"] = _depth_below_mm(q_ref, skin, robot)
            depth[key] = _depth_below_mm(q, skin, robot)
    if depth:
        metrics["max_depth_below_skin_mm"] = depth
    return metrics


def _depth_below_mm(q, skin_height: float, robot) -> float:
    """Largest depth (mm) of the tool tip below the plane z = skin_height over a run's joint positions (n, m)."""
    z = np.asarray(robot.tool_position(np.asarray(q).T))[:, 2]
    return float(max(0.0, 1e3 * np.max(skin_height - z)))


def write_report(scenario: Scenario | str = "paper", out_dir=None, settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None, sweep_summaries=(), tunings=(), budget_seconds: float | None = None,
                 notify=None) -> Path:
    """Simulate, analyze and write ``out_dir/report.html`` (plus ``analysis.json``, ``metrics.json`` and figures).

    ``sweep_summaries`` are folders written by ``dobkit sweep`` (``summary.json`` and its figures), and
    ``tunings`` folders written by ``dobkit tune`` (``tune.json`` and its figures); each becomes a section
    of the report.

    The time of the studies is estimated from the pace of the scenario's own run, simulated first
    (:mod:`analysis.report.estimate`); ``notify(text)``, if given, is told the estimate, and with
    ``budget_seconds`` (wall-clock s, None: no limit) a report that would run past it is refused then, with
    the estimate and the keys that set it (:class:`~blocks.engines.budget.BudgetError`), before the studies start.

    Returns
    -------
    pathlib.Path
        The report file.
    """
    from analysis.simulation.experiment import run_experiment
    from analysis.simulation.figures import paper_figures
    from analysis.sweep.summary import html_section

    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    for folder in sweep_summaries:           # a missing sweep summary is an error before any work is done
        if not (Path(folder) / "summary.json").is_file():
            raise FileNotFoundError(f"sweep summary folder '{folder}' has no summary.json (run 'dobkit sweep' first)")
    from analysis.tune.results import read_result
    for folder in tunings:                   # so is a missing or incomplete tuning
        read_result(folder)
    target = Path(out_dir)
    staging = staged_output(target)          # refuses a non-empty folder before any work is done
    import time

    from analysis.report.estimate import check_report_time, estimate_report
    started = time.perf_counter()
    experiment = run_experiment(s, None, progress=progress, figures=False)
    spent = time.perf_counter() - started
    # both runs (with and without the observer) give the pace: wall s per simulated s
    estimate = estimate_report(s, settings, spent, 2.0 * float(s.simulation.t_final))
    if notify is not None:
        notify(estimate.text())
    check_report_time(estimate, budget_seconds, spent, f"report of scenario '{s.name}'")
    metrics = experiment_metrics(experiment)
    result = run_analysis(s, settings, progress)
    with staging as stage, _stage(progress, "writing figures and report") as step:
        fig_dir = stage / "figures"
        parts = 5 + ANALYSIS_FIGURE_COUNT + 1                # Figures 4-8, the analysis figures, the page
        files = paper_figures(experiment.with_dob, experiment.without_dob, fig_dir,
                              progress=lambda f: step(5 * f / parts))
        files += write_figures(result, fig_dir, progress=lambda f: step((5 + ANALYSIS_FIGURE_COUNT * f) / parts),
                               joints=s.robot.joints)
        result = replace(result, figures=[f"figures/{p.name}" for p in files])
        (stage / "analysis.json").write_text(result.to_json())
        (stage / "metrics.json").write_text(metrics_json(metrics)[0])      # as dobkit simulate and fmu cosim
        pngs = {p.stem: p for p in files if p.suffix == ".png"}
        from analysis.tune.report import html_section as tune_section
        sweeps = tuple(html_section(folder) for folder in sweep_summaries) + tuple(map(tune_section, tunings))
        (stage / "report.html").write_text(render_html(result, metrics, s, pngs, sweeps), encoding="utf-8")
    return target / "report.html"
