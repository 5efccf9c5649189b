"""Section 6 of the report: disturbance responses of the loop held at q0, with and without the observer."""
from __future__ import annotations

from dataclasses import dataclass

from blocks.model.joints import JointSpace

from .text import ZERO_REL, Figure, Table, and_words, arm_joints, figures, fmt, is_paper_arm, join, split_caveats

__all__ = ["FrequencySection", "frequency_section"]


@dataclass(frozen=True)
class FrequencySection:
    """6. Disturbance responses of the held loop."""

    q0: str
    responses: Table
    closed_forms: list[str]
    reading: str
    figures: list[Figure]


def _frequency_reading(fr, stable: bool, arm: JointSpace, paper: bool = False) -> str:
    """The reading of the frequency responses; ``paper``: in the paper's words (its d3 sets the tool's depth)."""
    wo, w, est = (fr.tracking_without_dob.metrics, fr.tracking_with_dob.metrics, fr.estimation_with_dob.metrics)
    joints = f"joints 1-{len(w)}"
    text = ""
    if "prismatic" in arm.kinds:            # the first prismatic joint (the paper's d3 sets the tool's depth)
        j = arm.kinds.index("prismatic")
        dc_w = abs(w[j].dc_gain)
        zero = stable and dc_w <= ZERO_REL * w[j].peak_gain
        where = ("the prismatic joint", "depth error") if paper else \
            (f"the prismatic joint {arm.labels[j]}", "error on it")
        text = (f"A constant force of 1 N on {where[0]} leaves {fmt(-1e3 * wo[j].dc_gain, 4)} mm of {where[1]} "
                "without the observer and " + ("none with it. " if zero else f"{fmt(1e3 * dc_w, 4)} mm with it. "))
    if all(m.kind == "band-pass" for m in w):
        text += ("With the observer, disturbances reach the tracking error only in a band around "
                 f"{', '.join(fmt(m.peak_rad_s, 3) for m in w)} rad/s ({joints}; at most "
                 f"{', '.join(fmt(m.peak_gain, 3) for m in w)} per unit disturbance): slower ones are estimated and "
                 "cancelled, faster ones are filtered by the arm's inertia. ")
    else:
        text += ("With the observer the disturbance-to-error responses are " + ", ".join(m.kind for m in w)
                 + f" ({joints}). ")
    if all(m.kind == "high-pass" for m in est):
        corners = ", ".join(fmt(m.band_3db_rad_s[0], 3) for m in est)
        text += (f"The estimate follows a disturbance only below {corners}"
                 f" rad/s ({joints}; -3 dB), the observer bandwidth seen from each joint.")
    else:
        text += ("The estimation-error responses are " + ", ".join(m.kind for m in est) + f" ({joints}).")
    return text


def _band(low: float, high: float | None) -> str:
    """A -3 dB band in words: "below 3.2", "above 2.639", "2.1 to 7.5" or "every frequency" (rad/s).

    Examples
    --------
    >>> _band(2.639, None), _band(0.0, 3.2), _band(2.1, 7.5), _band(0.0, None)
    ('above 2.639', 'below 3.2', '2.1 to 7.5', 'every frequency')
    """
    if high is None:
        return "every frequency" if low <= 0 else f"above {fmt(low, 4)}"
    return f"below {fmt(high, 4)}" if low <= 0 else f"{fmt(low, 4)} to {fmt(high, 4)}"


def frequency_section(result, scenario, files: dict) -> FrequencySection | None:
    fr = result.frequency
    if fr is None:            # not computed for this arm: the summary says why
        return None
    rows = []
    for key, title in (("tracking_with_dob", "e, with observer"), ("tracking_without_dob", "e, without observer"),
                       ("estimation_with_dob", "d - d_hat, with observer")):
        data = getattr(fr, key)
        unit_key = "estimation" if key.startswith("estimation") else "tracking"
        for i, m in enumerate(data.metrics):
            band = m.band_3db_rad_s
            dc = m.dc_gain if abs(m.dc_gain) > 1e-9 * m.peak_gain else 0.0     # rounding noise shown as 0
            peak_at = "inf" if m.peak_rad_s is None else ("0 (DC)" if m.peak_rad_s == 0 else fmt(m.peak_rad_s, 4))
            rows.append([title, arm_joints(scenario).labels[i], fr.units[unit_key][i], fmt(dc, 4), fmt(m.peak_gain, 4), peak_at,
                         m.kind, _band(band[0], band[1])])
        rows.append([title, "closed form", "", "", "", "", "largest relative difference",
                     fmt(data.closed_form_max_rel_error, 2)])
    stable = result.operating_points[0].largest_real_part(True) < 0
    closed_forms = []
    for observer, name in ((True, "with"), (False, "without")):
        caveats = split_caveats(result, scenario, observer)
        err = fmt(fr.tracking(observer).closed_form_max_rel_error, 2)
        if caveats:
            closed_forms.append(f"The closed forms assume a perfect model, a disturbance that does not depend on the "
                                f"arm's state and the arm resting at q0; {name} the observer {and_words(caveats)}, so they "
                                f"are only approximate (largest relative difference {err}).")
        else:
            closed_forms.append(f"{name.capitalize()} the observer the linearized responses equal the closed forms "
                                f"(largest relative difference {err}).")
    return FrequencySection(
        q0=join(fr.q0, 5),
        responses=Table.of(["response", "joint", "unit", "DC gain", "peak gain", "peak at (rad/s)", "kind",
                            "-3 dB band (rad/s)"], rows, "Per-joint disturbance responses"),
        closed_forms=closed_forms, reading=_frequency_reading(fr, stable, arm_joints(scenario), is_paper_arm(scenario)),
        figures=figures(files, ("frequency_tracking", "Disturbance to tracking error, per joint"),
                         ("frequency_estimation", "Disturbance to estimation error, per joint")))

