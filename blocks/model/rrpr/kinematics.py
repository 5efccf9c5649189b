"""Forward, differential and inverse kinematics of the RRPR arm (paper Eq. 8, corrected).

The task-space pose is ``p = [x, y, z, phi]``: tool-tip position in the base
frame (m) and tool roll angle (rad).  With the paper's conventions

    x = a1 cos(theta1) + a2 cos(theta1 + theta2)
    y = a1 sin(theta1) + a2 sin(theta1 + theta2)
    z = d1 - d3 - d4
    phi = theta1 + theta2 - theta4

The paper's printed Jacobian has two errors (``J[0, 1]`` printed as
``-l2 cos`` and the last row printed ``[1, 1, 0, 1]``); the Jacobian here is
the exact derivative of the map above.  All functions accept a leading batch
shape ``(..., 4)`` and check their arguments once (:mod:`blocks.model.validation`):
a wrong type raises TypeError, a wrong shape or a non-finite entry ValueError,
naming the argument.
"""
from __future__ import annotations

import numpy as np

from blocks.model.arm import UnreachableError
from blocks.model.rrpr.parameters import RobotParameters, robot_parameters
from blocks.model.rrpr.tool_kernels import jacobian_entries, kinematic_lengths, tool_pose
from blocks.model.validation import joint_array, joint_arrays, real_array

__all__ = [
    "UnreachableError", "forward_kinematics", "jacobian", "jacobian_derivative_times_dq",
    "inverse_kinematics", "planar_reach",
]

ELBOWS = {"positive": 1.0, "negative": -1.0}


def forward_kinematics(q, params: RobotParameters) -> np.ndarray:
    """Tool pose ``[x (m), y (m), z (m), phi (rad)]`` for joint positions ``q``, shape (..., 4)."""
    q = joint_array(q, "q", robot_parameters(params).joints)
    return np.moveaxis(tool_pose(kinematic_lengths(params), np.moveaxis(q, -1, 0)), 0, -1)


def jacobian(q, params: RobotParameters) -> np.ndarray:
    """Analytic Jacobian ``dp/dq`` of :func:`forward_kinematics`, shape (..., 4, 4).

    Rows are ``x, y, z, phi``; columns are the joints.  Singular where
    ``sin(theta2) = 0`` (arm stretched or folded).
    """
    q = joint_array(q, "q", robot_parameters(params).joints)
    j00, j01, j10, j11 = jacobian_entries(kinematic_lengths(params), np.moveaxis(q, -1, 0))
    J = np.zeros(q.shape[:-1] + (4, 4))
    J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1] = j00, j01, j10, j11
    J[..., 2, 2] = -1.0
    J[..., 3, 0] = 1.0
    J[..., 3, 1] = 1.0
    J[..., 3, 3] = -1.0
    return J


def jacobian_derivative_times_dq(q, dq, params: RobotParameters) -> np.ndarray:
    """The velocity product ``J'(q, q') q'`` (task-space acceleration at zero joint acceleration)."""
    q, dq = joint_arrays({"q": q, "dq": dq}, robot_parameters(params).joints)
    t1, t12 = q[..., 0], q[..., 0] + q[..., 1]
    w1, w12 = dq[..., 0], dq[..., 0] + dq[..., 1]
    out = np.zeros(q.shape)
    out[..., 0] = -params.a1 * np.cos(t1) * w1 ** 2 - params.a2 * np.cos(t12) * w12 ** 2
    out[..., 1] = -params.a1 * np.sin(t1) * w1 ** 2 - params.a2 * np.sin(t12) * w12 ** 2
    return out


def planar_reach(params: RobotParameters) -> tuple[float, float]:
    """Inner and outer radius (m) of the reachable annulus in the x-y plane."""
    robot_parameters(params)
    return abs(params.a1 - params.a2), params.a1 + params.a2


def inverse_kinematics(pose, params: RobotParameters, elbow: str = "positive",
                       q_near=None, min_sin_theta2: float = 0.0) -> np.ndarray:
    """Joint positions that put the tool at ``pose``, shape (..., 4).

    Parameters
    ----------
    pose : array_like, shape (..., 4)
        ``[x (m), y (m), z (m), phi (rad)]``.
    params : RobotParameters
        Arm parameters (kinematic lengths ``a1``, ``a2``, offsets ``d1``, ``d4``).
    elbow : {"positive", "negative"}
        Sign of ``theta2`` (the two mirror solutions).
    q_near : array_like, shape (4,), optional
        The revolute angles ``theta1`` and ``theta4`` are returned as the
        representatives (modulo 2 pi) nearest to this configuration, so that a
        path that crosses the ``+-pi`` cut stays continuous.
    min_sin_theta2 : float
        Required distance from the singular configurations, as a lower bound
        on ``|sin(theta2)|`` (0 accepts the workspace boundary itself).

    Raises
    ------
    UnreachableError
        If any point lies outside the annulus ``|a1 - a2| <= r <= a1 + a2`` or
        closer to a singularity than ``min_sin_theta2``; the message names the
        first offending point.
    """
    if not isinstance(elbow, str) or elbow not in ELBOWS:
        raise ValueError(f"elbow must be one of {sorted(ELBOWS)}, got {elbow!r}")
    robot_parameters(params)
    pose = real_array(pose, "pose")
    if pose.shape[-1:] != (4,):
        raise ValueError(f"pose must have shape (..., 4), a last axis of length 4 (x, y, z, phi), got shape "
                         f"{pose.shape}")
    min_sin_theta2 = float(real_array(min_sin_theta2, "min_sin_theta2"))
    x, y, z, phi = pose[..., 0], pose[..., 1], pose[..., 2], pose[..., 3]
    a1, a2 = params.a1, params.a2
    c2 = (x ** 2 + y ** 2 - a1 ** 2 - a2 ** 2) / (2 * a1 * a2)
    s2 = ELBOWS[elbow] * np.sqrt(np.clip(1 - c2 ** 2, 0.0, None))
    bad = (np.abs(c2) > 1 + 1e-12) | (np.abs(s2) < min_sin_theta2)
    if np.any(bad):
        idx = tuple(np.argwhere(np.atleast_1d(bad))[0])
        p = np.atleast_2d(pose.reshape(-1, 4))[int(np.ravel_multi_index(idx, np.atleast_1d(bad).shape))]
        r = float(np.hypot(p[0], p[1]))
        inner, outer = planar_reach(params)
        raise UnreachableError(
            f"task-space point x={p[0]:.6g} m, y={p[1]:.6g} m (planar radius {r:.6g} m) is not reachable: "
            f"the arm reaches radii {inner:.6g} m to {outer:.6g} m"
            + (f" with |sin(theta2)| >= {min_sin_theta2:g} (singularity margin)" if min_sin_theta2 > 0 else "")
        )
    t2 = np.arctan2(s2, np.clip(c2, -1.0, 1.0))
    t1 = np.arctan2(y, x) - np.arctan2(a2 * s2, a1 + a2 * np.cos(t2))
    d3 = params.d1 - params.d4 - z
    t4 = t1 + t2 - phi
    if q_near is not None:
        q_near = joint_array(q_near, "q_near", params.joints)
        t1 = q_near[..., 0] + _wrap(t1 - q_near[..., 0])
        t4 = t1 + t2 - phi
        t4 = q_near[..., 3] + _wrap(t4 - q_near[..., 3])
    else:
        t1 = _wrap(t1)
    return np.stack([t1, t2, d3, t4], axis=-1)


def _wrap(angle):
    """Wrap to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi
