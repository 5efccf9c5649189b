"""The arm as a model: what every layer above the dynamics may know of a serial manipulator.

An :class:`ArmModel` gives the joints (count, names, kinds, units, limits),
the dynamics ``M(q) q'' + h(q, q') = tau`` with ``h = N(q, q') q' + G(q)``,
and the kinematics of one tool point (its position in the base frame, the
linear Jacobian and ``J'(q, q') q'``).  Laws, blocks, engines, scenario,
analysis, reports and FMU export take ``n``, names and units from
:attr:`ArmModel.joints` and the numbers from these methods; none of them may
assume the paper's four joints.

Two layers, one source
----------------------
*Row kernels* (:attr:`ArmModel.kernels`, :attr:`ArmModel.tool_kernels`)
are plain numpy functions of joint-first rows (``q[i]`` is a scalar, a
column or a traced symbol) that the engines call and the code generator
traces (:mod:`blocks.compiled.trace`).  A kernel module provides::

    inertia_matrix(k, q)            -> M(q), shape q.shape[1:] + (n, n)
    mass_times(k, q, v)             -> M(q) v, rows
    mass_solve(k, q, r)             -> M(q)^-1 r, rows
    bias_forces(k, q, dq)           -> N(q, q') q' + G(q), rows
    gravity_forces(k, q)            -> G(q), rows
    plant_acceleration(k, q, dq, f) -> M^-1 (f - h), rows

and a tool-kernel module::

    tool_position(kin, q)              -> p, rows (3,)
    tool_jacobian(kin, q)              -> dp/dq, rows (3, n)
    tool_acceleration_bias(kin, q, dq) -> J' q', rows (3,)

with ``k = arm.kernel_params()`` and ``kin = arm.tool_params()``.  The
methods of this class present the same numbers joint-last (``(..., n)``),
the layout analysis code and users expect.

The paper's RRPR (:class:`~blocks.model.rrpr.parameters.RobotParameters`, Table 1,
Eq. 5-8 in closed form) is the first model.
"""
from __future__ import annotations

import abc
import types

import numpy as np

from .joints import JointSpace

__all__ = ["ArmModel", "UnreachableError"]


class UnreachableError(ValueError):
    """A task-space point lies outside the arm's reachable workspace (or too near a singularity), or a reference
    leaves a joint's range."""


def _rows(x) -> np.ndarray:
    return np.moveaxis(np.asarray(x, dtype=float), -1, 0)


def _joint_last(rows) -> np.ndarray:
    return np.moveaxis(np.asarray(rows), 0, -1)


class ArmModel(abc.ABC):
    """A serial arm: joints, rigid-body dynamics and one tool point.

    Subclasses set :attr:`joints`, :attr:`kernels` and :attr:`tool_kernels` and
    implement :meth:`kernel_params` and :meth:`tool_params`; the joint-last
    methods below follow from them.
    """

    #: The joints, in order: count, names, kinds, units, limits.
    joints: JointSpace
    #: Module of the dynamics row kernels (see the module docstring).
    kernels: types.ModuleType
    #: Module of the tool-point row kernels.
    tool_kernels: types.ModuleType

    @abc.abstractmethod
    def kernel_params(self):
        """The parameters ``k`` the dynamics row kernels take."""

    @abc.abstractmethod
    def tool_params(self):
        """The parameters ``kin`` the tool row kernels take."""

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.joints.count

    # -- dynamics, joint-last -------------------------------------------------------------------------
    def inertia(self, q) -> np.ndarray:
        """``M(q)`` (kg m^2, kg on prismatic joints), shape ``(..., n, n)`` for ``q`` of shape ``(..., n)``."""
        return np.asarray(self.kernels.inertia_matrix(self.kernel_params(), _rows(q)))

    def bias(self, q, dq) -> np.ndarray:
        """``h(q, q') = N(q, q') q' + G(q)`` (N m, N), shape ``(..., n)``."""
        q, dq = np.broadcast_arrays(np.asarray(q, dtype=float), np.asarray(dq, dtype=float))
        return _joint_last(self.kernels.bias_forces(self.kernel_params(), _rows(q), _rows(dq)))

    def gravity_forces(self, q) -> np.ndarray:
        """``G(q)`` (N m, N), shape ``(..., n)``."""
        return _joint_last(self.kernels.gravity_forces(self.kernel_params(), _rows(q)))

    def forward_dynamics(self, q, dq, tau) -> np.ndarray:
        """``q'' = M(q)^-1 (tau - h(q, q'))`` (rad/s^2, m/s^2), shape ``(..., n)``."""
        q, dq, tau = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (q, dq, tau)))
        return _joint_last(self.kernels.plant_acceleration(self.kernel_params(), _rows(q), _rows(dq), _rows(tau)))

    def inverse_dynamics(self, q, dq, ddq) -> np.ndarray:
        """``tau = M(q) q'' + h(q, q')`` (N m, N), shape ``(..., n)``."""
        q, dq, ddq = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (q, dq, ddq)))
        k = self.kernel_params()
        rows = self.kernels.mass_times(k, _rows(q), _rows(ddq)) + self.kernels.bias_forces(k, _rows(q), _rows(dq))
        return _joint_last(rows)

    # -- the tool point, joint-last -------------------------------------------------------------------
    def tool_position(self, q) -> np.ndarray:
        """Tool-point position in the base frame (m), shape ``(..., 3)``."""
        return _joint_last(self.tool_kernels.tool_position(self.tool_params(), _rows(q)))

    def tool_jacobian(self, q) -> np.ndarray:
        """Linear Jacobian ``dp/dq`` of the tool point, shape ``(..., 3, n)`` (m/rad, m/m)."""
        J = np.asarray(self.tool_kernels.tool_jacobian(self.tool_params(), _rows(q)))
        return np.moveaxis(J, (0, 1), (-2, -1))

    def tool_acceleration_bias(self, q, dq) -> np.ndarray:
        """``J'(q, q') q'`` (m/s^2), shape ``(..., 3)``: the tool point's acceleration when ``q'' = 0``."""
        q, dq = np.broadcast_arrays(np.asarray(q, dtype=float), np.asarray(dq, dtype=float))
        return _joint_last(self.tool_kernels.tool_acceleration_bias(self.tool_params(), _rows(q), _rows(dq)))
