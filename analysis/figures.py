"""The paper's Figures 4-8 from a run with and a run without the disturbance observer.

Each figure is written as PNG (and SVG on request), with labelled axes and units:

* ``fig4_joint_tracking``: reference and actual joint positions;
* ``fig5_tracking_error``: ``q_ref - q`` per joint;
* ``fig6_disturbance_estimate``: the lumped disturbance ``d`` and its estimate ``d_hat``;
* ``fig7_estimation_error``: ``d - d_hat``;
* ``fig8_task_space``: the tool-tip path in task space (x, y, z) and its error.

Where the time goes (measured on the paper run, CPU seconds for the five
figures): drawing, not the data.  matplotlib's constrained layout draws a
figure once more to measure it, before every format it is saved in; SVG costs
about as much again as PNG.  So Figures 4-8 are laid out with fixed margins
(one draw per format), and :func:`save_figure` lays out any other figure once
and reuses that layout for all its formats.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from blocks.joints import RRPR_JOINTS  # noqa: E402
from blocks.kinematics import forward_kinematics  # noqa: E402
from blocks.metrics import signal  # noqa: E402
from blocks.parameters import RobotParameters  # noqa: E402

__all__ = ["paper_figures", "sampling_words", "save_figure", "convergence_figure", "JOINT_TITLES", "joint_title",
           "REFERENCE_STYLE", "has_tissue_model", "FIGURE_FORMATS"]

#: The formats a figure may be written in.
FIGURE_FORMATS = ("png", "svg")

#: How every figure names the joints (the names a person reads everywhere: ``Joint 1 (theta1)``, ...).
JOINT_TITLES = RRPR_JOINTS.labels
_COLORS = {"with": "tab:blue", "without": "tab:red", "d_hat": "tab:blue"}
#: The reference (or the true value) as a wide light band drawn first: a line that follows it exactly stays
#: visible on top of it, and the band stays visible around that line.
REFERENCE_STYLE = {"color": "0.72", "lw": 5.0, "solid_capstyle": "butt", "zorder": 1}


def joint_title(name: str) -> str:
    """The person's name of a joint signal: ``"q[2]"`` -> ``"Joint 3 (d3)"``; other names unchanged."""
    if name.endswith("]") and "[" in name:
        index = name[name.index("[") + 1:-1]
        if index.isdigit() and int(index) < len(JOINT_TITLES):
            return JOINT_TITLES[int(index)]
    return name


def has_tissue_model(scenario) -> bool:
    """Whether the scenario's disturbance includes the tissue model (a force that resists the tool below the skin)."""
    kind = scenario.data["disturbance"]["kind"]
    return "tissue" in ([kind] if isinstance(kind, str) else list(kind))


def _checked_formats(formats) -> tuple[str, ...]:
    formats = (formats,) if isinstance(formats, str) else tuple(formats)
    if not formats or any(f not in FIGURE_FORMATS for f in formats):
        raise ValueError(f"figure formats must be one or more of {list(FIGURE_FORMATS)}, got {formats!r}")
    return formats


def save_figure(fig, out_dir: Path, stem: str, formats=FIGURE_FORMATS) -> list[Path]:
    """Write ``fig`` as ``stem.png`` (120 dpi) and/or ``stem.svg`` in ``out_dir`` without metadata (dates), close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    out_dir : str or pathlib.Path
        Folder (created if needed).
    stem : str
        File name without suffix.
    formats : sequence of {"png", "svg"}
        The formats to write, in order (default both).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    formats = _checked_formats(formats)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{stem}.{fmt}" for fmt in formats]
    # A layout engine makes every savefig draw the figure twice (once to measure it): lay it out once here and
    # keep that layout for every format.
    engine = fig.get_layout_engine()
    if engine is not None:
        engine.execute(fig)
        fig.set_layout_engine(None)
    # No dates, no tool stamps and fixed SVG ids: the same run gives byte-identical files.
    with plt.rc_context({"svg.hashsalt": "dobkit"}):
        for fmt, path in zip(formats, paths):
            if fmt == "png":
                fig.savefig(path, dpi=120, metadata={"Software": None})
            else:
                fig.savefig(path, metadata={"Date": None, "Creator": None})
    plt.close(fig)
    return paths


#: Margins of the 2x2 joint grids (figure fractions), measured to fit the widest tick labels and the titles.
_GRID_MARGINS = {"left": 0.08, "right": 0.985, "bottom": 0.075, "top": 0.9, "wspace": 0.2, "hspace": 0.18}


def _joint_grid(title: str, joints=RRPR_JOINTS):
    # fixed margins (room for tick labels such as -0.00025 and a unit label): no layout pass per format;
    # two columns, a row per two joints (the paper's four: 2x2)
    n = joints.count
    rows = (n + 1) // 2
    fig, axes = plt.subplots(rows, 2, figsize=(11, 3.5 * rows), sharex=True, gridspec_kw=_GRID_MARGINS,
                             squeeze=False)
    fig.suptitle(title)
    for ax in axes.flat[n:]:
        ax.remove()
    for i, ax in enumerate(axes.flat[:n]):
        ax.set_title(joints.labels[i], fontsize=10)
        ax.grid(True, alpha=0.3)
        # below 1e-3 the axis shows a power of ten above it, so no tick label is wider than the margins allow
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4), useMathText=True)
        if i >= n - 2:
            ax.set_xlabel("time (s)")
    return fig, axes.flat[:n]


def _scale(i: int, joints=RRPR_JOINTS) -> tuple[float, str]:
    """Show a prismatic joint in mm, revolute joints in rad."""
    return (1e3, "mm") if joints.position_units[i] == "m" else (1.0, "rad")


def sampling_words(resp) -> str | None:
    """How a sampled run's estimate was made ("sampled at 1000 Hz, quantized encoders, ..."), None when continuous.

    Read from the response's scenario (:func:`blocks.derived.loop_response` keeps it): its ``[controller]``
    section makes the controller a program sampled at ``sample_rate``.
    """
    controller = getattr(getattr(resp, "scenario", None), "controller", None)
    if controller is None:
        return None
    rate = float(controller.sample_rate)
    quantized = any(float(r) > 0 for r in controller.position_resolution)
    words = (f"d_hat computed at {rate:g} Hz from {'quantized ' if quantized else ''}encoder readings, held "
             "between samples")
    step = float(np.median(np.diff(np.asarray(resp.time)))) if len(resp.time) > 1 else 0.0
    if step > 1.5 / rate:
        words += f"; drawn at the {1e3 * step:.3g} ms output instants"
    return words


def paper_figures(with_dob, without_dob, out_dir, progress=None, formats=FIGURE_FORMATS) -> list[Path]:
    """Write Figures 4-8 comparing a run with and a run without the observer.

    Parameters
    ----------
    with_dob, without_dob : control.TimeResponseData
        Responses of :func:`blocks.simulate` with ``observer=True`` and ``False``.
    out_dir : str or pathlib.Path
        Folder for the figure files (created if needed).
    progress : callable, optional
        ``progress(fraction)`` after each figure (fraction of the five written).
    formats : sequence of {"png", "svg"}
        The formats of each figure (default both; ``dobkit simulate`` writes PNG unless ``--svg``).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    def done(n: int) -> None:
        if progress is not None:
            progress(n / 5)

    formats = _checked_formats(formats)
    out_dir = Path(out_dir)
    t = np.asarray(with_dob.time)
    q_ref, q_w, q_wo = signal(with_dob, "q_ref"), signal(with_dob, "q"), signal(without_dob, "q")
    scenario = getattr(with_dob, "scenario", None)
    joints = scenario.robot.joints if scenario is not None else RRPR_JOINTS
    written = []

    fig, axes = _joint_grid("Figure 4: joint tracking of the laceration path", joints)
    for i, ax in enumerate(axes):
        k, unit = _scale(i, joints)
        ax.plot(t, k * q_ref[i], **REFERENCE_STYLE, label="reference (grey band)")
        ax.plot(t, k * q_w[i], color=_COLORS["with"], lw=1.2, label="with observer")
        ax.plot(t, k * q_wo[i], color=_COLORS["without"], lw=1.2, ls="--", label="without observer")
        ax.set_ylabel(f"position ({unit})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig4_joint_tracking", formats)
    done(1)

    fig, axes = _joint_grid("Figure 5: position tracking error q_ref - q", joints)
    for i, ax in enumerate(axes):
        k, unit = _scale(i, joints)
        ax.plot(t, k * (q_ref[i] - q_w[i]), color=_COLORS["with"], label="with observer")
        ax.plot(t, k * (q_ref[i] - q_wo[i]), color=_COLORS["without"], ls="--", label="without observer")
        ax.set_ylabel(f"error ({unit})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig5_tracking_error", formats)
    done(2)

    d, d_hat = signal(with_dob, "d"), signal(with_dob, "d_hat")
    tau_dis = signal(with_dob, "tau_dis")
    sampled = sampling_words(with_dob)
    fig, axes = _joint_grid("Figure 6: disturbance and its estimate (with observer)" if sampled is None else
                            "Figure 6: disturbance and its sampled, quantized estimate (with observer)", joints)
    if sampled is not None:
        fig.suptitle(fig.get_suptitle(), y=0.995)            # room for the line on how it was sampled
        fig.text(0.5, 0.94, sampled, ha="center", va="bottom", fontsize=9)
    for i, ax in enumerate(axes):
        ax.plot(t, d[i], **REFERENCE_STYLE, label="disturbance d, lumped (grey band)")
        if not np.allclose(d[i], tau_dis[i]):
            ax.plot(t, tau_dis[i], color="gray", lw=1, ls=":", label="external part tau_dis")
        if sampled is None:
            ax.plot(t, d_hat[i], color=_COLORS["d_hat"], lw=1.2, label="estimate d_hat")
        else:       # a program's output: a value held from each sample instant to the next, not a curve
            ax.step(t, d_hat[i], where="post", color=_COLORS["d_hat"], lw=0.8,
                    label="estimate d_hat, sampled (held)")
        ax.set_ylabel(f"disturbance ({joints.force_units[i]})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig6_disturbance_estimate", formats)
    done(3)

    fig, axes = _joint_grid("Figure 7: disturbance estimation error d - d_hat", joints)
    for i, ax in enumerate(axes):
        ax.plot(t, d[i] - d_hat[i], color=_COLORS["with"])
        ax.set_ylabel(f"error ({joints.force_units[i]})")
    written += save_figure(fig, out_dir, "fig7_estimation_error", formats)
    done(4)

    written += _task_space_figure(with_dob, without_dob, out_dir, formats)
    done(5)
    return written


def _task_space_figure(with_dob, without_dob, out_dir: Path, formats) -> list[Path]:
    scenario = with_dob.scenario
    robot = scenario.robot
    t = np.asarray(with_dob.time)
    if isinstance(robot, RobotParameters):
        p_ref = 1e3 * forward_kinematics(signal(with_dob, "q_ref").T, robot)[:, :3]
        p_w = 1e3 * forward_kinematics(signal(with_dob, "q").T, robot)[:, :3]
        p_wo = 1e3 * forward_kinematics(signal(without_dob, "q").T, robot)[:, :3]
    else:                           # any arm: its tool point (blocks.arm.ArmModel.tool_position)
        p_ref, p_w, p_wo = (1e3 * robot.tool_position(signal(r, sig).T)
                            for r, sig in ((with_dob, "q_ref"), (with_dob, "q"), (without_dob, "q")))
    fig = plt.figure(figsize=(13, 7))
    skin = getattr(scenario.trajectory, "skin_height", None)
    title = "Figure 8: tool-tip path in task space"
    if skin is not None and not has_tissue_model(scenario):
        title += "\n(this scenario has no tissue model: nothing resists the tool below the skin)"
    fig.suptitle(title)
    grid = fig.add_gridspec(3, 2, width_ratios=[1.2, 1], left=0.01, right=0.985, bottom=0.075, top=0.87,
                            wspace=0.1, hspace=0.22)
    ax3 = fig.add_subplot(grid[:, 0], projection="3d")
    ax3.plot(*p_ref.T, color="black", lw=2.2, label="reference")
    ax3.plot(*p_w.T, color=_COLORS["with"], lw=1.2, label="with observer")
    ax3.plot(*p_wo.T, color=_COLORS["without"], lw=1.2, ls="--", label="without observer")
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    ax3.legend(fontsize=8, loc="upper left")
    for k, name in enumerate("xyz"):
        ax = fig.add_subplot(grid[k, 1])
        ax.plot(t, p_ref[:, k], **REFERENCE_STYLE, label="reference (grey band)")
        ax.plot(t, p_w[:, k], color=_COLORS["with"], lw=1.2, label="with observer")
        ax.plot(t, p_wo[:, k], color=_COLORS["without"], lw=1.2, ls="--", label="without observer")
        ax.set_ylabel(f"{name} (mm)")
        ax.grid(True, alpha=0.3)
        if k == 2:
            if skin is not None:
                ax.axhline(1e3 * skin, color="tab:brown", lw=0.9, ls=":", label="skin surface")
            ax.set_xlabel("time (s)")
            ax.legend(fontsize=7, loc="center right")
    return save_figure(fig, out_dir, "fig8_task_space", formats)


def convergence_figure(study: dict, out_dir, stem: str = "convergence") -> list[Path]:
    """Log-log plot of the errors per joint against ``h`` with the fitted slope; PNG and SVG.

    Parameters
    ----------
    study : dict
        The result of :func:`cosim_convergence`.
    out_dir : str or pathlib.Path
        Folder to write ``<stem>.png`` and ``<stem>.svg`` in.

    Returns
    -------
    list of pathlib.Path
    """
    h = np.asarray(study["steps"])
    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    for name, errs in study["errors"].items():
        errs = np.asarray(errs)
        ok = errs > 0
        unit = study["units"][name]
        # the data as markers only, the fit as a line through them: a line that fits well stays visible
        points = ax.loglog(h[ok] * 1e3, errs[ok], "o", ms=7, label=f"{joint_title(name)} ({unit})")[0]
        if ok.sum() >= 2 and np.isfinite(study["order"]):
            # the common fitted slope through this joint's points (its own intercept)
            c = np.mean(np.log(errs[ok]) - study["order"] * np.log(h[ok]))
            ax.loglog(h * 1e3, np.exp(c) * h ** study["order"], "-", color=points.get_color(), lw=1.2, zorder=1)
    ax.plot([], [], "k-", lw=1.2, label=f"fitted slope p = {study['order']:.3f} (common to all joints)")
    ax.set_xticks(h * 1e3, [f"{v:g}" for v in h * 1e3])
    ax.minorticks_off()
    ax.set_xlabel("communication step h (ms)")
    ax.set_ylabel("max |q_cosim - q_monolithic| (rad; joint 3 in m)")
    ax.set_title(f"{study['scenario']}: co-simulation error vs step, FMI {study['fmi_version']}, "
                 f"t_final = {study['t_final']:g} s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=9)
    return save_figure(fig, Path(out_dir), stem)
