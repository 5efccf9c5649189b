"""What the analysis report shows: its numbers and statements, computed from the typed results.

:func:`build_view` turns an :class:`~analysis.report.AnalysisResult`, the
experiment's metrics and the scenario into a :class:`ReportView`: formatted
numbers, tables, figures (embedded as base64 PNG) and the statements that
interpret the numbers ("the observer limits the rejection speed", "the loop
goes unstable below ...").  Such statements are generated from the result and
only made when the result supports them; otherwise the number is stated
plainly.  The templates of :mod:`analysis.report_html` only lay the view out
(and escape every text).

:func:`plain_summary` gives the short statements for the surgical team.
"""
from __future__ import annotations

import base64
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blocks import forward_kinematics, inertia
from blocks.metrics import DISTURBANCE_UNITS, JOINT_LABELS, JOINT_UNITS
from blocks.scenario import Scenario

__all__ = ["ReportView", "Table", "Figure", "Paragraph", "build_view", "plain_summary", "worse_with_observer",
           "stability_text", "split_caveats", "fmt"]

# A component of a unit mode direction at least this large counts as "the mode moves this joint".
MODE_SHARE = 0.1
# Relative size below which a computed DC gain or offset is called zero.
ZERO_REL = 1e-6


# ---------------------------------------------------------------------------------------------------------------
# Number formatting


def fmt(value, digits: int = 4) -> str:
    """A number for the report (significant digits), '-' for None, 'inf' for infinity, 'nan' for NaN."""
    if value is None:
        return "-"
    value = float(value)
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if value == 0:
        return "0"
    return f"{value:.{digits}g}"


_f = fmt


def _join(values, digits: int = 4) -> str:
    """Numbers as a comma-separated list (see :func:`fmt`)."""
    return ", ".join(_f(v, digits) for v in values)


def _span(lo, hi, digits: int = 3) -> str:
    """'a to b', or 'a' when both print the same."""
    a, b = _f(lo, digits), _f(hi, digits)
    return a if a == b else f"{a} to {b}"


def _settling(value, digits: int = 3) -> str:
    return "not settled" if value is None else _f(value, digits)


def _pole(p: complex) -> str:
    if abs(p.imag) < 1e-9 * max(1.0, abs(p.real)):
        return _f(p.real, 6)
    return f"{_f(p.real, 6)} {'+' if p.imag > 0 else '-'} {_f(abs(p.imag), 6)}j"


def _is_number(text: str) -> bool:
    """Whether a table cell holds a number (right-aligned in the page)."""
    try:
        float(text.replace(" ", "").split(",")[0].replace("+", "").rstrip("j") or "x")
        return True
    except ValueError:
        return text in ("-", "inf", "not settled")


def _yes_no(value) -> str:
    return "n/a (no error at the start)" if value is None else ("yes" if value else "no")


# ---------------------------------------------------------------------------------------------------------------
# The pieces a page is made of


@dataclass(frozen=True)
class Cell:
    """One table cell: its text and whether it is a number."""

    text: str
    numeric: bool


@dataclass(frozen=True)
class Table:
    """A table: header texts, rows of cells, an optional caption."""

    header: list[str]
    rows: list[list[Cell]]
    caption: str | None = None

    @classmethod
    def of(cls, header, rows, caption: str | None = None) -> "Table":
        """A table from header and row texts; number cells are recognized."""
        return cls([str(h) for h in header], [[Cell(str(c), _is_number(str(c))) for c in row] for row in rows],
                   caption)


@dataclass(frozen=True)
class Figure:
    """An embedded PNG figure: caption (also its alt text) and ``data:`` URI."""

    caption: str
    data_uri: str


@dataclass(frozen=True)
class Paragraph:
    """A paragraph of plain text, optionally led by a bold word."""

    text: str
    lead: str | None = None


def _figures(files: dict, *items: tuple[str, str]) -> list[Figure]:
    """The figures among ``(stem, caption)`` items that were written (``files``: stem -> PNG path), in order."""
    return [Figure(caption, "data:image/png;base64," + base64.b64encode(Path(files[stem]).read_bytes()).decode("ascii"))
            for stem, caption in items if stem in files]


# ---------------------------------------------------------------------------------------------------------------
# Words for numbers


def _joints(indices) -> str:
    """'joint 3', 'joints 1 and 2', 'joints 1, 2 and 4' (0-based indices in)."""
    names = [str(i + 1) for i in indices]
    if len(names) == 1:
        return f"joint {names[0]}"
    return f"joints {', '.join(names[:-1])} and {names[-1]}"


def _mode_text(direction) -> str:
    """What a unit mode direction (disturbance space) moves: 'joint 3 alone' or 'joints 1, 2 and 4 together'."""
    v = np.abs(np.asarray(direction, dtype=float))
    idx = [i for i in range(len(v)) if v[i] >= MODE_SHARE]
    return f"{_joints(idx)} alone" if len(idx) == 1 else f"{_joints(idx)} together"


def _value(x, j: int, digits: int = 3) -> str:
    """A joint quantity with its unit."""
    return f"{_f(x, digits)} {JOINT_UNITS[j]}"


def _tool_offset_mm(q_a, q_b, robot) -> float:
    p = forward_kinematics(np.array([q_a, q_b], dtype=float), robot)
    return float(1e3 * np.linalg.norm(p[0, :3] - p[1, :3]))


def _kinds(kind) -> list[str]:
    """The disturbance kinds of a scenario's data as a list (empty for "none")."""
    if kind == "none":
        return []
    return [kind] if isinstance(kind, str) else list(kind)


def _and(words) -> str:
    words = list(words)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


STATE_DEPENDENT = {"friction": "friction depends on the joint velocities",
                   "tissue": "the tissue force depends on the tool's position and velocity"}


def split_caveats(result, scenario: Scenario, observer: bool) -> list[str]:
    """Why the perfect-model analytic forms (pole split, closed-form responses) may not hold for this scenario."""
    reasons = []
    if scenario.nominal != scenario.robot:
        reasons.append("the nominal model differs from the true one")
    reasons += [STATE_DEPENDENT[k] for k in _kinds(scenario.data["disturbance"]["kind"]) if k in STATE_DEPENDENT]
    op = result.operating_points[0]
    if not observer and np.max(np.abs(np.subtract(op.q_equilibrium_without_dob, op.q0))) > 0:
        reasons.append("the arm rests off q0 (by M^-1 d / Kp), where M(q) differs")
    return reasons


def stability_text(boundaries, subject: str, perfect_model: bool = True, prefix: str = "Model error: ") -> str:
    """A sentence on where a loop is stable over the inertia factors searched, from a boundary search result.

    Parameters
    ----------
    boundaries : analysis.linear.BoundarySearch
    subject : str
        What the sentence is about, e.g. "with the observer the held loop".
    perfect_model : bool
        Whether the scenario's nominal model is the true one (then the factor
        ``a`` is nominal/true inertia; otherwise it scales the scenario's nominal inertia).
    """
    lo, hi = boundaries.range
    found = boundaries.factors
    first_stable = boundaries.stable_at_low_end
    ref = "the true one" if perfect_model else "the scenario's nominal inertia, which itself differs from the true one"
    if not found:
        state = "stays stable" if first_stable else "is unstable"
        return (f"{prefix}{subject} {state} for every nominal inertia from {_f(lo)} to {_f(hi)} times {ref}: no "
                "stability boundary in the range searched.")
    edges = [lo] + found + [hi]
    stable, parts = first_stable, []
    for a, b in zip(edges[:-1], edges[1:]):
        parts.append(f"{'stable' if stable else 'unstable'} for a nominal inertia from {_f(a, 4)} to {_f(b, 4)}")
        stable = not stable
    return (f"{prefix}{subject} is " + ", ".join(parts) + f" times {ref}; it changes stability at a = "
            + ", ".join(_f(a, 6) for a in found) + f" (searched {_f(lo)} to {_f(hi)}).")


# ---------------------------------------------------------------------------------------------------------------
# Computed statements


def worse_with_observer(result, experiment: dict, scenario: Scenario) -> list[str]:
    """One statement per joint whose RMS position error along the path is larger with the observer than without.

    The explanation is built from the numbers: the offset the disturbance leaves
    on the joint without the observer (held at the path's start, ``M^-1 d / Kp``)
    against what the joint's own disturbance alone would leave, and whether the
    error with the observer is a start-up transient (largest early in the run,
    small at its end) while the observer learns the disturbance at the rate of
    its slowest mode along the path.
    """
    w, wo = experiment["with_dob"], experiment["without_dob"]
    op = result.operating_points[0]
    at = result.observer_bandwidth.along_trajectory
    q0 = np.asarray(op.q0, dtype=float)
    offset = np.asarray(op.q_equilibrium_without_dob, dtype=float) - q0
    d = np.asarray(op.disturbance_at_rest, dtype=float)
    own = np.abs(np.diag(np.linalg.inv(inertia(q0, scenario.nominal))) * d) / np.diag(scenario.kp)
    duration = experiment.get("duration_s")
    t_max = w.get("time_of_max_abs_position_error")
    lines = []
    for j in range(4):
        r_w, r_wo = w["rms_position_error"][j], wo["rms_position_error"][j]
        if not r_w > r_wo:
            continue
        text = (f"On joint {j + 1} ({JOINT_LABELS[j]}) the observer makes the position error along the path worse: "
                f"RMS {_value(r_w, j)} with it against {_value(r_wo, j)} without.")
        if np.max(np.abs(d)) > 0:
            text += (f" Held at the path's start, the disturbance leaves this joint only {_value(abs(offset[j]), j)} "
                     "off without the observer (M^-1 d / Kp)")
            if abs(offset[j]) < 0.5 * own[j]:
                text += (f": through the arm's coupled inertia the disturbances on the other joints nearly cancel "
                         f"this joint's own, which alone would leave {_value(own[j], j)}")
            text += "."
        peak, final = w["max_abs_position_error"][j], w["final_abs_position_error"][j]
        early = t_max is not None and duration is not None and t_max[j] <= 0.5 * duration
        if early and final < 0.5 * peak:
            text += (f" With the observer the error is a start-up transient: the observer starts from d_hat = 0 and "
                     f"learns the disturbance at the rate of its modes, the slowest {_f(at.min, 3)} to "
                     f"{_f(at.max, 3)} rad/s along the path (time constant up to {_f(1 / at.min, 3)} s), and the "
                     f"part not yet learned moves this joint by up to {_value(peak, j)} (at t = {_f(t_max[j], 3)} s; "
                     f"{_value(final, j)} at the end of the run).")
        else:
            text += (f" With the observer the error reaches {_value(peak, j)}"
                     + (f" at t = {_f(t_max[j], 3)} s" if t_max is not None else "")
                     + f" and is {_value(final, j)} at the end of the run.")
        lines.append(text)
    return lines


def _held_offset(result, scenario: Scenario) -> str:
    op = result.operating_points[0]
    d = np.asarray(op.disturbance_at_rest, dtype=float)
    kinds = _kinds(scenario.data["disturbance"]["kind"])
    if not np.max(np.abs(d)) > 0:
        why = (f"the scenario's disturbance models ({_and(kinds)}) give zero force on the arm at rest there" if kinds
               else "the scenario has no disturbance model")
        return (f"Held still at the path's start the arm feels no disturbance: {why}, so a held arm has no offset with "
                "or without the observer. The design check and the studies below apply a constant disturbance step "
                "instead.")
    text = ""
    stable_wo = op.largest_real_part(False) < 0
    offset = _tool_offset_mm(op.q_equilibrium_without_dob, op.q0, scenario.robot)
    depth = 1e3 * (op.q_equilibrium_without_dob[2] - op.q0[2])
    if stable_wo:
        text += (f"Held still at the path's start against the disturbance it feels there, the arm without the observer "
                 f"settles {_f(offset, 3)} mm away from its target ({_f(depth, 3)} mm of it along the tool axis, joint "
                 "3) and stays there for as long as the disturbance acts; the offset is M^-1 d / Kp, so a larger Kp "
                 "shrinks it and Kd does not change it.")
    else:
        text += (f"Held still at the path's start, the loop without the observer is unstable (largest pole real part "
                 f"{_f(op.largest_real_part(False), 4)} rad/s).")
    stable_w = op.largest_real_part(True) < 0
    offset_w = _tool_offset_mm(op.q_equilibrium_with_dob, op.q0, scenario.robot)
    metrics = result.frequency.tracking_with_dob.metrics
    dc_rel = max(abs(m.dc_gain) / m.peak_gain if m.peak_gain > 0 else 0.0 for m in metrics)
    if not stable_w:
        text += (f" With the observer the held loop is unstable at this configuration (largest pole real part "
                 f"{_f(op.largest_real_part(True), 4)} rad/s).")
    elif offset_w <= ZERO_REL * max(offset, 1e-3) and dc_rel <= ZERO_REL:
        text += (f" With the observer the arm rests on its target (offset {_f(offset_w, 2)} mm): the linearized "
                 f"tracking error has zero DC gain from every joint disturbance (largest |DC gain| / peak gain "
                 f"{_f(dc_rel, 2)}).")
    else:
        text += (f" With the observer the held arm rests {_f(offset_w, 3)} mm from its target (largest |DC gain| / "
                 f"peak gain of the tracking error {_f(dc_rel, 3)}).")
    return text


def _speed_statement(result, scenario: Scenario) -> str:
    slow = result.observer_bandwidth.slowest_rad_s
    pd = result.operating_points[0].pd_slowest_analytic_rad_s()
    text = (f"How quickly the observer learns a new disturbance is set by its slowest mode, {_f(slow.min, 3)} to "
            f"{_f(slow.max, 3)} rad/s across the workspace (time constant {_f(1 / slow.max, 3)} to "
            f"{_f(1 / slow.min, 3)} s), a mode that moves {_mode_text(slow.direction_at_min)}. ")
    if slow.max < pd:
        text += (f"It is {_f(pd / slow.max, 3)} to {_f(pd / slow.min, 3)} times slower than the slowest pole "
                 f"of the PD error dynamics s^2 + Kd s + Kp ({_f(pd, 3)} rad/s): the observer, not Kp and Kd, limits "
                 "how fast a disturbance is rejected.")
    elif slow.min > pd:
        text += (f"It is faster than the slowest pole of the PD error dynamics s^2 + Kd s + Kp ({_f(pd, 3)} rad/s) "
                 "everywhere: Kp and Kd, not the observer, limit how fast a disturbance is rejected.")
    else:
        text += (f"The slowest pole of the PD error dynamics s^2 + Kd s + Kp ({_f(pd, 3)} rad/s) lies inside that "
                 "range: in part of the workspace the observer is the slower of the two.")
    caveats = split_caveats(result, scenario, observer=True)
    if caveats:
        text += (f" Both are rates of the perfect-model analysis; here {_and(caveats)}, so the linearized loop's modes "
                 "differ (section 3).")
    return text


def _design_statement(result) -> str | None:
    design = result.observer_design
    sim = design.simulation
    base, new = sim.get("scenario gain"), sim.get("designed")
    if not (base and new):
        return None

    def within(run):
        t = run.convergence_time_s
        return f"after {_f(t, 3)} s" if t is not None else f"not within the {_f(run.time[-1], 3)} s run"
    cert = design.certificate_designed
    text = (f"In simulation (the path with a constant disturbance step) the estimate gets within "
            f"{_f(100 * base.threshold, 2)}% of the largest disturbance {within(base)} with the scenario's gain and "
            f"{within(new)} with a designed matrix gain whose slowest mode is {_f(design.slowest_rad_s, 3)} rad/s "
            f"on the whole workspace grid. ")
    if cert.holds:
        text += (f"Decay rate of its estimation error certified on the workspace grid for slowly varying disturbances "
                 f"on a perfect model: {_f(cert.beta_min_rad_s, 3)} rad/s for joint speeds up to "
                 f"{_join(design.speed_bound, 3)} (rad/s, rad/s, m/s, rad/s).")
    else:
        text += (f"No decay rate could be certified on the workspace grid for joint speeds up to "
                 f"{_join(design.speed_bound, 3)} (rad/s, rad/s, m/s, rad/s): the condition fails at q = "
                 f"[{_join(cert.q_at, 3)}].")
    return text


def _noise_statement(result) -> str | None:
    obs = result.studies.observer
    labels, runs = obs.labels, obs.runs
    k_ref = next((k for k, label in enumerate(labels) if label.endswith("(scenario)")), None)
    if "designed Y" not in labels or k_ref is None:
        return None
    k_new = labels.index("designed Y")
    if not (runs[k_ref].ok and runs[k_new].ok):
        return None
    n_ref, n_new = runs[k_ref].torque_noise_rms, runs[k_new].torque_noise_rms
    faster = obs.slowest_mode_rad_s[k_new] > obs.slowest_mode_rad_s[k_ref]
    noisier = all(a > b for a, b in zip(n_new, n_ref))
    lead = "The price of the faster observer is torque noise: w" if faster and noisier else "W"
    return (f"{lead}ith the assumed sensor noise the joint torques jitter by {_join(n_new, 3)} (N m, N m, N, N m RMS) "
            f"with the designed gain against {_join(n_ref, 3)} with the scenario's gain.")


def _gains_statement(result) -> str | None:
    g_w, g_wo = result.studies.gains_with_dob, result.studies.gains_without_dob
    ok_w = [r for row in g_w.runs for r in row if r.ok]
    ok_wo = [r for row in g_wo.runs for r in row if r.ok]
    if not (ok_w and ok_wo):
        return None
    ss_wo = [r.tool_mm.steady_state_error for r in ok_wo]
    ss_w = [r.tool_mm.steady_state_error for r in ok_w]
    ts_w = [r.tool_mm.settling_time_s for r in ok_w]
    settled = [t for t in ts_w if t is not None]
    text = (f"Gains (a constant disturbance step on the arm held at the path's start, {_f(g_w.t_final_s)} s runs): "
            f"over Kp = {_join(g_w.kp)} and Kd = {_join(g_w.kd)} the tool tip comes to rest "
            f"{_span(min(ss_wo), max(ss_wo))} mm from its target without the observer and "
            + ("exactly on it with the observer" if max(ss_w) == 0 else f"at most {_f(max(ss_w), 3)} mm with it"))
    if settled:
        text += (f"; with the observer the tool-tip error settles (within {_f(100 * g_w.settle_fraction)}% of its "
                 f"largest deviation) in {_span(min(settled), max(settled))} s")
    if len(settled) < len(ts_w):
        text += f" ({len(ts_w) - len(settled)} of {len(ts_w)} gain pairs not settled within the run)"
    return text + "."


def plain_summary(result, experiment: dict, scenario: Scenario) -> list[str]:
    """Short statements, computed from the numbers, on what they mean for the surgeon's tool (plain text).

    Parameters
    ----------
    result : analysis.report.AnalysisResult
    experiment : dict
        The experiment's metrics (see :func:`build_view`).
    scenario : Scenario
    """
    lines = []
    w, wo = experiment["with_dob"], experiment["without_dob"]
    if "max_tool_position_error_mm" in w:
        lines.append(f"Along the scenario's path the tool tip strays at most "
                     f"{_f(w['max_tool_position_error_mm'], 3)} mm from where it should be with the disturbance "
                     f"observer, and {_f(wo['max_tool_position_error_mm'], 3)} mm without it (RMS "
                     f"{_f(w['rms_tool_position_error_mm'], 3)} mm against "
                     f"{_f(wo['rms_tool_position_error_mm'], 3)} mm).")
    lines += worse_with_observer(result, experiment, scenario)
    lines.append(_held_offset(result, scenario))
    lines.append(_speed_statement(result, scenario))
    for statement in (_design_statement(result), _noise_statement(result)):
        if statement:
            lines.append(statement)
    for observer, name in ((True, "with"), (False, "without")):
        lines.append(stability_text(result.mismatch.loop(observer).boundaries, f"{name} the observer the held loop",
                                    scenario.nominal == scenario.robot))
    statement = _gains_statement(result)
    if statement:
        lines.append(statement)
    return lines


# ---------------------------------------------------------------------------------------------------------------
# The sections


@dataclass(frozen=True)
class ScenarioSection:
    """1. The scenario's settings and its complete TOML text."""

    settings: Table
    toml: str


@dataclass(frozen=True)
class SimulationSection:
    """2. Table 3 layout for the scenario's path, joints made worse by the observer, the tool tip, Figures 4-8."""

    metrics: Table
    worse: list[str]
    tool: Table | None
    figures: list[Figure]


@dataclass(frozen=True)
class LinearSection:
    """3. Poles and modes of the linearized loop, and its robustness to inertia mismatch."""

    caveat: str | None
    points: Table
    first_label: str
    first_q0: str
    modes: list[Table]
    complex_at: str | None
    reading: str
    figures: list[Figure]
    perfect_model: bool
    mismatch_q0: str
    stability: list[Paragraph]
    mismatch: Table
    mismatch_reading: str
    mismatch_figures: list[Figure]


@dataclass(frozen=True)
class BandwidthSection:
    """4. Observer modes over the workspace and along the path."""

    grid: str
    modes: Table
    slowest: str
    reading: str
    figures: list[Figure]


@dataclass(frozen=True)
class DesignSection:
    """5. The designed observer gain, its certificate and its check in simulation."""

    target: str
    c_per_s: str
    base_is_scenario_gain: bool
    mode_ranges: str
    gain: Table
    certificate: Table
    simulation_setup: str | None
    simulation: Table
    figures: list[Figure]


@dataclass(frozen=True)
class FrequencySection:
    """6. Disturbance responses of the held loop."""

    q0: str
    responses: Table
    closed_forms: list[str]
    reading: str
    figures: list[Figure]


@dataclass(frozen=True)
class StudiesSection:
    """7. The Kp x Kd study and the observer gain and noise study."""

    definition: str
    gain_figures: list[Figure]
    gains: Table
    gain_reading: str | None
    noise_setup: str
    observer: Table
    observer_reading: str | None
    observer_figures: list[Figure]


@dataclass(frozen=True)
class ReportView:
    """Everything the report page shows, in order."""

    scenario_name: str
    scenario_source: str
    dobkit_version: str
    python_control_version: str
    summary: list[str]
    scenario: ScenarioSection
    simulation: SimulationSection
    linear: LinearSection
    bandwidth: BandwidthSection
    design: DesignSection
    frequency: FrequencySection
    studies: StudiesSection
    extra_sections: list[str] = field(default_factory=list)


def _scenario_section(s: Scenario, result) -> ScenarioSection:
    rows = [["name", s.name], ["source", s.source], ["description", s.data.get("description", "")],
            ["Kp (1/s^2)", _join(np.diag(s.kp))], ["Kd (1/s)", _join(np.diag(s.kd))],
            ["observer gain Y (kg m^2/s)", np.array2string(s.observer_gain, precision=4, separator=", ")],
            ["observer variant", s.observer_variant], ["trajectory", s.data["trajectory"]["kind"]],
            ["disturbance", str(s.data["disturbance"]["kind"])],
            ["nominal model = true model", "yes" if s.nominal == s.robot else "no (see [nominal_scale])"],
            ["simulated time (s)", _f(s.simulation.t_final)]]
    return ScenarioSection(Table.of(["setting", "value"], rows), result.scenario.toml)


def _simulation_section(result, experiment: dict, scenario: Scenario, files: dict) -> SimulationSection:
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
    tool = None
    if "max_tool_position_error_mm" in w:
        tool = Table.of(["tool tip", "with observer", "without observer"],
                        [["largest position error (mm)", _f(w["max_tool_position_error_mm"]),
                          _f(wo["max_tool_position_error_mm"])],
                         ["RMS position error (mm)", _f(w["rms_tool_position_error_mm"]),
                          _f(wo["rms_tool_position_error_mm"])]])
    return SimulationSection(
        metrics=Table.of(["Table 3 layout"] + [f"joint {i + 1} ({JOINT_LABELS[i]})" for i in range(4)], rows,
                         "Tracking metrics per joint"),
        worse=worse_with_observer(result, experiment, scenario), tool=tool,
        figures=_figures(files, ("fig4_joint_tracking", "Figure 4: joint tracking, with and without the observer"),
                         ("fig5_tracking_error", "Figure 5: tracking error q_ref - q"),
                         ("fig6_disturbance_estimate", "Figure 6: lumped disturbance d and its estimate d_hat"),
                         ("fig7_estimation_error", "Figure 7: estimation error d - d_hat"),
                         ("fig8_task_space", "Figure 8: tool-tip path in task space")))


def _linear_reading(first, caveats: list) -> str:
    modes = first.modes_with_dob
    alpha = first.largest_real_part(True)
    obs_rates = sorted(m.decay_rate_rad_s for m in modes if m.block == "observer")
    pd_rates = sorted(m.decay_rate_rad_s for m in modes if m.block == "plant")
    slowest = modes[0]                                   # modes are sorted slowest first
    share = slowest.participation[slowest.block]
    if alpha >= 0:
        text = (f"With the observer the held loop is unstable at {first.label} (largest pole real part "
                f"{_f(alpha, 4)} rad/s). ")
    elif slowest.block == "observer" and share > 0.99 and pd_rates:
        text = (f"With the observer the slowest closed-loop mode is the observer's {_f(obs_rates[0], 4)} rad/s (time "
                f"constant {_f(1 / obs_rates[0], 3)} s), {_f(pd_rates[0] / obs_rates[0], 3)} times slower than the "
                f"slowest PD mode ({_f(pd_rates[0], 4)} rad/s). ")
    else:
        text = (f"With the observer the slowest closed-loop mode, {_f(slowest.decay_rate_rad_s, 4)} rad/s, is "
                f"attributed to the {'observer' if slowest.block == 'observer' else 'plant (PD)'} states "
                f"(participation {_f(share, 3)})"
                + (f"; the slowest mode attributed to the observer is {_f(obs_rates[0], 4)} rad/s" if obs_rates and
                   slowest.block != "observer" else "") + ". ")
    err = first.max_rel_error_with_dob
    if not caveats and err < 1e-6:
        text += (f"The linearized poles equal the analytic split to {_f(err, 2)} (relative): on a perfect model with a "
                 "disturbance that does not depend on the arm's state the loop is block-triangular (the observer "
                 "error drives the tracking error, not the reverse), so Kp and Kd place the plant poles and Y places "
                 "the observer poles, independently.")
    elif caveats:
        text += (f"The analytic split assumes a perfect model and a disturbance that does not depend on the arm's "
                 f"state; here {_and(caveats)}, so the linearized poles differ from it by up to {_f(err, 2)} "
                 "(relative) and the split is only a guide.")
    else:
        text += f"The linearized poles differ from the analytic split by up to {_f(err, 2)} (relative)."
    return text


def _decays(poles) -> list[float]:
    return [-p.real for p in poles]


def _smallest_damping(poles) -> float:
    return min(-p.real / abs(p) for p in poles)


def _mismatch_reading(mm, perfect_model: bool) -> str:
    sw = mm.with_dob.sweep
    factors = sw.factors
    slow = [min(_decays(poles)) for poles in sw.poles]
    damp = [_smallest_damping(poles) for poles in sw.poles]
    picks = sorted({0, len(factors) - 1} | ({factors.index(1.0)} if 1.0 in factors else set()),
                   key=lambda k: factors[k])
    text = ("With the observer, the slowest mode decays at "
            + ", ".join(f"{_f(slow[k], 4)} rad/s at a = {_f(factors[k], 3)}" for k in picks)
            + "; the smallest damping ratio is "
            + ", ".join(f"{_f(damp[k], 3)} at a = {_f(factors[k], 3)}" for k in picks) + ". ")
    return text + stability_text(mm.with_dob.boundaries, "With the observer the held loop", perfect_model, prefix="")


def _linear_section(result, scenario: Scenario, files: dict) -> LinearSection:
    ops = result.operating_points
    caveats_wo = split_caveats(result, scenario, observer=False)
    caveat = (f"Without the observer {_and(caveats_wo)}, so its poles deviate from the ideal PD roots by up to "
              f"{_f(ops[0].max_rel_error_without_dob, 2)} (relative) at the first operating point."
              if caveats_wo else None)
    rows = []
    for op in ops:
        obs = sorted(m.decay_rate_rad_s for m in op.modes_with_dob if m.block == "observer")
        pd = sorted({round(m.decay_rate_rad_s, 6) for m in op.modes_with_dob if m.block == "plant"})
        rows.append([op.label, _join(op.q0, 4), _join(obs, 5), _join(pd, 5), _f(op.max_rel_error_with_dob, 2),
                     _f(op.max_rel_error_without_dob, 2),
                     "yes" if op.attribution_agrees_with_dob and op.attribution_agrees_without_dob else "no"])
    points = Table.of(["operating point", "q0 (rad, rad, m, rad)", "observer decay rates (rad/s)",
                       "plant (PD) decay rates (rad/s)", "largest rel. difference, with",
                       "largest rel. difference, without", "attribution agrees"], rows,
                      "All operating points (poles real unless listed below)")
    first = ops[0]
    modes = []
    for observer, title in ((True, "with observer"), (False, "without observer")):
        rows = [[_pole(m.pole), _f(m.wn_rad_s), _f(m.zeta), _f(m.time_constant_s), m.block,
                 _f(m.participation.get(m.block, 1.0), 3), _pole(m.analytic_pole), m.analytic_block,
                 _f(m.rel_error_vs_analytic, 2)] for m in first.modes(observer)]
        modes.append(Table.of(["pole (rad/s)", "wn (rad/s)", "zeta", "time constant (s)", "block", "participation",
                               "analytic pole", "analytic block", "relative difference"], rows,
                              f"{title}: largest relative difference from the analytic split "
                              f"{_f(first.max_rel_error(observer), 2)}; attribution agrees with the analytic split: "
                              f"{'yes' if first.attribution_agrees(observer) else 'no'}"))
    complex_ops = [op.label for op in ops for observer in (True, False)
                   if any(abs(m.pole.imag) > 0 for m in op.modes(observer))]
    mm = result.mismatch
    perfect = scenario.nominal == scenario.robot
    stability, rows = [], []
    for observer, title in ((True, "with observer"), (False, "without observer")):
        sweep = mm.loop(observer).sweep
        for a, alpha, poles in zip(sweep.factors, sweep.spectral_abscissa, sweep.poles):
            rows.append([title, _f(a, 4), _f(alpha, 5), _f(min(_decays(poles)), 4), _f(max(_decays(poles)), 4),
                         _f(_smallest_damping(poles), 4)])
        stability.append(Paragraph(stability_text(mm.loop(observer).boundaries, "the held loop", perfect, prefix=""),
                                   f"Stability {title}:"))
    return LinearSection(
        caveat=caveat, points=points, first_label=first.label, first_q0=_join(first.q0, 5), modes=modes,
        complex_at=", ".join(sorted(set(complex_ops))) if complex_ops else None,
        reading=_linear_reading(first, split_caveats(result, scenario, observer=True)),
        figures=_figures(files, ("linear_poles", "Closed-loop poles (o: linearized, x: analytic split)")),
        perfect_model=perfect, mismatch_q0=_join(mm.q0, 5), stability=stability,
        mismatch=Table.of(["loop", "a", "largest real part (rad/s)", "slowest decay (rad/s)", "fastest decay (rad/s)",
                           "smallest damping ratio"], rows, "Poles against inertia mismatch"),
        mismatch_reading=_mismatch_reading(mm, perfect),
        mismatch_figures=_figures(files, ("linear_mismatch", "Stability and pole movement against inertia mismatch")))


def _bandwidth_section(result, files: dict) -> BandwidthSection:
    bw = result.observer_bandwidth
    s = bw.slowest_rad_s
    fast = bw.fastest_rad_s
    rows = [[f"mode {k + 1}", _f(lo, 4), _f(hi, 4), _f(1 / hi, 3), _f(1 / lo, 3)] for k, (lo, hi) in
            enumerate(bw.ranges_rad_s)]
    sens = ", ".join(f"{k}: {_f(v, 3)}" for k, v in bw.sensitivity_rad_s.items())
    at = bw.along_trajectory
    slowest = (f"Slowest mode: {_f(s.min, 4)} rad/s at q = [{_join(s.q_at_min, 4)}], {_f(s.max, 4)} rad/s "
               f"at q = [{_join(s.q_at_max, 4)}]. Along the scenario's path it is {_f(at.min, 4)} to "
               f"{_f(at.max, 4)} rad/s; its direction in disturbance space there is "
               f"[{_join(at.direction_at_min, 3)}] (theta1, theta2, d3, theta4): it moves "
               f"{_mode_text(at.direction_at_min)}. Largest change of any eigenvalue along each joint axis of "
               f"the grid (rad/s): {sens}.")
    Y = np.array(bw.Y)
    scalar = np.allclose(Y, Y[0, 0] * np.eye(4))
    spread = scalar and (s.min < 0.99 * Y[0, 0] or fast.max > 1.01 * Y[0, 0])
    reading = ((f"A gain Y = {_f(Y[0, 0])} I does not give one bandwidth of {_f(Y[0, 0])} rad/s: " if spread else "")
               + f"the observer's rates are the gain divided by the inertia seen in each modal direction, from "
                 f"{_f(s.min, 4)} rad/s (slowest mode, moving {_mode_text(s.direction_at_min)}) to "
                 f"{_f(fast.max, 4)} rad/s (fastest mode, moving {_mode_text(fast.direction_at_max)}). A "
                 f"disturbance that acts along the slowest direction is learnt with a time constant of up to "
                 f"{_f(1 / s.min, 3)} s.")
    return BandwidthSection(
        grid=" x ".join(str(n) for n in bw.grid.points),
        modes=Table.of(["mode", "min (rad/s)", "max (rad/s)", "time constant min (s)", "time constant max (s)"], rows,
                       "Eigenvalues of Y M^-1(q) over the workspace"),
        slowest=slowest, reading=reading,
        figures=_figures(files, ("observer_bandwidth", "Observer modes along theta2 and the slowest mode's direction")))


def _design_section(result, scenario: Scenario, files: dict) -> DesignSection:
    d = result.observer_design
    cd, cs = d.certificate_designed, d.certificate_scenario_gain
    crit_d, crit_s = d.critical_theta2_speed_designed, d.critical_theta2_speed_scenario_gain
    ranges = d.bandwidth_designed.ranges_rad_s
    gain = Table.of([""] + [f"col {j + 1}" for j in range(len(d.Y))],
                    [[f"row {i + 1}"] + [_f(v, 5) for v in row] for i, row in enumerate(d.Y)])
    certificate = Table.of(
        ["", "scenario gain", "designed gain"],
        [["speed bound (rad/s, rad/s, m/s, rad/s)", _join(d.speed_bound, 3), _join(d.speed_bound, 3)],
         ["certificate beta_min (rad/s)", _f(cs.beta_min_rad_s, 5), _f(cd.beta_min_rad_s, 5)],
         ["  reached at q", _join(cs.q_at, 4), _join(cd.q_at, 4)],
         ["  and q'", _join(cs.dq_at, 3), _join(cd.dq_at, 3)],
         ["condition holds", "yes" if cs.holds else "no", "yes" if cd.holds else "no"],
         ["beta at rest, min (rad/s)", _f(cs.beta_at_rest_min_rad_s, 5), _f(cd.beta_at_rest_min_rad_s, 5)],
         ["largest |theta2'| keeping beta > 0 (rad/s)",
          "unlimited" if crit_s.unlimited else _f(crit_s.speed_factor, 5),
          "unlimited" if crit_d.unlimited else _f(crit_d.speed_factor, 5)]],
        "Convergence certificate")
    sims = d.simulation
    first = next(iter(sims.values()), None)
    setup = None
    if first is not None:
        own = _kinds(scenario.data["disturbance"]["kind"])
        used = _kinds(first.disturbance_kind)
        if used == own:
            what = f"the scenario's disturbance ({_and(used) if used else 'none'})"
        else:
            what = (f"the constant step f_r = [{_join(first.f_r, 4)}] (N m, N m, N, N m; the paper's Eq. 4) in "
                    f"place of the scenario's disturbance models ({_and(own) if own else 'none'})"
                    if used == ["paper"] else f"the disturbance {_and(used) if used else 'none'}")
        setup = (f"Nonlinear simulation of the scenario's path (first {_f(first.time[-1], 4)} s, noise removed) "
                 f"with {what}: time to get within {_f(100 * first.threshold, 2)}% of the largest disturbance, "
                 "and whether V(t) stays below the certified decay over the states the run visited.")
    rows = [[label, _f(run.beta_run_rad_s, 4),
             "not within the run" if run.convergence_time_s is None else _f(run.convergence_time_s, 4),
             _join(run.rms_disturbance_error, 3), _yes_no(run.bound_holds)]
            for label, run in sims.items()]
    return DesignSection(
        target=_f(d.target_rad_s), c_per_s=_f(d.c_per_s, 6), base_is_scenario_gain=d.base_is_scenario_gain,
        mode_ranges=", ".join(_f(lo, 4) + " to " + _f(hi, 4) for lo, hi in ranges), gain=gain,
        certificate=certificate, simulation_setup=setup,
        simulation=Table.of(["gain", "beta over the visited states (rad/s)", "time to 2% (s)",
                             "RMS d - d_hat (N m, N m, N, N m)", "V(t) <= V(0) exp(-2 beta t)"], rows,
                            "Nonlinear simulation with each gain"),
        figures=_figures(files, ("observer_design", "Estimation error and Lyapunov certificate in simulation")))


def _frequency_reading(fr, stable: bool) -> str:
    wo, w, est = (fr.tracking_without_dob.metrics, fr.tracking_with_dob.metrics, fr.estimation_with_dob.metrics)
    dc_w = abs(w[2].dc_gain)
    zero = stable and dc_w <= ZERO_REL * w[2].peak_gain
    text = (f"A constant force of 1 N on the prismatic joint leaves {_f(-1e3 * wo[2].dc_gain, 4)} mm of depth error "
            "without the observer and " + ("none with it. " if zero else f"{_f(1e3 * dc_w, 4)} mm with it. "))
    if all(m.kind == "band-pass" for m in w):
        text += ("With the observer, disturbances reach the tracking error only in a band around "
                 f"{', '.join(_f(m.peak_rad_s, 3) for m in w)} rad/s (joints 1-4; at most "
                 f"{', '.join(_f(m.peak_gain, 3) for m in w)} per unit disturbance): slower ones are estimated and "
                 "cancelled, faster ones are filtered by the arm's inertia. ")
    else:
        text += ("With the observer the disturbance-to-error responses are " + ", ".join(m.kind for m in w)
                 + " (joints 1-4). ")
    if all(m.kind == "high-pass" for m in est):
        corners = ", ".join(_f(m.band_3db_rad_s[0], 3) for m in est)
        text += (f"The estimate follows a disturbance only below {corners}"
                 " rad/s (joints 1-4; -3 dB), the observer bandwidth seen from each joint.")
    else:
        text += ("The estimation-error responses are " + ", ".join(m.kind for m in est) + " (joints 1-4).")
    return text


def _frequency_section(result, scenario: Scenario, files: dict) -> FrequencySection:
    fr = result.frequency
    rows = []
    for key, title in (("tracking_with_dob", "e, with observer"), ("tracking_without_dob", "e, without observer"),
                       ("estimation_with_dob", "d - d_hat, with observer")):
        data = getattr(fr, key)
        unit_key = "estimation" if key.startswith("estimation") else "tracking"
        for i, m in enumerate(data.metrics):
            band = m.band_3db_rad_s
            dc = m.dc_gain if abs(m.dc_gain) > 1e-9 * m.peak_gain else 0.0     # rounding noise shown as 0
            peak_at = "inf" if m.peak_rad_s is None else ("0 (DC)" if m.peak_rad_s == 0 else _f(m.peak_rad_s, 4))
            rows.append([title, f"joint {i + 1}", fr.units[unit_key][i], _f(dc, 4), _f(m.peak_gain, 4), peak_at,
                         m.kind, f"{_f(band[0], 4)} to {'inf' if band[1] is None else _f(band[1], 4)}"])
        rows.append([title, "closed form", "", "", "", "", "largest relative difference",
                     _f(data.closed_form_max_rel_error, 2)])
    stable = result.operating_points[0].largest_real_part(True) < 0
    closed_forms = []
    for observer, name in ((True, "with"), (False, "without")):
        caveats = split_caveats(result, scenario, observer)
        err = _f(fr.tracking(observer).closed_form_max_rel_error, 2)
        if caveats:
            closed_forms.append(f"The closed forms assume a perfect model, a disturbance that does not depend on the "
                                f"arm's state and the arm resting at q0; {name} the observer {_and(caveats)}, so they "
                                f"are only approximate (largest relative difference {err}).")
        else:
            closed_forms.append(f"{name.capitalize()} the observer the linearized responses equal the closed forms "
                                f"(largest relative difference {err}).")
    return FrequencySection(
        q0=_join(fr.q0, 5),
        responses=Table.of(["response", "joint", "unit", "DC gain", "peak gain", "peak at (rad/s)", "kind",
                            "-3 dB band (rad/s)"], rows, "Per-joint disturbance responses"),
        closed_forms=closed_forms, reading=_frequency_reading(fr, stable),
        figures=_figures(files, ("frequency_tracking", "Disturbance to tracking error, per joint"),
                         ("frequency_estimation", "Disturbance to estimation error, per joint")))


def _study_definition(st, scenario: Scenario) -> str:
    g = st.gains_with_dob
    own = _kinds(scenario.data["disturbance"]["kind"])
    where = ("which is the scenario's own disturbance" if own == ["paper"] else
             f"in place of the scenario's disturbance models ({_and(own) if own else 'none'})")
    return (f"Every run holds the arm at the scenario's reference at t = 0, q_hold = [{_join(g.q_hold, 4)}] "
            f"(rad, rad, m, rad), and applies the constant disturbance step f_r = [{_join(g.f_r, 4)}] (N m, N m, "
            f"N, N m; the paper's Eq. 4) from t = 0, {where}, for "
            f"{_f(g.t_final_s)} s; models, noise-free sensors and solver settings are the scenario's. The arm "
            "starts at rest with d_hat = 0. Final value: the error where the held loop comes to rest (its "
            "equilibrium, computed); steady-state error: its size. Settling time: from then on the error stays within "
            f"{_f(100 * g.settle_fraction)}% of its largest deviation from the final value; 'not settled' when the "
            f"error is still outside that band during the last {_f(100 * g.final_window)}% of the run. Tool-tip "
            "position error in mm.")


def _observer_reading(obs, scenario: Scenario) -> str | None:
    ok = [k for k, r in enumerate(obs.runs) if r.ok and obs.labels[k] != "none"]
    if not ok or not obs.runs[0].ok:
        return None
    base = obs.runs[0].torque_noise_rms
    fastest = max(ok, key=lambda k: obs.slowest_mode_rad_s[k])
    slowest = min(ok, key=lambda k: obs.slowest_mode_rad_s[k])
    p_slow = obs.runs[slowest].tool_mm.peak_error
    p_fast = obs.runs[fastest].tool_mm.peak_error
    verb = "falls" if p_fast < p_slow else ("rises" if p_fast > p_slow else "stays")
    ratio = [n / b if b > 0 else float("nan") for n, b in zip(obs.runs[fastest].torque_noise_rms, base)]
    text = (f"From the slowest observer tested ({obs.labels[slowest]}) to the fastest ({obs.labels[fastest]}) "
            f"the peak tool-tip error after the step {verb} from {_f(p_slow, 3)} to {_f(p_fast, 3)} mm, and the torque "
            f"noise is {', '.join(_f(r, 3) for r in ratio)} times its value without the observer (joints 1-4)")
    finite = [r if math.isfinite(r) else -math.inf for r in ratio]
    j = int(np.argmax(finite))
    if finite[j] > 1:
        M = inertia(np.asarray(obs.q_hold, dtype=float), scenario.nominal)
        lightest = int(np.argmin(np.diag(M))) == j
        text += (f". The relative increase is largest on joint {j + 1}"
                 + (", the joint with the smallest inertia: the observer adds Y q' velocity noise to the "
                    "controller's M Kd q' noise, and Y / (M Kd) is largest where M is smallest" if lightest else "")
                 )
    return text + "."


def _gain_reading(st) -> str | None:
    """Computed observations on the Kp x Kd study."""
    def cells(study):
        return [(kp, kd, run.tool_mm) for kp, kd, run in study.cells() if run.ok]
    w, wo = cells(st.gains_with_dob), cells(st.gains_without_dob)
    if not w or not wo:
        return None
    by_kp = {}
    for kp, _, m in wo:
        by_kp.setdefault(kp, []).append(m.steady_state_error)
    offsets = ", ".join(f"{_f(np.mean(v), 3)} mm at Kp = {_f(kp)}" for kp, v in sorted(by_kp.items()))
    spread = max((max(v) - min(v)) / max(v) if max(v) > 0 else 0.0 for v in by_kp.values())
    text = (f"Without the observer the tool tip comes to rest {offsets}; across Kd it changes by at most "
            f"{_f(100 * spread, 2)}% at a given Kp. With the observer it comes to rest "
            + ("exactly on its target" if max(c[2].steady_state_error for c in w) == 0 else
               f"at most {_f(max(c[2].steady_state_error for c in w), 3)} mm from its target")
            + " for every pair; ")
    best_peak = min(w, key=lambda c: c[2].peak_error)
    text += f"the smallest peak error is {_f(best_peak[2].peak_error, 3)} mm (Kp = {_f(best_peak[0])}, " \
            f"Kd = {_f(best_peak[1])})"
    settled = [c for c in w if c[2].settling_time_s is not None]
    if settled:
        best_ts = min(settled, key=lambda c: c[2].settling_time_s)
        text += f", the shortest settling time {_f(best_ts[2].settling_time_s, 3)} s (Kp = {_f(best_ts[0])}, " \
                f"Kd = {_f(best_ts[1])})"
    if len(settled) < len(w):
        text += f" ({len(w) - len(settled)} of {len(w)} pairs not settled within the run)"
    best_rms = min(w, key=lambda c: c[2].rms_error)
    return text + f", the smallest RMS error {_f(best_rms[2].rms_error, 3)} mm (Kp = {_f(best_rms[0])}, " \
                  f"Kd = {_f(best_rms[1])})."


def _studies_section(result, scenario: Scenario, files: dict) -> StudiesSection:
    st = result.studies
    rows = []
    for study, title in ((st.gains_with_dob, "with"), (st.gains_without_dob, "without")):
        for kp, kd, r in study.cells():
            if not r.ok:
                rows.append([title, _f(kp), _f(kd), "failed", "", "", ""])
                continue
            m = r.tool_mm
            rows.append([title, _f(kp), _f(kd), _settling(m.settling_time_s), _f(m.steady_state_error, 3),
                         _f(m.peak_error, 3), _f(m.rms_error, 3)])
    gains = Table.of(["observer", "Kp (1/s^2)", "Kd (1/s)", "settling time (s)", "steady-state (mm)", "peak (mm)",
                      "RMS (mm)"], rows, "Kp x Kd study (tool tip)")
    obs = st.observer
    noise = obs.noise
    noise_setup = (f"Observer gain and measurement noise: the same step experiment ({_f(obs.t_final_s)} s runs) for "
                   f"each observer gain. Torque noise: runs of the first {_f(obs.noise_t_final_s)} s with noise on q "
                   f"of standard deviations {_join(noise['q_std'])} (rad, rad, m, rad) and on q' of "
                   f"{_join(noise['dq_std'])} (rad/s, rad/s, m/s, rad/s), sampled every "
                   f"{_f(noise.get('sample_period', 0.001))} s, seed {noise.get('seed', 0)}; torque noise = RMS of the "
                   "torque difference between the noisy and the clean run.")
    rows = []
    for k, label in enumerate(obs.labels):
        r = obs.runs[k]
        if not r.ok:
            rows.append([label, "failed"] + [""] * 7)
            continue
        m = r.tool_mm
        rows.append([label, _f(obs.slowest_mode_rad_s[k], 4), _settling(m.settling_time_s), _f(m.peak_error, 3),
                     _f(m.rms_error, 3), _f(r.clean_short.tool_mm.rms_error, 3), _f(r.noisy.tool_mm.rms_error, 3),
                     _join(r.torque_noise_rms, 3)])
    observer = Table.of(["observer gain", "slowest mode (rad/s)", "settling (s)", "peak (mm)", "RMS (mm)",
                         f"RMS, first {_f(obs.noise_t_final_s)} s (mm)", "same, with noise (mm)",
                         "torque noise RMS (N m, N m, N, N m)"], rows, "Observer gain study (tool tip)")
    return StudiesSection(
        definition=_study_definition(st, scenario),
        gain_figures=_figures(files, ("study_gains", "Gain study heat maps (the numbers are in the table below)")),
        gains=gains, gain_reading=_gain_reading(st), noise_setup=noise_setup, observer=observer,
        observer_reading=_observer_reading(obs, scenario),
        observer_figures=_figures(files, ("study_observer", "Error against torque noise for each observer gain")))


def build_view(result, experiment: dict, scenario: Scenario, figure_files: dict,
               extra_sections: tuple[str, ...] = ()) -> ReportView:
    """Everything the report shows, computed from the results.

    Parameters
    ----------
    result : analysis.report.AnalysisResult
    experiment : dict
        The experiment's metrics (``with_dob``/``without_dob`` of
        :func:`blocks.metrics.tracking_metrics`); optionally
        ``duration_s`` and, per run, ``time_of_max_abs_position_error``.
    scenario : Scenario
    figure_files : dict
        Figure stem -> PNG path; missing figures are left out.
    extra_sections : tuple of str
        Ready-made HTML sections appended at the end (for example a sweep summary).
    """
    return ReportView(
        scenario_name=scenario.name, scenario_source=scenario.source, dobkit_version=result.dobkit_version,
        python_control_version=result.python_control_version,
        summary=plain_summary(result, experiment, scenario),
        scenario=_scenario_section(scenario, result),
        simulation=_simulation_section(result, experiment, scenario, figure_files),
        linear=_linear_section(result, scenario, figure_files),
        bandwidth=_bandwidth_section(result, figure_files),
        design=_design_section(result, scenario, figure_files),
        frequency=_frequency_section(result, scenario, figure_files),
        studies=_studies_section(result, scenario, figure_files),
        extra_sections=list(extra_sections))
