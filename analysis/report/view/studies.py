"""Section 7 of the report: the Kp x Kd study and the observer gain and noise study.

Every comparison a reading makes is computed from the numbers it compares,
the extremes included: the smallest and largest peak of all the gains tried,
whether the peak falls at every step of the scalar gains, and which gains
beat the designed one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.simulation.studies import settling_definition

from .text import Figure, Table, and_words, arm_joints, figures, fmt, join, kinds, settling, units_list

__all__ = ["StudiesSection", "studies_section", "observer_reading", "gain_reading", "study_definition"]


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


def study_definition(st, scenario) -> str:
    g = st.gains_with_dob
    own = kinds(scenario.data["disturbance"]["kind"])
    where = ("which is the scenario's own disturbance" if own == ["paper"] else
             f"in place of the scenario's disturbance models ({and_words(own) if own else 'none'})")
    joints = arm_joints(scenario)
    return (f"Every run holds the arm at the scenario's reference at t = 0, q_hold = [{join(g.q_hold, 4)}] "
            f"({units_list(joints.position_units)}), and applies the constant disturbance step f_r = "
            f"[{join(g.f_r, 4)}] ({units_list(joints.force_units)}; the paper's Eq. 4) from t = 0, {where}, for "
            f"{fmt(g.t_final_s)} s; models, noise-free sensors and solver settings are the scenario's. The arm "
            "starts at rest with d_hat = 0. Final value: the error where the held loop comes to rest (its "
            "equilibrium, computed); steady-state error: its size. "
            + settling_definition(g.settle_fraction, g.final_window).capitalize()
            + ". Tool-tip position error in mm.")


def _scalar(gain) -> float | None:
    """``v`` when an observer gain is ``v I`` (given as a number, 4 equal numbers or a matrix), else None."""
    if gain is None:
        return None
    g = np.asarray(gain, dtype=float)
    if g.ndim == 0:
        return float(g)
    M = np.diag(g) if g.ndim == 1 else g
    d = np.diag(M)
    return float(d[0]) if np.array_equal(M, np.diag(d)) and np.all(d == d[0]) else None


def _noise_ratios(obs, k: int) -> list[float]:
    base = obs.runs[0].torque_noise_rms
    return [n / b if b > 0 else math.nan for n, b in zip(obs.runs[k].torque_noise_rms, base)]


def observer_reading(obs, scenario) -> str | None:
    """Computed observations on the observer gain study: peaks compared over every gain tried, and torque noise."""
    labels, runs = obs.labels, obs.runs
    ok = [k for k, r in enumerate(runs) if r.ok and labels[k] != "none"]
    if not ok:
        return None
    peak = {k: runs[k].tool_mm.peak_error for k in ok}
    slowest = obs.slowest_mode_rad_s or [None] * len(labels)
    k_lo, k_hi = min(ok, key=peak.get), max(ok, key=peak.get)
    text = (f"Over the {len(ok)} observer gains tried, the peak tool-tip error after the step ranges from "
            f"{fmt(peak[k_hi], 3)} mm ({labels[k_hi]}) down to {fmt(peak[k_lo], 3)} mm ({labels[k_lo]})")
    if runs[0].ok:
        text += f"; without the observer it is {fmt(runs[0].tool_mm.peak_error, 3)} mm"
    text += "."
    scalar = sorted((v, k) for k in ok if (v := _scalar(obs.gains[k])) is not None)
    if len(scalar) >= 2:
        values = [peak[k] for _, k in scalar]
        listed = ", ".join(f"{fmt(peak[k], 3)} mm ({v:g} I)" for v, k in scalar)
        if all(b < a for a, b in zip(values, values[1:])):
            text += f" Over the scalar gains Y = v I it falls at every step up in v: {listed}."
        else:
            text += f" Over the scalar gains Y = v I it does not fall at every step up in v: {listed}."
    if "designed Y" in labels and labels.index("designed Y") in ok:
        kd = labels.index("designed Y")
        ks = next((k for k in ok if labels[k].endswith("(scenario)")), None)
        text += f" The designed Y gives {fmt(peak[kd], 3)} mm"
        if ks is not None:
            text += f", against {fmt(peak[ks], 3)} mm with the scenario's gain ({labels[ks].removesuffix(' (scenario)')})"
        text += "."
        if slowest[kd] is not None:
            beat = [k for k in ok if k != kd and peak[k] < peak[kd] and slowest[k] is not None
                    and slowest[k] < slowest[kd]]
            if beat:
                text += (f" {and_words([labels[k] for k in beat])} give"
                         f"{'s' if len(beat) == 1 else ''} a smaller peak ({join([peak[k] for k in beat], 3)} mm) "
                         f"although {'its slowest mode is' if len(beat) == 1 else 'their slowest modes are'} slower "
                         f"({join([slowest[k] for k in beat], 3)} against {fmt(slowest[kd], 3)} rad/s): the slowest "
                         "observer mode alone does not set the peak.")
    if not runs[0].ok or runs[0].torque_noise_rms is None:          # no noise measured: nothing to weigh
        return text
    noisiest = max(ok, key=lambda k: max((r for r in _noise_ratios(obs, k) if math.isfinite(r)), default=-math.inf))
    ratio = _noise_ratios(obs, noisiest)
    text += (f" The price is torque noise: with {labels[noisiest]} the torque noise is "
             f"{join(ratio, 3)} times its value without the observer (joints 1-{len(ratio)})")
    if "designed Y" in labels and labels.index("designed Y") in ok and labels.index("designed Y") != noisiest:
        text += f", with the designed Y {join(_noise_ratios(obs, labels.index('designed Y')), 3)} times"
    finite = [r if math.isfinite(r) else -math.inf for r in ratio]
    j = int(np.argmax(finite))
    if finite[j] > 1:
        M = scenario.nominal.inertia(np.asarray(obs.q_hold, dtype=float))
        lightest = int(np.argmin(np.diag(M))) == j
        text += (f". The relative increase is largest on {arm_joints(scenario).labels[j]}"
                 + (", the joint with the smallest inertia: the observer adds Y q' velocity noise to the "
                    "controller's M Kd q' noise, and Y / (M Kd) is largest where M is smallest" if lightest else ""))
    return text + "."


def gain_reading(st) -> str | None:
    """Computed observations on the Kp x Kd study."""
    def cells(study):
        return [(kp, kd, run.tool_mm) for kp, kd, run in study.cells() if run.ok]
    w, wo = cells(st.gains_with_dob), cells(st.gains_without_dob)
    if not w or not wo:
        return None
    by_kp = {}
    for kp, _, m in wo:
        by_kp.setdefault(kp, []).append(m.steady_state_error)
    offsets = ", ".join(f"{fmt(np.mean(v), 3)} mm at Kp = {fmt(kp)}" for kp, v in sorted(by_kp.items()))
    spread = max((max(v) - min(v)) / max(v) if max(v) > 0 else 0.0 for v in by_kp.values())
    text = (f"Without the observer the tool tip comes to rest {offsets}; "
            + ("Kd does not change it" if spread == 0 else
               f"across Kd it changes by at most {fmt(100 * spread, 2)} % at a given Kp")
            + ". With the observer it comes to rest "
            + ("exactly on its target" if max(c[2].steady_state_error for c in w) == 0 else
               f"at most {fmt(max(c[2].steady_state_error for c in w), 3)} mm from its target")
            + " for every pair; ")
    best_peak = min(w, key=lambda c: c[2].peak_error)
    text += f"the smallest peak error is {fmt(best_peak[2].peak_error, 3)} mm (Kp = {fmt(best_peak[0])}, " \
            f"Kd = {fmt(best_peak[1])})"
    settled = [c for c in w if c[2].settling_time_s is not None]
    if settled:
        best_ts = min(settled, key=lambda c: c[2].settling_time_s)
        text += f", the shortest settling time {fmt(best_ts[2].settling_time_s, 3)} s (Kp = {fmt(best_ts[0])}, " \
                f"Kd = {fmt(best_ts[1])})"
    if len(settled) < len(w):
        text += f" ({len(w) - len(settled)} of {len(w)} pairs not settled within the run)"
    best_rms = min(w, key=lambda c: c[2].rms_error)
    return text + f", the smallest RMS error {fmt(best_rms[2].rms_error, 3)} mm (Kp = {fmt(best_rms[0])}, " \
                  f"Kd = {fmt(best_rms[1])})."


def studies_section(result, scenario, files: dict) -> StudiesSection:
    joints = arm_joints(scenario)
    st = result.studies
    rows = []
    for study, title in ((st.gains_with_dob, "with"), (st.gains_without_dob, "without")):
        for kp, kd, r in study.cells():
            if not r.ok:
                rows.append([title, fmt(kp), fmt(kd), "failed", "", "", ""])
                continue
            m = r.tool_mm
            rows.append([title, fmt(kp), fmt(kd), settling(m.settling_time_s), fmt(m.steady_state_error, 3),
                         fmt(m.peak_error, 3), fmt(m.rms_error, 3)])
    gains = Table.of(["observer", "Kp (1/s^2)", "Kd (1/s)", "settling time (s)", "steady-state (mm)", "peak (mm)",
                      "RMS (mm)"], rows, "Kp x Kd study (tool tip)")
    obs = st.observer
    noise = obs.noise
    if noise is None:
        noise_setup = (f"Observer gain: the same step experiment ({fmt(obs.t_final_s)} s runs) for each observer "
                       f"gain. Torque noise was not measured: {obs.noise_unavailable or 'no [noise] table'}.")
    else:
        noise_setup = (f"Observer gain and measurement noise: the same step experiment ({fmt(obs.t_final_s)} s runs) "
                       f"for each observer gain. Torque noise: runs of the first {fmt(obs.noise_t_final_s)} s with "
                       f"noise on q of standard deviations {join(noise['q_std'])} ({units_list(joints.position_units)}) "
                       f"and on q' of {join(noise['dq_std'])} ({units_list(joints.velocity_units)}), sampled every "
                       f"{fmt(noise.get('sample_period', 0.001))} s, seed {noise.get('seed', 0)}; torque noise = RMS "
                       "of the torque difference between the noisy and the clean run.")
    rows = []
    for k, label in enumerate(obs.labels):
        r = obs.runs[k]
        shown = "no observer" if label == "none" else label
        if not r.ok:
            rows.append([shown, "failed"] + [""] * 7)
            continue
        m = r.tool_mm
        slow = obs.slowest_mode_rad_s[k] if obs.slowest_mode_rad_s else None
        noisy = (["not measured"] * 3 if r.torque_noise_rms is None else
                 [fmt(r.clean_short.tool_mm.rms_error, 3), fmt(r.noisy.tool_mm.rms_error, 3),
                  join(r.torque_noise_rms, 3)])
        rows.append([shown, fmt(slow, 4), settling(m.settling_time_s), fmt(m.peak_error, 3),
                     fmt(m.rms_error, 3)] + noisy)
    observer = Table.of(["observer gain", "slowest mode (rad/s)", "settling time (s)", "peak (mm)", "RMS (mm)",
                         f"RMS, first {fmt(obs.noise_t_final_s)} s (mm)", "same, with noise (mm)",
                         f"torque noise RMS ({units_list(joints.force_units)})"], rows,
                        "Observer gain study (tool tip)")
    return StudiesSection(
        definition=study_definition(st, scenario),
        gain_figures=figures(files, ("study_gains", "Gain study heat maps (the numbers are in the table below)")),
        gains=gains, gain_reading=gain_reading(st), noise_setup=noise_setup, observer=observer,
        observer_reading=observer_reading(obs, scenario),
        observer_figures=figures(files, ("study_observer", "Error against torque noise for each observer gain")))
