"""The paper's Figures 4-8 from a run with and a run without the disturbance observer.

Each figure is written as PNG (and SVG on request), with labelled axes and units:

* ``fig4_joint_tracking``: reference and actual joint positions;
* ``fig5_tracking_error``: ``q_ref - q`` per joint;
* ``fig6_disturbance_estimate``: the lumped disturbance ``d`` and its estimate ``d_hat``;
* ``fig7_estimation_error``: ``d - d_hat``;
* ``fig8_task_space``: the tool-tip path in task space (x, y, z) and its error.

The joints (how many, their names and units) come from the arm of the run's
scenario (:attr:`blocks.model.arm.ArmModel.joints`): Figures 4-7 have one panel per
joint, in a grid sized by :func:`joint_grid_shape` (2 x 2 for the paper's four
joints), each titled ``Joint i (name)`` with the joint's unit on its axis.

Where the time goes (measured on the paper run, CPU seconds for the five
figures): drawing, not the data.  matplotlib's constrained layout draws a
figure once more to measure it, before every format it is saved in; SVG costs
about as much again as PNG.  So Figures 4-8 are laid out with fixed margins
(one draw per format), and :func:`save_figure` lays out any other figure once
and reuses that layout for all its formats.  The joint panels' tick labels are
plain text (only the power of ten above an axis is mathtext): parsing each label
as mathtext was a quarter of the figures' time.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import ScalarFormatter  # noqa: E402

from blocks.model.joints import JointSpace  # noqa: E402
from blocks.scenarios.scenario import default_arm  # noqa: E402

__all__ = ["paper_figures", "sampling_words", "save_figure", "convergence_figure", "joint_title",
           "REFERENCE_STYLE", "has_tissue_model", "FIGURE_FORMATS", "joint_grid_shape", "run_joints",
           "joint_signals", "joint_axes", "position_scale"]

#: The formats a figure may be written in.
FIGURE_FORMATS = ("png", "svg")

_COLORS = {"with": "tab:blue", "without": "tab:red", "d_hat": "tab:blue"}
#: The reference (or the true value) as a wide light band drawn first: a line that follows it exactly stays
#: visible on top of it, and the band stays visible around that line.
REFERENCE_STYLE = {"color": "0.72", "lw": 5.0, "solid_capstyle": "butt", "zorder": 1}


def joint_title(name: str, joints: JointSpace) -> str:
    """The person's name of a joint signal: ``"q[2]"`` -> ``"Joint 3 (d3)"``; other names unchanged.

    ``joints`` names the arm's joints (:attr:`blocks.model.arm.ArmModel.joints`).
    """
    if name.endswith("]") and "[" in name:
        index = name[name.index("[") + 1:-1]
        if index.isdigit() and int(index) < joints.count:
            return joints.labels[int(index)]
    return name


def run_joints(resp) -> JointSpace:
    """The joints of the arm a response ran on (its scenario's ``robot``); the default scenario's without one."""
    robot = getattr(getattr(resp, "scenario", None), "robot", None)
    joints = getattr(robot, "joints", None)
    return joints if isinstance(joints, JointSpace) else default_arm().joints


def joint_signals(resp, prefix: str, n: int) -> np.ndarray:
    """The joint signals ``prefix[0]`` .. ``prefix[n-1]`` of a response, shape ``(n, len(time))``.

    Raises
    ------
    KeyError
        If the response lacks one of them (the message names the signal and what the response has).
    """
    labels = list(resp.output_labels)
    rows = []
    for i in range(n):
        name = f"{prefix}[{i}]"
        if name not in labels:
            have = sorted({label.split("[")[0] for label in labels})
            raise KeyError(f"response has no signal '{name}' (an arm of {n} joints); its signals are {have}")
        rows.append(labels.index(name))
    return np.asarray(resp.outputs)[rows]


def position_scale(joints: JointSpace, i: int) -> tuple[float, str]:
    """Factor and unit a figure shows joint ``i``'s position in: prismatic joints in mm, revolute ones in rad."""
    return (1e3, "mm") if joints.position_units[i] == "m" else (1.0, joints.position_units[i])


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
#: The same margins in inches (what the fractions are on the paper's 11 x 7 in figure), for other grid sizes.
_MARGIN_IN = {"left": 0.88, "right": 0.165, "bottom": 0.525, "top": 0.7}


class _PlainTickFormatter(ScalarFormatter):
    """Tick labels as plain text, the power of ten above the axis (``x10^-3``) as mathtext.

    matplotlib's mathtext parse of every distinct tick label was a quarter of the figures' time; plain text draws
    the same digits in the same font.  Scientific style from 1e-3 down and 1e4 up.
    """

    def __init__(self) -> None:
        super().__init__(useMathText=True)
        self.set_scientific(True)
        self.set_powerlimits((-3, 4))

    def __call__(self, x, pos=None) -> str:
        label = super().__call__(x, pos)
        wrap = ("$\\mathdefault{", "}$")
        if label.startswith(wrap[0]) and label.endswith(wrap[1]):
            label = label[len(wrap[0]):-len(wrap[1])]
        return label


def joint_grid_shape(n: int) -> tuple[int, int]:
    """Rows and columns of a grid with one panel per joint: a single row up to 3 joints, then about square.

    >>> [joint_grid_shape(n) for n in (1, 2, 3, 4, 6, 7)]
    [(1, 1), (1, 2), (1, 3), (2, 2), (2, 3), (3, 3)]
    """
    if int(n) != n or n < 1:
        raise ValueError(f"joint count must be a whole number >= 1, got {n!r}")
    cols = n if n <= 3 else int(np.ceil(np.sqrt(n)))
    return int(np.ceil(n / cols)), cols


def joint_axes(title: str, joints: JointSpace):
    """A figure with one panel per joint (titled ``Joint i (name)``, shared time axis), and its panels in order.

    Unused cells of the grid are removed; the panel at the foot of each column carries the time axis label.
    """
    n = joints.count
    rows, cols = joint_grid_shape(n)
    if (rows, cols) == (2, 2):
        size, margins = (11, 7), _GRID_MARGINS
    else:
        size = ({1: 7.0, 2: 11.0}.get(cols, 1.0 + 4.4 * cols), 1.2 + 2.9 * rows)
        margins = {"left": _MARGIN_IN["left"] / size[0], "right": 1 - _MARGIN_IN["right"] / size[0],
                   "bottom": _MARGIN_IN["bottom"] / size[1], "top": 1 - _MARGIN_IN["top"] / size[1],
                   "wspace": 0.2 if cols <= 2 else 0.3, "hspace": 0.18 if rows <= 2 else 0.24}
    # fixed margins (room for tick labels such as -0.00025 and a unit label): no layout pass per format
    fig, grid = plt.subplots(rows, cols, figsize=size, sharex=True, squeeze=False, gridspec_kw=margins)
    fig.suptitle(title)
    cells = list(grid.flat)
    for ax in cells[n:]:
        ax.remove()
    axes = cells[:n]
    for i, ax in enumerate(axes):
        ax.set_title(joints.labels[i], fontsize=10)
        ax.grid(True, alpha=0.3)
        # below 1e-3 the axis shows a power of ten above it, so no tick label is wider than the margins allow
        ax.yaxis.set_major_formatter(_PlainTickFormatter())
        if i + cols >= n:                     # the lowest panel of its column
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("time (s)")
    return fig, axes


def sampling_words(resp) -> str | None:
    """How a sampled run's estimate was made ("sampled at 1000 Hz, quantized encoders, ..."), None when continuous.

    Read from the response's scenario (:func:`blocks.figure2.derived.loop_response` keeps it): its ``[controller]``
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


def paper_figures(with_dob, without_dob, out_dir, progress=None, formats=FIGURE_FORMATS,
                  joints: JointSpace | None = None) -> list[Path]:
    """Write Figures 4-8 comparing a run with and a run without the observer.

    Parameters
    ----------
    with_dob, without_dob : control.TimeResponseData
        Responses of :func:`blocks.simulate` with ``observer=True`` and ``False``; Figure 8 needs the
        scenario they carry (its arm's tool point).
    out_dir : str or pathlib.Path
        Folder for the figure files (created if needed).
    progress : callable, optional
        ``progress(fraction)`` after each figure (fraction of the five written).
    formats : sequence of {"png", "svg"}
        The formats of each figure (default both; ``dobkit simulate`` writes PNG unless ``--svg``).
    joints : blocks.model.joints.JointSpace, optional
        The arm's joints (count, names, units); default: those of the runs' scenario (:func:`run_joints`).

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
    joints = run_joints(with_dob) if joints is None else joints
    n, force_units = joints.count, joints.force_units
    t = np.asarray(with_dob.time)
    q_ref, q_w = joint_signals(with_dob, "q_ref", n), joint_signals(with_dob, "q", n)
    q_wo = joint_signals(without_dob, "q", n)
    written = []

    fig, axes = joint_axes(_tracking_title(with_dob), joints)
    for i, ax in enumerate(axes):
        k, unit = position_scale(joints, i)
        ax.plot(t, k * q_ref[i], **REFERENCE_STYLE, label="reference (grey band)")
        ax.plot(t, k * q_w[i], color=_COLORS["with"], lw=1.2, label="with observer")
        ax.plot(t, k * q_wo[i], color=_COLORS["without"], lw=1.2, ls="--", label="without observer")
        ax.set_ylabel(f"position ({unit})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig4_joint_tracking", formats)
    done(1)

    fig, axes = joint_axes("Figure 5: position tracking error q_ref - q", joints)
    for i, ax in enumerate(axes):
        k, unit = position_scale(joints, i)
        ax.plot(t, k * (q_ref[i] - q_w[i]), color=_COLORS["with"], label="with observer")
        ax.plot(t, k * (q_ref[i] - q_wo[i]), color=_COLORS["without"], ls="--", label="without observer")
        ax.set_ylabel(f"error ({unit})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig5_tracking_error", formats)
    done(2)

    d, d_hat = joint_signals(with_dob, "d", n), joint_signals(with_dob, "d_hat", n)
    tau_dis = joint_signals(with_dob, "tau_dis", n)
    sampled = sampling_words(with_dob)
    fig, axes = joint_axes("Figure 6: disturbance and its estimate (with observer)" if sampled is None else
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
        ax.set_ylabel(f"disturbance ({force_units[i]})")
    axes[0].legend(fontsize=8)
    written += save_figure(fig, out_dir, "fig6_disturbance_estimate", formats)
    done(3)

    fig, axes = joint_axes("Figure 7: disturbance estimation error d - d_hat", joints)
    for i, ax in enumerate(axes):
        ax.plot(t, d[i] - d_hat[i], color=_COLORS["with"])
        ax.set_ylabel(f"error ({force_units[i]})")
    written += save_figure(fig, out_dir, "fig7_estimation_error", formats)
    done(4)

    written += _task_space_figure(with_dob, q_ref, q_w, q_wo, out_dir, formats)
    done(5)
    return written


def _tracking_title(resp) -> str:
    """Figure 4's title: the paper's laceration path by name, any other path as the scenario's path."""
    trajectory = getattr(getattr(resp, "scenario", None), "data", {}).get("trajectory", {})
    kind = trajectory.get("kind") if isinstance(trajectory, dict) else None
    return "Figure 4: joint tracking of the " + ("laceration path" if kind in (None, "laceration") else
                                                 f"scenario's path ({kind})")


def _task_space_figure(with_dob, q_ref, q_w, q_wo, out_dir: Path, formats) -> list[Path]:
    scenario = with_dob.scenario
    robot = scenario.robot                  # any arm model: its tool point, in the base frame
    t = np.asarray(with_dob.time)
    p_ref, p_w, p_wo = (1e3 * np.asarray(robot.tool_position(q.T))[:, :3] for q in (q_ref, q_w, q_wo))
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


def convergence_figure(study: dict, out_dir, joints: JointSpace, stem: str = "convergence") -> list[Path]:
    """Log-log plot of the errors per joint against ``h`` with the fitted slope; PNG and SVG.

    Parameters
    ----------
    study : dict
        The result of :func:`cosim_convergence`.
    out_dir : str or pathlib.Path
        Folder to write ``<stem>.png`` and ``<stem>.svg`` in.
    joints : blocks.model.joints.JointSpace
        The arm's joints, which name the curves.

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
        points = ax.loglog(h[ok] * 1e3, errs[ok], "o", ms=7, label=f"{joint_title(name, joints)} ({unit})")[0]
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
