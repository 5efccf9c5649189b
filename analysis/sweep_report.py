"""Summaries of a sweep's results file: statistics, worst cases with their parameter values, and plots.

::

    from analysis.sweep_report import summarize, write_summary
    summary = summarize("sweep-results.jsonl")       # a dict, JSON-ready
    files = write_summary("sweep-results.jsonl", "sweep-summary")   # summary.json, summary.md, PNG + SVG figures

``summary.md`` is Markdown with relative links to the figures; :func:`html_section`
renders the same summary as a self-contained HTML ``<section>`` (figures embedded)
for ``dobkit report`` to include.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from blocks.parameters import RobotParameters
from blocks.metrics import DISTURBANCE_UNITS, JOINT_LABELS, JOINT_UNITS
from .sweep_runner import read_results

__all__ = ["summarize", "write_summary", "html_section", "metric_columns", "column_unit", "key_unit"]

_QUANTILES = (0.05, 0.5, 0.95)


def metric_columns(rows: list[dict]) -> dict[str, np.ndarray]:
    """Metric columns over the rows (``rms_position_error[2]``, ``max_tool_position_error_mm``); NaN where missing."""
    names: list[str] = []
    for row in rows:
        for name, value in row.get("metrics", {}).items():
            cols = [f"{name}[{j}]" for j in range(len(value))] if isinstance(value, list) else [name]
            names += [c for c in cols if c not in names]
    out = {c: np.full(len(rows), np.nan) for c in names}
    for i, row in enumerate(rows):
        for name, value in row.get("metrics", {}).items():
            if isinstance(value, list):
                for j, v in enumerate(value):
                    out[f"{name}[{j}]"][i] = np.nan if v is None else v
            else:
                out[name][i] = np.nan if value is None else value
    return out


def column_unit(column: str) -> str:
    """Unit of a metric column: the joint's unit, N m / N for disturbances, mm for the tool."""
    if column.endswith("_mm"):
        return "mm"
    if "[" in column:
        j = int(column.split("[")[1].rstrip("]"))
        return (DISTURBANCE_UNITS if "disturbance" in column else JOINT_UNITS)[j]
    return ""


def key_unit(key: str) -> str:
    """Unit of a swept scenario value, for axis labels."""
    section, _, name = key.partition(".")
    name, _, index = name.partition("[")
    if index and f"{section}.{name}" in ("disturbance.f_r", "disturbance.coulomb"):
        return DISTURBANCE_UNITS[int(index.rstrip("]"))]
    if section == "robot" and name in RobotParameters.names():
        return RobotParameters.unit(name)
    units = {"nominal_scale": "factor", "gains.kp": "1/s^2", "gains.kd": "1/s", "gains.observer": "kg m^2/s",
             "disturbance.f_r": "N m or N", "disturbance.coulomb": "N m or N", "noise.q_std": "rad or m",
             "noise.dq_std": "rad/s or m/s", "trajectory.duration": "s", "simulation.t_final": "s"}
    return units.get(section, units.get(f"{section}.{name}", ""))


def _label(column: str) -> str:
    if "[" in column:
        base, j = column.split("[")
        return f"{base} ({JOINT_LABELS[int(j.rstrip(']'))]})"
    return column


def summarize(results) -> dict:
    """Statistics of every metric column over the finished runs, the worst runs and the swept values' influence.

    Parameters
    ----------
    results : path or (header, rows)
        A results file written by :func:`analysis.sweep.run_sweep`.

    Returns
    -------
    dict
        ``sweep`` (the header), ``counts``, ``statistics`` (per column: count,
        mean, std, min, p5, median, p95, max, unit), ``worst`` (the
        ``worst_count`` runs with the largest ``worst_metric``, with their
        values), ``failed`` (diverged runs and their values), ``influence``
        (per swept scalar key: Spearman rank correlation with the worst metric).
    """
    header, rows = read_results(results) if not isinstance(results, tuple) else results
    header = header or {}
    ok = [r for r in rows if r.get("status") == "ok"]
    failed = [r for r in rows if r.get("status") != "ok"]
    cols = metric_columns(ok)
    stats = {}
    for name, values in cols.items():
        v = values[np.isfinite(values)]
        if v.size == 0:
            continue
        q05, q50, q95 = np.quantile(v, _QUANTILES)
        stats[name] = {"count": int(v.size), "mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                       "min": float(v.min()), "p5": float(q05), "median": float(q50), "p95": float(q95),
                       "max": float(v.max()), "unit": column_unit(name)}
    worst_metric = header.get("worst_metric") or (next(iter(cols)) if cols else None)
    worst_count = int(header.get("worst_count", 5))
    worst = []
    if worst_metric in cols:
        order = np.argsort(-np.nan_to_num(cols[worst_metric], nan=-np.inf))[:worst_count]
        worst = [{"run_id": ok[i]["run_id"], "index": ok[i]["index"], "values": ok[i]["values"],
                  worst_metric: float(cols[worst_metric][i])} for i in order]
    influence = {}
    if worst_metric in cols:
        y = cols[worst_metric]
        for key in sorted({k for r in ok for k in r["values"]}):
            x = np.array([_scalar(r["values"].get(key)) for r in ok], dtype=float)
            good = np.isfinite(x) & np.isfinite(y)
            if good.sum() >= 3 and np.ptp(x[good]) > 0 and np.ptp(y[good]) > 0:
                influence[key] = float(np.corrcoef(_ranks(x[good]), _ranks(y[good]))[0, 1])
    return {"sweep": header, "counts": {"runs": int(header.get("runs", len(rows))), "finished": len(rows),
                                        "ok": len(ok), "diverged": len(failed)},
            "worst_metric": worst_metric, "statistics": stats, "worst": worst,
            "failed": [{"run_id": r["run_id"], "index": r["index"], "values": r["values"],
                        "failed_at": r.get("failed_at"), "message": r.get("message", "")} for r in failed],
            "influence": influence}


def _scalar(value) -> float:
    if isinstance(value, bool) or value is None:
        return math.nan
    if isinstance(value, (int, float)):
        return float(value)
    return math.nan


def _ranks(x: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size)
    ranks[order] = np.arange(x.size)
    return ranks


def write_summary(results, out_dir, formats=("png", "svg")) -> dict:
    """Write ``summary.json``, ``summary.md`` and the figures to ``out_dir``; return their paths by name.

    Figures: one histogram panel per kept metric (the error distributions) and,
    for each swept scalar value, the worst metric against it with the worst
    runs marked (which values produced them).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header, rows = read_results(results) if not isinstance(results, tuple) else results
    summary = summarize((header, rows))
    ok = [r for r in rows if r.get("status") == "ok"]
    cols = metric_columns(ok)
    files: dict[str, list] = {"figures": []}

    groups: dict[str, list[str]] = {}
    for name in cols:
        groups.setdefault(name.split("[")[0], []).append(name)
    for metric, names in groups.items():
        # wide enough for the title of a one-panel figure; few ticks so long numbers do not collide
        fig, axes = plt.subplots(1, len(names), figsize=(max(3.4 * len(names), 6.0), 2.9), squeeze=False)
        for ax, name in zip(axes[0], names):
            v = cols[name][np.isfinite(cols[name])]
            ax.hist(v, bins=max(5, min(40, int(np.sqrt(max(v.size, 1))) * 2)), color="tab:blue", alpha=0.8)
            ax.set_xlabel(f"{_label(name)} [{column_unit(name)}]")
            ax.set_ylabel("runs")
            ax.xaxis.set_major_locator(plt.MaxNLocator(4))
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useOffset=False)
        fig.suptitle(f"Distribution of {metric} over {len(ok)} runs")
        fig.tight_layout()
        files["figures"] += _save(fig, out / f"hist_{metric}", formats)
        plt.close(fig)

    wm = summary["worst_metric"]
    worst_ids = {w["run_id"] for w in summary["worst"]}
    for key in summary["influence"]:
        x = np.array([_scalar(r["values"].get(key)) for r in ok])
        y = cols[wm]
        mark = np.array([r["run_id"] in worst_ids for r in ok])
        fig, ax = plt.subplots(figsize=(4.5, 3.2))
        ax.scatter(x[~mark], y[~mark], s=10, alpha=0.6, label="runs")
        ax.scatter(x[mark], y[mark], s=30, color="tab:red", label=f"worst {mark.sum()}")
        unit = key_unit(key)
        ax.set_xlabel(f"{key}" + (f" [{unit}]" if unit else ""))
        ax.set_ylabel(f"{_label(wm)} [{column_unit(wm)}]")
        ax.set_title(f"rank correlation {summary['influence'][key]:+.2f}")
        ax.legend(fontsize=8)
        fig.tight_layout()
        safe = key.replace(".", "_").replace("[", "_").replace("]", "")
        files["figures"] += _save(fig, out / f"worst_vs_{safe}", formats)
        plt.close(fig)

    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    (out / "summary.md").write_text(_markdown(summary, files["figures"], out), encoding="utf-8")
    files["json"], files["markdown"] = out / "summary.json", out / "summary.md"
    return files


def _save(fig, stem: Path, formats) -> list[Path]:
    paths = []
    for fmt in formats:
        path = stem.with_suffix(f".{fmt}")
        fig.savefig(path, dpi=120)
        paths.append(path)
    return paths


def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.4g}"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    return str(x)


def _markdown(summary: dict, figures: list[Path], out: Path) -> str:
    sw, c = summary["sweep"], summary["counts"]
    lines = [f"## Sweep '{sw.get('name', '?')}'", "",
             f"Base scenario '{sw.get('scenario', '?')}', engine {sw.get('engine', '?')}, "
             f"{'with' if sw.get('observer', True) else 'without'} observer: {c['finished']} of {c['runs']} runs "
             f"finished, {c['ok']} ok, {c['diverged']} diverged.", ""]
    if sw.get("grid"):
        lines += ["Grid: " + "; ".join(f"`{k}` = {_fmt(v)}" for k, v in sw["grid"].items()), ""]
    mc = sw.get("monte_carlo", {})
    if mc.get("distributions"):
        lines += [f"Monte Carlo: {mc['runs']} draws per grid point, seed {mc['seed']}: "
                  + "; ".join(f"`{k}` ~ {d['kind']}(" + ", ".join(f"{p}={_fmt(v)}" for p, v in d.items() if p != 'kind')
                              + ")" for k, d in mc["distributions"].items()), ""]
    lines += ["### Statistics", "", "| metric | unit | mean | std | min | p5 | median | p95 | max |",
              "|---|---|---|---|---|---|---|---|---|"]
    for name, s in summary["statistics"].items():
        lines.append(f"| {_label(name)} | {s['unit']} | " + " | ".join(_fmt(s[k]) for k in
                                                                   ("mean", "std", "min", "p5", "median", "p95", "max")) + " |")
    wm = summary["worst_metric"]
    if summary["worst"]:
        keys = sorted({k for w in summary["worst"] for k in w["values"]})
        lines += ["", f"### Worst {len(summary['worst'])} runs by {_label(wm)} [{column_unit(wm)}]", "",
                  "| run | " + " | ".join(f"`{k}`" for k in keys) + f" | {wm} |",
                  "|---|" + "---|" * (len(keys) + 1)]
        for w in summary["worst"]:
            lines.append(f"| {w['index']} | " + " | ".join(_fmt(w['values'].get(k, '')) for k in keys)
                         + f" | {_fmt(w[wm])} |")
    if summary["failed"]:
        lines += ["", "### Diverged runs", ""] + [f"- run {f['index']}: " + ", ".join(
            f"`{k}` = {_fmt(v)}" for k, v in f["values"].items()) + (f" (at t = {f['failed_at']:.4g} s)"
                                                                     if f.get("failed_at") is not None else "")
            for f in summary["failed"]]
    if summary["influence"]:
        lines += ["", f"### Influence on {_label(wm)} (Spearman rank correlation)", "",
                  "| value | correlation |", "|---|---|"]
        lines += [f"| `{k}` | {v:+.2f} |" for k, v in sorted(summary["influence"].items(), key=lambda kv: -abs(kv[1]))]
    pngs = [f for f in figures if f.suffix == ".png"]
    if pngs:
        lines += ["", "### Figures", ""] + [f"![{f.stem}]({f.relative_to(out)})" for f in pngs]
    return "\n".join(lines) + "\n"


def html_section(summary_dir) -> str:
    """The summary written by :func:`write_summary` as one self-contained HTML ``<section>``.

    Tables of the statistics and the worst runs (with the values that produced
    them), the diverged runs, the influence of each swept value, and every PNG
    figure embedded as data.
    """
    folder = Path(summary_dir)
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    esc = html.escape
    sw, c, wm = summary["sweep"], summary["counts"], summary["worst_metric"]

    def table(header, rows):
        head = "".join(f"<th>{esc(str(h))}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{esc(str(x))}</td>" for x in row) + "</tr>" for row in rows)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    parts = [f"<section class='sweep'><h2>Sweep {esc(str(sw.get('name', '?')))}</h2>",
             f"<p>Base scenario {esc(str(sw.get('scenario', '?')))}, engine {esc(str(sw.get('engine', '?')))}: "
             f"{c['finished']} of {c['runs']} runs finished, {c['ok']} ok, {c['diverged']} diverged.</p>",
             table(["metric", "unit", "mean", "std", "min", "p5", "median", "p95", "max"],
                   [[_label(n), st["unit"]] + [_fmt(st[k]) for k in ("mean", "std", "min", "p5", "median", "p95", "max")]
                    for n, st in summary["statistics"].items()])]
    if summary["worst"]:
        keys = sorted({k for w in summary["worst"] for k in w["values"]})
        parts += [f"<h3>Worst runs by {esc(_label(wm))} [{esc(column_unit(wm))}]</h3>",
                  table(["run"] + keys + [wm], [[w["index"]] + [_fmt(w["values"].get(k, "")) for k in keys]
                                                + [_fmt(w[wm])] for w in summary["worst"]])]
    if summary["failed"]:
        parts += ["<h3>Diverged runs</h3>", table(["run", "values", "at t [s]"], [
            [f["index"], ", ".join(f"{k} = {_fmt(v)}" for k, v in f["values"].items()), _fmt(f.get("failed_at"))]
            for f in summary["failed"]])]
    if summary["influence"]:
        parts += [f"<h3>Influence on {esc(_label(wm))} (Spearman rank correlation)</h3>",
                  table(["value", "correlation"], [[k, f"{v:+.2f}"] for k, v in summary["influence"].items()])]
    for png in sorted(folder.glob("*.png")):
        data = base64.b64encode(png.read_bytes()).decode("ascii")
        parts.append(f"<figure><img alt='{esc(png.stem)}' src='data:image/png;base64,{data}'>"
                     f"<figcaption>{esc(png.stem)}</figcaption></figure>")
    return "\n".join(parts) + "</section>"
