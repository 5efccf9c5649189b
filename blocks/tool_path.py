"""A task-space path of any arm's tool point, as joint references: the trajectory kind ``tool_path``.

The tool point (``arm.tool_kernels.tool_position``) moves through
``waypoints`` (m, base frame), one segment of equal length in time per pair,
each a quintic smoothstep that starts and ends at rest (so the path is C2);
after ``duration`` it holds the last point.  Joint references come from
:func:`blocks.arms.ik.joint_path` (damped least-squares IK for a square
Jacobian, the integrated resolved-rate law for a redundant arm; ``q''``
the exact derivative of ``q'``) at samples every
``sample_period`` s; between samples each joint follows the quintic Hermite
polynomial through the two samples' ``q, q', q''``, so the reference is C2
and its rates are the exact derivatives of its positions.  A point out of
reach (or beyond a joint's range) is refused by time, point and residual.

The laceration path (:class:`~blocks.trajectory.LacerationPath`) is the
paper's RRPR's closed-form path; this kind serves every arm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .bound_kernels import Kernels
from .kernels.noise import _sample_index
from .trajectory import quintic_hermite, smoothstep5

__all__ = ["ToolPath", "tool_path_output", "MAX_PATH_SAMPLES"]

#: Most IK samples a path may ask for (each is an iterative solve).
MAX_PATH_SAMPLES = 20_000
# The sample tables of the latest paths: a scenario varied many times solves its IK once.
_KEPT = 16
_tables: dict = {}


def tool_path_output(t, x, u, table, period):
    """Block kernel of :class:`ToolPath`: rows ``[q_ref; dq_ref; ddq_ref]`` at time(s) ``t`` (s).

    ``table`` holds the samples' ``[q; q'; q'']`` (3n, N) every ``period`` s; between two samples each
    joint follows the quintic Hermite polynomial of their values, rates and accelerations.
    """
    n = table.shape[0] // 3
    last = table.shape[1] - 1
    position = np.minimum(np.maximum(t / period, 0.0), last * 1.0)
    index = _sample_index(position, last)
    s = position - index
    h = period
    q0, q1 = table[:n, index], table[:n, index + 1]
    v0, v1 = table[n:2 * n, index] * h, table[n:2 * n, index + 1] * h
    a0, a1 = table[2 * n:, index] * (h * h), table[2 * n:, index + 1] * (h * h)
    q, dq, ddq = quintic_hermite(s, h, q0, v0, a0, q1, v1, a1)
    return np.concatenate((q, dq, ddq))


@dataclass(frozen=True)
class ToolPath:
    """The tool point through ``waypoints``, joint references by IK (see the module docstring).

    Parameters
    ----------
    arm : blocks.arm.ArmModel
        The arm (its tool point, Jacobian and joint ranges).
    waypoints : sequence of 3-sequences
        Tool-point positions (m, base frame), at least two.
    duration : float
        Time from the first waypoint to the last (s), > 0.
    sample_period : float
        Spacing of the IK samples (s), > 0.
    q0 : sequence of n floats, optional
        Where the first IK solve starts (default: the middle of the joints' ranges).

    Raises
    ------
    ValueError
        On a bad argument (named), or :class:`blocks.arms.ik.IKUnreachableError` for a point out of reach.
    """

    arm: object = field(repr=False)
    waypoints: tuple = ()
    duration: float = 10.0
    sample_period: float = 0.02
    q0: tuple | None = None

    def __post_init__(self) -> None:
        points = np.asarray(self.waypoints, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2 or not np.all(np.isfinite(points)):
            raise ValueError(f"trajectory.waypoints must be two or more points [x, y, z] (m), got {self.waypoints!r}")
        for name in ("duration", "sample_period"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"trajectory.{name} must be a number > 0 (s), got {value!r}")
        samples = int(math.ceil(self.duration / self.sample_period)) + 1
        if samples > MAX_PATH_SAMPLES:
            raise ValueError(f"trajectory.duration / trajectory.sample_period asks for {samples:,} IK samples; at most "
                             f"{MAX_PATH_SAMPLES:,} (raise trajectory.sample_period)")
        object.__setattr__(self, "waypoints", tuple(tuple(float(v) for v in p) for p in points))
        object.__setattr__(self, "duration", float(self.duration))
        object.__setattr__(self, "sample_period", float(self.sample_period))
        key = (id(self.arm), self.waypoints, self.duration, self.sample_period,
               None if self.q0 is None else tuple(np.asarray(self.q0, dtype=float).tolist()))
        found = _tables.get(key)
        if found is None or found[0] is not self.arm:
            from .arms.ik import joint_path
            t = self.sample_period * np.arange(samples)
            p, dp, ddp = self.task_space(t)
            path = joint_path(self.arm, t, p, dp, ddp, q0=self.q0)
            table = np.ascontiguousarray(np.vstack([path.q.T, path.dq.T, path.ddq.T]))
            table.setflags(write=False)
            found = _tables[key] = (self.arm, table)       # the arm is kept with its table: its id stays its own
            while len(_tables) > _KEPT:
                _tables.pop(next(iter(_tables)))
        object.__setattr__(self, "table", found[1])

    @property
    def n(self) -> int:
        """Number of joints the reference drives."""
        return self.arm.joints.count

    def task_space(self, t):
        """The tool point's path ``p, p', p''`` (m, m/s, m/s^2) at times ``t`` (s), each shape ``t.shape + (3,)``."""
        t = np.asarray(t, dtype=float)
        points = np.asarray(self.waypoints)
        segments = len(points) - 1
        T = self.duration / segments
        k = np.clip(np.floor(t / T), 0, segments - 1).astype(int)
        tau = np.clip(t / T - k, 0.0, 1.0)
        tau = np.where(t >= self.duration, 1.0, tau)
        s, ds, dds = smoothstep5(tau)
        step = points[k + 1] - points[k]
        return (points[k] + s[..., None] * step, (ds / T)[..., None] * step, (dds / T ** 2)[..., None] * step)

    def evaluate(self, t):
        """Joint references ``(q_ref, dq_ref, ddq_ref)`` at time(s) ``t`` (s): (n,) each, or (len(t), n)."""
        rows = tool_path_output(np.asarray(t, dtype=float) if np.ndim(t) else float(t), None, None, self.table,
                                self.sample_period)
        n = self.n
        rows = np.moveaxis(rows, 0, -1)
        return rows[..., :n], rows[..., n:2 * n], rows[..., 2 * n:]

    def evaluate_stacked(self, t) -> np.ndarray:
        """``[q_ref, dq_ref, ddq_ref]`` at time(s) ``t`` (s) in one array, shape ``np.shape(t) + (3n,)``."""
        return np.concatenate(self.evaluate(t), axis=-1)

    def kernels(self) -> Kernels:
        """The reference as a block kernel (:func:`tool_path_output`) over its sample table (a lookup by time)."""
        params = (self.table, self.sample_period)
        return Kernels(params, tool_path_output, column_params=params)
