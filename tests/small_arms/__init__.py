"""Two small arms written for the tests (closed form, by hand): a 2-link planar arm and a 3-joint cylindrical arm.

They subclass :class:`blocks.model.arm.ArmModel` with their own row-kernel modules, so the
analyses can be held against textbook derivations for a joint count other than four.
"""
from __future__ import annotations

import math

import numpy as np

from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace

from . import cylinder3_kernels, planar2_kernels

__all__ = ["PlanarTwoLink", "Cylindrical"]


class PlanarTwoLink(ArmModel):
    """Two revolute links in a vertical plane (gravity along -y), centres of mass at lc1, lc2.

    Textbook closed form (Spong, Hutchinson and Vidyasagar, Sec. 7.3):
    ``M11 = m1 lc1^2 + m2 (l1^2 + lc2^2 + 2 l1 lc2 c2) + I1 + I2``,
    ``M12 = m2 (lc2^2 + l1 lc2 c2) + I2``, ``M22 = m2 lc2^2 + I2``.
    """

    joints = JointSpace(names=("shoulder", "elbow"), kinds=("revolute", "revolute"),
                        limits=((-math.inf, math.inf), (-2.6, 2.6)))
    kernels = planar2_kernels
    tool_kernels = planar2_kernels

    def __init__(self, m1=2.0, m2=1.2, l1=0.5, l2=0.4, lc1=0.25, lc2=0.2, I1=0.05, I2=0.02, g=9.81):
        self.p = dict(m1=m1, m2=m2, l1=l1, l2=l2, lc1=lc1, lc2=lc2, I1=I1, I2=I2, g=g)

    def kernel_params(self):
        p = self.p
        return np.array([p["m1"], p["m2"], p["l1"], p["lc1"], p["lc2"], p["I1"], p["I2"], p["g"]])

    def tool_params(self):
        return np.array([self.p["l1"], self.p["l2"]])


class Cylindrical(ArmModel):
    """A base turning about the vertical (theta), a vertical stage (z, up) and a radial stage (r).

    The radial stage's mass m3 sits at radius r: ``M = diag(J + m3 r^2, m2 + m3, m3)``,
    ``h = [2 m3 r r' theta', (m2 + m3) g, -m3 r theta'^2]``, tool at ``(r cos theta, r sin theta, z)``.
    """

    joints = JointSpace(names=("theta", "z", "r"), kinds=("revolute", "prismatic", "prismatic"),
                        limits=((-math.inf, math.inf), (0.0, 0.5), (0.2, 0.6)))
    kernels = cylinder3_kernels
    tool_kernels = cylinder3_kernels

    def __init__(self, J=0.3, m2=4.0, m3=1.5, g=9.81):
        self.p = dict(J=J, m2=m2, m3=m3, g=g)

    def kernel_params(self):
        return np.array([self.p["J"], self.p["m2"], self.p["m3"], self.p["g"]])

    def tool_params(self):
        return np.zeros(0)
