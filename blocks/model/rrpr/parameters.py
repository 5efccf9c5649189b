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
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from ...arm import ArmModel
from ...joints import JointSpace
from . import dynamics_kernels as _arm_kernels
from . import tool_kernels as _tool_kernels
from .joints import RRPR_JOINTS

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
        # det M > 0 for every theta2 (docs/model.md, "Inertia matrix"):
        # (k1-k3)(k3-k5) - k2^2/4 > 0 at cos(theta2) = +-1
        # together with k4 > 0 and k5 > 0; equivalently M is positive definite everywhere.
        margin = (c.k1 - c.k3) * (c.k3 - c.k5) - c.k2 ** 2 / 4.0
        if c.k3 <= c.k5 or c.k1 <= c.k3 or margin <= 0:
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
