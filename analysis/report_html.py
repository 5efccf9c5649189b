"""The text and HTML of the analysis report: every statement is computed from the numbers it describes.

:func:`plain_summary` gives the short statements for the surgical team and
:func:`render_html` the whole page.  Statements that interpret the numbers
("the observer limits the rejection speed", "the loop goes unstable below ...")
are generated from the analysis result and only made when the result supports
them; otherwise the number is stated plainly.  All text goes through
:func:`html.escape`; markup is added only by the helpers here.
"""
from __future__ import annotations

import base64
import html
import math
from pathlib import Path

import numpy as np

from blocks import forward_kinematics, inertia
from blocks.scenario import Scenario
from blocks.metrics import DISTURBANCE_UNITS, JOINT_LABELS, JOINT_UNITS

__all__ = ["plain_summary", "render_html", "worse_with_observer", "stability_text"]

# A component of a unit mode direction at least this large counts as "the mode moves this joint".
MODE_SHARE = 0.1
# Relative size below which a computed DC gain or offset is called zero.
ZERO_REL = 1e-6


# ---------------------------------------------------------------------------------------------------------------
# Formatting and markup helpers (all text escaped)


def esc(text) -> str:
    """``text`` escaped for HTML (``<``, ``>``, ``&`` and quotes)."""
    return html.escape(str(text), quote=True)


def _f(value, digits: int = 4) -> str:
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


def _join(values, digits: int = 4) -> str:
    """Numbers as a comma-separated list (see :func:`_f`)."""
    return ", ".join(_f(v, digits) for v in values)


def _span(lo, hi, digits: int = 3) -> str:
    """'a to b', or 'a' when both print the same."""
    a, b = _f(lo, digits), _f(hi, digits)
    return a if a == b else f"{a} to {b}"


def _settling(value, digits: int = 3) -> str:
    return "not settled" if value is None else _f(value, digits)


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
        return text in ("-", "inf", "not settled")


def _p(text: str, lead: str | None = None) -> str:
    """A paragraph of plain text, optionally led by a bold word."""
    return "<p>" + (f"<b>{esc(lead)}</b> " if lead else "") + esc(text) + "</p>"


def _h(level: int, text: str, style: str = "") -> str:
    attr = f" style='{esc(style)}'" if style else ""
    return f"<h{level}{attr}>{esc(text)}</h{level}>"


def _table(header: list, rows: list, caption: str | None = None) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)

    def cell(c):
        c = str(c)
        return f"<td class='num'>{esc(c)}</td>" if _is_number(c) else f"<td>{esc(c)}</td>"
    body = "".join("<tr>" + "".join(cell(c) for c in row) + "</tr>" for row in rows)
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _details(summary: str, inner_html: str) -> str:
    return f"<details><summary>{esc(summary)}</summary>{inner_html}</details>"


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return (f'<figure><img alt="{esc(alt)}" src="data:image/png;base64,{data}"><figcaption>{esc(alt)}'
            "</figcaption></figure>")


def _figures(files: dict, *items: tuple[str, str]) -> str:
    """The figures among ``(stem, caption)`` items that were written (``files``: stem -> PNG path), in order."""
    return "".join(_img(files[stem], caption) for stem, caption in items if stem in files)


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


def _max_real(poles) -> float:
    return max(p[0] for p in poles)


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


def split_caveats(result: dict, scenario: Scenario, observer: bool) -> list[str]:
    """Why the perfect-model analytic forms (pole split, closed-form responses) may not hold for this scenario."""
    reasons = []
    if scenario.nominal != scenario.robot:
        reasons.append("the nominal model differs from the true one")
    reasons += [STATE_DEPENDENT[k] for k in _kinds(scenario.data["disturbance"]["kind"]) if k in STATE_DEPENDENT]
    op = result["operating_points"][0]
    if not observer and np.max(np.abs(np.subtract(op["q_equilibrium_without_dob"], op["q0"]))) > 0:
        reasons.append("the arm rests off q0 (by M^-1 d / Kp), where M(q) differs")
    return reasons


def stability_text(boundaries: dict, subject: str, perfect_model: bool = True, prefix: str = "Model error: ") -> str:
    """A sentence on where a loop is stable over the inertia factors searched, from a boundary search result.

    Parameters
    ----------
    boundaries : dict
        From :func:`analysis.linear.stability_boundaries`.
    subject : str
        What the sentence is about, e.g. "with the observer the held loop".
    perfect_model : bool
        Whether the scenario's nominal model is the true one (then the factor
        ``a`` is nominal/true inertia; otherwise it scales the scenario's nominal inertia).
    """
    lo, hi = boundaries["range"]
    found = boundaries["boundaries"]
    first_stable = boundaries["scan"]["spectral_abscissa"][0] < 0
    ref = "the true one" if perfect_model else "the scenario's nominal inertia, which itself differs from the true one"
    if not found:
        state = "stays stable" if first_stable else "is unstable"
        return (f"{prefix}{subject} {state} for every nominal inertia from {_f(lo)} to {_f(hi)} times {ref}: no "
                "stability boundary in the range searched.")
    edges = [lo] + [b["factor"] for b in found] + [hi]
    stable, parts = first_stable, []
    for a, b in zip(edges[:-1], edges[1:]):
        parts.append(f"{'stable' if stable else 'unstable'} for a nominal inertia from {_f(a, 4)} to {_f(b, 4)}")
        stable = not stable
    return (f"{prefix}{subject} is " + ", ".join(parts) + f" times {ref}; it changes stability at a = "
            + ", ".join(_f(b["factor"], 6) for b in found) + f" (searched {_f(lo)} to {_f(hi)}).")


# ---------------------------------------------------------------------------------------------------------------
# Computed statements


def worse_with_observer(result: dict, experiment: dict, scenario: Scenario) -> list[str]:
    """One statement per joint whose RMS position error along the path is larger with the observer than without.

    The explanation is built from the numbers: the offset the disturbance leaves
    on the joint without the observer (held at the path's start, ``M^-1 d / Kp``)
    against what the joint's own disturbance alone would leave, and whether the
    error with the observer is a start-up transient (largest early in the run,
    small at its end) while the observer learns the disturbance at the rate of
    its slowest mode along the path.
    """
    w, wo = experiment["with_dob"], experiment["without_dob"]
    op = result["operating_points"][0]
    at = result["observer_bandwidth"]["along_trajectory"]
    q0 = np.asarray(op["q0"], dtype=float)
    offset = np.asarray(op["q_equilibrium_without_dob"], dtype=float) - q0
    d = np.asarray(op.get("disturbance_at_rest", [0.0] * 4), dtype=float)
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
                     f"learns the disturbance at the rate of its modes, the slowest {_f(at['min'], 3)} to "
                     f"{_f(at['max'], 3)} rad/s along the path (time constant up to {_f(1 / at['min'], 3)} s), and the "
                     f"part not yet learned moves this joint by up to {_value(peak, j)} (at t = {_f(t_max[j], 3)} s; "
                     f"{_value(final, j)} at the end of the run).")
        else:
            text += (f" With the observer the error reaches {_value(peak, j)}"
                     + (f" at t = {_f(t_max[j], 3)} s" if t_max is not None else "")
                     + f" and is {_value(final, j)} at the end of the run.")
        lines.append(text)
    return lines


def _held_offset(result: dict, scenario: Scenario) -> str:
    op = result["operating_points"][0]
    d = np.asarray(op.get("disturbance_at_rest", [0.0] * 4), dtype=float)
    kinds = _kinds(scenario.data["disturbance"]["kind"])
    if not np.max(np.abs(d)) > 0:
        why = (f"the scenario's disturbance models ({_and(kinds)}) give zero force on the arm at rest there" if kinds
               else "the scenario has no disturbance model")
        return (f"Held still at the path's start the arm feels no disturbance: {why}, so a held arm has no offset with "
                "or without the observer. The design check and the studies below apply a constant disturbance step "
                "instead.")
    text = ""
    stable_wo = _max_real(op["poles_without_dob"]) < 0
    offset = _tool_offset_mm(op["q_equilibrium_without_dob"], op["q0"], scenario.robot)
    depth = 1e3 * (op["q_equilibrium_without_dob"][2] - op["q0"][2])
    if stable_wo:
        text += (f"Held still at the path's start against the disturbance it feels there, the arm without the observer "
                 f"settles {_f(offset, 3)} mm away from its target ({_f(depth, 3)} mm of it along the tool axis, joint "
                 "3) and stays there for as long as the disturbance acts; the offset is M^-1 d / Kp, so a larger Kp "
                 "shrinks it and Kd does not change it.")
    else:
        text += (f"Held still at the path's start, the loop without the observer is unstable (largest pole real part "
                 f"{_f(_max_real(op['poles_without_dob']), 4)} rad/s).")
    stable_w = _max_real(op["poles_with_dob"]) < 0
    offset_w = _tool_offset_mm(op["q_equilibrium_with_dob"], op["q0"], scenario.robot)
    metrics = result["frequency"]["tracking_with_dob"]["metrics"]
    dc_rel = max(abs(m["dc_gain"]) / m["peak_gain"] if m["peak_gain"] > 0 else 0.0 for m in metrics)
    if not stable_w:
        text += (f" With the observer the held loop is unstable at this configuration (largest pole real part "
                 f"{_f(_max_real(op['poles_with_dob']), 4)} rad/s).")
    elif offset_w <= ZERO_REL * max(offset, 1e-3) and dc_rel <= ZERO_REL:
        text += (f" With the observer the arm rests on its target (offset {_f(offset_w, 2)} mm): the linearized "
                 f"tracking error has zero DC gain from every joint disturbance (largest |DC gain| / peak gain "
                 f"{_f(dc_rel, 2)}).")
    else:
        text += (f" With the observer the held arm rests {_f(offset_w, 3)} mm from its target (largest |DC gain| / "
                 f"peak gain of the tracking error {_f(dc_rel, 3)}).")
    return text


def _speed_statement(result: dict, scenario: Scenario) -> str:
    op = result["operating_points"][0]
    slow = result["observer_bandwidth"]["slowest_rad_s"]
    pd = min(-m["analytic_pole"][0] for m in op["modes_without_dob"])
    text = (f"How quickly the observer learns a new disturbance is set by its slowest mode, {_f(slow['min'], 3)} to "
            f"{_f(slow['max'], 3)} rad/s across the workspace (time constant {_f(1 / slow['max'], 3)} to "
            f"{_f(1 / slow['min'], 3)} s), a mode that moves {_mode_text(slow['direction_at_min'])}. ")
    if slow["max"] < pd:
        text += (f"It is {_f(pd / slow['max'], 3)} to {_f(pd / slow['min'], 3)} times slower than the slowest pole "
                 f"of the PD error dynamics s^2 + Kd s + Kp ({_f(pd, 3)} rad/s): the observer, not Kp and Kd, limits "
                 "how fast a disturbance is rejected.")
    elif slow["min"] > pd:
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


def _design_statement(result: dict) -> str | None:
    design = result["observer_design"]
    sim = design["simulation"]
    base, new = sim.get("scenario gain"), sim.get("designed")
    if not (base and new):
        return None

    def within(run):
        t = run["convergence_time_s"]
        return f"after {_f(t, 3)} s" if t is not None else f"not within the {_f(run['time'][-1], 3)} s run"
    cert = design["certificate_designed"]
    text = (f"In simulation (the path with a constant disturbance step) the estimate gets within "
            f"{_f(100 * base['threshold'], 2)}% of the largest disturbance {within(base)} with the scenario's gain and "
            f"{within(new)} with a designed matrix gain whose slowest mode is {_f(design['slowest_rad_s'], 3)} rad/s "
            f"on the whole workspace grid. ")
    if cert["holds"]:
        text += (f"Decay rate of its estimation error certified on the workspace grid for slowly varying disturbances "
                 f"on a perfect model: {_f(cert['beta_min_rad_s'], 3)} rad/s for joint speeds up to "
                 f"{_join(design['speed_bound'], 3)} (rad/s, rad/s, m/s, rad/s).")
    else:
        text += (f"No decay rate could be certified on the workspace grid for joint speeds up to "
                 f"{_join(design['speed_bound'], 3)} (rad/s, rad/s, m/s, rad/s): the condition fails at q = "
                 f"[{_join(cert['q_at'], 3)}].")
    return text


def _noise_statement(result: dict) -> str | None:
    obs = result["studies"]["observer"]
    labels, runs = obs["labels"], obs["runs"]
    k_ref = next((k for k, label in enumerate(labels) if label.endswith("(scenario)")), None)
    if "designed Y" not in labels or k_ref is None:
        return None
    k_new = labels.index("designed Y")
    if not (runs[k_ref].get("ok") and runs[k_new].get("ok")):
        return None
    n_ref, n_new = runs[k_ref]["torque_noise_rms"], runs[k_new]["torque_noise_rms"]
    faster = obs["slowest_mode_rad_s"][k_new] > obs["slowest_mode_rad_s"][k_ref]
    noisier = all(a > b for a, b in zip(n_new, n_ref))
    lead = "The price of the faster observer is torque noise: w" if faster and noisier else "W"
    return (f"{lead}ith the assumed sensor noise the joint torques jitter by {_join(n_new, 3)} (N m, N m, N, N m RMS) "
            f"with the designed gain against {_join(n_ref, 3)} with the scenario's gain.")


def _gains_statement(result: dict) -> str | None:
    g_w, g_wo = result["studies"]["gains_with_dob"], result["studies"]["gains_without_dob"]
    ok_w = [r for row in g_w["runs"] for r in row if r.get("ok")]
    ok_wo = [r for row in g_wo["runs"] for r in row if r.get("ok")]
    if not (ok_w and ok_wo):
        return None
    ss_wo = [r["tool_mm"]["steady_state_error"] for r in ok_wo]
    ss_w = [r["tool_mm"]["steady_state_error"] for r in ok_w]
    ts_w = [r["tool_mm"]["settling_time_s"] for r in ok_w]
    settled = [t for t in ts_w if t is not None]
    text = (f"Gains (a constant disturbance step on the arm held at the path's start, {_f(g_w['t_final_s'])} s runs): "
            f"over Kp = {_join(g_w['kp'])} and Kd = {_join(g_w['kd'])} the tool tip comes to rest "
            f"{_span(min(ss_wo), max(ss_wo))} mm from its target without the observer and "
            + ("exactly on it with the observer" if max(ss_w) == 0 else f"at most {_f(max(ss_w), 3)} mm with it"))
    if settled:
        text += (f"; with the observer the tool-tip error settles (within {_f(100 * g_w['settle_fraction'])}% of its "
                 f"largest deviation) in {_span(min(settled), max(settled))} s")
    if len(settled) < len(ts_w):
        text += f" ({len(ts_w) - len(settled)} of {len(ts_w)} gain pairs not settled within the run)"
    return text + "."


def plain_summary(result: dict, experiment: dict, scenario: Scenario) -> list[str]:
    """Short statements, computed from the numbers, on what they mean for the surgeon's tool (plain text)."""
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
    for key, name in (("with_dob", "with"), ("without_dob", "without")):
        lines.append(stability_text(result["mismatch"][key]["boundaries"], f"{name} the observer the held loop",
                                    scenario.nominal == scenario.robot))
    statement = _gains_statement(result)
    if statement:
        lines.append(statement)
    return lines


# ---------------------------------------------------------------------------------------------------------------
# Sections

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
    return (_h(2, "1. Scenario") + _table(["setting", "value"], rows)
            + _details("complete scenario (TOML)", f"<pre>{esc(result['scenario']['toml'])}</pre>"))


def _section_simulation(result: dict, experiment: dict, scenario: Scenario, files: dict) -> str:
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
    text = (_h(2, "2. Simulation of the scenario (paper Figures 4-8, Table 3)")
            + _p("The nonlinear Figure-2 loop simulated with and without the observer. Table 3 of the paper lists RMS "
                 "errors (Eq. 13-14) for its own laceration path, which the paper does not give; the table below has "
                 "the same layout for this scenario's path.")
            + _table(["Table 3 layout"] + [f"joint {i + 1} ({JOINT_LABELS[i]})" for i in range(4)], rows,
                     "Tracking metrics per joint"))
    worse = worse_with_observer(result, experiment, scenario)
    if worse:
        text += "".join(_p(line, "Worse with the observer.") for line in worse)
    else:
        text += _p("On every joint the RMS position error is smaller with the observer than without.")
    if "max_tool_position_error_mm" in w:
        text += _table(["tool tip", "with observer", "without observer"],
                       [["largest position error (mm)", _f(w["max_tool_position_error_mm"]),
                         _f(wo["max_tool_position_error_mm"])],
                        ["RMS position error (mm)", _f(w["rms_tool_position_error_mm"]),
                         _f(wo["rms_tool_position_error_mm"])]])
    text += _figures(files, ("fig4_joint_tracking", "Figure 4: joint tracking, with and without the observer"),
                            ("fig5_tracking_error", "Figure 5: tracking error q_ref - q"),
                            ("fig6_disturbance_estimate", "Figure 6: lumped disturbance d and its estimate d_hat"),
                            ("fig7_estimation_error", "Figure 7: estimation error d - d_hat"),
                            ("fig8_task_space", "Figure 8: tool-tip path in task space"))
    return text


def _linear_reading(first: dict, caveats: list) -> str:
    modes = first["modes_with_dob"]
    alpha = _max_real(first["poles_with_dob"])
    obs_rates = sorted(-m["pole"][0] for m in modes if m["block"] == "observer")
    pd_rates = sorted(-m["pole"][0] for m in modes if m["block"] == "plant")
    slowest = modes[0]                                   # modes are sorted slowest first
    share = slowest["participation"][slowest["block"]]
    if alpha >= 0:
        text = (f"With the observer the held loop is unstable at {first['label']} (largest pole real part "
                f"{_f(alpha, 4)} rad/s). ")
    elif slowest["block"] == "observer" and share > 0.99 and pd_rates:
        text = (f"With the observer the slowest closed-loop mode is the observer's {_f(obs_rates[0], 4)} rad/s (time "
                f"constant {_f(1 / obs_rates[0], 3)} s), {_f(pd_rates[0] / obs_rates[0], 3)} times slower than the "
                f"slowest PD mode ({_f(pd_rates[0], 4)} rad/s). ")
    else:
        text = (f"With the observer the slowest closed-loop mode, {_f(-slowest['pole'][0], 4)} rad/s, is attributed "
                f"to the {'observer' if slowest['block'] == 'observer' else 'plant (PD)'} states (participation "
                f"{_f(share, 3)})"
                + (f"; the slowest mode attributed to the observer is {_f(obs_rates[0], 4)} rad/s" if obs_rates and
                   slowest["block"] != "observer" else "") + ". ")
    err = first["max_rel_error_with_dob"]
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


def _mismatch_reading(mm: dict, perfect_model: bool) -> str:
    sw = mm["with_dob"]["sweep"]
    factors = sw["factors"]
    slow = [min(-p[0] for p in poles) for poles in sw["poles"]]
    damp = [min(-p[0] / math.hypot(*p) for p in poles) for poles in sw["poles"]]
    picks = sorted({0, len(factors) - 1} | ({factors.index(1.0)} if 1.0 in factors else set()),
                   key=lambda k: factors[k])
    text = ("With the observer, the slowest mode decays at "
            + ", ".join(f"{_f(slow[k], 4)} rad/s at a = {_f(factors[k], 3)}" for k in picks)
            + "; the smallest damping ratio is "
            + ", ".join(f"{_f(damp[k], 3)} at a = {_f(factors[k], 3)}" for k in picks) + ". ")
    return text + stability_text(mm["with_dob"]["boundaries"], "With the observer the held loop", perfect_model,
                                 prefix="")


def _section_linear(result: dict, scenario: Scenario, files: dict) -> str:
    ops = result["operating_points"]
    caveats_wo = split_caveats(result, scenario, observer=False)
    text = (_h(2, "3. Linearized closed loop")
            + _p("The Figure-2 interconnection itself is linearized (control.linearize, central differences) with the "
                 "arm held at q0, the scenario's disturbance acting and every block at equilibrium (with the "
                 "observer: q = q0, d_hat = d). Each mode is assigned to the block that owns it by participation "
                 "factors, computed with the observer described by its estimate d_hat. The analytic split on a "
                 "perfect model is: roots of s^2 + Kd s + Kp per joint (plant / PD error dynamics) and eigenvalues of "
                 "-Y M^-1(q0) (observer). "
                 + (f"Without the observer {_and(caveats_wo)}, so its poles deviate from the ideal PD roots by up to "
                    f"{_f(ops[0]['max_rel_error_without_dob'], 2)} (relative) at the first operating point."
                    if caveats_wo else "")))
    rows = []
    for op in ops:
        obs = sorted(-m["pole"][0] for m in op["modes_with_dob"] if m["block"] == "observer")
        pd = sorted({round(-m["pole"][0], 6) for m in op["modes_with_dob"] if m["block"] == "plant"})
        rows.append([op["label"], _join(op["q0"], 4), _join(obs, 5), _join(pd, 5), _f(op["max_rel_error_with_dob"], 2),
                     _f(op["max_rel_error_without_dob"], 2),
                     "yes" if op["attribution_agrees_with_dob"] and op["attribution_agrees_without_dob"] else "no"])
    text += _table(["operating point", "q0 (rad, rad, m, rad)", "observer decay rates (rad/s)",
                    "plant (PD) decay rates (rad/s)", "largest rel. difference, with",
                    "largest rel. difference, without", "attribution agrees"], rows,
                   "All operating points (poles real unless listed below)")
    for op in ops[:1]:
        text += _h(3, f"All modes at {op['label']}, q0 = [{_join(op['q0'], 5)}] (rad, rad, m, rad)")
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
        text += _p(f"Complex poles occur at: {', '.join(sorted(set(complex_ops)))} (see the figure).")
    text += _p(_linear_reading(ops[0], split_caveats(result, scenario, observer=True)), "Reading.")
    text += _figures(files, ("linear_poles", "Closed-loop poles (o: linearized, x: analytic split)"))
    mm = result["mismatch"]
    perfect = scenario.nominal == scenario.robot
    text += (_h(3, "Inertia mismatch (nominal inertia scaled by a)")
             + _p("All nominal masses and inertias of the scenario are scaled by a (a = 1: the scenario's nominal "
                  "model, " + ("which is the true one, so a is the nominal/true inertia ratio" if perfect else
                               "which already differs from the true one") + f") at q0 = [{_join(mm['q0'], 5)}]. The "
                  "stability boundary is found by a logarithmic scan of a and Brent's method on the sign change of the "
                  "largest pole real part."))
    rows = []
    for key, title in (("with_dob", "with observer"), ("without_dob", "without observer")):
        sweep = mm[key]["sweep"]
        for a, alpha, poles in zip(sweep["factors"], sweep["spectral_abscissa"], sweep["poles"]):
            rows.append([title, _f(a, 4), _f(alpha, 5), _f(min(-p[0] for p in poles), 4),
                         _f(max(-p[0] for p in poles), 4), _f(min(-p[0] / math.hypot(*p) for p in poles), 4)])
        text += _p(stability_text(mm[key]["boundaries"], "the held loop", perfect, prefix=""), f"Stability {title}:")
    text += _table(["loop", "a", "largest real part (rad/s)", "slowest decay (rad/s)", "fastest decay (rad/s)",
                    "smallest damping ratio"], rows, "Poles against inertia mismatch")
    text += _p(_mismatch_reading(mm, perfect), "Reading.")
    text += _figures(files, ("linear_mismatch", "Stability and pole movement against inertia mismatch"))
    return text


def _section_bandwidth(result: dict, files: dict) -> str:
    bw = result["observer_bandwidth"]
    s = bw["slowest_rad_s"]
    fast = bw["fastest_rad_s"]
    rows = [[f"mode {k + 1}", _f(lo, 4), _f(hi, 4), _f(1 / hi, 3), _f(1 / lo, 3)] for k, (lo, hi) in
            enumerate(bw["ranges_rad_s"])]
    sens = ", ".join(f"{k}: {_f(v, 3)}" for k, v in bw["sensitivity_rad_s"].items())
    at = bw["along_trajectory"]
    text = (_h(2, "4. Observer bandwidth across the workspace")
            + _p("On a perfect model the estimation error obeys e_d' = -Y M^-1(q) e_d: the observer's modes decay at "
                 "the eigenvalues of Y M^-1(q). They were computed on a "
                 f"{' x '.join(str(n) for n in bw['grid']['points'])} grid over all four joints.")
            + _table(["mode", "min (rad/s)", "max (rad/s)", "time constant min (s)", "time constant max (s)"], rows,
                     "Eigenvalues of Y M^-1(q) over the workspace")
            + _p(f"Slowest mode: {_f(s['min'], 4)} rad/s at q = [{_join(s['q_at_min'], 4)}], {_f(s['max'], 4)} rad/s "
                 f"at q = [{_join(s['q_at_max'], 4)}]. Along the scenario's path it is {_f(at['min'], 4)} to "
                 f"{_f(at['max'], 4)} rad/s; its direction in disturbance space there is "
                 f"[{_join(at['direction_at_min'], 3)}] (theta1, theta2, d3, theta4): it moves "
                 f"{_mode_text(at['direction_at_min'])}. Largest change of any eigenvalue along each joint axis of "
                 f"the grid (rad/s): {sens}."))
    Y = np.array(bw["Y"])
    scalar = np.allclose(Y, Y[0, 0] * np.eye(4))
    spread = scalar and (s["min"] < 0.99 * Y[0, 0] or fast["max"] > 1.01 * Y[0, 0])
    text += _p((f"A gain Y = {_f(Y[0, 0])} I does not give one bandwidth of {_f(Y[0, 0])} rad/s: " if spread else "")
               + f"the observer's rates are the gain divided by the inertia seen in each modal direction, from "
                 f"{_f(s['min'], 4)} rad/s (slowest mode, moving {_mode_text(s['direction_at_min'])}) to "
                 f"{_f(fast['max'], 4)} rad/s (fastest mode, moving {_mode_text(fast['direction_at_max'])}). A "
                 f"disturbance that acts along the slowest direction is learnt with a time constant of up to "
                 f"{_f(1 / s['min'], 3)} s.", "Reading.")
    text += _figures(files, ("observer_bandwidth", "Observer modes along theta2 and the slowest mode's direction"))
    return text


def _matrix(M) -> str:
    return _table([""] + [f"col {j + 1}" for j in range(len(M))],
                  [[f"row {i + 1}"] + [_f(v, 5) for v in row] for i, row in enumerate(M)])


def _yes_no(value) -> str:
    return "n/a (no error at the start)" if value is None else ("yes" if value else "no")


def _section_design(result: dict, scenario: Scenario, files: dict) -> str:
    d = result["observer_design"]
    cd, cs = d["certificate_designed"], d["certificate_scenario_gain"]
    crit_d, crit_s = d["critical_theta2_speed_designed"], d["critical_theta2_speed_scenario_gain"]
    ranges = d["bandwidth_designed"]["ranges_rad_s"]
    start = "the scenario's gain Y_s plus " if d["base_is_scenario_gain"] else ""
    text = (_h(2, "5. Observer gain design")
            + _p(f"Target: slowest observer mode at least {_f(d['target_rad_s'])} rad/s everywhere on the workspace "
                 f"grid. Design: Y = {start}c M_ref, with M_ref the nominal inertia averaged over the workspace grid "
                 f"(it has the shape of M) and c = {_f(d['c_per_s'], 6)} 1/s the smallest value meeting the target on "
                 "the grid (bisection). "
                 + ("Because Y_s is symmetric positive semidefinite, no mode is slower than with Y_s (Weyl's "
                    "inequality). " if d["base_is_scenario_gain"] else "")
                 + "Modes of Y M^-1(q) over the workspace: "
                 + ", ".join(_f(lo, 4) + " to " + _f(hi, 4) for lo, hi in ranges) + " rad/s.")
            + _p("Designed Y (kg m^2/s, kg/s for joint 3):") + _matrix(d["Y"])
            + _p("Convergence condition of Mohammadi et al. (2013): Y + Y' - M'(q, q') >= 2 beta M(q) gives "
                 "V(t) <= V(0) exp(-2 beta t) with V = e_d' Y^-T M Y^-1 e_d, for a slowly varying disturbance on a "
                 "perfect model. The certificate is the smallest beta over the workspace grid and every vertex of the "
                 "joint-speed box |q'| <= bound (beta is concave in q', so its minimum over the box is at a vertex: "
                 "the check is exact at the grid points).")
            + _table(["", "scenario gain", "designed gain"],
                     [["speed bound (rad/s, rad/s, m/s, rad/s)", _join(d["speed_bound"], 3),
                       _join(d["speed_bound"], 3)],
                      ["certificate beta_min (rad/s)", _f(cs["beta_min_rad_s"], 5), _f(cd["beta_min_rad_s"], 5)],
                      ["  reached at q", _join(cs["q_at"], 4), _join(cd["q_at"], 4)],
                      ["  and q'", _join(cs["dq_at"], 3), _join(cd["dq_at"], 3)],
                      ["condition holds", "yes" if cs["holds"] else "no", "yes" if cd["holds"] else "no"],
                      ["beta at rest, min (rad/s)", _f(cs["beta_at_rest_min_rad_s"], 5),
                       _f(cd["beta_at_rest_min_rad_s"], 5)],
                      ["largest |theta2'| keeping beta > 0 (rad/s)",
                       "unlimited" if crit_s.get("unlimited") else _f(crit_s["speed_factor"], 5),
                       "unlimited" if crit_d.get("unlimited") else _f(crit_d["speed_factor"], 5)]],
                     "Convergence certificate"))
    sims = d["simulation"]
    first = next(iter(sims.values()), None)
    if first is not None:
        own = _kinds(scenario.data["disturbance"]["kind"])
        used = _kinds(first["disturbance_kind"])
        if used == own:
            what = f"the scenario's disturbance ({_and(used) if used else 'none'})"
        else:
            what = (f"the constant step f_r = [{_join(first['f_r'], 4)}] (N m, N m, N, N m; the paper's Eq. 4) in "
                    f"place of the scenario's disturbance models ({_and(own) if own else 'none'})"
                    if used == ["paper"] else f"the disturbance {_and(used) if used else 'none'}")
        text += _p(f"Nonlinear simulation of the scenario's path (first {_f(first['time'][-1], 4)} s, noise removed) "
                   f"with {what}: time to get within {_f(100 * first['threshold'], 2)}% of the largest disturbance, "
                   "and whether V(t) stays below the certified decay over the states the run visited.")
    rows = [[label, _f(run["beta_run_rad_s"], 4),
             "not within the run" if run["convergence_time_s"] is None else _f(run["convergence_time_s"], 4),
             _join(run["rms_disturbance_error"], 3), _yes_no(run["bound_holds"])]
            for label, run in sims.items()]
    text += _table(["gain", "beta over the visited states (rad/s)", "time to 2% (s)",
                    "RMS d - d_hat (N m, N m, N, N m)", "V(t) <= V(0) exp(-2 beta t)"], rows,
                   "Nonlinear simulation with each gain")
    text += _figures(files, ("observer_design", "Estimation error and Lyapunov certificate in simulation"))
    return text


def _frequency_reading(fr: dict, stable: bool) -> str:
    wo, w, est = (fr[k]["metrics"] for k in ("tracking_without_dob", "tracking_with_dob", "estimation_with_dob"))
    dc_w = abs(w[2]["dc_gain"])
    zero = stable and dc_w <= ZERO_REL * w[2]["peak_gain"]
    text = (f"A constant force of 1 N on the prismatic joint leaves {_f(-1e3 * wo[2]['dc_gain'], 4)} mm of depth error "
            "without the observer and " + ("none with it. " if zero else f"{_f(1e3 * dc_w, 4)} mm with it. "))
    if all(m["kind"] == "band-pass" for m in w):
        text += ("With the observer, disturbances reach the tracking error only in a band around "
                 f"{', '.join(_f(m['peak_rad_s'], 3) for m in w)} rad/s (joints 1-4; at most "
                 f"{', '.join(_f(m['peak_gain'], 3) for m in w)} per unit disturbance): slower ones are estimated and "
                 "cancelled, faster ones are filtered by the arm's inertia. ")
    else:
        text += ("With the observer the disturbance-to-error responses are " + ", ".join(m["kind"] for m in w)
                 + " (joints 1-4). ")
    if all(m["kind"] == "high-pass" for m in est):
        corners = ", ".join(_f(m["band_3db_rad_s"][0], 3) for m in est)
        text += (f"The estimate follows a disturbance only below {corners}"
                 " rad/s (joints 1-4; -3 dB), the observer bandwidth seen from each joint.")
    else:
        text += ("The estimation-error responses are " + ", ".join(m["kind"] for m in est) + " (joints 1-4).")
    return text


def _section_frequency(result: dict, scenario: Scenario, files: dict) -> str:
    fr = result["frequency"]
    text = (_h(2, "6. Disturbance rejection in frequency")
            + _p(f"Transfer functions of the loop linearized with the arm held at q0 = [{_join(fr['q0'], 5)}], from a "
                 "torque/force w[i] added at joint i to the tracking error e[i] = q_ref[i] - q[i] and to the "
                 "estimation error. Closed forms (perfect model): without observer E = -(s^2 + Kd s + Kp)^-1 M^-1 W; "
                 "with observer E = -s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1 W and E_d = s M (s M + Y)^-1 W."))
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
                         m["kind"], f"{_f(band[0], 4)} to {'inf' if band[1] is None else _f(band[1], 4)}"])
        rows.append([title, "closed form", "", "", "", "", "largest relative difference",
                     _f(data["closed_form_max_rel_error"], 2)])
    text += _table(["response", "joint", "unit", "DC gain", "peak gain", "peak at (rad/s)", "kind",
                    "-3 dB band (rad/s)"], rows, "Per-joint disturbance responses")
    stable = _max_real(result["operating_points"][0]["poles_with_dob"]) < 0
    for observer, key, name in ((True, "tracking_with_dob", "with"), (False, "tracking_without_dob", "without")):
        caveats = split_caveats(result, scenario, observer)
        err = _f(fr[key]["closed_form_max_rel_error"], 2)
        if caveats:
            text += _p(f"The closed forms assume a perfect model, a disturbance that does not depend on the arm's "
                       f"state and the arm resting at q0; {name} the observer {_and(caveats)}, so they are only "
                       f"approximate (largest relative difference {err}).")
        else:
            text += _p(f"{name.capitalize()} the observer the linearized responses equal the closed forms (largest "
                       f"relative difference {err}).")
    text += _p(_frequency_reading(fr, stable), "Reading.")
    text += _figures(files, ("frequency_tracking", "Disturbance to tracking error, per joint"),
                            ("frequency_estimation", "Disturbance to estimation error, per joint"))
    return text


def _study_definition(st: dict, scenario: Scenario) -> str:
    g = st["gains_with_dob"]
    own = _kinds(scenario.data["disturbance"]["kind"])
    where = ("which is the scenario's own disturbance" if own == ["paper"] else
             f"in place of the scenario's disturbance models ({_and(own) if own else 'none'})")
    return (f"Every run holds the arm at the scenario's reference at t = 0, q_hold = [{_join(g['q_hold'], 4)}] "
            f"(rad, rad, m, rad), and applies the constant disturbance step f_r = [{_join(g['f_r'], 4)}] (N m, N m, "
            f"N, N m; the paper's Eq. 4) from t = 0, {where}, for "
            f"{_f(g['t_final_s'])} s; models, noise-free sensors and solver settings are the scenario's. The arm "
            "starts at rest with d_hat = 0. Final value: the error where the held loop comes to rest (its "
            "equilibrium, computed); steady-state error: its size. Settling time: from then on the error stays within "
            f"{_f(100 * g['settle_fraction'])}% of its largest deviation from the final value; 'not settled' when the "
            f"error is still outside that band during the last {_f(100 * g['final_window'])}% of the run. Tool-tip "
            "position error in mm.")


def _section_studies(result: dict, scenario: Scenario, files: dict) -> str:
    st = result["studies"]
    text = _h(2, "7. Gain and noise studies") + _p(_study_definition(st, scenario))
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
                rows.append([title, _f(kp), _f(kd), _settling(m["settling_time_s"]), _f(m["steady_state_error"], 3),
                             _f(m["peak_error"], 3), _f(m["rms_error"], 3)])
    text += _figures(files, ("study_gains", "Gain study heat maps (the numbers are in the table below)"))
    text += _details("Kp x Kd study as a table",
                     _table(["observer", "Kp (1/s^2)", "Kd (1/s)", "settling time (s)", "steady-state (mm)",
                             "peak (mm)", "RMS (mm)"], rows, "Kp x Kd study (tool tip)"))
    reading = _gain_reading(st)
    if reading:
        text += _p(reading, "Reading.")
    obs = st["observer"]
    noise = obs["noise"]
    text += _p(f"Observer gain and measurement noise: the same step experiment ({_f(obs['t_final_s'])} s runs) for "
               f"each observer gain. Torque noise: runs of the first {_f(obs['noise_t_final_s'])} s with noise on q of "
               f"standard deviations {_join(noise['q_std'])} (rad, rad, m, rad) and on q' of "
               f"{_join(noise['dq_std'])} (rad/s, rad/s, m/s, rad/s), sampled every "
               f"{_f(noise.get('sample_period', 0.001))} s, seed {noise.get('seed', 0)}; torque noise = RMS of the "
               "torque difference between the noisy and the clean run.")
    rows = []
    for k, label in enumerate(obs["labels"]):
        r = obs["runs"][k]
        if not r.get("ok"):
            rows.append([label, "failed"] + [""] * 7)
            continue
        m = r["tool_mm"]
        rows.append([label, _f(obs["slowest_mode_rad_s"][k], 4), _settling(m["settling_time_s"]),
                     _f(m["peak_error"], 3), _f(m["rms_error"], 3), _f(r["clean_short"]["tool_mm"]["rms_error"], 3),
                     _f(r["noisy"]["tool_mm"]["rms_error"], 3), _join(r["torque_noise_rms"], 3)])
    text += _table(["observer gain", "slowest mode (rad/s)", "settling (s)", "peak (mm)", "RMS (mm)",
                    f"RMS, first {_f(obs['noise_t_final_s'])} s (mm)", "same, with noise (mm)",
                    "torque noise RMS (N m, N m, N, N m)"], rows, "Observer gain study (tool tip)")
    reading = _observer_reading(obs, scenario)
    if reading:
        text += _p(reading, "Reading.")
    text += _figures(files, ("study_observer", "Error against torque noise for each observer gain"))
    return text


def _observer_reading(obs: dict, scenario: Scenario) -> str | None:
    ok = [k for k, r in enumerate(obs["runs"]) if r.get("ok") and obs["labels"][k] != "none"]
    if not ok or not obs["runs"][0].get("ok"):
        return None
    base = obs["runs"][0]["torque_noise_rms"]
    fastest = max(ok, key=lambda k: obs["slowest_mode_rad_s"][k])
    slowest = min(ok, key=lambda k: obs["slowest_mode_rad_s"][k])
    p_slow = obs["runs"][slowest]["tool_mm"]["peak_error"]
    p_fast = obs["runs"][fastest]["tool_mm"]["peak_error"]
    verb = "falls" if p_fast < p_slow else ("rises" if p_fast > p_slow else "stays")
    ratio = [n / b if b > 0 else float("nan") for n, b in zip(obs["runs"][fastest]["torque_noise_rms"], base)]
    text = (f"From the slowest observer tested ({obs['labels'][slowest]}) to the fastest ({obs['labels'][fastest]}) "
            f"the peak tool-tip error after the step {verb} from {_f(p_slow, 3)} to {_f(p_fast, 3)} mm, and the torque "
            f"noise is {', '.join(_f(r, 3) for r in ratio)} times its value without the observer (joints 1-4)")
    finite = [r if math.isfinite(r) else -math.inf for r in ratio]
    j = int(np.argmax(finite))
    if finite[j] > 1:
        M = inertia(np.asarray(obs["q_hold"], dtype=float), scenario.nominal)
        lightest = int(np.argmin(np.diag(M))) == j
        text += (f". The relative increase is largest on joint {j + 1}"
                 + (", the joint with the smallest inertia: the observer adds Y q' velocity noise to the "
                    "controller's M Kd q' noise, and Y / (M Kd) is largest where M is smallest" if lightest else "")
                 )
    return text + "."


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
    spread = max((max(v) - min(v)) / max(v) if max(v) > 0 else 0.0 for v in by_kp.values())
    text = (f"Without the observer the tool tip comes to rest {offsets}; across Kd it changes by at most "
            f"{_f(100 * spread, 2)}% at a given Kp. With the observer it comes to rest "
            + ("exactly on its target" if max(c[2]["steady_state_error"] for c in w) == 0 else
               f"at most {_f(max(c[2]['steady_state_error'] for c in w), 3)} mm from its target")
            + " for every pair; ")
    best_peak = min(w, key=lambda c: c[2]["peak_error"])
    text += f"the smallest peak error is {_f(best_peak[2]['peak_error'], 3)} mm (Kp = {_f(best_peak[0])}, " \
            f"Kd = {_f(best_peak[1])})"
    settled = [c for c in w if c[2]["settling_time_s"] is not None]
    if settled:
        best_ts = min(settled, key=lambda c: c[2]["settling_time_s"])
        text += f", the shortest settling time {_f(best_ts[2]['settling_time_s'], 3)} s (Kp = {_f(best_ts[0])}, " \
                f"Kd = {_f(best_ts[1])})"
    if len(settled) < len(w):
        text += f" ({len(w) - len(settled)} of {len(w)} pairs not settled within the run)"
    best_rms = min(w, key=lambda c: c[2]["rms_error"])
    return text + f", the smallest RMS error {_f(best_rms[2]['rms_error'], 3)} mm (Kp = {_f(best_rms[0])}, " \
                  f"Kd = {_f(best_rms[1])})."


def render_html(result: dict, experiment: dict, scenario: Scenario, figure_files: dict,
                extra_sections: tuple[str, ...] = ()) -> str:
    """The report as one HTML string (figures embedded from the PNG files named in ``figure_files``).

    Parameters
    ----------
    result : dict
        From :func:`analysis.report.run_analysis`.
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
    summary = "".join(f"<li>{esc(line)}</li>" for line in plain_summary(result, experiment, scenario))
    body = (_h(1, f"dobkit analysis report: scenario '{scenario.name}'")
            + f"<p class='note'>{esc('dobkit ' + result['dobkit_version'] + ', python-control ')}"
              f"{esc(result['python_control_version'])}. Regenerate with <code>"
              f"{esc(f'dobkit report --scenario {scenario.source}')}</code>. Every number below is computed from the "
              "scenario.</p>"
            + "<div class='summary'>" + _h(2, "Summary for the surgical team", "margin-top:.4em")
            + f"<ul>{summary}</ul></div>"
            + _section_scenario(scenario, result) + _section_simulation(result, experiment, scenario, figure_files)
            + _section_linear(result, scenario, figure_files) + _section_bandwidth(result, figure_files)
            + _section_design(result, scenario, figure_files) + _section_frequency(result, scenario, figure_files)
            + _section_studies(result, scenario, figure_files) + "".join(extra_sections))
    title = esc("dobkit report: " + scenario.name)
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{title}"
            f"</title><style>{_CSS}</style></head><body>{body}</body></html>\n")
