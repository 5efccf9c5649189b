"""External disturbance models acting on the joints (paper Eq. 2 and 4, and realistic ones beside it).

Each model is a pure function of time and the true joint state returning the
generalised disturbance force ``tau_dis`` (N m for revolute joints, N for the
prismatic joint 3).  A :class:`DisturbanceSpec` names the models that act and
their parameters; the total is their sum.

Models
------
``paper``
    Eq. 4, ``f_r * sgn(2 t + 1)``.  For every ``t >= 0`` this is the constant
    step ``+f_r`` (docs/model.md, "Eq. 4 is a constant step"); it is
    implemented as printed.
``friction``
    Coulomb plus viscous joint friction opposing the joint velocity,
    ``-(F_c tanh(q'/v_s) + F_v q')``.  The sign function is smoothed by
    ``tanh`` with velocity scale ``v_s`` so the right-hand side stays smooth
    for an adaptive ODE solver; below ``|q'| ~ v_s`` friction acts like a
    stiff viscous damper ``F_c / v_s`` instead of sticking.
``tissue``
    Contact with the patient's skin, a horizontal plane at height
    ``skin_height`` (m, base frame).  When the tool tip is below the plane by
    ``p > 0`` the tissue pushes it up with ``F_z = max(0, k p - c z')`` (a
    spring-damper that cannot pull) and drags it in the plane with
    ``F_xy = -c_lat v_xy``.  The task-space force maps to the joints through
    the kinematic Jacobian, ``tau = J^T F``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from .parameters import RobotParameters
from .validation import joint_arrays, real_array, robot_parameters

__all__ = ["DisturbanceSpec", "DISTURBANCE_KINDS", "external_disturbance",
           "paper_disturbance", "friction_disturbance", "tissue_disturbance"]

DISTURBANCE_KINDS = ("paper", "friction", "tissue")

_Vec4 = tuple[float, float, float, float]


@dataclass(frozen=True)
class DisturbanceSpec:
    """Which external disturbances act on the plant, and their parameters.

    Parameters
    ----------
    kinds : tuple of str
        Any of ``"paper"``, ``"friction"``, ``"tissue"``; an empty tuple means no
        external disturbance.  Their torques add up.
    f_r : 4 floats
        Eq. 4 amplitudes (N m, N m, N, N m); paper: ``[1.43, 1.6, 1.4, 1.2]``.
    coulomb : 4 floats
        Coulomb friction levels ``F_c`` (N m, N m, N, N m).
    viscous : 4 floats
        Viscous coefficients ``F_v`` (N m s/rad, N m s/rad, N s/m, N m s/rad).
    friction_velocity : float
        Smoothing velocity ``v_s`` of the Coulomb term (rad/s or m/s), > 0.
    skin_height : float
        Height of the skin plane in the base frame (m).  The default is the
        tool height at ``d3 = 0.24 m`` (Table 1's link-3 offset).
    tissue_stiffness : float
        Normal stiffness of the tissue ``k`` (N/m), >= 0.
    tissue_damping : float
        Normal damping ``c`` (N s/m), >= 0.
    tissue_drag : float
        In-plane viscous drag ``c_lat`` while below the skin (N s/m), >= 0.
    """

    kinds: tuple[str, ...] = ("paper",)
    f_r: _Vec4 = (1.43, 1.6, 1.4, 1.2)
    coulomb: _Vec4 = (0.8, 0.6, 0.5, 0.1)
    viscous: _Vec4 = (0.4, 0.3, 2.0, 0.05)
    friction_velocity: float = 0.01
    skin_height: float = 0.12 - 0.24 - 0.271
    tissue_stiffness: float = 800.0
    tissue_damping: float = 10.0
    tissue_drag: float = 20.0

    def __post_init__(self) -> None:
        kinds = tuple(self.kinds)
        for kind in kinds:
            if kind not in DISTURBANCE_KINDS:
                raise ValueError(f"disturbance kind {kind!r} is unknown; choose from {list(DISTURBANCE_KINDS)}")
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"disturbance kinds {list(kinds)} name a model twice")
        object.__setattr__(self, "kinds", kinds)
        for name in ("f_r", "coulomb", "viscous"):
            value = tuple(float(v) for v in np.asarray(getattr(self, name), dtype=float).ravel())
            if len(value) != 4 or not all(math.isfinite(v) for v in value):
                raise ValueError(f"disturbance.{name} must be 4 finite numbers, got {getattr(self, name)!r}")
            if name != "f_r" and any(v < 0 for v in value):
                raise ValueError(f"disturbance.{name} must be >= 0, got {list(value)}")
            object.__setattr__(self, name, value)
        for name, lower, strict in (("friction_velocity", 0.0, True), ("tissue_stiffness", 0.0, False),
                                    ("tissue_damping", 0.0, False), ("tissue_drag", 0.0, False),
                                    ("skin_height", -math.inf, False)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"disturbance.{name} must be a finite number, got {value!r}")
            if (strict and value <= lower) or (not strict and value < lower):
                raise ValueError(f"disturbance.{name} must be {'>' if strict else '>='} {lower}, got {value!r}")
            object.__setattr__(self, name, float(value))


def _rows(x) -> np.ndarray:
    return np.moveaxis(np.asarray(x, dtype=float), -1, 0)


def paper_disturbance(t, f_r) -> np.ndarray:
    """Eq. 4: ``f_r * sgn(2 t + 1)``, shape ``broadcast(t[..., None], f_r)``."""
    t = np.asarray(t, dtype=float)
    return np.moveaxis(kernels.paper_disturbance(t, np.asarray(f_r, dtype=float).reshape((-1,) + (1,) * t.ndim)), 0, -1)


def friction_disturbance(dq, coulomb, viscous, friction_velocity: float) -> np.ndarray:
    """Smoothed Coulomb plus viscous friction ``-(F_c tanh(q'/v_s) + F_v q')``, shape (..., 4)."""
    dq = np.asarray(dq, dtype=float)
    return kernels.friction_disturbance(dq, np.asarray(coulomb, dtype=float), np.asarray(viscous, dtype=float),
                                        friction_velocity)


def tissue_disturbance(q, dq, spec: DisturbanceSpec, params: RobotParameters) -> np.ndarray:
    """Joint forces from the skin spring-damper contact, ``J(q)^T F``, shape (..., 4)."""
    q, dq = np.broadcast_arrays(np.asarray(q, dtype=float), np.asarray(dq, dtype=float))
    rows = kernels.tissue_disturbance(kernels.kinematic_lengths(params), _rows(q), _rows(dq), spec.skin_height,
                                      spec.tissue_stiffness, spec.tissue_damping, spec.tissue_drag)
    return np.moveaxis(rows, 0, -1)


def external_disturbance(t, q, dq, spec: DisturbanceSpec, params: RobotParameters) -> np.ndarray:
    """Total external disturbance ``tau_dis`` of the selected models, shape (..., 4).

    Parameters
    ----------
    t : float or array_like
        Time (s); broadcasts against the leading shape of ``q``.
    q, dq : array_like, shape (..., 4)
        True joint positions and velocities.
    spec : DisturbanceSpec
        Selected models and their parameters.
    params : RobotParameters
        True arm parameters (for the tissue contact kinematics).
    """
    if not isinstance(spec, DisturbanceSpec):
        raise TypeError(f"spec must be a DisturbanceSpec (scenario.disturbance), got {type(spec).__name__}")
    q, dq = joint_arrays({"q": q, "dq": dq}, robot_parameters(params).joints)
    t = real_array(t, "t")
    lead = np.broadcast_shapes(t.shape, q.shape[:-1])
    q, dq = (np.broadcast_to(a, lead + (4,)) for a in (q, dq))
    p = kernels.disturbance_params(spec, params)
    # per-joint parameters carry one axis per leading axis of the signals (see blocks.kernels)
    extra = (1,) * len(lead)
    p = p._replace(f_r=p.f_r.reshape((4,) + extra), coulomb=p.coulomb.reshape((4,) + extra),
                   viscous=p.viscous.reshape((4,) + extra), kin=p.kin.reshape((4,) + extra))
    return np.moveaxis(kernels.external_disturbance(np.broadcast_to(t, lead), _rows(q), _rows(dq), p), 0, -1)
