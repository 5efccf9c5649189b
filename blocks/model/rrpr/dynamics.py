"""Rigid-body dynamics ``M(q) q'' + N(q, q') q' + G(q) = tau`` of the RRPR arm, and of any arm model.

All functions are vectorised: ``q`` and ``dq`` may carry any leading batch
shape ``(..., n)``; matrices come back as ``(..., n, n)``.  For the paper's
RRPR (n = 4) the joint order is
``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]``.
:func:`inertia`, :func:`gravity`, :func:`forward_dynamics`,
:func:`inverse_dynamics` and :func:`kinetic_energy` take any
:class:`~blocks.model.arm.ArmModel` (its row kernels); the others are the RRPR's
closed form (Eq. 6's matrix, ``dM/dtheta2``, its potential energy).

The formulas are those of :mod:`blocks.model.rrpr.dynamics_kernels` (joint rows first); these
functions present them in the joint-last layout that analysis code and users
expect.  Each checks its arguments once (:mod:`blocks.model.validation`): a wrong
type raises TypeError, a wrong shape or a non-finite entry ValueError, naming
the argument.
"""
from __future__ import annotations

import numpy as np

from blocks.model.rrpr.dynamics_kernels import arm_constants, coriolis_forces
from blocks.model.rrpr.parameters import RobotParameters, robot_parameters
from blocks.model.validation import arm_model, joint_array, joint_arrays

__all__ = [
    "inertia", "inertia_derivative_theta2", "coriolis_vector", "coriolis_matrix", "gravity",
    "forward_dynamics", "inverse_dynamics", "kinetic_energy", "potential_energy",
]


def _checked(params, any_arm: bool = False, **arrays) -> list[np.ndarray]:
    """The arguments of a public function checked once (:mod:`blocks.model.validation`): the joint arrays, broadcast."""
    joints = (arm_model(params, "params") if any_arm else robot_parameters(params)).joints
    if len(arrays) == 1:
        (name, value), = arrays.items()
        return [joint_array(value, name, joints)]
    return joint_arrays(arrays, joints)


def _rows(x) -> np.ndarray:
    """A checked joint-last array as rows (joint first), for the kernels."""
    return np.moveaxis(x, -1, 0)


def _joint_last(rows: np.ndarray) -> np.ndarray:
    return np.moveaxis(rows, 0, -1)


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
    q, = _checked(params, True, q=q)
    return params.kernels.inertia_matrix(params.kernel_params(), _rows(q))


def inertia_derivative_theta2(q, params: RobotParameters) -> np.ndarray:
    """Partial derivative ``dM/dtheta2`` (the only configuration dependence), shape (..., 4, 4).

    ``M`` depends on ``theta2`` through ``k2 cos(theta2)`` in ``m00`` and half of it in ``m01``.
    """
    q, = _checked(params, q=q)
    k2s2 = params.constants.k2 * np.sin(q[..., 1])
    dM = np.zeros(q.shape[:-1] + (4, 4))
    dM[..., 0, 0] = -k2s2
    dM[..., 0, 1] = dM[..., 1, 0] = -0.5 * k2s2
    return dM


def coriolis_vector(q, dq, params: RobotParameters) -> np.ndarray:
    """Coriolis and centrifugal torques ``N(q, q') q'`` of Eq. 6, shape (..., 4), in N m / N."""
    q, dq = _checked(params, q=q, dq=dq)
    return _joint_last(coriolis_forces(arm_constants(params), _rows(q), _rows(dq)))


def coriolis_matrix(q, dq, params: RobotParameters) -> np.ndarray:
    """Christoffel factorisation ``C(q, q')`` with ``C q' = N q'`` and ``M' - 2C`` skew-symmetric.

    This is not the paper's printed matrix N (which gives the same vector but
    not the skew property); see ``docs/model.md``.  Shape (..., 4, 4).
    """
    q, dq = _checked(params, q=q, dq=dq)
    h = 0.5 * params.constants.k2 * np.sin(q[..., 1])
    C = np.zeros(np.broadcast(q, dq).shape[:-1] + (4, 4))
    C[..., 0, 0] = -h * dq[..., 1]
    C[..., 0, 1] = -h * (dq[..., 0] + dq[..., 1])
    C[..., 1, 0] = h * dq[..., 0]
    return C


def gravity(q, params: RobotParameters) -> np.ndarray:
    """Gravity vector ``G(q)`` of Eq. 7 (``d3`` positive downwards), shape (..., 4)."""
    q, = _checked(params, True, q=q)
    # N q' vanishes at q' = 0, leaving G
    return _joint_last(params.kernels.bias_forces(params.kernel_params(), _rows(q), np.zeros_like(_rows(q))))


def forward_dynamics(q, dq, tau, params: RobotParameters) -> np.ndarray:
    """Joint accelerations ``q'' = M^-1 (tau - N q' - G)``, shape (..., 4).

    Parameters
    ----------
    q, dq : array_like, shape (..., 4)
        Joint positions and velocities (rad, m; rad/s, m/s).
    tau : array_like, shape (..., 4)
        Total generalised force on each joint (N m, N for joint 3).
    """
    q, dq, tau = _checked(params, True, q=q, dq=dq, tau=tau)
    k, kern = params.kernel_params(), params.kernels
    force = _rows(tau) - kern.bias_forces(k, _rows(q), _rows(dq))
    return _joint_last(kern.mass_solve(k, _rows(q), force))


def inverse_dynamics(q, dq, ddq, params: RobotParameters) -> np.ndarray:
    """Generalised forces ``M q'' + N q' + G`` that produce ``ddq``, shape (..., 4)."""
    q, dq, ddq = _checked(params, True, q=q, dq=dq, ddq=ddq)
    k, kern = params.kernel_params(), params.kernels
    rows = kern.mass_times(k, _rows(q), _rows(ddq)) + kern.bias_forces(k, _rows(q), _rows(dq))
    return _joint_last(rows)


def kinetic_energy(q, dq, params: RobotParameters) -> np.ndarray:
    """Kinetic energy ``0.5 q'^T M(q) q'`` in J, shape (...)."""
    q, dq = _checked(params, True, q=q, dq=dq)
    rows = _rows(dq)
    return 0.5 * np.sum(rows * params.kernels.mass_times(params.kernel_params(), _rows(q), rows), axis=0)


def potential_energy(q, params: RobotParameters) -> np.ndarray:
    """Gravitational potential energy in J (zero at ``d3 = 0``), consistent with ``G = dV/dq``."""
    q, = _checked(params, q=q)
    return -params.constants.k4 * params.g * q[..., 2]
