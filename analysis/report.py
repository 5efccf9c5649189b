"""All analyses of a scenario in one place: ``analysis.json``, their figures, and a self-contained HTML report.

:func:`run_analysis` computes every analysis (pure, no files);
:func:`analyze` writes ``analysis.json`` and the figures; :func:`write_report`
also simulates the paper's experiment (Figures 4-8, Table 3) and writes one
``report.html`` (numbers and statements in :mod:`analysis.report_view`,
laid out by the templates of :mod:`analysis.report_html`) with every figure
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
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import control as ct
import numpy as np

from blocks import __version__
from blocks import load_scenario
from blocks.scenario import Scenario
from blocks.gains import validated_gain
from . import analysis_figures as figs
from .bandwidth import DEFAULT_POINTS, BandwidthSurvey, along_trajectory, bandwidth_survey, observer_modes, \
    workspace_grid
from .frequency import FrequencyAnalysis, frequency_analysis
from .gain_design import (ObserverDesign, confirm_by_simulation, convergence_certificate, critical_speed,
                          design_observer_gain)
from .linear import MismatchStudy, OperatingPoint, mismatch_analysis, operating_point_analysis
from blocks.metrics import signal
from blocks.outputs import staged_output
from blocks.progress import ProgressCallback as Progress
from .report_html import render_html
from .report_view import plain_summary
from .results import JsonResult, omitted_if_none, strict_json
from .studies import Studies, gain_grid_study, observer_gain_study

__all__ = ["AnalysisSettings", "QUICK_SETTINGS", "ScenarioInfo", "AnalysisResult", "run_analysis", "write_figures",
           "analyze", "write_report", "plain_summary", "render_html", "json_text", "experiment_metrics"]

# The design check and the studies replace the scenario's disturbance models by the constant step f_r (Eq. 4,
# with the scenario's f_r): the convergence certificate is about a constant or slowly varying disturbance, and a
# step on a held arm is what settling times are defined for.
STEP_DISTURBANCE = {"kind": "paper"}


@dataclass(frozen=True)
class AnalysisSettings:
    """What the analyses compute and on which grids.

    Attributes
    ----------
    observer_target_rad_s : float
        Target slowest observer mode of the gain design (rad/s), finite and > 0.
    speed_margin : float
        The certificate's joint-speed bound is this times the largest reference
        speed of the scenario per joint (rad/s, m/s), at least ``min_speed``.
    min_speed : 4 floats
        Floor of that bound (rad/s, rad/s, m/s, rad/s).
    mismatch_factors : floats
        Nominal/true inertia ratios of the pole sweep.
    boundary_range, boundary_points
        Range and scan size of the stability-boundary search.
    workspace_points : 4 ints
        Grid of the observer-bandwidth survey and the gain design
        (default :data:`analysis.bandwidth.DEFAULT_POINTS`).
    kp_values, kd_values, observer_values : floats
        Grids of the gain studies (scalar gains, the same on every joint).
    study_t_final : float
        Length (s) of the studies' runs: the arm held at the path's start under a
        disturbance step (see :mod:`analysis.studies`).
    design_t_final : float or None
        Length (s) of the design check's runs on the scenario's path (None: the
        whole path).
    noise_t_final : float
        Length (s) of the runs that measure the torque noise.
    workers : int
        Processes for the studies (results do not depend on it).
    """

    observer_target_rad_s: float = 10.0
    speed_margin: float = 2.0
    min_speed: tuple = (0.5, 0.5, 0.05, 0.5)
    mismatch_factors: tuple = (0.5, 0.595, 0.707, 0.841, 1.0, 1.189, 1.414, 1.682, 2.0)
    boundary_range: tuple = (0.02, 50.0)
    boundary_points: int = 25
    workspace_points: tuple = DEFAULT_POINTS
    kp_values: tuple = (45.0, 90.0, 180.0, 360.0)
    kd_values: tuple = (9.0, 18.0, 36.0, 72.0)
    observer_values: tuple = (1.0, 3.0, 10.0, 30.0, 100.0)
    study_t_final: float = 10.0
    design_t_final: float | None = 6.0
    noise_t_final: float = 2.0
    workers: int = field(default=1, compare=False)

    def __post_init__(self) -> None:
        t = self.observer_target_rad_s
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t <= 0:
            raise ValueError(f"observer target must be a finite number > 0 rad/s, got {t!r}")
        for name in ("study_t_final", "noise_t_final") + (("design_t_final",) if self.design_t_final is not None
                                                           else ()):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0 s, got {v!r}")

    def as_dict(self) -> dict:
        """JSON-ready settings (without ``workers``, which does not change results)."""
        out = asdict(self)
        out.pop("workers")
        return out


# Small grids and short runs: the same analyses in well under a minute (previews).
QUICK_SETTINGS = AnalysisSettings(mismatch_factors=(0.5, 1.0, 2.0), boundary_points=9,
                                  workspace_points=(3, 37, 2, 3), kp_values=(90.0, 180.0), kd_values=(18.0, 36.0),
                                  observer_values=(3.0, 30.0), study_t_final=6.0, design_t_final=2.0,
                                  noise_t_final=0.3)


@contextlib.contextmanager
def _stage(progress: Progress | None, name: str):
    """Report a stage's start (fraction 0) and, when it completes, its end (fraction 1)."""
    if progress is not None:
        progress(name, 0.0)
    yield
    if progress is not None:
        progress(name, 1.0)


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
    figures : list of str or None
        Files written with the result (left out of the JSON while None).
    """

    dobkit_version: str
    python_control_version: str
    scenario: ScenarioInfo
    settings: AnalysisSettings
    observer_bandwidth: BandwidthSurvey
    operating_points: list[OperatingPoint]
    mismatch: MismatchStudy
    observer_design: ObserverDesign
    frequency: FrequencyAnalysis
    studies: Studies
    figures: list[str] | None = omitted_if_none()


def run_analysis(scenario: Scenario | str = "paper", settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None) -> AnalysisResult:
    """Every analysis of the issue "Analysis and reports".

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
    q_grid, _ = workspace_grid(settings.workspace_points)
    info = ScenarioInfo(name=s.name, source=s.source, description=s.data.get("description", ""), toml=s.to_toml(),
                        perfect_model=s.nominal == s.robot)

    with _stage(progress, "observer bandwidth"):
        survey = replace(bandwidth_survey(s, points=settings.workspace_points), along_trajectory=along_trajectory(s))

    with _stage(progress, "linearized loop"):
        q_start = np.asarray(s.trajectory.evaluate(0.0)[0], dtype=float)
        q_mid = np.asarray(s.trajectory.evaluate(s.simulation.t_final / 2.0)[0], dtype=float)
        points = [("reference at t = 0", q_start), ("reference at mid-run", q_mid),
                  ("slowest observer mode (workspace)", np.array(survey.slowest_rad_s.q_at_min)),
                  ("slowest observer mode at its fastest (workspace)", np.array(survey.slowest_rad_s.q_at_max))]
        operating_points = [operating_point_analysis(s, q, label=label) for label, q in points]

    with _stage(progress, "inertia mismatch"):
        mismatch = mismatch_analysis(s, q_start, settings.mismatch_factors, *settings.boundary_range,
                                     points=settings.boundary_points)

    with _stage(progress, "observer gain design"):
        t_ref = np.linspace(0.0, s.simulation.t_final, 2001)
        speed = np.max(np.abs(s.trajectory.evaluate(t_ref)[1]), axis=0)
        bound = np.maximum(settings.speed_margin * speed, settings.min_speed)
        Y_s = s.observer_gain
        # lift the scenario's gain when it is symmetric positive semidefinite (then no mode gets slower)
        base = Y_s if np.allclose(Y_s, Y_s.T) and np.linalg.eigvalsh((Y_s + Y_s.T) / 2).min() >= 0 else None
        design = design_observer_gain(s.nominal, settings.observer_target_rad_s, q_grid, base=base)
        Y_design = design.Y
        designed = dict(
            target_rad_s=settings.observer_target_rad_s, base_is_scenario_gain=base is not None,
            Y=Y_design.tolist(), base=design.base.tolist(), M_ref=design.M_ref.tolist(), c_per_s=design.c_per_s,
            slowest_rad_s=design.slowest_rad_s, fastest_rad_s=design.fastest_rad_s,
            speed_bound=bound.tolist(), reference_speed_max=speed.tolist(),
            certificate_designed=convergence_certificate(s.nominal, Y_design, q_grid, bound),
            certificate_scenario_gain=convergence_certificate(s.nominal, s.observer_gain, q_grid, bound),
            critical_theta2_speed_designed=critical_speed(s.nominal, Y_design, q_grid, [0, 1, 0, 0]),
            critical_theta2_speed_scenario_gain=critical_speed(s.nominal, s.observer_gain, q_grid, [0, 1, 0, 0]),
            bandwidth_designed=bandwidth_survey(s, Y=Y_design, points=settings.workspace_points).overview(),
        )
    with _stage(progress, "observer gain design: simulation"):
        simulation = confirm_by_simulation(
            s, [("scenario gain", s.observer_gain), ("designed", Y_design)],
            t_final=_t_final(settings.design_t_final, s), disturbance=STEP_DISTURBANCE)
    observer_design = ObserverDesign(**designed, simulation=simulation)

    with _stage(progress, "frequency responses"):
        frequency = frequency_analysis(s, q_start)

    grids = {}
    for observer, key in ((True, "gains_with_dob"), (False, "gains_without_dob")):
        with _stage(progress, f"gain study {'with' if observer else 'without'} observer"):
            grids[key] = gain_grid_study(s, settings.kp_values, settings.kd_values, observer, settings.study_t_final,
                                         settings.workers)
    with _stage(progress, "observer gain and noise study"):
        gains = [(f"Y = {v:g} I" + (" (scenario)" if np.allclose(v * np.eye(4), s.observer_gain) else ""), v)
                 for v in settings.observer_values]
        if not any(label.endswith("(scenario)") for label, _ in gains):
            gains.insert(0, ("scenario Y (scenario)", s.observer_gain))
        gains.append(("designed Y", Y_design))
        obs = observer_gain_study(s, gains, t_final=settings.study_t_final, noise_t_final=settings.noise_t_final,
                                  workers=settings.workers)
        slowest = [None] + [
            float(np.real(observer_modes(s.nominal, validated_gain(g, "observer"),
                                         q_grid)[0][:, 0]).min())
            for _, g in gains]
    return AnalysisResult(
        dobkit_version=__version__, python_control_version=ct.__version__, scenario=info, settings=settings,
        observer_bandwidth=survey, operating_points=operating_points, mismatch=mismatch,
        observer_design=observer_design, frequency=frequency,
        studies=Studies(**grids, observer=replace(obs, slowest_mode_rad_s=slowest)))


def write_figures(result: AnalysisResult, out_dir) -> list[Path]:
    """Write every analysis figure of a :func:`run_analysis` result into ``out_dir`` (PNG and SVG)."""
    design = result.observer_design
    files = []
    files += figs.pole_figure(result.operating_points, out_dir)
    files += figs.mismatch_figure(result.mismatch, out_dir)
    files += figs.bandwidth_figure(result.observer_bandwidth, design.bandwidth_designed,
                                   result.operating_points[0].pd_slowest_analytic_rad_s(), out_dir)
    files += figs.design_figure(design.simulation, out_dir)
    files += figs.bode_figure(result.frequency, out_dir, "tracking")
    files += figs.bode_figure(result.frequency, out_dir, "estimation")
    files += figs.gain_study_figure(result.studies.gains_with_dob, result.studies.gains_without_dob, out_dir)
    files += figs.observer_study_figure(result.studies.observer, out_dir)
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
    target = Path(out_dir)
    staging = staged_output(target)          # refuses a non-empty folder before any work is done
    result = run_analysis(scenario, settings, progress)
    with staging as stage:
        with _stage(progress, "writing figures"):
            result = replace(result, figures=[p.name for p in write_figures(result, stage)])
        (stage / "analysis.json").write_text(result.to_json())
    return result, sorted(target.iterdir())


def experiment_metrics(experiment) -> dict:
    """The experiment's metrics plus what the report's statements need: ``duration_s`` and, per run,
    ``time_of_max_abs_position_error`` (s, per joint)."""
    metrics = copy.deepcopy(experiment.metrics)
    for key in ("with_dob", "without_dob"):
        run = getattr(experiment, key)
        t = np.asarray(run.time)
        e = signal(run, "q_ref") - signal(run, "q")
        metrics[key]["time_of_max_abs_position_error"] = t[np.argmax(np.abs(e), axis=1)].tolist()
        metrics["duration_s"] = float(t[-1])
    return metrics


def write_report(scenario: Scenario | str = "paper", out_dir=None, settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None, sweep_summaries=()) -> Path:
    """Simulate, analyze and write ``out_dir/report.html`` (plus ``analysis.json``, ``metrics.json`` and figures).

    ``sweep_summaries`` are folders written by ``dobkit sweep`` (``summary.json`` and its figures); each
    becomes a section of the report.

    Returns
    -------
    pathlib.Path
        The report file.
    """
    from .experiment import run_experiment
    from .figures import paper_figures

    from .sweep_report import html_section

    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    for folder in sweep_summaries:           # a missing sweep summary is an error before any work is done
        if not (Path(folder) / "summary.json").is_file():
            raise FileNotFoundError(f"sweep summary folder '{folder}' has no summary.json (run 'dobkit sweep' first)")
    target = Path(out_dir)
    staging = staged_output(target)          # refuses a non-empty folder before any work is done
    experiment = run_experiment(s, None, progress=progress, figures=False)
    metrics = experiment_metrics(experiment)
    result = run_analysis(s, settings, progress)
    with staging as stage, _stage(progress, "writing figures and report"):
        fig_dir = stage / "figures"
        files = paper_figures(experiment.with_dob, experiment.without_dob, fig_dir) + write_figures(result, fig_dir)
        result = replace(result, figures=[f"figures/{p.name}" for p in files])
        (stage / "analysis.json").write_text(result.to_json())
        (stage / "metrics.json").write_text(json_text(metrics))
        pngs = {p.stem: p for p in files if p.suffix == ".png"}
        sweeps = tuple(html_section(folder) for folder in sweep_summaries)
        (stage / "report.html").write_text(render_html(result, metrics, s, pngs, sweeps), encoding="utf-8")
    return target / "report.html"
