"""Section 8 of the report (scenarios with a ``[controller]`` section): the digital implementation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace

from .text import Figure, Table, figures, fmt, mixed_units, pole, units_list

__all__ = ["DigitalSection", "digital_section"]


@dataclass(frozen=True)
class DigitalSection:
    """8. The controller as a program sampled at a fixed rate."""

    settings: Table
    answer: str
    poles: Table
    gain_limit: Table
    rule: Table
    rule_text: str
    quantization: Table | None
    figures: list[Figure]


def digital_section(result, files: dict, arm: ArmModel) -> DigitalSection | None:
    """Section 8 for the scenario's arm ``arm`` (its joints' names and units, whether its gravity is constant)."""
    d = result.digital
    joints = arm.joints
    if d is None:
        return None
    shown = {"sample_rate": "sample rate (Hz)", "delay": "delay (samples)",
             "observer_discretization": "observer update", "velocity": "velocity estimate",
             "velocity_cutoff": "velocity low-pass cut-off (Hz)",
             "position_resolution": f"encoder resolution ({units_list(joints.position_units)})",
             "torque_limit": f"torque limit ({units_list(joints.force_units)}; 0 = none)"}
    settings = Table.of(["setting", "value"], [[shown.get(k, k), ", ".join(fmt(x, 4) for x in v)
                                               if isinstance(v, (list, tuple)) else
                                               (fmt(v, 6) if isinstance(v, (int, float)) else str(v))]
                                              for k, v in d.settings.items()], "The scenario's [controller] section")
    modes = [m for m in d.poles.modes if np.isfinite(m.wn_rad_s)]
    poles = Table.of(["z", "|z|", "s = ln(z) / Ts (1/s)", "damping", "block"],
                     [[pole(m.z), fmt(abs(m.z), 6), pole(m.s_equivalent), fmt(m.zeta, 3), m.block] for m in modes],
                     f"Poles of the sampled loop at {fmt(d.sample_rate_hz, 5)} Hz, held at the path's start "
                     f"(max |z| = {fmt(d.poles.spectral_radius, 6)}; poles at z = 0 left out)")
    curves = d.gain_limit.curves
    rows = []
    for k, rate in enumerate(curves[0].rates_hz):
        rows.append([fmt(rate, 5), fmt(curves[0].euler_bound_scale[k], 4)]
                    + [fmt(c.largest_scale[k], 4) for c in curves])
    gain_limit = Table.of(["rate (Hz)", "2 / (Ts lambda_max)"]
                          + [f"{c.discretization}, delay {c.delay}" for c in curves], rows,
                          "Largest stable observer gain, in multiples of the scenario's gain")
    rule = Table.of(["rate (Hz)"] + [f"{c.discretization}, delay {c.delay}" for c in curves],
                    [[fmt(rate, 5)] + [fmt(c.ts_lambda_limit[k], 5) if c.ts_lambda_limit else "-" for c in curves]
                     for k, rate in enumerate(curves[0].rates_hz)],
                    "The same limits as Ts lambda_max(Y M^-1): the loop is stable while Ts lambda_max(Y M^-1) "
                    "stays below these numbers")
    quantization = None
    if d.quantization is not None:
        q = d.quantization
        rows, titles = range(len(q.predicted_rms)), joints.labels
        noise_units = mixed_units(joints.force_units)
        if q.simulated_rms is None:       # the quick preview does not simulate it: no column of dashes
            quantization = Table.of(
                ["joint", "resolution", "torque noise, linear model"],
                [[titles[i], fmt(q.position_resolution[i], 4), fmt(q.predicted_rms[i], 3)] for i in rows],
                f"RMS torque noise from encoder quantization ({noise_units}), from the linear model only: the "
                "quick preview does not simulate it (the full report does)")
        else:
            quantization = Table.of(
                ["joint", "resolution", "torque noise, linear model", "torque noise, simulated"],
                [[titles[i], fmt(q.position_resolution[i], 4), fmt(q.predicted_rms[i], 3),
                  fmt(q.simulated_rms[i], 3)] for i in rows],
                f"RMS torque noise from encoder quantization ({noise_units})")
    return DigitalSection(settings=settings, answer=d.answer, poles=poles, gain_limit=gain_limit, rule=rule,
                          rule_text=_rule_text(d, joints, arm.constant_gravity), quantization=quantization,
                          figures=figures(files, ("digital_poles", "Poles of the sampled loop"),
                                          ("digital_gain_limit", "How fast the observer may be at each sample rate"),
                                          ("digital_quantization", "Torque noise from encoder quantization")))


def _rule_text(d, joints: JointSpace, constant_gravity: bool) -> str:
    """How the limits were computed, with the scenario's own numbers (none of them written by hand)."""
    c = d.settings
    own = f"{c.get('observer_discretization', 'euler')} update, {c.get('velocity', 'measured')} velocity"
    if c.get("velocity_cutoff"):
        own += f" through a {fmt(c['velocity_cutoff'], 4)} Hz low-pass"
    return (f"The limits are computed, not assumed: at each configuration checked the loop is linearized at rest "
            f"(the plant under the held torque, discretized exactly; the controller; the observer's update; the "
            f"velocity estimate; the delay) and a gain is stable while the one-sample map's spectral radius is "
            f"below 1 (blocks.figure2.digital_stability, the same computation that refuses an unstable scenario before it "
            f"runs). For the scenario ({own}, delay {c.get('delay', 0)}) at {fmt(d.sample_rate_hz, 5)} Hz the "
            f"rule is Ts lambda_max(Y M^-1) < {fmt(d.ts_lambda_limit, 5)}. Only forward Euler with measured "
            f"velocity has the closed form 2 (the column 2 / (Ts lambda_max)): its estimate's error obeys "
            f"e[k+1] = (I - Ts Y M^-1) e[k] whatever the torque, delayed or not; zoh and a velocity estimate "
            f"couple the estimate with the tracking and lower the limit, and a delay lowers theirs further."
            + ("" if constant_gravity else
               " On this arm gravity varies with the configuration: its slope dG/dq, felt by the arm through the "
               "sample but seen by the controller and the observer at the sampled position, enters the map at each "
               "configuration; it couples Euler's estimate with the motion too, so its limit may differ slightly "
               "from 2."))
