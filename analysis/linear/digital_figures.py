"""Figures of the digital-implementation analysis (:mod:`analysis.linear.digital`): z-plane poles, the observer-gain
limit against the sample rate, and the torque noise from encoder quantization."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from analysis.linear.digital import DigitalAnalysis  # noqa: E402
from analysis.simulation.figures import save_figure  # noqa: E402
from blocks.model.joints import JointSpace  # noqa: E402

__all__ = ["digital_figures"]

_BLOCK_COLORS = {"plant": "tab:blue", "observer": "tab:orange", "encoder": "tab:green", "actuator": "tab:red"}


def digital_figures(result: DigitalAnalysis, out_dir, joints: JointSpace) -> list[Path]:
    """Write ``digital_poles``, ``digital_gain_limit`` and (with encoders) ``digital_quantization``.

    ``joints`` (the arm's) names the joints and their force units on the quantization figure.
    """
    out_dir = Path(out_dir)
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.2), constrained_layout=True, gridspec_kw={"width_ratios": [1, 1.3]})
    ax = axes[0]
    theta = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(theta), np.sin(theta), color="gray", lw=0.8, label="unit circle (stability limit)")
    for block, color in _BLOCK_COLORS.items():
        z = np.array([m.z for m in result.poles.modes if m.block == block])
        if z.size:
            ax.plot(z.real, z.imag, "o", mfc="none", color=color, label=f"{block} modes")
    ax.set_aspect("equal")
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title(f"z-plane at {result.sample_rate_hz:g} Hz (max |z| = {result.poles.spectral_radius:.5f})",
                 fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    ax = axes[1]
    for block, color in _BLOCK_COLORS.items():
        s_eq = np.array([m.s_equivalent for m in result.poles.modes if m.block == block and np.isfinite(m.wn_rad_s)])
        if s_eq.size:
            ax.plot(s_eq.real, s_eq.imag, "o", mfc="none", color=color, label=f"{block} modes")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.axvline(0, color="gray", lw=0.8)
    ax.set_xlabel("real part of ln(z) / Ts (1/s, symlog scale)")
    ax.set_ylabel("imaginary part (rad/s)")
    ax.set_title("Continuous equivalents s = ln(z) / Ts (poles at z = 0, a delay, left out)", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    paths += save_figure(fig, out_dir, "digital_poles")

    fig, ax = plt.subplots(figsize=(7.5, 5), constrained_layout=True)
    curves = result.gain_limit.curves
    ax.loglog(curves[0].rates_hz, curves[0].euler_bound_scale, "k--", lw=1.2,
              label="2 / (Ts lambda_max(Y M^-1)): Euler, measured velocity")
    for curve, marker in zip(curves, "osd^v<>ph"):
        ax.loglog(curve.rates_hz, curve.largest_scale, marker + "-", ms=5, mfc="none",
                  label=f"{curve.discretization}, delay {curve.delay}")
    ax.axhline(1.0, color="tab:red", lw=0.8, label="the scenario's gain")
    ax.axvline(result.sample_rate_hz, color="gray", lw=0.8, ls=":", label="the scenario's rate")
    ax.set_xlabel("sample rate (Hz)")
    ax.set_ylabel("largest stable gain / scenario gain")
    ax.set_title("How fast the observer may be at each sample rate", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    paths += save_figure(fig, out_dir, "digital_gain_limit")

    if result.quantization is not None:
        q = result.quantization
        fig, ax = plt.subplots(figsize=(7.5, 4.2), constrained_layout=True)
        x = np.arange(len(q.predicted_rms))
        ax.bar(x - 0.2, q.predicted_rms, 0.4, label="linear model (white quantization error)")
        if q.simulated_rms is not None:
            ax.bar(x + 0.2, q.simulated_rms, 0.4, label="simulated (with minus without quantization)")
        ax.set_xticks(x, [f"{lab}\n({u})" for lab, u in zip(joints.labels, joints.force_units)])
        ax.set_yscale("log")
        ax.set_ylabel("RMS torque noise")
        ax.set_title("Torque noise from encoder quantization", fontsize=10)
        ax.grid(True, axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=8)
        paths += save_figure(fig, out_dir, "digital_quantization")
    return paths
