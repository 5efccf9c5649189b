"""Reference trajectories: a suturing path on the skin (task space, via inverse kinematics) and joint sines.

Both kinds expose ``evaluate(t) -> (q_ref, dq_ref, ddq_ref)`` for a scalar or
an array of times (s); the arrays have shape ``(n,)`` or ``(len(t), n)`` for the arm's ``n``
joints.  The laceration path is a task-space path (:func:`laceration_pose`); an arm model turns
it into joint references (the paper's arm in closed form, the path its model's ``laceration_path`` makes;
any other arm's tool point by IK, :class:`blocks.scenarios.tool_path.ToolLaceration`).

The laceration path
-------------------
A laceration is a line (or a gently curved arc, ``bulge``) on the skin, a
horizontal plane at ``skin_height``.  The tool places ``stitches`` stitches at
equal spacing along it, first to last.  The motion alternates between two
kinds of phase of equal length ``duration / (2 * stitches - 1)``:

* a *stitch*: the tool, resting above the skin at ``hover`` height, dips to
  ``depth`` below the skin and back while it rolls the needle by
  ``needle_roll`` and back;
* a *travel*: the tool moves along the laceration to the next stitch point.

Every phase starts and ends at rest with zero acceleration (a quintic
"smoothstep" for travel, a ``64 tau^3 (1 - tau)^3`` bump for the dip and
roll), so the task-space path is C2 and the joint references have exact,
continuous first and second derivatives.  They come from inverse kinematics:
``q = IK(p)``, ``q' = J^-1 p'``, ``q'' = J^-1 (p'' - J' q')`` -- no finite
differences.  After ``duration`` the reference holds the last pose.

``duration`` belongs to the path, not to the run: a scenario's
``simulation.t_final`` never rescales it.  A run shorter than the path follows
its first ``t_final`` seconds exactly; a longer one holds the path's end.

Construction samples the whole path and raises
:class:`~blocks.model.arm.UnreachableError` if any point is outside
the workspace or a joint's range, or too close to a singularity.  A joint-sine
reference is checked against the joint ranges by the scenario that runs it
(:func:`check_joint_ranges`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blocks.diagram.bound_kernels import Kernels
from blocks.kernels.splines import bump6, smoothstep5  # noqa: F401  (names this module has given)
from blocks.model.task_path import LACERATION_FIELDS, check_joint_ranges, laceration_pose  # noqa: F401
from blocks.model.task_path import finite_values as _finite

__all__ = ["JointSine", "TRAJECTORY_KINDS", "check_joint_ranges", "smoothstep5", "bump6", "laceration_pose",
           "joint_sine_output"]

#: The kinds of reference: the laceration path, joint sines (any arm), a tool-point path (any arm,
#: :mod:`blocks.scenarios.tool_path`).
TRAJECTORY_KINDS = ("laceration", "joint_sine", "tool_path")


def joint_sine_output(t, x, u, amplitude, omega, offset):
    """Block kernel of :class:`JointSine`: rows ``[q_ref; dq_ref; ddq_ref]`` at time(s) ``t`` (s).

    One time gives (3n,); a row of K times with parameters of shape (n, 1) gives (3n, K).
    """
    phase = omega * t
    return np.concatenate((offset + amplitude * np.sin(phase), amplitude * omega * np.cos(phase),
                           -amplitude * omega ** 2 * np.sin(phase)))


@dataclass(frozen=True)
class JointSine:
    """``q_ref = offset + amplitude * sin(omega * t)`` per joint, for checks and for any arm.

    Parameters
    ----------
    amplitude : n floats
        Amplitudes, one per joint (rad or m; the defaults suit the paper's arm: rad, rad, m, rad).
    omega : float or n floats
        Angular frequencies (rad/s).
    offset : n floats
        Offsets (rad or m), as many as ``amplitude``.
    """

    amplitude: tuple[float, ...] = (0.1, 0.1, 0.01, 0.1)
    omega: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    offset: tuple[float, ...] = (0.0, 2.0, 0.24, 0.0)

    def __post_init__(self) -> None:
        amplitude = _finite(self.amplitude, "amplitude")
        if amplitude.ndim != 1 or amplitude.size == 0:
            raise ValueError(f"trajectory.amplitude must be a list of numbers (one per joint), got {self.amplitude!r}")
        n = amplitude.size
        for name in ("amplitude", "omega", "offset"):
            value = _finite(getattr(self, name), name)
            if name == "omega" and value.ndim == 0:
                value = np.full(n, float(value))
            if value.shape != (n,):
                raise ValueError(f"trajectory.{name} must be {n} numbers, as many as trajectory.amplitude"
                                 + (", or one" if name == "omega" else "") + f", got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(v) for v in value))

    @property
    def n(self) -> int:
        """Number of joints the reference drives."""
        return len(self.amplitude)

    def evaluate(self, t):
        """Joint references ``(q_ref, dq_ref, ddq_ref)`` at time(s) ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        a, w, c = (np.array(v) for v in (self.amplitude, self.omega, self.offset))
        phase = t[..., None] * w
        return c + a * np.sin(phase), a * w * np.cos(phase), -a * w ** 2 * np.sin(phase)

    def evaluate_stacked(self, t) -> np.ndarray:
        """``[q_ref, dq_ref, ddq_ref]`` at time(s) ``t`` (s) in one array, shape ``np.shape(t) + (3n,)``."""
        return np.concatenate(self.evaluate(t), axis=-1)

    def kernels(self) -> Kernels:
        """The reference as a block kernel (:func:`joint_sine_output`) with amplitude, omega and offset (n,) each."""
        return Kernels(tuple(np.array(v) for v in (self.amplitude, self.omega, self.offset)), joint_sine_output)
