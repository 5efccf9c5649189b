"""The paper's RRPR surgical arm in closed form: Table 1, Eq. 5-8, its joint ranges and the laceration path's IK.

Modules
-------
:mod:`~blocks.model.rrpr.parameters`
    :class:`RobotParameters` (Table 1, the inertia constants k1..k5; an :class:`~blocks.model.arm.ArmModel`).
:mod:`~blocks.model.rrpr.joints`
    :data:`RRPR_JOINTS` (theta1, theta2, d3, theta4) and the prismatic stroke :data:`D3_STROKE`.
:mod:`~blocks.model.rrpr.dynamics_kernels`, :mod:`~blocks.model.rrpr.tool_kernels`
    The row kernels the laws, engines and code generator call (M, M v, M^-1 r, N q' + G; the tool pose).
:mod:`~blocks.model.rrpr.dynamics`, :mod:`~blocks.model.rrpr.kinematics`
    The same maths joint-last, checked, for analyses and users (Eq. 5-7; Eq. 8 as corrected, its inverse).
:mod:`~blocks.model.rrpr.laceration`
    :class:`LacerationPath`: the suturing path's joint references by closed-form inverse kinematics.

Nothing outside this package names the RRPR except the paper scenario (the default scenario) and the top-level
API's re-exports (``blocks.RobotParameters``, ...).
"""
from blocks.lazy import lazy_exports

_WHERE = {
    "parameters": ("RobotParameters", "InertiaConstants", "PAPER_PARAMETERS", "ParameterError"),
    "joints": ("RRPR_JOINTS", "D3_STROKE"),
    "dynamics": ("inertia", "inertia_derivative_theta2", "coriolis_vector", "coriolis_matrix", "gravity",
                 "forward_dynamics", "inverse_dynamics", "kinetic_energy", "potential_energy"),
    "kinematics": ("ELBOWS", "forward_kinematics", "jacobian", "jacobian_derivative_times_dq", "inverse_kinematics",
                   "planar_reach"),
    "laceration": ("LacerationPath",),
}
__all__ = sorted(name for names in _WHERE.values() for name in names)
__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals())
