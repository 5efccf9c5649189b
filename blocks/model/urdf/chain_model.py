"""A serial (or tree) arm given by its geometry and inertias: the :class:`~blocks.model.arm.ArmModel` of URDF arms.

The maths is :mod:`blocks.kernels.chain` (CRBA, RNEA, Cholesky, tool
point) on a :class:`~blocks.kernels.chain.ChainParams`; this class adds the
joints (names, kinds, units, limits) and the bookkeeping between dobkit's
joint vector (one number per joint: an angle for a continuous joint) and
pinocchio's configuration (a continuous joint is ``(cos, sin)`` there).
"""
from __future__ import annotations

import numpy as np

from blocks.kernels import chain as _chain
from blocks.kernels.chain import ChainParams
from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace

__all__ = ["ChainArm"]


class ChainArm(ArmModel):
    """An arm of ``n`` revolute and prismatic joints from its kinematic tree and body inertias.

    Parameters
    ----------
    chain : ChainParams
        Geometry, inertias, gravity and tool frame (see :class:`~blocks.kernels.chain.ChainParams`).
    joints : JointSpace
        Names, kinds and limits (rad, m) of the joints, in the chain's order.
    tool_frame : str
        Name of the tool frame (for messages and reports).
    continuous : tuple of bool, optional
        Which joints are continuous (pinocchio keeps them as ``(cos, sin)``).
    source : str, optional
        Where the arm came from (the URDF path), for messages.

    Attributes
    ----------
    pin_model : pinocchio.Model or None
        The reduced pinocchio model the chain was read from (locked joints
        removed), kept as the reference for tests; None when built otherwise.
    """

    kernels = _chain
    tool_kernels = _chain

    def __init__(self, chain: ChainParams, joints: JointSpace, tool_frame: str, continuous=None,
                 source: str | None = None) -> None:
        if joints.count != chain.n or tuple(joints.kinds) != tuple(chain.kinds):
            raise ValueError(f"joints {joints.names} ({joints.kinds}) do not match the chain's {chain.n} joints "
                             f"({chain.kinds})")
        self.chain = chain
        self.joints = joints
        self.tool_frame = tool_frame
        self.continuous = tuple(bool(c) for c in (continuous or (False,) * chain.n))
        self.source = source
        self.pin_model = None

    def __repr__(self) -> str:
        return f"ChainArm({self.n} joints {list(self.joints.names)}, tool {self.tool_frame!r}, from {self.source!r})"

    def kernel_params(self) -> ChainParams:
        """The :class:`~blocks.kernels.chain.ChainParams` the row kernels take (structure for a trace)."""
        return self.chain

    def tool_params(self) -> ChainParams:
        """The same :class:`~blocks.kernels.chain.ChainParams`: it carries the tool frame."""
        return self.chain

    @property
    def gravity(self) -> np.ndarray:
        """Gravitational acceleration in the base frame (m/s^2), shape (3,)."""
        return np.array(self.chain.gravity)

    def pinocchio_configuration(self, q) -> np.ndarray:
        """pinocchio's configuration vector of joint positions ``q`` (shape (n,)): ``(cos, sin)`` for a
        continuous joint, the value itself otherwise."""
        q = np.asarray(q, dtype=float).reshape(self.n)
        parts = [np.array([np.cos(v), np.sin(v)]) if c else np.array([v]) for v, c in zip(q, self.continuous)]
        return np.concatenate(parts)
