"""Gain tuning files: which gains to tune within which bounds, for which objective, under which constraints.

A tuning file (TOML) names a base scenario, the gains to search, the objective
over a Monte Carlo set of mismatches and disturbances, and the constraints::

    name = "paper-tune"          # optional (default: the file's name); a plain file name
    description = "..."          # optional
    scenario = "paper"           # built-in name, or a scenario file (relative to the tuning file)
    objective = "worst"          # "worst" (largest over the set) or "mean" of the metric
    metric = "rms_tool_position_error_mm"    # or "max_tool_position_error_mm" (mm, per run)

    [search]                     # bounds of the gains to tune; a gain left out keeps the scenario's value
    "gains.kp" = [50, 1000]      # one value for every joint (1/s^2) ...
    "gains.kd" = [5, 80]         # (1/s)
    "gains.observer" = [[1, 100], [1, 100], [0.5, 50], [1, 100]]   # ... or one per joint: a diagonal (kg m^2/s)
    seed = 1                     # of the search (default 1)
    population = 12              # candidates per generation of differential evolution (default 12, >= 5)
    max_evaluations = 400        # objective evaluations in all, search and polish (default 400)
    polish_evaluations = 80      # of those, for the local polish (default a fifth, at most 100; 0: none)

    [constraints]                # every one optional
    torque_noise_rms = "base"    # N m (N): a number, n numbers, or "base": the base scenario's gains' own noise
    torque_limit = 40            # N m (N): a number or n; peak |tau| over every run of the set
    stability_margin = 0.5       # 1/s: the linearized loop's poles have real parts <= -margin
    min_damping_ratio = 0.7      # of the error dynamics, every joint (default 0.7; 0: not constrained) ...
    max_overshoot = 0.05         # ... or instead the largest overshoot of a step (a fraction: 0.05 = 5 %)
    min_observer_bandwidth_ratio = 0.5   # slowest observer mode / tracking bandwidth (default: not constrained)
    sampled_margin = 0.2         # with a [controller]: Ts lambda_max(Y M^-1) at most (1 - margin) x the sampled
                                 # loop's limit (default 0.2 with a [controller]; 0: not constrained)
    sensor_noise = {q_std = [2e-4, 2e-4, 2e-5, 2e-4], dq_std = [5e-3, 5e-3, 5e-4, 5e-3], sample_period = 0.001}
                                 # default: the scenario's [noise], else analysis.simulation.studies.default_noise of the arm

Per-joint values (the bounds of a per-joint gain, ``torque_noise_rms``,
``torque_limit``, ``q_std``, ``dq_std``) have one entry per joint of the base
scenario's arm, in its joint order and units (``scenario.robot.joints``): n = 4
(rad, rad, m, rad; N m, N m, N, N m) for the paper's RRPR, the URDF's joints for
a URDF arm.

    [monte_carlo]                # the mismatch / disturbance set, exactly as in sweep files (analysis.sweep.spec)
    runs = 64
    seed = 1
    [monte_carlo.distributions]
    "nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
    "disturbance.f_r[2]" = {kind = "uniform", low = 0.7, high = 2.1}

Without ``[monte_carlo]`` the set is the base scenario alone.  The set's
keys must be ones that vary within a batch (:data:`blocks.figure2.batch.BATCH_KEYS`),
and not the tuned gains.

The search runs over ``log10`` of each gain (gains span decades), each gain
rounded to :data:`SIGNIFICANT_DIGITS` significant digits, so the tuned scenario
file holds exactly the values that were evaluated.

Constraints (:mod:`analysis.tune.linear` for the linear ones)
    *Torque noise*: the stationary RMS of the torque caused by the sensor noise,
    per joint, at the noise sample instants, for the loop held at the path's
    start (the arm of :mod:`analysis.simulation.studies`) with the base scenario's models.
    ``"base"`` sets the budget to the noise of the base scenario's own gains
    (the paper's on the paper scenario): the same torque-noise budget.
    *Stability margin*: the spectral abscissa of the held loop linearized at
    :data:`STABILITY_CONFIGURATIONS` configurations along the path, for the base
    models and every member of the set (true and nominal inertia), is at most
    ``-margin``.  *Torque limit*: the peak ``|tau|`` per joint on the output
    grid of every run of the set.  The linear constraints cost milliseconds and
    are checked first: a candidate that fails the torque noise or the stability
    margin is not simulated.
    *Damping*: the error dynamics ``e'' + Kd e' + Kp e = 0`` of each joint
    (paper-notes, Eq. 9-11) has the damping ratio ``zeta = kd / (2 sqrt(kp))``;
    every joint's must be at least ``min_damping_ratio`` (default
    :data:`DEFAULT_MIN_DAMPING`: a well-damped response, about 4.6 % overshoot).
    ``max_overshoot`` states it as the step's overshoot instead,
    ``exp(-pi zeta / sqrt(1 - zeta^2))`` (0 for ``zeta >= 1``).  Candidates that
    miss only this are simulated all the same, so that the search's own log
    tells what the constraint costs (the best evaluation that meets every other
    constraint: :attr:`analysis.tune.results.TuneResult.unconstrained`).
    *Observer bandwidth ratio*: the slowest mode of the observer, the smallest
    eigenvalue of ``Y M^-1(q)`` with the base nominal inertia at the stability
    configurations (rad/s, :mod:`analysis.linear.bandwidth`), over the tracking
    bandwidth, the largest natural frequency ``sqrt(kp)`` of the error dynamics
    (rad/s), is at least ``min_observer_bandwidth_ratio``.
    *Sampled loop* (a scenario with a ``[controller]``): the digital loop's
    stability rule ``Ts lambda_max(Y M^-1) < limit``, the limit computed for the
    candidate's ``Kp``, ``Kd`` and the controller's settings along the path by
    :mod:`blocks.figure2.digital_stability` (2 for Euler with measured velocity, less
    with ``"zoh"``, a velocity difference or a delay); the candidate keeps
    ``Ts lambda_max`` at most ``(1 - sampled_margin)`` times it (default
    :data:`DEFAULT_SAMPLED_MARGIN`).  Checked as the sampled map's spectral
    radius with the observer gain raised by ``1 / (1 - sampled_margin)`` (below
    1: met), which costs one eigenvalue problem per configuration.  The set
    itself is simulated with the continuous controller (the batches have no
    sampling): the digital loop enters the tuning through this constraint, and
    the tuned scenario file keeps the ``[controller]``.

Everything is validated when the file is read, before anything runs; errors
name the key.  Running a tuning: :mod:`analysis.tune.runner`.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from analysis.jobs.keys import Key, failing, number, numbers, read_table, read_top, scenario_value, whole
from analysis.simulation.studies import default_noise
from analysis.sweep.spec import SweepError, check_name, json_default, split_changes, sweep_from_dict
from blocks.engines.budget import Budget
from blocks.figure2.batch import BATCH_KEYS
from blocks.scenarios.scenario import Scenario, ScenarioError, default_arm, load_scenario, parse_key

__all__ = ["TuneError", "Parameter", "Limits", "TuneSpec", "load_tuning", "tuning_from_dict", "builtin_tunings",
           "with_evaluations", "HEADER_PARTS",
           "TUNABLE", "OBJECTIVES", "TUNE_METRICS", "METRIC_WORDS", "SIGNIFICANT_DIGITS", "STABILITY_CONFIGURATIONS",
           "DEFAULT_MIN_DAMPING", "DEFAULT_SAMPLED_MARGIN", "damping_ratios", "overshoots", "damping_for_overshoot"]

#: The gains a tuning may search.
TUNABLE = ("gains.kp", "gains.kd", "gains.observer")
#: How the metric is reduced over the set.
OBJECTIVES = ("worst", "mean")
#: Metrics the objective may use (mm, one number per run).
TUNE_METRICS = ("rms_tool_position_error_mm", "max_tool_position_error_mm")
#: The metrics as a person reads them.
METRIC_WORDS = {"rms_tool_position_error_mm": "RMS tool-tip error",
                "max_tool_position_error_mm": "largest tool-tip error"}
#: Tuned gains are rounded to this many significant digits (the values the scenario file holds).
SIGNIFICANT_DIGITS = 6
#: Configurations along the path at which the stability margin is checked (equally spaced in time).
STABILITY_CONFIGURATIONS = 5
#: The damping ratio of the error dynamics every joint must reach unless the tuning file says otherwise.
DEFAULT_MIN_DAMPING = 0.7
#: Default fraction of the sampled loop's stability limit kept free, for a scenario with a [controller].
DEFAULT_SAMPLED_MARGIN = 0.2
_GAIN_UNITS = {"gains.kp": "1/s^2", "gains.kd": "1/s", "gains.observer": "kg m^2/s"}


class TuneError(ValueError):
    """A tuning file or setting is invalid, or its constraints cannot be met; the message names the key."""


@dataclass(frozen=True)
class Parameter:
    """One searched value: a gain for every joint (``joint`` None) or one joint's diagonal entry.

    Attributes
    ----------
    key : str
        ``"gains.kp"``, ``"gains.kd"`` or ``"gains.observer"``.
    joint : int or None
    low, high : float
        Bounds of the gain (its unit), ``0 < low < high``.
    """

    key: str
    joint: int | None
    low: float
    high: float

    @property
    def name(self) -> str:
        """``gains.kp`` or ``gains.observer[2]``."""
        return self.key if self.joint is None else f"{self.key}[{self.joint}]"

    @property
    def unit(self) -> str:
        return _GAIN_UNITS[self.key]

    def value(self, u: float) -> float:
        """The gain at ``u`` in [0, 1] on a log scale between the bounds, rounded (:data:`SIGNIFICANT_DIGITS`)."""
        lo, hi = math.log10(self.low), math.log10(self.high)
        u = min(1.0, max(0.0, float(u)))
        return min(self.high, max(self.low, _round(10.0 ** (lo + u * (hi - lo)))))

    def unit_of(self, gain: float) -> float:
        """The ``u`` in [0, 1] of a gain (inverse of :meth:`value`, before rounding)."""
        lo, hi = math.log10(self.low), math.log10(self.high)
        return (math.log10(gain) - lo) / (hi - lo)


def _round(value: float) -> float:
    return float(f"{value:.{SIGNIFICANT_DIGITS}g}")


@dataclass(frozen=True)
class Limits:
    """The constraints of a tuning (None: not constrained).

    Attributes
    ----------
    torque_noise_rms : numpy.ndarray or None
        Per joint of the arm (N m for a revolute joint, N for a prismatic one).
    torque_noise_from : str
        ``"base"`` (the base gains' own noise) or ``"given"``.
    torque_limit : numpy.ndarray or None
        Peak ``|tau|`` per joint (N m or N).
    stability_margin : float or None
        1/s.
    sensor_noise : dict
        ``q_std``, ``dq_std`` (n numbers each) and ``sample_period`` (s) of the torque-noise constraint.
    min_damping_ratio : float or None
        Of the error dynamics, every joint (module docstring); None with ``max_overshoot`` or when switched off.
    damping_from : str
        ``"default"`` (:data:`DEFAULT_MIN_DAMPING`), ``"given"``, ``"overshoot"`` or ``"off"``.
    max_overshoot : float or None
        Largest step overshoot of the error dynamics, a fraction.
    min_observer_bandwidth_ratio : float or None
        Slowest observer mode over the tracking bandwidth.
    sampled_margin : float or None
        With a ``[controller]``: the fraction of the sampled loop's limit on ``Ts lambda_max(Y M^-1)`` kept free.
    sampled_from : str
        ``"default"`` (:data:`DEFAULT_SAMPLED_MARGIN`), ``"given"`` or ``"off"``.
    """

    torque_noise_rms: np.ndarray | None
    torque_noise_from: str
    torque_limit: np.ndarray | None
    stability_margin: float | None
    sensor_noise: dict
    min_damping_ratio: float | None = None
    damping_from: str = "off"
    max_overshoot: float | None = None
    min_observer_bandwidth_ratio: float | None = None
    sampled_margin: float | None = None
    sampled_from: str = "off"

    def as_dict(self) -> dict:
        # the sampled margin's keys only where there is one: tunings without a [controller] keep their definition
        sampled = {} if self.sampled_margin is None else {"sampled_margin": self.sampled_margin,
                                                           "sampled_from": self.sampled_from}
        return {"torque_noise_rms": None if self.torque_noise_rms is None else self.torque_noise_rms.tolist(),
                "torque_noise_from": self.torque_noise_from,
                "torque_limit": None if self.torque_limit is None else self.torque_limit.tolist(),
                "stability_margin": self.stability_margin, "sensor_noise": self.sensor_noise,
                "min_damping_ratio": self.min_damping_ratio, "damping_from": self.damping_from,
                "max_overshoot": self.max_overshoot,
                "min_observer_bandwidth_ratio": self.min_observer_bandwidth_ratio} | sampled


def damping_ratios(kp, kd, n: int | None = None) -> np.ndarray:
    """``zeta = kd / (2 sqrt(kp))`` per joint of ``e'' + kd e' + kp e = 0`` (kp 1/s^2, kd 1/s).

    ``kp`` and ``kd`` are scalars or one value per joint; ``n`` (the arm's joint count) sizes the result when both
    are scalars (default: the length of whichever is a vector, else the default scenario's arm's joint count).
    """
    kp, kd = np.asarray(kp, dtype=float), np.asarray(kd, dtype=float)
    if n is None:
        n = max(kp.size if kp.ndim else 0, kd.size if kd.ndim else 0) or default_arm().n
    return np.broadcast_to(kd, (n,)) / (2.0 * np.sqrt(np.broadcast_to(kp, (n,))))


def overshoots(zeta) -> np.ndarray:
    """Step overshoot (a fraction) of a second-order system of damping ratio ``zeta``: 0 when ``zeta >= 1``."""
    z = np.minimum(np.asarray(zeta, dtype=float), 1.0)
    with np.errstate(divide="ignore"):
        return np.where(z < 1.0, np.exp(-np.pi * z / np.sqrt(1.0 - z * z)), 0.0)


def damping_for_overshoot(overshoot: float) -> float:
    """The damping ratio whose step overshoot is ``overshoot`` (0 < overshoot < 1): the inverse of :func:`overshoots`."""
    a = -math.log(overshoot)
    return a / math.sqrt(math.pi ** 2 + a * a)


@dataclass
class TuneSpec:
    """A validated tuning (see the module docstring).

    Attributes
    ----------
    base : Scenario
        The base scenario (its gains are the reference the tuned ones are compared with).
    parameters : list of Parameter
        The searched values, in order (the search vector).
    records : list of dict
        The set: per run, its per-member scenario values (``[{}]`` without Monte Carlo).
    draws : dict
        The ``[monte_carlo]`` table as validated (runs, seed, distributions), for the header.
    limits : Limits
    hold : numpy.ndarray
        Where the torque noise is computed: the path's reference at t = 0 (the arm's position units).
    configurations : numpy.ndarray, shape (STABILITY_CONFIGURATIONS, n)
        Where the stability margin is checked.
    definition : str
        Hash of everything that decides which gains are evaluated and what an evaluation gives (not the name,
        the description or the evaluation budget).
    """

    name: str
    source: str
    description: str
    base: Scenario
    objective: str
    metric: str
    parameters: list
    seed: int
    population: int
    max_evaluations: int
    polish_evaluations: int
    limits: Limits
    records: list
    draws: dict
    hold: np.ndarray
    configurations: np.ndarray
    definition: str = ""
    budget: Budget = field(default_factory=Budget)

    @property
    def joints(self):
        """The base scenario's arm's joints (:class:`blocks.model.joints.JointSpace`): names, kinds, units."""
        return self.base.robot.joints

    @property
    def n(self) -> int:
        """Joints of the base scenario's arm."""
        return self.joints.count

    @property
    def runs(self) -> int:
        """Runs in the set (members of one evaluation's batch)."""
        return len(self.records)

    @property
    def generations(self) -> int:
        """Generations of differential evolution after the first population, within the evaluation budget."""
        return max(0, (self.max_evaluations - self.polish_evaluations) // self.population - 1)

    def gains(self, u) -> dict:
        """The scenario changes of a point ``u`` of the unit box: ``{"gains.kp": 412.3, "gains.observer": [...]}``.

        Per-joint parameters of a gain fill its diagonal; joints not searched keep the base value.
        """
        u = np.asarray(u, dtype=float).ravel()
        out: dict[str, Any] = {}
        for p, ui in zip(self.parameters, u):
            value = p.value(ui)
            if p.joint is None:
                out[p.key] = value
            else:
                diagonal = out.setdefault(p.key, self.base_diagonal(p.key))
                diagonal[p.joint] = value
        return out

    def base_diagonal(self, key: str) -> list[float]:
        """The base scenario's diagonal of a gain (n numbers)."""
        matrix = {"gains.kp": self.base.kp, "gains.kd": self.base.kd, "gains.observer": self.base.observer_gain}[key]
        return [float(v) for v in np.diag(matrix)]

    def base_gains(self) -> dict:
        """The base scenario's values of the tuned gains, as the scenario file has them."""
        return {key: copy.deepcopy(self.base.data["gains"][key.split(".")[1]]) for key in self.tuned_keys}

    def gains_of_base(self) -> dict:
        """The base gains as a candidate: written as :meth:`gains` writes them when that is the same values
        (so the search's first member, the base gains, is the same candidate), else as the scenario has them."""
        point = self.base_point()
        if point is not None:
            gains = self.gains(point)
            if all(np.array_equal(np.broadcast_to(np.asarray(v, dtype=float), (self.n,)), self.base_diagonal(k))
                   for k, v in gains.items()):
                return gains
        return self.base_gains()

    @property
    def tuned_keys(self) -> list[str]:
        return list(dict.fromkeys(p.key for p in self.parameters))

    def base_point(self) -> np.ndarray | None:
        """The base gains as a point of the unit box, or None when they are not one (outside the bounds, a
        matrix observer gain, or joints that differ where one value is searched)."""
        u = []
        for p in self.parameters:
            matrix = {"gains.kp": self.base.kp, "gains.kd": self.base.kd, "gains.observer": self.base.observer_gain}[
                p.key]
            if np.any(matrix - np.diag(np.diag(matrix))):
                return None
            diagonal = np.diag(matrix)
            value = float(diagonal[0] if p.joint is None else diagonal[p.joint])
            if p.joint is None and np.any(diagonal != value):
                return None
            if not p.low <= value <= p.high:
                return None
            u.append(p.unit_of(value))
        return np.array(u)

    def header(self) -> dict:
        """What the evaluation log records about the tuning (its first line)."""
        return {"tune": {"name": self.name, "source": self.source, "description": self.description,
                         "definition": self.definition, **self._decisive(),
                         "max_evaluations": self.max_evaluations, "polish_evaluations": self.polish_evaluations}}

    def _decisive(self) -> dict:
        return {"scenario": self.base.name, "scenario_values": _hash(self.base.data), "objective": self.objective,
                "metric": self.metric,
                "search": {p.name: [p.low, p.high] for p in self.parameters},
                "seed": self.seed, "population": self.population, "constraints": self.limits.as_dict(),
                "monte_carlo": self.draws, "set": _hash(self.records)}


#: The evaluation-log header entries that decide evaluations, in words (:func:`analysis.jobs.files.differences`).
HEADER_PARTS = {"scenario": "the base scenario", "scenario_values": "the base scenario's values",
                "objective": "objective", "metric": "metric", "search": "the [search] bounds", "seed": "search.seed",
                "population": "search.population", "constraints": "[constraints]", "monte_carlo": "[monte_carlo]",
                "set": "the Monte Carlo set"}


def _hash(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=json_default).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------------------------
# Reading and validating
# --------------------------------------------------------------------------------------------
def builtin_tunings() -> list[str]:
    """Names of the tuning files shipped with the toolkit (``analysis/tune/tunings``)."""
    folder = resources.files("analysis.tune") / "tunings"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_tuning(name_or_path: str | Path, budget: Budget | None = None) -> TuneSpec:
    """Read and fully validate a tuning file (TOML), or a built-in one by name (:func:`builtin_tunings`).

    Raises
    ------
    TuneError
        On any problem, before anything runs; the message names the key.
    blocks.engines.budget.BudgetError
        When one evaluation would exceed the memory or step budget.
    """
    path = Path(name_or_path)
    if path.suffix != ".toml" and "/" not in str(name_or_path) and not path.exists():
        names = builtin_tunings()
        if str(name_or_path) not in names:
            raise TuneError(f"no built-in tuning named '{name_or_path}'; built-in: {names} (or give a .toml path)")
        text = (resources.files("analysis.tune") / "tunings" / f"{name_or_path}.toml").read_text(encoding="utf-8")
        source, folder = str(name_or_path), None
    else:
        from analysis.jobs.files import read_job_file
        text = read_job_file(path, TuneError, "tuning file")  # a regular file of at most 1 MiB (not a FIFO)
        source, folder = str(path), path.parent
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise TuneError(f"{source}: not valid TOML: {err}") from None
    return tuning_from_dict(data, source=source, folder=folder, budget=budget)


def _positive(v) -> bool:
    """A number > 0 or a non-empty list of numbers > 0."""
    return (number(v) and v > 0) or (isinstance(v, list) and bool(v) and numbers(v, len(v)) and min(v) > 0)


#: The settings of a tuning file by table (None: the top level); gain bounds in [search] are checked apart.
_KEYS: dict[str | None, dict[str, Key]] = {
    None: {"name": Key(lambda v: isinstance(v, str), "a plain file name"),
           "description": Key(lambda v: isinstance(v, str), "a string", ""),
           "scenario": Key(lambda v: isinstance(v, str), "a built-in scenario name or a file path", "paper"),
           "objective": Key(lambda v: v in OBJECTIVES, f"one of {list(OBJECTIVES)}", "worst"),
           "metric": Key(lambda v: v in TUNE_METRICS, f"one of {list(TUNE_METRICS)}", TUNE_METRICS[0]),
           "search": Key(lambda v: isinstance(v, dict), "a table ([search])", {}),
           "constraints": Key(lambda v: isinstance(v, dict), "a table ([constraints])", {}),
           "monte_carlo": Key(lambda v: isinstance(v, dict), "a table ([monte_carlo])", {})},
    "search": {"seed": Key(whole(0), "a whole number >= 0", 1),
               "population": Key(whole(5), "a whole number >= 5", 12),
               "max_evaluations": Key(whole(1), "a whole number >= 1", 400),
               "polish_evaluations": Key(whole(0), "a whole number >= 0")},
    "constraints": {
        # per joint of the base scenario's arm: sized and worded for it by _constraint_keys
        "torque_noise_rms": Key(lambda v: v == "base" or _positive(v), '"base", a number > 0 or one number > 0 per joint'),
        "torque_limit": Key(_positive, "a number > 0 or one number > 0 per joint"),
        "stability_margin": Key(lambda v: number(v) and v >= 0, "a number >= 0 (1/s)"),
        "min_damping_ratio": Key(lambda v: number(v) and 0 <= v <= 10,
                                  f"a number from 0 (not constrained) to 10 (default {DEFAULT_MIN_DAMPING})"),
        "max_overshoot": Key(lambda v: number(v) and 0 < v < 1, "a fraction between 0 and 1 (0.05 = 5 %)"),
        "min_observer_bandwidth_ratio": Key(lambda v: number(v) and v > 0, "a number > 0"),
        "sampled_margin": Key(lambda v: number(v) and 0 <= v < 1,
                              f"a fraction from 0 (not constrained) to below 1 (default {DEFAULT_SAMPLED_MARGIN} with "
                              "a [controller])"),
        "sensor_noise": Key(lambda v: isinstance(v, dict), "a table {q_std = [...], dq_std = [...], sample_period}")},
}
_NOISE_KEYS = ("q_std", "dq_std", "sample_period")


def _one_per_joint(base: Scenario, what: str = "numbers > 0", units: tuple[str, ...] | None = None) -> str:
    """How a message asks for one value per joint of the base scenario's arm: ``"4 numbers > 0 (N m, N m, N, N m)"``
    for the paper's arm (its messages as they were), with the arm's name and joints for any other arm."""
    joints = base.robot.joints
    units = joints.force_units if units is None else units
    words = f"{joints.count} {what} ({', '.join(units)})"
    if base.robot.paper is not None:
        return words
    return f"{words}, one per joint of the arm {base.arm_name!r} ({', '.join(joints.names)})"


def _force_units(base: Scenario) -> str:
    """The base arm's force units for a message: ``"N m"`` for the paper's arm (as it was), else one per joint."""
    return "N m" if base.robot.paper is not None else ", ".join(base.robot.joints.force_units)


def _constraint_keys(base: Scenario) -> dict:
    """:data:`_KEYS` with the per-joint constraints sized and worded for the base scenario's arm."""
    n = base.robot.joints.count
    per_joint = _one_per_joint(base)
    keys = dict(_KEYS["constraints"])
    keys["torque_noise_rms"] = Key(lambda v: v == "base" or (number(v) and v > 0) or (numbers(v, n) and min(v) > 0),
                                   f'"base", a number > 0 or {per_joint}')
    keys["torque_limit"] = Key(lambda v: (number(v) and v > 0) or (numbers(v, n) and min(v) > 0),
                               f"a number > 0 or {per_joint}")
    return _KEYS | {"constraints": keys}


def _read(table: dict, section: str | None, fail, skip: Callable[[str], bool] = lambda k: False,
          keys: dict | None = None) -> dict:
    """The keys of one table checked against ``keys`` (default :data:`_KEYS`; :func:`analysis.jobs.keys.read_table`)."""
    also = f" and the gains {list(TUNABLE)} with their bounds" if section == "search" else ""
    return read_table(table, _KEYS if keys is None else keys, section, fail, skip=skip, also=also)


def tuning_from_dict(data: dict, source: str = "<dict>", folder: Path | None = None,
                     budget: Budget | None = None) -> TuneSpec:
    """Validate a tuning given as a dictionary (the parsed TOML); see :func:`load_tuning`."""

    fail = failing(TuneError, source)
    budget = Budget.from_env() if budget is None else budget
    top = read_top(data, _KEYS, "tuning", fail)
    name = top["name"] if top["name"] is not None else (Path(source).stem if source.endswith(".toml") else source)
    try:
        check_name(name, "'name'" if top["name"] is not None else "the tuning file's name")
    except SweepError as err:
        fail(str(err))
    search = _read(top["search"], "search", fail, skip=lambda k: "." in k)
    base, records, draws = _the_set(top, name, source, folder, budget, fail)
    if base.observer_variant != "correct":
        fail(f"the scenario's observer.variant is {base.observer_variant!r}; tuning needs the correct observer "
             "(its constraints use the correct observer's linearization)")
    parameters = _parameters({k: v for k, v in top["search"].items() if "." in k}, base, fail)
    drawn = [k for k in draws.get("distributions", {}) if parse_key(k)[0] == "gains" and
             f"gains.{parse_key(k)[1]}" in {p.key for p in parameters}]
    if drawn:
        fail(f"monte_carlo.distributions.\"{drawn[0]}\" draws a gain that [search] tunes; tune it or draw it")
    limits = _limits(_read(top["constraints"], "constraints", fail, keys=_constraint_keys(base)), base, fail)
    max_ev = search["max_evaluations"]
    polish = search["polish_evaluations"]
    if polish is None:
        polish = min(100, max_ev // 5)
    _check_evaluations(max_ev, polish, search["population"], fail)
    t_end = base.simulation.t_final
    times = np.linspace(0.0, t_end, STABILITY_CONFIGURATIONS)
    configurations = np.array([np.asarray(base.trajectory.evaluate(t)[0], dtype=float) for t in times])
    spec = TuneSpec(name=name, source=source, description=top["description"], base=base,
                    objective=top["objective"], metric=top["metric"], parameters=parameters, seed=search["seed"],
                    population=search["population"], max_evaluations=max_ev, polish_evaluations=polish,
                    limits=limits, records=records, draws=draws, hold=configurations[0].copy(),
                    configurations=configurations, budget=budget)
    spec.definition = _hash(spec._decisive() | {"scenario_data": spec.base.data})
    return spec


def with_evaluations(spec: TuneSpec, max_evaluations: int) -> TuneSpec:
    """The tuning with another evaluation budget (not part of its definition: a larger one continues it).

    Raises
    ------
    TuneError
        When the budget leaves differential evolution fewer than two generations after the polish's share.
    """
    if isinstance(max_evaluations, bool) or not isinstance(max_evaluations, int) or max_evaluations < 1:
        raise TuneError(f"max_evaluations must be a whole number >= 1, got {max_evaluations!r}")
    fail = failing(TuneError, spec.source)
    _check_evaluations(max_evaluations, spec.polish_evaluations, spec.population, fail)
    return dataclasses.replace(spec, max_evaluations=max_evaluations)


def _check_evaluations(max_ev: int, polish: int, population: int, fail) -> None:
    if polish > max_ev:
        fail(f"'search.polish_evaluations' ({polish}) must not exceed 'search.max_evaluations' ({max_ev})")
    if max_ev - polish < 2 * population:
        fail(f"'search.max_evaluations' ({max_ev}) leaves {max_ev - polish} evaluations for differential evolution "
             f"after the polish's {polish}: fewer than two generations of 'search.population' = {population}; "
             "raise max_evaluations or lower population")


def _the_set(top: dict, name: str, source: str, folder: Path | None, budget: Budget, fail):
    """The base scenario and the set's records, through the sweep's own Monte Carlo validation and draws."""
    mc = top["monte_carlo"]
    if not mc:
        target = top["scenario"]
        if folder is not None and (target.endswith(".toml") or "/" in target) and not Path(target).is_absolute():
            target = str(folder / target)
        try:
            return load_scenario(target), [{}], {}
        except ScenarioError as err:
            fail(f"'scenario': {err}")
    sweep = {"name": name, "scenario": top["scenario"], "monte_carlo": mc, "outputs": {"metrics": [top["metric"]]}}
    try:
        spec = sweep_from_dict(sweep, source=source, folder=folder, budget=budget)
    except SweepError as err:
        raise TuneError(str(err)) from None
    records = []
    for run in spec.runs:
        shared, member = split_changes(run.values)
        if shared:
            key = next(iter(shared))
            fail(f"monte_carlo.distributions.\"{key}\" cannot vary within a batch: every candidate's set runs as one "
                 f"batch, so only per-member keys may be drawn ({', '.join(sorted(BATCH_KEYS))}, and their "
                 "elements)")
        records.append(member)
    draws = {"runs": spec.runs_per_point, "seed": spec.seed,
             "distributions": {k: {"kind": d.kind} | d.params for k, d in spec.distributions.items()}}
    return spec.base, records, draws


def _parameters(bounds: dict, base: Scenario, fail) -> list[Parameter]:
    if not bounds:
        fail(f"[search] names no gain to tune; give bounds for at least one of {list(TUNABLE)}, e.g. "
             "\"gains.kp\" = [50, 1000]")
    out = []
    for key, value in bounds.items():
        label = f"search.\"{key}\""
        if key not in TUNABLE:
            fail(f"{label} is not a tunable gain; tunable: {list(TUNABLE)} (a gain left out keeps the scenario's "
                 "value)")
        bandwidth = base.data["gains"].get("observer_bandwidth")
        if key == "gains.observer" and bandwidth is not None:
            # every candidate would give both and be refused ("variant 0: ... both set the observer gain Y")
            fail(f"{label} tunes Y, which the scenario {base.name!r} sets through 'gains.observer_bandwidth' "
                 f"({bandwidth:g} rad/s, Y = bandwidth x M(q0)); remove that key from the scenario to tune Y "
                 "directly, or leave gains.observer out of [search]")
        n = base.robot.joints.count
        per_joint = isinstance(value, list) and len(value) == n and all(isinstance(v, list) for v in value)
        if isinstance(value, list) and len(value) not in (2, n) and value and all(isinstance(v, list) for v in value):
            fail(f"{label} gives {len(value)} bounds [low, high]; the arm {base.arm_name!r} has {n} joints "
                 f"({', '.join(base.robot.joints.names)}): give one [low, high] for every joint or {n} of them")
        pairs = value if per_joint else [value]
        for j, pair in enumerate(pairs):
            where = f"{label}[{j}]" if per_joint else label
            if not (isinstance(pair, list) and len(pair) == 2 and all(map(number, pair))):
                fail(f"{where} must be bounds [low, high] (two numbers)"
                     + ("" if per_joint else f", or {n} of them [[low, high], ...] for one gain per joint")
                     + f", got {pair!r}")
            low, high = float(pair[0]), float(pair[1])
            if low == high:
                fail(f"{where} = {pair!r} is empty: the low bound must be below the high bound (leave a gain out "
                     "of [search] to keep its value)")
            if low > high:
                fail(f"{where} = {pair!r} is inverted: low {pair[0]!r} > high {pair[1]!r}; write [low, high]")
            if low <= 0:
                fail(f"{where} = {pair!r}: gains are > 0 (the search runs over log10 of the gain)")
            out.append(Parameter(key=key, joint=j if per_joint else None, low=low, high=high))
    return out


def _limits(table: dict, base: Scenario, fail) -> Limits:
    # the default per joint of this arm (the paper's 4 values made a 6-joint arm's noise model 8 entries long)
    noise = dict(base.data["noise"]) if base.noise is not None else default_noise(base.robot.joints)
    given = table["sensor_noise"]
    if given is not None:
        unknown = sorted(set(given) - set(_NOISE_KEYS))
        if unknown:
            fail(f"unknown key(s) {[f'constraints.sensor_noise.{k}' for k in unknown]}; allowed: "
                 f"{', '.join(_NOISE_KEYS)}")
        joints = base.robot.joints
        paper = base.robot.paper is not None          # the paper's arm: its messages as they were
        for k in _NOISE_KEYS:           # the scenario's [noise] values, by its own validator, then the sign
            # (out of a scenario the validator sizes per-joint lists for the RRPR: another arm's are checked below)
            if k in given and (paper or k == "sample_period"):
                scenario_value(f"noise.{k}", given[k], f"constraints.sensor_noise.{k}", fail)
        for k in ("q_std", "dq_std"):
            if k in given and not (numbers(given[k], joints.count) and min(given[k]) >= 0):
                units = joints.position_units if k == "q_std" else joints.velocity_units
                allowed = "4 numbers >= 0" if paper else _one_per_joint(base, "numbers >= 0", units)
                fail(f"'constraints.sensor_noise.{k}' must be {allowed}, got {given[k]!r}")
        if "sample_period" in given and not given["sample_period"] > 0:
            fail(f"'constraints.sensor_noise.sample_period' must be a number > 0 (s), got {given['sample_period']!r}")
        noise.update(given)
    sensor = {"q_std": [float(v) for v in noise["q_std"]], "dq_std": [float(v) for v in noise["dq_std"]],
              "sample_period": float(noise["sample_period"])}
    if table["torque_noise_rms"] is not None and not any(sensor["q_std"] + sensor["dq_std"]):
        fail("'constraints.torque_noise_rms' is given but the sensor noise is zero on every joint; give "
             "constraints.sensor_noise")
    n = base.robot.joints.count
    vector = lambda v: None if v is None else np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()  # noqa: E731
    budget = table["torque_noise_rms"]
    source = "base" if budget == "base" else "given"
    if budget == "base":
        from analysis.tune.linear import torque_noise_rms
        from blocks import inertia
        q0 = np.asarray(base.trajectory.evaluate(0.0)[0], dtype=float)
        budget = torque_noise_rms(inertia(q0, base.robot), inertia(q0, base.nominal), base.kp, base.kd,
                                  base.observer_gain, sensor["q_std"], sensor["dq_std"], sensor["sample_period"])
        if not np.all(np.isfinite(budget)):
            fail("'constraints.torque_noise_rms' = \"base\": the base scenario's own gains do not give a stable "
                 f"held loop, so they set no torque-noise budget; give numbers ({_force_units(base)})")
    if table["max_overshoot"] is not None and table["min_damping_ratio"] is not None:
        fail(f"'constraints.min_damping_ratio' ({table['min_damping_ratio']!r}) and 'constraints.max_overshoot' "
             f"({table['max_overshoot']!r}) state one constraint twice; give one of them")
    if table["max_overshoot"] is not None:
        damping, damping_from = None, "overshoot"
    elif table["min_damping_ratio"] is None:
        damping, damping_from = DEFAULT_MIN_DAMPING, "default"
    else:
        damping = float(table["min_damping_ratio"]) or None
        damping_from = "given" if damping else "off"
    ratio = table["min_observer_bandwidth_ratio"]
    sampled = table["sampled_margin"]
    if sampled is not None and base.controller is None:
        fail(f"'constraints.sampled_margin' ({sampled!r}) needs a scenario with a [controller] (a sampled loop); "
             f"the scenario '{base.name}' has none")
    if base.controller is None:
        sampled, sampled_from = None, "off"
    elif sampled is None:
        sampled, sampled_from = DEFAULT_SAMPLED_MARGIN, "default"
    else:
        sampled_from = "given" if sampled > 0 else "off"
        sampled = float(sampled) if sampled > 0 else None
    return Limits(torque_noise_rms=vector(budget), torque_noise_from=source, torque_limit=vector(table["torque_limit"]),
                  stability_margin=None if table["stability_margin"] is None else float(table["stability_margin"]),
                  sensor_noise=sensor, min_damping_ratio=damping, damping_from=damping_from,
                  max_overshoot=None if table["max_overshoot"] is None else float(table["max_overshoot"]),
                  min_observer_bandwidth_ratio=None if ratio is None else float(ratio), sampled_margin=sampled,
                  sampled_from=sampled_from)
