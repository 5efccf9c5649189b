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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from blocks.batch import BATCH_KEYS, METRICS, Variants, auto_substeps
from blocks.scenario import Scenario, ScenarioError, load_scenario

__all__ = ["SweepError", "Distribution", "Run", "SweepSpec", "load_sweep", "sweep_from_dict", "scenario_changes",
           "split_changes", "apply_changes", "json_default", "DISTRIBUTIONS", "ENGINES"]

ENGINES = ("batch", "fast")
_TOP_KEYS = ("name", "description", "scenario", "observer", "engine", "grid", "monte_carlo", "outputs", "batch")
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


def sweep_from_dict(data: dict, source: str = "<dict>", folder: Path | None = None) -> SweepSpec:
    """Validate a sweep given as a dictionary (the parsed TOML); see :func:`load_sweep`."""
    where = source

    def fail(msg: str):
        raise SweepError(f"{where}: {msg}")

    if not isinstance(data, dict):
        fail(f"a sweep must be a table, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        fail(f"unknown key(s) {unknown}; allowed at the top level: {list(_TOP_KEYS)}")
    base = _base_scenario(data.get("scenario", "paper"), folder, fail)
    observer = data.get("observer", True)
    if not isinstance(observer, bool):
        fail(f"'observer' must be true or false, got {observer!r}")
    engine = data.get("engine", "batch")
    if engine not in ENGINES:
        fail(f"'engine' must be one of {list(ENGINES)}, got {engine!r}")
    name = data.get("name", Path(source).stem if source.endswith(".toml") else "sweep")
    description = data.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str):
            fail(f"'{key}' must be a string, got {value!r}")

    grid = _table(data, "grid", fail)
    for key, values in grid.items():
        _check_key(key, base, f"grid.\"{key}\"", fail)
        if not isinstance(values, list):
            fail(f"grid.\"{key}\" must be a list of values, got {values!r}")
        if not values:
            fail(f"grid.\"{key}\" is empty: give at least one value")
        seen = []
        for v in values:
            if v in seen:
                fail(f"grid.\"{key}\" repeats the value {v!r}")
            seen.append(v)

    mc = _table(data, "monte_carlo", fail)
    unknown = sorted(set(mc) - {"runs", "seed", "distributions"})
    if unknown:
        fail(f"unknown key(s) {['monte_carlo.' + k for k in unknown]}; allowed: runs, seed, distributions")
    runs = mc.get("runs", 0 if not mc else None)
    if mc and ("runs" not in mc or isinstance(runs, bool) or not isinstance(runs, int) or runs < 1):
        fail(f"'monte_carlo.runs' must be a whole number >= 1, got {mc.get('runs')!r}")
    seed = mc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        fail(f"'monte_carlo.seed' must be a whole number >= 0, got {seed!r}")
    dist_table = mc.get("distributions", {})
    if not isinstance(dist_table, dict):
        fail(f"'monte_carlo.distributions' must be a table, got {dist_table!r}")
    if mc and not dist_table:
        fail("'monte_carlo.distributions' is empty: name at least one uncertain value")
    distributions = {}
    for key, spec in dist_table.items():
        label = f"monte_carlo.distributions.\"{key}\""
        _check_key(key, base, label, fail)
        if key in grid:
            fail(f"'{key}' is both in [grid] and in {label}; vary it in one place")
        distributions[key] = _distribution(spec, label, fail)

    outputs = _table(data, "outputs", fail)
    unknown = sorted(set(outputs) - {"metrics", "worst_metric", "worst_count"})
    if unknown:
        fail(f"unknown key(s) {['outputs.' + k for k in unknown]}; allowed: metrics, worst_metric, worst_count")
    applicable = tuple(m for m in METRICS if observer or m not in _OBSERVER_METRICS)
    metrics = outputs.get("metrics", list(applicable))
    if not isinstance(metrics, list) or not metrics or not all(isinstance(m, str) for m in metrics):
        fail(f"'outputs.metrics' must be a non-empty list of metric names, got {metrics!r}")
    for m in metrics:
        if m not in METRICS:
            fail(f"'outputs.metrics' names an unknown metric {m!r}; choose from {list(METRICS)}")
        if m not in applicable:
            fail(f"'outputs.metrics' asks for {m!r}, which needs the observer (observer = true)")
    columns = [f"{m}[{j}]" if m in _PER_JOINT else m for m in metrics for j in range(4 if m in _PER_JOINT else 1)]
    default_worst = "max_tool_position_error_mm" if "max_tool_position_error_mm" in metrics else columns[0]
    worst_metric = outputs.get("worst_metric", default_worst)
    if worst_metric not in columns:
        fail(f"'outputs.worst_metric' must be one of the kept metric columns {columns}, got {worst_metric!r}")
    worst_count = outputs.get("worst_count", 5)
    if isinstance(worst_count, bool) or not isinstance(worst_count, int) or worst_count < 1:
        fail(f"'outputs.worst_count' must be a whole number >= 1, got {worst_count!r}")

    batch = _table(data, "batch", fail)
    unknown = sorted(set(batch) - {"size", "substeps"})
    if unknown:
        fail(f"unknown key(s) {['batch.' + k for k in unknown]}; allowed: size, substeps")
    size = batch.get("size", 250)
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        fail(f"'batch.size' must be a whole number >= 1, got {size!r}")
    substeps = batch.get("substeps", "auto")
    if substeps != "auto" and (isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1):
        fail(f"'batch.substeps' must be \"auto\" or a whole number >= 1, got {substeps!r}")

    if not grid and not distributions:
        fail("the sweep varies nothing: give a [grid] or [monte_carlo.distributions]")
    spec = SweepSpec(name=name, source=source, base=base, observer=observer, engine=engine, grid=grid,
                     runs_per_point=runs or 0, seed=seed, distributions=distributions, metrics=tuple(metrics),
                     worst_metric=worst_metric, worst_count=worst_count, batch_size=size,
                     substeps=None if substeps == "auto" else substeps, description=description)
    spec.runs = _make_runs(spec)
    _validate_runs(spec, fail)
    return spec


def _base_scenario(value, folder: Path | None, fail) -> Scenario:
    if not isinstance(value, str):
        fail(f"'scenario' must be a built-in scenario name or a file path, got {value!r}")
    target = value
    if folder is not None and (value.endswith(".toml") or "/" in value) and not Path(value).is_absolute():
        target = str(folder / value)
    try:
        return load_scenario(target)
    except ScenarioError as err:
        fail(f"'scenario': {err}")


def _table(data: dict, key: str, fail) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        fail(f"'{key}' must be a table ([{key}]), got {value!r}")
    return value


def _split_key(key: str) -> tuple[str, str, int | None]:
    """``"disturbance.f_r[2]"`` -> ("disturbance", "f_r", 2)."""
    index = None
    if key.endswith("]") and "[" in key:
        key, _, rest = key.partition("[")
        index = int(rest[:-1]) if rest[:-1].isdigit() else -1
    section, _, name = key.partition(".")
    return section, name, index


def _check_key(key: str, base: Scenario, label: str, fail) -> None:
    """A sweep key must name an existing scenario value (and a valid element of a vector)."""
    section, name, index = _split_key(key)
    if not name or section not in base.data or not isinstance(base.data[section], dict):
        sections = [k for k, v in base.data.items() if isinstance(v, dict)]
        fail(f"{label}: '{key}' is not a scenario key 'section.key' (sections: {sections})")
    table = base.data[section]
    known = ("q", "dq", "d_hat") if section == "initial" else tuple(sorted(table))
    if name not in known:
        fail(f"{label}: '{key}' is not a scenario key; keys of [{section}]: {list(known)}")
    if index is not None:
        current = table.get(name)
        if index < 0 or not isinstance(current, list) or index >= len(current):
            fail(f"{label}: '{key}' indexes element {index} of '{section}.{name}', which is "
                 f"{'not a list' if not isinstance(current, list) else f'a list of {len(current)}'}")


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


def scenario_changes(base: Scenario, values: dict) -> dict[str, Any]:
    """A run's sweep values as full dotted scenario keys: ``"disturbance.f_r[2]"`` becomes the whole 4-vector."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        section, name, index = _split_key(key)
        full = f"{section}.{name}"
        if index is None:
            out[full] = value
        else:
            vec = list(out.get(full, base.data[section][name]))
            vec[index] = value
            out[full] = vec
    return out


def split_changes(base: Scenario, changes: dict) -> tuple[dict, dict]:
    """Split a run's full dotted changes into the part its batch shares (keys outside
    :data:`~blocks.batch.BATCH_KEYS`) and the per-member part."""
    structural = {k: v for k, v in changes.items() if k not in BATCH_KEYS}
    return structural, {k: v for k, v in changes.items() if k in BATCH_KEYS}


def apply_changes(base: Scenario, changes: dict) -> Scenario:
    """``base`` with full dotted changes (``{"gains.kp": 100}``) applied, validated."""
    sections: dict[str, dict] = {}
    for key, value in changes.items():
        section, name = key.split(".", 1)
        sections.setdefault(section, {})[name] = value
    return base.replace(**sections)


def _validate_runs(spec: SweepSpec, fail) -> None:
    """Build every distinct shared scenario and validate every run's values, before anything runs."""
    groups: dict[str, list[tuple[Run, dict]]] = {}
    bases: dict[str, Scenario] = {}
    for run in spec.runs:
        structural, member = split_changes(spec.base, scenario_changes(spec.base, run.values))
        gkey = json.dumps(structural, sort_keys=True, default=json_default)
        if gkey not in bases:
            try:
                bases[gkey] = apply_changes(spec.base, structural) if structural else spec.base
            except ScenarioError as err:
                fail(f"run {run.index} ({_describe(run.values)}): {err}")
        groups.setdefault(gkey, []).append((run, member))
    for gkey, members in groups.items():
        if spec.engine == "fast":
            for run, member in members:
                try:
                    apply_changes(bases[gkey], member)
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
