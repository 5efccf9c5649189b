"""The summary for the surgical team: short statements computed from the numbers.

Each statement leads with plain words and millimetres (what the tool tip
does, how long the observer takes) and per-second rates; control notation (poles, ``M^-1 d / Kp``,
``d_hat``) stays in the numbered sections, a gain's name at most in parentheses.  A statement is only
made where the numbers support it.
"""
from __future__ import annotations

import numpy as np

from .simulation import worse_with_observer_short
from .text import (
    ZERO_REL,
    and_words,
    arm_joints,
    fmt,
    is_paper_arm,
    join,
    kinds,
    mode_text,
    span,
    split_caveats,
    stable_ranges,
    units_list,
)

__all__ = ["plain_summary"]


def _tool_offset_mm(q_a, q_b, robot) -> float:
    p = np.asarray(robot.tool_position(np.array([q_a, q_b], dtype=float)))
    return float(1e3 * np.linalg.norm(p[0, :3] - p[1, :3]))


def _tool_tip(experiment: dict) -> str | None:
    w, wo = experiment["with_dob"], experiment["without_dob"]
    if "max_tool_position_error_mm" not in w:
        return None
    return (f"Along the scenario's path the tool tip strays at most {fmt(w['max_tool_position_error_mm'], 3)} mm from "
            f"where it should be with the disturbance observer, and {fmt(wo['max_tool_position_error_mm'], 3)} mm "
            f"without it (RMS {fmt(w['rms_tool_position_error_mm'], 3)} mm against "
            f"{fmt(wo['rms_tool_position_error_mm'], 3)} mm).")


def _growth(rate: float) -> str:
    """How an unstable held arm's error grows, in words, from the largest pole real part ``rate`` (1/s, >= 0).

    >>> _growth(0.5), _growth(0.0)
    ('error grows by a factor e every 2 s', 'error does not die out')
    """
    return f"error grows by a factor e every {fmt(1 / rate, 3)} s" if rate > 0 else "error does not die out"


def _held_offset(result, scenario) -> str:
    op = result.operating_points[0]
    d = np.asarray(op.disturbance_at_rest, dtype=float)
    found = kinds(scenario.data["disturbance"]["kind"])
    if not np.max(np.abs(d)) > 0:
        why = (f"the scenario's disturbance models ({and_words(found)}) give zero force on the arm at rest there"
               if found else "the scenario has no disturbance model")
        return (f"Held still at the start of the path the arm feels no disturbance ({why}), so it rests on its "
                "target with or without the observer. The design check and the studies below apply a constant "
                "disturbance step instead.")
    text = ""
    if op.largest_real_part(False) < 0:
        offset = _tool_offset_mm(op.q_equilibrium_without_dob, op.q0, scenario.robot)
        # the paper's arm inserts the tool along joint 3 (d3): that part of the offset is its depth
        depth = (f" ({fmt(1e3 * (op.q_equilibrium_without_dob[2] - op.q0[2]), 3)} mm of it in depth, along the tool "
                 "axis)") if is_paper_arm(scenario) else ""
        text += (f"Held still at the start of the path against the disturbance, the tool tip without the observer "
                 f"settles {fmt(offset, 3)} mm from its target{depth} and stays there as long as the disturbance "
                 "acts; a stiffer position control (larger Kp) shrinks that offset in proportion, more damping "
                 "(Kd) does not change it.")
        scale = offset
    else:
        text += (f"Held still at the start of the path, the arm without the observer does not stay put: a small "
                 f"{_growth(op.largest_real_part(False))} (section 3).")
        scale = 1.0
    if op.largest_real_part(True) >= 0:
        return text + (f" With the observer it does not stay put there either: a small "
                       f"{_growth(op.largest_real_part(True))} (section 3).")
    offset_w = _tool_offset_mm(op.q_equilibrium_with_dob, op.q0, scenario.robot)
    if offset_w <= ZERO_REL * max(scale, 1e-3):
        return text + " With the observer the tool tip comes back onto its target (section 6)."
    return text + f" With the observer it rests {fmt(offset_w, 3)} mm from its target."


def _speed(result, scenario) -> str:
    slow = result.observer_bandwidth.slowest_rad_s
    pd = result.operating_points[0].pd_slowest_analytic_rad_s()
    text = (f"The observer needs {span(1 / slow.max, 1 / slow.min)} s (its slowest time constant) to learn a new "
            "disturbance; until then part of the disturbance still moves the tool. Its slowest rate is "
            f"{fmt(slow.min, 3)} to {fmt(slow.max, 3)} per second across the workspace, slowest for a disturbance "
            f"on {mode_text(slow.direction_at_min)}. ")
    if slow.max < pd:
        text += (f"It is {fmt(pd / slow.max, 3)} to {fmt(pd / slow.min, 3)} times slower than the position control "
                 f"(which pulls the tool back at {fmt(pd, 3)} per second at the slowest): the observer, not the "
                 "position control's stiffness, limits how fast a disturbance is rejected.")
    elif slow.min > pd:
        text += (f"It is faster than the position control everywhere (which pulls the tool back at {fmt(pd, 3)} "
                 "per second at the slowest): the position control's stiffness, not the observer, limits how fast a "
                 "disturbance is rejected.")
    else:
        text += (f"The position control pulls the tool back at {fmt(pd, 3)} per second at the slowest, inside "
                 "that range: in part of the workspace the observer is the slower of the two.")
    caveats = split_caveats(result, scenario, observer=True)
    if caveats:
        text += (f" Both rates assume the controller knows the arm exactly; here {and_words(caveats)}, so the "
                 "actual rates differ somewhat (section 3).")
    return text


def _rate_along_path(result, scenario) -> str | None:
    """Why a scenario's ``observer_bandwidth`` can learn a disturbance slowly on its path (plain words).

    ``observer_bandwidth = w`` makes the gain ``Y = w M^(q0)``: every observer rate is ``w`` at the start of the
    path and only there, since ``Y M^-1(q)`` changes with the arm's inertia.  Where the path takes the arm to
    a configuration of larger inertia (a base joint with the arm stretched out), the slowest rate falls;
    four time constants (98 %) of that rate is how long learning a disturbance takes there.
    """
    gains = getattr(scenario, "user_data", {}).get("gains", {})
    at = getattr(result.observer_bandwidth, "along_trajectory", None)
    if "observer_bandwidth" not in gains or at is None:
        return None
    w = float(gains["observer_bandwidth"])
    if not at.min < 0.5 * w:
        return None
    k = int(np.argmin(at.slowest_rad_s))
    return (f"The scenario's observer_bandwidth sets the observer's rate to {fmt(w, 3)} per second at the start of "
            f"the path only (the gain is scaled to the arm's inertia there). Along the path the inertia changes and "
            f"the slowest rate falls to {fmt(at.min, 3)} per second (t = {fmt(at.time[k], 3)} s, a disturbance on "
            f"{mode_text(at.direction_at_min)}), so learning a disturbance there takes up to "
            f"{fmt(4.0 / at.min, 2)} s; a gain designed over the whole workspace (section 5) keeps every rate at "
            f"or above its target.")


def _design(result, joints) -> str | None:
    design = result.observer_design
    sim = design.simulation
    base, new = sim.get("scenario gain"), sim.get("designed")
    if not (base and new):
        return None

    def took(run) -> str:
        t = run.convergence_time_s
        return f"{fmt(t, 3)} s" if t is not None else f"more than the {fmt(run.time[-1], 3)} s simulated"
    pct = fmt(100 * new.threshold, 2)
    if new.convergence_time_s is not None:
        text = (f"A faster observer gain can be designed: with it the estimate of a constant disturbance on the path is "
                f"within {pct} % of the disturbance after {took(new)}, against {took(base)} with the scenario's "
                "gain.")
    else:
        text = (f"A designed observer gain was tried: with it the estimate of a constant disturbance on the path takes "
                f"{took(new)} to get within {pct} % of the disturbance, against {took(base)} with the scenario's "
                "gain.")
    cert = design.certificate_designed
    text += (f" (With the designed gain the observer learns at {fmt(design.slowest_rad_s, 3)} per second or faster "
             "anywhere in the workspace")
    if cert.holds:
        text += (f"; if the controller knew the arm exactly, and for disturbances that change slowly, its error is "
                 f"guaranteed to shrink at {fmt(cert.beta_min_rad_s, 3)} per second or faster while the joints move "
                 f"no faster than {join(design.speed_bound, 3)} ({units_list(joints.velocity_units)}).)")
    else:
        text += (f"; no such guarantee holds for joint speeds up to {join(design.speed_bound, 3)} "
                 f"({units_list(joints.velocity_units)}): it fails at the joint positions [{join(cert.q_at, 3)}].)")
    return text


def _noise(result, joints) -> str | None:
    obs = result.studies.observer
    labels, runs = obs.labels, obs.runs
    k_ref = next((k for k, label in enumerate(labels) if label.endswith("(scenario)")), None)
    if "designed Y" not in labels or k_ref is None:
        return None
    k_new = labels.index("designed Y")
    if not (runs[k_ref].ok and runs[k_new].ok) or runs[k_ref].torque_noise_rms is None:
        return None
    n_ref, n_new = runs[k_ref].torque_noise_rms, runs[k_new].torque_noise_rms
    units = "RMS: " + units_list(joints.force_units)
    if all(a > b > 0 for a, b in zip(n_new, n_ref)):
        more = [100 * (a / b - 1) for a, b in zip(n_new, n_ref)]
        return (f"The price of the faster gain is torque noise: with the assumed sensor noise the joint torques jitter "
                f"{span(min(more), max(more), 2)} % more with the designed gain than with the scenario's "
                f"({join(n_new, 3)} against {join(n_ref, 3)}; {units}).")
    return (f"With the assumed sensor noise the joint torques jitter by {join(n_new, 3)} with the designed gain "
            f"against {join(n_ref, 3)} with the scenario's gain ({units}).")


def _robustness(result, scenario) -> str:
    perfect = scenario.nominal == scenario.robot
    ref = "the true one" if perfect else "the scenario's nominal inertia"
    lo, hi = result.mismatch.with_dob.boundaries.range
    parts = []
    for observer, name in ((True, "with"), (False, "without")):
        search = result.mismatch.loop(observer).boundaries
        ranges = stable_ranges(search)
        if ranges == [tuple(search.range)]:
            parts.append(f"{name} the observer for every factor searched")
        elif not ranges:
            parts.append(f"{name} the observer for none")
        else:
            parts.append(f"{name} the observer only for factors " + " and ".join(f"{fmt(a, 4)} to {fmt(b, 4)}"
                                                                                 for a, b in ranges))
    return (f"Model error: if the controller's model of the arm's inertia is off by a factor from {fmt(lo)} to "
            f"{fmt(hi)} times {ref} (the range searched, arm held at the start of the path), the loop stays stable "
            + " and ".join(parts) + " (section 3).")


def _gains(result) -> str | None:
    g_w, g_wo = result.studies.gains_with_dob, result.studies.gains_without_dob
    ok_w = [r for row in g_w.runs for r in row if r.ok]
    ok_wo = [r for row in g_wo.runs for r in row if r.ok]
    if not (ok_w and ok_wo):
        return None
    ss_wo = [r.tool_mm.steady_state_error for r in ok_wo]
    ss_w = [r.tool_mm.steady_state_error for r in ok_w]
    settled = [r.tool_mm.settling_time_s for r in ok_w if r.tool_mm.settling_time_s is not None]
    text = (f"Gains: held at the start of the path and hit by a constant disturbance, the tool tip comes to rest "
            f"{span(min(ss_wo), max(ss_wo))} mm from its target without the observer and "
            + ("exactly on it with the observer" if max(ss_w) == 0 else f"at most {fmt(max(ss_w), 3)} mm from it with "
                                                                        "the observer"))
    if settled:
        text += f"; with the observer it settles in {span(min(settled), max(settled))} s"
    if len(settled) < len(ok_w):
        text += f" ({len(ok_w) - len(settled)} of {len(ok_w)} gain pairs not settled within the run)"
    return text + (f" (over the position-control stiffnesses and dampings of section 7, runs of "
                   f"{fmt(g_w.t_final_s)} s; settling time as defined there).")


def plain_summary(result, experiment: dict, scenario) -> list[str]:
    """Short statements, computed from the numbers, on what they mean for the surgeon's tool (plain text).

    Parameters
    ----------
    result : analysis.report.build.AnalysisResult
    experiment : dict
        The experiment's metrics (see :func:`analysis.report.view.build_view`).
    scenario : Scenario
    """
    joints = arm_joints(scenario)
    lines = [_tool_tip(experiment), worse_with_observer_short(experiment, joints), _held_offset(result, scenario),
             _speed(result, scenario), _rate_along_path(result, scenario), _design(result, joints),
             _noise(result, joints), _robustness(result, scenario),
             _gains(result)]
    # what could not be computed for this arm, one line each, with the reason (the rest of the report stands)
    lines += [f"Not computed for this arm: {line}" for line in getattr(result, "not_done", ())]
    return [line for line in lines if line]
