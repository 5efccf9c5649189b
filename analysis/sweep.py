"""Parameter sweeps: grids of scenario values and Monte Carlo draws, run batched, one results row per run.

A sweep file (TOML) names a base scenario, the values to vary and what to keep::

    scenario = "paper"            # built-in name, or a scenario file (relative to the sweep file)
    observer = true               # optional (default true)
    engine = "batch"              # "batch" (default: blocks.batch) or "fast" (one blocks.simulate per run)

    [grid]                        # every combination is run
    "gains.kp" = [100, 180, 250]
    "trajectory.stitches" = [3, 5]     # keys outside blocks.batch.BATCH_KEYS split the sweep into batches

    [monte_carlo]                 # `runs` draws, for every grid point (the same draws for each)
    runs = 200
    seed = 1
    [monte_carlo.distributions]
    "nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
    "disturbance.f_r[2]" = {kind = "normal", mean = 1.4, std = 0.2}    # [i]: one element of a 4-vector
    "robot.m3" = {kind = "lognormal", mean = -1.77, sigma = 0.1}        # exp(normal(mean, sigma))
    "noise.seed" = {kind = "choice", values = [1, 2, 3]}                # optional weights = [...]

    [outputs]
    metrics = ["rms_position_error", "max_tool_position_error_mm"]      # default: all that apply
    worst_metric = "max_tool_position_error_mm"                         # ranks the worst cases
    worst_count = 5

    [batch]
    size = 250                    # members per batch (default 250)
    substeps = "auto"             # RK4 steps per output interval (default "auto")

Keys are the scenario's dotted keys (``section.key``, see
:mod:`blocks.scenario`).  Everything -- keys, grids, distributions and
every drawn value -- is validated before the first run; errors name the key.

Each run has an id: a hash of the base scenario, the engine settings and the
run's values, plus its draw number.  Running a sweep (results file, batching,
local processes or Dask, resuming): :mod:`analysis.sweep_runner`.
Summaries and plots: :mod:`analysis.sweep_report`.
"""
from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from blocks.batch import BATCH_KEYS, METRICS, Variants, auto_substeps
from blocks.scenario import Scenario, ScenarioError, load_scenario, parse_key

__all__ = ["SweepError", "Distribution", "Run", "SweepSpec", "load_sweep", "sweep_from_dict", "split_changes",
           "json_default", "DISTRIBUTIONS", "ENGINES"]

ENGINES = ("batch", "fast")
#: Distribution kinds and their parameters (required, optional).
DISTRIBUTIONS = {"uniform": (("low", "high"), ()), "normal": (("mean", "std"), ()),
                 "lognormal": (("mean", "sigma"), ()), "choice": (("values",), ("weights",))}
_OBSERVER_METRICS = ("rms_disturbance_error", "max_abs_disturbance_error")
_PER_JOINT = ("rms_position_error", "max_abs_position_error", "final_abs_position_error", "rms_disturbance_error",
              "max_abs_disturbance_error")


class SweepError(ValueError):
    """A sweep file or value is invalid; the message names the key."""


@dataclass(frozen=True)
class Distribution:
    """A distribution of one uncertain value (see :data:`DISTRIBUTIONS`)."""

    kind: str
    params: dict

    def draw(self, rng: np.random.Generator, n: int) -> list:
        """``n`` draws as plain Python values."""
        p = self.params
        if self.kind == "uniform":
            return rng.uniform(p["low"], p["high"], n).tolist()
        if self.kind == "normal":
            return rng.normal(p["mean"], p["std"], n).tolist()
        if self.kind == "lognormal":
            return rng.lognormal(p["mean"], p["sigma"], n).tolist()
        weights = p.get("weights")
        prob = None if weights is None else np.asarray(weights, dtype=float) / np.sum(weights)
        return [copy.deepcopy(p["values"][i]) for i in rng.choice(len(p["values"]), size=n, p=prob)]


@dataclass(frozen=True)
class Run:
    """One run of a sweep: its id, its position, its values by sweep key, and its draw number (or None)."""

    run_id: str
    index: int
    values: dict
    draw: int | None = None


@dataclass
class SweepSpec:
    """A validated sweep (see the module docstring).

    Attributes
    ----------
    base : Scenario
        The base scenario.
    grid : dict
        Sweep key -> list of values.
    runs_per_point, seed : int
        Monte Carlo draws per grid point (0 without Monte Carlo) and their seed.
    distributions : dict
        Sweep key -> :class:`Distribution`.
    metrics : tuple of str
        Metrics kept per run.
    runs : list of Run
        Every run, in order.
    """

    name: str
    source: str
    base: Scenario
    observer: bool
    engine: str
    grid: dict
    runs_per_point: int
    seed: int
    distributions: dict
    metrics: tuple
    worst_metric: str
    worst_count: int
    batch_size: int
    substeps: int | None
    description: str = ""
    runs: list = field(default_factory=list)
    #: Per shared scenario (batch engine): one step schedule for all its batches -- the finest
    #: any of its runs needs -- so that a run's numbers do not depend on how runs are batched.
    schedules: dict = field(default_factory=dict)

    def scenario(self, run: Run) -> Scenario:
        """The complete scenario of one run: the base with the run's values (:meth:`Scenario.with_changes`)."""
        return self.base.with_changes(run.values)

    def header(self) -> dict:
        """What the results file records about the sweep (first line)."""
        return {"sweep": {"name": self.name, "source": self.source, "scenario": self.base.name,
                          "observer": self.observer, "engine": self.engine, "grid": self.grid,
                          "monte_carlo": {"runs": self.runs_per_point, "seed": self.seed,
                                          "distributions": {k: {"kind": d.kind} | d.params
                                                            for k, d in self.distributions.items()}},
                          "metrics": list(self.metrics), "worst_metric": self.worst_metric,
                          "worst_count": self.worst_count, "runs": len(self.runs)}}


# --------------------------------------------------------------------------------------------
# Reading and validating
# --------------------------------------------------------------------------------------------
def load_sweep(path: str | Path) -> SweepSpec:
    """Read and fully validate a sweep file (TOML).

    Raises
    ------
    SweepError
        On any problem, before anything runs; the message names the key.
    """
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"sweep file '{path}' does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{path}: not valid TOML: {err}") from None
    return sweep_from_dict(data, source=str(path), folder=path.parent)


@dataclass(frozen=True)
class _Key:
    """One key of a sweep file: whether a value is allowed, what is (for the message), and its default."""

    allows: Callable[[Any], bool]
    expected: str
    default: Any = None


def _whole(minimum: int) -> Callable[[Any], bool]:
    return lambda v: not isinstance(v, bool) and isinstance(v, int) and v >= minimum


def _text(v) -> bool:
    return isinstance(v, str)


def _a_table(v) -> bool:
    return isinstance(v, dict)


#: The keys of a sweep file by table (None: the top level), with their checks and defaults.  Defaults
#: of None are derived from other keys (name from the file name, metrics from ``observer``, ...).
_KEYS: dict[str | None, dict[str, _Key]] = {
    None: {"name": _Key(_text, "a string"), "description": _Key(_text, "a string", ""),
           "scenario": _Key(_text, "a built-in scenario name or a file path", "paper"),
           "observer": _Key(lambda v: isinstance(v, bool), "true or false", True),
           "engine": _Key(lambda v: v in ENGINES, f"one of {list(ENGINES)}", "batch"),
           "grid": _Key(_a_table, "a table ([grid])", {}), "monte_carlo": _Key(_a_table, "a table ([monte_carlo])", {}),
           "outputs": _Key(_a_table, "a table ([outputs])", {}), "batch": _Key(_a_table, "a table ([batch])", {})},
    "monte_carlo": {"runs": _Key(_whole(1), "a whole number >= 1"), "seed": _Key(_whole(0), "a whole number >= 0", 0),
                    "distributions": _Key(_a_table, "a table of distributions by scenario key", {})},
    "outputs": {"metrics": _Key(lambda v: isinstance(v, list) and bool(v) and all(map(_text, v)),
                                "a non-empty list of metric names"),
                "worst_metric": _Key(_text, "one of the kept metric columns"),
                "worst_count": _Key(_whole(1), "a whole number >= 1", 5)},
    "batch": {"size": _Key(_whole(1), "a whole number >= 1", 250),
              "substeps": _Key(lambda v: v == "auto" or _whole(1)(v), '"auto" or a whole number >= 1', "auto")},
}


def _read(table: dict, section: str | None, fail) -> dict:
    """The keys of one table checked against :data:`_KEYS`, defaults filled in."""
    keys = _KEYS[section]
    unknown = sorted(set(table) - set(keys))
    if unknown:
        fail(f"unknown key(s) {[k if section is None else f'{section}.{k}' for k in unknown]}; allowed "
             f"{'at the top level' if section is None else f'in [{section}]'}: {', '.join(keys)}")
    out = {}
    for key, spec in keys.items():
        value = table.get(key, copy.deepcopy(spec.default))
        if key in table and not spec.allows(value):
            fail(f"'{key if section is None else f'{section}.{key}'}' must be {spec.expected}, got {value!r}")
        out[key] = value
    return out


def sweep_from_dict(data: dict, source: str = "<dict>", folder: Path | None = None) -> SweepSpec:
    """Validate a sweep given as a dictionary (the parsed TOML); see :func:`load_sweep`."""

    def fail(msg: str):
        raise SweepError(f"{source}: {msg}")

    if not isinstance(data, dict):
        fail(f"a sweep must be a table, got {type(data).__name__}")
    top = _read(data, None, fail)
    base = _base_scenario(top["scenario"], folder, fail)
    grid = _grid(top["grid"], base, fail)
    mc = _read(top["monte_carlo"], "monte_carlo", fail)
    if top["monte_carlo"] and mc["runs"] is None:
        fail(f"'monte_carlo.runs' must be a whole number >= 1, got {mc['runs']!r}")
    if top["monte_carlo"] and not mc["distributions"]:
        fail("'monte_carlo.distributions' is empty: name at least one uncertain value")
    distributions = {}
    for key, spec in mc["distributions"].items():
        label = f"monte_carlo.distributions.\"{key}\""
        _check_key(key, base, label, fail)
        if key in grid:
            fail(f"'{key}' is both in [grid] and in {label}; vary it in one place")
        distributions[key] = _distribution(spec, label, fail)
    outputs = _read(top["outputs"], "outputs", fail)
    metrics, worst_metric = _outputs(outputs, top["observer"], fail)
    batch = _read(top["batch"], "batch", fail)
    if not grid and not distributions:
        fail("the sweep varies nothing: give a [grid] or [monte_carlo.distributions]")
    name = top["name"] if top["name"] is not None else Path(source).stem if source.endswith(".toml") else "sweep"
    spec = SweepSpec(name=name, source=source, base=base, observer=top["observer"], engine=top["engine"], grid=grid,
                     runs_per_point=mc["runs"] or 0, seed=mc["seed"], distributions=distributions,
                     metrics=tuple(metrics), worst_metric=worst_metric, worst_count=outputs["worst_count"],
                     batch_size=batch["size"], substeps=None if batch["substeps"] == "auto" else batch["substeps"],
                     description=top["description"])
    spec.runs = _make_runs(spec)
    _validate_runs(spec, fail)
    return spec


def _grid(grid: dict, base: Scenario, fail) -> dict:
    for key, values in grid.items():
        _check_key(key, base, f"grid.\"{key}\"", fail)
        if not isinstance(values, list):
            fail(f"grid.\"{key}\" must be a list of values, got {values!r}")
        if not values:
            fail(f"grid.\"{key}\" is empty: give at least one value")
        for i, v in enumerate(values):
            if v in values[:i]:
                fail(f"grid.\"{key}\" repeats the value {v!r}")
    return grid


def _outputs(outputs: dict, observer: bool, fail) -> tuple[list, str]:
    """The kept metrics (default: all that apply) and the column that ranks the worst runs."""
    applicable = tuple(m for m in METRICS if observer or m not in _OBSERVER_METRICS)
    metrics = outputs["metrics"] if outputs["metrics"] is not None else list(applicable)
    for m in metrics:
        if m not in METRICS:
            fail(f"'outputs.metrics' names an unknown metric {m!r}; choose from {list(METRICS)}")
        if m not in applicable:
            fail(f"'outputs.metrics' asks for {m!r}, which needs the observer (observer = true)")
    columns = [f"{m}[{j}]" if m in _PER_JOINT else m for m in metrics for j in range(4 if m in _PER_JOINT else 1)]
    worst = outputs["worst_metric"]
    if worst is None:
        worst = "max_tool_position_error_mm" if "max_tool_position_error_mm" in metrics else columns[0]
    if worst not in columns:
        fail(f"'outputs.worst_metric' must be one of the kept metric columns {columns}, got {worst!r}")
    return metrics, worst


def _base_scenario(value: str, folder: Path | None, fail) -> Scenario:
    target = value
    if folder is not None and (value.endswith(".toml") or "/" in value) and not Path(value).is_absolute():
        target = str(folder / value)
    try:
        return load_scenario(target)
    except ScenarioError as err:
        fail(f"'scenario': {err}")


def _check_key(key: str, base: Scenario, label: str, fail) -> None:
    """A sweep key must name an existing scenario value (and a valid element of a list)."""
    try:
        base.check_key(key)
    except ScenarioError as err:
        fail(f"{label}: {err}")


def _distribution(spec, label: str, fail) -> Distribution:
    if not isinstance(spec, dict):
        fail(f"{label} must be a table like {{kind = \"uniform\", low = 0.8, high = 1.2}}, got {spec!r}")
    kind = spec.get("kind")
    if kind not in DISTRIBUTIONS:
        fail(f"{label}: 'kind' must be one of {list(DISTRIBUTIONS)}, got {kind!r}")
    required, optional = DISTRIBUTIONS[kind]
    params = {k: v for k, v in spec.items() if k != "kind"}
    unknown = sorted(set(params) - set(required) - set(optional))
    missing = [k for k in required if k not in params]
    if unknown or missing:
        fail(f"{label}: kind '{kind}' takes {list(required + optional)}"
             + (f"; unknown {unknown}" if unknown else "") + (f"; missing {missing}" if missing else ""))

    def number(k, positive=False):
        v = params[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail(f"{label}: '{k}' must be a finite number, got {v!r}")
        if positive and v <= 0:
            fail(f"{label}: '{k}' must be > 0, got {v!r}")
        return float(v)

    if kind == "uniform":
        low, high = number("low"), number("high")
        if not low < high:
            fail(f"{label}: 'low' must be < 'high', got low = {low}, high = {high}")
    elif kind == "normal":
        number("mean"), number("std", positive=True)
    elif kind == "lognormal":
        number("mean"), number("sigma", positive=True)
    else:
        values = params["values"]
        if not isinstance(values, list) or not values:
            fail(f"{label}: 'values' must be a non-empty list, got {values!r}")
        weights = params.get("weights")
        if weights is not None:
            ok = isinstance(weights, list) and len(weights) == len(values) and all(
                not isinstance(w, bool) and isinstance(w, (int, float)) and math.isfinite(w) and w >= 0 for w in weights)
            if not ok or sum(weights) <= 0:
                fail(f"{label}: 'weights' must be {len(values)} numbers >= 0 with a positive sum, got {weights!r}")
    return Distribution(kind=kind, params=dict(params))


def _make_runs(spec: SweepSpec) -> list[Run]:
    keys = list(spec.grid)
    points = list(itertools.product(*(spec.grid[k] for k in keys))) if keys else [()]
    rng = np.random.default_rng(spec.seed)
    draws = {k: d.draw(rng, spec.runs_per_point) for k, d in spec.distributions.items()}
    identity = {"scenario": spec.base.data, "observer": spec.observer, "engine": spec.engine,
                "substeps": spec.substeps if spec.engine == "batch" else None}
    runs = []
    for point in points:
        for draw in (range(spec.runs_per_point) if spec.distributions else [None]):
            values = dict(zip(keys, point))
            if draw is not None:
                values.update({k: v[draw] for k, v in draws.items()})
            runs.append(Run(run_id=_run_id(identity, values, draw), index=len(runs), values=values, draw=draw))
    return runs


def _run_id(identity: dict, values: dict, draw: int | None) -> str:
    payload = json.dumps({"identity": identity, "values": values, "draw": draw}, sort_keys=True, default=json_default)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def json_default(value):
    """``json.dumps`` helper: numpy scalars and arrays as plain values."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {value!r} as JSON")


def split_changes(values: Mapping[str, Any]) -> tuple[dict, dict]:
    """Split a run's values into the part its batch shares and the per-member part: keys in
    :data:`~blocks.batch.BATCH_KEYS` and their elements (``"disturbance.f_r[2]"``) vary within a batch."""
    member = {k: v for k, v in values.items() if _list_key(k) in BATCH_KEYS}
    return {k: v for k, v in values.items() if k not in member}, member


def _list_key(key: str) -> str:
    section, name, _ = parse_key(key)
    return f"{section}.{name}"


def _validate_runs(spec: SweepSpec, fail) -> None:
    """Build every distinct shared scenario and validate every run's values, before anything runs."""
    groups: dict[str, list[tuple[Run, dict]]] = {}
    bases: dict[str, Scenario] = {}
    for run in spec.runs:
        shared, member = split_changes(run.values)
        gkey = json.dumps(shared, sort_keys=True, default=json_default)
        if gkey not in bases:
            try:
                bases[gkey] = spec.base.with_changes(shared)
            except ScenarioError as err:
                fail(f"run {run.index} ({_describe(run.values)}): {err}")
        groups.setdefault(gkey, []).append((run, member))
    for gkey, members in groups.items():
        if spec.engine == "fast":
            for run, member in members:
                try:
                    bases[gkey].with_changes(member)
                except ScenarioError as err:
                    fail(f"run {run.index} ({_describe(run.values)}): {err}")
            continue
        substeps, noise = spec.substeps or 1, False
        for start in range(0, len(members), spec.batch_size):     # in chunks: noise tables are large
            chunk = members[start:start + spec.batch_size]
            try:
                variants = Variants(bases[gkey], [m for _, m in chunk])
                if spec.substeps is None:
                    substeps = max(substeps, auto_substeps(variants, spec.observer))
                noise = noise or any(nz is not None for nz in variants.noises)
            except ScenarioError as err:
                found = re.match(r"variant (\d+): (.*)", str(err), re.S)
                if found:
                    run = chunk[int(found.group(1))][0]
                    fail(f"run {run.index} ({_describe(run.values)}): {found.group(2)}")
                fail(str(err))
        spec.schedules[gkey] = {"substeps": substeps, "noise": noise}


def _describe(values: dict) -> str:
    return ", ".join(f"{k} = {v!r}" for k, v in values.items())
