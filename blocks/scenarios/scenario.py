"""Scenario files: one TOML file fully determines a run.

A scenario names the true robot, the nominal model the controller and observer
believe in, the gains, the reference trajectory, the disturbances, the
measurement noise, the initial state and the solver settings.  ``paper`` is
built in and is the default.  Every key is checked: an unknown key or a bad
value raises :class:`ScenarioError` naming the key, the value and what is
allowed, before anything is simulated.

Sections and keys (units in brackets)::

    name, description                      free text
    [arm]            a URDF arm instead of the paper's RRPR (blocks.scenarios.scenario_arm): urdf (relative to the file),
                     tool_frame, locked, locked_values, gravity [m/s^2], nominal_mass_scale; absent: the RRPR
    [robot]          true plant, any of m1..m4 [kg], l1, l2 [m], I1..I4 [kg m^2], g [m/s^2],
                     a1, a2, d1, d4 [m]; Table 1 by default
    [nominal_scale]  per-parameter factor nominal / true (Eq. 3 internal disturbance), same names, 1 by default;
                     for a URDF arm per link: link name = factor (that link's mass and inertia in the nominal model)
    [gains]          kp [1/s^2], kd [1/s]: scalar or n; observer [kg m^2/s]: scalar, n or n x n, or
                     observer_bandwidth [rad/s]: Y = omega M^(q0) (one of the two)
    [observer]       variant = "correct" | "paper-eq16"
    [trajectory]     kind = "laceration" | "joint_sine" | "tool_path" and that kind's keys (blocks.diagram.trajectory,
                     blocks.scenarios.tool_path); a laceration lasts duration [s] (10 by default) whatever
                     simulation.t_final is, and stitches the skin plane disturbance.skin_height [m]
    [disturbance]    kind = "paper" | "friction" | "tissue" | a list of them | "none", and their keys
    [noise]          q_std [rad, m], dq_std [rad/s, m/s] (a number or n each), seed, sample_period [s]
    [initial]        q, dq (n each; default: on the reference), d_hat (n; default 0)
    [simulation]     t_final [s], output_step [s], rtol, atol, method, max_step [s]
    [controller]     the digital controller (blocks.diagram.digital): sample_rate [Hz], delay [samples],
                     observer_discretization, velocity, velocity_cutoff [Hz], position_resolution
                     [rad, m] (a number or n), torque_limit [N m, N] (a number or n); absent: the
                     continuous controller

Each section is read by one entry of the table ``_SECTIONS``: the keys it
allows with the check of each value, and how its object is built from them.
Per-joint lists have one entry per joint of the arm (n = 4 for the RRPR);
``[robot]`` is the RRPR's and refused, by name, for another arm.  For a URDF
arm ``[nominal_scale]`` scales links (``shaft_link = 1.2``; times
``arm.nominal_mass_scale``), and a laceration is its tool point's path by IK
(:class:`~blocks.scenarios.tool_path.ToolLaceration`: ``start``, ``end`` and the skin
plane required; ``sample_period`` as for ``tool_path``; the RRPR's
``needle_roll``, ``roll_offset``, ``elbow`` and ``singularity_margin`` are
not its keys).  The tissue model acts on any arm; for another arm without a
laceration ``disturbance.skin_height`` defaults to the tool height at the
reference's start (written into the scenario's data).

A scenario is varied by dotted keys, validated like a file::

    s = load_scenario("paper").with_changes({"gains.kp": 100, "disturbance.f_r[2]": 1.5})
"""
from __future__ import annotations

import contextvars
import dataclasses
import functools
import json
import math
import os
import re
import stat
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from blocks.diagram.digital import DISCRETIZATIONS, VELOCITY_SOURCES, DigitalController
from blocks.diagram.gains import GAIN_KEYS, OBSERVER_VARIANTS, GainError, validated_gain
from blocks.diagram.trajectory import TRAJECTORY_KINDS, JointSine, check_joint_ranges
from blocks.model.arm import ArmModel
from blocks.model.default import default_arm  # noqa: F401  (a scenario's default arm, also named here)
from blocks.model.disturbances import DISTURBANCE_KINDS, KIND_ALIASES, DisturbanceSpec
from blocks.model.noise import MeasurementNoise
from blocks.model.rrpr.joints import RRPR_JOINTS
from blocks.model.rrpr.laceration import LacerationPath
from blocks.model.rrpr.parameters import ParameterError, RobotParameters
from blocks.model.validation import number_text, read_only_array
from blocks.scenarios.scenario_arm import (
    ARM_KEYS,
    arm_name,
    is_rrpr,
    joint_sine_defaults,
    link_masses,
    link_scaled_nominal,
    load_arm,
    observer_gain_from_bandwidth,
    scaled_nominal,
    skin_height_default,
)
from blocks.scenarios.tool_path import LACERATION_KEYS, ToolLaceration, ToolPath

__all__ = ["Scenario", "ScenarioError", "SimulationSettings", "load_scenario", "builtin_scenarios",
           "scenario_from_dict", "to_toml", "parse_key", "check_value", "default_arm"]



SOLVER_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
# Largest grids a scenario may ask for: beyond these a run would exhaust memory rather than finish.
MAX_OUTPUT_POINTS = 2_000_000
MAX_NOISE_SAMPLES = 2_000_000       # 8 signals x 8 bytes: 128 MB
MAX_SCENARIO_BYTES = 1_000_000
# Shortest phase of a laceration path (s).
MIN_PHASE_DURATION = 1e-3
# Shortest output step and sample spacing (s): below it times lose their meaning in double precision.
MIN_TIME_STEP = 1e-9
# Solver tolerances that mean something: tighter than rounding is noise, looser than 1 % is not a solution.
RTOL_RANGE = (1e-13, 1e-2)
ATOL_RANGE = (1e-15, 1e-2)


class ScenarioError(ValueError):
    """A scenario file or value is invalid; the message names the key."""


@dataclass(frozen=True)
class SimulationSettings:
    """Solver settings.

    Parameters
    ----------
    t_final : float
        Simulated time (s), > 0.
    output_step : float
        Spacing of the uniform output grid (s), > 0 and <= t_final.
    rtol, atol : float
        Relative and absolute tolerances of the ODE solver, > 0.
    method : str
        A :func:`scipy.integrate.solve_ivp` method.
    max_step : float
        Largest solver step (s), > 0; ``inf`` lets the solver choose.
    """

    t_final: float = 10.0
    output_step: float = 0.005
    rtol: float = 1e-6
    atol: float = 1e-8
    method: str = "RK45"
    max_step: float = math.inf

    @property
    def time_grid(self) -> np.ndarray:
        """The uniform output grid ``0, h, 2h, ..., t_final`` (s)."""
        n = int(round(self.t_final / self.output_step))
        return np.linspace(0.0, n * self.output_step, n + 1)


# --------------------------------------------------------------------------------------------
# Read-only values: what a scenario holds cannot be changed through it
# --------------------------------------------------------------------------------------------
class _ReadOnlyDict(dict):
    """A dict that refuses changes.  It is a dict for every reader (``json``, ``==``, ``|``, ``dict(...)``);
    a copy (``copy.deepcopy``, pickling) is a plain, changeable dict."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a scenario's settings are read-only; vary a scenario with Scenario.with_changes")

    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):
        return dict, (dict(self),)


class _ReadOnlyList(list):
    """A list that refuses changes (see :class:`_ReadOnlyDict`)."""

    _refuse = _ReadOnlyDict._refuse
    __setitem__ = __delitem__ = __iadd__ = __imul__ = append = extend = insert = pop = remove = clear = sort = \
        reverse = _refuse

    def __reduce__(self):
        return list, (list(self),)


def _read_only(value):
    """A read-only deep copy of plain settings (dicts, lists, numbers, text)."""
    if isinstance(value, Mapping):
        return _ReadOnlyDict({k: _read_only(v) for k, v in value.items()})
    if isinstance(value, (list, tuple, np.ndarray)):
        return _ReadOnlyList(_read_only(v) for v in value)
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def _read_only_array(value) -> np.ndarray:
    # a copy that cannot be made writable again: neither the caller's array nor setflags changes the scenario
    return read_only_array(value)


def _plain(value):
    """Plain, changeable settings: dicts, lists, Python numbers (numpy values and tuples converted)."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def _same(a, b) -> bool:
    """Equality of field values, arrays by value (``==`` on arrays is elementwise)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape \
            and bool(np.array_equal(a, b))
    if isinstance(a, Mapping) or isinstance(b, Mapping):
        return isinstance(a, Mapping) and isinstance(b, Mapping) and a.keys() == b.keys() \
            and all(_same(a[k], b[k]) for k in a)
    return bool(a == b)


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario (see the module docstring for the keys).

    A scenario cannot be changed: its arrays are read-only and its settings
    (``data``, ``user_data``, ``initial``) refuse writes.  A new scenario is
    made with :meth:`with_changes`.  Two scenarios are equal when every field
    is equal (arrays by value), including ``source`` and ``user_data``, which
    decide how :meth:`with_changes` derives defaults; ``a.data == b.data``
    asks whether two scenarios describe the same run.  Scenarios are hashable
    (the hash follows ``name``, ``source`` and ``data``), so they can be keys.

    Attributes
    ----------
    name : str
    data : dict
        The complete settings, defaults filled in; ``to_toml(data)`` writes a
        file that reproduces this run.
    robot, nominal : ArmModel
        True plant and nominal model (:class:`~blocks.model.rrpr.parameters.RobotParameters` for the paper's RRPR).
    kp, kd : numpy.ndarray
        n x n diagonal controller gains (1/s^2, 1/s).
    observer_gain : numpy.ndarray
        n x n observer gain ``Y`` (kg m^2/s, kg/s on a prismatic joint).
    observer_variant : str
    trajectory : LacerationPath or JointSine
    disturbance : DisturbanceSpec
    noise : MeasurementNoise or None
        None when every standard deviation is zero.
    initial : dict
        ``q``, ``dq``, ``d_hat`` as n-arrays or None (None: on the reference / zero).
    simulation : SimulationSettings
    controller : DigitalController or None
        The digital controller's settings; None for the continuous controller.
    source : str
        Where the scenario came from (built-in name or file path).
    user_data : dict
        The settings as given, before defaults were filled in; :meth:`with_changes`
        starts from these so that derived values (the path's skin plane is
        ``disturbance.skin_height``) are derived again.
    """

    name: str
    data: dict
    robot: ArmModel
    nominal: ArmModel
    kp: np.ndarray
    kd: np.ndarray
    observer_gain: np.ndarray
    observer_variant: str
    trajectory: Any
    disturbance: DisturbanceSpec
    noise: MeasurementNoise | None
    initial: dict
    simulation: SimulationSettings
    controller: DigitalController | None = None
    source: str = "<dict>"
    user_data: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "observer_gain"):
            object.__setattr__(self, name, _read_only_array(getattr(self, name)))
        object.__setattr__(self, "initial", _ReadOnlyDict(
            {k: None if v is None else _read_only_array(v) for k, v in self.initial.items()}))
        object.__setattr__(self, "data", _read_only(self.data))
        object.__setattr__(self, "user_data", _read_only(self.user_data))

    def __eq__(self, other) -> bool:
        if not isinstance(other, Scenario):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in dataclasses.fields(self))

    def __hash__(self) -> int:
        # equal scenarios have equal data, name and source, so equal hashes
        return hash((self.name, self.source, json.dumps(self.data, sort_keys=True)))

    def __reduce__(self):
        # through the constructor, so that a copy or an unpickled scenario is read-only too
        return Scenario, tuple(getattr(self, f.name) for f in dataclasses.fields(self))

    def with_changes(self, changes: Mapping[str, Any]) -> Scenario:
        """A new scenario with some values changed by dotted key, validated like a file.

        Parameters
        ----------
        changes : mapping
            ``"section.key"`` -> value as the file takes it (``"gains.kp": 100``,
            ``"nominal_scale.m1": 1.2``), ``"section.key[i]"`` -> one element of
            a list (``"disturbance.f_r[2]": 1.5``), or ``"name"`` /
            ``"description"`` -> text.  Applied in order.  Defaults that
            follow other keys are derived again (the laceration path's skin
            plane is ``disturbance.skin_height``); ``simulation.t_final``
            never changes the path: its duration is ``trajectory.duration``
            (10 s by default), a shorter run ends early on the same path and
            a longer one holds its last pose.  A new ``trajectory.kind``
            starts that section afresh, since each kind has its own keys.

        Raises
        ------
        ScenarioError
            Naming the dotted key, on an unknown key or an invalid value.

        Examples
        --------
        >>> s = load_scenario("paper").with_changes({"gains.kp": 100})
        >>> float(s.kp[0, 0])
        100.0
        >>> load_scenario("paper").with_changes({"simulation.t_final": 2.0}).trajectory.duration
        10.0
        >>> load_scenario("paper").with_changes({"disturbance.f_r[2]": 1.5}).disturbance.f_r
        (1.43, 1.6, 1.5, 1.2)
        """
        if not isinstance(changes, Mapping):
            raise ScenarioError(f"{self.source}: changes must be a mapping of dotted keys to values "
                                f"({{'gains.kp': 100}}), got {changes!r}")
        if not changes:
            return self
        try:
            return self._changed(changes)
        except RecursionError:
            raise ScenarioError(f"{self.source}: {_TOO_DEEP}") from None

    def _changed(self, changes: Mapping[str, Any]) -> Scenario:
        try:
            whole = self.expand(changes)
        except ScenarioError as err:
            raise ScenarioError(f"{self.source}: {err}") from None
        data = _plain(self.user_data)
        urdf = data.get("arm", {}).get("urdf")
        if isinstance(urdf, str) and not urdf.startswith("example:") and "arm.urdf" not in whole:
            # the file this scenario read: a relative path given in Python is relative to the working folder of
            # then, not of now (os.chdir between the two made the same scenario's change fail: "does not exist")
            data["arm"]["urdf"] = self.data["arm"]["urdf"]
        if "trajectory.kind" in whole and whole["trajectory.kind"] != self.data["trajectory"]["kind"]:
            data["trajectory"] = {}         # each kind has its own keys
        for key, value in whole.items():
            section, name, _ = parse_key(key)
            if name:
                data.setdefault(section, {})[name] = _plain(value)
            else:
                data[section] = _plain(value)
        if "arm" not in data and not is_rrpr(self.robot):        # an arm given in Python stays
            return scenario_from_dict(data, source=self.source, arm=self.robot, nominal=self.nominal)
        return scenario_from_dict(data, source=self.source)

    @property
    def arm_name(self) -> str:
        """How messages and outputs name the scenario's arm (the URDF file's stem; ``rrpr`` for the paper's)."""
        return arm_name(self.robot, self.data.get("arm", {}).get("urdf"))

    def replace(self, **sections) -> Scenario:
        """:meth:`with_changes` written by section: ``replace(gains={"kp": 100})`` is
        ``with_changes({"gains.kp": 100})``; ``name=`` and ``description=`` set those."""
        changes: dict[str, Any] = {}
        for section, values in sections.items():
            if isinstance(values, Mapping):
                changes.update({f"{section}.{key}": value for key, value in values.items()})
            else:
                changes[section] = values
        return self.with_changes(changes)

    def expand(self, changes: Mapping[str, Any]) -> dict[str, Any]:
        """``changes`` with each element key (``"disturbance.f_r[2]"``) replaced by its whole list,
        taken from this scenario (or from an earlier change of the same list).

        Raises
        ------
        ScenarioError
            On a malformed key, an unknown section, or an element key whose
            value is not a list that long.  Keys within a section are checked
            when the changes are validated.
        """
        out: dict[str, Any] = {}
        for key, value in changes.items():
            section, name, index = parse_key(key)
            full = f"{section}.{name}" if name else section
            if index is None:
                out[full] = value
                continue
            current = _plain(out[full] if full in out else self.data.get(section, {}).get(name))
            if not isinstance(current, list) or index >= len(current):
                what = f"a list of {len(current)}" if isinstance(current, list) else \
                    "not given in this scenario" if current is None else f"{current!r}, not a list"
                raise ScenarioError(f"'{key}' indexes element {index} of '{full}', which is {what}")
            current[index] = value
            out[full] = current
        return out

    def check_key(self, key: str) -> None:
        """Check that a dotted key (``"gains.kp"``, ``"disturbance.f_r[2]"``) names a value of this scenario.

        Raises
        ------
        ScenarioError
            Naming the key and the keys its section has.
        """
        section, name, index = parse_key(key)
        if name:
            kind = self.data["trajectory"]["kind"]
            known = tuple(_arm_checks(section, kind, self.robot) or _SECTIONS[section].checks_for(kind))
            if name not in known:
                raise ScenarioError(f"'{key}' is not a scenario key; keys of [{section}]: {list(known)}")
        if index is not None:
            self.expand({key: 0.0})

    def to_toml(self) -> str:
        """The complete scenario as TOML text."""
        return to_toml(self.data)


# --------------------------------------------------------------------------------------------
# Checks of single values: (value, dotted key) -> the value as the model takes it
# --------------------------------------------------------------------------------------------
Check = Callable[[Any, str], Any]


def _finite(lower: float | None = None, strict: bool = False) -> Check:
    def check(value, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not _finite_float(value):
            raise ScenarioError(f"'{key}' must be a finite number, got {_number_text(value)}")
        if lower is not None and (value <= lower if strict else value < lower):
            raise ScenarioError(f"'{key}' must be {'>' if strict else '>='} {lower}, got {value!r}")
        return float(value)
    return check


_number_text = number_text


def _finite_float(value) -> bool:
    """A number that is finite as a float (an int too large for a float is not)."""
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _in_range(low: float, high: float) -> Check:
    def check(value, key: str) -> float:
        value = _finite(0.0, strict=True)(value, key)
        if not low <= value <= high:
            raise ScenarioError(f"'{key}' must be between {low:g} and {high:g} (a solver tolerance), got {value!r}")
        return value
    return check


def _positive_or_inf(value, key: str) -> float:
    return math.inf if value == math.inf and not isinstance(value, bool) else _finite(0.0, strict=True)(value, key)


def _one_of(options) -> Check:
    def check(value, key: str):
        if not isinstance(value, str) or value not in options:
            raise ScenarioError(f"'{key}' must be one of {list(options)}, got {value!r}")
        return value
    return check


def _vector(length: int) -> Check:
    def check(value, key: str) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise ScenarioError(f"'{key}' must be a list of {length} numbers, got {value!r}")
        return tuple(_finite()(v, f"{key}[{i}]") for i, v in enumerate(value))
    return check


def _like(default) -> Check:
    """The type of the key's default: text, a whole number, a number, or a number or a list of numbers."""
    whole = isinstance(default, int) and not isinstance(default, bool)
    expected = "a whole number" if whole else "a number or a list of numbers" if isinstance(default, tuple) \
        else "a number"

    def check(value, key: str):
        if isinstance(value, bool):
            raise ScenarioError(f"'{key}' must not be true/false, got {value!r}")
        if isinstance(default, str):
            if not isinstance(value, str):
                raise ScenarioError(f"'{key}' must be text, got {value!r}")
            return value
        if isinstance(value, str):
            raise ScenarioError(f"'{key}' must be {expected}, got the text {value!r}")
        if whole:
            if not isinstance(value, int):
                raise ScenarioError(f"'{key}' must be a whole number, got {value!r}")
            return value
        if isinstance(value, (int, float)):
            return _finite()(value, key)
        if isinstance(value, (list, tuple)) and isinstance(default, tuple):
            return tuple(_finite()(v, f"{key}[{i}]") for i, v in enumerate(value))
        raise ScenarioError(f"'{key}' must be {expected}, got {value!r}")
    return check


def _gain(value, key: str):
    """A gain checked by :func:`~blocks.diagram.gains.validated_gain`; kept as given (the file's form) for the settings."""
    ctx = _context()
    try:
        validated_gain(value, key.split(".", 1)[1], ctx.joints, ctx.arm_label)
    except GainError as err:
        raise ScenarioError(str(err)) from None
    return _plain(value)


def _disturbance_kinds(value, key: str) -> tuple[str, ...]:
    kinds = [value] if isinstance(value, str) else value
    if not isinstance(kinds, (list, tuple)) or not all(isinstance(k, str) for k in kinds):
        raise ScenarioError(f"'{key}' must be a string or a list of strings, got {value!r}")
    kinds = [k for k in kinds if k != "none"]
    bad = [k for k in kinds if k not in DISTURBANCE_KINDS and k not in KIND_ALIASES]
    if bad:
        raise ScenarioError(f"'{key}' has unknown kind(s) {bad}; choose from "
                            f"{list(DISTURBANCE_KINDS) + list(KIND_ALIASES)} or 'none'")
    return tuple(kinds)


def _defaults(cls, skip=()) -> dict[str, Any]:
    return {f.name: f.default for f in dataclasses.fields(cls) if f.name not in skip}


# --------------------------------------------------------------------------------------------
# Sections: keys with their checks, and how the section's object and its complete settings are made
# --------------------------------------------------------------------------------------------
GAIN_DEFAULTS = {"kp": 180.0, "kd": 36.0, "observer": 10.0}     # the paper's Kp, Kd and Y = "K3"


# --------------------------------------------------------------------------------------------
# The arm: [arm] (a URDF arm) or the paper's RRPR ([robot], [nominal_scale]); later checks read it
# --------------------------------------------------------------------------------------------
@dataclass
class _ArmContext:
    """What the checks of one scenario being validated know of its arm (the RRPR until [arm] is read)."""

    joints: Any = RRPR_JOINTS
    name: str = "rrpr"
    base: Path | None = None
    given: tuple | None = None          # (robot, nominal) given in Python
    arm: Any = None                     # the true arm, when it is not the RRPR
    nominal: Any = None
    urdf: dict | None = None            # the [arm] section's values as the arm was loaded (a URDF arm)
    skin_given: bool = False            # whether [disturbance] sets skin_height

    @property
    def arm_label(self) -> str | None:
        """The arm's name for messages, None for the paper's RRPR (its messages stay as they were)."""
        return None if self.arm is None else self.name


_ARM_CONTEXT: contextvars.ContextVar = contextvars.ContextVar("scenario_arm")


def _context() -> _ArmContext:
    return _ARM_CONTEXT.get(None) or _ArmContext()


def _text(value, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise ScenarioError(f"'{key}' must be {ARM_KEYS.get(key.split('.')[-1], 'text')}, got {value!r}")
    return value


def _names(value, key: str) -> tuple[str, ...]:
    value = [value] if isinstance(value, str) else value
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) and v for v in value):
        raise ScenarioError(f"'{key}' must be a list of joint names, got {value!r}")
    return tuple(value)


def _numbers(value, key: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)):
        raise ScenarioError(f"'{key}' must be a list of numbers, got {value!r}")
    return tuple(_finite()(v, f"{key}[{i}]") for i, v in enumerate(value))


def _gravity(value, key: str):
    if isinstance(value, (list, tuple)):
        if len(value) != 3:
            raise ScenarioError(f"'{key}' must be a number (m/s^2, along -z) or 3 numbers [gx, gy, gz], got {value!r}")
        return _numbers(value, key)
    return _finite(0.0)(value, key)


def _example_urdf(urdf: str):
    """``example:NAME``: the URDF of an example arm (scope4, or one of example-robot-data's: `dobkit arms`)."""
    from blocks.model.urdf.examples import example_urdf
    return example_urdf(urdf.split(":", 1)[1])


def _example_defaults(values: dict) -> None:
    """An example arm's tool frame and locked joints (its gripper's fingers) where ``[arm]`` gives none."""
    from blocks.model.urdf.examples import example_defaults
    info = example_defaults(values["urdf"].split(":", 1)[1])
    values.setdefault("tool_frame", info.tool_frame)
    if "locked" not in values and info.locked:
        values["locked"] = list(info.locked)


def _build_arm(given: dict, built: dict):
    ctx = _context()
    if not given:
        if ctx.given is None:
            return None, None
        robot, nominal = ctx.given
        ctx.joints, ctx.name, ctx.arm, ctx.nominal = robot.joints, arm_name(robot), robot, nominal
        return robot, None
    if ctx.given is not None:
        raise ScenarioError("[arm] cannot be given with an arm model passed in Python (scenario_from_dict(arm=...))")
    values = dict(given)
    if values["urdf"].startswith("example:") if "urdf" in values else False:
        try:
            _example_defaults(values)
            values["urdf"] = str(_example_urdf(values["urdf"]))
        except (ValueError, ModuleNotFoundError) as err:
            raise ScenarioError(f"'arm.urdf' = {given['urdf']!r}: {err}") from None
    arm, name, resolved = load_arm(values, ctx.base, ScenarioError)
    if "urdf" in given and given["urdf"].startswith("example:"):
        name = given["urdf"].split(":", 1)[1]
    nominal = scaled_nominal(arm, given.get("nominal_mass_scale", 1.0), ScenarioError)
    ctx.joints, ctx.name, ctx.arm, ctx.nominal, ctx.urdf = arm.joints, name, arm, nominal, values
    data = {k: _plain(v) for k, v in given.items()}
    if not given["urdf"].startswith("example:"):
        data["urdf"] = resolved         # the written scenario (scenario.toml of a run) finds the file from anywhere
    data.setdefault("nominal_mass_scale", 1.0)
    return arm, data


def _not_rrpr_section(section: str, given: dict) -> None:
    ctx = _context()
    if given:
        raise ScenarioError(f"[{section}] ({', '.join(f'{section}.{k}' for k in given)}) describes the paper's RRPR; "
                            f"the scenario's arm is {ctx.name!r} ({ctx.joints.count} joints, from [arm]): remove "
                            f"[{section}]" + (" (use 'arm.nominal_mass_scale' for a nominal-model mismatch)"
                                              if section == "nominal_scale" else ""))


def _build_robot(given: dict, built: dict):
    if _context().arm is not None:
        _not_rrpr_section("robot", given)
        return _context().arm, None
    try:
        robot = RobotParameters(**given)
    except ParameterError as err:
        given_text = ", ".join(f"'robot.{k}' = {v!r}" for k, v in given.items())
        raise ScenarioError(f"[robot] ({given_text}) {err}") from None
    return robot, robot.as_dict()


def _build_nominal(given: dict, built: dict):
    ctx = _context()
    if ctx.arm is not None and ctx.urdf is not None:
        if not given:
            return ctx.nominal, None
        # per link of the URDF: each named link's mass and inertia times its factor, then every link's times
        # arm.nominal_mass_scale
        nominal = link_scaled_nominal(ctx.arm, ctx.urdf, ctx.base, given, ScenarioError)
        return scaled_nominal(nominal, ctx.urdf.get("nominal_mass_scale", 1.0), ScenarioError), dict(given)
    if ctx.arm is not None:
        _not_rrpr_section("nominal_scale", given)
        return ctx.nominal, None
    try:
        nominal = built["robot"].scaled(**given)
    except ParameterError as err:
        given_text = ", ".join(f"'nominal_scale.{k}' = {v!r}" for k, v in given.items())
        raise ScenarioError(f"[nominal_scale] ({given_text}) gives an impossible nominal model: {err}") from None
    return nominal, {k: given.get(k, 1.0) for k in RobotParameters.names()}


def _build_gains(given: dict, built: dict):
    ctx = _context()
    if "observer" in given and "observer_bandwidth" in given:
        raise ScenarioError(f"'gains.observer' ({_number_text(given['observer'])}) and 'gains.observer_bandwidth' "
                            f"({given['observer_bandwidth']!r} rad/s) both set the observer gain Y; give one of them")
    gains = GAIN_DEFAULTS | given
    if "observer_bandwidth" in given:          # Y = omega M^(q0) is made once the start q0 is known (_validated)
        del gains["observer"]
    return {k: (validated_gain(v, k, ctx.joints, ctx.arm_label) if k in GAIN_KEYS else v) for k, v in gains.items()}, \
        gains


def _build_observer(given: dict, built: dict):
    variant = given.get("variant", "correct")
    return variant, {"variant": variant}


def _build_simulation(given: dict, built: dict):
    sim = SimulationSettings(**given)
    if sim.output_step < MIN_TIME_STEP:
        raise ScenarioError(f"'simulation.output_step' ({sim.output_step:g} s) must be at least {MIN_TIME_STEP:g} s")
    if sim.output_step > sim.t_final:
        raise ScenarioError(f"'simulation.output_step' ({sim.output_step} s) must not exceed "
                            f"'simulation.t_final' ({sim.t_final} s)")
    steps = sim.t_final / sim.output_step
    if steps > MAX_OUTPUT_POINTS:
        raise ScenarioError(f"'simulation.t_final' / 'simulation.output_step' asks for {steps:.3g} output "
                            f"points; at most {MAX_OUTPUT_POINTS:,} are allowed (raise output_step)")
    if abs(steps - round(steps)) > 1e-9 * max(1.0, steps):
        raise ScenarioError(f"'simulation.t_final' ({sim.t_final} s) must be a whole multiple of "
                            f"'simulation.output_step' ({sim.output_step} s)")
    return sim, {k: v for k, v in dataclasses.asdict(sim).items() if v != math.inf}


def _build_disturbance(given: dict, built: dict):
    ctx = _context()
    # Eq. 4's f_r is the RRPR's four numbers: another arm has no external disturbance unless it is given
    kinds = given.get("kind", ("paper",) if ctx.arm is None else ())
    ctx.skin_given = "skin_height" in given
    lists = {}
    if ctx.arm is not None:             # the per-joint lists not given: zeros of the arm's n (the defaults are the RRPR's)
        lists = {k: (0.0,) * ctx.joints.count for k in ("f_r", "coulomb", "viscous") if k not in given}
        for k in ("f_r", "coulomb", "viscous"):
            value = given.get(k)
            if isinstance(value, tuple) and len(value) != ctx.joints.count:
                raise ScenarioError(f"[disturbance] 'disturbance.{k}' has {len(value)} values; the arm {ctx.name!r} has "
                                    f"{ctx.joints.count} joints ({', '.join(ctx.joints.names)}): give one per joint")
    try:
        spec = DisturbanceSpec(kinds=kinds, **lists, **{k: v for k, v in given.items() if k != "kind"})
        spec.check_arm(built["robot"], ctx.name if ctx.arm is not None else None)
    except ValueError as err:
        raise ScenarioError(f"[disturbance] {err}") from None
    per_joint = ("f_r", "coulomb", "viscous")
    values = {f: _plain(getattr(spec, f)) for f in _defaults(DisturbanceSpec, skip=("kinds",))
              if ctx.arm is None or f not in per_joint or f in spec.per_joint() or f in given}
    return spec, {"kind": list(kinds) if kinds else "none"} | values


def _points(value, key: str) -> tuple:
    """Two or more points [x, y, z] (m)."""
    if not isinstance(value, (list, tuple)) or len(value) < 2 or \
            not all(isinstance(p, (list, tuple)) and len(p) == 3 for p in value):
        raise ScenarioError(f"'{key}' must be a list of two or more points [x, y, z] (m), got {value!r}")
    return tuple(tuple(_finite()(v, f"{key}[{i}][{j}]") for j, v in enumerate(p)) for i, p in enumerate(value))


def _build_trajectory(given: dict, built: dict):
    kind = given.get("kind", "joint_sine" if _context().arm is not None else _SECTIONS["trajectory"].default_kind)
    kw = {k: v for k, v in given.items() if k != "kind"}
    ctx = _context()
    if kind == "laceration" and ctx.arm is not None:
        return _arm_laceration(kw, built, ctx)
    if kind == "joint_sine" and ctx.arm is not None:
        kw = joint_sine_defaults(ctx.arm) | kw
        n = ctx.joints.count
        for key in ("amplitude", "offset", "omega"):
            value = kw[key]
            if isinstance(value, (list, tuple)) and len(value) != n:
                raise ScenarioError(f"'trajectory.{key}' has {len(value)} values; the arm {ctx.name!r} has {n} "
                                    f"joints ({', '.join(ctx.joints.names)}): give one per joint")
    if kind == "laceration":
        # the path keeps its own duration (trajectory.duration, 10 s by default): simulation.t_final only
        # says how much of it is simulated, so a shorter run is the start of the same path
        kw["skin_height"] = _skin_height(kw, built["disturbance"])
        _check_phases(kw, built["simulation"])
    try:
        if kind == "laceration":
            trajectory = built["robot"].laceration_path(**kw)       # the arm's own closed form
        elif kind == "tool_path":
            if "waypoints" not in kw:
                raise ScenarioError("'trajectory.waypoints' is required for kind = 'tool_path' (two or more points "
                                    "[x, y, z] of the tool point, m, in the arm's base frame)")
            trajectory = ToolPath(built["robot"], **kw)
        else:
            trajectory = JointSine(**kw)
            _check_sine_ranges(trajectory, built)
    except (ValueError, TypeError) as err:          # UnreachableError is a ValueError
        raise ScenarioError(f"[trajectory] {err}") from None
    # the skin plane is written once, under [disturbance]
    keys = [k for k in _SECTIONS["trajectory"].checks_for(kind) if k not in ("kind", "skin_height")]
    return trajectory, {"kind": kind} | {k: _plain(getattr(trajectory, k)) for k in keys}


def _arm_laceration(kw: dict, built: dict, ctx) -> tuple:
    """The laceration path of an arm other than the RRPR: the tool point's, by IK (:class:`ToolLaceration`).

    Its ends and its skin plane have no default (the RRPR's would be out of the arm's reach): ``trajectory.start``,
    ``trajectory.end`` and ``disturbance.skin_height`` (or ``trajectory.skin_height``, the same plane) are required.
    """
    missing = [f"'trajectory.{k}'" for k in ("start", "end") if k not in kw]
    if missing:
        raise ScenarioError(f"{' and '.join(missing)} required for kind = 'laceration' on the arm {ctx.name!r}: the "
                            "laceration's ends (x, y) in the arm's base frame, m (the defaults are the paper's RRPR's)")
    if ctx.skin_given:
        kw["skin_height"] = _skin_height(kw, built["disturbance"])
    elif "skin_height" not in kw:
        raise ScenarioError(f"the laceration path of the arm {ctx.name!r} needs its skin plane: set "
                            "'disturbance.skin_height' (m, the plane's height in the arm's base frame; the tissue "
                            "contact pushes back from it)")
    _check_phases(kw, built["simulation"])
    try:
        trajectory = ToolLaceration(built["robot"], **kw)
    except (ValueError, TypeError) as err:          # UnreachableError, BudgetError are ValueErrors
        raise ScenarioError(f"[trajectory] {err}") from None
    keys = [k for k in LACERATION_KEYS if k != "skin_height"]
    return trajectory, {"kind": "laceration"} | {k: _plain(getattr(trajectory, k)) for k in keys}


def _check_sine_ranges(sine: JointSine, built: dict) -> None:
    """Refuse joint sines that leave a joint's range within the run: a joint whose sine completes a period
    reaches ``offset +- |amplitude|``; a shorter stretch is sampled (4001 points: a missed peak is below 1e-6 of
    the amplitude)."""
    t_final = built["simulation"].t_final
    q, _, _ = sine.evaluate(np.linspace(0.0, t_final, 4001))
    offset, amplitude = np.array(sine.offset), np.abs(sine.amplitude)
    whole = np.abs(sine.omega) * t_final >= 2 * math.pi
    extremes = np.where(whole, [offset - amplitude, offset + amplitude], offset)
    check_joint_ranges(np.vstack([q, extremes]), built["robot"].joints, "joint sine",
                       "q = trajectory.offset + trajectory.amplitude x sin(trajectory.omega t) over the run")


def _skin_height(path: dict, disturbance: DisturbanceSpec) -> float:
    """The laceration's skin plane (m): ``disturbance.skin_height``, the one source shared with the tissue model.

    ``trajectory.skin_height`` is accepted only when it says the same; a path
    stitching one plane while the tissue pushes back from another is refused.
    """
    skin = disturbance.skin_height
    given = path.get("skin_height", skin)
    if not math.isclose(given, skin, rel_tol=0.0, abs_tol=1e-12):
        raise ScenarioError(f"'trajectory.skin_height' ({given!r} m) disagrees with 'disturbance.skin_height' "
                            f"({skin!r} m): the path and the tissue model share one skin plane; set "
                            "'disturbance.skin_height' only")
    return skin


def _check_phases(path: dict, sim: SimulationSettings) -> None:
    """Refuse a laceration path whose phases (a stitch or a move between stitches) are shorter than
    :data:`MIN_PHASE_DURATION`: no arm sews that fast, and a huge stitch count would only cost memory and time."""
    stitches = path.get("stitches", LacerationPath.stitches)
    if isinstance(stitches, int) and stitches >= 1:
        try:
            phase = path.get("duration", LacerationPath.duration) / (2 * stitches - 1)
        except OverflowError:               # a count beyond any float: phases of no length
            phase = 0.0
        if phase < MIN_PHASE_DURATION:
            raise ScenarioError(f"'trajectory.stitches' = {_number_text(stitches)} makes each of the path's "
                                f"{_number_text(2 * stitches - 1)} phases {phase:.3g} s long, shorter than "
                                f"{MIN_PHASE_DURATION:g} s: use fewer stitches or a longer 'trajectory.duration'")


def _build_noise(given: dict, built: dict):
    ctx = _context()
    t_final = built["simulation"].t_final
    period = given.get("sample_period", MeasurementNoise.sample_period)
    # a list of the wrong length or a negative value is refused by MeasurementNoise, by key
    stds = tuple(np.atleast_1d(given.get("q_std", ()))) + tuple(np.atleast_1d(given.get("dq_std", ())))
    if period > 0 and period < MIN_TIME_STEP:
        raise ScenarioError(f"'noise.sample_period' ({period:g} s) must be at least {MIN_TIME_STEP:g} s")
    if any(v != 0 for v in stds) and period > 0 and t_final / period > MAX_NOISE_SAMPLES:
        raise ScenarioError(f"'noise.sample_period' ({period} s) asks for {t_final / period:.3g} noise samples "
                            f"over {t_final} s; at most {MAX_NOISE_SAMPLES:,} are allowed")
    try:
        noise = MeasurementNoise(t_final=t_final, joints=ctx.joints, **given)
    except ValueError as err:
        raise ScenarioError(f"[noise] {err}{_for_arm(ctx)}") from None
    return (noise if noise.enabled else None), {k: _plain(getattr(noise, k)) for k in _NOISE_KEYS}


def _for_arm(ctx) -> str:
    """`` (arm 'NAME', n joints)`` for messages about another arm than the paper's RRPR (whose stay as they were)."""
    return "" if ctx.arm is None else f" (arm {ctx.name!r}, {ctx.joints.count} joints)"


def _build_controller(given: dict, built: dict):
    if not given:           # absent: the continuous controller, and no [controller] in the settings
        return None, None
    ctx = _context()
    if "sample_rate" not in given:
        raise ScenarioError("'controller.sample_rate' is required in a [controller] section (Hz)")
    try:
        controller = DigitalController(**given, joints=ctx.joints)
    except ValueError as err:
        raise ScenarioError(f"{err}{_for_arm(ctx)}") from None
    values = {k: _plain(getattr(controller, k)) for k in _CONTROLLER_KEYS if getattr(controller, k) is not None}
    return controller, values


def _whole(lower: int) -> Check:
    def check(value, key: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < lower:
            raise ScenarioError(f"'{key}' must be a whole number >= {lower}, got {value!r}")
        return value
    return check


def _joint_vector(value, key: str) -> tuple[float, ...]:
    """One number per joint of the scenario's arm."""
    ctx = _context()
    n = ctx.joints.count
    if isinstance(value, (list, tuple)) and len(value) != n and ctx.name != "rrpr":
        raise ScenarioError(f"'{key}' has {len(value)} values; the arm {ctx.name!r} has {n} joints "
                            f"({', '.join(ctx.joints.names)}): give one per joint")
    return _vector(n)(value, key)


def _joint_setting(value, key: str):
    """A per-joint setting: one number for every joint (kept as given) or one per joint of the scenario's arm."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _finite(0.0)(value, key)
    return _joint_vector(value, key)


def _joint_positions(value, key: str) -> tuple[float, ...]:
    """Joint positions (rad, m) within the joints' ranges (the prismatic joint's stroke)."""
    joints = _context().joints
    q = _joint_vector(value, key)
    for i, (v, (lo, hi)) in enumerate(zip(q, joints.limits)):
        if not lo <= v <= hi:
            unit = joints.position_units[i]
            raise ScenarioError(f"'{key}[{i}]' = {v!r} {unit} is outside the range of joint {joints.names[i]}, "
                                f"{lo:g} to {hi:g} {unit}")
    return q


def _build_initial(given: dict, built: dict):
    return {k: (np.array(given[k]) if k in given else None) for k in _INITIAL_KEYS}, \
        {k: list(v) for k, v in given.items()}


@dataclass(frozen=True)
class _Section:
    """How one ``[section]`` is read: its keys and the check of each value, and how it is built.

    ``build(given, built)`` takes the checked values given (defaults are the
    builder's) and the objects of the sections before it, and returns the
    section's object and its complete settings.  A section with ``by_kind``
    has a ``kind`` key (``default_kind`` when not given) that decides its other keys.
    """

    checks: Mapping[str, Check]
    build: Callable[[dict, dict], tuple[Any, dict]]
    by_kind: Mapping[str, Mapping[str, Check]] = field(default_factory=dict)
    default_kind: str = ""

    def checks_for(self, kind: str | None = None) -> Mapping[str, Check]:
        """The keys allowed (with their checks) for a section of this ``kind``."""
        return dict(self.checks) | dict(self.by_kind.get(kind, {})) if self.by_kind else self.checks


_ROBOT_KEYS = RobotParameters.names()
_NOISE_KEYS = ("q_std", "dq_std", "seed", "sample_period")
_CONTROLLER_KEYS = tuple(f.name for f in dataclasses.fields(DigitalController) if f.name != "joints")
_INITIAL_KEYS = ("q", "dq", "d_hat")

#: The sections in the order they are built (later ones use earlier ones' objects).
_SECTIONS: dict[str, _Section] = {
    "arm": _Section({"urdf": _text, "tool_frame": _text, "locked": _names, "locked_values": _numbers,
                     "gravity": _gravity, "nominal_mass_scale": _finite(0.0, strict=True)}, _build_arm),
    "robot": _Section({k: _finite() for k in _ROBOT_KEYS}, _build_robot),
    "nominal_scale": _Section({k: _finite(0.0, strict=True) for k in _ROBOT_KEYS}, _build_nominal),
    "gains": _Section({k: _gain for k in GAIN_KEYS} | {"observer_bandwidth": _finite(0.0, strict=True)},
                      _build_gains),
    "observer": _Section({"variant": _one_of(OBSERVER_VARIANTS)}, _build_observer),
    "simulation": _Section({"t_final": _finite(0.0, True), "output_step": _finite(0.0, True),
                            "rtol": _in_range(*RTOL_RANGE), "atol": _in_range(*ATOL_RANGE),
                            "method": _one_of(SOLVER_METHODS), "max_step": _positive_or_inf}, _build_simulation),
    "disturbance": _Section({"kind": _disturbance_kinds} | {k: _like(d) for k, d in
                                                            _defaults(DisturbanceSpec, skip=("kinds",)).items()},
                            _build_disturbance),
    "trajectory": _Section({"kind": _one_of(TRAJECTORY_KINDS)}, _build_trajectory, by_kind={
        "laceration": {k: _like(d) for k, d in _defaults(LacerationPath, skip=("params",)).items()},
        "joint_sine": {k: _like(d) for k, d in _defaults(JointSine).items()},
        "tool_path": {"waypoints": _points, "duration": _finite(0.0, True), "sample_period": _finite(0.0, True)}},
        default_kind="laceration"),
    # q_std, dq_std: a number (every joint) or one per joint, as their tuple form says
    "noise": _Section({k: _like((d,) if k.endswith("_std") else d) for k, d in _defaults(MeasurementNoise).items()
                       if k in _NOISE_KEYS},
                      _build_noise),
    "initial": _Section({"q": _joint_positions} | {k: _joint_vector for k in _INITIAL_KEYS[1:]},
                        _build_initial),
    "controller": _Section({"sample_rate": _finite(0.0, strict=True), "delay": _whole(0),
                            "observer_discretization": _one_of(DISCRETIZATIONS), "velocity": _one_of(VELOCITY_SOURCES),
                            "velocity_cutoff": _finite(0.0, strict=True),
                            "position_resolution": _joint_setting,
                            "torque_limit": _joint_setting}, _build_controller),
}
_TOP_KEYS = ("name", "description") + tuple(_SECTIONS)
_KEY = re.compile(r"(?P<section>[A-Za-z_]\w*)(?:\.(?P<name>\w+))?(?:\[(?P<index>\d+)\])?")


@functools.lru_cache(maxsize=4096)       # a batch parses the same few keys for every member
def parse_key(key: str) -> tuple[str, str, int | None]:
    """Split a dotted scenario key: ``"disturbance.f_r[2]"`` -> ``("disturbance", "f_r", 2)``,
    ``"gains.kp"`` -> ``("gains", "kp", None)``, ``"name"`` -> ``("name", "", None)``.

    Raises
    ------
    ScenarioError
        On a key that is not ``section.key``, ``section.key[i]``, ``name`` or
        ``description``, or names an unknown section.
    """
    found = _KEY.fullmatch(key) if isinstance(key, str) else None
    if found is None or (found["name"] is None and (found["section"] not in ("name", "description")
                                                      or found["index"] is not None)):
        raise ScenarioError(f"{key!r} is not a scenario key: write 'section.key' or 'section.key[i]' "
                            f"(sections: {list(_SECTIONS)}), or 'name' / 'description'")
    if found["name"] is not None and found["section"] not in _SECTIONS:
        raise ScenarioError(f"'{key}' is not a scenario key: there is no section [{found['section']}] "
                            f"(sections: {list(_SECTIONS)})")
    index = found["index"]
    return found["section"], found["name"] or "", None if index is None else int(index)


def check_value(key: str, value, trajectory_kind: str = "laceration"):
    """One value checked as a scenario file checks it (type, shape, sign), without the checks across keys.

    Parameters
    ----------
    key : str
        A dotted key ``"section.key"`` (``"gains.kp"``, ``"noise.seed"``).
    value
        The value as a file gives it.
    trajectory_kind : str
        Whose keys ``trajectory.*`` are.

    Returns
    -------
    The value as the model takes it: a float, a tuple of floats, text, a whole
    number; a gain as given (its matrix is :func:`~blocks.diagram.gains.validated_gain`'s).

    Raises
    ------
    ScenarioError
        Naming the key, without a source.
    """
    section, name, index = parse_key(key)
    if not name or index is not None:
        raise ScenarioError(f"'{key}' is not a 'section.key' with a value of its own")
    checks = _SECTIONS[section].checks_for(trajectory_kind)
    if name not in checks:
        raise ScenarioError(f"'{key}' is not a scenario key; keys of [{section}]: {list(checks)}")
    return checks[name](value, key)


def builtin_scenarios() -> list[str]:
    """Names of the scenarios shipped with the toolkit."""
    folder = resources.files("blocks") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_scenario(name_or_path: str | Path = "paper") -> Scenario:
    """Load a built-in scenario by name or a TOML file by path.

    Parameters
    ----------
    name_or_path : str or pathlib.Path
        A built-in name (see :func:`builtin_scenarios`) or a path to a ``.toml`` file.

    Raises
    ------
    ScenarioError
        If the file does not exist, is not valid TOML, or any key or value is invalid.
    """
    text, source = _read_source(name_or_path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        if str(source).lower().endswith(".urdf") or text.lstrip().startswith("<"):
            raise ScenarioError(f"{source} is an XML or URDF file, not a scenario (TOML); a URDF arm is named in a "
                                "scenario's [arm] section: urdf = \"...\", tool_frame = \"...\"") from None
        raise ScenarioError(f"{source}: not valid TOML: {err}") from None
    except RecursionError:              # tomllib reads nested arrays recursively
        raise ScenarioError(f"{source}: {_TOO_DEEP}") from None
    return scenario_from_dict(data, source=source)


def _read_source(name_or_path) -> tuple[str, str]:
    if isinstance(name_or_path, Mapping):
        raise TypeError("a scenario given as a dict is read with blocks.scenario_from_dict(data); load_scenario "
                        "takes a built-in name or the path of a .toml file")
    if not isinstance(name_or_path, (str, Path)):
        raise TypeError(f"a scenario is a Scenario, a built-in name or the path of a .toml file, got "
                        f"{type(name_or_path).__name__} {name_or_path!r}")
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists() or "/" in str(name_or_path):
        if path.is_dir():
            raise ScenarioError(f"'{path}' is a folder, not a scenario file (give the path of a .toml file)")
        if not path.exists():
            raise ScenarioError(f"scenario file '{path}' does not exist")
        raw = _read_bounded(path)
        try:
            # utf-8-sig: a byte-order mark, as some editors write, is not part of the TOML text
            return raw.decode("utf-8-sig"), str(path)
        except UnicodeDecodeError as err:
            raise ScenarioError(f"scenario file '{path}' is not UTF-8 text (byte {err.start})") from None
    names = builtin_scenarios()
    if str(name_or_path) not in names:
        raise ScenarioError(f"no built-in scenario named '{name_or_path}'; built-in: {names} (or give a .toml path)")
    return (resources.files("blocks") / "scenarios" / f"{name_or_path}.toml").read_text(encoding="utf-8"), \
        str(name_or_path)


def _read_bounded(path: Path) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_SCENARIO_BYTES`.

    Opened without blocking and checked on the open file, so that a FIFO (which would wait for a writer) or a
    device (``/dev/zero``, endless) is refused rather than read.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as err:
        raise ScenarioError(f"scenario file '{path}' cannot be read ({err.strerror or err})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ScenarioError(f"scenario file '{path}' is not a regular file (a device, pipe or socket); give the "
                                "path of a .toml file")
        raw = f.read(MAX_SCENARIO_BYTES + 1)
    if len(raw) > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"scenario file '{path}' is {path.stat().st_size:,} bytes; a scenario is a short text "
                            f"file (at most {MAX_SCENARIO_BYTES:,} bytes)")
    return raw


def scenario_from_dict(data: Mapping, source: str = "<dict>", arm: ArmModel | None = None,
                       nominal: ArmModel | None = None) -> Scenario:
    """Validate a scenario given as a nested dictionary (the parsed TOML) and fill in defaults.

    Parameters
    ----------
    data : mapping
        The scenario's sections.
    source : str
        Where it came from (a file path: ``arm.urdf`` is relative to its folder).
    arm, nominal : ArmModel, optional
        An arm model made in Python (instead of ``[arm]``) and the nominal model the controller and observer use
        (default: ``arm`` itself); every per-joint value then has ``arm.n`` entries.

    Raises
    ------
    ScenarioError
        On the first invalid key or value; the message starts with ``source``
        and names the key.
    """
    if arm is not None and not isinstance(arm, ArmModel):
        raise TypeError(f"arm must be an arm model (blocks.model.arm.ArmModel), got {type(arm).__name__} {arm!r:.80}")
    if nominal is not None and (arm is None or not isinstance(nominal, ArmModel) or nominal.kernels is not arm.kernels
                                or nominal.joints != arm.joints):
        raise TypeError("nominal must be an arm model of the same kind and joints as arm (and arm must be given)")
    given = None if arm is None or is_rrpr(arm) and nominal is None and isinstance(arm, RobotParameters) else \
        (arm, arm if nominal is None else nominal)
    base = Path(source).resolve().parent if source.endswith(".toml") else None
    token = _ARM_CONTEXT.set(_ArmContext(base=base, given=given))
    try:
        return _validated(data, source)
    except ScenarioError as err:
        raise ScenarioError(f"{source}: {err}") from None
    except RecursionError:
        raise ScenarioError(f"{source}: {_TOO_DEEP}") from None
    finally:
        _ARM_CONTEXT.reset(token)


_TOO_DEEP = ("a value is nested too deeply (lists within lists hundreds of levels deep); a scenario's values are "
             "numbers, lists of numbers and at most an n x n matrix")


def _validated(data: Mapping, source: str) -> Scenario:
    if not isinstance(data, Mapping):
        raise ScenarioError(f"a scenario must be a table, got {type(data).__name__}")
    _check_keys(data, _TOP_KEYS, "top level")
    name = data.get("name", Path(source).stem if source.endswith(".toml") else source)
    description = data.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str):
            raise ScenarioError(f"'{key}' must be a string, got {value!r}")
    tables = {section: _table(data, section) for section in _SECTIONS}
    built: dict[str, Any] = {}
    out: dict[str, Any] = {"name": name, "description": description}
    for section, spec in _SECTIONS.items():
        table = tables[section]
        default_kind = "joint_sine" if section == "trajectory" and _context().arm is not None else spec.default_kind
        kind = spec.checks["kind"](table.get("kind", default_kind), f"{section}.kind") if spec.by_kind else None
        checks = _arm_checks(section, kind) or spec.checks_for(kind)
        _check_keys(table, checks, section, note=f" for kind = {kind!r}" if kind else "", kind=kind)
        given = {k: checks[k](v, f"{section}.{k}") for k, v in table.items()}
        built[section], out[section] = spec.build(given, built)
        if out[section] is None:            # an optional section that is absent
            del out[section]
    gains = built["gains"]
    _check_nominal_invertible(built, data)
    if "observer_bandwidth" in gains:
        gains["observer"] = _bandwidth_gain(gains["observer_bandwidth"], built)
    if isinstance(built["trajectory"], ToolLaceration):
        # the laceration's skin plane is the tissue's, written once under [disturbance]
        skin = built["trajectory"].skin_height
        built["disturbance"] = dataclasses.replace(built["disturbance"], skin_height=skin)
        out["disturbance"] = dict(out["disturbance"], skin_height=skin)
    elif _context().arm is not None and "skin_height" not in tables["disturbance"] \
            and "tissue" in built["disturbance"].kinds:
        # the default plane is the RRPR's: another arm's skin goes through its tool point at the reference's start
        skin = skin_height_default(built["robot"], built["trajectory"].evaluate(0.0)[0])
        built["disturbance"] = dataclasses.replace(built["disturbance"], skin_height=skin)
        out["disturbance"] = dict(out["disturbance"], skin_height=skin)
    return Scenario(name=name, data=out, robot=built["robot"], nominal=built["nominal_scale"],
                    kp=gains["kp"], kd=gains["kd"], observer_gain=gains["observer"],
                    observer_variant=built["observer"], trajectory=built["trajectory"],
                    disturbance=built["disturbance"], noise=built["noise"], initial=built["initial"],
                    simulation=built["simulation"], controller=built["controller"], source=source,
                    user_data=_plain(data))


def _start(built: dict) -> np.ndarray:
    """The start ``q0``: ``initial.q``, else the reference at t = 0."""
    q0 = built["initial"]["q"]
    return np.asarray(built["trajectory"].evaluate(0.0)[0] if q0 is None else q0, dtype=float)


def _nominal_keys(data: Mapping) -> str:
    arm, scale = data.get("arm"), data.get("nominal_scale")
    keys = [f"'arm.nominal_mass_scale' = {arm['nominal_mass_scale']!r}"] \
        if isinstance(arm, Mapping) and "nominal_mass_scale" in arm else []
    if isinstance(scale, Mapping):
        keys += [f"'nominal_scale.{k}' = {v!r}" for k, v in scale.items()]
    return ", ".join(keys) or "the nominal model's defaults"


def _check_nominal_invertible(built: dict, data: Mapping) -> None:
    """The nominal inertia ``M^(q0)``, which the controller and observer invert, must be invertible in double
    precision: a scale of 1e-320 takes every entry below the smallest normal double (numpy then said only
    "Singular matrix" when the run began)."""
    q0 = _start(built)
    with np.errstate(all="ignore"):
        M = np.asarray(built["nominal_scale"].inertia(q0), dtype=float)
    diagonal = np.diag(M)
    usable = bool(np.all(np.isfinite(M)) and np.all(diagonal >= np.finfo(float).tiny))
    if usable:
        try:
            np.linalg.cholesky(0.5 * (M + M.T))
        except np.linalg.LinAlgError:
            usable = False
    if not usable:
        raise ScenarioError(f"the nominal model's inertia M^(q0) at the start q0 = {number_text(q0.tolist())} "
                            f"(its diagonal {number_text(diagonal.tolist())}) cannot be inverted in double precision; "
                            f"it is set by {_nominal_keys(data)}: give the nominal model's masses as real masses (a "
                            "scale near 1: it is the controller's estimate of the arm)")


def _bandwidth_gain(omega: float, built: dict) -> np.ndarray:
    """``Y = omega M^(q0)`` at the start ``q0`` (``initial.q``, else the reference at t = 0), checked as a gain."""
    q0 = _start(built)
    ctx = _context()
    try:
        return validated_gain(observer_gain_from_bandwidth(built["nominal_scale"], omega, q0), "observer",
                              ctx.joints, ctx.arm_label)
    except GainError as err:    # Y is made from the bandwidth: the key the file sets is the one to name
        raise ScenarioError(f"'gains.observer_bandwidth' = {omega!r} rad/s gives the observer gain Y = omega M^(q0) "
                            f"that is not a usable gain (Y must {str(err).split(' must ', 1)[-1]}); give a bandwidth of a "
                            "few rad/s to a few hundred rad/s") from None


def _arm_checks(section: str, kind: str | None, arm=None) -> dict | None:
    """The keys of a section that depend on the arm (None: the section's own): a laceration's on an arm other
    than the RRPR (:data:`blocks.scenarios.tool_path.LACERATION_KEYS`), a URDF arm's ``[nominal_scale]`` (its links)."""
    ctx = _context()
    arm = ctx.arm if arm is None else arm
    if arm is None or is_rrpr(arm):
        return None
    if section == "trajectory" and kind == "laceration":
        shared = _SECTIONS["trajectory"].checks_for("laceration")
        return {"kind": shared["kind"]} | {k: shared.get(k, _finite(0.0, True)) for k in LACERATION_KEYS}
    if section == "nominal_scale" and getattr(arm, "chain", None) is not None and (ctx.urdf is not None
                                                                                  or ctx.arm is None):
        return {k: _finite(0.0, strict=True) for k in link_masses(arm)}
    return None


def _table(data: Mapping, key: str) -> Mapping:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        raise ScenarioError(f"'{key}' must be a table ([{key}]), got {value!r}")
    return value


#: What the keys of a task-space path mean (docs/tool-path.md), shown with the allowed keys when one is unknown.
KEY_MEANINGS = {("trajectory", "tool_path"): {
    "waypoints": "two or more [x, y, z] positions of the tool point (m, in the arm's base frame)",
    "duration": "time from the first waypoint to the last (s, > 0; the last point is held after it)",
    "sample_period": "time between inverse-kinematics samples (s, > 0; quintic Hermite between them)",
}}


def _check_keys(table: Mapping, allowed, section: str, note: str = "", kind: str | None = None) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        where = "at the top level" if section == "top level" else f"in [{section}]{note}"
        names = unknown if section == "top level" else [f"{section}.{k}" for k in unknown]
        meanings = KEY_MEANINGS.get((section, kind), {})
        listed = ", ".join(f"{k} ({meanings[k]})" if k in meanings else str(k) for k in allowed)
        raise ScenarioError(f"unknown key(s) {', '.join(map(str, names))}; allowed {where}: {listed}")


def to_toml(data: Mapping) -> str:
    """Write a scenario dictionary (top-level scalars plus one level of tables) as TOML text."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, Mapping)]
    for key, table in data.items():
        if isinstance(table, Mapping):
            lines += ["", f"[{key}]"] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


_TOML_ESCAPES = {"\\": "\\\\", '"': '\\"', "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + "".join(_TOML_ESCAPES.get(ch, ch if 0x20 <= ord(ch) != 0x7F else f"\\u{ord(ch):04X}")
                             for ch in value) + '"'
    if isinstance(value, (int, float, np.floating, np.integer)):
        return repr(float(value)) if isinstance(value, (float, np.floating)) else str(int(value))
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")
