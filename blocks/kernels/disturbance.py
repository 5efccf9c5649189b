"""External disturbance models, Eq. 4 and beside it: their forces on the joints (N m, N for joint 3).

``paper``: Eq. 4, ``f_r sgn(2t + 1)``, a constant step for ``t >= 0``.
``friction``: ``-(F_c tanh(q'/v_s) + F_v q')``, Coulomb smoothed by ``tanh``.
``tissue``: below the skin plane ``z = skin_height`` the tissue pushes the
tool up with ``F_z = max(0, k p - c z')`` (``p`` the depth) and drags it in
the plane with ``-c_lat v_xy``; the joints feel ``J(q)^T F``.
The models are described for users in :mod:`blocks.model.disturbances`.

The tissue contact takes the arm's kernels first, ``model`` (an
:class:`~blocks.kernels.model.ArmKernels`), and reads the tool point through
``model.tool_position`` and ``model.tool_jacobian``: one source for every
arm (the paper's RRPR in closed form, a URDF arm's chain kernels).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["DisturbanceParams", "disturbance_params", "paper_disturbance", "friction_disturbance",
           "tissue_disturbance", "external_disturbance"]


class DisturbanceParams(NamedTuple):
    """Arrays and numbers of the selected disturbance models, in the kernels' layout.

    ``paper`` (the Eq. 4 step), ``friction`` and ``tissue`` say which
    models act (each for any arm); ``f_r``, ``coulomb`` and ``viscous`` are
    per-joint rows (N m, N; N m s/rad, N s/m), ``friction_velocity`` is
    ``v_s`` (rad/s, m/s), the tissue numbers are in m, N/m, N s/m and N s/m,
    and ``kin`` are the arm's tool parameters (``arm.tool_params()``: the
    RRPR's kinematic lengths ``[a1, a2, d1, d4]``, m, or a URDF arm's chain).
    """

    paper: bool
    friction: bool
    tissue: bool
    f_r: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray
    friction_velocity: float
    skin_height: float
    tissue_stiffness: float
    tissue_damping: float
    tissue_drag: float
    kin: np.ndarray


def disturbance_params(spec, params) -> DisturbanceParams:
    """The :class:`DisturbanceParams` of a :class:`~blocks.model.disturbances.DisturbanceSpec` on an arm.

    ``kin`` is the arm's tool parameters (``params.tool_params()``; the RRPR's
    kinematic lengths), read by the tissue contact and by the tool-tip rows
    of the compiled engine.  For an arm other than the RRPR a per-joint list
    of a model that does not act is given as n zeros, so that every array
    has the arm's joint count.
    """
    n = params.joints.count
    acting = spec.per_joint() if hasattr(spec, "per_joint") else ("f_r", "coulomb", "viscous")

    def joint_row(name):
        value = np.array(getattr(spec, name), dtype=float)
        return value if name in acting or value.shape == (n,) else np.zeros(n)

    return DisturbanceParams(
        paper="paper" in spec.kinds, friction="friction" in spec.kinds,
        tissue="tissue" in spec.kinds,
        f_r=joint_row("f_r"), coulomb=joint_row("coulomb"), viscous=joint_row("viscous"),
        friction_velocity=float(spec.friction_velocity),
        skin_height=float(spec.skin_height), tissue_stiffness=float(spec.tissue_stiffness),
        tissue_damping=float(spec.tissue_damping), tissue_drag=float(spec.tissue_drag),
        kin=params.tool_params())


def paper_disturbance(t, f_r):
    """Eq. 4, ``f_r sgn(2t + 1)``, at time(s) ``t`` (s); broadcasts ``f_r`` against ``t``."""
    return f_r * np.sign(2.0 * t + 1.0)


def friction_disturbance(dq, coulomb, viscous, friction_velocity):
    """Smoothed Coulomb plus viscous friction ``-(F_c tanh(q'/v_s) + F_v q')``; ``dq``'s shape."""
    return -(coulomb * np.tanh(dq / friction_velocity) + viscous * dq)


def _structural_zero(a) -> bool:
    """Whether a Jacobian entry is a constant zero of the arm's structure (a Python number, as the RRPR's
    object-array zeros and a chain's skipped terms are in a trace), whose product a trace need not carry."""
    return (a.__class__ is float or a.__class__ is int) and a == 0


def _jacobian_times(J, x, r: int):
    """Row ``r`` of ``J x``: ``sum_j J[r, j] x[j]``, leaving out structural zeros (same numbers: ``y + 0 x = y``
    for finite ``x``)."""
    out = 0.0
    for j in range(x.shape[0]):
        if not _structural_zero(J[r, j]):
            out = out + J[r, j] * x[j]
    return out


def tissue_disturbance(model, kin, q, dq, skin_height, stiffness, damping, drag):
    """Joint forces ``J(q)^T F`` of the skin contact (see the module docstring); ``dq``'s shape.

    ``J`` is the tool point's linear Jacobian (``model.tool_jacobian``), the
    depth ``skin_height - z`` is read from ``model.tool_position``; ``F =
    (-c_lat v_x, -c_lat v_y, max(0, k p - c v_z))`` with ``v = J q'`` while
    ``p > 0``, zero above the skin.
    """
    J = model.tool_jacobian(kin, q)
    depth = skin_height - model.tool_position(kin, q)[2]
    inside = depth > 0.0
    vx, vy, vz = _jacobian_times(J, dq, 0), _jacobian_times(J, dq, 1), _jacobian_times(J, dq, 2)
    fz = np.maximum(0.0, stiffness * depth - damping * vz) * inside          # a spring-damper that cannot pull
    fx = -drag * vx * inside
    fy = -drag * vy * inside
    out = np.empty_like(dq)
    for j in range(dq.shape[0]):
        tau = 0.0
        for r, f in ((0, fx), (1, fy), (2, fz)):
            if not _structural_zero(J[r, j]):
                tau = tau + J[r, j] * f
        out[j] = tau
    return out


def external_disturbance(model, t, q, dq, p: DisturbanceParams):
    """Sum of the selected models' joint forces ``tau_dis`` (N m, N) at time ``t`` (s) and state ``q, dq``
    (``model``: the arm's kernels, for the tissue contact's tool point)."""
    out = np.zeros_like(dq)
    if p.paper:
        out = out + paper_disturbance(t, p.f_r)
    if p.friction:
        out = out + friction_disturbance(dq, p.coulomb, p.viscous, p.friction_velocity)
    if p.tissue:
        out = out + tissue_disturbance(model, p.kin, q, dq, p.skin_height, p.tissue_stiffness, p.tissue_damping,
                                       p.tissue_drag)
    return out
