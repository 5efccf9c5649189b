"""Physical parameters of the RRPR surgical arm (paper Table 1) and derived constants.

The inertia constants k1..k5 of the paper (Eq. 5) follow from Table 1.  In the
dynamics, ``l1`` and ``l2`` are the distances to the link centres of mass: the
inertia matrix of Eq. 5 is that of a SCARA whose links are ``2*l1`` and
``2*l2`` long.  The paper's kinematics (Eq. 8) use ``l1`` and ``l2`` as the link
lengths, so the kinematic lengths are separate parameters ``a1`` and ``a2``
whose defaults keep the paper's numbers.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import types
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace
from blocks.model.rrpr import dynamics_kernels as _arm_kernels
from blocks.model.rrpr import tool_kernels as _tool_kernels
from blocks.model.rrpr.joints import RRPR_JOINTS
from blocks.model.validation import _kind

__all__ = ["RobotParameters", "InertiaConstants", "PAPER_PARAMETERS", "ParameterError"]


class ParameterError(ValueError):
    """A robot parameter is missing, non-finite or physically impossible."""


# (unit, must be strictly positive)
_UNITS = {
    "m1": ("kg", True), "m2": ("kg", True), "m3": ("kg", True), "m4": ("kg", True),
    "l1": ("m", True), "l2": ("m", True),
    "I1": ("kg m^2", True), "I2": ("kg m^2", True), "I3": ("kg m^2", True), "I4": ("kg m^2", True),
    "g": ("m/s^2", False),
    "a1": ("m", True), "a2": ("m", True), "d1": ("m", False), "d4": ("m", False),
}


_FD_STEP = 1e-6   # m or rad; the joints other than theta2 (M does not depend on them)

#: Rest pose of the paper's arm (rad, rad, m, rad): see :meth:`RobotParameters.rest_pose`.
REST_POSE = (0.0, math.pi / 2, 0.24, 0.0)

_DESCRIPTIONS = {
    "m1": "mass of link 1", "m2": "mass of link 2", "m3": "mass of link 3", "m4": "mass of link 4",
    "l1": "centre-of-mass distance of link 1 (Eq. 5)", "l2": "centre-of-mass distance of link 2 (Eq. 5)",
    "I1": "inertia of link 1", "I2": "inertia of link 2", "I3": "inertia of link 3", "I4": "inertia of link 4",
    "g": "gravitational acceleration", "a1": "kinematic length of link 1 (Eq. 8)",
    "a2": "kinematic length of link 2 (Eq. 8)", "d1": "height of the joint-2 plane above the base",
    "d4": "tool length below the prismatic stage",
}


@dataclass(frozen=True)
class InertiaConstants:
    """The lumped constants of the paper's Eq. 5-7.

    Attributes
    ----------
    k1, k2, k3, k5 : float
        Inertia constants in kg m^2.
    k4 : float
        Mass of the prismatic stage ``m3 + m4`` in kg.
    g : float
        Gravitational acceleration in m/s^2.
    """

    k1: float
    k2: float
    k3: float
    k4: float
    k5: float
    g: float




def inertia_margins(c) -> list:
    """``M(q)`` positive definite for every theta2 (docs/model.md, "Inertia matrix"), as margins that must all be
    > 0: ``k1 - k3``, ``k3 - k5`` and ``(k1-k3)(k3-k5) - k2^2/4`` (det M > 0 at cos(theta2) = +-1; with k4, k5 > 0
    M is then positive definite everywhere), each with its condition in words.  ``c`` holds k1..k5 as numbers,
    arrays over members or traced symbols."""
    return [(c.k1 - c.k3, "k1 > k3"), (c.k3 - c.k5, "k3 > k5"),
            ((c.k1 - c.k3) * (c.k3 - c.k5) - c.k2 * c.k2 / 4.0, "(k1-k3)(k3-k5) > k2^2/4")]
@dataclass(frozen=True)
class RobotParameters(ArmModel):
    """Masses, lengths and inertias of the arm (paper Table 1), SI units.

    Parameters
    ----------
    m1, m2, m3, m4 : float
        Link masses in kg.
    l1, l2 : float
        Dynamic lengths of links 1 and 2 in m (centre-of-mass distances in Eq. 5).
    I1, I2, I3, I4 : float
        Link moments of inertia about their centroids in kg m^2.
    g : float
        Gravitational acceleration in m/s^2 (0 switches gravity off).
    a1, a2 : float
        Kinematic link lengths in m used by forward/inverse kinematics (Eq. 8).
    d1 : float
        Height of joint 2's plane above the base in m (Table 2 offset of joint 1).
    d4 : float
        Tool length below the prismatic stage in m.

    Attributes
    ----------
    joints : JointSpace
        The arm's joints (count, names, kinds, units): the paper's RRPR arm.
    """

    joints: ClassVar[JointSpace] = RRPR_JOINTS
    kernels: ClassVar = _arm_kernels
    tool_kernels: ClassVar = _tool_kernels
    paper: ClassVar[str] = "Verma, Chauhan & Gupta 2019"
    stacks_constants: ClassVar[bool] = True      # k = [k1..k5, g], one float vector per arm
    constant_gravity: ClassVar[bool] = True      # only d3 carries weight, the same in every pose (Eq. 7)
    inertia_depends_on: ClassVar[tuple[int, ...]] = (1,)     # theta2 alone (Eq. 5)
    held_values: ClassVar[tuple[float, ...]] = (0.3, 1.57, 2.8)     # theta2 (rad): near folded, right angle, stretched

    m1: float = 5.58
    m2: float = 0.689
    m3: float = 0.17
    m4: float = 0.08
    l1: float = 0.5
    l2: float = 0.2
    I1: float = 1.18456
    I2: float = 1.36439
    I3: float = 1.4629
    I4: float = 1.47486
    g: float = 9.8
    a1: float = 0.5
    a2: float = 0.2
    d1: float = 0.12
    d4: float = 0.271

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            unit, positive = _UNITS[f.name]
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ParameterError(f"robot parameter '{f.name}' must be a number in {unit}, got {value!r}")
            if not math.isfinite(value):
                raise ParameterError(f"robot parameter '{f.name}' must be finite, got {value!r} {unit}")
            if positive and value <= 0:
                raise ParameterError(f"robot parameter '{f.name}' must be > 0 {unit}, got {value!r}")
            object.__setattr__(self, f.name, float(value))
        c = self.constants
        if any(not margin > 0 for margin, _ in inertia_margins(c)):
            raise ParameterError(
                "robot parameters give an inertia matrix that is not positive definite for every theta2 "
                f"(k1={c.k1:.6g}, k3={c.k3:.6g}, k5={c.k5:.6g} kg m^2, k2={c.k2:.6g} kg m^2; need "
                "k1 > k3 > k5 and (k1-k3)(k3-k5) > k2^2/4)"
            )

    @functools.cached_property
    def constants(self) -> InertiaConstants:
        """The paper's k1..k5 (Eq. 5-7) from Table 1."""
        m34 = self.m3 + self.m4
        s1 = self.m2 * (self.l2 ** 2 + 4 * self.l1 ** 2)
        s2 = m34 * (4 * self.l1 ** 2 + 4 * self.l2 ** 2)
        k1 = self.I1 + self.I2 + self.I3 + self.I4 + self.m1 * self.l1 ** 2 + s1 + s2
        k2 = 2 * (2 * self.l1 * self.l2 * self.m2 + 4 * self.l1 * self.l2 * m34)
        k3 = self.I2 + self.I3 + self.I4 + self.m2 * self.l2 ** 2 + 4 * self.l2 ** 2 * m34
        return InertiaConstants(k1=k1, k2=k2, k3=k3, k4=m34, k5=self.I4, g=self.g)

    def scaled(self, **scales: float) -> RobotParameters:
        """Return a copy with named parameters multiplied by the given factors.

        Examples
        --------
        >>> RobotParameters().scaled(m1=2.0).m1
        11.16
        """
        unknown = sorted(set(scales) - set(_UNITS))
        if unknown:
            raise ParameterError(f"unknown robot parameter(s) {unknown}; known: {sorted(_UNITS)}")
        for key, factor in scales.items():
            if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor <= 0:
                raise ParameterError(f"scale for robot parameter '{key}' must be a finite number > 0, got {factor!r}")
        return dataclasses.replace(self, **{k: getattr(self, k) * v for k, v in scales.items()})

    def kernel_params(self) -> np.ndarray:
        """``k = [k1, k2, k3, k4, k5, g]`` for the closed-form row kernels of :mod:`blocks.model.rrpr.dynamics_kernels`."""
        return _arm_kernels.arm_constants(self)

    def tool_params(self) -> np.ndarray:
        """``kin = [a1, a2, d1, d4]`` (m) for the tool row kernels of :mod:`blocks.model.rrpr.tool_kernels`."""
        return _tool_kernels.kinematic_lengths(self)

    # -- the arm-model interface's questions (blocks.model.arm.ArmModel) -------------------------------------------------
    @property
    def name(self) -> str:
        """``rrpr``: how messages and output files name the paper's arm."""
        return "rrpr"

    def description(self) -> str:
        """The paper's arm, for reports and the exported FMU's description."""
        return "4-DOF RRPR surgical arm (Verma, Chauhan & Gupta 2019, Eq. 1, 5-7)"

    def in_words(self) -> str:
        """How a sentence names the paper's arm."""
        return "the paper's RRPR arm"

    def closed_form_inertia_partials(self, q) -> np.ndarray:
        """``dM/dq_j`` at each configuration, shape (..., 4, 4, 4) (last-but-two axis: j).

        ``j = 1`` (theta2) is the analytic derivative :func:`~blocks.model.rrpr.dynamics.inertia_derivative_theta2`;
        the other joints use central differences (exactly zero: the inertia depends on theta2 only, but that is
        not assumed).
        """
        from blocks.model.rrpr.dynamics import inertia_derivative_theta2

        q = np.asarray(q, dtype=float)
        parts = []
        for j in range(self.n):
            if j == 1:
                parts.append(inertia_derivative_theta2(q, self))
                continue
            dq = np.zeros(self.n)
            dq[j] = _FD_STEP
            parts.append((self.inertia(q + dq) - self.inertia(q - dq)) / (2 * _FD_STEP))
        return np.stack(parts, axis=-3)

    def rest_pose(self) -> list[float]:
        """The elbow at a right angle (``theta2 = pi/2``, as far as it gets from the singular ``theta2 = 0, pi``
        where the planar Jacobian's determinant ``a1 a2 sin(theta2)`` vanishes) and the tool slide at Table 1's
        ``d3 = 0.24 m`` (rad, rad, m, rad)."""
        return list(REST_POSE)

    def parameter_names(self) -> tuple[str, ...]:
        """Table 1's names (the scenario's ``[robot]`` keys)."""
        return RobotParameters.names()

    def parameter_unit(self, name: str) -> str:
        """SI unit of a Table-1 parameter."""
        if name not in _UNITS:
            raise KeyError(f"rrpr has no parameter {name!r}; it has {list(_UNITS)}")
        return _UNITS[name][0]

    def parameter_positive(self, name: str) -> bool:
        """Whether a Table-1 parameter must be > 0 (all but ``g``, ``d1``, ``d4``)."""
        self.parameter_unit(name)
        return _UNITS[name][1]

    def parameter_description(self, name: str) -> str:
        """What a Table-1 parameter is, in a few words."""
        self.parameter_unit(name)
        return _DESCRIPTIONS[name]

    def calculated_parameters(self) -> tuple[tuple[str, str, str], ...]:
        """The inertia constants k1..k5 of Eq. 5-7, computed from Table 1."""
        return tuple((name, unit, f"inertia constant {name} of Eq. 5-7, from Table 1") for name, unit in
                     (("k1", "kg m^2"), ("k2", "kg m^2"), ("k3", "kg m^2"), ("k4", "kg"), ("k5", "kg m^2")))

    def with_parameters(self, **values: float) -> RobotParameters:
        """A copy with Table-1 parameters replaced (SI values, checked as a new arm is)."""
        unknown = sorted(set(values) - set(_UNITS))
        if unknown:
            raise ParameterError(f"unknown robot parameter(s) {unknown}; known: {sorted(_UNITS)}")
        return dataclasses.replace(self, **values)

    def stacked_kernel_params(self, values: dict) -> np.ndarray:
        """``[k1, k2, k3, k4, k5, g]`` of Eq. 5-7 (rows) for Table 1 values given as numbers or arrays over the
        members (SI), by :attr:`constants`' own operations; shape (6, N)."""
        kernel = self.exported_parameter_map(values)[0]
        return np.array(np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in kernel)))

    def exported_parameter_map(self, values: dict):
        """Table 1 -> ``[k1..k5, g]`` of Eq. 5-7 (:attr:`constants` run on ``values``), the tool lengths
        ``[a1, a2, d1, d4]``, k1..k5 as calculated constants and the margins of ``M(q)`` positive definite for every
        theta2 (docs/model.md, "Inertia matrix"): k1 > k3, k3 > k5, (k1-k3)(k3-k5) > k2^2/4."""
        c = RobotParameters.constants.func(types.SimpleNamespace(**values))
        kernel = [c.k1, c.k2, c.k3, c.k4, c.k5, c.g]
        tool = [values["a1"], values["a2"], values["d1"], values["d4"]]
        calculated = [(name, unit, text, getattr(c, name)) for name, unit, text in self.calculated_parameters()]
        return kernel, tool, calculated, inertia_margins(c)

    def parameters_valid(self, values: dict) -> bool:
        """Whether every member's Table 1 (arrays over the members, SI) is finite, positive where it must be, and
        gives an inertia matrix positive definite for every theta2: the checks of :meth:`__post_init__` over all
        members at once."""
        for name, v in values.items():
            if not np.all(np.isfinite(v)) or (_UNITS[name][1] and not np.all(v > 0)):
                return False
        c = RobotParameters.constants.func(types.SimpleNamespace(**values))       # Eq. 5-7 over the members
        return all(bool(np.all(margin > 0)) for margin, _ in inertia_margins(c))

    def laceration_path(self, **keys):
        """The laceration path's joint references by closed-form IK (:class:`~blocks.model.rrpr.laceration.
        LacerationPath`)."""
        from blocks.model.rrpr.laceration import LacerationPath
        return LacerationPath(params=self, **keys)

    def as_dict(self) -> dict[str, float]:
        """Parameters as a plain dictionary (name -> SI value)."""
        return dataclasses.asdict(self)

    @staticmethod
    def unit(name: str) -> str:
        """SI unit of the named parameter."""
        return _UNITS[name][0]

    @staticmethod
    def names() -> tuple[str, ...]:
        """Names of all parameters, in declaration order."""
        return tuple(f.name for f in fields(RobotParameters))


PAPER_PARAMETERS = RobotParameters()


def robot_parameters(value, name: str = "params") -> RobotParameters:
    """``value`` when it is the arm's :class:`~blocks.model.rrpr.parameters.RobotParameters`.

    Raises
    ------
    TypeError
        Naming the argument and what it got (``blocks.PAPER_PARAMETERS`` is the paper's arm).
    """
    if not isinstance(value, RobotParameters):
        raise TypeError(f"{name} must be the paper's arm, RobotParameters (blocks.PAPER_PARAMETERS is the paper's arm, "
                        f"scenario.robot a scenario's), got {_kind(value)} {value!r:.80}")
    return value
