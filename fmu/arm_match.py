"""Whether a plant FMU is the plant of a scenario's arm: its joints, its model kind and its recorded bodies.

Checked before an FMU runs as a scenario's plant (:func:`fmu.load` with a
scenario, co-simulation, the convergence study, ``dobkit fmu check --arm``):
an FMU of another arm would otherwise run and give another arm's numbers.
"""
from __future__ import annotations

import math

from .errors import FMUError

__all__ = ["arm_name", "check_arm_matches", "check_scenario_arm", "joint_count"]


def joint_count(model_description) -> int:
    """Number of joints of a dobkit plant FMU: its inputs ``tau[i]``."""
    return sum(1 for v in model_description.modelVariables if v.causality == "input" and v.name.startswith("tau["))


def arm_name(arm) -> str:
    """How a report names an arm (:meth:`blocks.model.arm.ArmModel.in_words`): ``the 4-joint arm ['yaw', ...] from
    <file>``."""
    return arm.in_words()


def check_arm_matches(model_description, arm, name: str) -> None:
    """Refuse, by name, an FMU whose joints are not the arm's: count, kinds (units of ``q[i]``), ranges.

    Raises
    ------
    FMUError
        Naming the first difference.
    """
    n = joint_count(model_description)
    joints = arm.joints
    if n != joints.count:
        raise FMUError(f"the FMU has {n} joints (inputs tau[0..{n - 1}]); {name} has {joints.count}: the FMU is "
                       "not this arm's plant")
    by_name = {v.name: v for v in model_description.modelVariables}
    for i in range(n):
        v = by_name.get(f"q[{i}]")
        if v is None:
            raise FMUError(f"the FMU has no variable q[{i}]: it is not a dobkit plant FMU")
        unit = joints.position_units[i]
        if v.unit is not None and v.unit != unit:
            raise FMUError(f"q[{i}] of the FMU is in {v.unit}; joint {i + 1} ({joints.names[i]}) of {name} is "
                           f"{joints.kinds[i]} ({unit}): the FMU is not this arm's plant")
        lo, hi = joints.limits[i]
        fmu_lo = -math.inf if v.min is None else float(v.min)
        fmu_hi = math.inf if v.max is None else float(v.max)
        if (fmu_lo, fmu_hi) != (lo, hi) and not (v.min is None and v.max is None):
            raise FMUError(f"q[{i}] of the FMU ranges from {fmu_lo:g} to {fmu_hi:g} {unit}; joint {joints.names[i]} "
                           f"of {name} from {lo:g} to {hi:g} {unit}: the FMU is not this arm's plant")


def check_scenario_arm(extracted, model_description, scenario, parameters: str = "scenario") -> None:
    """Refuse a dobkit plant FMU exported for another arm than ``scenario``'s, before it is run as its plant.

    A dobkit plant FMU (one with ``disturbance_paper``) is the paper's RRPR
    (Table-1 parameters, no arm record) or the arm recorded in it
    (:mod:`fmu.arm_record`).  Its joints must be the scenario arm's
    (:func:`check_arm_matches`), its model the same kind, and, with
    ``parameters="scenario"``, a recorded arm's bodies the scenario's: they
    are constants of its C code, which no start value changes.  Another FMU
    is taken at the user's word.

    Raises
    ------
    FMUError
        Naming the FMU's arm, the scenario's arm and what to do.
    """
    from .arm_record import ARM_RECORD, arm_from_record

    names = {v.name for v in model_description.modelVariables}
    if "disturbance_paper" not in names:
        return
    arm = scenario.robot
    theirs = f"the arm of scenario {scenario.name!r}, {arm_name(arm)}"
    check_arm_matches(model_description, arm, theirs)
    record = extracted.root / ARM_RECORD
    recorded = arm_from_record(record.read_text(encoding="utf-8")) if record.is_file() else None
    export = f"export this scenario's plant (dobkit fmu export --scenario {scenario.name})"
    # an FMU without an arm record is the arm of the paper, exported with its named parameters
    if (arm.paper is not None) != (recorded is None):
        mine = "the paper's RRPR arm (Table-1 parameters)" if recorded is None else f"{arm_name(recorded)} " \
               "(recorded in it)"
        raise FMUError(f"the FMU is the plant of {mine}; {theirs}: it is not this scenario's plant; {export}")
    chain = getattr(arm, "chain", None)          # an arm model of the user's own: its joints were the check
    differ = [] if recorded is None or chain is None else [
        f for f in type(chain).__dataclass_fields__ if getattr(chain, f) != getattr(recorded.chain, f)]  # eq=False
    if differ and parameters == "scenario":
        verb = "differs" if len(differ) == 1 else "differ"
        raise FMUError(f"the FMU is the plant of {arm_name(recorded)} (recorded in it), whose {', '.join(differ)} "
                       f"{verb} from {theirs}; an exported arm's bodies are constants of its code, which the "
                       f"scenario's values cannot set: {export}, or keep the FMU's own arm (--parameters fmu)")
