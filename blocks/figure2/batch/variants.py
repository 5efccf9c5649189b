"""Variants of a batch: per-member scenario values by dotted key, validated before anything runs.

A member's values are checked one by one with the scenario's own checks
(:func:`~blocks.scenarios.scenario.check_value`, :func:`~blocks.diagram.gains.validated_gain`)
and then combined into the member's model objects, without building a whole
scenario per member; :meth:`Variants.scenario` builds that scenario, through
:meth:`Scenario.with_changes <blocks.scenarios.scenario.Scenario.with_changes>`, when one
member is to be run alone.

Numbers as columns
------------------
When every varied key of a paper-arm batch is one of :data:`COLUMN_KEYS`
(model mismatch, Kp, Kd, the external disturbance's numbers) the values are
checked as whole columns, ``(N,)`` or ``(N, n)`` arrays: the same rules (a
finite number, its sign, one value per joint) and the nominal arm's
positive definite inertia (Eq. 5-7 over all members at once), in about
1 us per member instead of about 0.6 ms.  The members' model objects are
made only when asked for (:attr:`Variants.members` and the arrays beside
it); the compiled batch reads the columns (:mod:`blocks.figure2.batch.rows`).
Whatever these column checks do not pass goes through the member-by-member
checks, which name the member, the key and the value.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from blocks.diagram.gains import GainError, validated_gain
from blocks.model.arm import ArmModel
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.noise import MeasurementNoise
from blocks.scenarios.scenario import Scenario, ScenarioError, check_value, default_arm, load_scenario, parse_key
from blocks.scenarios.scenario_arm import observer_gain_from_bandwidth

__all__ = ["BATCH_KEYS", "COLUMN_KEYS", "SHARED_KEYS", "SHARED_SECTIONS", "Variants", "column_values",
           "shared_reason"]

#: Keys that shape what the members of a batch share, each with the reason.  The reference is evaluated once for
#: the whole batch, and the laceration path is solved for the arm's kinematic lengths and the skin plane; the
#: disturbance kinds choose the plant's terms; the noise sample period and the solver settings set the shared
#: step schedule; a digital controller is not a continuous batch.  Every other key reaches only the numbers of
#: some block's kernels, which a batch stacks per member (:mod:`blocks.figure2.batch.members`).
SHARED_KEYS = {
    **{f"robot.{k}": "the reference path is solved for the arm's kinematic lengths" for k in ("a1", "a2", "d1", "d4")},
    "disturbance.kind": "the disturbance kinds choose the terms the plant evaluates",
    "disturbance.skin_height": "the reference path runs on the skin plane",
    "noise.sample_period": "the noise sample times join the shared step schedule",
    # a URDF arm ([arm]): its structure is the loop's; only the nominal model's mass scale reaches block numbers
    **{f"arm.{k}": "the arm's joints, frames and gravity are the loop's structure, shared by all members"
       for k in ("urdf", "tool_frame", "locked", "locked_values", "gravity")},
}
#: Sections shared whole by the members of a batch.
SHARED_SECTIONS = {"trajectory": "the reference is evaluated once for the whole batch",
                   "simulation": "the members share one step schedule and output grid",
                   "controller": "a batch integrates the continuous loop; a digital controller runs alone",
                   "name": "the batch has one base scenario", "description": "the batch has one base scenario"}


def shared_reason(key: str) -> str | None:
    """Why a dotted key cannot vary within a batch, or None when it may (an element key ``"disturbance.f_r[2]"``
    as its list's key)."""
    section, name, _ = parse_key(key)
    if section in SHARED_SECTIONS:
        return SHARED_SECTIONS[section]
    return SHARED_KEYS.get(f"{section}.{name}")


#: Keys checked as whole columns on an arm whose constants stack per member (the default scenario's; see "Numbers
#: as columns"): key -> (values per member, lower bound, strict): ``"one"`` a number, ``"joints"`` n numbers,
#: ``"one or joints"`` either.
COLUMN_KEYS = {
    **{f"nominal_scale.{k}": ("one", 0.0, True) for k in default_arm().parameter_names()},
    "gains.kp": ("one or joints", 0.0, True), "gains.kd": ("one or joints", 0.0, True),
    "disturbance.f_r": ("joints", None, False), "disturbance.coulomb": ("joints", 0.0, False),
    "disturbance.viscous": ("joints", 0.0, False), "disturbance.friction_velocity": ("one", 0.0, True),
    **{f"disturbance.tissue_{k}": ("one", 0.0, False) for k in ("stiffness", "damping", "drag")},
}
# Attributes made from each member's model objects, on first use when the values were checked as columns
_MADE_PER_MEMBER = ("members", "robots", "nominals", "kp", "kd", "y_diag", "y_full", "extra", "disturbance", "initial")


def _batch_keys() -> frozenset:
    from blocks.scenarios.scenario import _SECTIONS  # the scenario's table of keys, read, never changed
    keys = {f"{section}.{name}" for section, spec in _SECTIONS.items() for name in spec.checks_for("laceration")}
    return frozenset(k for k in keys if shared_reason(k) is None)


#: Dotted scenario keys that may differ between the members of one batch (an element key such as
#: ``"disturbance.f_r[2]"`` may too, when its list's key is here): every key but those that shape the shared
#: part (:data:`SHARED_KEYS`, :data:`SHARED_SECTIONS`), computed from the scenario's keys.
BATCH_KEYS = _batch_keys()


@dataclass(frozen=True)
class _BatchedDisturbance:
    """:class:`DisturbanceSpec` with per-member arrays, (N, n) and (N, 1), for :func:`external_disturbance`."""

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
        :data:`BATCH_KEYS`, or elements of those lists (``"disturbance.f_r[2]"``);
        values are what the scenario file takes there (``"gains.kp"``: a number
        or n, the arm's joint count; ``"disturbance.f_r"``: n numbers; ...).
        For an arm from ``[arm]`` (a URDF arm) ``arm.nominal_mass_scale`` may
        vary, the arm's other keys may not.

    Raises
    ------
    ScenarioError
        Before anything is simulated, on an unknown or non-batchable key or an
        invalid value; the message names the member, the key and the value.
    """

    def __init__(self, base: Scenario | str, records) -> None:
        self.base = base if isinstance(base, Scenario) else load_scenario(base)
        # an arm whose constants stack per member is checked as columns (no model object per member)
        self.columns = column_values(self.base, records) if self.base.robot.stacks_constants else None
        if self.columns is not None:
            self._n = len(next(iter(self.columns.values())))
            return                              # checked as columns; the model objects are made when asked for
        self.records = _as_records(records)
        self._n = len(self.records)
        if not self.records:
            raise ScenarioError("a batch needs at least one variant, got none")
        if self.base.robot.stacks_constants:
            self._build([self._checked(i, rec) for i, rec in enumerate(self.records)])
        else:
            self._build_from_scenarios()

    def __len__(self) -> int:
        return self._n

    def __getattr__(self, name: str):
        # only for what the column checks left unmade (see "Numbers as columns")
        columns = self.__dict__.get("columns")
        if columns is None or name.startswith("__"):
            raise AttributeError(name)
        if name == "records":
            keys = list(columns)
            rows = zip(*(columns[k].tolist() for k in keys))
            self.records = [dict(zip(keys, row)) for row in rows]
            return self.records
        if name == "noises":                    # no noise key is a column key: every member has the base's
            return [self.base.noise] * self._n
        if name in _MADE_PER_MEMBER:
            self._build([self._checked(i, rec) for i, rec in enumerate(self.records)])
            return self.__dict__[name]
        raise AttributeError(name)

    def scenario(self, i: int) -> Scenario:
        """Member ``i`` as a complete scenario, for a single run with :func:`~blocks.figure2.loop.simulate`."""
        return self.base.with_changes(self.records[i])

    # -- validation and stacking ----------------------------------------------------------------
    def _checked(self, i: int, record: dict) -> dict[str, dict]:
        """A member's values by section and key, each checked as the scenario file checks it."""
        try:
            whole = self.base.expand(record)
        except ScenarioError as err:
            raise ScenarioError(f"variant {i}: {err}") from None
        self._refuse_shared(i, whole)
        sections: dict[str, dict] = {}
        for key, value in whole.items():
            section, name, _ = parse_key(key)
            try:
                sections.setdefault(section, {})[name] = validated_gain(value, name, self.base.robot.joints) \
                    if section == "gains" and name != "observer_bandwidth" else check_value(key, value)
            except (ScenarioError, GainError) as err:
                raise ScenarioError(f"variant {i}: {err}") from None
        return sections

    def _refuse_shared(self, i: int, whole: Mapping) -> None:
        bad = sorted(key for key in whole if shared_reason(key) is not None)
        if bad:
            why = "; ".join(f"{key} = {whole[key]!r:.40}: {shared_reason(key)}" for key in bad)
            raise ScenarioError(f"variant {i}: key(s) {bad} cannot vary within a batch ({why}); vary them between "
                                f"batches (a sweep does)")

    def _build_from_scenarios(self) -> None:
        """Members of a scenario whose arm is not the paper's RRPR (an ``[arm]``): each member's model objects
        are those of its own validated scenario (:meth:`Scenario.with_changes`), so every per-joint check, the
        observer gain from ``gains.observer_bandwidth`` and the nominal arm of ``arm.nominal_mass_scale`` are
        made as its single run makes them (the arm is read once and shared; equal records share a scenario)."""
        s = self.base
        memo: dict = {}
        nominals: dict = {}
        fields, ys, extra = [], [], []
        for i, record in enumerate(self.records):
            try:
                whole = s.expand(record)
            except ScenarioError as err:
                raise ScenarioError(f"variant {i}: {err}") from None
            self._refuse_shared(i, whole)
            key = _freeze(record)
            if key not in memo:
                try:
                    memo[key] = s.with_changes(record)
                except ScenarioError as err:
                    raise ScenarioError(f"variant {i}: {err}") from None
            m = memo[key]
            # the arm's structure keys cannot vary: the true arm is the base's own object (also after a
            # scenario crossed a process boundary, where a newly read arm would be another object), and a
            # member with the base's nominal scale has the base's nominal arm
            scale = m.data["arm"].get("nominal_mass_scale")
            nominal = s.nominal if scale == s.data["arm"].get("nominal_mass_scale") else \
                nominals.setdefault(scale, m.nominal)
            fields.append({"robot": s.robot, "nominal": nominal, "kp": m.kp, "kd": m.kd,
                           "observer_gain": m.observer_gain, "observer_variant": m.observer_variant,
                           "disturbance": m.disturbance, "noise": m.noise, "initial": m.initial})
            ys.append(np.asarray(m.observer_gain, dtype=float))
            extra.append(1.0 if m.observer_variant == "paper-eq16" else 0.0)
        self._stack(fields, ys, extra)

    def _stack(self, fields: list[dict], ys: list, extra: list) -> None:
        """The members' model objects (:attr:`members`) and their numbers over a trailing member axis."""
        s = self.base
        specs = [f["disturbance"] for f in fields]
        self.robots, self.nominals = [f["robot"] for f in fields], [f["nominal"] for f in fields]
        #: Each member's model objects by the name of the :class:`~blocks.scenarios.scenario.Scenario` field they replace.
        self.members = fields
        self.kp = np.array([np.diag(f["kp"]) for f in fields]).T                 # (n, N), 1/s^2
        self.kd = np.array([np.diag(f["kd"]) for f in fields]).T                 # (n, N), 1/s
        Y = np.array(ys)                                                     # (N, n, n)
        self.y_diag = Y.diagonal(axis1=1, axis2=2).T.copy() if not np.any(Y - _diag_part(Y)) else None
        self.y_full = None if self.y_diag is not None else np.moveaxis(Y, 0, -1).copy()   # (n, n, N)
        self.extra = np.array(extra)
        self.disturbance = _BatchedDisturbance(
            kinds=s.disturbance.kinds, f_r=np.array([sp.f_r for sp in specs]),
            coulomb=np.array([sp.coulomb for sp in specs]), viscous=np.array([sp.viscous for sp in specs]),
            friction_velocity=np.array([[sp.friction_velocity] for sp in specs]), skin_height=s.disturbance.skin_height,
            tissue_stiffness=s.disturbance.tissue_stiffness, tissue_damping=s.disturbance.tissue_damping,
            tissue_drag=s.disturbance.tissue_drag)
        self.noises = [f["noise"] for f in fields]
        self.initial = [f["initial"] for f in fields]

    def _build(self, members: list[dict[str, dict]]) -> None:
        s = self.base
        base_robot, base_scale, base_noise = dict(s.data["robot"]), dict(s.data["nominal_scale"]), dict(s.data["noise"])
        robots, nominals, kp, kd, ys, extra, specs, noises, initial, fields = [], [], [], [], [], [], [], [], [], []
        memo: dict = {}
        for i, sec in enumerate(members):
            key = ("robot", _freeze(sec.get("robot")), _freeze(sec.get("nominal_scale")))
            if key not in memo:
                try:
                    robot = s.robot if "robot" not in sec else s.robot.with_parameters(**(base_robot | sec["robot"]))
                    nominal = s.nominal if not (set(sec) & {"robot", "nominal_scale"}) else \
                        robot.scaled(**(base_scale | sec.get("nominal_scale", {})))
                except ValueError as err:          # the arm's own refusal of its parameters
                    raise ScenarioError(f"variant {i}: {err} "
                                        f"(values {_show(self.records[i], ('robot.', 'nominal_scale.'))})") from None
                memo[key] = (robot, nominal)
            robot, nominal = memo[key]
            robots.append(robot)
            nominals.append(nominal)
            gains = sec.get("gains", {})
            kp.append(np.diag(gains.get("kp", s.kp)))
            kd.append(np.diag(gains.get("kd", s.kd)))
            ys.append(self._observer_gain(i, sec, nominal, memo))
            variant = sec.get("observer", {}).get("variant", s.observer_variant)
            extra.append(1.0 if variant == "paper-eq16" else 0.0)
            specs.append(self._spec(sec.get("disturbance"), i, memo))
            noises.append(self._noise(sec.get("noise"), base_noise, i))
            initial.append(dict(s.initial) | {k: np.array(v) for k, v in sec.get("initial", {}).items()})
            fields.append({"robot": robot, "nominal": nominal, "kp": gains.get("kp", s.kp),
                            "kd": gains.get("kd", s.kd), "observer_gain": ys[-1], "observer_variant": variant,
                            "disturbance": specs[-1], "noise": noises[-1], "initial": initial[-1]})
        self._stack(fields, ys, extra)

    def _observer_gain(self, i: int, sec: dict, nominal: ArmModel, memo: dict) -> np.ndarray:
        """Member ``i``'s observer gain ``Y`` as its single run makes it: its own ``gains.observer``, else with
        ``gains.observer_bandwidth`` (the member's or the base's) ``Y = omega M^(q0)`` of the member's nominal
        arm at its start ``q0`` (``initial.q``, else the reference at t = 0), else the base's."""
        s, gains = self.base, sec.get("gains", {})
        given = dict(s.user_data.get("gains", {})) | gains        # the gains the member's scenario file holds
        if "observer" in given and "observer_bandwidth" in given:
            try:                                # the single run's refusal, in its words
                self.scenario(i)
            except ScenarioError as err:
                raise ScenarioError(f"variant {i}: {err}") from None
        if "observer" in gains:
            return gains["observer"]
        omega = given.get("observer_bandwidth")
        q0 = sec.get("initial", {}).get("q", s.initial["q"])
        if omega is None or (nominal is s.nominal and "observer_bandwidth" not in gains and q0 is s.initial["q"]):
            return s.observer_gain
        if q0 is None:
            q0 = np.asarray(s.trajectory.evaluate(0.0)[0], dtype=float)
        key = ("observer", id(nominal), float(omega), tuple(np.ravel(q0)))
        if key not in memo:
            try:
                memo[key] = validated_gain(observer_gain_from_bandwidth(nominal, float(omega), q0), "observer",
                                             nominal.joints)
            except GainError as err:
                raise ScenarioError(f"variant {i}: observer gain from 'gains.observer_bandwidth' = {omega!r}: "
                                    f"{err}") from None
        return memo[key]

    def _spec(self, overrides, i: int, memo: dict) -> DisturbanceSpec:
        base = self.base.disturbance
        if not overrides:
            return base
        key = ("dist", _freeze(overrides))
        if key not in memo:
            try:
                memo[key] = dataclasses.replace(base, **overrides)
            except ValueError as err:
                raise ScenarioError(f"variant {i}: {err}") from None
        return memo[key]

    def _noise(self, overrides, base_noise: dict, i: int) -> MeasurementNoise | None:
        if not overrides:
            return self.base.noise
        settings = base_noise | overrides
        try:
            noise = MeasurementNoise(q_std=tuple(settings["q_std"]), dq_std=tuple(settings["dq_std"]),
                                     seed=settings["seed"], sample_period=settings["sample_period"],
                                     t_final=self.base.simulation.t_final, joints=self.base.robot.joints)
        except ValueError as err:
            raise ScenarioError(f"variant {i}: {err}") from None
        return noise if noise.enabled else None


def column_values(base: Scenario, records) -> dict[str, np.ndarray] | None:
    """The variants of a paper-arm batch as checked columns, key -> (N,) or (N, n) floats, or None when they are
    not all numbers of :data:`COLUMN_KEYS` or do not pass the column checks (then they are checked member by
    member, which names what is wrong).

    The checks are those of the member-by-member path, applied to whole columns: each value a finite number
    (not true/false) of its key's sign, n of them per member where the key takes a list, and the nominal arm of
    every member (the base's nominal scales with the member's) with a positive definite inertia matrix.
    """
    if isinstance(records, Mapping):
        given = dict(records)
        if any(isinstance(v, (str, bytes, Mapping)) or not isinstance(v, (list, tuple, np.ndarray))
               for v in given.values()):
            return None
    elif isinstance(records, (list, tuple)) and records and all(isinstance(r, Mapping) for r in records):
        keys = list(records[0])
        if any(len(r) != len(keys) or any(k not in r for k in keys) for r in records):
            return None
        given = {k: [r[k] for r in records] for k in keys}
    else:
        return None
    if not given or any(key not in COLUMN_KEYS for key in given):
        return None
    n = base.robot.joints.count
    columns, size = {}, None
    for key, values in given.items():
        try:
            arr = np.asarray(values)
        except ValueError:                      # ragged: some members give a number, others a list
            return None
        if arr.dtype.kind not in "iuf" or arr.ndim == 0 or (size is not None and arr.shape[0] != size):
            return None
        size = arr.shape[0]
        arr = arr.astype(float)
        per, lower, strict = COLUMN_KEYS[key]
        shape_ok = (arr.ndim == 1 and per != "joints") or (arr.ndim == 2 and arr.shape[1] == n and per != "one")
        if not shape_ok or not np.all(np.isfinite(arr)):
            return None
        if lower is not None and not np.all(arr > lower if strict else arr >= lower):
            return None
        columns[key] = arr
    if not size:
        return None
    scales = {k.split(".", 1)[1]: columns[k] for k in columns if k.startswith("nominal_scale.")}
    if scales and not _nominal_positive_definite(base, scales):
        return None
    return columns


def nominal_values(base: Scenario, scales: dict) -> dict[str, np.ndarray]:
    """Every member's nominal arm parameters (SI): the true arm's times the member's ``scales`` (N,) where given,
    else the base's nominal scale, as :meth:`~blocks.model.arm.ArmModel.scaled` multiplies them."""
    robot, given = base.robot, dict(base.data.get("nominal_scale", {}))
    values = {}
    for name in robot.parameter_names():
        factor = scales.get(name, given.get(name))
        value = getattr(robot, name)
        values[name] = np.full(len(next(iter(scales.values()))), value) if factor is None else value * factor
    return values


def _nominal_positive_definite(base: Scenario, scales: dict) -> bool:
    """Whether every member's nominal arm -- the base's nominal scales with the member's ``scales`` (N,) --
    has positive, finite parameters and an inertia matrix positive definite for every joint angle, the checks of
    arm's own checks over all members at once (:meth:`~blocks.model.arm.ArmModel.parameters_valid`)."""
    return base.robot.parameters_valid(nominal_values(base, scales))


def _as_records(records) -> list[dict]:
    if isinstance(records, Mapping):
        for k, v in records.items():
            if isinstance(v, Mapping) or not isinstance(v, (list, tuple, np.ndarray)):
                nested = isinstance(v, Mapping) and v
                hint = (f"write dotted keys, {{'{k}.{next(iter(v))}': [...]}}" if nested else
                        "each column is a list with one value per variant, {'gains.kp': [100, 180]}")
                raise ScenarioError(f"variant column {k!r} must be a list of values, got {v!r:.80}; {hint}")
        lengths = {k: len(v) for k, v in records.items()}
        if len(set(lengths.values())) > 1:
            raise ScenarioError(f"variant columns must all have the same length, got {lengths}")
        n = next(iter(lengths.values()), 0)
        return [{str(k): _plain(records[k][i]) for k in records} for i in range(n)]
    if isinstance(records, (str, bytes)) or not isinstance(records, Iterable):
        raise ScenarioError(f"variants must be a mapping of columns ({{'gains.kp': [100, 180]}}) or a list of "
                            f"mappings ([{{'gains.kp': 100}}, ...]), got {type(records).__name__} {records!r:.80}")
    out = []
    for i, rec in enumerate(records):
        if not isinstance(rec, Mapping):
            raise ScenarioError(f"variant {i} must be a mapping of dotted keys to values, got {rec!r}")
        out.append({str(k): _plain(v) for k, v in rec.items()})
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
    """A hashable copy of checked values (for memoising equal settings)."""
    if isinstance(value, Mapping):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(v) for v in value)
    return value


def _show(record: Mapping, prefixes) -> dict:
    return {k: _plain(v) for k, v in record.items() if k.startswith(tuple(prefixes))}


def _diag_part(Y: np.ndarray) -> np.ndarray:
    return Y * np.eye(Y.shape[-1])
