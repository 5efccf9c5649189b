"""Section 3 of the report: poles and modes of the linearized loop, and its robustness to inertia mismatch."""
from __future__ import annotations

from dataclasses import dataclass

from .text import (
    Figure,
    Paragraph,
    Table,
    and_words,
    arm_joints,
    figures,
    fmt,
    join,
    pole,
    split_caveats,
    stability_text,
    units_list,
)

__all__ = ["LinearSection", "linear_section"]


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


def _linear_reading(first, caveats: list) -> str:
    modes = first.modes_with_dob
    alpha = first.largest_real_part(True)
    obs_rates = sorted(m.decay_rate_rad_s for m in modes if m.block == "observer")
    pd_rates = sorted(m.decay_rate_rad_s for m in modes if m.block == "plant")
    slowest = modes[0]                                   # modes are sorted slowest first
    share = slowest.participation[slowest.block]
    if alpha >= 0:
        text = (f"With the observer the held loop is unstable at {first.label} (largest pole real part "
                f"{fmt(alpha, 4)} rad/s). ")
    elif slowest.block == "observer" and share > 0.99 and pd_rates:
        text = (f"With the observer the slowest closed-loop mode is the observer's {fmt(obs_rates[0], 4)} rad/s (time "
                f"constant {fmt(1 / obs_rates[0], 3)} s), {fmt(pd_rates[0] / obs_rates[0], 3)} times slower than the "
                f"slowest PD mode ({fmt(pd_rates[0], 4)} rad/s). ")
    else:
        text = (f"With the observer the slowest closed-loop mode, {fmt(slowest.decay_rate_rad_s, 4)} rad/s, is "
                f"attributed to the {'observer' if slowest.block == 'observer' else 'plant (PD)'} states "
                f"(participation {fmt(share, 3)})"
                + (f"; the slowest mode attributed to the observer is {fmt(obs_rates[0], 4)} rad/s" if obs_rates and
                   slowest.block != "observer" else "") + ". ")
    err = first.max_rel_error_with_dob
    if not caveats and err < 1e-6:
        text += (f"The linearized poles equal the analytic split to {fmt(err, 2)} (relative): on a perfect model with a "
                 "disturbance that does not depend on the arm's state the loop is block-triangular (the observer "
                 "error drives the tracking error, not the reverse), so Kp and Kd place the plant poles and Y places "
                 "the observer poles, independently.")
    elif caveats:
        text += (f"The analytic split assumes a perfect model and a disturbance that does not depend on the arm's "
                 f"state; here {and_words(caveats)}, so the linearized poles differ from it by up to {fmt(err, 2)} "
                 "(relative) and the split is only a guide.")
    else:
        text += f"The linearized poles differ from the analytic split by up to {fmt(err, 2)} (relative)."
    return text


def _decays(poles) -> list[float]:
    return [-p.real for p in poles]


def _smallest_damping(poles) -> float:
    return min(-p.real / abs(p) for p in poles)


def _mismatch_reading(mm, perfect_model: bool) -> str:
    sw = mm.with_dob.sweep
    factors = sw.factors
    slow = [min(_decays(poles)) if poles else float("nan") for poles in sw.poles]
    damp = [_smallest_damping(poles) if poles else float("nan") for poles in sw.poles]
    picks = sorted({0, len(factors) - 1} | ({factors.index(1.0)} if 1.0 in factors else set()),
                   key=lambda k: factors[k])
    text = ("With the observer, the slowest mode decays at "
            + ", ".join(f"{fmt(slow[k], 4)} rad/s at a = {fmt(factors[k], 3)}" for k in picks)
            + "; the smallest damping ratio is "
            + ", ".join(f"{fmt(damp[k], 3)} at a = {fmt(factors[k], 3)}" for k in picks) + ". ")
    return text + stability_text(mm.with_dob.boundaries, "With the observer the held loop", perfect_model, prefix="")


def linear_section(result, scenario, files: dict) -> LinearSection:
    ops = result.operating_points
    caveats_wo = split_caveats(result, scenario, observer=False)
    caveat = (f"Without the observer {and_words(caveats_wo)}, so its poles deviate from the ideal PD roots by up to "
              f"{fmt(ops[0].max_rel_error_without_dob, 2)} (relative) at the first operating point."
              if caveats_wo else None)
    rows = []
    for op in ops:
        obs = sorted(m.decay_rate_rad_s for m in op.modes_with_dob if m.block == "observer")
        pd = sorted({round(m.decay_rate_rad_s, 6) for m in op.modes_with_dob if m.block == "plant"})
        rows.append([op.label, join(op.q0, 4), join(obs, 5), join(pd, 5), fmt(op.max_rel_error_with_dob, 2),
                     fmt(op.max_rel_error_without_dob, 2),
                     "yes" if op.attribution_agrees_with_dob and op.attribution_agrees_without_dob else "no"])
    points = Table.of(["operating point", f"q0 ({units_list(arm_joints(scenario).position_units)})",
                       "observer decay rates (rad/s)",
                       "plant (PD) decay rates (rad/s)", "largest rel. difference, with",
                       "largest rel. difference, without", "attribution agrees"], rows,
                      "All operating points (poles real unless listed below)")
    first = ops[0]
    modes = []
    for observer, title in ((True, "with observer"), (False, "without observer")):
        rows = [[pole(m.pole), fmt(m.wn_rad_s), fmt(m.zeta), fmt(m.time_constant_s), m.block,
                 fmt(m.participation.get(m.block, 1.0), 3), pole(m.analytic_pole), m.analytic_block,
                 fmt(m.rel_error_vs_analytic, 2)] for m in first.modes(observer)]
        modes.append(Table.of(["pole (rad/s)", "wn (rad/s)", "zeta", "time constant (s)", "block", "participation",
                               "analytic pole", "analytic block", "relative difference"], rows,
                              f"{title}: largest relative difference from the analytic split "
                              f"{fmt(first.max_rel_error(observer), 2)}; attribution agrees with the analytic split: "
                              f"{'yes' if first.attribution_agrees(observer) else 'no'}"))
    complex_ops = [op.label for op in ops for observer in (True, False)
                   if any(abs(m.pole.imag) > 0 for m in op.modes(observer))]
    mm = result.mismatch
    perfect = scenario.nominal == scenario.robot
    stability, rows = [], []
    for observer, title in ((True, "with observer"), (False, "without observer")):
        sweep = mm.loop(observer).sweep
        for a, alpha, poles in zip(sweep.factors, sweep.spectral_abscissa, sweep.poles):
            if not poles:       # the arm has no resting position near q0 at this factor: no poles to speak of
                rows.append([title, fmt(a, 4), "no rest near q0", "", "", ""])
                continue
            rows.append([title, fmt(a, 4), fmt(alpha, 5), fmt(min(_decays(poles)), 4), fmt(max(_decays(poles)), 4),
                         fmt(_smallest_damping(poles), 4)])
        stability.append(Paragraph(stability_text(mm.loop(observer).boundaries, "the held loop", perfect, prefix=""),
                                   f"Stability {title}:"))
    return LinearSection(
        caveat=caveat, points=points, first_label=first.label, first_q0=join(first.q0, 5), modes=modes,
        complex_at=", ".join(sorted(set(complex_ops))) if complex_ops else None,
        reading=_linear_reading(first, split_caveats(result, scenario, observer=True)),
        figures=figures(files, ("linear_poles", "Closed-loop poles: rings with the observer, squares without, "
                                                "dots and crosses the analytic split")),
        perfect_model=perfect, mismatch_q0=join(mm.q0, 5), stability=stability,
        mismatch=Table.of(["loop", "a", "largest real part (rad/s)", "slowest decay (rad/s)", "fastest decay (rad/s)",
                           "smallest damping ratio"], rows, "Poles against inertia mismatch"),
        mismatch_reading=_mismatch_reading(mm, perfect),
        mismatch_figures=figures(files, ("linear_mismatch", "Stability and pole movement against inertia mismatch")))

