"""Rigid-body dynamics of the RRPR arm: ``M(q) q'' + N(q, q') q' + G(q) = tau``.

All functions are vectorised: ``q`` and ``dq`` may carry any leading batch
shape ``(..., 4)``; matrices come back as ``(..., 4, 4)``.  Joint order is
``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]``.
"""
from __future__ import annotations

import numpy as np

from .parameters import RobotParameters

__all__ = [
    "inertia", "inertia_derivative_theta2", "coriolis_vector", "coriolis_matrix", "gravity",
    "forward_dynamics", "inverse_dynamics", "kinetic_energy", "potential_energy",
]


def _as_joint_array(x, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.shape[-1:] != (4,):
        raise ValueError(f"{name} must have a last axis of length 4 (joints), got shape {arr.shape}")
    return arr


def inertia(q, params: RobotParameters) -> np.ndarray:
    """Inertia matrix ``M(q)`` of Eq. 5 (kg m^2, kg for the prismatic joint).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Joint positions (rad, rad, m, rad).
    params : RobotParameters
        Arm parameters.

    Returns
    -------
    numpy.ndarray, shape (..., 4, 4)
        Symmetric positive definite inertia matrix.
    """
    q = _as_joint_array(q, "q")
    k = params.constants
    c2 = np.cos(q[..., 1])
    M = np.zeros(q.shape[:-1] + (4, 4))
    M[..., 0, 0] = k.k1 + k.k2 * c2
    M[..., 0, 1] = M[..., 1, 0] = k.k3 + 0.5 * k.k2 * c2
    M[..., 1, 1] = k.k3
    M[..., 2, 2] = k.k4
    M[..., 0, 3] = M[..., 3, 0] = -k.k5
    M[..., 1, 3] = M[..., 3, 1] = -k.k5
    M[..., 3, 3] = k.k5
    return M


def inertia_derivative_theta2(q, params: RobotParameters) -> np.ndarray:
    """Partial derivative ``dM/dtheta2`` (the only configuration dependence), shape (..., 4, 4)."""
    q = _as_joint_array(q, "q")
    k = params.constants
    s2 = np.sin(q[..., 1])
    dM = np.zeros(q.shape[:-1] + (4, 4))
    dM[..., 0, 0] = -k.k2 * s2
    dM[..., 0, 1] = dM[..., 1, 0] = -0.5 * k.k2 * s2
    return dM


def coriolis_vector(q, dq, params: RobotParameters) -> np.ndarray:
    """Coriolis and centrifugal torques ``N(q, q') q'`` of Eq. 6, shape (..., 4), in N m / N."""
    q = _as_joint_array(q, "q")
    dq = _as_joint_array(dq, "dq")
    k = params.constants
    s2 = np.sin(q[..., 1])
    out = np.zeros(np.broadcast(q, dq).shape)
    out[..., 0] = -k.k2 * s2 * dq[..., 1] * (dq[..., 0] + 0.5 * dq[..., 1])
    out[..., 1] = 0.5 * k.k2 * s2 * dq[..., 0] ** 2
    return out


def coriolis_matrix(q, dq, params: RobotParameters) -> np.ndarray:
    """Christoffel factorisation ``C(q, q')`` with ``C q' = N q'`` and ``M' - 2C`` skew-symmetric.

    This is not the paper's printed matrix N (which gives the same vector but
    not the skew property); see paper-notes.  Shape (..., 4, 4).
    """
    q = _as_joint_array(q, "q")
    dq = _as_joint_array(dq, "dq")
    h = 0.5 * params.constants.k2 * np.sin(q[..., 1])
    C = np.zeros(np.broadcast(q, dq).shape[:-1] + (4, 4))
    C[..., 0, 0] = -h * dq[..., 1]
    C[..., 0, 1] = -h * (dq[..., 0] + dq[..., 1])
    C[..., 1, 0] = h * dq[..., 0]
    return C


def gravity(q, params: RobotParameters) -> np.ndarray:
    """Gravity vector ``G(q)`` of Eq. 7 (``d3`` positive downwards), shape (..., 4)."""
    q = _as_joint_array(q, "q")
    G = np.zeros(q.shape)
    G[..., 2] = -params.constants.k4 * params.g
    return G


def forward_dynamics(q, dq, tau, params: RobotParameters) -> np.ndarray:
    """Joint accelerations ``q'' = M^-1 (tau - N q' - G)``, shape (..., 4).

    Parameters
    ----------
    q, dq : array_like, shape (..., 4)
        Joint positions and velocities (rad, m; rad/s, m/s).
    tau : array_like, shape (..., 4)
        Total generalised force on each joint (N m, N for joint 3).
    """
    rhs = np.asarray(tau, dtype=float) - coriolis_vector(q, dq, params) - gravity(q, params)
    return np.linalg.solve(inertia(q, params), rhs[..., None])[..., 0]


def inverse_dynamics(q, dq, ddq, params: RobotParameters) -> np.ndarray:
    """Generalised forces ``M q'' + N q' + G`` that produce ``ddq``, shape (..., 4)."""
    M = inertia(q, params)
    return (M @ np.asarray(ddq, dtype=float)[..., None])[..., 0] + coriolis_vector(q, dq, params) + gravity(q, params)


def kinetic_energy(q, dq, params: RobotParameters) -> np.ndarray:
    """Kinetic energy ``0.5 q'^T M(q) q'`` in J, shape (...)."""
    dq = _as_joint_array(dq, "dq")
    return 0.5 * np.einsum("...i,...ij,...j->...", dq, inertia(q, params), dq)


def potential_energy(q, params: RobotParameters) -> np.ndarray:
    """Gravitational potential energy in J (zero at ``d3 = 0``), consistent with ``G = dV/dq``."""
    q = _as_joint_array(q, "q")
    return -params.constants.k4 * params.g * q[..., 2]
