"""Start values that make a plant FMU the true plant of a scenario.

Shared by :func:`fmu.load` (``scenario=``) and
:func:`fmu.cosimulate` (``parameters="scenario"``), so that a loaded
block and a co-simulated FMU get the same values.
"""
from __future__ import annotations

import warnings

from blocks.scenarios.scenario import Scenario, default_arm

from .variables import plant_parameter_values

__all__ = ["plant_start_values", "JOINTS", "DEFAULT_START_Q", "default_start_q"]

#: Joint count of the default scenario's arm.
JOINTS = default_arm().n

#: Start pose of the default scenario's arm's plant FMU exported without one (rad, rad, m, rad; the arm's
#: :meth:`~blocks.model.arm.ArmModel.rest_pose`: the paper's elbow at a right angle, the tool slide at d3 = 0.24 m).
#: An export from a scenario (``dobkit fmu export``) starts where the scenario does.
DEFAULT_START_Q = tuple(default_arm().rest_pose())


def default_start_q(arm) -> list[float]:
    """Start pose of an arm's plant FMU exported without one (rad, m): the arm's own rest pose
    (:meth:`blocks.model.arm.ArmModel.rest_pose`; for a chain each joint at 0, or at the middle of its range when the
    range excludes 0: the Panda's elbow, -3.07 to -0.07 rad, starts at -1.57 rad)."""
    return arm.rest_pose()


def plant_start_values(scenario: Scenario, fmu_variables: set[str] | None, parameters: str = "scenario",
                       stacklevel: int = 3) -> dict:
    """FMU start values for a scenario: the arm's start state and, optionally, its true-plant parameters.

    Parameters
    ----------
    scenario : Scenario
        The arm starts at ``initial.q`` / ``initial.dq`` when set, else on the
        reference at t = 0 (rad, m; rad/s, m/s).
    fmu_variables : set of str or None
        Names the FMU declares; scenario parameters it lacks are left out with
        a warning naming them (None: keep all).
    parameters : {"scenario", "fmu"}
        ``scenario``: include the true robot parameters (Table 1 names) and the
        disturbance models and their parameters; ``fmu``: the state only.
    stacklevel : int
        Passed to :func:`warnings.warn` so that the warning points at the caller's caller.

    Returns
    -------
    dict
        Variable name -> value (``q[i]``, ``dq[i]`` and, with ``scenario``, ``m1`` ... ``disturbance_tissue``).

    Raises
    ------
    ValueError
        If ``parameters`` is neither ``"scenario"`` nor ``"fmu"``.
    """
    if parameters not in ("scenario", "fmu"):
        raise ValueError(f"parameters must be 'scenario' or 'fmu', got {parameters!r}")
    s = scenario
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    n = s.robot.joints.count
    values = {f"q[{i}]": float(q0[i]) for i in range(n)} | {f"dq[{i}]": float(dq0[i]) for i in range(n)}
    if parameters == "scenario":
        wanted = plant_parameter_values(s.robot, s.disturbance)
        if fmu_variables is not None:
            absent = sorted(set(wanted) - fmu_variables)
            if absent:
                warnings.warn(f"the FMU does not declare scenario parameter(s) {absent}; it uses its own values",
                              stacklevel=stacklevel)
            wanted = {k: v for k, v in wanted.items() if k in fmu_variables}
        values |= wanted
    return values
