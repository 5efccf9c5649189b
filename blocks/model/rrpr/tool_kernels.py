"""Forward and differential kinematics of the tool, Eq. 8 as corrected (see ``docs/model.md``).

``p = [x, y, z, phi]`` with ``x = a1 c1 + a2 c12``, ``y = a1 s1 + a2 s12``,
``z = d1 - d3 - d4`` and ``phi = theta1 + theta2 - theta4``.  The Jacobian's
only configuration-dependent entries are those of the planar part, rows
``x, y`` and columns ``theta1, theta2``; the rest is ``J[2, 2] = -1`` and the
last row ``[1, 1, 0, -1]``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["kinematic_lengths", "tool_pose", "jacobian_entries", "tool_velocity", "tool_position", "tool_jacobian",
           "tool_acceleration_bias"]


def kinematic_lengths(params) -> np.ndarray:
    """``kin = [a1, a2, d1, d4]`` (m) of a :class:`~blocks.model.rrpr.parameters.RobotParameters`."""
    return np.array([params.a1, params.a2, params.d1, params.d4], dtype=float)


def tool_pose(kin, q):
    """Tool pose rows ``[x, y, z (m), phi (rad)]`` at joint positions ``q``; ``q``'s shape."""
    t12 = q[0] + q[1]
    out = np.empty_like(q)
    out[0] = kin[0] * np.cos(q[0]) + kin[1] * np.cos(t12)
    out[1] = kin[0] * np.sin(q[0]) + kin[1] * np.sin(t12)
    out[2] = kin[2] - q[2] - kin[3]
    out[3] = t12 - q[3]
    return out


def jacobian_entries(kin, q):
    """The planar entries ``(J00, J01, J10, J11)`` of ``dp/dq`` (m/rad) at joint positions ``q``."""
    t12 = q[0] + q[1]
    a2s12 = kin[1] * np.sin(t12)
    a2c12 = kin[1] * np.cos(t12)
    return -kin[0] * np.sin(q[0]) - a2s12, -a2s12, kin[0] * np.cos(q[0]) + a2c12, a2c12


def tool_velocity(kin, q, dq):
    """Tool velocity rows ``J(q) q'`` (m/s, rad/s); ``dq``'s shape."""
    j00, j01, j10, j11 = jacobian_entries(kin, q)
    out = np.empty_like(dq)
    out[0] = j00 * dq[0] + j01 * dq[1]
    out[1] = j10 * dq[0] + j11 * dq[1]
    out[2] = -dq[2]
    out[3] = dq[0] + dq[1] - dq[3]
    return out


# --------------------------------------------------------------------------------------------------------------
# The arm-model interface (blocks.model.arm.ArmModel): the tool point in the base frame, for any arm the same rows
# --------------------------------------------------------------------------------------------------------------
def tool_position(kin, q):
    """Tool-tip position rows ``[x, y, z]`` (m) in the base frame; shape ``(3,) + q.shape[1:]``."""
    return tool_pose(kin, q)[:3]


def tool_jacobian(kin, q):
    """Linear Jacobian ``dp/dq`` of the tool tip, rows ``(3, 4) + q.shape[1:]`` (m/rad, m/m)."""
    j00, j01, j10, j11 = jacobian_entries(kin, q)
    out = np.zeros((3, 4) + np.shape(q[0]), dtype=np.result_type(q, float))
    out[0, 0], out[0, 1], out[1, 0], out[1, 1] = j00, j01, j10, j11
    out[2, 2] = -1.0
    return out


def tool_acceleration_bias(kin, q, dq):
    """``J'(q, q') q'`` (m/s^2): the tool tip's acceleration at ``q'' = 0``, rows ``(3,) + dq.shape[1:]``."""
    t12 = q[0] + q[1]
    w1, w12 = dq[0] * dq[0], (dq[0] + dq[1]) * (dq[0] + dq[1])
    out = np.zeros((3,) + np.shape(dq[0]), dtype=np.result_type(dq, float))
    out[0] = -kin[0] * np.cos(q[0]) * w1 - kin[1] * np.cos(t12) * w12
    out[1] = -kin[0] * np.sin(q[0]) * w1 - kin[1] * np.sin(t12) * w12
    return out
