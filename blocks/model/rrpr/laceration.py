"""The paper's RRPR on the suturing path: the laceration's joint references by closed-form inverse kinematics.

The task-space path (stitches along a laceration on the skin, :func:`blocks.model.task_path.laceration_pose`) is any
arm's; this module turns it into the RRPR's joint references in closed form: ``q = IK(p)``, ``q' = J^-1 p'``,
``q'' = J^-1 (p'' - J' q')``, no finite differences.  Another arm's tool point follows the same path by numerical
IK (:class:`blocks.scenarios.tool_path.ToolLaceration`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from blocks.kernels.bound import Kernels
from blocks.model.arm import UnreachableError
from blocks.model.rrpr.kinematics import ELBOWS, inverse_kinematics, jacobian, jacobian_derivative_times_dq
from blocks.model.rrpr.parameters import RobotParameters
from blocks.model.task_path import check_joint_ranges, laceration_pose, settle_laceration_shape
from blocks.model.task_path import one_number as _scalar

__all__ = ["LacerationPath", "laceration_rows", "laceration_reference", "laceration_output"]


def _planar_solve(a1, a2, c1, s1, c12, s12, det, bx, by):
    """``J_xy^-1 [bx, by]`` for the planar 2x2 block of the Jacobian (determinant ``det = a1 a2 sin(theta2)``)."""
    return (a2 * c12 * bx + a2 * s12 * by) / det, (-(a1 * c1 + a2 * c12) * bx - (a1 * s1 + a2 * s12) * by) / det


def laceration_rows(t, g):
    """``[q_ref, dq_ref, ddq_ref]`` of a laceration path at one time ``t`` (s) as a tuple of 12 floats.

    Closed-form inverse kinematics, using the arm's structure: the planar
    2x2 block of J has determinant ``a1 a2 sin(theta2)``, ``d3' = -z'`` and
    ``theta4' = theta1' + theta2' - phi'``; ``theta1`` and ``theta4`` are
    taken on the branch nearest the path's start pose.  A tuple, not an
    array, so that compiled code calls it without allocating.
    """
    x, y, z, phi, vx, vy, vz, vphi, ax, ay, az, aphi = laceration_pose(t, g)
    a1, a2, d1, d4, elbow, q_near1, q_near4 = g[13], g[14], g[15], g[16], g[17], g[18], g[19]
    c2 = (x * x + y * y - a1 * a1 - a2 * a2) / (2 * a1 * a2)
    if abs(c2) > 1:
        raise UnreachableError("laceration path leaves the workspace")
    s2 = elbow * math.sqrt(max(0.0, 1 - c2 * c2))
    t2 = math.atan2(s2, c2)
    t1 = math.atan2(y, x) - math.atan2(a2 * s2, a1 + a2 * c2)
    t1 = q_near1 + (t1 - q_near1 + math.pi) % (2 * math.pi) - math.pi
    t4 = t1 + t2 - phi
    t4 = q_near4 + (t4 - q_near4 + math.pi) % (2 * math.pi) - math.pi
    c1, s1, c12, s12 = math.cos(t1), math.sin(t1), math.cos(t1 + t2), math.sin(t1 + t2)
    det = a1 * a2 * s2
    w1, w2 = _planar_solve(a1, a2, c1, s1, c12, s12, det, vx, vy)
    w12 = w1 + w2
    bx = ax + a1 * c1 * w1 ** 2 + a2 * c12 * w12 ** 2      # p'' - J' q'
    by = ay + a1 * s1 * w1 ** 2 + a2 * s12 * w12 ** 2
    e1, e2 = _planar_solve(a1, a2, c1, s1, c12, s12, det, bx, by)
    return (t1, t2, d1 - d4 - z, t4, w1, w2, -vz, w12 - vphi, e1, e2, -az, e1 + e2 - aphi)


def laceration_reference(t, g):
    """``[q_ref, dq_ref, ddq_ref]`` (12,) of a laceration path at one time ``t`` (s) (see :func:`laceration_rows`)."""
    return np.array(laceration_rows(t, g))


def laceration_output(t, x, u, g):
    """Block kernel of a laceration path: rows ``[q_ref; dq_ref; ddq_ref]``, 12 floats at one time or (12, K) at K
    times."""
    if isinstance(t, (int, float)):          # one time (numba compiles this branch only)
        return laceration_rows(t, g)
    out = np.empty((12, t.shape[0]))
    for k in range(t.shape[0]):
        row = laceration_rows(float(t[k]), g)
        for i in range(12):
            out[i, k] = row[i]
    return out


@dataclass(frozen=True)
class LacerationPath:
    """A suturing path along a laceration, turned into joint references by inverse kinematics.

    Parameters
    ----------
    params : RobotParameters
        Arm parameters (its kinematic lengths and offsets).
    start, end : 2 floats
        End points of the laceration in the base x-y plane (m).
    bulge : float
        Sideways offset of the laceration's midpoint from the straight line
        (m, positive to the left of start->end); 0 is a straight cut.
    stitches : int
        Number of stitches, >= 2, the first at ``start`` and the last at ``end``.
    skin_height : float
        Height of the skin plane in the base frame (m).  A scenario sets it
        from ``disturbance.skin_height``, the plane the tissue model uses.
    hover : float
        Tool height above the skin while travelling (m), >= 0.
    depth : float
        Depth of each stitch below the skin (m), > 0.
    needle_roll : float
        Tool roll used to drive the needle at each stitch (rad).
    roll_offset : float
        Tool roll angle ``phi`` at rest (rad).
    duration : float
        Time to complete all stitches (s), > 0; the paper's 10 s by default,
        independent of how long a run is simulated.
    elbow : {"positive", "negative"}
        Inverse-kinematics branch (sign of theta2).
    singularity_margin : float
        Smallest allowed distance of ``theta2`` from 0 and pi along the path (rad).
    """

    params: RobotParameters = field(default_factory=RobotParameters)
    start: tuple[float, float] = (0.42, -0.04)
    end: tuple[float, float] = (0.42, 0.04)
    bulge: float = 0.0
    stitches: int = 5
    skin_height: float = 0.12 - 0.24 - 0.271
    hover: float = 0.003
    depth: float = 0.004
    needle_roll: float = 1.0
    roll_offset: float = 0.0
    duration: float = 10.0
    elbow: str = "positive"
    singularity_margin: float = 0.2

    def __post_init__(self) -> None:
        settle_laceration_shape(self)
        for name, unit in (("needle_roll", "rad"), ("roll_offset", "rad"), ("duration", "s"),
                           ("singularity_margin", "rad")):
            object.__setattr__(self, name, _scalar(getattr(self, name), name, unit))
        if self.duration <= 0:
            raise ValueError(f"trajectory.duration must be > 0 s, got {self.duration}")
        if not 0 <= self.singularity_margin < math.pi / 2:
            raise ValueError(f"trajectory.singularity_margin must be in [0, pi/2) rad, got {self.singularity_margin}")
        if self.elbow not in ELBOWS:
            raise ValueError(f"trajectory.elbow must be one of {sorted(ELBOWS)}, got {self.elbow!r}")
        # The branch reference for theta1/theta4 continuity is the rest pose at the start.
        object.__setattr__(self, "_q_near", None)
        object.__setattr__(self, "_table", self._geometry())      # the pose does not depend on the branch
        self._check_reachable()
        q0 = inverse_kinematics(self.pose(0.0)[0][0], self.params, self.elbow)
        object.__setattr__(self, "_q_near", q0)
        object.__setattr__(self, "_table", self._geometry())

    # -- task space -------------------------------------------------------------------------
    @property
    def phase_duration(self) -> float:
        """Length of one stitch or travel phase (s)."""
        return self.duration / (2 * self.stitches - 1)

    def pose(self, t):
        """Task-space reference ``[x, y, z, phi]`` and its first two time derivatives.

        Returns three arrays of shape ``(len(t), 4)`` (m, m, m, rad and their rates).
        """
        rows = [self._pose_scalar(float(ti)) for ti in np.atleast_1d(np.asarray(t, dtype=float))]
        return tuple(np.array([row[k] for row in rows], dtype=float).reshape(-1, 4) for k in range(3))

    def _pose_scalar(self, t: float):
        """The pose and its rates at one time, in plain floats (the simulator calls this thousands of times)."""
        p = laceration_pose(float(t), self._table)
        return p[0:4], p[4:8], p[8:12]

    def _geometry(self) -> tuple:
        """The path's numbers in the layout of :func:`laceration_pose` (the reference kernel's parameter).

        A tuple of Python floats: the numpy engine's one-point evaluation does
        its arithmetic on floats, which is several times faster than on numpy
        scalars; numba takes the tuple as it is.
        """
        q_near = (0.0, 0.0, 0.0, 0.0) if self._q_near is None else self._q_near
        return tuple(float(v) for v in (self.phase_duration, self.stitches, self.duration, *self.start, *self.end,
                                        self.bulge, self.skin_height, self.hover, self.depth, self.needle_roll,
                                        self.roll_offset, self.params.a1, self.params.a2, self.params.d1,
                                        self.params.d4, ELBOWS[self.elbow], q_near[0], q_near[3]))

    def _evaluate_scalar(self, t: float) -> np.ndarray:
        """``[q_ref, dq_ref, ddq_ref]`` (12,) at one time (see :func:`laceration_reference`)."""
        return laceration_reference(float(t), self._table)

    def kernels(self) -> Kernels:
        """The reference as a block kernel (:func:`laceration_output`) with the path's numbers as its parameter."""
        return Kernels((self._table,), laceration_output, column_params=(self._table,))

    # -- joint space ------------------------------------------------------------------------
    def evaluate(self, t):
        """Joint references ``(q_ref, dq_ref, ddq_ref)`` at time(s) ``t`` (s)."""
        scalar = np.ndim(t) == 0
        if scalar and self._q_near is not None:
            refs = self._evaluate_scalar(t)
            return refs[:4], refs[4:8], refs[8:]
        pos, vel, acc = self.pose(t)
        q = inverse_kinematics(pos, self.params, self.elbow, q_near=self._q_near)
        J = jacobian(q, self.params)
        dq = np.linalg.solve(J, vel[..., None])[..., 0]
        ddq = np.linalg.solve(J, (acc - jacobian_derivative_times_dq(q, dq, self.params))[..., None])[..., 0]
        if scalar:
            return q[0], dq[0], ddq[0]
        return q, dq, ddq

    def evaluate_stacked(self, t) -> np.ndarray:
        """``[q_ref, dq_ref, ddq_ref]`` at time(s) ``t`` (s) in one array, shape ``np.shape(t) + (12,)``."""
        if np.ndim(t) == 0 and self._q_near is not None:
            return self._evaluate_scalar(t)
        return np.concatenate(self.evaluate(t), axis=-1)

    def _check_reachable(self, samples: int = 4001) -> None:
        t = np.linspace(0.0, self.duration, samples)
        pos, _, _ = self.pose(t)
        try:
            q = inverse_kinematics(pos, self.params, self.elbow, min_sin_theta2=math.sin(self.singularity_margin))
        except UnreachableError as err:
            raise UnreachableError(f"laceration path: {err}") from None
        # the planar reach is checked above; the height sets the prismatic joint, which has a stroke
        p = self.params
        top, bottom = self.skin_height + self.hover, self.skin_height - self.depth
        strokes = [lim for lim, kind in zip(p.joints.limits, p.joints.kinds) if kind == "prismatic"]
        heights = "" if len(strokes) != 1 else (
            f"; the stroke allows tool heights z = d1 - d3 - d4 from {p.d1 - p.d4 - strokes[0][1]:.6g} m to "
            f"{p.d1 - p.d4 - strokes[0][0]:.6g} m")
        check_joint_ranges(q, p.joints, "laceration path", f"the tool goes from trajectory.skin_height + "
                                                           f"trajectory.hover = {top:.6g} m down to trajectory."
                                                           f"skin_height - trajectory.depth = {bottom:.6g} m{heights}")
