"""The laceration's task-space path and the checks every reference shares: below the blocks, for every arm model.

:func:`laceration_pose` is the suturing path on the skin in task space (stitches along a line or an arc, dips and
needle rolls, each phase a C2 bump or smoothstep); an arm model turns it into joint references (the paper's arm
in closed form, its model's ``laceration_path``; any other arm's tool point by IK,
:class:`blocks.scenarios.tool_path.ToolLaceration`).  :mod:`blocks.diagram.trajectory` describes the path and
builds the reference blocks; the arm models' paths and the scenario layer read these functions from here, so that
no arm model imports the diagram layer.
"""
from __future__ import annotations

import math

import numpy as np

from blocks.kernels.splines import bump6, smoothstep5
from blocks.model.arm import UnreachableError

__all__ = ["LACERATION_FIELDS", "laceration_pose", "finite_values", "one_number", "check_joint_ranges",
           "settle_laceration_shape"]


# --------------------------------------------------------------------------------------------------------------
# Reference kernels: plain functions of a time and a parameter tuple, in the subset of Python numba compiles.
# The path objects call them, and their blocks carry them (see the paper arm's laceration path's ``kernels``).
# --------------------------------------------------------------------------------------------------------------
#: Layout of a laceration path's parameter tuple (the paper arm's laceration path's ``_geometry``).
LACERATION_FIELDS = ("phase_duration", "stitches", "duration", "x0", "y0", "x1", "y1", "bulge", "skin_height",
                     "hover", "depth", "needle_roll", "roll_offset", "a1", "a2", "d1", "d4", "elbow", "q_near1",
                     "q_near4")


def laceration_pose(t, g):
    """Task-space pose ``[x, y, z, phi]`` of a laceration path at time ``t`` (s) and its two rates, as 12 floats.

    ``g`` holds the path's numbers in the order of :data:`LACERATION_FIELDS`.
    """
    T, stitches, duration = g[0], int(g[1]), g[2]
    phase = min(max(math.floor(t / T), 0), 2 * stitches - 2)
    tau = 1.0 if t >= duration else min(max(t / T - phase, 0.0), 1.0)
    step = 1.0 / (stitches - 1)
    # arc parameter s along the laceration advances in travel phases; the dip b acts in stitch phases
    s, ds, dds, b, db, ddb = step * (phase // 2), 0.0, 0.0, 0.0, 0.0, 0.0
    if phase % 2 == 1:
        sig, dsig, ddsig = smoothstep5(tau)
        s, ds, dds = s + step * sig, step * dsig / T, step * ddsig / T ** 2
    else:
        b, db, ddb = bump6(tau)
        db, ddb = db / T, ddb / T ** 2
    # the laceration: start + s (end - start) + a parabolic sideways offset of 'bulge' at its middle
    x0, y0, x1, y1, bulge = g[3], g[4], g[5], g[6], g[7]
    skin_height, hover, depth, needle_roll, roll_offset = g[8], g[9], g[10], g[11], g[12]
    dx, dy = x1 - x0, y1 - y0
    length = math.hypot(dx, dy)
    nx, ny = -dy / length, dx / length
    w, dw, ddw = 4 * bulge * s * (1 - s), 4 * bulge * (1 - 2 * s), -8 * bulge
    tx, ty = dx + dw * nx, dy + dw * ny
    reach = hover + depth
    return (x0 + s * dx + w * nx, y0 + s * dy + w * ny, skin_height + hover - reach * b, roll_offset + needle_roll * b,
            tx * ds, ty * ds, -reach * db, needle_roll * db,
            ddw * nx * ds ** 2 + tx * dds, ddw * ny * ds ** 2 + ty * dds, -reach * ddb, needle_roll * ddb)


def finite_values(value, name: str):
    """``value`` as a float array, refused naming ``trajectory.<name>`` when it is not numbers or not finite."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"trajectory.{name} must be a number or a list of numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"trajectory.{name} must be finite, got {value!r}")
    return arr


def one_number(value, name: str, unit: str) -> float:
    """``value`` as one float (in ``unit``), refused naming ``trajectory.<name>`` otherwise."""
    arr = finite_values(value, name)
    if arr.ndim != 0:
        raise ValueError(f"trajectory.{name} must be one number in {unit}, got {value!r}")
    return float(arr)


def check_joint_ranges(q, joints, what: str, why: str = "") -> None:
    """Refuse joint references ``q`` (shape (..., n)) that leave a joint's range (:attr:`JointSpace.limits
    <blocks.model.joints.JointSpace.limits>`).

    Raises
    ------
    UnreachableError
        Naming ``what`` (the reference), the joint, the value it reaches, its range and ``why`` (the keys that
        set the reference).
    """
    problem = joints.outside_limits(q)
    if problem is not None:
        raise UnreachableError(f"{what}: {problem}" + (f" ({why})" if why else ""))


def settle_laceration_shape(path) -> None:
    """Check the laceration's shape every path of it shares and store it normalised on ``path`` (a frozen
    dataclass): ``start`` and ``end`` as 2 floats each (m, distinct), ``bulge``, ``skin_height``, ``hover`` (>= 0) and
    ``depth`` (> 0) as floats (m), ``stitches`` as a whole number >= 2.

    Raises
    ------
    ValueError
        Naming the ``trajectory.<key>`` that is wrong and what it got.
    """
    for name in ("start", "end"):
        value = finite_values(getattr(path, name), name)
        if value.shape != (2,):
            raise ValueError(f"trajectory.{name} must be 2 numbers (x, y) in m, got {getattr(path, name)!r}")
        object.__setattr__(path, name, tuple(float(v) for v in value))
    for name in ("bulge", "skin_height", "hover", "depth"):
        object.__setattr__(path, name, one_number(getattr(path, name), name, "m"))
    stitches = path.stitches
    if not isinstance(stitches, (int, np.integer)) or isinstance(stitches, bool) or stitches < 2:
        raise ValueError(f"trajectory.stitches must be a whole number >= 2, got {stitches!r}")
    object.__setattr__(path, "stitches", int(stitches))
    if path.hover < 0:
        raise ValueError(f"trajectory.hover must be >= 0 m, got {path.hover}")
    if path.depth <= 0:
        raise ValueError(f"trajectory.depth must be > 0 m, got {path.depth}")
    if np.allclose(path.start, path.end):
        raise ValueError("trajectory.start and trajectory.end must differ")
