"""All analyses of a scenario in one place: ``analysis.json``, their figures, and a self-contained HTML report.

:func:`run_analysis` computes every analysis (pure, no files);
:func:`analyze` writes ``analysis.json`` and the figures; :func:`write_report`
also simulates the paper's experiment (Figures 4-8, Table 3) and writes one
``report.html`` with every figure embedded as base64 PNG and a plain-language
summary computed from the numbers.  Nothing in the output depends on the
time of day or the number of worker processes, so the same scenario and
settings give the same numbers.
"""
from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import control as ct
import numpy as np

from .. import __version__
from ..blocks import forward_kinematics, load_scenario
from ..blocks.scenario import Scenario
from ..blocks.systems import gain_matrix
from . import analysis_figures as figs
from .bandwidth import along_trajectory, bandwidth_survey, observer_modes, workspace_grid
from .frequency import frequency_analysis
from .gain_design import (confirm_by_simulation, convergence_certificate, critical_speed, design_observer_gain)
from .linear import mismatch_sweep, operating_point_analysis, stability_boundaries
from .metrics import DISTURBANCE_UNITS, JOINT_LABELS, JOINT_UNITS
from .studies import gain_grid_study, observer_gain_study

__all__ = ["AnalysisSettings", "QUICK_SETTINGS", "run_analysis", "write_figures", "analyze", "write_report",
           "plain_summary", "render_html"]

Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class AnalysisSettings:
    """What the analyses compute and on which grids.

    Attributes
    ----------
    observer_target_rad_s : float
        Target slowest observer mode of the gain design (rad/s).
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
        Grid of the observer-bandwidth survey and the gain design.
    kp_values, kd_values, observer_values : floats
        Grids of the gain studies (scalar gains, the same on every joint).
    study_t_final, design_t_final, noise_t_final : float or None
        Run lengths (s) of the gain study, the design check and the noise study
        (None: the scenario's own).
    workers : int
        Processes for the studies (results do not depend on it).
    """

    observer_target_rad_s: float = 10.0
    speed_margin: float = 2.0
    min_speed: tuple = (0.5, 0.5, 0.05, 0.5)
    mismatch_factors: tuple = (0.5, 0.595, 0.707, 0.841, 1.0, 1.189, 1.414, 1.682, 2.0)
    boundary_range: tuple = (0.02, 50.0)
    boundary_points: int = 25
    workspace_points: tuple = (5, 73, 3, 5)
    kp_values: tuple = (45.0, 90.0, 180.0, 360.0)
    kd_values: tuple = (9.0, 18.0, 36.0, 72.0)
    observer_values: tuple = (1.0, 3.0, 10.0, 30.0, 100.0)
    study_t_final: float | None = None
    design_t_final: float | None = 6.0
    noise_t_final: float | None = 2.0
    workers: int = field(default=1, compare=False)

    def as_dict(self) -> dict:
        """JSON-ready settings (without ``workers``, which does not change results)."""
        out = asdict(self)
        out.pop("workers")
        return out


# Small grids and short runs: the same analyses in well under a minute (previews).
QUICK_SETTINGS = AnalysisSettings(mismatch_factors=(0.5, 1.0, 2.0), boundary_points=9,
                                  workspace_points=(3, 37, 2, 3), kp_values=(90.0, 180.0), kd_values=(18.0, 36.0),
                                  observer_values=(3.0, 30.0), study_t_final=1.0, design_t_final=2.0,
                                  noise_t_final=0.3)


def _report(progress: Progress | None, stage: str, fraction: float = 0.0) -> None:
    if progress is not None:
        progress(stage, fraction)


def _t_final(value, scenario: Scenario):
    return None if value is None else min(float(value), scenario.simulation.t_final)


def run_analysis(scenario: Scenario | str = "paper", settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None) -> dict:
    """Every analysis of the issue "Analysis and reports", JSON-ready.

    Returns
    -------
    dict
        ``operating_points`` (linearized poles and modes, see
        :func:`~dobkit.analysis.linear.operating_point_analysis`), ``mismatch``,
        ``observer_bandwidth``, ``observer_design``, ``frequency``, ``studies``,
        plus ``scenario``, ``settings`` and versions.
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    q_grid, _ = workspace_grid(settings.workspace_points)
    out = {"dobkit_version": __version__, "python_control_version": ct.__version__,
           "scenario": {"name": s.name, "source": s.source, "description": s.data.get("description", ""),
                        "toml": s.to_toml()},
           "settings": settings.as_dict()}

    _report(progress, "observer bandwidth")
    survey = bandwidth_survey(s, points=settings.workspace_points)
    survey["along_trajectory"] = along_trajectory(s)
    out["observer_bandwidth"] = survey

    _report(progress, "linearized loop")
    q_start = np.asarray(s.trajectory.evaluate(0.0)[0], dtype=float)
    q_mid = np.asarray(s.trajectory.evaluate(s.simulation.t_final / 2.0)[0], dtype=float)
    points = [("reference at t = 0", q_start), ("reference at mid-run", q_mid),
              ("slowest observer mode (workspace)", np.array(survey["slowest_rad_s"]["q_at_min"])),
              ("slowest observer mode at its fastest (workspace)", np.array(survey["slowest_rad_s"]["q_at_max"]))]
    out["operating_points"] = [{"label": label, **operating_point_analysis(s, q)} for label, q in points]

    _report(progress, "inertia mismatch")
    out["mismatch"] = {"q0": q_start.tolist()}
    for observer, key in ((True, "with_dob"), (False, "without_dob")):
        out["mismatch"][key] = {
            "sweep": mismatch_sweep(s, q_start, settings.mismatch_factors, observer),
            "boundaries": stability_boundaries(s, q_start, observer, *settings.boundary_range,
                                               points=settings.boundary_points),
        }

    _report(progress, "observer gain design")
    t_ref = np.linspace(0.0, s.simulation.t_final, 2001)
    speed = np.max(np.abs(s.trajectory.evaluate(t_ref)[1]), axis=0)
    bound = np.maximum(settings.speed_margin * speed, settings.min_speed)
    Y_s = s.observer_gain
    # lift the scenario's gain when it is symmetric positive semidefinite (then no mode gets slower)
    base = Y_s if np.allclose(Y_s, Y_s.T) and np.linalg.eigvalsh((Y_s + Y_s.T) / 2).min() >= 0 else None
    design = design_observer_gain(s.nominal, settings.observer_target_rad_s, q_grid, base=base)
    Y_design = design["Y"]
    out["observer_design"] = {
        "target_rad_s": settings.observer_target_rad_s, "base_is_scenario_gain": base is not None,
        "Y": Y_design.tolist(), "base": design["base"].tolist(), "M_ref": design["M_ref"].tolist(),
        "c_per_s": design["c_per_s"],
        "slowest_rad_s": design["slowest_rad_s"], "fastest_rad_s": design["fastest_rad_s"],
        "speed_bound": bound.tolist(), "reference_speed_max": speed.tolist(),
        "certificate_designed": convergence_certificate(s.nominal, Y_design, q_grid, bound),
        "certificate_scenario_gain": convergence_certificate(s.nominal, s.observer_gain, q_grid, bound),
        "critical_theta2_speed_designed": critical_speed(s.nominal, Y_design, q_grid, [0, 1, 0, 0]),
        "critical_theta2_speed_scenario_gain": critical_speed(s.nominal, s.observer_gain, q_grid, [0, 1, 0, 0]),
        "bandwidth_designed": {k: v for k, v in bandwidth_survey(s, Y=Y_design, points=settings.workspace_points)
                               .items() if k in ("theta2", "eigenvalues", "slowest_rad_s", "ranges_rad_s")},
    }
    _report(progress, "observer gain design: simulation", 0.5)
    out["observer_design"]["simulation"] = confirm_by_simulation(
        s, [("scenario gain", s.observer_gain), ("designed", Y_design)], t_final=_t_final(settings.design_t_final, s))

    _report(progress, "frequency responses")
    out["frequency"] = frequency_analysis(s, q_start)

    studies = {}
    for observer, key in ((True, "gains_with_dob"), (False, "gains_without_dob")):
        _report(progress, f"gain study {'with' if observer else 'without'} observer")
        studies[key] = gain_grid_study(s, settings.kp_values, settings.kd_values, observer,
                                       _t_final(settings.study_t_final, s), settings.workers)
    _report(progress, "observer gain and noise study")
    gains = [(f"Y = {v:g} I" + (" (scenario)" if np.allclose(v * np.eye(4), s.observer_gain) else ""), v)
             for v in settings.observer_values]
    if not any(label.endswith("(scenario)") for label, _ in gains):
        gains.insert(0, ("scenario Y (scenario)", s.observer_gain))
    gains.append(("designed Y", Y_design))
    obs = observer_gain_study(s, gains, t_final=_t_final(settings.noise_t_final, s), workers=settings.workers)
    obs["slowest_mode_rad_s"] = [None] + [
        float(np.real(observer_modes(s.nominal, gain_matrix(g, "observer", allow_matrix=True), q_grid)[0][:, 0]).min())
        for _, g in gains]
    studies["observer"] = obs
    out["studies"] = studies
    _report(progress, "analysis done", 1.0)
    return out


def write_figures(result: dict, out_dir, formats=figs.FORMATS) -> list[Path]:
    """Write every analysis figure of a :func:`run_analysis` result into ``out_dir`` (PNG and/or SVG)."""
    pd_slowest = min(-m["analytic_pole"][0] for m in result["operating_points"][0]["modes_without_dob"])
    design = result["observer_design"]
    files = []
    files += figs.pole_figure(result["operating_points"], out_dir, formats)
    files += figs.mismatch_figure(result["mismatch"], out_dir, formats)
    files += figs.bandwidth_figure(result["observer_bandwidth"], design["bandwidth_designed"], pd_slowest, out_dir,
                                   formats)
    files += figs.design_figure(design["simulation"], out_dir, formats)
    files += figs.bode_figure(result["frequency"], out_dir, "tracking", formats)
    files += figs.bode_figure(result["frequency"], out_dir, "estimation", formats)
    files += figs.gain_study_figure(result["studies"]["gains_with_dob"], result["studies"]["gains_without_dob"],
                                    out_dir, formats)
    files += figs.observer_study_figure(result["studies"]["observer"], out_dir, formats)
    return files


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def _dumps(result: dict) -> str:
    return json.dumps(result, indent=1, default=_json_default, allow_nan=False) + "\n"


def analyze(scenario: Scenario | str = "paper", out_dir=None, settings: AnalysisSettings = AnalysisSettings(),
            progress: Progress | None = None) -> tuple[dict, list[Path]]:
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
    (dict, list of pathlib.Path)
        The result (as written to ``analysis.json``) and the files written.
    """
    from .experiment import staged_output

    target = Path(out_dir)
    staging = staged_output(target)          # refuses a non-empty folder before any work is done
    result = run_analysis(scenario, settings, progress)
    with staging as stage:
        names = [p.name for p in write_figures(result, stage)]
        result["figures"] = names
        (stage / "analysis.json").write_text(_dumps(result))
    return result, sorted(target.iterdir())


# ---------------------------------------------------------------------------------------------------------------
# The HTML report


def _f(value, digits: int = 4) -> str:
    """A number for the report (significant digits), '-' for None, 'inf' for infinity."""
    if value is None:
        return "-"
    value = float(value)
    if math.isinf(value):
        return "inf"
    if value == 0:
        return "0"
    return f"{value:.{digits}g}"


def _join(values, digits: int = 4) -> str:
    """Numbers as a comma-separated list (see :func:`_f`)."""
    return ", ".join(_f(v, digits) for v in values)


def _pole(p) -> str:
    re, im = p
    if abs(im) < 1e-9 * max(1.0, abs(re)):
        return _f(re, 6)
    return f"{_f(re, 6)} {'+' if im > 0 else '-'} {_f(abs(im), 6)}j"


def _is_number(text: str) -> bool:
    try:
        float(text.replace(" ", "").split(",")[0].replace("+", "").rstrip("j") or "x")
        return True
    except ValueError:
        return text in ("-", "inf")


def _table(header: list, rows: list, caption: str | None = None) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)

    def cell(c):
        c = str(c)
        return f"<td class='num'>{html.escape(c)}</td>" if _is_number(c) else f"<td>{html.escape(c)}</td>"
    body = "".join("<tr>" + "".join(cell(c) for c in row) + "</tr>" for row in rows)
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"><figcaption>' \
           f"{html.escape(alt)}</figcaption></figure>"


def _tool_offset_mm(q_a, q_b, robot) -> float:
    p = forward_kinematics(np.array([q_a, q_b]), robot)
    return float(1e3 * np.linalg.norm(p[0, :3] - p[1, :3]))


def plain_summary(result: dict, experiment: dict, scenario: Scenario) -> list[str]:
    """Short statements, computed from the numbers, on what they mean for the surgeon's tool."""
    op = result["operating_points"][0]
    bw = result["observer_bandwidth"]
    design = result["observer_design"]
    sim = design["simulation"]
    lines = []
    w, wo = experiment["with_dob"], experiment["without_dob"]
    if "max_tool_position_error_mm" in w:
        lines.append(f"Along the scenario's path the tool tip strays at most "
                     f"{_f(w['max_tool_position_error_mm'], 3)} mm from where it should be with the disturbance "
                     f"observer, and {_f(wo['max_tool_position_error_mm'], 3)} mm without it (RMS "
                     f"{_f(w['rms_tool_position_error_mm'], 3)} mm against "
                     f"{_f(wo['rms_tool_position_error_mm'], 3)} mm).")
    offset = _tool_offset_mm(op["q_equilibrium_without_dob"], op["q0"], scenario.robot)
    depth = 1e3 * (op["q_equilibrium_without_dob"][2] - op["q0"][2])
    lines.append(f"Held still against the scenario's constant disturbance, the arm without the observer settles "
                 f"{_f(offset, 3)} mm away from its target ({_f(depth, 3)} mm of it along the tool axis, joint 3) "
                 f"and stays there for as long as the disturbance acts; the PD gains only scale this offset (1/Kp). "
                 f"With the observer the offset is zero: the tracking error has zero DC gain from every joint "
                 f"disturbance.")
    slow = bw["slowest_rad_s"]
    pd = min(-m["analytic_pole"][0] for m in op["modes_without_dob"])
    lines.append(f"How quickly the observer learns a new disturbance is set by its slowest mode, "
                 f"{_f(slow['min'], 3)} to {_f(slow['max'], 3)} rad/s across the workspace (time constant "
                 f"{_f(1 / slow['max'], 3)} to {_f(1 / slow['min'], 3)} s). This whole-arm mode is "
                 f"{_f(pd / slow['min'], 3)} times slower than the slowest tracking-loop pole ({_f(pd, 3)} rad/s): "
                 f"it is the observer, not Kp and Kd, that limits how fast a disturbance is rejected.")
    base, new = sim.get("scenario gain"), sim.get("designed")
    def within(run):
        t = run["convergence_time_s"]
        return f"after {_f(t, 3)} s" if t is not None else f"not within the {_f(run['time'][-1], 3)} s run"
    if base and new:
        lines.append(f"In simulation the estimate gets within {_f(100 * base['threshold'], 2)}% of the disturbance "
                     f"{within(base)} with the scenario's gain and {within(new)} with a designed matrix gain whose "
                     f"slowest mode is "
                     f"{_f(design['slowest_rad_s'], 3)} rad/s everywhere in the workspace "
                     f"(guaranteed decay rate {_f(design['certificate_designed']['beta_min_rad_s'], 3)} rad/s for "
                     f"joint speeds up to {_join(design['speed_bound'], 3)} rad/s, m/s).")
    obs = result["studies"]["observer"]
    labels = obs["labels"]
    runs = obs["runs"]
    k_ref = next((k for k, label in enumerate(labels) if label.endswith("(scenario)")), None)
    if "designed Y" in labels and k_ref is not None and runs[k_ref].get("ok") \
            and runs[labels.index("designed Y")].get("ok"):
        n_ref, n_new = runs[k_ref]["torque_noise_rms"], runs[labels.index("designed Y")]["torque_noise_rms"]
        lines.append(f"The price of the faster observer is torque noise: with the assumed sensor noise the joint "
                     f"torques jitter by {_join(n_new, 3)} (N m, N m, N, N m RMS) with the designed gain "
                     f"against {_join(n_ref, 3)} with the scenario's gain.")
    for key, name in (("with_dob", "with"), ("without_dob", "without")):
        b = result["mismatch"][key]["boundaries"]
        lo, hi = b["range"]
        if b["boundaries"]:
            edges = ", ".join(f"{_f(x['factor'], 4)} (stable {x['stable_side']})" for x in b["boundaries"])
            lines.append(f"Model error: {name} the observer the held loop loses stability when the nominal inertia is "
                         f"{edges} times the true one (searched {_f(lo)}x to {_f(hi)}x).")
        else:
            lines.append(f"Model error: {name} the observer the held loop stays stable for every nominal inertia from "
                         f"{_f(lo)}x to {_f(hi)}x the true one.")
    g_w, g_wo = result["studies"]["gains_with_dob"], result["studies"]["gains_without_dob"]
    ss_wo = [r["tool_mm"]["steady_state_error"] for row in g_wo["runs"] for r in row if r.get("ok")]
    ss_w = [r["tool_mm"]["steady_state_error"] for row in g_w["runs"] for r in row if r.get("ok")]
    ts_w = [r["tool_mm"]["settling_time_s"] for row in g_w["runs"] for r in row if r.get("ok")]
    if ss_wo and ss_w:
        settled = [t for t in ts_w if t is not None]
        lines.append(f"Gains: over Kp = {_join(g_w['kp'])} and Kd = {_join(g_w['kd'])}"
                     f", the end-of-run tool-tip error is {_f(min(ss_wo), 3)} to {_f(max(ss_wo), 3)} mm without the "
                     f"observer and at most {_f(max(ss_w), 3)} mm with it"
                     + (f"; with the observer the tool-tip error settles in {_f(min(settled), 3)} to "
                        f"{_f(max(settled), 3)} s" if settled else "") + ".")
    return lines


_CSS = """
body{font-family:Helvetica,Arial,sans-serif;max-width:1180px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:3px solid #246;padding-bottom:.3em} h2{border-bottom:1px solid #aaa;margin-top:2em;color:#246}
table{border-collapse:collapse;margin:.8em 0;font-size:.88em} caption{text-align:left;font-weight:bold;padding:.3em 0}
th,td{border:1px solid #bbb;padding:.25em .55em;text-align:left;vertical-align:top} th{background:#e8eef5}
td.num{text-align:right;white-space:nowrap} figure{margin:1em 0} img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.85em;color:#555} .summary{background:#f3f7ee;border-left:5px solid #6a4;padding:.6em 1.2em}
pre{background:#f6f6f6;padding:.8em;overflow-x:auto;font-size:.85em} .note{color:#555;font-size:.9em}
"""


def _section_scenario(s: Scenario, result: dict) -> str:
    rows = [["name", s.name], ["source", s.source], ["description", s.data.get("description", "")],
            ["Kp (1/s^2)", _join(np.diag(s.kp))], ["Kd (1/s)", _join(np.diag(s.kd))],
            ["observer gain Y (kg m^2/s)", np.array2string(s.observer_gain, precision=4, separator=", ")],
            ["observer variant", s.observer_variant], ["trajectory", s.data["trajectory"]["kind"]],
            ["disturbance", str(s.data["disturbance"]["kind"])],
            ["nominal model = true model", "yes" if s.nominal == s.robot else "no (see [nominal_scale])"],
            ["simulated time (s)", _f(s.simulation.t_final)]]
    return ("<h2>1. Scenario</h2>" + _table(["setting", "value"], rows)
            + f"<details><summary>complete scenario (TOML)</summary><pre>{html.escape(result['scenario']['toml'])}"
              "</pre></details>")


def _section_simulation(experiment: dict, files: dict) -> str:
    w, wo = experiment["with_dob"], experiment["without_dob"]
    units = [f"({u})" for u in JOINT_UNITS]
    rows = [["RMS position error, with observer"] + [_f(v) for v in w["rms_position_error"]],
            ["RMS position error, without observer"] + [_f(v) for v in wo["rms_position_error"]],
            ["largest position error, with observer"] + [_f(v) for v in w["max_abs_position_error"]],
            ["largest position error, without observer"] + [_f(v) for v in wo["max_abs_position_error"]],
            ["  units"] + units]
    if "rms_disturbance_error" in w:
        rows += [["RMS disturbance error d - d_hat, with observer"] + [_f(v) for v in w["rms_disturbance_error"]],
                 ["  units"] + [f"({u})" for u in DISTURBANCE_UNITS]]
    text = ("<h2>2. Simulation of the scenario (paper Figures 4-8, Table 3)</h2>"
            "<p>The nonlinear Figure-2 loop simulated with and without the observer. Table 3 of the paper lists RMS "
            "errors (Eq. 13-14) for its own laceration path, which the paper does not give; the table below has the "
            "same layout for this scenario's path.</p>"
            + _table(["Table 3 layout"] + [f"joint {i + 1} ({JOINT_LABELS[i]})" for i in range(4)], rows,
                     "Tracking metrics per joint"))
    if "max_tool_position_error_mm" in w:
        text += _table(["tool tip", "with observer", "without observer"],
                       [["largest position error (mm)", _f(w["max_tool_position_error_mm"]),
                         _f(wo["max_tool_position_error_mm"])],
                        ["RMS position error (mm)", _f(w["rms_tool_position_error_mm"]),
                         _f(wo["rms_tool_position_error_mm"])]])
    for stem, caption in (("fig4_joint_tracking", "Figure 4: joint tracking, with and without the observer"),
                          ("fig5_tracking_error", "Figure 5: tracking error q_ref - q"),
                          ("fig6_disturbance_estimate", "Figure 6: lumped disturbance d and its estimate d_hat"),
                          ("fig7_estimation_error", "Figure 7: estimation error d - d_hat"),
                          ("fig8_task_space", "Figure 8: tool-tip path in task space")):
        if stem in files:
            text += _img(files[stem], caption)
    return text


def _section_linear(result: dict, files: dict) -> str:
    text = ("<h2>3. Linearized closed loop</h2><p>The Figure-2 interconnection itself is linearized "
            "(<code>control.linearize</code>, central differences) with the arm held at q0, the scenario's constant "
            "disturbance acting and every block at equilibrium (with the observer: q = q0, d_hat = d). Each mode is "
            "assigned to the block that owns it by participation factors, computed with the observer described by its "
            "estimate d_hat. The analytic split on a perfect model is: roots of s^2 + Kd s + Kp per joint (plant / "
            "PD error dynamics) and eigenvalues of -Y M^-1(q0) (observer). Without the observer the arm rests off q0 "
            "(by M^-1 d / Kp) where M(q) differs slightly, so its poles deviate slightly from the ideal PD roots.</p>")
    ops = result["operating_points"]
    rows = []
    for op in ops:
        obs = sorted(-m["pole"][0] for m in op["modes_with_dob"] if m["block"] == "observer")
        pd = sorted({round(-m["pole"][0], 6) for m in op["modes_with_dob"] if m["block"] == "plant"})
        rows.append([op["label"], _join(op["q0"], 4), _join(obs, 5),
                     _join(pd, 5), _f(op["max_rel_error_with_dob"], 2),
                     _f(op["max_rel_error_without_dob"], 2),
                     "yes" if op["attribution_agrees_with_dob"] and op["attribution_agrees_without_dob"] else "no"])
    text += _table(["operating point", "q0 (rad, rad, m, rad)", "observer decay rates (rad/s)",
                    "plant (PD) decay rates (rad/s)", "largest rel. difference, with",
                    "largest rel. difference, without", "attribution agrees"], rows,
                   "All operating points (poles real unless listed below)")
    for op in ops[:1]:
        text += f"<h3>All modes at {html.escape(op['label'])}, q0 = [{_join(op['q0'], 5)}] " \
                f"(rad, rad, m, rad)</h3>"
        for key, title in (("with_dob", "with observer"), ("without_dob", "without observer")):
            rows = [[_pole(m["pole"]), _f(m["wn_rad_s"]), _f(m["zeta"]), _f(m["time_constant_s"]), m["block"],
                     _f(m["participation"].get(m["block"], 1.0), 3), _pole(m["analytic_pole"]),
                     m["analytic_block"], _f(m["rel_error_vs_analytic"], 2)] for m in op[f"modes_{key}"]]
            text += _table(["pole (rad/s)", "wn (rad/s)", "zeta", "time constant (s)", "block", "participation",
                            "analytic pole", "analytic block", "relative difference"], rows,
                           f"{title}: largest relative difference from the analytic split "
                           f"{_f(op[f'max_rel_error_{key}'], 2)}; attribution agrees with the analytic split: "
                           f"{'yes' if op[f'attribution_agrees_{key}'] else 'no'}")
    complex_ops = [op["label"] for op in ops for key in ("with_dob", "without_dob")
                   if any(abs(m["pole"][1]) > 0 for m in op[f"modes_{key}"])]
    if complex_ops:
        text += f"<p>Complex poles occur at: {html.escape(', '.join(sorted(set(complex_ops))))} (see the figure).</p>"
    first = ops[0]
    obs_rates = sorted(-m["pole"][0] for m in first["modes_with_dob"] if m["block"] == "observer")
    pd_rates = sorted(-m["pole"][0] for m in first["modes_with_dob"] if m["block"] == "plant")
    text += (f"<p><b>Reading.</b> With the observer the slowest closed-loop mode is the observer's "
             f"{_f(obs_rates[0], 4)} rad/s (time constant {_f(1 / obs_rates[0], 3)} s), "
             f"{_f(pd_rates[0] / obs_rates[0], 3)} times slower than the slowest PD mode ({_f(pd_rates[0], 4)} "
             "rad/s). On a perfect model the loop is "
             "block-triangular (the observer error drives the tracking error, not the reverse): Kp and Kd place the "
             "plant poles and Y places the observer poles, independently.</p>")
    if "linear_poles" in files:
        text += _img(files["linear_poles"], "Closed-loop poles (o: linearized, x: analytic split)")
    mm = result["mismatch"]
    text += (f"<h3>Inertia mismatch (nominal inertia M^ = a M)</h3><p>All nominal masses and inertias are scaled by a "
             f"at q0 = [{_join(mm['q0'], 5)}]. The stability boundary is found by a logarithmic scan "
             f"and bisection on a.</p>")
    rows = []
    for key, title in (("with_dob", "with observer"), ("without_dob", "without observer")):
        sweep = mm[key]["sweep"]
        b = mm[key]["boundaries"]
        for a, alpha, poles in zip(sweep["factors"], sweep["spectral_abscissa"], sweep["poles"]):
            rows.append([title, _f(a, 4), _f(alpha, 5), _f(min(-p[0] for p in poles), 4),
                         _f(max(-p[0] for p in poles), 4), _f(min(-p[0] / math.hypot(*p) for p in poles), 4)])
        edges = "; ".join(f"a = {_f(x['factor'], 6)} (stable {x['stable_side']})" for x in b["boundaries"]) or \
            f"none in {_f(b['range'][0])} to {_f(b['range'][1])}"
        text += f"<p><b>Stability boundary {title}:</b> {html.escape(edges)}.</p>"
    text += _table(["loop", "a", "largest real part (rad/s)", "slowest decay (rad/s)", "fastest decay (rad/s)",
                    "smallest damping ratio"], rows, "Poles against inertia mismatch")
    sw = mm["with_dob"]["sweep"]
    slow = [min(-p[0] for p in poles) for poles in sw["poles"]]
    text += (f"<p><b>Reading.</b> Over a = {_f(min(sw['factors']), 3)} to {_f(max(sw['factors']), 3)} the slowest mode "
             f"with the observer decays at {_f(min(slow), 4)} to {_f(max(slow), 4)} rad/s: an overestimated inertia "
             "(a &gt; 1) slows the observer (its modes scale like Y (a M)^-1), an underestimated one speeds it up but "
             "lowers the damping, and far enough below 1 the loop with the observer goes unstable.</p>")
    if "linear_mismatch" in files:
        text += _img(files["linear_mismatch"], "Stability and pole movement against inertia mismatch")
    return text


def _section_bandwidth(result: dict, files: dict) -> str:
    bw = result["observer_bandwidth"]
    s = bw["slowest_rad_s"]
    rows = [[f"mode {k + 1}", _f(lo, 4), _f(hi, 4), _f(1 / hi, 3), _f(1 / lo, 3)] for k, (lo, hi) in
            enumerate(bw["ranges_rad_s"])]
    sens = ", ".join(f"{k}: {_f(v, 3)}" for k, v in bw["sensitivity_rad_s"].items())
    at = bw["along_trajectory"]
    text = ("<h2>4. Observer bandwidth across the workspace</h2><p>On a perfect model the estimation error obeys "
            "e_d' = -Y M^-1(q) e_d: the observer's modes decay at the eigenvalues of Y M^-1(q). They were computed "
            f"on a {' x '.join(str(n) for n in bw['grid']['points'])} grid over all four joints.</p>"
            + _table(["mode", "min (rad/s)", "max (rad/s)", "time constant min (s)", "time constant max (s)"], rows,
                     "Eigenvalues of Y M^-1(q) over the workspace")
            + f"<p>Slowest mode: {_f(s['min'], 4)} rad/s at q = [{_join(s['q_at_min'], 4)}], "
              f"{_f(s['max'], 4)} rad/s at q = [{_join(s['q_at_max'], 4)}]. Along the scenario's "
              f"path it is {_f(at['min'], 4)} to {_f(at['max'], 4)} rad/s; its direction in disturbance space there is "
              f"[{_join(at['direction_at_min'], 3)}] (theta1, theta2, d3, theta4): a whole-arm mode. "
              f"Largest change of any eigenvalue along each joint axis of the grid (rad/s): {html.escape(sens)}.</p>")
    lo_all, hi_all = bw["ranges_rad_s"][0][0], bw["ranges_rad_s"][-1][1]
    Y = np.array(bw["Y"])
    scalar = np.allclose(Y, Y[0, 0] * np.eye(4))
    text += ("<p><b>Reading.</b> "
             + (f"A gain Y = {_f(Y[0, 0])} I does not give one bandwidth of {_f(Y[0, 0])} rad/s: " if scalar else "")
             + f"the observer's rates are the gain divided by the inertia seen in each modal direction, from "
               f"{_f(lo_all, 4)} rad/s (the heavy whole-arm rotation) to {_f(hi_all, 4)} rad/s. A disturbance that "
               f"acts along the slow direction is learnt with a time constant of about {_f(1 / lo_all, 3)} s.</p>")
    if "observer_bandwidth" in files:
        text += _img(files["observer_bandwidth"], "Observer modes along theta2 and the slowest mode's direction")
    return text


def _matrix(M) -> str:
    return _table([""] + [f"col {j + 1}" for j in range(len(M))],
                  [[f"row {i + 1}"] + [_f(v, 5) for v in row] for i, row in enumerate(M)])


def _section_design(result: dict, files: dict) -> str:
    d = result["observer_design"]
    cd, cs = d["certificate_designed"], d["certificate_scenario_gain"]
    crit_d, crit_s = d["critical_theta2_speed_designed"], d["critical_theta2_speed_scenario_gain"]
    ranges = d["bandwidth_designed"]["ranges_rad_s"]
    start = "the scenario's gain Y_s plus" if d["base_is_scenario_gain"] else ""
    text = ("<h2>5. Observer gain design</h2>"
            f"<p>Target: slowest observer mode at least {_f(d['target_rad_s'])} rad/s everywhere in the workspace. "
            f"Design: Y = {start} c M_ref, with M_ref the nominal inertia averaged over the workspace grid (it has the "
            f"shape of M, so it lifts the slow whole-arm mode most) and c = {_f(d['c_per_s'], 6)} 1/s the smallest "
            f"value meeting the target on the grid (bisection). "
            + ("Because Y_s is symmetric positive semidefinite, no mode is slower than with Y_s (Weyl's inequality). "
               if d["base_is_scenario_gain"] else "")
            + f"Modes of Y M^-1(q) over the workspace: {', '.join(_f(lo, 4) + '-' + _f(hi, 4) for lo, hi in ranges)}"
              " rad/s.</p>"
            + "<p>Designed Y (kg m^2/s, kg/s for joint 3):</p>" + _matrix(d["Y"])
            + "<p>Convergence condition of Mohammadi et al. (2013): Y + Y' - M'(q, q') >= 2 beta M(q) gives "
              "V(t) <= V(0) exp(-2 beta t) with V = e_d' Y^-T M Y^-1 e_d. The certificate is the smallest beta over "
              "the grid and every vertex of the joint-speed box |q'| <= bound (exact for the grid: beta is concave in "
              "q').</p>"
            + _table(["", "scenario gain", "designed gain"],
                     [["speed bound (rad/s, rad/s, m/s, rad/s)", _join(d["speed_bound"], 3),
                       _join(d["speed_bound"], 3)],
                      ["certificate beta_min (rad/s)", _f(cs["beta_min_rad_s"], 5), _f(cd["beta_min_rad_s"], 5)],
                      ["  reached at q", _join(cs["q_at"], 4), _join(cd["q_at"], 4)],
                      ["  and q'", _join(cs["dq_at"], 3), _join(cd["dq_at"], 3)],
                      ["condition holds", "yes" if cs["holds"] else "no", "yes" if cd["holds"] else "no"],
                      ["beta at rest, min (rad/s)", _f(cs["beta_at_rest_min_rad_s"], 5),
                       _f(cd["beta_at_rest_min_rad_s"], 5)],
                      ["largest |theta2'| keeping beta > 0 (rad/s)", _f(crit_s["speed_factor"], 5),
                       _f(crit_d["speed_factor"], 5)]], "Convergence certificate"))
    rows = [[label, _f(run["beta_run_rad_s"], 4), _f(run["convergence_time_s"], 4),
             _join(run["rms_disturbance_error"], 3), "yes" if run["bound_holds"] else "no"]
            for label, run in d["simulation"].items()]
    text += _table(["gain", "beta over the visited states (rad/s)", "time to 2% (s)",
                    "RMS d - d_hat (N m, N m, N, N m)", "V(t) <= V(0) exp(-2 beta t)"], rows,
                   "Nonlinear simulation of the scenario with each gain")
    if "observer_design" in files:
        text += _img(files["observer_design"], "Estimation error and Lyapunov certificate in simulation")
    return text


def _section_frequency(result: dict, files: dict) -> str:
    fr = result["frequency"]
    text = ("<h2>6. Disturbance rejection in frequency</h2>"
            f"<p>Transfer functions of the loop linearized with the arm held at q0 = "
            f"[{_join(fr['q0'], 5)}], from a torque/force w[i] added at joint i to the tracking error "
            "e[i] = q_ref[i] - q[i] and to the estimation error. Closed forms (perfect model): without observer "
            "E = -(s^2 + Kd s + Kp)^-1 M^-1 W; with observer E = -s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1 W and "
            "E_d = s M (s M + Y)^-1 W.</p>")
    rows = []
    for key, title in (("tracking_with_dob", "e, with observer"), ("tracking_without_dob", "e, without observer"),
                       ("estimation_with_dob", "d - d_hat, with observer")):
        data = fr[key]
        unit_key = "estimation" if key.startswith("estimation") else "tracking"
        for i, m in enumerate(data["metrics"]):
            band = m["band_3db_rad_s"]
            dc = m["dc_gain"] if abs(m["dc_gain"]) > 1e-9 * m["peak_gain"] else 0.0     # rounding noise shown as 0
            peak_at = "inf" if m["peak_rad_s"] is None else \
                ("0 (DC)" if m["peak_rad_s"] == 0 else _f(m["peak_rad_s"], 4))
            rows.append([title, f"joint {i + 1}", fr["units"][unit_key][i], _f(dc, 4), _f(m["peak_gain"], 4), peak_at,
                         m["kind"],
                         f"{_f(band[0], 4)} to {'inf' if band[1] is None else _f(band[1], 4)}"])
        rows.append([title, "closed form", "", "", "", "", "largest relative difference",
                     _f(data["closed_form_max_rel_error"], 2)])
    text += _table(["response", "joint", "unit", "DC gain", "peak gain", "peak at (rad/s)", "kind",
                    "-3 dB band (rad/s)"], rows, "Per-joint disturbance responses")
    wo, w, est = (fr[k]["metrics"] for k in ("tracking_without_dob", "tracking_with_dob", "estimation_with_dob"))
    text += ("<p>Without the observer the arm rests off q0 (section 3), so the frozen-q0 closed form is only "
             f"approximate there (largest relative difference "
             f"{_f(fr['tracking_without_dob']['closed_form_max_rel_error'], 2)}). <b>Reading.</b> A constant force of "
             f"1 N on the prismatic joint leaves {_f(-1e3 * wo[2]['dc_gain'], 4)} mm of depth error without the "
             "observer and none with it. With the observer, disturbances are passed to the "
             f"tracking error only in a band around {', '.join(_f(m['peak_rad_s'], 3) for m in w)} rad/s (joints 1-4; "
             f"at most {', '.join(_f(m['peak_gain'], 3) for m in w)} per unit disturbance): slower ones are estimated "
             "and cancelled, faster ones are filtered by the arm's inertia. The estimate follows a disturbance only "
             f"below {', '.join(_f(m['band_3db_rad_s'][0], 3) for m in est)} rad/s (joints 1-4; -3 dB), the observer "
             "bandwidth seen from each joint.</p>")
    for stem, caption in (("frequency_tracking", "Disturbance to tracking error, per joint"),
                          ("frequency_estimation", "Disturbance to estimation error, per joint")):
        if stem in files:
            text += _img(files[stem], caption)
    return text


def _section_studies(result: dict, files: dict) -> str:
    st = result["studies"]
    text = ("<h2>7. Gain and noise studies</h2><p>Nonlinear simulations of the scenario "
            f"({_f(st['gains_with_dob']['t_final_s'])} s runs) over a grid of scalar gains, the same on every joint. "
            "Tool-tip position error in mm. Settling time: from then on the error stays within 2% of its largest "
            "deviation from the end-of-run value (mean over the last 10% of the run); '-' means not settled within the "
            "run. Steady-state error: that end-of-run value.</p>")
    rows = []
    for key, title in (("gains_with_dob", "with"), ("gains_without_dob", "without")):
        g = st[key]
        for i, kp in enumerate(g["kp"]):
            for j, kd in enumerate(g["kd"]):
                r = g["runs"][i][j]
                if not r.get("ok"):
                    rows.append([title, _f(kp), _f(kd), "failed", "", "", ""])
                    continue
                m = r["tool_mm"]
                rows.append([title, _f(kp), _f(kd), _f(m["settling_time_s"], 3), _f(m["steady_state_error"], 3),
                             _f(m["peak_error"], 3), _f(m["rms_error"], 3)])
    if "study_gains" in files:
        text += _img(files["study_gains"], "Gain study heat maps (the numbers are in the table below)")
    text += ("<details><summary>Kp x Kd study as a table</summary>"
             + _table(["observer", "Kp (1/s^2)", "Kd (1/s)", "settling time (s)", "steady-state (mm)", "peak (mm)",
                       "RMS (mm)"], rows, "Kp x Kd study (tool tip)") + "</details>")
    text += _gain_reading(st)
    obs = st["observer"]
    noise = obs["noise"]
    text += (f"<p>Observer gain and measurement noise ({_f(obs['t_final_s'])} s runs): noise on q with standard "
             f"deviations {_join(noise['q_std'])} (rad, rad, m, rad) and on q' with "
             f"{_join(noise['dq_std'])} (rad/s, rad/s, m/s, rad/s), sampled every "
             f"{_f(noise.get('sample_period', 0.001))} s, seed {noise.get('seed', 0)}. Torque noise = RMS of the "
             "torque difference between the noisy and the clean run.</p>")
    rows = []
    for k, label in enumerate(obs["labels"]):
        r = obs["runs"][k]
        if not r.get("ok"):
            rows.append([label, "failed"] + [""] * 6)
            continue
        m = r["tool_mm"]
        rows.append([label, _f(obs["slowest_mode_rad_s"][k], 4), _f(m["settling_time_s"], 3), _f(m["peak_error"], 3),
                     _f(m["rms_error"], 3), _f(r["noisy"]["tool_mm"]["rms_error"], 3)]
                    + [_join(r["torque_noise_rms"], 3)])
    text += _table(["observer gain", "slowest mode (rad/s)", "settling (s)", "peak (mm)", "RMS (mm)",
                    "RMS with noise (mm)", "torque noise RMS (N m, N m, N, N m)"], rows,
                   "Observer gain study (tool tip)")
    ok = [k for k, r in enumerate(obs["runs"]) if r.get("ok") and obs["labels"][k] != "none"]
    if ok and obs["runs"][0].get("ok"):
        base = obs["runs"][0]["torque_noise_rms"]
        fastest = max(ok, key=lambda k: obs["slowest_mode_rad_s"][k])
        slowest = min(ok, key=lambda k: obs["slowest_mode_rad_s"][k])
        ratio = [n / b if b > 0 else float("nan") for n, b in zip(obs["runs"][fastest]["torque_noise_rms"], base)]
        text += (f"<p><b>Reading.</b> From the slowest observer tested ({html.escape(obs['labels'][slowest])}) to the "
                 f"fastest ({html.escape(obs['labels'][fastest])}) the peak tool-tip error falls from "
                 f"{_f(obs['runs'][slowest]['tool_mm']['peak_error'], 3)} to "
                 f"{_f(obs['runs'][fastest]['tool_mm']['peak_error'], 3)} mm, while the torque noise grows to "
                 f"{', '.join(_f(r, 3) for r in ratio)} times its value without the observer (joints 1-4): the "
                 "observer feeds the velocity noise to the torque through d_hat = Y q' + z, which matters most on "
                 "the light prismatic joint.</p>")
    if "study_observer" in files:
        text += _img(files["study_observer"], "Error against torque noise for each observer gain")
    return text


def _gain_reading(st: dict) -> str:
    """Computed observations on the Kp x Kd study."""
    def cells(key):
        g = st[key]
        return [(kp, kd, g["runs"][i][j]["tool_mm"]) for i, kp in enumerate(g["kp"]) for j, kd in enumerate(g["kd"])
                if g["runs"][i][j].get("ok")]
    w, wo = cells("gains_with_dob"), cells("gains_without_dob")
    if not w or not wo:
        return ""
    by_kp = {}
    for kp, _, m in wo:
        by_kp.setdefault(kp, []).append(m["steady_state_error"])
    offsets = ", ".join(f"{_f(np.mean(v), 3)} mm at Kp = {_f(kp)}" for kp, v in sorted(by_kp.items()))
    settled = [c for c in w if c[2]["settling_time_s"] is not None]
    text = (f"<p><b>Reading.</b> Without the observer the end-of-run tool-tip error is set by Kp alone ({offsets}): "
            f"Kd hardly changes it. With the observer it is at most "
            f"{_f(max(c[2]['steady_state_error'] for c in w), 3)} mm for every pair, and the gains trade transient "
            "against speed: ")
    best_peak = min(w, key=lambda c: c[2]["peak_error"])
    text += f"the smallest peak error is {_f(best_peak[2]['peak_error'], 3)} mm (Kp = {_f(best_peak[0])}, " \
            f"Kd = {_f(best_peak[1])})"
    if settled:
        best_ts = min(settled, key=lambda c: c[2]["settling_time_s"])
        text += f", the shortest settling time {_f(best_ts[2]['settling_time_s'], 3)} s (Kp = {_f(best_ts[0])}, " \
                f"Kd = {_f(best_ts[1])})"
    best_rms = min(w, key=lambda c: c[2]["rms_error"])
    return text + f", the smallest RMS error {_f(best_rms[2]['rms_error'], 3)} mm (Kp = {_f(best_rms[0])}, " \
                  f"Kd = {_f(best_rms[1])}).</p>"


def render_html(result: dict, experiment: dict, scenario: Scenario, figure_files: dict) -> str:
    """The report as one HTML string (figures embedded from the PNG files named in ``figure_files``)."""
    summary = "".join(f"<li>{html.escape(line)}</li>" for line in plain_summary(result, experiment, scenario))
    body = (f"<h1>dobkit analysis report: scenario '{html.escape(scenario.name)}'</h1>"
            f"<p class='note'>dobkit {html.escape(result['dobkit_version'])}, python-control "
            f"{html.escape(result['python_control_version'])}. Regenerate with <code>dobkit report --scenario "
            f"{html.escape(scenario.source)}</code>. Every number below is computed from the scenario.</p>"
            "<div class='summary'><h2 style='margin-top:.4em'>Summary for the surgical team</h2>"
            f"<ul>{summary}</ul></div>"
            + _section_scenario(scenario, result) + _section_simulation(experiment, figure_files)
            + _section_linear(result, figure_files) + _section_bandwidth(result, figure_files)
            + _section_design(result, figure_files) + _section_frequency(result, figure_files)
            + _section_studies(result, figure_files))
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>dobkit report: "
            f"{html.escape(scenario.name)}</title><style>{_CSS}</style></head><body>{body}</body></html>\n")


def write_report(scenario: Scenario | str = "paper", out_dir=None, settings: AnalysisSettings = AnalysisSettings(),
                 progress: Progress | None = None) -> Path:
    """Simulate, analyze and write ``out_dir/report.html`` (plus ``analysis.json``, ``metrics.json`` and figures).

    Returns
    -------
    pathlib.Path
        The report file.
    """
    from .experiment import run_experiment, staged_output
    from .figures import paper_figures

    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    target = Path(out_dir)
    with staged_output(target) as stage:
        experiment = run_experiment(s, None, progress=progress, figures=False)
        result = run_analysis(s, settings, progress)
        _report(progress, "writing figures and report")
        fig_dir = stage / "figures"
        # PNG only: the report embeds PNG (the analyze command writes SVG too)
        files = paper_figures(experiment.with_dob, experiment.without_dob, fig_dir) \
            + write_figures(result, fig_dir, formats=("png",))
        result["figures"] = [f"figures/{p.name}" for p in files]
        (stage / "analysis.json").write_text(_dumps(result))
        (stage / "metrics.json").write_text(_dumps(experiment.metrics))
        pngs = {p.stem: p for p in files if p.suffix == ".png"}
        (stage / "report.html").write_text(render_html(result, experiment.metrics, s, pngs), encoding="utf-8")
    return target / "report.html"
