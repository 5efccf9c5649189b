"""Figures and the report section of a tuning (``tune.json`` of :mod:`analysis.tune.runner`).

Figures (PNG and SVG, in ``figures/`` of the tuning's folder):

``tune_history``
    The objective of every simulated evaluation in order, feasible and not,
    the best feasible one so far, the base gains' objective, and where the
    polish starts.
``tune_robustness``
    The distribution of the metric over the set's runs with the base gains and
    with the tuned ones (their worst and mean marked).
``tune_constraints``
    Torque noise and peak torque per joint with the base and the tuned gains,
    against the budget and the limit.
``tune_step``, ``tune_bode`` (when the runner hands over the designs' error dynamics)
    Each joint's response to a unit step of its own reference, and its
    disturbance-to-error gain ``|E_j / D_j|`` over frequency, with the base and the
    tuned gains, from the loop linearized at the tuning's held configuration
    (:mod:`analysis.tune.response`).

:func:`html_section` renders a tuning folder as one self-contained HTML
``<section>`` (template ``tune_section.html``, autoescaped, figures embedded)
for ``dobkit report --tune``.
"""
from __future__ import annotations

import base64
import math
from pathlib import Path

import numpy as np

from analysis.jobs.figures import new_figure, save_figure
from analysis.report.html import template_environment
from analysis.tune.results import read_result
from analysis.tune.spec import METRIC_WORDS, overshoots

__all__ = ["write_figures", "html_section", "read_result", "evaluation_counts", "evaluations_text", "FIGURES"]

FIGURES = ("tune_history", "tune_robustness", "tune_constraints", "tune_step", "tune_bode")
#: Frequencies of the disturbance-to-error figure (rad/s).
BODE_OMEGA = np.geomspace(1e-2, 1e3, 300)


def evaluation_counts(result) -> dict[str, int]:
    """A tuning's evaluations counted once, from its history, for every place that states them.

    Returns
    -------
    dict of str to int
        ``total`` (every evaluation, the base gains' and the final one included), ``base``, ``search``,
        ``polish``, ``final`` (per phase), ``refused`` (refused by the linear constraints, not simulated),
        ``with_simulation`` (``total - refused``), of those ``simulated_now`` (candidates simulated in this
        run), ``from_log`` (taken from the evaluation log of an earlier run) and ``repeats`` (gains already
        simulated earlier in the same search, evaluated again).
    """
    h = result.history
    phases = list(h.phase)
    total = len(phases)
    with_simulation = int(sum(bool(s) for s in h.simulated))
    now = int(result.evaluations.get("simulated", 0))
    from_log = int(result.evaluations.get("from_log", 0))
    return {"total": total, **{p: phases.count(p) for p in ("base", "search", "polish", "final")},
            "refused": total - with_simulation, "with_simulation": with_simulation, "simulated_now": now,
            "from_log": from_log, "repeats": max(0, with_simulation - now - from_log)}


def evaluations_text(result) -> str:
    """One sentence on a tuning's evaluations (:func:`evaluation_counts`): the same words in the report's
    section, its figure caption and the command's output.

    Examples
    --------
    ``397 evaluations (1 with the base gains, 336 search, 60 polish): 243 refused by the linear constraints
    without simulating, 154 with a simulation of the set (148 simulated in this run, 6 repeats of gains
    already simulated)``
    """
    c = evaluation_counts(result)
    phases = ", ".join(f"{c[p]} {word}" for p, word in (("base", "with the base gains"), ("search", "search"),
                                                        ("polish", "polish"), ("final", "final"))
                       if c[p] or p in ("search", "polish"))
    parts = [f"{c['simulated_now']} simulated in this run"]
    if c["from_log"]:
        parts.append(f"{c['from_log']} taken from the evaluation log of an earlier, stopped run")
    if c["repeats"]:
        parts.append(f"{c['repeats']} repeat{'s' if c['repeats'] != 1 else ''} of gains already simulated")
    return (f"{c['total']} evaluations ({phases}): {c['refused']} refused by the linear constraints without "
            f"simulating, {c['with_simulation']} with a simulation of the set ({', '.join(parts)})")


def _save(fig, folder: Path, stem: str) -> str:
    save_figure(fig, folder / stem)
    return f"{stem}.png"


_figure = new_figure


def write_figures(result, folder, designs: dict | None = None, joints=None) -> list[tuple[str, str]]:
    """Write the tuning's figures into ``folder``; return (PNG file name, caption) per figure.

    Parameters
    ----------
    result : TuneResult
    folder : path
    designs : dict, optional
        ``{"base gains": (sys, (kp, kd)), "tuned gains": ...}``: each design's linearized error dynamics
        (:func:`analysis.tune.response.error_dynamics`) and PD gains; with it the step and Bode figures are drawn.
    joints : blocks.model.joints.JointSpace, optional
        The arm's joints, for those figures' labels; required with ``designs``.
    """
    folder = Path(folder)
    words = METRIC_WORDS.get(result.metric, result.metric)
    out = []
    out.append(_history(result, folder, words))
    out.append(_robustness(result, folder, words))
    out.append(_constraints(result, folder))
    if designs:
        if joints is None:
            raise ValueError("write_figures: the step and Bode figures of 'designs' need the arm's joints")
        out.append(_step(designs, folder, joints))
        out.append(_bode(designs, folder, joints))
    return out


_DESIGN_COLOURS = {"base gains": "tab:gray", "tuned gains": "tab:blue"}


def _joint_axes(fig, n: int):
    cols = min(n, 4 if n != 4 else 2)
    rows = math.ceil(n / cols)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    return axes[:n]


def _step(designs: dict, folder: Path, joints) -> tuple[str, str]:
    from analysis.tune.response import as_gain_matrix, pd_poles, step_responses
    from analysis.tune.spec import damping_ratios

    n = joints.count
    slowest = min(float(np.min(np.abs(pd_poles(kp, kd, n).real))) for _, (kp, kd) in designs.values())
    t = np.linspace(0.0, float(np.clip(8.0 / max(slowest, 1e-9), 0.1, 20.0)), 600)
    fig = _figure((7.2, 4.6))
    axes = _joint_axes(fig, n)
    for label, (sys, (kp, kd)) in designs.items():
        x = step_responses(sys, t)
        zeta = damping_ratios(np.diag(as_gain_matrix(kp, n)), np.diag(as_gain_matrix(kd, n)))
        for j, ax in enumerate(axes):
            ax.plot(t, x[j], color=_DESIGN_COLOURS.get(label), lw=1.3,
                    label=f"{label}: zeta {zeta[j]:.2f}, overshoot {100 * max(0.0, x[j].max() - 1):.1f} %")
    for j, ax in enumerate(axes):
        ax.axhline(1.0, color="black", lw=0.6, ls=":")
        ax.set_title(joints.labels[j], fontsize=9)
        ax.set_xlabel("time after the step [s]")
        ax.set_ylabel("position / step [-]")
        ax.legend(fontsize=6, loc="lower right")
    caption = ("Each joint's position after a unit step of its own reference, as a fraction of the step, with the "
               "base and the tuned gains: the loop (computed torque and observer, the scenario's true and nominal "
               "models) linearized at the tuning's held configuration; above 1 is overshoot.")
    return _save(fig, folder, "tune_step"), caption


def _bode(designs: dict, folder: Path, joints) -> tuple[str, str]:
    from analysis.tune.response import disturbance_gains

    n = joints.count
    fig = _figure((7.2, 4.6))
    axes = _joint_axes(fig, n)
    for label, (sys, _) in designs.items():
        gains = disturbance_gains(sys, BODE_OMEGA)
        for j, ax in enumerate(axes):
            ax.loglog(BODE_OMEGA, gains[j], color=_DESIGN_COLOURS.get(label), lw=1.3,
                      label=f"{label}: peak {gains[j].max():.3g} at {BODE_OMEGA[np.argmax(gains[j])]:.3g} rad/s")
    for j, ax in enumerate(axes):
        unit = f"{joints.position_units[j]}/({joints.force_units[j]})" if " " in joints.force_units[j] else \
            f"{joints.position_units[j]}/{joints.force_units[j]}"
        ax.set_title(joints.labels[j], fontsize=9)
        ax.set_xlabel("frequency [rad/s]")
        ax.set_ylabel(f"|E / D| [{unit}]")
        ax.legend(fontsize=6, loc="lower center")
    caption = ("Error dynamics over frequency: the tracking error per unit of a sinusoidal disturbance on the same "
               "joint, |E_j / D_j|, with the base and the tuned gains (the loop linearized at the tuning's held "
               "configuration); it falls to zero at low frequency, where the observer cancels the disturbance.")
    return _save(fig, folder, "tune_bode"), caption


def _history(result, folder: Path, words: str) -> tuple[str, str]:
    h = result.history
    n = len(h.phase)
    index = np.arange(1, n + 1)
    objective = np.array([np.nan if v is None else v for v in h.objective], dtype=float)
    feasible = np.array(h.feasible, dtype=bool)
    simulated = np.array(h.simulated, dtype=bool)
    fig = _figure((6.4, 3.6))
    ax = fig.subplots()
    shown = simulated & np.isfinite(objective)
    ax.scatter(index[shown & feasible], objective[shown & feasible], s=10, color="tab:blue", label="feasible")
    ax.scatter(index[shown & ~feasible], objective[shown & ~feasible], s=14, marker="x", color="tab:red",
               label="simulated, infeasible")
    best = np.where(feasible & np.isfinite(objective), objective, np.inf)
    running = np.minimum.accumulate(best) if n else best
    ok = np.isfinite(running)
    if ok.any():
        ax.step(index[ok], running[ok], where="post", color="black", lw=1.2, label="best feasible so far")
    if result.base.objective is not None:
        ax.axhline(result.base.objective, color="tab:gray", ls="--", lw=1, label="base gains")
    polish = [i for i, p in enumerate(h.phase) if p == "polish"]
    if polish:
        ax.axvline(polish[0] + 0.5, color="tab:green", ls=":", lw=1, label="polish starts")
    finite = objective[shown]
    if finite.size and np.nanmax(finite) > 20 * np.nanmin(finite) > 0:
        ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel(f"{result.objective} {words} [mm]")
    ax.legend(fontsize=7, loc="upper right")
    return _save(fig, folder, "tune_history"), _history_caption(result, words)


def _history_caption(result, words: str) -> str:
    """The history figure's caption; the report makes it again, so a folder written before the counts had
    one source states them as the section does."""
    return (f"The {result.objective} {words} over the {result.runs}-run set of each evaluation with a "
            f"simulation, in order ({evaluations_text(result)}), the best feasible one so far and the base "
            "scenario's gains (dashed).")


def _robustness(result, folder: Path, words: str) -> tuple[str, str]:
    fig = _figure((6.0, 3.4))
    ax = fig.subplots()
    sets = [("base gains", result.base, "tab:gray"), ("tuned gains", result.tuned, "tab:blue")]
    data = [np.array([np.nan if v is None else v for v in (p.values or [])], dtype=float) for _, p, _ in sets]
    finite = np.concatenate([d[np.isfinite(d)] for d in data]) if data else np.array([])
    if finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        if hi <= lo:
            lo, hi = lo * 0.95, hi * 1.05 + 1e-12
        edges = np.linspace(lo, hi, max(6, min(30, 2 * int(math.sqrt(result.runs))) + 1))
        for (label, _, color), d in zip(sets, data):
            d = d[np.isfinite(d)]
            if d.size:
                ax.hist(d, bins=edges, color=color, alpha=0.55, label=f"{label}: worst {d.max():.3g}, "
                        f"mean {d.mean():.3g} mm")
                ax.axvline(d.max(), color=color, lw=1.5)
                ax.axvline(d.mean(), color=color, lw=1, ls="--")
    ax.set_xlabel(f"{words} [mm]")
    ax.set_ylabel("runs")
    ax.legend(fontsize=7)
    caption = (f"Robustness: the {words} of each of the {result.runs} runs of the set (model mismatch and "
               "disturbances) with the base scenario's gains and with the tuned ones; solid lines: worst, "
               "dashed: mean.")
    return _save(fig, folder, "tune_robustness"), caption


def _constraints(result, folder: Path) -> tuple[str, str]:
    fig = _figure((7.2, 3.4))
    left, right = fig.subplots(1, 2)
    joints = np.arange(len(result.joints))
    width = 0.38
    handles = {}
    for ax, attr, limit_key, title in ((left, "torque_noise_rms", "torque_noise_rms", "torque noise (RMS)"),
                                       (right, "peak_torque", "torque_limit", "peak |torque| over the set")):
        for k, (label, point, color) in enumerate((("base gains", result.base, "tab:gray"),
                                                   ("tuned gains", result.tuned, "tab:blue"))):
            values = getattr(point, attr)
            if values is not None:
                handles[label] = ax.bar(joints + (k - 0.5) * width, [np.nan if v is None else v for v in values],
                                        width, color=color)
        limit = result.limits.get(limit_key)
        if limit is not None:
            handles["budget / limit"] = ax.scatter(joints, limit, marker="_", s=400, color="tab:red", zorder=3)
        ax.set_xticks(joints, list(result.joints))
        ax.set_ylabel(f"{title} [{'; '.join(dict.fromkeys(result.force_units))}]")
    noise = np.array([v for p in (result.base, result.tuned) for v in p.torque_noise_rms], dtype=float)
    if np.any(np.isfinite(noise) & (noise > 0)):
        left.set_yscale("log")          # a light joint (the RRPR's d3) is decades below the others
    fig.legend(list(handles.values()), list(handles), loc="outside upper center", ncol=len(handles), fontsize=8)
    caption = (f"Constraints per joint ({_units_phrase(result)}): the torque noise that the sensor noise "
               "causes (linearized held loop) and the peak torque over every run of the set, with the base and "
               "the tuned gains; red: the budget and the limit where the tuning sets them.")
    return _save(fig, folder, "tune_constraints"), caption


def _units_phrase(result) -> str:
    """The force units of the result's arm in words: ``"N m; N for the prismatic joint d3"`` for the RRPR."""
    prismatic = [name for name, unit in zip(result.joints, result.force_units) if unit == "N"]
    revolute = len(prismatic) < len(result.joints)
    if not prismatic:
        return "N m"
    words = f"the prismatic joint{'s' if len(prismatic) > 1 else ''} {', '.join(prismatic)}"
    return f"N m; N for {words}" if revolute else "N"


def _force_label(result) -> str:
    """``"[N m, N m, N, N m]"``: the unit of each joint's torque or force, in joint order."""
    return f"[{', '.join(result.force_units)}]"


# --------------------------------------------------------------------------------------------
# The report section
# --------------------------------------------------------------------------------------------
def _fmt(value, digits: int = 4) -> str:
    if value is None:
        return "-"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]"
    if isinstance(value, float) and not math.isfinite(value):
        return "-"
    return f"{value:.{digits}g}" if isinstance(value, (int, float)) else str(value)


def _gain_rows(result) -> list[list[str]]:
    rows = []
    for name, unit, bounds in zip(result.parameters, result.units, result.bounds):
        key, _, joint = name.partition("[")
        base, tuned = result.base.gains.get(key), result.tuned.gains.get(key)
        if joint:
            j = int(joint.rstrip("]"))
            base = base[j] if isinstance(base, list) and len(base) == len(result.joints) and \
                not isinstance(base[0], list) else base
            tuned = tuned[j] if isinstance(tuned, list) else tuned
        rows.append([name, unit, f"{_fmt(bounds[0])} to {_fmt(bounds[1])}", _fmt(base, 6), _fmt(tuned, 6)])
    return rows


def _margin(result, key: str) -> str:
    """The tuned gains' margin on one constraint, in its unit (analysis.tune.evaluate, "Margins")."""
    value = result.tuned.margins.get(key)
    if value is None:
        return "-"
    if key in ("torque_noise_rms", "torque_limit"):
        return f"{100 * value:+.3g} % of the limit"
    if key in ("max_overshoot", "sampled_margin"):
        return f"{100 * value:+.3g} % points"
    return f"{value:+.3g}" + (" 1/s" if key == "stability_margin" else "")


def _constraint_rows(result) -> list[list[str]]:
    limits, rows = result.limits, []
    if limits.get("torque_noise_rms") is not None:
        source = " (the base gains' own)" if limits.get("torque_noise_from") == "base" else ""
        rows.append([f"torque noise RMS {_force_label(result)}", _fmt(limits["torque_noise_rms"]) + source,
                     _fmt(result.base.torque_noise_rms), _fmt(result.tuned.torque_noise_rms),
                     _margin(result, "torque_noise_rms")])
    if limits.get("torque_limit") is not None:
        rows.append([f"peak |torque| {_force_label(result)}", _fmt(limits["torque_limit"]), _fmt(result.base.peak_torque),
                     _fmt(result.tuned.peak_torque), _margin(result, "torque_limit")])
    margin = limits.get("stability_margin")
    rows.append(["slowest pole, real part [1/s]", "-" if margin is None else f"<= {_fmt(-margin)}",
                 _fmt(result.base.spectral_abscissa), _fmt(result.tuned.spectral_abscissa),
                 _margin(result, "stability_margin")])
    if result.tuned.damping_ratio:
        minimum, overshoot = limits.get("min_damping_ratio"), limits.get("max_overshoot")
        bound = (f">= {_fmt(minimum)}" + (" (default)" if limits.get("damping_from") == "default" else "")
                 if minimum is not None else "-")
        rows.append(["damping ratio of the error dynamics, kd / (2 sqrt(kp)), per joint", bound,
                     _fmt(result.base.damping_ratio, 3), _fmt(result.tuned.damping_ratio, 3),
                     _margin(result, "min_damping_ratio")])
        if overshoot is not None:
            rows.append(["step overshoot of the error dynamics [%]", f"<= {_fmt(100 * overshoot)}",
                         _fmt([100 * v for v in overshoots(result.base.damping_ratio)], 3),
                         _fmt([100 * v for v in overshoots(result.tuned.damping_ratio)], 3),
                         _margin(result, "max_overshoot")])
    sampled = limits.get("sampled_margin")
    if sampled is not None:
        def ts(point):
            loop = point.sampled_loop
            return "-" if loop is None else f"{_fmt(loop['ts_lambda_max'])} of {_fmt(loop['ts_lambda_limit'])}"
        rows.append(["sampled loop: Ts lambda_max(Y M^-1) of its stability limit", f"<= {_fmt(1 - sampled)} of it",
                     ts(result.base), ts(result.tuned), _margin(result, "sampled_margin")])
    ratio = limits.get("min_observer_bandwidth_ratio")
    if ratio is not None:
        rows.append(["slowest observer mode / tracking bandwidth", f">= {_fmt(ratio)}",
                     _fmt(result.base.bandwidth_ratio), _fmt(result.tuned.bandwidth_ratio),
                     _margin(result, "min_observer_bandwidth_ratio")])
    return rows


def _damping_cost(result) -> str:
    """One sentence on what the damping constraint costs (empty without one)."""
    free, cost = result.unconstrained, result.damping_cost
    if free is None or cost is None:
        return ""
    words = METRIC_WORDS.get(result.metric, result.metric)
    searched = result.unconstrained_from == "search"
    how = "the same search run without it reaches" if searched else "the best of this search's own evaluations reaches"
    note = "" if searched else (" The search was steered by the constraint, so the optimum without it may be lower "
                                "still, and the cost larger (dobkit tune --compare-unconstrained runs the search "
                                "without it).")
    return (f"Without the damping constraint, {how} a {result.objective} {words} of {_fmt(free.objective)} mm with "
            f"damping ratios {_fmt(free.damping_ratio, 3)} (gains {_fmt_gains(free.gains)}): the constraint costs "
            f"{_fmt(cost)} mm.{note}")


#: Each costed constraint as the report names it.
_COST_NAMES = {"min_damping_ratio": "damping ratio of the error dynamics", "max_overshoot": "step overshoot",
               "min_observer_bandwidth_ratio": "observer bandwidth ratio", "sampled_margin": "sampled loop margin",
               "torque_noise_rms": "torque-noise budget"}


def _cost_rows(result) -> list[list[str]]:
    """One row per constraint searched without (``--constraint-costs``): margin, binds, objective and cost."""
    rows = []
    for c in result.constraint_costs or []:
        rows.append([_COST_NAMES.get(c.constraint, c.constraint), _margin(result, c.constraint),
                     "yes" if c.binds else "no", _fmt(c.objective), _fmt(c.cost),
                     _fmt_gains(c.gains) if c.binds else "-"])
    return rows


def _cost_note(result) -> str:
    """The sentence above the costs table: how they were measured, and the reference."""
    costs = result.constraint_costs
    if costs is None:
        return ""
    if not costs:
        return "The tuning has none of the constraints whose cost is measured."
    words = METRIC_WORDS.get(result.metric, result.metric)
    reference = costs[0].reference
    if reference is None:
        return "No evaluation met every constraint, so what each costs is not known."
    return (f"The same search was run again without each constraint in turn. With every constraint on, the lowest "
            f"{result.objective} {words} found is {_fmt(reference)} mm; without one, the lowest among the gains that "
            "meet every other constraint; the difference is what that constraint costs (0 where it does not bind).")


def _fmt_gains(gains: dict) -> str:
    return ", ".join(f"{k} = {_fmt(v, 6)}" for k, v in gains.items())


def html_section(folder) -> str:
    """A tuning folder as one self-contained HTML ``<section>`` (figures embedded as PNG data).

    Raises
    ------
    TuneError
        See :func:`read_result`.
    """
    folder = Path(folder)
    result = read_result(folder)
    words = METRIC_WORDS.get(result.metric, result.metric)
    figures = [(_history_caption(result, words) if f.file == "tune_history.png" else f.caption,
                "data:image/png;base64," + base64.b64encode((folder / "figures" / f.file).read_bytes()).decode("ascii"))
               for f in result.figures]
    view = {"r": result, "words": words, "gain_rows": _gain_rows(result),
            "constraint_rows": _constraint_rows(result),
            "base_objective": _fmt(result.base.objective), "tuned_objective": _fmt(result.tuned.objective),
            "base_nominal": _fmt(result.base.nominal), "tuned_nominal": _fmt(result.tuned.nominal),
            "evaluations": evaluations_text(result),
            "damping_cost": "" if result.constraint_costs is not None else _damping_cost(result),
            "cost_note": _cost_note(result), "cost_rows": _cost_rows(result)}
    return template_environment().get_template("tune_section.html").render(v=view, figures=figures)
