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
traces (:mod:`blocks.kernels.trace`).  A kernel module provides::

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

with ``k = arm.kernel_params()`` and ``kin = arm.tool_params()``; the laws
take both as one value, ``arm.arm_kernels``.  The
methods of this class present the same numbers joint-last (``(..., n)``),
the layout analysis code and users expect.

What the layers above ask of an arm beyond its maths is asked here too, never by testing which arm it is:
its name and one-line description, the pose it rests in, its named physical parameters (what a scenario's
``[robot]`` section, a sweep or an FMU may set), whether its kernel constants stack per batch member, whether
its gravity is the same in every configuration, whether it is the arm a publication's numbers are for (so that
reports compare with them), and its own closed-form laceration path, if it has one.

The paper's RRPR (:mod:`blocks.model.rrpr`, Table 1, Eq. 5-8 in closed form) is the first model; a URDF chain
(:mod:`blocks.model.urdf`) another.
"""
from __future__ import annotations

import abc
import math
import types
from typing import ClassVar

import numpy as np

from blocks.model.joints import JointSpace

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
    #: The publication whose arm this is, for reports that compare with its numbers; None for any other arm.
    paper: ClassVar[str | None] = None
    #: Whether ``k = kernel_params()`` is one flat float vector that a batch stacks per member (a closed form).
    stacks_constants: ClassVar[bool] = False
    #: Whether ``G(q)`` is the same in every configuration (then ``dG/dq = 0`` and the sampled maps lose a term).
    constant_gravity: ClassVar[bool] = False
    #: The joints ``M(q)`` depends on, where the model knows them in closed form (None: not known).
    inertia_depends_on: ClassVar[tuple[int, ...] | None] = None
    #: Values of the second joint at which the sampled loop's gain-limit study holds the arm, where the arm's
    #: source chose them (None: within the joint's survey range).
    held_values: ClassVar[tuple[float, ...] | None] = None

    @abc.abstractmethod
    def kernel_params(self):
        """The parameters ``k`` the dynamics row kernels take."""

    @abc.abstractmethod
    def tool_params(self):
        """The parameters ``kin`` the tool row kernels take."""

    @property
    def arm_kernels(self):
        """Both kernel modules as one value (:class:`~blocks.kernels.model.ArmKernels`), the ``model`` argument of
        the laws and block kernels of :mod:`blocks.kernels`."""
        from blocks.kernels.model import arm_kernels
        return arm_kernels(self)

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.joints.count

    # -- what the layers above ask of an arm ------------------------------------------------------------
    @property
    def name(self) -> str:
        """How messages and output files name the arm (a model may set its own)."""
        return type(self).__name__

    def description(self) -> str:
        """One line for reports and exported models: joint count, names and the tool point."""
        tool = getattr(self, "tool_frame", None)
        return f"{self.n}-joint arm ({', '.join(self.joints.names)}" + (f"; tool {tool})" if tool else ")")

    def in_words(self) -> str:
        """How a sentence names the arm: ``the 6-joint arm ['shoulder_pan', ...] from <file>``."""
        source = getattr(self, "source", None)
        return f"the {self.n}-joint arm {list(self.joints.names)}" + (f" from {source}" if source else "")

    def closed_form_inertia_partials(self, q):
        """``dM/dq_j`` (shape (..., n, n, n), last-but-two axis j) where the model has them in closed form; None
        when it has not (the analyses then differentiate ``M`` numerically)."""
        return None

    def rest_pose(self) -> list[float]:
        """A pose to start in when none is given (rad, m): each joint at 0, or at the middle of its range when the
        range excludes 0 (a range open on one side: its finite end)."""
        def start(lo: float, hi: float) -> float:
            if lo <= 0.0 <= hi:
                return 0.0
            if math.isfinite(lo) and math.isfinite(hi):
                return 0.5 * (lo + hi)
            return lo if math.isfinite(lo) else hi

        return [start(lo, hi) for lo, hi in self.joints.limits]

    def parameter_names(self) -> tuple[str, ...]:
        """The arm's named physical parameters a scenario, a sweep or an FMU may set (none: its numbers are fixed)."""
        return ()

    def parameter_unit(self, name: str) -> str:
        """SI unit of the named parameter (see :meth:`parameter_names`)."""
        raise KeyError(f"{self.name} has no parameter {name!r}; it has {list(self.parameter_names()) or 'none'}")

    def parameter_positive(self, name: str) -> bool:
        """Whether the named parameter must be > 0 (a mass, a length), else any finite number (an offset)."""
        self.parameter_unit(name)
        return True

    def parameter_description(self, name: str) -> str:
        """What the named parameter is, in a few words (an exported FMU's variable description)."""
        return name

    def calculated_parameters(self) -> tuple[tuple[str, str, str], ...]:
        """Constants the model computes from its parameters, as ``(name, SI unit, description)`` (an exported
        FMU declares them as calculated parameters); none by default."""
        return ()

    def parameter_values(self) -> dict[str, float]:
        """The named parameters' values (SI), in :meth:`parameter_names` order."""
        return {name: float(getattr(self, name)) for name in self.parameter_names()}

    def with_parameters(self, **values: float) -> ArmModel:
        """A copy with named parameters replaced (SI values); refused for names the arm does not have."""
        if values:
            raise KeyError(f"{self.name} has no parameter(s) {sorted(values)}; it has "
                           f"{list(self.parameter_names()) or 'none'}")
        return self

    def scaled(self, **factors: float) -> ArmModel:
        """A copy with named parameters multiplied by the given factors (a scenario's ``[nominal_scale]``)."""
        values = self.parameter_values()
        return self.with_parameters(**{k: values[k] * f if k in values else f for k, f in factors.items()})

    def parameters_valid(self, values: dict) -> bool:
        """Whether every arm of a batch is valid, its named parameters given as arrays over the members (SI), all
        checked at once: only a model whose constants stack per member (:attr:`stacks_constants`) answers."""
        raise NotImplementedError(f"{self.name} does not check its parameters as columns")

    def stacked_kernel_params(self, values: dict) -> np.ndarray:
        """:meth:`kernel_params` of the arms whose named parameters are ``values`` (SI; numbers or arrays over the
        members of a batch), one column per member, in the model's own operations (the same floats as each
        member's arm gives): only a model whose constants stack per member (:attr:`stacks_constants`) answers."""
        raise NotImplementedError(f"{self.name} does not stack its constants per member")

    def exported_parameter_map(self, values: dict):
        """What a plant FMU whose real parameters are this arm's named parameters computes from them, or None.

        Parameters
        ----------
        values : dict
            The named parameters (:meth:`parameter_names`) as numbers or as traced symbols (their arithmetic
            only: the map is traced into the FMU's C).

        Returns
        -------
        tuple or None
            ``(kernel_params, tool_params, calculated, margins)``: :meth:`kernel_params` and :meth:`tool_params` as
            lists of expressions of ``values``; the calculated constants as ``(name, SI unit, description,
            expression)``; the validity margins as ``(expression, condition in words)``, each > 0 on a valid arm.
            None (the default): the arm's numbers are fixed, structure in the generated code.
        """
        return None

    def laceration_path(self, **keys):
        """The arm's own closed-form joint references for the laceration path (the scenario's ``[trajectory]``
        keys), or None: the tool point then follows the path by IK (:class:`blocks.scenarios.tool_path.ToolLaceration`)."""
        return None

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
