"""Variants of a batch: per-member scenario values by dotted key, validated before anything runs."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from collections.abc import Mapping

import numpy as np

from ..disturbances import DisturbanceSpec
from ..noise import MeasurementNoise
from ..parameters import ParameterError, RobotParameters
from ..scenario import Scenario, ScenarioError, load_scenario
from ..gains import OBSERVER_VARIANTS, GainError, validated_gain
from ..joints import RRPR_JOINTS

JOINTS = RRPR_JOINTS.count

__all__ = ["BATCH_KEYS", "Variants"]

_DYNAMIC = ("m1", "m2", "m3", "m4", "l1", "l2", "I1", "I2", "I3", "I4", "g")

#: Dotted scenario keys that may differ between the members of one batch.  The kinematic
#: lengths (a1, a2, d1, d4), the trajectory, the disturbance kinds, tissue contact, the
#: noise sample period and the solver settings shape the shared part and may not.
BATCH_KEYS = frozenset(
    [f"robot.{k}" for k in _DYNAMIC] + [f"nominal_scale.{k}" for k in _DYNAMIC]
    + ["gains.kp", "gains.kd", "gains.observer", "observer.variant",
       "disturbance.f_r", "disturbance.coulomb", "disturbance.viscous", "disturbance.friction_velocity",
       "noise.q_std", "noise.dq_std", "noise.seed", "initial.q", "initial.dq", "initial.d_hat"])


@dataclass(frozen=True)
class _BatchedDisturbance:
    """:class:`DisturbanceSpec` with per-member arrays, (N, 4) and (N, 1), for :func:`external_disturbance`."""

    kinds: tuple
    f_r: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray
    friction_velocity: np.ndarray
    skin_height: float
    tissue_stiffness: float
    tissue_damping: float
    tissue_drag: float


class Variants:
    """N validated variants of a base scenario.

    Parameters
    ----------
    base : Scenario or str
        The shared scenario (or its name/path).
    records : sequence of mappings, or a mapping of sequences
        Either one mapping per member, ``{"gains.kp": 100, "robot.m1": 6.0}``
        (a key left out keeps the base value), or one mapping of columns,
        ``{"gains.kp": [100, 180, 250]}`` (all the same length).  Keys are in
        :data:`BATCH_KEYS`; values are what the scenario file takes there
        (``"gains.kp"``: a number or 4; ``"disturbance.f_r"``: 4 numbers; ...).

    Raises
    ------
    ScenarioError
        Before anything is simulated, on an unknown or non-batchable key or an
        invalid value; the message names the member, the key and the value.
    """

    def __init__(self, base: Scenario | str, records) -> None:
        self.base = base if isinstance(base, Scenario) else load_scenario(base)
        self.records = _as_records(records)
        if not self.records:
            raise ScenarioError("a batch needs at least one variant, got none")
        for i, rec in enumerate(self.records):
            bad = sorted(set(rec) - BATCH_KEYS)
            if bad:
                raise ScenarioError(f"variant {i}: key(s) {bad} cannot vary within a batch; "
                                    f"batchable keys: {sorted(BATCH_KEYS)}")
        self._build()

    def __len__(self) -> int:
        return len(self.records)

    def scenario(self, i: int) -> Scenario:
        """Member ``i`` as a complete scenario, for a single run with :func:`~blocks.loop.simulate`."""
        changes: dict[str, dict] = {}
        for key, value in self.records[i].items():
            section, name = key.split(".", 1)
            changes.setdefault(section, {})[name] = _plain(value)
        return self.base.replace(**changes)

    # -- validation and stacking ----------------------------------------------------------------
    def _build(self) -> None:
        s = self.base
        robots, nominals, kp, kd, ys, extra, specs, noises, initial = [], [], [], [], [], [], [], [], []
        memo: dict = {}
        for i, rec in enumerate(self.records):
            sec = _sections(rec)
            try:
                key = ("robot", _freeze(sec.get("robot")), _freeze(sec.get("nominal_scale")))
                if key not in memo:
                    robot = s.robot if "robot" not in sec else RobotParameters(**(s.data["robot"] | sec["robot"]))
                    nominal = s.nominal if not (set(sec) & {"robot", "nominal_scale"}) else \
                        robot.scaled(**(s.data["nominal_scale"] | sec.get("nominal_scale", {})))
                    memo[key] = (robot, nominal)
                robot, nominal = memo[key]
            except (ParameterError, TypeError) as err:
                raise ScenarioError(f"variant {i}: {err} (values {_show(rec, ('robot.', 'nominal_scale.'))})") from None
            robots.append(robot)
            nominals.append(nominal)
            gains = sec.get("gains", {})
            kp.append(np.diag(_gain(gains.get("kp"), s.kp, "kp", i)))
            kd.append(np.diag(_gain(gains.get("kd"), s.kd, "kd", i)))
            ys.append(_gain(gains.get("observer"), s.observer_gain, "observer", i))
            variant = sec.get("observer", {}).get("variant", s.observer_variant)
            if variant not in OBSERVER_VARIANTS:
                raise ScenarioError(f"variant {i}: 'observer.variant' must be one of {list(OBSERVER_VARIANTS)}, "
                                    f"got {variant!r}")
            extra.append(1.0 if variant == "paper-eq16" else 0.0)
            specs.append(self._spec(sec.get("disturbance"), i, memo))
            noises.append(self._noise(sec.get("noise"), i))
            initial.append(self._initial(sec.get("initial", {}), i))
        self.robots, self.nominals = robots, nominals
        self.kp, self.kd = np.array(kp).T, np.array(kd).T                    # (4, N), 1/s^2 and 1/s
        Y = np.array(ys)                                                     # (N, 4, 4)
        self.y_diag = Y.diagonal(axis1=1, axis2=2).T.copy() if not np.any(Y - _diag_part(Y)) else None
        self.y_full = None if self.y_diag is not None else np.moveaxis(Y, 0, -1).copy()   # (4, 4, N)
        self.extra = np.array(extra)
        self.disturbance = _BatchedDisturbance(
            kinds=s.disturbance.kinds, f_r=np.array([sp.f_r for sp in specs]),
            coulomb=np.array([sp.coulomb for sp in specs]), viscous=np.array([sp.viscous for sp in specs]),
            friction_velocity=np.array([[sp.friction_velocity] for sp in specs]), skin_height=s.disturbance.skin_height,
            tissue_stiffness=s.disturbance.tissue_stiffness, tissue_damping=s.disturbance.tissue_damping,
            tissue_drag=s.disturbance.tissue_drag)
        self.noises = noises
        self.initial = initial

    def _spec(self, overrides, i: int, memo: dict) -> DisturbanceSpec:
        base = self.base.disturbance
        if not overrides:
            return base
        key = ("dist", _freeze(overrides))
        if key not in memo:
            fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(DisturbanceSpec)}
            try:
                memo[key] = DisturbanceSpec(**(fields | {k: _plain(v) for k, v in overrides.items()}))
            except (ValueError, TypeError) as err:
                raise ScenarioError(f"variant {i}: {err}") from None
        return memo[key]

    def _noise(self, overrides, i: int) -> MeasurementNoise | None:
        base = self.base
        if not overrides:
            return base.noise
        settings = dict(base.data["noise"]) | {k: _plain(v) for k, v in overrides.items()}
        try:
            noise = MeasurementNoise(q_std=tuple(settings["q_std"]), dq_std=tuple(settings["dq_std"]),
                                     seed=settings["seed"], sample_period=settings["sample_period"],
                                     t_final=base.simulation.t_final)
        except (ValueError, TypeError) as err:
            raise ScenarioError(f"variant {i}: {err}") from None
        return noise if noise.enabled else None

    def _initial(self, overrides: dict, i: int) -> dict:
        out = dict(self.base.initial)
        for key, value in overrides.items():
            arr = np.asarray(value, dtype=float) if not isinstance(value, (str, bool)) else np.array([])
            if arr.shape != (JOINTS,) or not np.all(np.isfinite(arr)):
                raise ScenarioError(f"variant {i}: 'initial.{key}' must be a list of 4 finite numbers, got {value!r}")
            out[key] = arr
        return out


def _as_records(records) -> list[dict]:
    if isinstance(records, Mapping):
        lengths = {k: len(v) for k, v in records.items()}
        if len(set(lengths.values())) > 1:
            raise ScenarioError(f"variant columns must all have the same length, got {lengths}")
        n = next(iter(lengths.values()), 0)
        return [{str(k): _plain(records[k][i]) for k in records} for i in range(n)]
    out = []
    for i, rec in enumerate(records):
        if not isinstance(rec, Mapping):
            raise ScenarioError(f"variant {i} must be a mapping of dotted keys to values, got {rec!r}")
        out.append({str(k): _plain(v) for k, v in rec.items()})
    return out


def _sections(record: Mapping) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for key, value in record.items():
        section, name = key.split(".", 1)
        out.setdefault(section, {})[name] = value
    return out


def _plain(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


def _freeze(value):
    """A hashable copy of plain values (for memoising equal settings)."""
    if isinstance(value, Mapping):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(v) for v in value)
    return value


def _show(record: Mapping, prefixes) -> dict:
    return {k: _plain(v) for k, v in record.items() if k.startswith(tuple(prefixes))}


def _diag_part(Y: np.ndarray) -> np.ndarray:
    return Y * np.eye(JOINTS)


def _gain(value, default: np.ndarray, name: str, i: int) -> np.ndarray:
    """A member's gain matrix, validated as the scenario validates ``gains.<name>``."""
    if value is None:
        return default
    if isinstance(value, (bool, str)):
        raise ScenarioError(f"variant {i}: 'gains.{name}' must be a number or a list of numbers, got {value!r}")
    try:
        return validated_gain(_plain(value), name)
    except GainError as err:
        raise ScenarioError(f"variant {i}: {err}") from None
