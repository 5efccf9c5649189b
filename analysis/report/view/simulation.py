"""Section 2 of the report: the scenario simulated with and without the observer (Table 3 layout, Figures 4-8).

The joints (count, names, units) are the scenario's arm's.  The paper's arm
gets the paper's Table 3 layout (one column per joint); any other arm one row
per joint, which fits any number of joints.

:func:`worse_with_observer` explains, from the numbers, each joint that the
observer makes worse along the path; :func:`worse_with_observer_short` is the
summary's one-sentence version of it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.simulation.figures import has_tissue_model
from blocks.model.joints import JointSpace

from .text import Figure, Table, column, figures, fmt, is_paper_arm
from .text import value as _value

__all__ = ["SimulationSection", "simulation_section", "worse_with_observer", "worse_with_observer_short",
           "figure8_caption"]


@dataclass(frozen=True)
class SimulationSection:
    """2. Table 3 layout for the scenario's path, joints made worse by the observer, the tool tip, Figures 4-8."""

    metrics: Table
    worse: list[str]
    tool: Table | None
    figures: list[Figure]
    #: What the table is set against: the paper's Table 3 (the paper's arm) or this arm's joints.
    intro: str = ""


def _worse_joints(experiment: dict) -> list[int]:
    w, wo = experiment["with_dob"], experiment["without_dob"]
    return [j for j in range(len(w["rms_position_error"]))
            if w["rms_position_error"][j] > wo["rms_position_error"][j]]


def _is_transient(experiment: dict, j: int) -> bool:
    """Whether joint j's error with the observer is a start-up transient: largest in the first half of the run and
    less than half as large at its end."""
    w = experiment["with_dob"]
    duration, t_max = experiment.get("duration_s"), w.get("time_of_max_abs_position_error")
    early = t_max is not None and duration is not None and t_max[j] <= 0.5 * duration
    return early and w["final_abs_position_error"][j] < 0.5 * w["max_abs_position_error"][j]


def worse_with_observer(result, experiment: dict, scenario) -> list[str]:
    """One statement per joint whose RMS position error along the path is larger with the observer than without.

    The explanation is built from the numbers: the offset the disturbance leaves
    on the joint without the observer (held at the path's start, ``M^-1 d / Kp``)
    against what the joint's own disturbance alone would leave, and whether the
    error with the observer is a start-up transient (largest early in the run,
    small at its end) while the observer learns the disturbance at the rate of
    its slowest mode along the path.
    """
    if not _worse_joints(experiment):
        return []
    joints = scenario.robot.joints
    titles = joints.labels

    def value(x, j):
        return _value(x, j, joints=joints)

    w, wo = experiment["with_dob"], experiment["without_dob"]
    op = result.operating_points[0]
    at = result.observer_bandwidth.along_trajectory
    q0 = np.asarray(op.q0, dtype=float)
    offset = np.asarray(op.q_equilibrium_without_dob, dtype=float) - q0
    d = np.asarray(op.disturbance_at_rest, dtype=float)
    own = np.abs(np.diag(np.linalg.inv(scenario.nominal.inertia(q0))) * d) / np.diag(scenario.kp)
    t_max = w.get("time_of_max_abs_position_error")
    lines = []
    for j in _worse_joints(experiment):
        r_w, r_wo = w["rms_position_error"][j], wo["rms_position_error"][j]
        text = (f"On {titles[j]} the observer makes the position error along the path worse: "
                f"RMS {value(r_w, j)} with it against {value(r_wo, j)} without.")
        if np.max(np.abs(d)) > 0:
            text += (f" Held at the path's start, the disturbance leaves this joint only {value(abs(offset[j]), j)} "
                     "off without the observer (where it comes to rest: M^-1 d / Kp, M at the rest pose)")
            if abs(offset[j]) < 0.5 * own[j]:
                text += (f": through the arm's coupled inertia the disturbances on the other joints nearly cancel "
                         f"this joint's own, which alone would leave {value(own[j], j)}")
            text += "."
        peak, final = w["max_abs_position_error"][j], w["final_abs_position_error"][j]
        if _is_transient(experiment, j):
            text += (f" With the observer the error is a start-up transient: the observer starts from d_hat = 0 and "
                     f"learns the disturbance at the rate of its modes, the slowest {fmt(at.min, 3)} to "
                     f"{fmt(at.max, 3)} rad/s along the path (time constant up to {fmt(1 / at.min, 3)} s), and the "
                     f"part not yet learned moves this joint by up to {value(peak, j)} (at t = {fmt(t_max[j], 3)} s; "
                     f"{value(final, j)} at the end of the run).")
        else:
            text += (f" With the observer the error reaches {value(peak, j)}"
                     + (f" at t = {fmt(t_max[j], 3)} s" if t_max is not None else "")
                     + f" and is {value(final, j)} at the end of the run.")
        lines.append(text)
    return lines


def worse_with_observer_short(experiment: dict, joints: JointSpace) -> str | None:
    """The summary's sentence on the joints the observer makes worse along the path (None if there are none).

    ``joints`` are the arm's: their names and position units.
    """
    worse = _worse_joints(experiment)
    if not worse:
        return None

    def value(x, j):
        return _value(x, j, joints=joints)

    w, wo = experiment["with_dob"], experiment["without_dob"]
    parts = []
    for j in worse:
        part = (f"{joints.labels[j]}, RMS error {value(w['rms_position_error'][j], j)} with it against "
                f"{value(wo['rms_position_error'][j], j)} without")
        if _is_transient(experiment, j):
            t = w["time_of_max_abs_position_error"][j]
            part += (f", and only while the observer is still learning the disturbance after the start (largest at "
                     f"t = {fmt(t, 3)} s, {value(w['final_abs_position_error'][j], j)} at the end)")
        parts.append(part)
    lead = "one joint" if len(worse) == 1 else f"{len(worse)} joints"
    text = f"The observer makes {lead} worse along the path: " + "; ".join(parts) + "."
    tool_w, tool_wo = w.get("rms_tool_position_error_mm"), wo.get("rms_tool_position_error_mm")
    if tool_w is not None and tool_w < tool_wo:
        text += " The tool tip as a whole still gains from the observer (first point)."
    return text + " Section 2 explains why."


def figure8_caption(experiment: dict, scenario) -> str:
    """Figure 8's caption; where the path dips below a skin that the scenario does not model, it says so."""
    caption = "Figure 8: tool-tip path in task space"
    skin = getattr(scenario.trajectory, "skin_height", None)
    if skin is None or has_tissue_model(scenario):
        return caption
    depth = experiment.get("max_depth_below_skin_mm")
    caption += (". The skin is the plane z = " + fmt(1e3 * skin, 4) + " mm (dotted). This scenario has no tissue "
                "model: nothing resists the tool below the skin")
    if depth:
        caption += (f", so the depths are those of a tool moving freely: at most {fmt(depth['reference'], 3)} mm "
                    f"below the skin as planned, {fmt(depth['with_dob'], 3)} mm with the observer and "
                    f"{fmt(depth['without_dob'], 3)} mm without it. Real tissue would push back (the 'tissue' "
                    "disturbance model)")
    return caption + "."


def _one_notation(columns: list) -> list[list[str]]:
    """Columns of numbers written in one notation for the whole table: scientific for every number when any one
    needs it (a table of 1.611e-04 beside 0.000233 reads as two kinds of number), else fixed.

    Examples
    --------
    >>> _one_notation([[0.0001611, 0.25], [0.0000233, 1.5]])
    [['1.611e-04', '2.500e-01'], ['2.330e-05', '1.500e+00']]
    >>> _one_notation([[0.339, 0.25], [1.5, None]])
    [['0.339', '0.25'], ['1.5', '-']]
    """
    flat = column([v for values in columns for v in values])
    out, k = [], 0
    for values in columns:
        out.append(flat[k:k + len(values)])
        k += len(values)
    return out


def _table_3_layout(numbers: list, joints: JointSpace) -> Table:
    """The paper's Table 3 layout: one column per joint, a row of units under the position and the force rows."""
    n = joints.count
    columns = _one_notation([[values[j] for _, values in numbers] for j in range(n)])
    text = [[name] + [columns[j][k] for j in range(n)] for k, (name, _) in enumerate(numbers)]
    rows = text[:4] + [["  units"] + [f"({u})" for u in joints.position_units]]
    if len(text) > 4:
        rows += [text[4], ["  units"] + [f"({u})" for u in joints.force_units]]
    return Table.of(["Table 3 layout"] + list(joints.labels), rows, "Tracking metrics per joint")


def _joint_rows(numbers: list, joints: JointSpace) -> Table:
    """Table 3 turned for any arm: one row per joint with its units, one column per metric."""
    n = joints.count
    columns = _one_notation([values for _, values in numbers])
    header = ["joint", "position unit"] + [name for name, _ in numbers[:4]]
    if len(numbers) > 4:
        header += ["force unit", numbers[4][0]]
    rows = []
    for j in range(n):
        row = [joints.labels[j], joints.position_units[j]] + [columns[k][j] for k in range(4)]
        if len(numbers) > 4:
            row += [joints.force_units[j], columns[4][j]]
        rows.append(row)
    return Table.of(header, rows, f"Tracking metrics per joint ({n} joints)")


def simulation_section(result, experiment: dict, scenario, files: dict) -> SimulationSection:
    joints = scenario.robot.joints
    w, wo = experiment["with_dob"], experiment["without_dob"]
    numbers = [("RMS position error, with observer", w["rms_position_error"]),
               ("RMS position error, without observer", wo["rms_position_error"]),
               ("largest position error, with observer", w["max_abs_position_error"]),
               ("largest position error, without observer", wo["max_abs_position_error"])]
    if "rms_disturbance_error" in w:
        numbers.append(("RMS disturbance error d - d_hat, with observer", w["rms_disturbance_error"]))
    given = {len(values) for _, values in numbers}
    if given != {joints.count}:
        raise ValueError(f"the experiment's metrics hold {sorted(given)} joints; the scenario's arm has "
                         f"{joints.count} ({', '.join(joints.names)})")
    paper = is_paper_arm(scenario)
    if paper:
        intro = ("The nonlinear Figure-2 loop simulated with and without the observer. Table 3 of the paper lists "
                 "RMS errors (Eq. 13-14) for its own laceration path, which the paper does not give; the table below "
                 "has the same layout for this scenario's path.")
    else:
        intro = (f"The nonlinear Figure-2 loop simulated with and without the observer, for this scenario's arm of "
                 f"{joints.count} joints: RMS errors as in the paper's Eq. 13-14, one row per joint. The paper's "
                 "Table 3 is for its own 4-joint arm and is not compared here.")
    tool = None
    if "max_tool_position_error_mm" in w:
        tool = Table.of(["tool tip", "with observer", "without observer"],
                        [["largest position error (mm)", fmt(w["max_tool_position_error_mm"]),
                          fmt(wo["max_tool_position_error_mm"])],
                         ["RMS position error (mm)", fmt(w["rms_tool_position_error_mm"]),
                          fmt(wo["rms_tool_position_error_mm"])]])
    return SimulationSection(
        metrics=_table_3_layout(numbers, joints) if paper else _joint_rows(numbers, joints),
        worse=worse_with_observer(result, experiment, scenario), tool=tool,
        figures=figures(files, ("fig4_joint_tracking", "Figure 4: joint tracking, with and without the observer "
                                                       "(the reference is the grey band)"),
                        ("fig5_tracking_error", "Figure 5: tracking error q_ref - q"),
                        ("fig6_disturbance_estimate", "Figure 6: lumped disturbance d (grey band) and its estimate "
                                                      "d_hat"),
                        ("fig7_estimation_error", "Figure 7: estimation error d - d_hat"),
                        ("fig8_task_space", figure8_caption(experiment, scenario))),
        intro=intro)
