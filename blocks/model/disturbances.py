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
``step``
    The same law under the name it has for any arm: ``f_r`` is one
    generalised force per joint of the arm (n numbers).
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
    the tool point's linear Jacobian, ``tau = J(q)^T F`` with the tool
    velocity ``v = J(q) q'``.  Any arm: the tool point and its Jacobian are
    the arm's (``tool_position``, ``tool_jacobian`` of its tool kernels; on
    the paper's RRPR its tool moves along z with ``d3`` alone).  The default
    plane is the RRPR's (the tool height at ``d3 = 0.24 m``); a scenario of
    another arm (``[arm]``) that does not set ``disturbance.skin_height``
    puts the skin through the tool point at the reference's start,
    ``z_tool(q_ref(0))`` (:func:`blocks.scenarios.scenario_arm.skin_height_default`),
    so the tissue acts wherever the tool goes below where it starts.

Per-joint lists (``f_r``, ``coulomb``, ``viscous``) have one entry per joint
of the arm that the spec acts on; the defaults are the paper's four.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blocks import kernels
from blocks.model.arm import ArmModel
from blocks.model.validation import arm_model, joint_arrays, real_array

__all__ = ["DisturbanceSpec", "DISTURBANCE_KINDS", "KIND_ALIASES", "external_disturbance",
           "paper_disturbance", "friction_disturbance", "tissue_disturbance"]

DISTURBANCE_KINDS = ("paper", "friction", "tissue")
#: Other names of a model: ``step`` is Eq. 4 under the name it has for any arm.
KIND_ALIASES = {"step": "paper"}

_Vec4 = tuple[float, ...]


@dataclass(frozen=True)
class DisturbanceSpec:
    """Which external disturbances act on the plant, and their parameters.

    Parameters
    ----------
    kinds : tuple of str
        Any of ``"paper"`` (or ``"step"``, the same law, kept as ``"paper"``), ``"friction"``, ``"tissue"``; an empty
        tuple means no external disturbance.  Their torques add up.
    f_r : n floats
        Eq. 4 amplitudes (N m, N m, N, N m for the RRPR); paper: ``[1.43, 1.6, 1.4, 1.2]``.
    coulomb : n floats
        Coulomb friction levels ``F_c`` (N m or N per joint).
    viscous : n floats
        Viscous coefficients ``F_v`` (N m s/rad or N s/m per joint).
    friction_velocity : float
        Smoothing velocity ``v_s`` of the Coulomb term (rad/s or m/s), > 0.
    skin_height : float
        Height of the skin plane in the base frame (m).  The default is the
        RRPR's tool height at ``d3 = 0.24 m`` (Table 1's link-3 offset); for
        another arm give the plane (a scenario of a URDF arm defaults it to
        the tool height at the reference's start).
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
            if kind not in DISTURBANCE_KINDS and kind not in KIND_ALIASES:
                raise ValueError(f"disturbance kind {kind!r} is unknown; choose from "
                                 f"{list(DISTURBANCE_KINDS) + list(KIND_ALIASES)}")
        if len({KIND_ALIASES.get(k, k) for k in kinds}) != len(kinds):
            raise ValueError(f"disturbance kinds {list(kinds)} name a model twice ('step' is 'paper' for any arm)")
        kinds = tuple(KIND_ALIASES.get(k, k) for k in kinds)
        object.__setattr__(self, "kinds", kinds)
        for name in ("f_r", "coulomb", "viscous"):
            value = tuple(float(v) for v in np.asarray(getattr(self, name), dtype=float).ravel())
            if not value or not all(math.isfinite(v) for v in value):
                raise ValueError(f"disturbance.{name} must be a list of finite numbers (one per joint), got "
                                 f"{getattr(self, name)!r}")
            if name != "f_r" and any(v < 0 for v in value):
                raise ValueError(f"disturbance.{name} must be >= 0, got {list(value)}")
            object.__setattr__(self, name, value)
        sizes = {name: len(getattr(self, name)) for name in ("f_r", "coulomb", "viscous")}
        if len(set(sizes.values())) > 1:
            raise ValueError("the per-joint lists disturbance.f_r, disturbance.coulomb and disturbance.viscous must "
                             f"have one value per joint each, got {sizes} values (the defaults are the paper's four)")
        for name, lower, strict in (("friction_velocity", 0.0, True), ("tissue_stiffness", 0.0, False),
                                    ("tissue_damping", 0.0, False), ("tissue_drag", 0.0, False),
                                    ("skin_height", -math.inf, False)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"disturbance.{name} must be a finite number, got {value!r}")
            if (strict and value <= lower) or (not strict and value < lower):
                raise ValueError(f"disturbance.{name} must be {'>' if strict else '>='} {lower}, got {value!r}")
            object.__setattr__(self, name, float(value))

    def per_joint(self) -> tuple[str, ...]:
        """The per-joint lists the acting models read: ``f_r`` (paper, step), ``coulomb`` and ``viscous`` (friction)."""
        out = ("f_r",) if "paper" in self.kinds else ()
        return out + (("coulomb", "viscous") if "friction" in self.kinds else ())

    def check_arm(self, arm, name: str | None = None) -> None:
        """Refuse a spec that does not fit ``arm``: a per-joint list of the wrong length (every model works on any
        arm: the tissue contact through the arm's tool kernels).

        Raises
        ------
        ValueError
            Naming ``disturbance.<key>``, its length and the arm's joint count, or the model and the arm.
        """
        label = f"the arm {name!r}" if name else "the arm"
        n = arm.joints.count
        for key in self.per_joint():
            value = getattr(self, key)
            if len(value) != n:
                raise ValueError(f"'disturbance.{key}' has {len(value)} values; {label} has {n} joints "
                                 f"({', '.join(arm.joints.names)}): give one per joint")


def _rows(x) -> np.ndarray:
    return np.moveaxis(np.asarray(x, dtype=float), -1, 0)


def paper_disturbance(t, f_r) -> np.ndarray:
    """Eq. 4: ``f_r * sgn(2 t + 1)``, shape ``broadcast(t[..., None], f_r)``."""
    t = np.asarray(t, dtype=float)
    return np.moveaxis(kernels.paper_disturbance(t, np.asarray(f_r, dtype=float).reshape((-1,) + (1,) * t.ndim)), 0, -1)


def friction_disturbance(dq, coulomb, viscous, friction_velocity: float) -> np.ndarray:
    """Smoothed Coulomb plus viscous friction ``-(F_c tanh(q'/v_s) + F_v q')``, ``dq``'s shape (..., n)."""
    dq = np.asarray(dq, dtype=float)
    return kernels.friction_disturbance(dq, np.asarray(coulomb, dtype=float), np.asarray(viscous, dtype=float),
                                        friction_velocity)


def tissue_disturbance(q, dq, spec: DisturbanceSpec, params: ArmModel) -> np.ndarray:
    """Joint forces of the skin spring-damper contact, ``J(q)^T F`` (N m, N), shape (..., n).

    Parameters
    ----------
    q, dq : array_like, shape (..., n)
        Joint positions (rad, m) and velocities (rad/s, m/s).
    spec : DisturbanceSpec
        The plane ``skin_height`` (m) and the tissue's ``tissue_stiffness`` (N/m), ``tissue_damping`` and
        ``tissue_drag`` (N s/m).
    params : ArmModel
        The arm: its tool point and linear Jacobian (the paper's RRPR or any other model).
    """
    arm = arm_model(params, "params")
    q, dq = joint_arrays({"q": q, "dq": dq}, arm.joints)
    q, dq = np.broadcast_arrays(q, dq)
    rows = kernels.tissue_disturbance(arm.arm_kernels, arm.tool_params(), _rows(q), _rows(dq), spec.skin_height,
                                      spec.tissue_stiffness, spec.tissue_damping, spec.tissue_drag)
    return np.moveaxis(np.asarray(rows, dtype=float), 0, -1)


def external_disturbance(t, q, dq, spec: DisturbanceSpec, params: ArmModel) -> np.ndarray:
    """Total external disturbance ``tau_dis`` of the selected models, shape (..., n).

    Parameters
    ----------
    t : float or array_like
        Time (s); broadcasts against the leading shape of ``q``.
    q, dq : array_like, shape (..., n)
        True joint positions and velocities.
    spec : DisturbanceSpec
        Selected models and their parameters.
    params : ArmModel
        The true arm (its joint count; its tool point for the tissue contact).
    """
    if not isinstance(spec, DisturbanceSpec):
        raise TypeError(f"spec must be a DisturbanceSpec (scenario.disturbance), got {type(spec).__name__}")
    arm = arm_model(params, "params")
    spec.check_arm(arm)
    q, dq = joint_arrays({"q": q, "dq": dq}, arm.joints)
    t = real_array(t, "t")
    lead = np.broadcast_shapes(t.shape, q.shape[:-1])
    n = arm.joints.count
    q, dq = (np.broadcast_to(a, lead + (n,)) for a in (q, dq))
    p = kernels.disturbance_params(spec, arm)
    # per-joint parameters carry one axis per leading axis of the signals (see blocks.kernels)
    extra = (1,) * len(lead)
    p = p._replace(f_r=p.f_r.reshape(p.f_r.shape + extra), coulomb=p.coulomb.reshape(p.coulomb.shape + extra),
                   viscous=p.viscous.reshape(p.viscous.shape + extra),
                   kin=p.kin.reshape(p.kin.shape + extra) if isinstance(p.kin, np.ndarray) else p.kin)
    return np.moveaxis(kernels.external_disturbance(arm.arm_kernels, np.broadcast_to(t, lead), _rows(q), _rows(dq), p), 0, -1)
