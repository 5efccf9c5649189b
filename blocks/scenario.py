"""Scenario files: one TOML file fully determines a run.

A scenario names the true robot, the nominal model the controller and observer
believe in, the gains, the reference trajectory, the disturbances, the
measurement noise, the initial state and the solver settings.  ``paper`` is
built in and is the default.  Every key is checked: an unknown key or a bad
value raises :class:`ScenarioError` naming the key, the value and what is
allowed, before anything is simulated.

Sections and keys (units in brackets)::

    name, description                      free text
    [robot]          true plant, any of m1..m4 [kg], l1, l2 [m], I1..I4 [kg m^2], g [m/s^2],
                     a1, a2, d1, d4 [m]; Table 1 by default
    [nominal_scale]  per-parameter factor nominal / true (Eq. 3 internal disturbance), same names, 1 by default
    [gains]          kp [1/s^2], kd [1/s]: scalar or 4; observer [kg m^2/s]: scalar, 4 or 4x4
    [observer]       variant = "correct" | "paper-eq16"
    [trajectory]     kind = "laceration" | "joint_sine" and that kind's keys (blocks.trajectory)
    [disturbance]    kind = "paper" | "friction" | "tissue" | a list of them | "none", and their keys
    [noise]          q_std [rad, m], dq_std [rad/s, m/s] (4 each), seed, sample_period [s]
    [initial]        q, dq (4 each; default: on the reference), d_hat (4; default 0)
    [simulation]     t_final [s], output_step [s], rtol, atol, method, max_step [s]
"""
from __future__ import annotations

import copy
import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .disturbances import DISTURBANCE_KINDS, DisturbanceSpec
from .kinematics import UnreachableError
from .noise import MeasurementNoise
from .parameters import ParameterError, RobotParameters
from .gains import OBSERVER_VARIANTS, GainError, validated_gain
from .trajectory import TRAJECTORY_KINDS, JointSine, LacerationPath

__all__ = ["Scenario", "ScenarioError", "SimulationSettings", "load_scenario", "builtin_scenarios",
           "scenario_from_dict", "to_toml"]

SOLVER_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")


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


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario (see the module docstring for the keys).

    Attributes
    ----------
    name : str
    data : dict
        The complete settings, defaults filled in; ``to_toml(data)`` writes a
        file that reproduces this run.
    robot, nominal : RobotParameters
        True plant and nominal model.
    kp, kd : numpy.ndarray
        4x4 diagonal controller gains.
    observer_gain : numpy.ndarray
        4x4 observer gain ``Y``.
    observer_variant : str
    trajectory : LacerationPath or JointSine
    disturbance : DisturbanceSpec
    noise : MeasurementNoise or None
        None when every standard deviation is zero.
    initial : dict
        ``q``, ``dq``, ``d_hat`` as 4-arrays or None (None: on the reference / zero).
    simulation : SimulationSettings
    source : str
        Where the scenario came from (built-in name or file path).
    user_data : dict
        The settings as given, before defaults were filled in; :meth:`replace`
        starts from these so that derived defaults (the path duration follows
        ``simulation.t_final``, the path's skin height follows the tissue
        model's) are derived again.
    """

    name: str
    data: dict
    robot: RobotParameters
    nominal: RobotParameters
    kp: np.ndarray
    kd: np.ndarray
    observer_gain: np.ndarray
    observer_variant: str
    trajectory: Any
    disturbance: DisturbanceSpec
    noise: MeasurementNoise | None
    initial: dict
    simulation: SimulationSettings
    source: str = "<dict>"
    user_data: dict = field(default_factory=dict)

    def __eq__(self, other) -> bool:
        return isinstance(other, Scenario) and self.data == other.data

    __hash__ = None

    def replace(self, **changes) -> "Scenario":
        """A new scenario with some keys changed, validated like a file.

        Each keyword is a section name with a dict of keys to change (merged
        into the keys given so far), or a top-level key with its value.  A
        ``trajectory`` change with a different ``kind`` starts that section
        afresh, since each kind has its own keys.

        Examples
        --------
        >>> s = load_scenario("paper").replace(gains={"kp": 100})
        >>> float(s.kp[0, 0])
        100.0
        >>> load_scenario("paper").replace(simulation={"t_final": 2.0}).trajectory.duration
        2.0
        """
        data = copy.deepcopy(self.user_data)
        for section, values in changes.items():
            old = data.get(section)
            if isinstance(values, dict) and isinstance(old, dict):
                fresh = section == "trajectory" and values.get("kind", old.get("kind")) != old.get("kind")
                data[section] = dict(values) if fresh else {**old, **values}
            else:
                data[section] = copy.deepcopy(values)
        return scenario_from_dict(data, source=self.source)

    def to_toml(self) -> str:
        """The complete scenario as TOML text."""
        return to_toml(self.data)


_SECTIONS = ("robot", "nominal_scale", "gains", "observer", "trajectory", "disturbance", "noise", "initial",
             "simulation")
_TOP_KEYS = ("name", "description") + _SECTIONS
_LACERATION_KEYS = tuple(f.name for f in dataclasses.fields(LacerationPath) if f.name != "params")
_JOINT_SINE_KEYS = tuple(f.name for f in dataclasses.fields(JointSine))
_DISTURBANCE_KEYS = tuple(f.name for f in dataclasses.fields(DisturbanceSpec) if f.name != "kinds")
_DEFAULTS = {
    "disturbance": {f.name: f.default for f in dataclasses.fields(DisturbanceSpec)},
    "laceration": {f.name: f.default for f in dataclasses.fields(LacerationPath) if f.name != "params"},
    "joint_sine": {f.name: f.default for f in dataclasses.fields(JointSine)},
    "noise": {f.name: f.default for f in dataclasses.fields(MeasurementNoise)},
}
# Largest grids a scenario may ask for: beyond these a run would exhaust memory rather than finish.
MAX_OUTPUT_POINTS = 2_000_000
MAX_NOISE_SAMPLES = 20_000_000


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
        raise ScenarioError(f"{source}: not valid TOML: {err}") from None
    return scenario_from_dict(data, source=source)


def _read_source(name_or_path) -> tuple[str, str]:
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists() or "/" in str(name_or_path):
        if not path.is_file():
            raise ScenarioError(f"scenario file '{path}' does not exist")
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except UnicodeDecodeError as err:
            raise ScenarioError(f"scenario file '{path}' is not UTF-8 text (byte {err.start})") from None
    names = builtin_scenarios()
    if str(name_or_path) not in names:
        raise ScenarioError(f"no built-in scenario named '{name_or_path}'; built-in: {names} (or give a .toml path)")
    return (resources.files("blocks") / "scenarios" / f"{name_or_path}.toml").read_text(encoding="utf-8"), \
        str(name_or_path)


def _table(data: dict, key: str, source: str) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ScenarioError(f"{source}: '{key}' must be a table ([{key}]), got {value!r}")
    return dict(value)


def _check_keys(table: dict, allowed, section: str, source: str, note: str = "") -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        where = "at the top level" if section == "top level" else f"in [{section}]{note}"
        names = unknown if section == "top level" else [f"{section}.{k}" for k in unknown]
        raise ScenarioError(f"{source}: unknown key(s) {', '.join(names)}; allowed {where}: {', '.join(allowed)}")


def _number(value, key: str, source: str, lower=None, strict=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{source}: '{key}' must be a finite number, got {value!r}")
    if lower is not None and (value <= lower if strict else value < lower):
        raise ScenarioError(f"{source}: '{key}' must be {'>' if strict else '>='} {lower}, got {value!r}")
    return float(value)


def _vector(value, key: str, source: str, length: int = 4) -> list[float]:
    if not isinstance(value, list) or len(value) != length:
        raise ScenarioError(f"{source}: '{key}' must be a list of {length} numbers, got {value!r}")
    return [_number(v, f"{key}[{i}]", source) for i, v in enumerate(value)]


def scenario_from_dict(data: dict, source: str = "<dict>") -> Scenario:
    """Validate a scenario given as a nested dictionary (the parsed TOML) and fill in defaults."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: a scenario must be a table, got {type(data).__name__}")
    _check_keys(data, _TOP_KEYS, "top level", source)
    name = data.get("name", Path(source).stem if source.endswith(".toml") else source)
    description = data.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str):
            raise ScenarioError(f"{source}: '{key}' must be a string, got {value!r}")
    t = {key: _table(data, key, source) for key in _SECTIONS}
    out: dict[str, Any] = {"name": name, "description": description}

    # robot and nominal model
    names = RobotParameters.names()
    _check_keys(t["robot"], names, "robot", source)
    _check_keys(t["nominal_scale"], names, "nominal_scale", source)
    try:
        robot = RobotParameters(**{k: _number(v, f"robot.{k}", source) for k, v in t["robot"].items()})
    except ParameterError as err:
        raise ScenarioError(f"{source}: [robot] {err}") from None
    scales = {k: _number(v, f"nominal_scale.{k}", source, 0.0, strict=True) for k, v in t["nominal_scale"].items()}
    try:
        nominal = robot.scaled(**scales)
    except ParameterError as err:
        raise ScenarioError(f"{source}: [nominal_scale] gives an impossible nominal model: {err}") from None
    out["robot"] = robot.as_dict()
    out["nominal_scale"] = {k: scales.get(k, 1.0) for k in names}

    # gains and observer
    _check_keys(t["gains"], ("kp", "kd", "observer"), "gains", source)
    gains = {"kp": 180.0, "kd": 36.0, "observer": 10.0} | t["gains"]
    mats = {}
    for key, value in gains.items():
        try:
            mats[key] = validated_gain(_as_array(value, f"gains.{key}", source), key)
        except GainError as err:
            raise ScenarioError(f"{source}: {err}") from None
    out["gains"] = gains
    _check_keys(t["observer"], ("variant",), "observer", source)
    variant = t["observer"].get("variant", "correct")
    if variant not in OBSERVER_VARIANTS:
        raise ScenarioError(f"{source}: 'observer.variant' must be one of {list(OBSERVER_VARIANTS)}, got {variant!r}")
    out["observer"] = {"variant": variant}

    # simulation
    sim_t = t["simulation"]
    _check_keys(sim_t, [f.name for f in dataclasses.fields(SimulationSettings)], "simulation", source)
    sim_kw = {}
    for key in ("t_final", "output_step", "rtol", "atol", "max_step"):
        if key in sim_t:
            sim_kw[key] = _number(sim_t[key], f"simulation.{key}", source, 0.0, strict=True) \
                if not (key == "max_step" and sim_t[key] == math.inf) else math.inf
    if "method" in sim_t:
        if sim_t["method"] not in SOLVER_METHODS:
            raise ScenarioError(f"{source}: 'simulation.method' must be one of {list(SOLVER_METHODS)}, "
                                f"got {sim_t['method']!r}")
        sim_kw["method"] = sim_t["method"]
    simulation = SimulationSettings(**sim_kw)
    if simulation.output_step > simulation.t_final:
        raise ScenarioError(f"{source}: 'simulation.output_step' ({simulation.output_step} s) must not exceed "
                            f"'simulation.t_final' ({simulation.t_final} s)")
    steps = simulation.t_final / simulation.output_step
    if steps > MAX_OUTPUT_POINTS:
        raise ScenarioError(f"{source}: 'simulation.t_final' / 'simulation.output_step' asks for {steps:.3g} output "
                            f"points; at most {MAX_OUTPUT_POINTS:,} are allowed (raise output_step)")
    if abs(steps - round(steps)) > 1e-9 * max(1.0, steps):
        raise ScenarioError(f"{source}: 'simulation.t_final' ({simulation.t_final} s) must be a whole multiple of "
                            f"'simulation.output_step' ({simulation.output_step} s)")
    out["simulation"] = {k: v for k, v in dataclasses.asdict(simulation).items() if v != math.inf}

    # disturbance
    dist_t = t["disturbance"]
    _check_keys(dist_t, ("kind",) + _DISTURBANCE_KEYS, "disturbance", source)
    kind = dist_t.pop("kind", "paper")
    kinds = [kind] if isinstance(kind, str) else kind
    if not isinstance(kinds, list) or not all(isinstance(k, str) for k in kinds):
        raise ScenarioError(f"{source}: 'disturbance.kind' must be a string or a list of strings, got {kind!r}")
    kinds = [k for k in kinds if k != "none"]
    bad = [k for k in kinds if k not in DISTURBANCE_KINDS]
    if bad:
        raise ScenarioError(f"{source}: 'disturbance.kind' has unknown kind(s) {bad}; "
                            f"choose from {list(DISTURBANCE_KINDS)} or 'none'")
    try:
        disturbance = DisturbanceSpec(kinds=tuple(kinds), **{
            k: _as_value(v, f"disturbance.{k}", source, _DEFAULTS["disturbance"][k]) for k, v in dist_t.items()})
    except ScenarioError:
        raise
    except ValueError as err:
        raise ScenarioError(f"{source}: [disturbance] {err}") from None
    dist_data = dataclasses.asdict(disturbance)
    dist_data.pop("kinds")
    out["disturbance"] = {"kind": list(kinds) if kinds else "none"} | {k: _plain(v) for k, v in dist_data.items()}

    # trajectory
    traj_t = t["trajectory"]
    kind = traj_t.pop("kind", "laceration")
    if kind not in TRAJECTORY_KINDS:
        raise ScenarioError(f"{source}: 'trajectory.kind' must be one of {list(TRAJECTORY_KINDS)}, got {kind!r}")
    keys = _LACERATION_KEYS if kind == "laceration" else _JOINT_SINE_KEYS
    _check_keys(traj_t, keys, "trajectory", source, note=f" for kind = {kind!r}")
    kw = {k: _as_value(v, f"trajectory.{k}", source, _DEFAULTS[kind][k]) for k, v in traj_t.items()}
    try:
        if kind == "laceration":
            kw.setdefault("duration", simulation.t_final)
            kw.setdefault("skin_height", disturbance.skin_height)
            trajectory = LacerationPath(params=robot, **kw)
        else:
            trajectory = JointSine(**kw)
    except UnreachableError as err:
        raise ScenarioError(f"{source}: [trajectory] {err}") from None
    except (ValueError, TypeError) as err:
        raise ScenarioError(f"{source}: [trajectory] {err}") from None
    traj_data = {k: _plain(getattr(trajectory, k)) for k in keys}
    out["trajectory"] = {"kind": kind} | traj_data

    # noise
    noise_t = t["noise"]
    _check_keys(noise_t, ("q_std", "dq_std", "seed", "sample_period"), "noise", source)
    noise_kw = {k: _as_value(v, f"noise.{k}", source, _DEFAULTS["noise"][k]) for k, v in noise_t.items()}
    period = noise_kw.get("sample_period", _DEFAULTS["noise"]["sample_period"])
    if isinstance(period, float) and period > 0 and simulation.t_final / period > MAX_NOISE_SAMPLES:
        raise ScenarioError(f"{source}: 'noise.sample_period' ({period} s) asks for "
                            f"{simulation.t_final / period:.3g} noise samples over {simulation.t_final} s; "
                            f"at most {MAX_NOISE_SAMPLES:,} are allowed")
    try:
        noise = MeasurementNoise(t_final=simulation.t_final, **noise_kw)
    except ValueError as err:
        raise ScenarioError(f"{source}: [noise] {err}") from None
    out["noise"] = {k: _plain(getattr(noise, k)) for k in ("q_std", "dq_std", "seed", "sample_period")}

    # initial state
    init_t = t["initial"]
    _check_keys(init_t, ("q", "dq", "d_hat"), "initial", source)
    initial = {k: (np.array(_vector(init_t[k], f"initial.{k}", source)) if k in init_t else None)
               for k in ("q", "dq", "d_hat")}
    out["initial"] = {k: v.tolist() for k, v in initial.items() if v is not None}

    return Scenario(name=name, data=out, robot=robot, nominal=nominal, kp=mats["kp"], kd=mats["kd"],
                    observer_gain=mats["observer"], observer_variant=variant, trajectory=trajectory,
                    disturbance=disturbance, noise=noise if noise.enabled else None, initial=initial,
                    simulation=simulation, source=source, user_data=copy.deepcopy(data))


def _as_array(value, key: str, source: str):
    if isinstance(value, bool) or isinstance(value, str):
        raise ScenarioError(f"{source}: '{key}' must be a number or a list of numbers, got {value!r}")
    if isinstance(value, (int, float)):
        return _number(value, key, source)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ScenarioError(f"{source}: '{key}' must be a number or a (nested) list of numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(f"{source}: '{key}' must be finite, got {value!r}")
    return arr


def _as_value(value, key: str, source: str, default):
    """Check a value against the type of the key's default: text, a whole number, a number or a list of numbers."""
    if isinstance(value, bool):
        raise ScenarioError(f"{source}: '{key}' must not be true/false, got {value!r}")
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ScenarioError(f"{source}: '{key}' must be text, got {value!r}")
        return value
    whole = isinstance(default, int) and not isinstance(default, bool)
    expected = "a whole number" if whole else "a number or a list of numbers" if isinstance(default, tuple) \
        else "a number"
    if isinstance(value, str):
        raise ScenarioError(f"{source}: '{key}' must be {expected}, got the text {value!r}")
    if whole:
        if not isinstance(value, int):
            raise ScenarioError(f"{source}: '{key}' must be a whole number, got {value!r}")
        return value
    if isinstance(value, (int, float)):
        return _number(value, key, source)
    if isinstance(value, list) and isinstance(default, tuple):
        return tuple(_number(v, f"{key}[{i}]", source) for i, v in enumerate(value))
    raise ScenarioError(f"{source}: '{key}' must be {expected}, got {value!r}")


def _plain(value):
    if isinstance(value, (tuple, list, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def to_toml(data: dict) -> str:
    """Write a scenario dictionary (top-level scalars plus one level of tables) as TOML text."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for key, table in data.items():
        if isinstance(table, dict):
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
