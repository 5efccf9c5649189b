"""What the analyses read of an arm model: joint vectors, workspace ranges, and derivatives of its dynamics.

Every analysis takes the joint count, names, units and limits from the
model (:class:`blocks.arm.ArmModel`), never from a constant.  The
derivatives the linearization and the observer certificate need are taken
from the model when it gives them exactly (a method ``inertia_partials(q)``
or ``acceleration_jacobians(q, dq, tau)``) and otherwise by central
differences of its methods with :data:`FD_STEP`.

Step of the central differences
    The error of a central difference with step ``h`` is about
    ``h^2 |f'''| / 6`` (truncation) plus ``eps |f| / h`` (rounding); the sum is
    smallest near ``h = (3 eps)^(1/3) ~ 9e-6`` when ``f`` varies on a scale of
    one unit (rad, or m for prismatic joints whose inertia terms are
    polynomial in the extension).  :data:`FD_STEP` = 6e-6 gives a relative
    error near 1e-10 for trigonometric dependences; the tests hold it against
    the paper arm's exact ``dM/dtheta2`` (:func:`blocks.dynamics.inertia_derivative_theta2`).
"""
from __future__ import annotations

import math

import numpy as np

from blocks.arm import ArmModel
from blocks.joints import RRPR_JOINTS, JointSpace

__all__ = ["FD_STEP", "RRPR_RANGES", "RRPR_POINTS", "arm_model", "joint_vector", "joint_matrix", "workspace_ranges",
           "default_points", "inertia_partials", "acceleration_jacobians"]

#: Central-difference step (rad, m) of the model's derivatives (see the module docstring).
FD_STEP = 6e-6

#: The paper arm's survey ranges (rad, rad, m, rad): within its joint limits, the prismatic range spanning the
#: laceration path's depths (about 0.24 m) with a wide margin; revolute joints cover a full turn.
RRPR_RANGES = ((-np.pi, np.pi), (-np.pi, np.pi), (0.10, 0.35), (-np.pi, np.pi))
#: The paper arm's survey grid: fine along theta2, the only joint its inertia depends on.
RRPR_POINTS = (5, 73, 3, 5)

# Full-factorial grids of other arms hold at most about this many configurations.
_GRID_BUDGET = 20000


def arm_model(model, name: str = "arm") -> ArmModel:
    """``model`` checked to be an arm model (:class:`blocks.arm.ArmModel`)."""
    if not isinstance(model, ArmModel):
        raise TypeError(f"{name} must be a blocks.arm.ArmModel (for example blocks.parameters.RobotParameters), "
                        f"got {type(model).__name__}")
    return model


def joint_vector(value, name: str, joints: JointSpace) -> np.ndarray:
    """``value`` as ``n`` finite numbers, one per joint in the joint's unit; a clear ValueError otherwise."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (joints.count,) or not np.all(np.isfinite(arr)):
        units = ", ".join(joints.position_units)
        raise ValueError(f"{name} must be {joints.count} finite numbers ({units}), one per joint "
                         f"{list(joints.names)}, got {value!r}")
    return arr


def joint_matrix(value, name: str, n: int) -> np.ndarray:
    """``value`` as an ``n x n`` gain: a scalar (times I), ``n`` numbers (diagonal) or ``n x n``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = arr * np.eye(n)
    elif arr.shape == (n,):
        arr = np.diag(arr)
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite scalar, {n} numbers or an {n} x {n} matrix, got {value!r}")
    return arr


def workspace_ranges(joints: JointSpace) -> tuple[tuple[float, float], ...]:
    """Where the analyses sample each joint: within its limits; a full turn for an unlimited revolute joint.

    The paper's arm keeps its survey ranges (:data:`RRPR_RANGES`).  A revolute
    joint limited on one side only turns a full turn from that side.

    Raises
    ------
    ValueError
        For a prismatic joint without finite limits (no range to sample), naming it.
    """
    if joints == RRPR_JOINTS:
        return RRPR_RANGES
    out = []
    for name, kind, (lo, hi) in zip(joints.names, joints.kinds, joints.limits):
        if math.isfinite(lo) and math.isfinite(hi):
            out.append((lo, hi))
        elif kind == "revolute":
            out.append((lo, lo + 2 * math.pi) if math.isfinite(lo) else
                       (hi - 2 * math.pi, hi) if math.isfinite(hi) else (-math.pi, math.pi))
        else:
            raise ValueError(f"joint {name!r} is prismatic with limits ({lo}, {hi}) m: give it finite limits "
                             "(or pass ranges) so that its range can be sampled")
    return tuple(out)


def default_points(joints: JointSpace) -> tuple[int, ...]:
    """Points per joint of the default survey grid: :data:`RRPR_POINTS` for the paper's arm, else the same count
    on every joint with at most about 20000 configurations in all (3 to 73 per joint)."""
    if joints == RRPR_JOINTS:
        return RRPR_POINTS
    per = int(math.floor(_GRID_BUDGET ** (1.0 / joints.count) + 1e-9))
    return (min(73, max(3, per)),) * joints.count


def inertia_partials(arm: ArmModel, q, step: float = FD_STEP) -> np.ndarray:
    """``dM/dq_j`` at each configuration, shape ``(..., n, n, n)`` (last-but-two axis: j), kg m^2/rad etc.

    The model's own ``inertia_partials(q)`` when it has one (exact);
    otherwise central differences of :meth:`ArmModel.inertia` with ``step``.
    """
    q = np.asarray(q, dtype=float)
    exact = getattr(arm, "inertia_partials", None)
    if callable(exact):
        return np.asarray(exact(q), dtype=float)
    n = arm.n
    parts = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = step
        parts.append((arm.inertia(q + e) - arm.inertia(q - e)) / (2.0 * step))
    return np.stack(parts, axis=-3)


def acceleration_jacobians(arm: ArmModel, q, dq, tau, step: float = FD_STEP) -> tuple[np.ndarray, ...]:
    """Partials of the forward dynamics ``q'' = M^-1(q) (tau - h(q, q'))`` at one state.

    Parameters
    ----------
    arm : ArmModel
    q, dq, tau : array_like, shape (n,)
        Joint positions (rad, m), velocities (rad/s, m/s) and generalised forces (N m, N).
    step : float
        Central-difference step (rad, m; rad/s, m/s), used unless the model has an
        exact ``acceleration_jacobians(q, dq, tau)``.

    Returns
    -------
    d_q, d_dq, d_tau : numpy.ndarray, shape (n, n)
        ``d q''/d q`` (1/s^2), ``d q''/d q'`` (1/s) and ``d q''/d tau = M^-1``.
        ``d_q`` is ``-M^-1 (dM/dq q'' + dh/dq)``, ``d_dq`` is ``-M^-1 dh/dq'``:
        the derivatives of ``M^-1 h`` the linearization needs.
    """
    q, dq, tau = (np.asarray(v, dtype=float) for v in (q, dq, tau))
    exact = getattr(arm, "acceleration_jacobians", None)
    if callable(exact):
        return tuple(np.asarray(m, dtype=float) for m in exact(q, dq, tau))
    n = arm.n
    E = step * np.eye(n)
    # one batched call per side: rows 0..n-1 move q, rows n..2n-1 move q'
    qs = np.concatenate([q + E, np.broadcast_to(q, (n, n))])
    dqs = np.concatenate([np.broadcast_to(dq, (n, n)), dq + E])
    plus = arm.forward_dynamics(qs, dqs, np.broadcast_to(tau, (2 * n, n)))
    qs = np.concatenate([q - E, np.broadcast_to(q, (n, n))])
    dqs = np.concatenate([np.broadcast_to(dq, (n, n)), dq - E])
    minus = arm.forward_dynamics(qs, dqs, np.broadcast_to(tau, (2 * n, n)))
    d = ((plus - minus) / (2.0 * step)).T            # column k: derivative along state k
    return d[:, :n], d[:, n:], np.linalg.inv(arm.inertia(q))
