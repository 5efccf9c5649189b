"""Figures of the analyses (headless matplotlib; PNG and SVG; labelled axes with units).

Each function takes the typed result of one analysis (see
:mod:`analysis.results`) and writes
``stem.png`` and ``stem.svg`` into a folder with
:func:`analysis.simulation.figures.save_figure` (no dates or tool stamps, fixed SVG
ids: the same numbers give the same bytes), returning the paths.  Per-joint
figures take the arm's joints (``joints``, a :class:`blocks.model.joints.JointSpace`)
for their panels, names and units.
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from analysis.linear.bandwidth import BandwidthOverview, BandwidthSurvey  # noqa: E402
from analysis.linear.frequency import FrequencyAnalysis  # noqa: E402
from analysis.linear.gain_design import SimulationCheck  # noqa: E402
from analysis.linear.loop import MismatchStudy, OperatingPoint  # noqa: E402
from analysis.simulation.figures import joint_grid_shape, save_figure  # noqa: E402
from analysis.simulation.studies import GainGridStudy, ObserverGainStudy, settling_definition  # noqa: E402
from blocks.model.joints import JointSpace  # noqa: E402

__all__ = ["pole_figure", "mismatch_figure", "bandwidth_figure", "design_figure", "bode_figure",
           "gain_study_figure", "gain_study_axes", "observer_study_figure", "ZERO_SHARE", "design_axes"]

_BLOCK_COLORS = {"plant": "tab:blue", "observer": "tab:orange"}


def _finish(ax, title: str, which: str = "both", axis: str = "both", **legend) -> None:
    """The title, light grid and small legend every analysis panel carries."""
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3, which=which, axis=axis)
    ax.legend(**{"fontsize": 8, **legend})


def pole_figure(operating_points: list[OperatingPoint], out_dir) -> list[Path]:
    """Closed-loop poles: complex plane of the first operating point, decay rates of all of them."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1, 1.3]})
    ax = axes[0]
    first = operating_points[0]
    # where the loops share a pole the markers nest: a large ring (with), a small filled square inside it
    # (without) and the analytic split as a small black dot at the centre
    for key, style, title in (("with_dob", dict(marker="o", ms=13, mfc="none", mew=1.6), "with observer"),
                              ("without_dob", dict(marker="s", ms=6, mew=0), "without")):
        for block in ("plant", "observer"):
            poles = np.array([m.pole for m in first.modes(key == "with_dob") if m.block == block])
            if len(poles):
                color = _BLOCK_COLORS[block]
                ax.plot(poles.real, poles.imag, ls="none", color=color, mfc=style.get("mfc", color),
                        label=f"{title}: {block} modes", **{k: v for k, v in style.items() if k != "mfc"})
    analytic = np.array([m.analytic_pole for m in first.modes_with_dob])
    ax.plot(analytic.real, analytic.imag, ".", ms=3, color="black", label="analytic split (perfect model)")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.axvline(0, color="gray", lw=0.8)
    ax.set_xlabel("real part (rad/s, symlog scale)")
    ax.set_ylabel("imaginary part (rad/s)")
    _finish(ax, f"Poles at {first.label or 'the first operating point'}")
    ax = axes[1]
    rows = []
    for op in operating_points:
        for observer, title in ((True, "with"), (False, "without")):
            rows.append((f"{op.label}, {title}", op.modes(observer)))
    for r, (_, modes) in enumerate(rows):
        for m in modes:
            ax.plot(m.decay_rate_rad_s, r, "o", ms=7, mfc="none", color=_BLOCK_COLORS[m.block])
            ax.plot(-m.analytic_pole.real, r, "x", ms=4, color="black")
    for block, color in _BLOCK_COLORS.items():
        ax.plot([], [], "o", mfc="none", color=color, label=f"{block} mode")
    ax.plot([], [], "x", color="black", label="analytic")
    ax.set_yticks(range(len(rows)), [label for label, _ in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("decay rate -Re(pole) (rad/s, log scale)")
    # the legend below the axes, where it covers no pole
    _finish(ax, "Decay rates at every operating point", axis="x", loc="upper center", bbox_to_anchor=(0.5, -0.12),
            ncol=3)
    return save_figure(fig, out_dir, "linear_poles")


def mismatch_figure(mismatch: MismatchStudy, out_dir) -> list[Path]:
    """Spectral abscissa and pole decay rates against the nominal/true inertia ratio."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), constrained_layout=True)
    ax = axes[0]
    for observer, color, label in ((True, "tab:orange", "with observer"), (False, "tab:blue", "without")):
        search = mismatch.loop(observer).boundaries
        ax.plot(search.scan.factors, search.scan.spectral_abscissa, "o-", ms=3, color=color, label=label)
        for a in search.factors:
            ax.axvline(a, color=color, ls="--", lw=1)
            ax.annotate(f"boundary a = {a:.4g}", (a, 0), textcoords="offset points",
                        xytext=(5, 10), fontsize=8, color=color)
    ax.axhline(0, color="black", lw=0.8)
    lo, hi = min(mismatch.with_dob.sweep.factors), max(mismatch.with_dob.sweep.factors)
    ax.axvspan(lo, hi, color="green", alpha=0.08, label=f"pole sweep {lo:g}x-{hi:g}x")
    ax.set_xscale("log")
    ax.set_xlabel("scale a of the scenario's nominal inertia (a = 1: the scenario's model)")
    ax.set_ylabel("largest pole real part (rad/s)")
    _finish(ax, "Stability against inertia mismatch (> 0: unstable)")
    ax = axes[1]
    for observer, marker, label in ((True, "o", "with observer"), (False, "s", "without")):
        sweep = mismatch.loop(observer).sweep
        for a, poles in zip(sweep.factors, sweep.poles):
            re = -np.array([p.real for p in poles])
            ax.plot(np.full(re.shape, a), np.where(re > 0, re, np.nan), marker, ms=4, mfc="none",
                    color="tab:orange" if observer else "tab:blue",
                    label=label if a == sweep.factors[0] else None)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("scale a of the scenario's nominal inertia")
    ax.set_ylabel("decay rate -Re(pole) (rad/s)")
    _finish(ax, f"How every pole moves over {lo:g}x-{hi:g}x")
    return save_figure(fig, out_dir, "linear_mismatch")


def bandwidth_figure(survey: BandwidthSurvey, designed: BandwidthOverview | None, pd_slowest: float,
                     out_dir, joints: JointSpace) -> list[Path]:
    """Eigenvalues of ``Y M^-1`` along the survey's slice joint (log scale) and the slowest mode's direction.

    The slice joint (theta2 for the paper's arm) is named, with its unit, from ``joints``.
    """
    theta2 = np.array(survey.theta2)            # the slice's values (the key keeps the paper arm's name)
    along = survey.slice_joint_name
    unit = joints.position_units[list(joints.names).index(along)] if along in joints.names else "rad"
    eig = np.array(survey.eigenvalues)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    ax = axes[0]
    for k in range(eig.shape[1]):
        lo, hi = f"{eig[:, k].min():.3g}", f"{eig[:, k].max():.3g}"
        ax.plot(theta2, eig[:, k], lw=2.2 if k == 0 else 1.4,
                label=f"mode {k + 1}: {lo if lo == hi else f'{lo} to {hi}'} rad/s")
    if designed is not None:
        d_eig = np.array(designed.eigenvalues)
        for k in range(d_eig.shape[1]):
            ax.plot(theta2, d_eig[:, k], color="black", ls="--", lw=1,
                    label=f"designed Y (all {d_eig.shape[1]} modes)" if k == 0 else None)
    # on top of the modes, in black: it may lie on one of them
    ax.axhline(pd_slowest, color="black", ls=":", lw=2, zorder=5, label=f"slowest PD pole {pd_slowest:.3g} rad/s")
    ax.set_yscale("log")
    ax.set_xlabel(f"{along} ({unit})")
    ax.set_ylabel("observer mode decay rate (rad/s)")
    # the legend below the axes, where it covers no curve
    _finish(ax, f"Eigenvalues of Y M^-1(q) along {along} (solid: scenario gain Y)", loc="upper center",
            bbox_to_anchor=(0.5, -0.14), ncol=2)
    ax = axes[1]
    direction = np.array(survey.slowest_direction)
    for j in range(direction.shape[1]):
        ax.plot(theta2, direction[:, j], label=joints.labels[j])
    ax.set_xlabel(f"{along} ({unit})")
    ax.set_ylabel("component of unit eigenvector (1)")
    _finish(ax, "Direction of the slowest observer mode (disturbance space)", which="major")
    return save_figure(fig, out_dir, "observer_bandwidth")


def _error_groups(run: SimulationCheck, joints: JointSpace) -> list[tuple[str, str, np.ndarray]]:
    """``|d - d_hat|`` of a run per unit: (joints in words, unit, norm over those joints per output time).

    Torques (N m) and forces (N) are never summed into one number; results written before the per-joint error
    was kept give their one mixed norm, labelled so.
    """
    if run.error_per_joint is None:
        return [("all joints", "N m and N mixed", np.array(run.error_norm, dtype=float))]
    err = np.array(run.error_per_joint, dtype=float)
    groups = []
    units = joints.force_units
    for unit in dict.fromkeys(units):
        same = [j for j, u in enumerate(units) if u == unit]
        words = ("joint " if len(same) == 1 else "joints ") + ", ".join(str(j + 1) for j in same)
        groups.append((words, unit, np.linalg.norm(err[:, same], axis=1)))
    return groups


def design_figure(confirm: dict[str, SimulationCheck], out_dir, joints: JointSpace) -> list[Path]:
    """Simulated estimation error (per unit: the revolute joints in N m, prismatic ones in N) and the
    Lyapunov certificate, paper gain against the designed gain."""
    return save_figure(design_axes(confirm, joints), out_dir, "observer_design")


def design_axes(confirm: dict[str, SimulationCheck], joints: JointSpace):
    """The figure of :func:`design_figure`, not yet written (matplotlib Figure)."""
    first = next(iter(confirm.values()))
    rows = len(_error_groups(first, joints))
    fig = plt.figure(figsize=(12, 2.6 + 2.0 * rows), constrained_layout=True)
    grid = fig.add_gridspec(rows, 2)
    error_axes = [fig.add_subplot(grid[r, 0]) for r in range(rows)]
    bound_ax = fig.add_subplot(grid[:, 1])
    colors = ["tab:red", "tab:blue", "tab:green", "tab:purple"]
    tops = [0.0] * rows
    for (label, run), color in zip(confirm.items(), colors):
        t = np.array(run.time)
        conv = run.convergence_time_s
        for r, (ax, (words, unit, err)) in enumerate(zip(error_axes, _error_groups(run, joints))):
            # an error of exactly zero has no place on a log axis: leave it out rather than draw it at 1e-300
            name = (f"{label}: within {100 * run.threshold:g}% after "
                    + (f"{conv:.3g} s" if conv is not None else "- (not within the run)")) if r == 0 else label
            ax.semilogy(t, np.where(err > 0, err, np.nan), color=color, label=name)
            ax.set_ylabel(f"|d - d_hat|, {words} ({unit})")
            tops[r] = max(tops[r], float(np.max(err)) if err.size else 0.0)
        if run.lyapunov_ratio is not None:         # None: no error at the start (V(0) = 0), nothing to bound
            bound_ax.semilogy(t, run.lyapunov_ratio, color=color, label=f"{label}: V/V(0)")
            bound_ax.semilogy(t, np.exp(-2 * run.beta_run_rad_s * t), color=color, ls="--",
                              label=f"{label}: bound exp(-2 beta t), beta = {run.beta_run_rad_s:.3g} rad/s")
    for ax, top in zip(error_axes, tops):
        # below these levels the ODE solver's own error dominates the curves
        if top > 0:
            ax.set_ylim(1e-6 * top, 3 * top)
    error_axes[-1].set_xlabel("time (s)")
    error_axes[0].set_title("Estimation error in the nonlinear simulation", fontsize=10)
    bound_ax.set_xlabel("time (s)")
    bound_ax.set_ylabel("V(t) / V(0) (1)")
    bound_ax.set_ylim(1e-10, 10)
    bound_ax.set_title("Lyapunov function against its certified decay", fontsize=10)
    for ax in error_axes + [bound_ax]:
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=8)
    return fig


def bode_figure(freq: FrequencyAnalysis, out_dir, kind: str, joints: JointSpace) -> list[Path]:
    """Bode magnitude per joint of ``w[i] -> e[i]`` (``kind="tracking"``) or ``w[i] -> e_d[i]`` (``"estimation"``),
    one panel per joint (a 2 x 2 grid for four)."""
    omega = np.array(freq.omega_rad_s)
    n = joints.count
    rows, cols = joint_grid_shape(n)
    size = (12, 7) if (rows, cols) == (2, 2) else ({1: 7.0, 2: 12.0}.get(cols, 1.0 + 4.4 * cols), 1.2 + 2.9 * rows)
    fig, grid = plt.subplots(rows, cols, figsize=size, constrained_layout=True, sharex=True, squeeze=False)
    for ax in grid.flat[n:]:
        ax.remove()
    axes = grid.flat[:n]
    units = freq.units[kind]
    curves = [("with_dob", "tab:blue", "-", "with observer")]
    if kind == "tracking":
        curves.append(("without_dob", "tab:red", "--", "without observer"))
    for i, ax in enumerate(axes):
        for key, color, ls, label in curves:
            data = getattr(freq, f"{kind}_{key}")
            mag = np.maximum(np.array(data.magnitude[i]), 1e-300)
            ax.semilogx(omega, 20 * np.log10(mag), color=color, ls=ls, label=label)
            m = data.metrics[i]
            if m.kind == "band-pass" and m.peak_rad_s:
                ax.plot(m.peak_rad_s, 20 * np.log10(m.peak_gain), "v", color=color)
            for edge in m.band_3db_rad_s:
                if edge:
                    ax.axvline(edge, color=color, ls=":", lw=0.8)
        ax.set_title(joints.labels[i], fontsize=10)
        ax.set_ylabel(f"|{'E' if kind == 'tracking' else 'E_d'}/W| (dB re 1 {units[i]})")
        ax.grid(True, alpha=0.3, which="both")
        if i + cols >= n:                     # the lowest panel of its column
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("frequency (rad/s)")
        if kind == "tracking":
            ax.set_ylim(bottom=max(ax.get_ylim()[0], -200))
    axes[0].legend(fontsize=8)
    what = "tracking error e = q_ref - q" if kind == "tracking" else "estimation error d - d_hat"
    fig.suptitle(f"Disturbance w[i] on joint i to {what} on joint i (frozen at q0; dotted: -3 dB edges)")
    return save_figure(fig, out_dir, f"frequency_{kind}")


def _grid_values(study: GainGridStudy, metric: str) -> tuple[np.ndarray, list]:
    """Values of one tool-tip metric over the grid (NaN where there is none) and the text of each cell."""
    out = np.full((len(study.kp), len(study.kd)), np.nan)
    text = [["" for _ in study.kd] for _ in study.kp]
    for i, row in enumerate(study.runs):
        for j, run in enumerate(row):
            if not run.ok:
                text[i][j] = "failed"
                continue
            value = getattr(run.tool_mm, metric)
            if value is None:
                text[i][j] = "not\nsettled"
            else:
                out[i, j] = value
                text[i][j] = f"{value:.3g}"
    return out, text


#: A panel whose every value is below this share of its study's largest peak error is zero to rounding: a colour
#: scale over it would only show rounding noise (or, all values equal, matplotlib's arbitrary +-0.1 range).
ZERO_SHARE = 1e-6


def _zero_to_rounding(values: np.ndarray, study: GainGridStudy) -> float | None:
    """The bound (mm) under which every value of a panel lies when that is zero to rounding, else None."""
    finite = values[np.isfinite(values)]
    peaks = [run.tool_mm.peak_error for row in study.runs for run in row if run.ok]
    scale = max(peaks) if peaks else 0.0
    if finite.size == 0 or scale <= 0:
        return None
    bound = ZERO_SHARE * scale
    return bound if float(np.max(np.abs(finite))) <= bound else None


def gain_study_axes(with_dob: GainGridStudy, without_dob: GainGridStudy):
    """The figure of :func:`gain_study_figure`, not yet written (matplotlib Figure with a 2 x 4 grid of axes)."""
    metrics = (("settling_time_s", "settling time (s)"), ("steady_state_error", "steady-state error (mm)"),
               ("peak_error", "peak error (mm)"), ("rms_error", "RMS error (mm)"))
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5), constrained_layout=True)
    for r, (study, title) in enumerate(((with_dob, "with observer"), (without_dob, "without observer"))):
        for c, (metric, label) in enumerate(metrics):
            ax = axes[r, c]
            values, text = _grid_values(study, metric)
            zero = _zero_to_rounding(values, study) if metric != "settling_time_s" else None
            if zero is not None:
                # one flat grey, no colour bar: there is nothing to scale
                im = ax.imshow(np.where(np.isfinite(values), 0.0, np.nan), origin="lower", cmap="Greys",
                               vmin=-1.0, vmax=4.0, aspect="auto")
                text = [["0" if t and t[0].isdigit() else t for t in row] for row in text]
            else:
                im = ax.imshow(values, origin="lower", cmap="viridis", aspect="auto")
            for i in range(values.shape[0]):
                for j in range(values.shape[1]):
                    # dark text on the light (high) end of the colour map and on empty cells
                    light = zero is not None or not np.isfinite(values[i, j]) or im.norm(values[i, j]) > 0.6
                    ax.text(j, i, text[i][j], ha="center", va="center", fontsize=8,
                            color="black" if light else "white")
            ax.set_xticks(range(len(study.kd)), [f"{v:g}" for v in study.kd])
            ax.set_yticks(range(len(study.kp)), [f"{v:g}" for v in study.kp])
            ax.set_xlabel("Kd (1/s)")
            ax.set_ylabel("Kp (1/s^2)")
            if zero is not None:
                ax.set_title(f"tool tip {label}\n{title}: zero to rounding (< {zero:.1g} mm) at every gain",
                             fontsize=9)
            else:
                ax.set_title(f"tool tip {label}\n{title}", fontsize=9)
                fig.colorbar(im, ax=ax, shrink=0.8)
    definition = settling_definition(with_dob.settle_fraction, with_dob.final_window).capitalize()
    fig.suptitle(f"Gain study: tool-tip error after a disturbance step on the held arm, over Kp x Kd "
                 f"({with_dob.t_final_s:g} s runs)\n" + "\n".join(textwrap.wrap(definition, 150)), fontsize=10)
    return fig


def gain_study_figure(with_dob: GainGridStudy, without_dob: GainGridStudy, out_dir) -> list[Path]:
    """Heat maps of the tool-tip error metrics over the Kp x Kd grid, with and without the observer.

    A panel whose values are all zero to rounding (below :data:`ZERO_SHARE` of the study's largest peak
    error, as the observer's steady-state error is) is drawn flat, without a colour bar, and says so.
    """
    return save_figure(gain_study_axes(with_dob, without_dob), out_dir, "study_gains")


def observer_study_figure(study: ObserverGainStudy, out_dir, joints: JointSpace) -> list[Path]:
    """Trade-off of the observer gain: tool-tip error and torque noise against the slowest observer mode."""
    labels, runs, slowest = study.labels, study.runs, study.slowest_mode_rad_s
    ok = [k for k, r in enumerate(runs) if r.ok and slowest[k] is not None]
    base = runs[0].torque_noise_rms if runs[0].ok else None
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.6), constrained_layout=True)
    x = np.array([slowest[k] for k in ok])
    ax = axes[0]
    for metric, marker, name in (("peak_error", "o", "peak"), ("rms_error", "s", "RMS")):
        ax.plot(x, [getattr(runs[k].tool_mm, metric) for k in ok], marker, label=f"{name} tool-tip error")
    if runs[0].ok:
        peak, rms = runs[0].tool_mm.peak_error, runs[0].tool_mm.rms_error
        ax.axhline(peak, ls="--", lw=1, color="gray",
                   label=f"no observer: peak {peak:.3g} mm" + (f", RMS {rms:.3g} mm" if rms > 0.9 * peak else ""))
        if rms <= 0.9 * peak:                 # a separate line only where it does not lie on the peak's
            ax.axhline(rms, ls=":", lw=1, color="gray", label=f"no observer: RMS {rms:.3g} mm")
    for xi, k in zip(x, ok):
        ax.annotate(labels[k], (xi, runs[k].tool_mm.peak_error), textcoords="offset points", xytext=(4, 4),
                    fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("slowest observer mode over the workspace (rad/s)")
    ax.set_ylabel("tool-tip error (mm)")
    _finish(ax, f"What a faster observer buys (disturbance step, {study.t_final_s:g} s runs)", fontsize=7)
    if study.noise is None:                  # the arm takes no [noise] table: the cost panels say so
        for ax in axes[1:]:
            ax.axis("off")
            ax.text(0.5, 0.5, "torque noise not measured:\nthis arm takes no [noise] table", ha="center",
                    va="center", transform=ax.transAxes)
        return save_figure(fig, out_dir, "study_observer")
    ax = axes[1]
    noise = np.array([runs[k].torque_noise_rms for k in ok])
    n, titles, units = joints.count, joints.labels, joints.force_units
    for j in range(n):
        ratio = noise[:, j] / base[j] if base is not None else noise[:, j]
        ax.plot(x, ratio, "o", label=f"{titles[j]} ({units[j]})")
    ax.axhline(1.0, color="gray", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("slowest observer mode over the workspace (rad/s)")
    ax.set_ylabel("torque noise / torque noise without observer (1)" if base is not None else "torque noise")
    _finish(ax, "What it costs: torque noise from measurement noise")
    ax = axes[2]
    shown = [0] + ok if runs[0].ok else ok
    width = 0.8 / len(shown)
    for m, k in enumerate(shown):
        ax.bar(np.arange(n) + m * width, runs[k].torque_noise_rms, width,
               label="no observer" if labels[k] == "none" else labels[k])
    ax.set_xticks(np.arange(n) + 0.4 - width / 2,
                  [f"{titles[j]}\n({units[j]})" for j in range(n)], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("torque noise RMS (" + _units_words(joints) + ")")
    # the legend below the bars, where it covers none of them
    _finish(ax, "Torque noise per joint", axis="y", fontsize=7, ncol=3, loc="upper center",
            bbox_to_anchor=(0.5, -0.16))
    return save_figure(fig, out_dir, "study_observer")


def _units_words(joints: JointSpace) -> str:
    """The force units of an arm's joints in words: ``N m; N on Joint 3`` for the paper's arm, ``N m`` for an
    arm of revolute joints only."""
    units = joints.force_units
    common = max(dict.fromkeys(units), key=units.count)
    others = [j for j, u in enumerate(units) if u != common]
    if not others:
        return common
    rest = "; ".join(f"{units[j]} on {joints.labels[j].split(' (')[0]}" for j in others)
    return f"{common}; {rest}"
