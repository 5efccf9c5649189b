"""Summaries of a sweep's results file: statistics, worst cases with their parameter values, and plots.

::

    from analysis.sweep_report import summarize, write_summary
    summary = summarize("sweep-results.jsonl")       # a SweepSummary
    files = write_summary("sweep-results.jsonl", "sweep-summary")   # summary.json, summary.md, PNG + SVG figures

``summary.json`` is the :class:`SweepSummary` as strict JSON (reads back with
:meth:`SweepSummary.from_json`).  ``summary.md`` is Markdown with relative links
to the figures; :func:`html_section` renders the same summary as a
self-contained HTML ``<section>`` (figures embedded) for ``dobkit report`` to
include.  Both come from templates (``sweep_summary.md``,
``sweep_section.html``); the numbers are formatted here.
"""
from __future__ import annotations

import base64
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blocks.parameters import RobotParameters
from blocks.metrics import DISTURBANCE_UNITS, JOINT_LABELS, JOINT_UNITS
from .report_html import template_environment
from .results import JsonResult, plain
from .sweep_runner import read_results

__all__ = ["RunCounts", "ColumnStatistics", "WorstRun", "DivergedRun", "SweepSummary", "summarize", "write_summary",
           "html_section", "metric_columns", "column_unit", "key_unit"]

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


@dataclass(frozen=True)
class RunCounts(JsonResult):
    """Runs in the sweep, finished (in the results file), finished ok, and diverged."""

    runs: int
    finished: int
    ok: int
    diverged: int


@dataclass(frozen=True)
class ColumnStatistics(JsonResult):
    """Statistics of one metric column over the finished runs (finite values only), in ``unit``."""

    count: int
    mean: float
    std: float
    min: float
    p5: float
    median: float
    p95: float
    max: float
    unit: str


@dataclass(frozen=True)
class WorstRun:
    """One of the worst runs: its id, index, swept values and its value of the worst metric.

    In JSON the value's key is the metric's name (see :class:`SweepSummary`).
    """

    run_id: str
    index: int
    values: dict
    value: float


@dataclass(frozen=True)
class DivergedRun(JsonResult):
    """A run that diverged: its values, when (``failed_at``, s; None if unknown) and the message."""

    run_id: str
    index: int
    values: dict
    failed_at: float | None
    message: str


@dataclass(frozen=True)
class SweepSummary(JsonResult):
    """Statistics of a sweep's results (see :func:`summarize`).

    Attributes
    ----------
    sweep : dict
        The results file's header (the sweep's definition).
    counts : RunCounts
    worst_metric : str or None
        The metric column the worst runs are ranked by.
    statistics : dict of str to ColumnStatistics
        Per metric column (``rms_position_error[2]``, ``max_tool_position_error_mm``).
    worst : list of WorstRun
        Largest ``worst_metric`` first; in JSON each carries the value under the metric's name.
    failed : list of DivergedRun
    influence : dict of str to float
        Per swept scalar key, the Spearman rank correlation with the worst metric.
    """

    sweep: dict
    counts: RunCounts
    worst_metric: str | None
    statistics: dict[str, ColumnStatistics]
    worst: list[WorstRun]
    failed: list[DivergedRun]
    influence: dict[str, float]

    def as_dict(self) -> dict:
        """JSON-ready dict; each worst run holds its value under the worst metric's name."""
        worst = [{"run_id": w.run_id, "index": w.index, "values": plain(w.values),
                  str(self.worst_metric): plain(w.value)} for w in self.worst]
        return {f.name: worst if f.name == "worst" else plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, data: dict, where: str | None = None) -> "SweepSummary":
        """Read back from :meth:`as_dict`'s form."""
        metric = data.get("worst_metric")
        worst = [WorstRun(run_id=w["run_id"], index=w["index"], values=w["values"],
                          value=math.nan if w.get(metric) is None else float(w[metric])) for w in data.get("worst", [])]
        out = super().from_dict({**data, "worst": []}, where)
        return dataclasses.replace(out, worst=worst)


def summarize(results) -> SweepSummary:
    """Statistics of every metric column over the finished runs, the worst runs and the swept values' influence.

    Parameters
    ----------
    results : path or (header, rows)
        A results file written by :func:`analysis.sweep_runner.run_sweep`.

    Returns
    -------
    SweepSummary
        Statistics per column (count, mean, std, min, p5, median, p95, max,
        unit), the ``worst_count`` runs with the largest ``worst_metric`` with
        their values, the diverged runs, and the influence of each swept scalar
        key (Spearman rank correlation with the worst metric).
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
        stats[name] = ColumnStatistics(count=int(v.size), mean=float(v.mean()),
                                       std=float(v.std(ddof=1)) if v.size > 1 else 0.0, min=float(v.min()),
                                       p5=float(q05), median=float(q50), p95=float(q95), max=float(v.max()),
                                       unit=column_unit(name))
    worst_metric = header.get("worst_metric") or (next(iter(cols)) if cols else None)
    worst_count = int(header.get("worst_count", 5))
    worst = []
    if worst_metric in cols:
        order = np.argsort(-np.nan_to_num(cols[worst_metric], nan=-np.inf))[:worst_count]
        worst = [WorstRun(run_id=ok[i]["run_id"], index=ok[i]["index"], values=ok[i]["values"],
                          value=float(cols[worst_metric][i])) for i in order]
    influence = {}
    if worst_metric in cols:
        y = cols[worst_metric]
        for key in sorted({k for r in ok for k in r["values"]}):
            x = np.array([_scalar(r["values"].get(key)) for r in ok], dtype=float)
            good = np.isfinite(x) & np.isfinite(y)
            if good.sum() >= 3 and np.ptp(x[good]) > 0 and np.ptp(y[good]) > 0:
                influence[key] = float(np.corrcoef(_ranks(x[good]), _ranks(y[good]))[0, 1])
    return SweepSummary(
        sweep=header,
        counts=RunCounts(runs=int(header.get("runs", len(rows))), finished=len(rows), ok=len(ok),
                         diverged=len(failed)),
        worst_metric=worst_metric, statistics=stats, worst=worst,
        failed=[DivergedRun(run_id=r["run_id"], index=r["index"], values=r["values"], failed_at=r.get("failed_at"),
                            message=r.get("message", "")) for r in failed],
        influence=influence)


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

    wm = summary.worst_metric
    worst_ids = {w.run_id for w in summary.worst}
    for key in summary.influence:
        x = np.array([_scalar(r["values"].get(key)) for r in ok])
        y = cols[wm]
        mark = np.array([r["run_id"] in worst_ids for r in ok])
        fig, ax = plt.subplots(figsize=(4.5, 3.2))
        ax.scatter(x[~mark], y[~mark], s=10, alpha=0.6, label="runs")
        ax.scatter(x[mark], y[mark], s=30, color="tab:red", label=f"worst {mark.sum()}")
        unit = key_unit(key)
        ax.set_xlabel(f"{key}" + (f" [{unit}]" if unit else ""))
        ax.set_ylabel(f"{_label(wm)} [{column_unit(wm)}]")
        ax.set_title(f"rank correlation {summary.influence[key]:+.2f}")
        ax.legend(fontsize=8)
        fig.tight_layout()
        safe = key.replace(".", "_").replace("[", "_").replace("]", "")
        files["figures"] += _save(fig, out / f"worst_vs_{safe}", formats)
        plt.close(fig)

    (out / "summary.json").write_text(summary.to_json(indent=2), encoding="utf-8")
    pngs = [f for f in files["figures"] if f.suffix == ".png"]
    (out / "summary.md").write_text(_markdown(summary, [(f.stem, f.relative_to(out).as_posix()) for f in pngs]),
                                    encoding="utf-8")
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


def _view(summary: SweepSummary) -> dict:
    """The summary's numbers as the texts the Markdown and HTML templates lay out."""
    sw, wm = summary.sweep, summary.worst_metric
    keys = sorted({k for w in summary.worst for k in w.values})
    mc = sw.get("monte_carlo", {})
    statistics = [(_label(n), st.unit, [_fmt(getattr(st, k)) for k in _STATISTICS])
                  for n, st in summary.statistics.items()]
    worst = [(w.index, [_fmt(w.values.get(k, "")) for k in keys], _fmt(w.value)) for w in summary.worst]
    failed = [(f.index, [(k, _fmt(v)) for k, v in f.values.items()],
               None if f.failed_at is None else f"{f.failed_at:.4g}", _fmt(f.failed_at)) for f in summary.failed]
    return {
        "name": str(sw.get("name", "?")), "scenario": str(sw.get("scenario", "?")),
        "engine": str(sw.get("engine", "?")), "observer": "with" if sw.get("observer", True) else "without",
        "counts": summary.counts,
        "grid": [(k, _fmt(v)) for k, v in (sw.get("grid") or {}).items()],
        "monte_carlo": None if not mc.get("distributions") else {
            "runs": mc["runs"], "seed": mc["seed"],
            "distributions": [(k, d["kind"], [(p, _fmt(v)) for p, v in d.items() if p != "kind"])
                              for k, d in mc["distributions"].items()]},
        "statistics": statistics,
        "statistics_rows": [[label, unit] + values for label, unit, values in statistics],
        "worst_metric": wm, "worst_label": _label(wm) if wm else "", "worst_unit": column_unit(wm) if wm else "",
        "worst_keys": keys, "worst": worst,
        "worst_rows": [[index] + values + [value] for index, values, value in worst],
        "failed": failed,
        "failed_rows": [[index, ", ".join(f"{k} = {v}" for k, v in values), at_text]
                        for index, values, _, at_text in failed],
        "influence": [(k, f"{v:+.2f}") for k, v in summary.influence.items()],
        "influence_by_size": [(k, f"{v:+.2f}")
                              for k, v in sorted(summary.influence.items(), key=lambda kv: -abs(kv[1]))],
    }


_STATISTICS = ("mean", "std", "min", "p5", "median", "p95", "max")


def _markdown(summary: SweepSummary, figures: list[tuple[str, str]]) -> str:
    """``summary.md``: the summary with links to the figures (``(stem, relative path)`` of each PNG)."""
    template = template_environment().get_template("sweep_summary.md")
    return template.render(s=_view(summary), figures=figures)


def html_section(summary_dir) -> str:
    """The summary written by :func:`write_summary` as one self-contained HTML ``<section>``.

    Tables of the statistics and the worst runs (with the values that produced
    them), the diverged runs, the influence of each swept value, and every PNG
    figure embedded as data.  Every text is escaped by the template.
    """
    folder = Path(summary_dir)
    summary = SweepSummary.from_json((folder / "summary.json").read_text(encoding="utf-8"))
    figures = [(png.stem, "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii"))
               for png in sorted(folder.glob("*.png"))]
    return template_environment().get_template("sweep_section.html").render(s=_view(summary), figures=figures)
