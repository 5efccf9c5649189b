"""Arm models, each in its own place: the paper's RRPR in closed form (:mod:`blocks.model.rrpr`).

Every layer above an arm model reads the arm through :class:`blocks.model.arm.ArmModel` (joints, dynamics, tool
kinematics, what it describes for a report); none of them names a particular arm.  URDF chains are
:mod:`blocks.model.urdf`.
"""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
