"""The arm's dynamics terms, Eq. 5-7: inertia, Coriolis and gravity forces, and the plant's acceleration.

``M(q)`` depends on ``theta2`` only, through ``c2 = cos(theta2)``, and has a
fixed sparsity: the prismatic joint 3 is decoupled and joint 4 couples to
joints 1 and 2 through ``-k5`` only.  :func:`inertia_entries` gives its
distinct entries; :func:`mass_times` and :func:`mass_solve` use that structure
instead of a general 4x4 product or solve.  See ``docs/model.md`` for the
model and the corrections to the paper.
"""
from __future__ import annotations

import numpy as np

__all__ = ["arm_constants", "inertia_entries", "inertia_matrix", "mass_times", "mass_solve", "coriolis_forces", "bias_forces",
           "gravity_forces", "plant_acceleration"]


def arm_constants(params) -> np.ndarray:
    """``k = [k1, k2, k3, k4, k5, g]`` of a :class:`~blocks.model.rrpr.parameters.RobotParameters` (kg m^2, kg, m/s^2)."""
    c = params.constants
    return np.array([c.k1, c.k2, c.k3, c.k4, c.k5, c.g], dtype=float)


def inertia_entries(k, c2):
    """The distinct entries ``(m00, m01, m11, m22, m33)`` of ``M(q)``, Eq. 5.

    The others follow from the arm's structure: ``m10 = m01``,
    ``m03 = m30 = m13 = m31 = -m33`` and zero between joint 3 and the rest.

    Parameters
    ----------
    k : numpy.ndarray
        Arm constants ``[k1, k2, k3, k4, k5, g]`` (see :func:`arm_constants`).
    c2 : float or numpy.ndarray
        ``cos(theta2)``.
    """
    k2c2 = k[1] * c2
    return k[0] + k2c2, k[2] + 0.5 * k2c2, k[2], k[3], k[4]


def inertia_matrix(k, q) -> np.ndarray:
    """``M(q)`` as a matrix, shape ``broadcast(k[0], q[1]).shape + (4, 4)`` (kg m^2, kg), from :func:`inertia_entries`.

    For the analyses that need the whole matrix; the right-hand sides use
    :func:`mass_times` and :func:`mass_solve` instead.
    """
    m00, m01, m11, m22, m33 = np.broadcast_arrays(*inertia_entries(k, np.cos(q[1])))
    M = np.zeros(m00.shape + (4, 4))
    M[..., 0, 0] = m00
    M[..., 0, 1] = M[..., 1, 0] = m01
    M[..., 1, 1] = m11
    M[..., 2, 2] = m22
    M[..., 0, 3] = M[..., 3, 0] = M[..., 1, 3] = M[..., 3, 1] = -m33
    M[..., 3, 3] = m33
    return M


def mass_times(k, q, v):
    """``M(q) v`` (N m, N) at joint positions ``q`` for a joint vector ``v`` (rad/s^2, m/s^2); ``v``'s shape."""
    m00, m01, m11, m22, m33 = inertia_entries(k, np.cos(q[1]))
    coupling = m33 * v[3]
    out = np.empty_like(v)
    out[0] = m00 * v[0] + m01 * v[1] - coupling
    out[1] = m01 * v[0] + m11 * v[1] - coupling
    out[2] = m22 * v[2]
    out[3] = coupling - m33 * (v[0] + v[1])
    return out


def mass_solve(k, q, r):
    """``M(q)^-1 r`` at joint positions ``q`` for a generalised force ``r`` (N m, N); ``r``'s shape.

    Row 3 of ``M x = r`` reads ``m33 (x3 - x0 - x1) = r3``, so
    ``x3 = x0 + x1 + r3 / m33``; substituting it into rows 0 and 1 leaves a
    2x2 system whose determinant ``(k1 - k3)(k3 - k5) - k2^2 c2^2 / 4`` is
    positive for every valid arm.
    """
    m00, m01, m11, m22, m33 = inertia_entries(k, np.cos(q[1]))
    a = m00 - m33
    b = m01 - m33
    c = m11 - m33
    r03 = r[0] + r[3]
    r13 = r[1] + r[3]
    inv_det = 1.0 / (a * c - b * b)
    out = np.empty_like(r)
    out[0] = (c * r03 - b * r13) * inv_det
    out[1] = (a * r13 - b * r03) * inv_det
    out[2] = r[2] / m22
    out[3] = out[0] + out[1] + r[3] / m33
    return out


def coriolis_forces(k, q, dq):
    """Coriolis and centrifugal forces ``N(q, q') q'`` of Eq. 6 (N m) at joint positions ``q``; ``dq``'s shape."""
    h = k[1] * np.sin(q[1])
    out = np.empty_like(dq)
    out[0] = -h * dq[1] * (dq[0] + 0.5 * dq[1])
    out[1] = 0.5 * h * dq[0] * dq[0]
    out[2] = 0.0
    out[3] = 0.0
    return out


def bias_forces(k, q, dq):
    """``N(q, q') q' + G(q)`` (N m, N): Eq. 6 plus gravity, Eq. 7, on the prismatic joint (``d3`` positive down)."""
    out = coriolis_forces(k, q, dq)
    out[2] = out[2] - k[3] * k[5]
    return out


def gravity_forces(k, q):
    """``G(q)`` of Eq. 7 (N m, N): only the prismatic joint carries weight (``d3`` positive down); ``q``'s shape."""
    out = np.zeros_like(q * k[5])
    out[2] = out[2] - k[3] * k[5]
    return out


def plant_acceleration(k, q, dq, force):
    """Joint accelerations ``q'' = M(q)^-1 (force - N(q, q') q' - G(q))`` (rad/s^2, m/s^2), Eq. 1.

    Parameters
    ----------
    k : numpy.ndarray
        Arm constants (see :func:`arm_constants`).
    q, dq : numpy.ndarray
        Joint positions (rad, m) and velocities (rad/s, m/s), rows.
    force : numpy.ndarray
        Total generalised force on the joints, ``tau + tau_dis`` (N m, N).
    """
    return mass_solve(k, q, force - bias_forces(k, q, dq))
