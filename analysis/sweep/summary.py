"""Summaries of a sweep's results file: statistics, worst cases with their parameter values, and plots.

::

    from analysis.sweep.summary import summarize, write_summary
    summary = summarize("sweep-results.jsonl")       # a SweepSummary
    files = write_summary("sweep-results.jsonl", "sweep-summary")   # summary.json, summary.md, PNG + SVG figures

``summary.json`` is the :class:`SweepSummary` as strict JSON (reads back with
:meth:`SweepSummary.from_json`); it names the results file and the sweep
definition it summarises and lists its figures with their captions.
``summary.md`` is Markdown with relative links to the figures (every text from
a name or a value escaped); :func:`html_section` renders the same summary as a
self-contained HTML ``<section>`` (figures embedded) for ``dobkit report`` to
include.  Both come from templates (``sweep_summary.md``,
``sweep_section.html``); the numbers and the words are made here.

Given the sweep (``spec=``), only rows of its current runs count: a row whose
id is not the id of the run at its index, or a second row of one run, is left
out.  Rows that are not usable (missing fields, not JSON) are left out and
listed.  The summary folder is written in a temporary folder beside it and
moved into place when complete, so it is never half old, half new.  Figures
take any data: constant, one value, NaN and infinite values (those are
counted, not drawn).

Per-joint columns and keys (``rms_position_error[2]``, ``disturbance.f_r[2]``)
are named and given units from the sweep's base scenario's arm
(``scenario.robot.joints``): ``Joint 3 (d3)``, m, N for the paper's RRPR,
``Joint 3 (insertion)`` for the built-in ``scope4``.  The arm's joints are kept
in ``summary.json`` (:attr:`SweepSummary.joints`), so that the report labels
them the same way.

A sweep with a ``[sensitivity]`` table (:mod:`analysis.sweep.sensitivity`)
gets its indices in ``summary.json`` (``"sobol"`` or ``"morris"``), a table
of the values ranked by their index for each metric column, and one bar chart
per metric with the 95 % confidence intervals.
"""
from __future__ import annotations

import base64
import dataclasses
import functools
import heapq
import html
import math
import os
import re
import shutil
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.jobs.figures import JobFigure, new_figure, save_figure
from analysis.jobs.files import differences
from analysis.report.html import template_environment
from analysis.results import JsonResult, omitted_if_none, plain
from analysis.sweep.runner import ResultsFile, read_header
from analysis.sweep.sensitivity import from_runs
from analysis.sweep.spec import HEADER_PARTS, SweepError, SweepSpec, json_default
from blocks.model.joints import JointSpace
from blocks.plumbing.outputs import interrupts_held
from blocks.scenarios.scenario import default_arm

__all__ = ["RunCounts", "ColumnStatistics", "WorstRun", "DivergedRun", "SweepFigure", "SweepSummary", "summarize",
           "write_summary", "html_section", "column_unit", "key_unit", "metric_name", "column_label", "key_name",
           "METRIC_NAMES", "FAILED_LISTED"]

_QUANTILES = (0.05, 0.5, 0.95)
#: Diverged runs listed by name in a summary (all are counted).
FAILED_LISTED = 100

#: The tracking metrics as a person reads them.
METRIC_NAMES = {
    "rms_position_error": "RMS position error",
    "max_abs_position_error": "peak position error",
    "final_abs_position_error": "final position error",
    "max_tool_position_error_mm": "peak tool-tip error",
    "rms_tool_position_error_mm": "RMS tool-tip error",
    "rms_disturbance_error": "RMS disturbance-estimate error |d - d_hat|",
}
_KEY_NAMES = {
    "gains.kp": "position gain Kp", "gains.kd": "velocity gain Kd", "gains.observer": "observer gain Y",
    "observer.variant": "observer variant", "disturbance.f_r": "Eq. 4 amplitude f_r",
    "disturbance.coulomb": "Coulomb friction", "disturbance.viscous": "viscous friction",
    "disturbance.friction_velocity": "friction velocity scale", "noise.q_std": "position noise (std)",
    "noise.dq_std": "velocity noise (std)", "noise.seed": "noise seed", "noise.sample_period": "noise sample period",
    "trajectory.stitches": "stitches", "trajectory.duration": "path duration", "simulation.t_final": "simulated time",
    "simulation.output_step": "output step", "initial.q": "initial position", "initial.dq": "initial velocity",
    "initial.d_hat": "initial estimate d_hat", "gains.observer_bandwidth": "observer bandwidth",
    "arm.nominal_mass_scale": "nominal-model mass scale", "arm.gravity": "gravity",
}
# SI prefixes for axes: values are shown in a unit that puts the largest near 1..1000, never with an offset.
_PREFIXED = {"m": "m", "rad": "rad", "N m": "N m", "N": "N", "mm": "m", "rad/s": "rad/s", "m/s": "m/s"}
_PREFIXES = {6: "M", 3: "k", 0: "", -3: "m", -6: "µ", -9: "n", -12: "p"}
# Lengths of a surgical arm read in m, mm or µm; smaller ones in mm (as the tables give them), not nm or pm, and
# never as a power of ten in the unit ("[1e-12 m]").
_LENGTH_POWERS = (0, -3, -6)


# --------------------------------------------------------------------------------------------
# Names and units for people
# --------------------------------------------------------------------------------------------
def metric_name(metric: str) -> str:
    """A metric as a person reads it (``rms_position_error`` -> ``RMS position error``)."""
    return METRIC_NAMES.get(metric, metric.replace("_", " "))


def _joint(column: str) -> int | None:
    found = re.fullmatch(r".*\[(\d+)\]", column)
    return int(found.group(1)) if found else None


def column_label(column: str, joints: JointSpace) -> str:
    """A metric column for people: ``RMS position error, Joint 3 (d3)``, ``peak tool-tip error``.

    ``joints``: the arm whose joints the column's index counts.
    """
    j = _joint(column)
    name = metric_name(column.split("[")[0])
    if j is None:
        return name
    joint = joints.labels[j] if j < joints.count else f"joint {j + 1}"
    return f"{name}, {joint}"


def column_unit(column: str, joints: JointSpace) -> str:
    """Unit of a metric column: the joint's position unit (rad, m), its force unit (N m, N) for disturbances, mm
    for the tool; ``joints`` as in :func:`column_label`."""
    if column.endswith("_mm"):
        return "mm"
    j = _joint(column)
    if j is not None and j < joints.count:
        return (joints.force_units if "disturbance" in column else joints.position_units)[j]
    return ""


def key_name(key: str, joints: JointSpace) -> str:
    """A swept scenario key for people: ``disturbance.f_r[2]`` -> ``Eq. 4 amplitude f_r, Joint 3 (d3)``;
    ``joints`` as in :func:`column_label`."""
    section, _, rest = key.partition(".")
    name, _, index = rest.partition("[")
    base = f"{section}.{name}"
    if base in _KEY_NAMES:
        text = _KEY_NAMES[base]
    elif section == "robot":
        text = f"true {name}"
    elif section == "nominal_scale":
        text = f"nominal-model scale of {name}"
    else:
        text = key
        index = ""
    if index:
        j = int(index.rstrip("]"))
        text += f", {joints.labels[j] if j < joints.count else f'element {j}'}"
    return text


def _default_arm_of(joints: JointSpace):
    """The default scenario's arm when ``joints`` are its joints (a summary keeps the joints, not the arm), else
    None: its named parameters (``robot.*``) and wording apply."""
    arm = default_arm()
    return arm if joints == arm.joints else None


def key_unit(key: str, joints: JointSpace) -> str:
    """Unit of a swept scenario value, for axis labels; ``joints`` as in :func:`column_label`."""
    arm = _default_arm_of(joints)
    paper = arm is not None and arm.paper is not None
    section, _, name = key.partition(".")
    name, _, index = name.partition("[")
    j = int(index.rstrip("]")) if index else None
    if j is not None and j < joints.count and f"{section}.{name}" in ("disturbance.f_r", "disturbance.coulomb"):
        return joints.force_units[j]
    if j is not None and j < joints.count and f"{section}.{name}" in ("noise.q_std", "initial.q"):
        return joints.position_units[j]
    if section == "robot" and arm is not None and name in arm.parameter_names():
        return arm.parameter_unit(name)
    # Y's unit per joint kind (kg m^2/s on a revolute joint, kg/s on a prismatic one); the paper's arm keeps its
    # one word
    gain_units = tuple("kg m^2/s" if u == "rad" else "kg/s" for u in joints.position_units)
    if j is not None and j < joints.count and f"{section}.{name}" == "gains.observer" and not paper:
        return gain_units[j]
    force, position, velocity, gain = (" or ".join(dict.fromkeys(u)) for u in
                                       (joints.force_units, joints.position_units, joints.velocity_units, gain_units))
    units = {"nominal_scale": "factor", "gains.kp": "1/s^2", "gains.kd": "1/s",
             "gains.observer": "kg m^2/s" if paper else gain,
             "gains.observer_bandwidth": "rad/s", "arm.nominal_mass_scale": "factor", "arm.gravity": "m/s^2",
             "disturbance.f_r": force, "disturbance.coulomb": force, "noise.q_std": position,
             "noise.dq_std": velocity, "trajectory.duration": "s", "simulation.t_final": "s",
             "simulation.output_step": "s", "noise.sample_period": "s"}
    return units.get(section, units.get(f"{section}.{name}", ""))


def _arm_joints(record: dict | None) -> JointSpace:
    """The joints kept in a summary (:attr:`SweepSummary.joints`); the default scenario's arm's when it keeps none."""
    own = default_arm().joints
    if not record:
        return own
    joints = JointSpace(names=tuple(record["names"]), kinds=tuple(record["kinds"]))
    # the default arm keeps its own joint space (with its ranges), which decides its robot.* units
    return own if (joints.names, joints.kinds) == (own.names, own.kinds) else joints


def _joints_record(joints: JointSpace) -> dict:
    return {"names": list(joints.names), "kinds": list(joints.kinds)}


def _joints_of_header(header: dict) -> JointSpace:
    """The arm of a results file's sweep read without its sweep file: the joints its header keeps
    (:func:`analysis.sweep.spec.joints_record`); for a file written before the header kept them, the built-in
    scenario the header names when its values are the ones the sweep ran (the hash in the header), else the
    default scenario's arm's."""
    import hashlib
    import json

    from blocks.scenarios.scenario import ScenarioError, builtin_scenarios, load_scenario
    kept = header.get("joints")
    if isinstance(kept, dict):
        try:
            return _arm_joints(kept)
        except (KeyError, TypeError, ValueError):        # a hand-edited header: fall back to what it names
            pass
    name = header.get("scenario")
    if not isinstance(name, str) or name not in builtin_scenarios():
        return default_arm().joints
    try:
        base = load_scenario(name)
    except (ScenarioError, OSError, ImportError):
        return default_arm().joints
    digest = hashlib.sha256(json.dumps(base.data, sort_keys=True, default=json_default).encode()).hexdigest()[:16]
    return base.robot.joints if digest == header.get("scenario_values") else default_arm().joints


def _with_unit(text: str, unit: str) -> str:
    return f"{text} [{unit}]" if unit else text


def _table_scale(unit: str) -> tuple[float, str]:
    """(factor, unit text) of a table's numbers: lengths in mm, every other unit as it is, and the numbers with
    four significant digits (``3.538e-07 mm``), so that a reader compares rows without reading prefixes."""
    return (1e-3, "mm") if unit == "m" else (1.0, unit)


def _display_scale(unit: str, values: np.ndarray) -> tuple[float, str]:
    """(factor, unit text): divide values by factor to show them in ``unit text`` (an SI prefix or a power of
    ten in the unit), so that no axis needs an offset or a scale printed apart from its label."""
    finite = np.abs(values[np.isfinite(values)])
    largest = float(finite.max()) if finite.size else 0.0
    base_factor = 1e-3 if unit == "mm" else 1.0          # mm values as metres, then prefixed
    largest *= base_factor
    if largest == 0.0 or not math.isfinite(largest):
        return 1.0, unit
    power = 3 * math.floor(math.log10(largest) / 3)
    prefixed = power in (_LENGTH_POWERS if unit in ("m", "mm") else _PREFIXES)
    if unit in _PREFIXED and prefixed:
        return 10.0 ** power / base_factor, f"{_PREFIXES[power]}{_PREFIXED[unit]}"
    if unit in ("m", "mm") and power < min(_LENGTH_POWERS):
        return 1e-3 / base_factor, "mm"           # tiny lengths: mm with their own digits (3.5e-07)
    if -3 <= math.log10(largest) < 4:
        return 1.0, unit
    return 10.0 ** power / base_factor, f"1e{power} {_PREFIXED.get(unit, unit)}".strip()


# --------------------------------------------------------------------------------------------
# The typed summary
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunCounts(JsonResult):
    """Runs in the sweep, finished (in the results file), finished ok, and diverged."""

    runs: int
    finished: int
    ok: int
    diverged: int


@dataclass(frozen=True)
class ColumnStatistics(JsonResult):
    """Statistics of one metric column over the finished runs (finite values only), in ``unit``;
    ``not_finite`` runs had no finite value."""

    count: int
    mean: float
    std: float
    min: float
    p5: float
    median: float
    p95: float
    max: float
    unit: str
    not_finite: int = 0


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


#: One figure of a summary: its PNG file (an SVG beside it) and its caption (the job figure of both kinds of job).
SweepFigure = JobFigure


@dataclass(frozen=True)
class SweepSummary(JsonResult):
    """Statistics of a sweep's results (see :func:`summarize`).

    Attributes
    ----------
    sweep : dict
        The sweep's header (its definition).
    counts : RunCounts
    worst_metric : str or None
        The metric column the worst runs are ranked by.
    statistics : dict of str to ColumnStatistics
        Per metric column (``rms_position_error[2]``, ``max_tool_position_error_mm``).
    worst : list of WorstRun
        Largest ``worst_metric`` first (finite values only); in JSON each carries the value under the metric's name.
    failed : list of DivergedRun
        The first :data:`FAILED_LISTED` diverged runs (``counts.diverged`` counts all).
    influence : dict of str to float
        Per swept scalar key, the Spearman rank correlation with the worst metric.
    results : str
        The results file summarised (its name).
    definition : str
        The sweep definition of that file (see :mod:`analysis.sweep.runner`).
    problems : list of str
        Lines of the results file left out as unusable, and rows of other runs left out.
    figures : list of SweepFigure
        The figures written with this summary (by :func:`write_summary`).
    joints : dict
        The base scenario's arm's joints, ``{"names": [...], "kinds": [...]}`` (revolute or prismatic), which name
        the per-joint columns and give their units; empty in a summary written before it was kept (the RRPR).
    sobol, morris : dict or None
        A ``[sensitivity]`` sweep's indices (:func:`analysis.sweep.sensitivity.indices`): Sobol
        ``{"first": {METRIC: {KEY: [per joint]}}, "total": ..., "first_conf": ..., "total_conf": ...}``, Morris
        ``{"mu_star": ..., "sigma": ..., "mu_star_conf": ...}``; left out of the JSON when None.
    sensitivity_note : str or None
        Why a ``[sensitivity]`` sweep has no indices (or some column has none); left out when None.
    """

    sweep: dict
    counts: RunCounts
    worst_metric: str | None
    statistics: dict[str, ColumnStatistics]
    worst: list[WorstRun]
    failed: list[DivergedRun]
    influence: dict[str, float]
    results: str = ""
    definition: str = ""
    problems: list[str] = dataclasses.field(default_factory=list)
    figures: list[SweepFigure] = dataclasses.field(default_factory=list)
    joints: dict = dataclasses.field(default_factory=dict)
    sobol: dict | None = omitted_if_none()
    morris: dict | None = omitted_if_none()
    sensitivity_note: str | None = omitted_if_none()

    @property
    def arm_joints(self) -> JointSpace:
        """:attr:`joints` as a :class:`blocks.model.joints.JointSpace` (the default scenario's arm's when none is kept)."""
        return _arm_joints(self.joints)

    def as_dict(self) -> dict:
        """JSON-ready dict; each worst run holds its value under the worst metric's name."""
        worst = [{"run_id": w.run_id, "index": w.index, "values": plain(w.values),
                  str(self.worst_metric): plain(w.value)} for w in self.worst]
        return {f.name: worst if f.name == "worst" else plain(getattr(self, f.name)) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not None or not f.metadata.get("omit_if_none")}

    @classmethod
    def from_dict(cls, data: dict, where: str | None = None) -> SweepSummary:
        """Read back from :meth:`as_dict`'s form."""
        metric = data.get("worst_metric")
        worst = [WorstRun(run_id=w["run_id"], index=w["index"], values=w["values"],
                          value=math.nan if w.get(metric) is None else float(w[metric])) for w in data.get("worst", [])]
        out = super().from_dict({**data, "worst": []}, where)
        return dataclasses.replace(out, worst=worst)


# --------------------------------------------------------------------------------------------
# Reading the rows into columns (a few hundred bytes a run, whatever the rows hold)
# --------------------------------------------------------------------------------------------
@dataclass
class _Table:
    """The usable rows of the current runs as columns: metric values and swept scalar values per ok run."""

    header: dict
    joints: JointSpace = dataclasses.field(default_factory=lambda: default_arm().joints)   # the base scenario's arm
    count: int = 0                                   # ok runs
    index: array = dataclasses.field(default_factory=lambda: array("q"))
    columns: dict = dataclasses.field(default_factory=dict)      # column -> array('d')
    values: dict = dataclasses.field(default_factory=dict)       # swept key -> array('d') (NaN: not a number)
    worst: list = dataclasses.field(default_factory=list)        # heap of (value, -position, row)
    failed: list = dataclasses.field(default_factory=list)
    diverged: int = 0
    problems: list = dataclasses.field(default_factory=list)

    def add_ok(self, row: dict, worst_metric: str | None, worst_count: int) -> None:
        position = self.count
        for name, value in row["metrics"].items():
            items = [(f"{name}[{j}]", v) for j, v in enumerate(value)] if isinstance(value, list) else [(name, value)]
            for column, v in items:
                if column not in self.columns:
                    self.columns[column] = array("d", [math.nan]) * position
                self.columns[column].append(math.nan if v is None else float(v))
        for key, value in row["values"].items():
            if key not in self.values:
                self.values[key] = array("d", [math.nan]) * position
            self.values[key].append(_scalar(value))
        for store in (*self.columns.values(), *self.values.values()):     # a column this row lacks
            if len(store) == position:
                store.append(math.nan)
        self.index.append(row["index"])
        self.count += 1
        if worst_metric is not None:
            v = self.columns.get(worst_metric, [math.nan] * (position + 1))[position]
            if math.isfinite(v):
                item = (v, -position, {"run_id": row["run_id"], "index": row["index"], "values": row["values"]})
                if len(self.worst) < worst_count:
                    heapq.heappush(self.worst, item)
                elif item[:2] > self.worst[0][:2]:
                    heapq.heapreplace(self.worst, item)

    def array(self, store) -> np.ndarray:
        return np.frombuffer(store, dtype=float) if len(store) else np.zeros(0)


def _scalar(value) -> float:
    if isinstance(value, bool) or value is None:
        return math.nan
    if isinstance(value, (int, float)):
        return float(value)
    return math.nan


def _load(results, spec: SweepSpec | None) -> tuple[_Table, str]:
    """Read a results file (or a ``(header, rows)`` pair) into a :class:`_Table`; returns it and the file name."""
    if isinstance(results, tuple):
        header, rows, name = results[0], iter(results[1]), ""
        file = None
    else:
        path = Path(results)
        if not path.is_file():
            raise SweepError(f"results file '{path}' does not exist" + (" (it is a folder)" if path.is_dir() else
                                                                         "; run the sweep first"))
        header = read_header(path)
        file = ResultsFile(path, header)
        rows, name = file.rows(), path.name
    header = dict(header or {})
    if spec is not None:
        if header and header.get("definition") != spec.definition:
            what = ", ".join(differences(header, spec.header()["sweep"], HEADER_PARTS)) or "the sweep definition"
            raise SweepError(f"results file '{name or 'given'}' holds another definition of sweep "
                             f"'{header.get('name')}' ({what} differ(s)); its summary would not describe this sweep "
                             "file. Run the sweep (with --restart to move the old file aside) first")
        header = spec.header()["sweep"]
    worst_metric = header.get("worst_metric")
    worst_count = int(header.get("worst_count", 5) or 5)
    joints = spec.base.robot.joints if spec is not None else _joints_of_header(header)
    table = _Table(header=header, joints=joints)
    seen: set = set()
    other = repeated = 0
    for row in rows:
        if spec is not None and not (0 <= row["index"] < len(spec.runs)
                                     and spec.runs.run_id(row["index"]) == row["run_id"]):
            other += 1
            continue
        if file is None:                     # a results file gives each run once (jobs.files.JobLog.rows)
            if row["run_id"] in seen:
                repeated += 1
                continue
            seen.add(row["run_id"])
        if row["status"] == "ok":
            table.add_ok(row, worst_metric, worst_count)
        else:
            table.diverged += 1
            if len(table.failed) < FAILED_LISTED:
                table.failed.append(row)
    del seen
    if file is not None:
        table.problems += file.problems
        repeated += file.repeated
    if other:
        table.problems.append(f"{other} row(s) of runs that are not in this sweep were left out")
    if repeated:
        table.problems.append(f"{repeated} repeated row(s) of one run were counted once")
    if worst_metric is None and table.columns:
        table.header["worst_metric"] = next(iter(table.columns))
    return table, name


def summarize(results, spec: SweepSpec | None = None) -> SweepSummary:
    """Statistics of every metric column over the finished runs, the worst runs and the swept values' influence.

    Parameters
    ----------
    results : path or (header, rows)
        A results file written by :func:`analysis.sweep.runner.run_sweep`.
    spec : SweepSpec, optional
        The sweep: its header is shown, and only rows of its runs count
        (a results file of another definition is refused).

    Returns
    -------
    SweepSummary
        Statistics per column (count, mean, std, min, p5, median, p95, max,
        unit), the ``worst_count`` runs with the largest ``worst_metric`` with
        their values, the diverged runs, and the influence of each swept scalar
        key (Spearman rank correlation with the worst metric).
    """
    table, name = _load(results, spec)
    return _summary(table, name)


def _summary(table: _Table, name: str) -> SweepSummary:
    header = table.header
    stats = {}
    for column, store in table.columns.items():
        values = table.array(store)
        v = values[np.isfinite(values)]
        if v.size == 0:
            continue
        # in units of the largest value, so that values near the float limit do not overflow the sums
        top = float(np.max(np.abs(v)))
        top = top if top > 0 else 1.0
        w = v / top
        q05, q50, q95 = (float(q) * top for q in np.quantile(w, _QUANTILES))
        mean, std = float(np.mean(w)) * top, float(np.std(w, ddof=1)) * top if v.size > 1 else 0.0
        stats[column] = ColumnStatistics(count=int(v.size), mean=mean, std=std, min=float(v.min()), p5=q05,
                                         median=q50, p95=q95, max=float(v.max()),
                                         unit=column_unit(column, table.joints), not_finite=int(values.size - v.size))
    worst_metric = header.get("worst_metric")
    worst = [WorstRun(run_id=row["run_id"], index=row["index"], values=row["values"], value=value)
             for value, _, row in sorted(table.worst, key=lambda item: (-item[0], -item[1]))]
    influence = {}
    if worst_metric in table.columns:
        y = table.array(table.columns[worst_metric])
        for key, store in table.values.items():
            x = table.array(store)
            good = np.isfinite(x) & np.isfinite(y)
            if good.sum() >= 3 and np.max(x[good]) > np.min(x[good]) and np.max(y[good]) > np.min(y[good]):
                r = float(np.corrcoef(_ranks(x[good]), _ranks(y[good]))[0, 1])
                if math.isfinite(r):
                    influence[key] = r
    finished = table.count + table.diverged
    sensitivity, note = None, None
    if isinstance(header.get("sensitivity"), dict):
        sensitivity, note = from_runs(header["sensitivity"], np.frombuffer(table.index, dtype=np.int64),
                                      {c: table.array(v) for c, v in table.columns.items()},
                                      {k: table.array(v) for k, v in table.values.items()}, table.diverged)
    return SweepSummary(
        sweep=header,
        counts=RunCounts(runs=int(header.get("runs", finished)), finished=finished, ok=table.count,
                         diverged=table.diverged),
        worst_metric=worst_metric, statistics=stats, worst=worst,
        failed=[DivergedRun(run_id=r["run_id"], index=r["index"], values=r["values"],
                            failed_at=r.get("failed_at") if isinstance(r.get("failed_at"), (int, float)) else None,
                            message=str(r.get("message", ""))) for r in table.failed],
        influence=influence, results=name, definition=str(header.get("definition", "")),
        problems=list(table.problems), joints=_joints_record(table.joints),
        sobol=(sensitivity or {}).get("sobol"), morris=(sensitivity or {}).get("morris"), sensitivity_note=note or None)


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks with ties given their mean rank (Spearman's definition)."""
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size)
    ranks[order] = np.arange(x.size, dtype=float)
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    return sums[inverse] / counts[inverse]


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------
def _histogram(ax, values: np.ndarray, unit: str, label: str) -> str:
    """One histogram panel of any data; returns a note on what is not drawn ('' if everything is)."""
    finite = values[np.isfinite(values)]
    hidden = values.size - finite.size
    note = f"{hidden} not finite" if hidden else ""
    factor, shown_unit = _display_scale(unit, finite)
    x = finite / factor
    ax.set_xlabel(_with_unit(label, shown_unit))
    ax.set_ylabel("runs")
    if x.size == 0:
        ax.text(0.5, 0.5, "no finite values", ha="center", va="center", transform=ax.transAxes)
        ax.set_xticks([])
        return note
    lo, hi = float(x.min()), float(x.max())
    scale = max(abs(lo), abs(hi))
    if hi - lo <= 1e-9 * scale or hi == lo:
        # one value (to 9 digits): one bar, labelled, rather than bins narrower than the numbers' resolution
        width = 0.05 * scale if scale > 0 else 1.0
        ax.bar([0.5 * (lo + hi)], [x.size], width=width, color="tab:blue", alpha=0.8)
        ax.set_xlim(0.5 * (lo + hi) - 5 * width, 0.5 * (lo + hi) + 5 * width)
        ax.set_ylim(0, 1.3 * x.size)
        ax.text(0.5, 0.96, f"all {x.size}: {0.5 * (lo + hi):.6g}", ha="center", va="top", transform=ax.transAxes,
                fontsize=8)
    else:
        bins = max(5, min(40, 2 * int(math.sqrt(x.size))))
        # explicit edges: numpy's own refuse a spread of a few units in the last place ("too many bins")
        edges = np.linspace(lo, hi, bins + 1) if math.isfinite(hi - lo) else np.linspace(lo / 2, hi / 2, bins + 1) * 2
        edges[0], edges[-1] = lo, hi
        counts, _, _ = ax.hist(x, bins=edges, color="tab:blue", alpha=0.8)
        ax.set_ylim(0, 1.15 * max(1.0, float(np.max(counts))))
    _plain_ticks(ax.xaxis)
    import matplotlib.ticker as mticker
    ax.yaxis.set_major_locator(mticker.MaxNLocator(5, integer=True))
    if note:
        ax.text(0.98, 0.98, note, ha="right", va="top", transform=ax.transAxes, fontsize=7, color="tab:red")
    return note


def _plain_ticks(axis) -> None:
    """Few tick labels, without an offset or a power of ten printed apart from the axis label (the values
    are already in a unit that suits them, see :func:`_display_scale`)."""
    import matplotlib.ticker as mticker
    axis.set_major_locator(mticker.MaxNLocator(4))
    # each label carries its own digits: 0.25, 1200, or 3.5e-07 for a tiny length in mm (no offset, no "1e-7" apart)
    axis.set_major_formatter(mticker.FuncFormatter(lambda v, _: "0" if v == 0 else f"{v:.4g}"))


def _figures(table: _Table, summary: SweepSummary, out: Path, formats) -> list[tuple[list[Path], str]]:
    """Write the histograms and worst-case plots into ``out``; return (files, caption) per figure."""
    return [(save_figure(fig, out / stem, formats), caption) for fig, stem, caption in _draw_figures(table, summary)]


def _draw_figures(table: _Table, summary: SweepSummary):
    """The summary's figures, one at a time: ``(figure, file stem, caption)``."""
    yield from _sensitivity_figures(summary, table.joints)
    groups: dict[str, list[str]] = {}
    for column in table.columns:
        groups.setdefault(column.split("[")[0], []).append(column)
    n, joints = table.count, table.joints
    runs = f"{n} finished run{'s' if n != 1 else ''}"
    for metric, columns in groups.items():
        fig = new_figure((max(3.3 * len(columns), 5.0), 3.1))
        axes = fig.subplots(1, len(columns), squeeze=False)
        notes = []
        for ax, column in zip(axes[0], columns):
            j = _joint(column)
            label = joints.labels[j] if j is not None and j < joints.count else _capital(metric_name(metric))
            note = _histogram(ax, table.array(table.columns[column]), column_unit(column, joints), label)
            if note:
                notes.append(f"{label}: {note}")
        fig.suptitle(_capital(f"{metric_name(metric)} over {n} run{'s' if n != 1 else ''}"), fontsize=11)
        caption = (f"Distribution of the {metric_name(metric)} over the {runs}"
                   + (", one panel per joint" if len(columns) > 1 else "") + "."
                   + (f" Not drawn: {'; '.join(notes)}." if notes else ""))
        yield fig, f"hist_{metric}", caption

    wm = summary.worst_metric
    if wm not in table.columns:
        return
    y_all = table.array(table.columns[wm])
    mark_all = np.zeros(n, dtype=bool)
    mark_all[[-position for _, position, _ in table.worst]] = True
    for key, r in summary.influence.items():
        x_all = table.array(table.values[key])
        good = np.isfinite(x_all) & np.isfinite(y_all)
        x, y, mark = x_all[good], y_all[good], mark_all[good]
        xf, xunit = _display_scale(key_unit(key, joints), x)
        yf, yunit = _display_scale(column_unit(wm, joints), y)
        fig = new_figure((5.2, 3.6))
        ax = fig.subplots()
        ax.scatter(x[~mark] / xf, y[~mark] / yf, s=10, alpha=0.6, color="tab:blue")
        ax.scatter(x[mark] / xf, y[mark] / yf, s=30, color="tab:red")
        ax.set_xlabel(_with_unit(_capital(key_name(key, joints)), xunit))
        ax.set_ylabel(_with_unit(_capital(_short(column_label(wm, joints))), yunit))
        _plain_ticks(ax.xaxis)
        _plain_ticks(ax.yaxis)
        # the key in the title rather than a legend, which would hide points
        ax.set_title(f"red: the {int(mark.sum())} worst runs; rank correlation {r:+.2f}", fontsize=9)
        safe = key.replace(".", "_").replace("[", "_").replace("]", "")
        caption = (f"{_capital(column_label(wm, joints))} against the {key_name(key, joints)} ({key}), one point "
                   f"per finished run; red: the {int(mark.sum())} worst. Spearman rank correlation {r:+.2f}.")
        yield fig, f"worst_vs_{safe}", caption


#: How each method's indices are drawn: (bars as (entry, its interval or None, legend), axis words).
_SENSITIVITY_BARS = {
    "sobol": ((("first", "first_conf", "first order S1 (alone)"), ("total", "total_conf", "total ST (with interactions)")),
              "Sobol index"),
    "morris": ((("mu_star", "mu_star_conf", "mu* (mean |effect|)"), ("sigma", None, "sigma (spread of the effects)")),
               "effect over the whole range"),
}


def _per_joint(entry, joint: int | None) -> float:
    """One column's number of a per-key entry (a list per joint, or one number), NaN for null."""
    value = entry[joint] if joint is not None and isinstance(entry, list) and joint < len(entry) else entry
    return math.nan if not isinstance(value, (int, float)) else float(value)


def _sensitivity_figures(summary: SweepSummary, joints: JointSpace):
    """One horizontal bar chart per metric of a sensitivity sweep (a panel per joint): each value's indices with
    their 95 % confidence intervals."""
    method = "sobol" if summary.sobol is not None else "morris" if summary.morris is not None else None
    if method is None:
        return
    found = summary.sobol if method == "sobol" else summary.morris
    bars, words = _SENSITIVITY_BARS[method]
    record = summary.sweep.get("sensitivity") or {}
    design = (f"N = {record.get('samples')}" if method == "sobol" else f"r = {record.get('samples')} trajectories, "
              f"{record.get('levels')} levels") + f", {summary.counts.ok:,} runs"
    for metric, by_key in found[bars[0][0]].items():
        keys = list(by_key)
        first = by_key[keys[0]] if keys else None
        panels = [None] if not isinstance(first, list) else list(range(len(first)))
        fig = new_figure((max(3.3 * len(panels), 5.0), 1.8 + 0.55 * len(keys)))
        axes = fig.subplots(1, len(panels), squeeze=False, sharey=True)[0]
        for ax, joint in zip(axes, panels):
            column = metric if joint is None else f"{metric}[{joint}]"
            names = [name for entry, conf, _ in bars for name in (entry, conf) if name]
            numbers = {name: np.array([_per_joint(found[name][metric].get(k), joint) for k in keys]) for name in names}
            if method == "sobol":
                factor, shown = 1.0, "share of the variance"
            else:
                factor, shown = _display_scale(column_unit(column, joints),
                                               np.concatenate([numbers[e] for e, _, _ in bars]))
            y = np.arange(len(keys))
            for b, (entry, conf, legend) in enumerate(bars):
                width = numbers[entry] / factor
                err = None if conf is None else np.nan_to_num(numbers[conf] / factor)
                ax.barh(y + (b - 0.5) * 0.4, np.nan_to_num(width), height=0.38, xerr=err, capsize=3,
                        color=("tab:blue", "tab:orange")[b], label=legend)
            ax.set_yticks(y, labels=[_capital(key_name(k, joints)) for k in keys], fontsize=8)
            ax.axvline(0.0, color="black", lw=0.6)
            ax.set_xlabel(_with_unit(_capital(words), shown), fontsize=9)
            joint_label = joints.labels[joint] if joint is not None and joint < joints.count else ""
            ax.set_title(joint_label or _capital(metric_name(metric)), fontsize=9)
            if method == "sobol":
                # both indices' intervals inside the axes (a first-order interval can reach past the total's)
                ends = np.r_[numbers["first"] - numbers["first_conf"], numbers["first"] + numbers["first_conf"],
                             numbers["total"] - numbers["total_conf"], numbers["total"] + numbers["total_conf"], 0]
                ax.set_xlim(min(-0.05, float(np.nanmin(ends))) - 0.02, max(1.05, float(np.nanmax(ends))) + 0.02)
        axes[0].invert_yaxis()                   # the first value on top (the axes share theirs)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
        fig.suptitle(_capital(f"{method.capitalize()} sensitivity of the {metric_name(metric)}"), fontsize=11)
        caption = (f"{method.capitalize()} sensitivity of the {metric_name(metric)} to each uncertain value ({design})"
                   + (", one panel per joint" if panels[0] is not None else "") + ": "
                   + ("first-order index S1 (the share of its variance the value explains alone) and total index ST "
                      "(with all its interactions)" if method == "sobol" else
                      "mu* (the mean absolute change of the metric when the value moves across its whole range) and "
                      "sigma (the spread of those changes: interactions and nonlinearity)")
                   + "; error bars: 95 % bootstrap confidence intervals.")
        yield fig, f"{method}_{metric}", caption


def _capital(text: str) -> str:
    """Text with a capital first letter ('RMS' stays as it is)."""
    return text[:1].upper() + text[1:]


def _short(label: str) -> str:
    """An axis label without the notation that makes it too long for a small figure."""
    return label.replace(" |d - d_hat|", "")


# --------------------------------------------------------------------------------------------
# Writing the summary folder: built aside, moved into place whole
# --------------------------------------------------------------------------------------------
def write_summary(results, out_dir, formats=("png", "svg"), spec: SweepSpec | None = None) -> dict:
    """Write ``summary.json``, ``summary.md`` and the figures to ``out_dir``; return their paths by name.

    Figures: one histogram panel per kept metric column (the error
    distributions) and, for each swept scalar value, the worst metric against
    it with the worst runs marked (which values produced them).  Everything is
    written into a temporary folder beside ``out_dir`` and moved into place
    when complete; an existing ``out_dir`` must be a summary folder (it holds
    ``summary.json``) or empty.

    Parameters
    ----------
    results : path or (header, rows)
    out_dir : path
    formats : tuple of str
        Figure formats; the first must be ``png`` (the summaries link and embed PNGs).
    spec : SweepSpec, optional
        The sweep; only rows of its runs count (see :func:`summarize`).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise SweepError(f"summary folder '{out}' is a file; choose another --summary-dir")
    if out.is_dir() and any(out.iterdir()) and not (out / "summary.json").is_file():
        raise SweepError(f"summary folder '{out}' holds other files (no summary.json): it is not a sweep summary, "
                         "and would be replaced; choose another --summary-dir")
    if "png" not in formats:
        raise ValueError(f"formats must include 'png' (the summaries show PNGs), got {formats!r}")
    table, name = _load(results, spec)
    summary = _summary(table, name)
    out.parent.mkdir(parents=True, exist_ok=True)
    # a name known before the folder exists: an interrupt right after it is made (inside mkdtemp, before its
    # name came back) left it behind
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)           # a killed process's of the same number
    _remove_stale_stages(out)
    try:
        stage.mkdir()
        drawn = _figures(table, summary, stage, formats)
        figures = [SweepFigure(file=next(p.name for p in paths if p.suffix == ".png"), caption=caption)
                   for paths, caption in drawn]
        summary = dataclasses.replace(summary, figures=figures)
        (stage / "summary.json").write_text(summary.to_json(indent=2), encoding="utf-8")
        (stage / "summary.md").write_text(_markdown(summary), encoding="utf-8")
        _into_place(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    files = [out / p.name for paths, _ in drawn for p in paths]
    return {"figures": files, "json": out / "summary.json", "markdown": out / "summary.md", "summary": summary}


def _remove_stale_stages(out: Path) -> list[Path]:
    """Remove what ``kill -9`` of an earlier summary writer left beside ``out``: its staging folder
    (``.NAME.partial-<pid>``, stayed for good), and its swapped-out previous summary (``.NAME.old-<pid>``,
    put back when ``out`` itself is missing: the kill came between the two renames); only of processes that
    no longer exist.  Returns the paths removed or put back."""
    from blocks.plumbing.outputs import _pid_alive
    done = []
    for kind in ("partial", "old"):
        prefix = f".{out.name}.{kind}-"
        try:
            found = [p for p in out.parent.iterdir() if p.name.startswith(prefix)]
        except OSError:
            return done
        for path in found:
            pid = path.name[len(prefix):]
            if not (pid.isascii() and pid.isdigit()) or int(pid) == os.getpid() or _pid_alive(int(pid)) \
                    or path.is_symlink() or not path.is_dir():
                continue
            if kind == "old" and not out.exists():
                path.rename(out)
            else:
                shutil.rmtree(path, ignore_errors=True)
            done.append(path)
    return done


def _into_place(stage: Path, out: Path) -> None:
    """Replace ``out`` by ``stage``: two renames, so ``out`` is the whole old or the whole new summary."""
    os.chmod(stage, 0o777 & ~_umask())
    with interrupts_held():             # between the two renames there is no summary folder at all
        if not out.exists():
            stage.rename(out)
            return
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        out.rename(old)
        try:
            stage.rename(out)
        except BaseException:
            old.rename(out)
            raise
    shutil.rmtree(old, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# --------------------------------------------------------------------------------------------
# Markdown and HTML
# --------------------------------------------------------------------------------------------
def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.4g}"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    return str(x)


def _md(text) -> str:
    """Text for Markdown: no HTML can come through, and a table cell cannot be split."""
    return html.escape(str(text), quote=False).replace("|", "\\|").replace("`", "'").replace("\n", " ")


def _code(text) -> str:
    """A key in a code span when it is a plain key, else escaped text."""
    text = str(text)
    return f"`{text}`" if re.fullmatch(r"[\w.\[\]-]+", text) else _md(text)


@functools.cache
def _markdown_environment():
    env = template_environment().overlay()
    env.filters["md"] = _md
    env.filters["code"] = _code
    return env


_STATISTICS = ("mean", "std", "min", "p5", "median", "p95", "max")


def _view(summary: SweepSummary) -> dict:
    """The summary's numbers and names as the texts the Markdown and HTML templates lay out."""
    sw, wm = summary.sweep, summary.worst_metric
    joints = summary.arm_joints
    keys = list(dict.fromkeys(k for w in summary.worst for k in w.values))
    mc = sw.get("monte_carlo") or {}
    statistics = []
    for column, st in summary.statistics.items():
        factor, unit = _table_scale(st.unit)
        numbers = [_fmt(getattr(st, k) / factor) for k in _STATISTICS]
        statistics.append((_capital(column_label(column, joints)), unit, numbers, st.count, st.not_finite))
    worst_factor, worst_unit = _table_scale(column_unit(wm, joints) if wm else "")
    worst = [(w.index, [_fmt(w.values.get(k, "")) for k in keys], _fmt(w.value / worst_factor)) for w in summary.worst]
    failed = [(f.index, [(k, key_name(k, joints), _fmt(v)) for k, v in f.values.items()],
               None if f.failed_at is None else f"{f.failed_at:.4g}", f.message) for f in summary.failed]
    return {
        "name": str(sw.get("name", "?")), "description": str(sw.get("description", "") or ""),
        "scenario": str(sw.get("scenario", "?")), "engine": str(sw.get("engine", "?")),
        "observer": "with" if sw.get("observer", True) else "without",
        "counts": summary.counts, "results": summary.results, "definition": summary.definition,
        "grid": [(k, key_name(k, joints), _fmt(v)) for k, v in (sw.get("grid") or {}).items()],
        "monte_carlo": None if not mc.get("distributions") else {
            "runs": mc.get("runs"), "seed": mc.get("seed"),
            "distributions": [(k, key_name(k, joints), d.get("kind", "?"), [(p, _fmt(v)) for p, v in d.items() if p != "kind"])
                              for k, d in mc["distributions"].items()]},
        "statistics": statistics,
        "statistics_rows": [[label, unit] + values + [count] for label, unit, values, count, _ in statistics],
        "not_finite": "; ".join(f"{label}: {nf} run{'s' if nf != 1 else ''}" for label, _, _, _, nf in statistics
                                if nf),
        "worst_metric": wm, "worst_label": column_label(wm, joints) if wm else "", "worst_unit": worst_unit,
        "worst_keys": [(k, key_name(k, joints), key_unit(k, joints)) for k in keys], "worst": worst,
        "worst_header": ["run"] + [_with_unit(key_name(k, joints), key_unit(k, joints)) for k in keys]
        + [_with_unit(column_label(wm, joints), worst_unit) if wm else ""],
        "worst_rows": [[index] + values + [value] for index, values, value in worst],
        "failed": failed, "failed_more": summary.counts.diverged - len(summary.failed),
        "failed_rows": [[index, ", ".join(f"{name} = {v}" for _, name, v in values), at or "?", message]
                        for index, values, at, message in failed],
        "influence": [(k, key_name(k, joints), f"{v:+.2f}")
                      for k, v in sorted(summary.influence.items(), key=lambda kv: -abs(kv[1]))],
        "influence_rows": [[key_name(k, joints), k, f"{v:+.2f}"]
                           for k, v in sorted(summary.influence.items(), key=lambda kv: -abs(kv[1]))],
        "problems": summary.problems[:20], "problems_more": max(0, len(summary.problems) - 20),
        "sensitivity": _sensitivity_view(summary, joints),
    }


def _sensitivity_view(summary: SweepSummary, joints: JointSpace) -> dict | None:
    """A sensitivity sweep's design in words and its ranked table: per metric column, the values from the largest
    total index (Sobol) or mu* (Morris) down, each number with its 95 % interval."""
    record = summary.sweep.get("sensitivity")
    if not isinstance(record, dict):
        return None
    method = str(record.get("method", "?"))
    distributions = [(k, key_name(k, joints), str(d.get("kind", "?")), [(p, _fmt(v)) for p, v in d.items() if p != "kind"])
                     for k, d in (record.get("distributions") or {}).items()]
    k = len(distributions)
    design = (f"Sobol design (Saltelli's scheme, scrambled Sobol sequence), N = {record.get('samples')} samples x "
              f"(k + 2) = {record.get('runs')} runs for k = {k} values" if method == "sobol" else
              f"Morris design, r = {record.get('samples')} trajectories of {record.get('levels')} levels x (k + 1) = "
              f"{record.get('runs')} runs for k = {k} values") + f", seed {record.get('seed')}"
    found = summary.sobol if method == "sobol" else summary.morris
    rows = []
    if found:
        rank_by, shown = (("total", (("first", "first_conf"), ("total", "total_conf"))) if method == "sobol" else
                          ("mu_star", (("mu_star", "mu_star_conf"), ("sigma", None))))
        for metric, by_key in found[rank_by].items():
            first = next(iter(by_key.values()), None)
            for joint in ([None] if not isinstance(first, list) else range(len(first))):
                column = metric if joint is None else f"{metric}[{joint}]"
                factor, unit = (1.0, "") if method == "sobol" else _table_scale(column_unit(column, joints))
                order = sorted(by_key, key=lambda key: -_finite_or(_per_joint(by_key[key], joint), -math.inf))
                for rank, key in enumerate(order, 1):
                    numbers = []
                    for entry, conf in shown:
                        v = _per_joint(found[entry][metric][key], joint) / factor
                        c = _per_joint(found[conf][metric][key], joint) / factor if conf else None
                        numbers.append("not computed" if not math.isfinite(v) else
                                       f"{v:.3g}" + (f" ± {c:.2g}" if c is not None and math.isfinite(c) else ""))
                    rows.append([_capital(column_label(column, joints))] + ([unit] if method == "morris" else [])
                                + [rank, key_name(key, joints), key] + numbers)
    header = (["metric", "rank", "value", "key", "first order S1 ± 95 %", "total ST ± 95 %"] if method == "sobol" else
              ["metric", "unit", "rank", "value", "key", "mu* ± 95 %", "sigma"])
    return {"method": method, "title": "Sobol indices" if method == "sobol" else "Morris screening",
            "design": design, "distributions": distributions, "header": header, "rows": rows,
            "note": summary.sensitivity_note or "",
            "meaning": ("S1: the share of a metric's variance over the design that the value explains alone; ST: its "
                        "share with all its interactions (ST - S1 is what it explains only together with others). "
                        "An index near 0 says the value does not move that metric." if method == "sobol" else
                        "mu*: the mean absolute change of a metric when the value moves across its whole range, in "
                        "the metric's unit; sigma: the spread of those changes (interactions, nonlinearity). A mu* "
                        "near 0 says the value does not move that metric.")}


def _finite_or(value: float, other: float) -> float:
    return value if math.isfinite(value) else other


def _markdown(summary: SweepSummary) -> str:
    """``summary.md``: the summary with links to its figures."""
    template = _markdown_environment().get_template("sweep_summary.md")
    return template.render(s=_view(summary), figures=[(f.file, f.caption) for f in summary.figures])


def html_section(summary_dir) -> str:
    """The summary written by :func:`write_summary` as one self-contained HTML ``<section>``.

    Tables of the statistics and the worst runs (with the values that produced
    them), the diverged runs, the influence of each swept value, and every
    figure the summary lists, embedded as data with its caption.  Every text
    is escaped by the template.

    Raises
    ------
    SweepError
        When the folder is not a complete summary: no ``summary.json``, one
        written before summaries listed their figures, or a listed figure missing.
    """
    folder = Path(summary_dir)
    path = folder / "summary.json"
    if not path.is_file():
        raise SweepError(f"sweep summary folder '{folder}' has no summary.json (run 'dobkit sweep' first)")
    try:
        summary = SweepSummary.from_json(path.read_text(encoding="utf-8"))
    except (ValueError, KeyError, TypeError) as err:
        raise SweepError(f"sweep summary '{path}' cannot be read ({err}); write it again with "
                         "'dobkit sweep FILE --summary-only'") from None
    if not summary.figures and summary.counts.ok:
        raise SweepError(f"sweep summary '{folder}' lists no figures (written by an older dobkit, or incomplete); "
                         "write it again with 'dobkit sweep FILE --summary-only'")
    figures = []
    for figure in summary.figures:
        png = folder / figure.file
        if Path(figure.file).name != figure.file or not png.is_file():
            raise SweepError(f"sweep summary '{folder}' lists the figure '{figure.file}', which is not there: the "
                             "folder is incomplete; write it again with 'dobkit sweep FILE --summary-only'")
        figures.append((figure.caption, "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")))
    return template_environment().get_template("sweep_section.html").render(s=_view(summary), figures=figures)

