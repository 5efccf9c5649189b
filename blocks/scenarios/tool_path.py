"""Task-space paths of any arm's tool point, as joint references: the trajectory kinds ``tool_path`` and, for an
arm other than the paper's RRPR, ``laceration``.

:class:`ToolPath` moves the tool point (``arm.tool_kernels.tool_position``)
through ``waypoints`` (m, base frame), one segment of equal length in time per
pair, each a quintic smoothstep that starts and ends at rest (so the path is
C2); after ``duration`` it holds the last point.  :class:`ToolLaceration` is
the suturing path of :mod:`blocks.diagram.trajectory` (stitches along a laceration on
the skin plane: hover, dip to ``depth`` below the skin, travel) for the tool
point of any arm; the needle roll of the paper's RRPR, a joint of its own,
has no counterpart in a tool point's position and is not part of it.

Joint references come from :func:`blocks.model.urdf.ik.joint_path` (damped
least-squares IK for a square Jacobian, the integrated resolved-rate law for a
redundant arm; ``q''`` the exact derivative of ``q'``) at samples every
``sample_period`` s; between samples each joint follows the quintic Hermite
polynomial through the two samples' ``q, q', q''``, so the reference is C2 and
its rates are the exact derivatives of its positions.

Reachability.  The path's own corners -- every waypoint, and for a laceration
every phase's ends and middle (the bottom of each stitch) -- are solved by IK
when the path is made, whatever ``sample_period`` is, and a point out of reach
(or beyond a joint's range) is refused by time, point and residual; a
``sample_period`` longer than a segment (a phase) is refused, so that no
segment passes between two samples unseen.  Every sample is then refused the
same way when the path is solved.

Cost.  The first :data:`PROBE_SAMPLES` samples are solved when the path is
made and timed: the solve is estimated as that per-sample cost times the
samples (:attr:`solve_seconds`).  A path estimated at no more than
:data:`EAGER_SECONDS` is solved at once; a longer one (a redundant arm's
resolved-rate law over thousands of samples takes minutes) waits until a run
needs it, so that the run's estimate (:func:`blocks.figure2.run_limits.estimate_run`)
and budget check see its cost first; :meth:`solve` then refuses it over the
wall-time budget (``--max-seconds``, ``DOBKIT_MAX_SECONDS``) before it starts,
shows its progress and stops when the budget runs out.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from blocks.diagram.bound_kernels import Kernels
from blocks.kernels.noise import _sample_index
from blocks.kernels.splines import quintic_hermite, smoothstep5
from blocks.model.task_path import laceration_pose, settle_laceration_shape

__all__ = ["ToolPath", "ToolLaceration", "tool_path_output", "MAX_PATH_SAMPLES", "PROBE_SAMPLES", "EAGER_SECONDS"]

#: Most IK samples a path may ask for (each is an iterative solve).
MAX_PATH_SAMPLES = 20_000
#: Samples solved and timed when a path is made, for the estimate of the whole solve.
PROBE_SAMPLES = 12
#: A path whose solve is estimated at most this long (s) is solved when it is made; a longer one when first needed.
EAGER_SECONDS = 2.0
#: Distinct corners solved when a path is made; the rest (a long list of waypoints) when the path is solved.
CORNERS_AT_ONCE = 64
# The sample tables (and probes) of the latest paths: a scenario varied many times solves its IK once.
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


class _Record:
    """What is known of one path's solve: its arm, the probe's start column, per-sample cost, and the table."""

    def __init__(self, arm, start: np.ndarray, per_sample: float, method: str, table=None) -> None:
        self.arm, self.start, self.per_sample, self.method, self.table = arm, start, per_sample, method, table


def _keep(key, record: _Record) -> None:
    _tables[key] = record               # the arm is kept with its table: its id stays its own
    while len(_tables) > _KEPT:
        _tables.pop(next(iter(_tables)))


class _SampledIK:
    """The IK sample table of a task-space path, its cost and its lookup (shared by :class:`ToolPath` and
    :class:`ToolLaceration`; each gives ``task_space``, ``_pieces`` and ``_corner_times``)."""

    #: How messages name the path.
    _what = "tool path"

    def _prepare(self) -> None:
        samples = int(math.ceil(self.duration / self.sample_period)) + 1
        if samples > MAX_PATH_SAMPLES:
            raise ValueError(f"trajectory.duration / trajectory.sample_period asks for {samples:,} IK samples; at most "
                             f"{MAX_PATH_SAMPLES:,} (raise trajectory.sample_period)")
        object.__setattr__(self, "samples", samples)
        key = (type(self).__name__, id(self.arm), self._identity(), self.duration, self.sample_period,
               None if self.q0 is None else tuple(np.asarray(self.q0, dtype=float).tolist()))
        object.__setattr__(self, "_key", key)
        found = _tables.get(key)
        if found is None or found.arm is not self.arm:
            self._check_corners(CORNERS_AT_ONCE)
            piece, count, word = self._pieces()
            if self.sample_period > piece * (1 + 1e-12):
                raise ValueError(f"trajectory.sample_period ({self.sample_period:g} s) is longer than one {word} of the "
                                 f"{self._what} ({piece:.6g} s: trajectory.duration / {count} {word}s): the IK samples "
                                 f"would pass over parts of the path unseen; at most {piece:.6g} s")
            found = self._probe()
            _keep(key, found)
        object.__setattr__(self, "_record", found)
        if found.table is None and self.solve_seconds <= EAGER_SECONDS:
            self.solve(budget=False)

    def _times(self) -> np.ndarray:
        return self.sample_period * np.arange(self.samples)

    def _joint_path(self, t, on_sample=None):
        from blocks.model.urdf.ik import joint_path
        p, dp, ddp = self.task_space(t)
        return joint_path(self.arm, t, p, dp, ddp, q0=self.q0, on_sample=on_sample)

    def _corners(self) -> tuple[np.ndarray, np.ndarray]:
        """The path's distinct corners (waypoints, a laceration's phase ends and stitch bottoms) and their first
        times (a loop's repeated points once)."""
        times = np.asarray(self._corner_times(), dtype=float)
        points = self.task_space(times)[0]
        _, first = np.unique(points, axis=0, return_index=True)
        first = np.sort(first)
        return times[first], points[first]

    def _check_corners(self, most: int | None = None, skip: int = 0) -> None:
        """IK of the path's distinct corners ``skip`` to ``skip + most``, each from the one before: a corner out of
        reach is refused by time, point and residual, however far apart the samples are."""
        from blocks.model.urdf.ik import solve_ik
        times, points = self._corners()
        end = None if most is None else skip + most
        q = self.q0
        for t, point in zip(times[skip:end], points[skip:end]):
            q, _ = solve_ik(self.arm, point, q, t=float(t))

    def _probe(self) -> _Record:
        """Solve and time the first :data:`PROBE_SAMPLES` samples (all of them for a short path)."""
        t = self._times()
        count = min(self.samples, PROBE_SAMPLES)
        started = time.perf_counter()
        path = self._joint_path(t[:count])
        per_sample = (time.perf_counter() - started) / count
        start = np.concatenate([path.q[0], path.dq[0], path.ddq[0]])[:, None]
        table = self._frozen(path) if count == self.samples else None
        return _Record(self.arm, start, per_sample, path.method, table)

    @staticmethod
    def _frozen(path) -> np.ndarray:
        table = np.ascontiguousarray(np.vstack([path.q.T, path.dq.T, path.ddq.T]))
        table.setflags(write=False)
        return table

    # -- cost and solve ---------------------------------------------------------------------------------------
    @property
    def solved(self) -> bool:
        """Whether the joint references are solved (else :meth:`solve` runs when they are first needed)."""
        return self._record.table is not None

    @property
    def method(self) -> str:
        """How the IK is solved: ``"dls"`` or ``"resolved_rate"`` (:func:`blocks.model.urdf.ik.joint_path`)."""
        return self._record.method

    @property
    def solve_seconds(self) -> float:
        """Estimated wall time (s) of the solve still to do: 0 when solved, else the probe's per-sample cost times
        the samples."""
        return 0.0 if self.solved else self._record.per_sample * (self.samples + self._corners_left())

    def _corners_left(self) -> int:
        """Distinct corners beyond :data:`CORNERS_AT_ONCE`, solved with the samples."""
        count = len(np.asarray(self._corner_times()))
        return 0 if count <= CORNERS_AT_ONCE else max(0, len(self._corners()[0]) - CORNERS_AT_ONCE)

    def solve_reason(self) -> str:
        """How :attr:`solve_seconds` comes about, in words (for a budget message)."""
        law = "the resolved-rate law" if self.method == "resolved_rate" else "damped least squares"
        return (f"{self.samples:,} IK samples of the {self._what} by {law} at about "
                f"{1e3 * self._record.per_sample:.3g} ms each (measured on the first {min(self.samples, PROBE_SAMPLES)})"
                f": trajectory.duration {self.duration:g} s / trajectory.sample_period {self.sample_period:g} s")

    def solve(self, budget=None, progress=None) -> None:
        """Solve every sample now (nothing when solved), within ``budget``'s wall time.

        Parameters
        ----------
        budget : blocks.engines.budget.Budget, None or False
            Its ``seconds`` bound the solve: refused before it starts when :attr:`solve_seconds` is over it, stopped
            when it runs out.  None: :meth:`Budget.from_env <blocks.engines.budget.Budget.from_env>`; False: no bound.
        progress : file, optional
            Where a long solve writes its progress (default standard error).

        Raises
        ------
        blocks.engines.budget.BudgetError
            Over the wall-time budget (before, with the estimate and the keys; or when it ran out, with the sample).
        blocks.model.urdf.ik.IKUnreachableError
            At the first sample out of reach (time, point, residual).
        """
        if self.solved:
            return
        from blocks.engines.budget import ENVIRONMENT, Budget, BudgetError, Estimate
        if budget is None:
            budget = Budget.from_env()
        seconds = None if budget is False else budget.seconds
        what = f"the {self._what}'s joint references"
        if seconds is not None:
            budget.check(self.estimate(), what)
        deadline = None if seconds is None else time.monotonic() + seconds
        stream = sys.stderr if progress is None else progress
        show = budget is not False
        if show:
            stream.write(f"solving {what}: {self.solve_reason()}; about {self.solve_seconds:.3g} s\n")
            stream.flush()
        from blocks.plumbing.progress import StageProgress
        t = self._times()
        shown = StageProgress(stream, enabled=show)
        stage = f"solving the {self._what} ({self.samples:,} samples)"

        def on_sample(k: int) -> None:
            shown(stage, (k + 1) / self.samples)
            if deadline is not None and time.monotonic() > deadline:
                raise BudgetError(f"{what}: the wall-time budget of {seconds:g} s ran out at sample {k + 1:,} of "
                                  f"{self.samples:,} (t = {t[k]:.6g} s of the path); raise it with --max-seconds or "
                                  f"{ENVIRONMENT['seconds']}, or take a longer trajectory.sample_period",
                                  Estimate(memory=0, seconds=self.solve_seconds), "trajectory.sample_period",
                                  "seconds")

        with shown:
            if self._corners_left():
                self._check_corners(skip=CORNERS_AT_ONCE)
            path = self._joint_path(t, on_sample)
        self._record.table = self._frozen(path)
        _keep(self._key, self._record)

    def estimate(self):
        """The solve still to do as a :class:`blocks.engines.budget.Estimate` (its ``seconds``, the key and the reason)."""
        from blocks.engines.budget import Estimate
        return Estimate(memory=24 * self.arm.n * self.samples, seconds=self.solve_seconds,
                        keys={"seconds": "trajectory.sample_period"}, reasons={"seconds": self.solve_reason()})

    @property
    def table(self) -> np.ndarray:
        """The samples' ``[q; q'; q'']``, shape (3n, N), read-only (solved now if it was not)."""
        if not self.solved:
            self.solve()
        return self._record.table

    # -- evaluation -------------------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of joints the reference drives."""
        return self.arm.joints.count

    def evaluate(self, t):
        """Joint references ``(q_ref, dq_ref, ddq_ref)`` at time(s) ``t`` (s): (n,) each, or (len(t), n)."""
        if not self.solved and np.ndim(t) == 0 and float(t) <= 0.0:
            # the start, as the table gives it (the quintic at s = 0 reads the first column only), without the solve
            table = np.hstack([self._record.start, self._record.start])
        else:
            table = self.table
        rows = tool_path_output(np.asarray(t, dtype=float) if np.ndim(t) else float(t), None, None, table,
                                self.sample_period)
        n = self.n
        rows = np.moveaxis(rows, 0, -1)
        return rows[..., :n], rows[..., n:2 * n], rows[..., 2 * n:]

    def evaluate_stacked(self, t) -> np.ndarray:
        """``[q_ref, dq_ref, ddq_ref]`` at time(s) ``t`` (s) in one array, shape ``np.shape(t) + (3n,)``."""
        return np.concatenate(self.evaluate(t), axis=-1)

    def positions_near(self, t) -> np.ndarray:
        """Joint positions (m, n) on the path at times ``t`` (s) without the solve: the samples' table when solved,
        else IK of each point from the one before (an estimate's inertias need no more)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.solved:
            return np.asarray(self.evaluate(t)[0])
        from blocks.model.urdf.ik import solve_ik
        points = self.task_space(t)[0]
        q, out = self._record.start[:self.n, 0], []
        for ti, point in zip(t, points):
            q, _ = solve_ik(self.arm, point, q, t=float(ti))
            out.append(q)
        return np.array(out)

    def kernels(self) -> Kernels:
        """The reference as a block kernel (:func:`tool_path_output`) over its sample table (a lookup by time)."""
        params = (self.table, self.sample_period)
        return Kernels(params, tool_path_output, column_params=params)


def _check_times(path) -> None:
    for name in ("duration", "sample_period"):
        value = getattr(path, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ValueError(f"trajectory.{name} must be a number > 0 (s), got {value!r}")
        object.__setattr__(path, name, float(value))


@dataclass(frozen=True)
class ToolPath(_SampledIK):
    """The tool point through ``waypoints``, joint references by IK (see the module docstring).

    Parameters
    ----------
    arm : blocks.model.arm.ArmModel
        The arm (its tool point, Jacobian and joint ranges).
    waypoints : sequence of 3-sequences
        Tool-point positions (m, base frame), at least two.
    duration : float
        Time from the first waypoint to the last (s), > 0.
    sample_period : float
        Spacing of the IK samples (s), > 0 and at most one segment's time, ``duration / (len(waypoints) - 1)``.
    q0 : sequence of n floats, optional
        Where the first IK solve starts (default: the middle of the joints' ranges).

    Raises
    ------
    ValueError
        On a bad argument (named), or :class:`blocks.model.urdf.ik.IKUnreachableError` for a point out of reach.
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
        _check_times(self)
        object.__setattr__(self, "waypoints", tuple(tuple(float(v) for v in p) for p in points))
        self._prepare()

    def _identity(self) -> tuple:
        return self.waypoints

    def _pieces(self) -> tuple[float, int, str]:
        segments = len(self.waypoints) - 1
        return self.duration / segments, segments, "segment"

    def _corner_times(self):
        return self.duration / (len(self.waypoints) - 1) * np.arange(len(self.waypoints))

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


#: The keys of a laceration on an arm other than the paper's RRPR, and what each is (the RRPR's path has
#: needle_roll, roll_offset, elbow and singularity_margin besides, for its roll joint and closed-form IK).
LACERATION_KEYS = ("start", "end", "bulge", "stitches", "skin_height", "hover", "depth", "duration", "sample_period")


@dataclass(frozen=True)
class ToolLaceration(_SampledIK):
    """The suturing path of the paper's arm (its model's ``laceration_path``) for the tool point of any arm, by IK.

    The tool point places ``stitches`` stitches along a laceration from ``start`` to ``end`` (a line, or an arc
    ``bulge`` to its left) on the skin plane ``z = skin_height``: at each it rests ``hover`` above the skin,
    dips to ``depth`` below it and back (a ``64 tau^3 (1 - tau)^3`` bump), then travels to the next (a quintic
    smoothstep); phases of equal length ``duration / (2 stitches - 1)``; the last point is held after
    ``duration``.  Positions (m, base frame), times (s).

    Parameters
    ----------
    arm : blocks.model.arm.ArmModel
    start, end : 2 floats
        The laceration's ends in the base x-y plane (m).
    skin_height : float
        The skin plane's height (m, base frame): the tissue contact's ``disturbance.skin_height``.
    bulge, stitches, hover, depth, duration
        As the paper arm's laceration path takes them.
    sample_period : float
        Spacing of the IK samples (s), > 0 and at most one phase.
    q0 : sequence of n floats, optional
        Where the first IK solve starts (default: the middle of the joints' ranges).
    """

    arm: object = field(repr=False)
    start: tuple = (0.0, 0.0)
    end: tuple = (0.0, 0.0)
    skin_height: float = 0.0
    bulge: float = 0.0
    stitches: int = 5
    hover: float = 0.003
    depth: float = 0.004
    duration: float = 10.0
    sample_period: float = 0.02
    q0: tuple | None = None

    _what = "laceration path"

    def __post_init__(self) -> None:
        settle_laceration_shape(self)
        _check_times(self)
        # the pose kernel's numbers (blocks.model.task_path.LACERATION_FIELDS); the RRPR's roll and IK branch are unused
        g = (self.phase_duration, self.stitches, self.duration, *self.start, *self.end, self.bulge, self.skin_height,
             self.hover, self.depth, 0.0, 0.0) + (0.0,) * 7
        object.__setattr__(self, "_geometry", tuple(float(v) for v in g))
        self._prepare()

    @property
    def phase_duration(self) -> float:
        """Length of one stitch or travel phase (s)."""
        return self.duration / (2 * self.stitches - 1)

    def _identity(self) -> tuple:
        return self._geometry

    def _pieces(self) -> tuple[float, int, str]:
        return self.phase_duration, 2 * self.stitches - 1, "phase"

    def _corner_times(self):
        # every phase's ends and middle: the hover points, the stitches' bottoms and the travels' midpoints
        return 0.5 * self.phase_duration * np.arange(2 * (2 * self.stitches - 1) + 1)

    def task_space(self, t):
        """The tool point's path ``p, p', p''`` (m, m/s, m/s^2) at times ``t`` (s), each shape ``t.shape + (3,)``."""
        t = np.asarray(t, dtype=float)
        rows = np.array([laceration_pose(float(ti), self._geometry) for ti in t.ravel()]).reshape(t.shape + (12,))
        return rows[..., 0:3], rows[..., 4:7], rows[..., 8:11]
