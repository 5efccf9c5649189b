"""Arm models beyond the paper's RRPR: any serial arm from a URDF (pinocchio reads it, dobkit's kernels compute).

``load_urdf_arm(path, tool_frame, locked=(), locked_values=None, gravity=None)`` gives a
:class:`ChainArm`, an :class:`~blocks.model.arm.ArmModel`; :func:`scope4_urdf` is the bundled 4-joint surgical arm,
:func:`example_urdf` finds every serial arm of ``example-robot-data`` by name (:func:`example_arms` lists
them); :func:`joint_path` turns a task-space path of the tool point into joint references (damped least-squares
IK when at most three joints move the point, the integrated resolved-rate law of
:mod:`~blocks.model.urdf.resolved_rate` for a redundant arm).
"""
from blocks.lazy import lazy_exports

_WHERE = {
    "chain_model": ("ChainArm",),
    "urdf": ("load_urdf_arm", "UrdfError", "UrdfFileError", "UrdfParseError", "UnknownFrameError",
             "UnknownJointError", "UnsupportedJointError", "InertiaError"),
    "examples": ("example_urdf", "scope4_urdf", "example_arm", "example_arms", "example_names"),
    "ik": ("joint_path", "solve_ik", "jacobian_rate", "IKUnreachableError", "JointPath"),
}
__all__ = sorted(name for names in _WHERE.values() for name in names)
__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals())
