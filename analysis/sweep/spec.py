"""Parameter sweeps: grids of scenario values and Monte Carlo draws, run batched, one results row per run.

A sweep file (TOML) names a base scenario, the values to vary and what to keep::

    name = "robustness"           # optional (default: the file's name); a plain file name, used for files
    scenario = "paper"            # built-in name, or a scenario file (relative to the sweep file)
    observer = true               # optional (default true)
    engine = "batch"              # "batch" (default: blocks.figure2.batch), "cuda" (blocks.figure2.batch on the GPU) or "fast"
                                  # (one blocks.simulate per run)

    [grid]                        # every combination is run
    "gains.kp" = [100, 180, 250]
    "trajectory.stitches" = [3, 5]     # keys outside blocks.figure2.batch.BATCH_KEYS split the sweep into batches

    [monte_carlo]                 # `runs` draws, for every grid point (the same draws for each)
    runs = 200
    seed = 1
    [monte_carlo.distributions]
    "nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
    "disturbance.f_r[2]" = {kind = "normal", mean = 1.4, std = 0.2}    # [i]: one element of an n-vector
    "robot.m3" = {kind = "lognormal", mean = -1.77, sigma = 0.1}        # exp(normal(mean, sigma))
    "noise.seed" = {kind = "choice", values = [1, 2, 3]}                # optional weights = [...]

    [sensitivity]                 # instead of [grid] and [monte_carlo]: a Sobol or Morris design
    method = "sobol"              # "sobol" (N x (k + 2) runs) or "morris" (r x (k + 1) runs)
    samples = 1024                # Sobol: N, a power of 2; Morris: r trajectories
    seed = 1
    [sensitivity.distributions]   # as [monte_carlo.distributions]; no "choice"; Morris: "uniform" only
    "disturbance.f_r[0]" = {kind = "uniform", low = 0.7, high = 2.1}

    [outputs]
    metrics = ["rms_position_error", "max_tool_position_error_mm"]      # default: all that apply
    worst_metric = "max_tool_position_error_mm"                         # ranks the worst cases
    worst_count = 5

    [batch]
    size = 250                    # members per batch at most (default 250; fewer when memory asks for it)
    substeps = "auto"             # RK4 steps per output interval (default "auto": each run's own)

With ``engine = "cuda"`` every batch runs as :func:`blocks.figure2.batch.simulate_batch`
with ``engine="cuda"`` (one GPU thread per run, fixed-step RK4 on the
batch's schedule, :mod:`blocks.engines.gpu`): the same runs, batches and numbers
as ``"batch"`` to rounding, one batch at a time on the one device (a
larger ``batch.size`` fills it better).  A machine without numba-cuda, a
CUDA driver or a device is refused when the sweep file is checked, with
the reason, before any run.

A ``[sensitivity]`` sweep's runs are its design, in design order; its
summary has the indices of every kept metric column (see
:mod:`analysis.sweep.sensitivity`).

Keys are the scenario's dotted keys (``section.key``, see
:mod:`blocks.scenarios.scenario`).  Everything -- keys, grids, distributions and
every drawn value -- is validated before the first run; errors name the key.

Budgets
    Before anything is built the sweep's size is checked against the memory
    budget (:class:`blocks.engines.budget.Budget`: about :data:`SWEEP_RUN_BYTES` per
    run for its bookkeeping and summary), naming the grid key or
    ``monte_carlo.runs`` that makes it large (a sensitivity design's run
    count, ``sensitivity.samples``, before the design is made).  Then, with the batch engine,
    each run's step count and a one-run batch's memory are estimated from its
    scenario and checked, naming the key that makes the step small or the
    schedule long (``gains.observer``, ``trajectory.stitches``,
    ``batch.substeps``, ``noise.sample_period``, ...).

Step sizes
    With ``substeps = "auto"`` every run gets the step its own values need
    (:func:`blocks.figure2.batch.auto_substeps` of that run alone, rounded up to a
    power of two), and runs are batched only with runs of the same step and
    the same noise setting: a stiff run never imposes its step on mild ones,
    and a run's numbers do not depend on which runs share its batch.

Each run has an id: a hash of the base scenario, the engine settings and the
run's values, plus its draw number.  The sweep's *definition* (the hash of
everything that decides its runs and their rows) is recorded in the results
file.  Runs are not held in memory: :attr:`SweepSpec.runs` computes each one
when asked.  Running a sweep (results file, batching, local processes or
Dask, resuming): :mod:`analysis.sweep.runner`.  Summaries and plots:
:mod:`analysis.sweep.summary`.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.jobs.files import json_default
from analysis.jobs.keys import Key, a_table, failing, read_table, read_top, text, whole
from analysis.sweep.distributions import DISTRIBUTIONS, Distribution
from analysis.sweep.sensitivity import DEFAULT_LEVELS, KINDS, METHODS, Sensitivity, run_count, salib, samples_problem
from blocks.engines.budget import Budget, BudgetError, Estimate, estimate_batch, format_bytes, schedule_steps
from blocks.figure2.batch import BATCH_KEYS, METRICS, Variants, auto_substeps, fastest_rate
from blocks.figure2.batch.schedule import STEP_LAMBDA, STEPS_PER_PHASE, TISSUE_STEP
from blocks.figure2.metrics import OBSERVER_METRICS
from blocks.plumbing.progress import count_progress
from blocks.scenarios.scenario import Scenario, ScenarioError, load_scenario, parse_key

__all__ = ["SweepError", "Distribution", "Run", "RunList", "RunPlan", "SweepSpec", "load_sweep", "sweep_from_dict",
           "split_changes", "json_default", "check_name", "HEADER_PARTS", "run_schedule", "DISTRIBUTIONS", "ENGINES",
           "BATCH_ENGINES",
           "SWEEP_RUN_BYTES", "CHECK_PROGRESS_RUNS",
           "PRESENTATION_KEYS"]

ENGINES = ("batch", "fast", "cuda")
#: The engines that run batches of :func:`blocks.figure2.batch.simulate_batch` (on the CPU, or on the GPU).
BATCH_ENGINES = ("batch", "cuda")
#: Memory (bytes) a sweep holds per run while running and summarising: the run's plan entry, its id in
#: the set of finished runs, its metric columns and swept values in the summary (measured: about 500).
SWEEP_RUN_BYTES = 1024
#: Sweeps of this many runs or more show the progress of their validation (it takes about 50-250 us a run).
CHECK_PROGRESS_RUNS = 20_000
#: Header entries that only change how results are shown, not which runs there are or what their rows hold.
PRESENTATION_KEYS = ("name", "source", "description", "worst_metric", "worst_count", "runs")
_OBSERVER_METRICS = OBSERVER_METRICS
_PER_JOINT = tuple(m for m in METRICS if "tool" not in m)        # the tool-tip metrics are one number a run
# Member keys that do not change how fast the loop is (so not its step): see blocks.figure2.batch.fastest_rate.
_RATE_FREE = ("noise.", "initial.", "disturbance.f_r", "observer.variant")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,99}")


class SweepError(ValueError):
    """A sweep file or value is invalid; the message names the key."""


def check_name(name: str, what: str = "'name'") -> str:
    """A sweep name is used in file names: one plain file-name component (letters, digits, ``_ . + -``,
    not starting with a dot, at most 100 characters).

    Raises
    ------
    SweepError
        Naming the value and what is allowed.
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise SweepError(f"{what} must be a plain file name (letters, digits and _ . + -, starting with a letter "
                         f"or digit, at most 100 characters; no folders), got {name!r}")
    return name


@dataclass(frozen=True)
class Run:
    """One run of a sweep: its id, its position, its values by sweep key, and its draw number (or None)."""

    run_id: str
    index: int
    values: dict
    draw: int | None = None


class RunList(Sequence):
    """The runs of a sweep, each computed when asked (a 1e6-run sweep holds no list of runs).

    Order: the grid points in ``itertools.product`` order of the ``[grid]``
    keys (the last key fastest), and at each point the Monte Carlo draws in
    order (the same draws at every point).
    """

    def __init__(self, grid: dict, draws: dict, per_point: int, identity: dict) -> None:
        self.keys = list(grid)
        self.grid = grid
        self.draws = draws
        self.per_point = per_point if draws else 1
        self.points = math.prod(len(v) for v in grid.values())
        self._identity = json.dumps(identity, sort_keys=True, default=json_default)

    def __len__(self) -> int:
        return self.points * self.per_point

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"run indices are whole numbers, got {index!r}")
        n = len(self)
        i = int(index) + n if index < 0 else int(index)
        if not 0 <= i < n:
            raise IndexError(f"run {index} of a sweep of {n} runs")
        values, draw = self.values(i)
        return Run(run_id=self._run_id(values, draw), index=i, values=values, draw=draw)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def values(self, i: int) -> tuple[dict, int | None]:
        """Run ``i``'s values by sweep key and its draw number (None without Monte Carlo)."""
        point, draw = divmod(i, self.per_point)
        picked = []
        for key in reversed(self.keys):
            point, k = divmod(point, len(self.grid[key]))
            picked.append((key, self.grid[key][k]))
        values = dict(reversed(picked))
        if not self.draws:
            return values, None
        values.update({k: v[draw] for k, v in self.draws.items()})
        return values, draw

    def run_id(self, i: int) -> str:
        """Run ``i``'s id without building the :class:`Run`."""
        return self._run_id(*self.values(i))

    def _run_id(self, values: dict, draw: int | None) -> str:
        # the text json.dumps({"identity", "values", "draw"}, sort_keys=True) gives, with the identity
        # serialised once for all runs
        payload = (f'{{"draw": {json.dumps(draw)}, "identity": {self._identity}, '
                   f'"values": {json.dumps(values, sort_keys=True, default=json_default)}}}')
        return hashlib.sha256(payload.encode()).hexdigest()[:16]


@dataclass
class RunPlan:
    """How the batch engine runs each run: its shared-scenario group, its RK4 substeps and whether it has noise.

    Attributes
    ----------
    group : numpy.ndarray of int
        Per run, the index into ``shared`` of the changes its batch shares.
    substeps : numpy.ndarray of int
        Per run, RK4 steps per output interval (0 with the fast engine).
    noise : numpy.ndarray of bool
        Per run, whether it has measurement noise.
    shared : list of dict
        The shared changes of each group (keys outside :data:`~blocks.figure2.batch.BATCH_KEYS`).
    largest : Estimate or None
        The largest one-run estimate over the sweep's runs (steps and memory).
    """

    group: np.ndarray
    substeps: np.ndarray
    noise: np.ndarray
    shared: list
    largest: Estimate | None = None

    def classes(self) -> dict[tuple[int, bool], int]:
        """Runs by (substeps, noise)."""
        out: dict[tuple[int, bool], int] = {}
        for s, nz in zip(self.substeps.tolist(), self.noise.tolist()):
            out[(s, nz)] = out.get((s, nz), 0) + 1
        return dict(sorted(out.items()))


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
    runs : RunList
        Every run, in order, computed when asked.
    definition : str
        Hash of everything that decides the runs and their rows (not the name or how results are shown).
    plan : RunPlan
        How each run is batched (group, substeps, noise).
    budget : Budget
        The budget the sweep was checked against.
    sensitivity : Sensitivity or None
        The ``[sensitivity]`` table, whose design the runs are (None without one).
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
    runs: RunList | None = None
    definition: str = ""
    plan: RunPlan | None = None
    budget: Budget = field(default_factory=Budget)
    sensitivity: Sensitivity | None = None

    def scenario(self, run: Run) -> Scenario:
        """The complete scenario of one run: the base with the run's values (:meth:`Scenario.with_changes`)."""
        return self.base.with_changes(run.values)

    def identity(self) -> dict:
        """What every run id hashes besides the run's values: base scenario, observer, engine, substeps."""
        return {"scenario": self.base.data, "observer": self.observer, "engine": self.engine,
                "substeps": self.substeps if self.engine in BATCH_ENGINES else None}

    def header(self) -> dict:
        """What the results file records about the sweep (first line)."""
        scenario_hash = hashlib.sha256(json.dumps(self.base.data, sort_keys=True, default=json_default)
                                       .encode()).hexdigest()[:16]
        return {"sweep": {"name": self.name, "source": self.source, "description": self.description,
                          "definition": self.definition, "scenario": self.base.name,
                          "scenario_values": scenario_hash,
                          "observer": self.observer, "engine": self.engine, "substeps": self.substeps,
                          "grid": self.grid,
                          "monte_carlo": {"runs": self.runs_per_point, "seed": self.seed,
                                          "distributions": {k: {"kind": d.kind} | d.params
                                                            for k, d in self.distributions.items()}},
                          "metrics": list(self.metrics), "worst_metric": self.worst_metric,
                          "worst_count": self.worst_count, "runs": len(self.runs),
                          "joints": joints_record(self.base.robot.joints)}
                | ({"sensitivity": self.sensitivity.record()} if self.sensitivity is not None else {})}


def joints_record(joints) -> dict:
    """The base scenario's arm's joints as the results header keeps them: names and kinds (which rebuild the
    :class:`~blocks.model.joints.JointSpace` that names the per-joint columns), and their units, for a person reading
    the file.  A presentation entry: it is not part of the definition (the base scenario's values are)."""
    return {"names": list(joints.names), "kinds": list(joints.kinds), "position_units": list(joints.position_units),
            "force_units": list(joints.force_units)}


#: The results-file header entries that decide runs and rows, in words (see :func:`analysis.jobs.files.differences`).
HEADER_PARTS = {"scenario": "the base scenario", "scenario_values": "the base scenario's values",
                "observer": "observer on/off", "engine": "the engine", "substeps": "batch.substeps", "grid": "[grid]",
                "monte_carlo": "[monte_carlo]", "metrics": "outputs.metrics", "sensitivity": "[sensitivity]"}


# --------------------------------------------------------------------------------------------
# Reading and validating
# --------------------------------------------------------------------------------------------
def load_sweep(path: str | Path, budget: Budget | None = None, progress=False) -> SweepSpec:
    """Read and fully validate a sweep file (TOML).

    Parameters
    ----------
    path : path
        The sweep file.
    budget : Budget, optional
        Memory and step budget (default: :meth:`Budget.from_env`).
    progress : bool or callable
        Show the validation of a large sweep (:data:`CHECK_PROGRESS_RUNS` runs or more) as
        :func:`blocks.plumbing.progress.count_progress` does.

    Raises
    ------
    SweepError
        On any problem, before anything runs; the message names the key.
    BudgetError
        When the sweep or one of its runs would exceed the budget; the message names the key and the estimate.
    """
    path = Path(path)
    from analysis.jobs.files import read_job_file
    text = read_job_file(path, SweepError, "sweep file")   # a regular file of at most 1 MiB (not /dev/zero, a FIFO)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{path}: not valid TOML: {err}") from None
    return sweep_from_dict(data, source=str(path), folder=path.parent, budget=budget, progress=progress)


#: The keys of a sweep file by table (None: the top level), with their checks and defaults.  Defaults
#: of None are derived from other keys (name from the file name, metrics from ``observer``, ...).
_KEYS: dict[str | None, dict[str, Key]] = {
    None: {"name": Key(lambda v: isinstance(v, str) and bool(_NAME.fullmatch(v)),
                        "a plain file name (letters, digits and _ . + -, starting with a letter or digit, at most "
                        "100 characters; no folders)"),
           "description": Key(text, "a string", ""),
           "scenario": Key(text, "a built-in scenario name or a file path", "paper"),
           "observer": Key(lambda v: isinstance(v, bool), "true or false", True),
           "engine": Key(lambda v: v in ENGINES, f"one of {list(ENGINES)}", "batch"),
           "grid": Key(a_table, "a table ([grid])", {}), "monte_carlo": Key(a_table, "a table ([monte_carlo])", {}),
           "outputs": Key(a_table, "a table ([outputs])", {}), "batch": Key(a_table, "a table ([batch])", {}),
           "sensitivity": Key(a_table, "a table ([sensitivity])", {})},
    "monte_carlo": {"runs": Key(whole(1), "a whole number >= 1"), "seed": Key(whole(0), "a whole number >= 0", 0),
                    "distributions": Key(a_table, "a table of distributions by scenario key", {})},
    "sensitivity": {"method": Key(lambda v: v in METHODS, f"one of {list(METHODS)}"),
                    "samples": Key(whole(1), "a whole number >= 1"), "seed": Key(whole(0), "a whole number >= 0", 0),
                    "levels": Key(whole(1), "a whole number >= 1 (Morris grid levels)"),
                    "distributions": Key(a_table, "a table of distributions by scenario key", {})},
    "outputs": {"metrics": Key(lambda v: isinstance(v, list) and bool(v) and all(map(text, v)),
                                "a non-empty list of metric names"),
                "worst_metric": Key(text, "one of the kept metric columns"),
                "worst_count": Key(whole(1), "a whole number >= 1", 5)},
    "batch": {"size": Key(whole(1), "a whole number >= 1", 250),
              "substeps": Key(lambda v: v == "auto" or whole(1)(v), '"auto" or a whole number >= 1', "auto")},
}


def _read(table: dict, section: str | None, fail) -> dict:
    """The keys of one table checked against :data:`_KEYS`, defaults filled in (:func:`analysis.jobs.keys.read_table`)."""
    return read_table(table, _KEYS, section, fail)


def sweep_from_dict(data: dict, source: str = "<dict>", folder: Path | None = None,
                    budget: Budget | None = None, progress=False) -> SweepSpec:
    """Validate a sweep given as a dictionary (the parsed TOML); see :func:`load_sweep`."""

    fail = failing(SweepError, source)
    budget = Budget.from_env() if budget is None else budget
    top = read_top(data, _KEYS, "sweep", fail)
    if top["engine"] == "cuda":
        _check_cuda(fail)
    name = top["name"]
    if name is None:
        name = Path(source).stem if source.endswith(".toml") else "sweep"
        if not _NAME.fullmatch(name):
            fail(f"the sweep file's name {name!r} cannot name its files; give a plain 'name' (letters, digits "
                 "and _ . + -)")
    base = _base_scenario(top["scenario"], folder, fail)
    mc = _read(top["monte_carlo"], "monte_carlo", fail)
    if top["monte_carlo"] and mc["runs"] is None:
        fail(f"'monte_carlo.runs' must be a whole number >= 1, got {mc['runs']!r}")
    if top["monte_carlo"] and not mc["distributions"]:
        fail("'monte_carlo.distributions' is empty: name at least one uncertain value")
    for key, values in top["grid"].items():
        if not isinstance(values, list):
            fail(f"grid.\"{key}\" must be a list of values, got {values!r}")
    _check_size(name, top["grid"], mc["runs"] or 0, bool(mc["distributions"]), budget, fail)
    sensitivity = _sensitivity(top, base, name, budget, fail) if top["sensitivity"] else None
    grid = _grid(top["grid"], base, fail)
    distributions = {}
    for key, spec in mc["distributions"].items():
        label = f"monte_carlo.distributions.\"{key}\""
        _check_key(key, base, label, fail)
        if key in grid:
            fail(f"'{key}' is both in [grid] and in {label}; vary it in one place")
        distributions[key] = _distribution(spec, label, fail)
    outputs = _read(top["outputs"], "outputs", fail)
    metrics, worst_metric = _outputs(outputs, top["observer"], fail, base.robot.joints.count)
    batch = _read(top["batch"], "batch", fail)
    if not grid and not distributions and sensitivity is None:
        fail("the sweep varies nothing: give a [grid], [monte_carlo.distributions] or [sensitivity]")
    spec = SweepSpec(name=name, source=source, base=base, observer=top["observer"], engine=top["engine"], grid=grid,
                     runs_per_point=mc["runs"] or 0, seed=mc["seed"], distributions=distributions,
                     metrics=tuple(metrics), worst_metric=worst_metric, worst_count=outputs["worst_count"],
                     batch_size=batch["size"], substeps=None if batch["substeps"] == "auto" else batch["substeps"],
                     description=top["description"], budget=budget, sensitivity=sensitivity)
    if sensitivity is None:
        rng = np.random.default_rng(spec.seed)
        draws = {k: d.draw(rng, spec.runs_per_point) for k, d in distributions.items()}
        spec.runs = RunList(grid, draws, spec.runs_per_point, spec.identity())
    else:                    # the design's rows are the runs, in design order (its draw numbers)
        design = sensitivity.design()
        draws = {k: design[:, j].tolist() for j, k in enumerate(sensitivity.keys)}
        del design
        spec.runs = RunList({}, draws, sensitivity.runs, spec.identity())
    spec.definition = _definition(spec)
    counter = count_progress(progress if len(spec.runs) >= CHECK_PROGRESS_RUNS else False, len(spec.runs),
                             label="checking")
    try:
        spec.plan = _plan(spec, fail, counter)
    finally:
        counter.close()
    return spec


def _definition(spec: SweepSpec) -> str:
    """Hash of what decides the runs and their rows (see :data:`PRESENTATION_KEYS` for what it leaves out)."""
    header = spec.header()["sweep"]
    decisive = {k: v for k, v in header.items() if k not in PRESENTATION_KEYS + ("definition",)}
    decisive["identity"] = spec.identity()
    text = json.dumps(decisive, sort_keys=True, default=json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _check_size(name: str, grid: dict, runs_per_point: int, drawn: bool, budget: Budget, fail) -> None:
    """Refuse, before anything is built, a sweep whose bookkeeping alone would exceed the memory budget."""
    factors = {f"grid.\"{k}\"": len(v) for k, v in grid.items()}
    if drawn and runs_per_point:
        factors["monte_carlo.runs"] = runs_per_point
    runs = math.prod(factors.values()) if factors else 0
    need = runs * SWEEP_RUN_BYTES
    if need > budget.memory:
        key = max(factors, key=factors.get)
        shape = " x ".join(f"{n}" for n in factors.values())
        estimate = Estimate(memory=need, parts={"runs": need}, keys={"runs": key},
                            reasons={"runs": f"{runs:.3g} runs"})
        raise BudgetError(
            f"{name}: the sweep has {runs:,} runs ({shape}), which need about {format_bytes(need)} of memory to run "
            f"and summarise ({SWEEP_RUN_BYTES} bytes a run), over the memory budget of {format_bytes(budget.memory)}; "
            f"the largest factor is {key} ({factors[key]:,} values). Split the sweep, or raise the budget with "
            f"--max-memory or DOBKIT_MAX_MEMORY", estimate, key, "memory")


def _sensitivity(top: dict, base: Scenario, name: str, budget: Budget, fail) -> Sensitivity:
    """The ``[sensitivity]`` table validated, and its run count checked against the budget before its design is
    made (see :mod:`analysis.sweep.sensitivity`)."""
    table = _read(top["sensitivity"], "sensitivity", fail)
    if top["grid"] or top["monte_carlo"]:
        fail("a [sensitivity] sweep's runs are its design: it takes no [grid] or [monte_carlo] (give the values "
             "that stay fixed in its scenario, and the uncertain ones in [sensitivity.distributions])")
    method, samples = table["method"], table["samples"]
    if method is None:
        fail(f"'sensitivity.method' must be one of {list(METHODS)}, got nothing")
    if samples is None:
        fail("'sensitivity.samples' must be given: N of a Sobol design (a power of 2) or r, the Morris trajectories")
    problem = samples_problem(method, samples, table["levels"])
    if problem:
        fail(problem)
    if not table["distributions"]:
        fail("'sensitivity.distributions' is empty: name at least one uncertain value")
    distributions = {}
    for key, spec in table["distributions"].items():
        label = f"sensitivity.distributions.\"{key}\""
        _check_key(key, base, label, fail)
        if isinstance(spec, dict) and spec.get("kind") in DISTRIBUTIONS and spec["kind"] not in KINDS[method]:
            why = "a Morris trajectory moves each value over levels that include both ends of a bounded range" \
                if method == "morris" else "the indices apportion the variance of values on an ordered scale"
            fail(f"{label}: kind '{spec['kind']}' cannot be used with method '{method}' ({why}); choose from "
                 f"{list(KINDS[method])}")
        distributions[key] = _distribution(spec, label, fail)
    settings = Sensitivity(method=method, samples=samples, seed=table["seed"], distributions=distributions,
                           levels=(table["levels"] or DEFAULT_LEVELS) if method == "morris" else 0)
    runs = run_count(method, samples, len(distributions))
    need = runs * SWEEP_RUN_BYTES
    if need > budget.memory:
        k = len(distributions)
        shape = f"N = {samples:,} x (k + 2)" if method == "sobol" else f"r = {samples:,} x (k + 1)"
        estimate = Estimate(memory=need, parts={"runs": need}, keys={"runs": "sensitivity.samples"},
                            reasons={"runs": f"{runs:.3g} runs"})
        raise BudgetError(
            f"{name}: the {method} design has {runs:,} runs ({shape} with k = {k} values), which need about "
            f"{format_bytes(need)} of memory to run and summarise ({SWEEP_RUN_BYTES} bytes a run), over the memory "
            f"budget of {format_bytes(budget.memory)}; lower sensitivity.samples, or raise the budget with "
            "--max-memory or DOBKIT_MAX_MEMORY", estimate, "sensitivity.samples", "memory")
    try:
        salib()
    except ImportError as err:
        fail(str(err))
    return settings


def _grid(grid: dict, base: Scenario, fail) -> dict:
    for key, values in grid.items():
        _check_key(key, base, f"grid.\"{key}\"", fail)
        if not values:
            fail(f"grid.\"{key}\" is empty: give at least one value")
        seen: dict[str, int] = {}
        for i, v in enumerate(values):
            text = json.dumps(v, sort_keys=True, default=json_default)
            if text in seen or (isinstance(v, float) and v != v):
                fail(f"grid.\"{key}\" repeats the value {v!r}")
            seen[text] = i
    return grid


def _outputs(outputs: dict, observer: bool, fail, joints: int) -> tuple[list, str]:
    """The kept metrics (default: all that apply) and the column that ranks the worst runs (per-joint metrics
    have one column per joint of the base scenario's arm)."""
    applicable = tuple(m for m in METRICS if observer or m not in _OBSERVER_METRICS)
    metrics = outputs["metrics"] if outputs["metrics"] is not None else list(applicable)
    for m in metrics:
        if m not in METRICS:
            fail(f"'outputs.metrics' names an unknown metric {m!r}; choose from {list(METRICS)}")
        if m not in applicable:
            fail(f"'outputs.metrics' asks for {m!r}, which needs the observer (observer = true)")
    columns = [f"{m}[{j}]" if m in _PER_JOINT else m for m in metrics for j in range(joints if m in _PER_JOINT else 1)]
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
                not isinstance(w, bool) and isinstance(w, (int, float)) and math.isfinite(w) and w >= 0
                for w in weights)
            if not ok or sum(weights) <= 0:
                fail(f"{label}: 'weights' must be {len(values)} numbers >= 0 with a positive sum, got {weights!r}")
    return Distribution(kind=kind, params=dict(params))


def split_changes(values: Mapping[str, Any]) -> tuple[dict, dict]:
    """Split a run's values into the part its batch shares and the per-member part: keys in
    :data:`~blocks.figure2.batch.BATCH_KEYS` and their elements (``"disturbance.f_r[2]"``) vary within a batch."""
    member = {k: v for k, v in values.items() if _list_key(k) in BATCH_KEYS}
    return {k: v for k, v in values.items() if k not in member}, member


def _list_key(key: str) -> str:
    section, name, _ = parse_key(key)
    return f"{section}.{name}"


# --------------------------------------------------------------------------------------------
# The plan: every run validated, its step chosen and its estimate checked, before anything runs
# --------------------------------------------------------------------------------------------
def _plan(spec: SweepSpec, fail, counter) -> RunPlan:
    """Validate every run's values, group the runs by shared scenario, give each run its step, and check
    each (group, step, noise) class against the budget; a group's runs are taken a chunk at a time."""
    runs = spec.runs
    n = len(runs)
    shared_keys = [k for k in list(spec.grid) + list(runs.draws) if _list_key(k) not in BATCH_KEYS]
    group = np.zeros(n, dtype=np.int32)
    shared_list: list[dict] = [{}]
    if shared_keys:
        index: dict[str, int] = {}
        shared_list = []
        for i in range(n):
            values, _ = runs.values(i)
            shared = {k: values[k] for k in shared_keys}
            text = json.dumps(shared, sort_keys=True, default=json_default)
            if text not in index:
                index[text] = len(shared_list)
                shared_list.append(shared)
            group[i] = index[text]
    substeps = np.zeros(n, dtype=np.int64)
    noise = np.zeros(n, dtype=bool)
    plan = RunPlan(group=group, substeps=substeps, noise=noise, shared=shared_list)
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.diff(group[order])) + 1
    for members in np.split(order, bounds):
        first = int(members[0])
        try:
            base = spec.base.with_changes(shared_list[group[first]])
        except ScenarioError as err:
            fail(f"run {first} ({_describe(runs.values(first)[0])}): {err}")
        if spec.engine == "fast":
            for i in members.tolist():
                values = runs.values(i)[0]
                try:
                    base.with_changes(split_changes(values)[1])
                except ScenarioError as err:
                    fail(f"run {i} ({_describe(values)}): {err}")
                counter.update(1)
            continue
        _plan_group(spec, base, members, plan, fail, counter)
    return plan


def _check_cuda(fail) -> None:
    """Refuse ``engine = "cuda"`` where it cannot run (no numba-cuda, driver or device; no numba), with the
    reason of :func:`blocks.engines.gpu.device.cuda_unavailable_reason`, before anything else is checked or run."""
    from blocks.engines.compiled.jit import numba_or_none
    from blocks.engines.gpu.device import cuda_unavailable_reason
    reason = cuda_unavailable_reason()
    if reason is None and numba_or_none() is None:
        reason = "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    if reason is not None:
        fail(f"engine = \"cuda\" cannot run here: {reason}; use engine = \"batch\" on the CPU")


def _cuda_group_reason(variants: Variants, observer: bool, program: bool) -> str | None:
    """Why the GPU cannot run a chunk of a group's runs (:func:`blocks.engines.gpu.batch.gpu_batch_reason`: one generated
    code for all members; with ``program``, once per group, every block of the loop traced), or None; the loop's
    code is generated, not compiled."""
    from blocks.engines.compiled.codegen import CompiledUnavailable
    from blocks.engines.compiled.engine import CompiledLoopEngine
    from blocks.engines.gpu.batch import gpu_batch_reason
    from blocks.figure2.batch.members import shared_loop
    reason = gpu_batch_reason(variants)
    if reason is None and program:
        try:
            reason = gpu_batch_reason(variants, CompiledLoopEngine(shared_loop(variants, observer)))
        except CompiledUnavailable as err:
            reason = str(err)
    return reason


def _plan_group(spec: SweepSpec, base: Scenario, members: np.ndarray, plan: RunPlan, fail, counter) -> None:
    """Validate one shared-scenario group's runs in chunks (bounded memory), give each run its substeps and
    noise flag, and check every (substeps, noise) class of the group against the budget."""
    runs = spec.runs
    samples = _noise_samples(base)
    # a chunk's variants hold their noise samples: keep a chunk within the budget even if every run is noisy
    n = base.robot.n
    per_member = estimate_batch(2, steps=0, grid_points=0, noise=True, noise_samples=samples, joints=n).memory - \
        estimate_batch(1, steps=0, grid_points=0, noise=True, noise_samples=samples, joints=n).memory
    chunk = max(1, min(spec.batch_size, int(spec.budget.memory // max(1, 2 * per_member))))
    quiet = _without_noise(base)
    memo: dict[str, int] = {}
    for start in range(0, members.size, chunk):
        idx = members[start:start + chunk].tolist()
        values = [runs.values(i)[0] for i in idx]
        records = [split_changes(v)[1] for v in values]
        try:
            variants = Variants(base, records)
        except ScenarioError as err:
            found = re.match(r"variant (\d+): (.*)", str(err), re.S)
            if found:
                k = int(found.group(1))
                fail(f"run {idx[k]} ({_describe(values[k])}): {found.group(2)}")
            fail(str(err))
        plan.noise[idx] = [nz is not None for nz in variants.noises]
        if spec.engine == "cuda":
            reason = _cuda_group_reason(variants, spec.observer, program=start == 0)
            if reason is not None:
                fail(f"engine = \"cuda\" cannot run run {idx[0]} ({_describe(values[0])}) and its batch: {reason}")
        if spec.substeps is not None:
            plan.substeps[idx] = spec.substeps
        elif auto_substeps(variants, spec.observer) == 1:      # the finest member needs 1: so do all
            plan.substeps[idx] = 1
        else:
            own = [_own_substeps(quiet, record, spec.observer, memo) for record in records]
            for k, substeps in enumerate(own):
                if substeps > spec.budget.steps:    # steps = substeps x output steps: over budget on any grid
                    fail(f"{spec.name}: run {idx[k]} ({_describe(values[k])}) needs {substeps:.3g} substeps per "
                         f"output step (its fastest dynamics), so more integrator steps than the step budget of "
                         f"{spec.budget.steps:.3g}; narrow its values or raise the budget with --max-steps or "
                         f"DOBKIT_MAX_STEPS")
            plan.substeps[idx] = own
        del variants
        counter.update(len(idx))
    classes = {}
    for i in members.tolist():
        classes.setdefault((int(plan.substeps[i]), bool(plan.noise[i])), i)
    for (substeps, noisy), i in classes.items():
        values = runs.values(i)[0]
        estimate = _run_estimate(spec, base, quiet, split_changes(values)[1], substeps, noisy)
        what = f"{spec.name}: run {i} ({_describe(values)})"
        spec.budget.check(estimate, what)
        if plan.largest is None or (estimate.steps, estimate.memory) > (plan.largest.steps, plan.largest.memory):
            plan.largest = estimate


def _own_substeps(quiet: Scenario, record: dict, observer: bool, memo: dict) -> int:
    """The substeps one run needs alone (:func:`~blocks.figure2.batch.auto_substeps`), rounded up to a power of two
    so that runs of similar stiffness share batches; noise and other rate-free keys do not count."""
    relevant = {k: v for k, v in record.items() if not k.startswith(_RATE_FREE)}
    text = json.dumps(relevant, sort_keys=True, default=json_default)
    if text not in memo:
        need = auto_substeps(Variants(quiet, [relevant]), observer)
        # a value far out (a lognormal's tail) may need more than any budget: kept below 2**62, refused by the caller
        memo[text] = 1 << max(0, math.ceil(math.log2(min(need, 2.0 ** 62))))
    return memo[text]


def _without_noise(base: Scenario) -> Scenario:
    """The scenario with noise off: the step does not depend on it, and noise tables cost memory."""
    if base.noise is None:
        return base
    n = base.robot.joints.count
    return base.with_changes({"noise.q_std": [0.0] * n, "noise.dq_std": [0.0] * n})


def _noise_samples(base: Scenario) -> int:
    period = base.data["noise"].get("sample_period")
    if period is None:          # an arm without measurement noise (a URDF arm's scenario has no [noise] keys)
        return 0
    return int(math.ceil(base.simulation.t_final / period)) + 2


@dataclass(frozen=True)
class Schedule:
    """The size of a run's fixed-step schedule (see :func:`run_schedule`), counted, not built."""

    steps: int
    grid_points: int
    noise_samples: int
    grid_steps: int
    path_breaks: int
    noise_breaks: int


def run_schedule(base: Scenario, substeps: int, noisy: bool) -> Schedule:
    """Steps of a batch run of ``base`` (shared scenario) at ``substeps`` per output interval, with or without
    noise: the output grid divided by ``substeps``, plus the path's phase boundaries and, with noise, the noise
    sample times (as :func:`blocks.figure2.batch.schedule.batch_schedule` builds them; an upper bound)."""
    sim = base.simulation
    grid_steps = schedule_steps(sim.t_final, sim.output_step, substeps)
    path = _path_breakpoints(base)
    samples = _noise_samples(base)
    noise_breaks = samples - 3 if noisy else 0
    return Schedule(steps=grid_steps + path + noise_breaks, grid_points=int(round(sim.t_final / sim.output_step)) + 1,
                    noise_samples=samples, grid_steps=grid_steps, path_breaks=path, noise_breaks=noise_breaks)


def _path_breakpoints(base: Scenario) -> int:
    """Breakpoints of the reference before ``t_final`` (the laceration path's phase boundaries), counted."""
    trajectory, t_final = base.trajectory, base.simulation.t_final
    phase = getattr(trajectory, "phase_duration", None)
    stitches = getattr(trajectory, "stitches", None)
    if phase and stitches:
        return int(min(2 * stitches - 1, math.floor(t_final / phase) + 1))
    explicit = getattr(trajectory, "breakpoints", None)
    return len(list(explicit())) if callable(explicit) else 0


def _run_estimate(spec: SweepSpec, base: Scenario, quiet: Scenario, record: dict, substeps: int,
                  noisy: bool) -> Estimate:
    """Steps and one-run batch memory of a run, with the key that drives the step count."""
    sim = base.simulation
    size = run_schedule(base, substeps, noisy)
    path = size.path_breaks
    n_grid = size.grid_points - 1
    causes = {"grid": size.grid_steps, "path": path, "noise": size.noise_breaks}
    cause = max(causes, key=causes.get)
    if cause == "path":
        key, reason = "trajectory.stitches", (f"{path:.3g} phase boundaries of a {base.trajectory.stitches}-stitch "
                                              "path, each a step end")
    elif cause == "noise":
        key, reason = "noise.sample_period", (f"a step end at every noise sample, every "
                                              f"{base.data['noise']['sample_period']:g} s for {sim.t_final:g} s")
    elif substeps == 1:
        key, reason = "simulation.t_final", f"{n_grid:.3g} output intervals of {sim.output_step:g} s"
    elif spec.substeps is not None:
        key, reason = "batch.substeps", f"{n_grid:.3g} output intervals x {substeps} substeps"
    else:
        key, reason = _step_cause(quiet, record, spec.observer, n_grid, substeps)
    return estimate_batch(1, steps=size.steps, grid_points=size.grid_points, noise=noisy,
                          noise_samples=size.noise_samples, keys={"steps": key}, steps_reason=reason,
                          joints=quiet.robot.n)


def _step_cause(quiet: Scenario, record: dict, observer: bool, n_grid: int, substeps: int) -> tuple[str, str]:
    """What makes a run's automatic step small: the loop's fastest rate (observer or PD gains), the path's
    phases, or tissue contact -- whichever bounds :func:`blocks.figure2.batch.auto_substeps`."""
    relevant = {k: v for k, v in record.items() if not k.startswith(_RATE_FREE)}
    variants = Variants(quiet, [relevant])
    rate = fastest_rate(variants, observer)
    sim = quiet.simulation
    tail = f"{n_grid:.3g} output intervals x {substeps} substeps (h = {sim.output_step / substeps:.2g} s)"
    by_rate = math.ceil(sim.output_step * rate / STEP_LAMBDA - 1e-9)
    if by_rate >= auto_substeps(variants, observer):
        if observer and fastest_rate(variants, False) < rate:
            return "gains.observer", f"{tail}, as the observer's rate {rate:.3g} 1/s needs h <= {STEP_LAMBDA}/rate"
        return "gains.kp", f"{tail}, as the PD loop's rate {rate:.3g} 1/s needs h <= {STEP_LAMBDA}/rate"
    phase = getattr(quiet.trajectory, "phase_duration", None)
    if "tissue" in quiet.disturbance.kinds and (phase is None or TISSUE_STEP < phase / STEPS_PER_PHASE):
        return "disturbance.kinds", f"{tail}, as tissue contact needs h <= {TISSUE_STEP} s"
    if phase is not None:
        return "trajectory.stitches", (f"{tail}, as each phase of the {quiet.trajectory.stitches}-stitch path "
                                       f"({phase:.3g} s) needs {STEPS_PER_PHASE} steps")
    return "trajectory.omega", f"{tail}, as each period of the reference needs {STEPS_PER_PHASE} steps"


def _describe(values: dict) -> str:
    text = ", ".join(f"{k} = {v!r}" for k, v in values.items())
    return text if len(text) <= 200 else text[:197] + "..."
