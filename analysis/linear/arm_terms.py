"""What the analyses read of an arm model: joint vectors, workspace ranges, and derivatives of its dynamics.

Every analysis takes the joint count, names, units and limits from the
model (:class:`blocks.model.arm.ArmModel`), never from a constant.  The
derivatives the linearization and the observer certificate need
(:func:`inertia_partials`, :func:`acceleration_jacobians`, with the step
:data:`FD_STEP`) live in :mod:`blocks.model.arm_derivatives`, where the sampled
loop's stability check (:mod:`blocks.figure2.digital_stability`) takes the gravity
slope from the same source; they are re-exported here.
"""
from __future__ import annotations

import math

import numpy as np

from blocks.model.arm import ArmModel
from blocks.model.arm_derivatives import FD_STEP, acceleration_jacobians, gravity_slopes, inertia_partials
from blocks.model.joints import JointSpace

__all__ = ["FD_STEP", "arm_model", "joint_vector", "joint_matrix", "workspace_ranges",
           "default_points", "inertia_partials", "acceleration_jacobians", "gravity_slopes"]


# Full-factorial grids of other arms hold at most about this many configurations.
_GRID_BUDGET = 20000


def arm_model(model, name: str = "arm") -> ArmModel:
    """``model`` checked to be an arm model (:class:`blocks.model.arm.ArmModel`)."""
    if not isinstance(model, ArmModel):
        raise TypeError(f"{name} must be a blocks.model.arm.ArmModel (for example the default scenario's arm, "
                        "blocks.model.default.default_arm()), "
                        f"got {type(model).__name__}")
    return model


def joint_vector(value, name: str, joints: JointSpace) -> np.ndarray:
    """``value`` as ``n`` finite numbers, one per joint in the joint's unit; a clear ValueError otherwise."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (joints.count,) or not np.all(np.isfinite(arr)):
        units = ", ".join(joints.position_units)
        raise ValueError(f"{name} must be {joints.count} finite numbers ({units}), one per joint "
                         f"{list(joints.names)}, got {value!r}")
    return arr


def joint_matrix(value, name: str, n: int) -> np.ndarray:
    """``value`` as an ``n x n`` gain: a scalar (times I), ``n`` numbers (diagonal) or ``n x n``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = arr * np.eye(n)
    elif arr.shape == (n,):
        arr = np.diag(arr)
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite scalar, {n} numbers or an {n} x {n} matrix, got {value!r}")
    return arr


def workspace_ranges(joints: JointSpace) -> tuple[tuple[float, float], ...]:
    """Where the analyses sample each joint: within its limits; a full turn for an unlimited revolute joint.

    An arm whose joints carry survey ranges (:attr:`blocks.model.joints.JointSpace.survey_ranges`, the paper's) keeps
    them.  A revolute
    joint limited on one side only turns a full turn from that side.

    Raises
    ------
    ValueError
        For a prismatic joint without finite limits (no range to sample), naming it.
    """
    if joints.survey_ranges is not None:
        return joints.survey_ranges
    out = []
    for name, kind, (lo, hi) in zip(joints.names, joints.kinds, joints.limits):
        if math.isfinite(lo) and math.isfinite(hi):
            out.append((lo, hi))
        elif kind == "revolute":
            out.append((lo, lo + 2 * math.pi) if math.isfinite(lo) else
                       (hi - 2 * math.pi, hi) if math.isfinite(hi) else (-math.pi, math.pi))
        else:
            raise ValueError(f"joint {name!r} is prismatic with limits ({lo}, {hi}) m: give it finite limits "
                             "(or pass ranges) so that its range can be sampled")
    return tuple(out)


def default_points(joints: JointSpace) -> tuple[int, ...]:
    """Points per joint of the default survey grid: :attr:`~blocks.model.joints.JointSpace.survey_points` where the
    arm's joints carry them (the paper's), else the same count on every joint with at most about 20000
    configurations in all (3 to 73 per joint)."""
    if joints.survey_points is not None:
        return joints.survey_points
    per = int(math.floor(_GRID_BUDGET ** (1.0 / joints.count) + 1e-9))
    return (min(73, max(3, per)),) * joints.count
