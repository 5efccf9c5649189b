"""The joints of an arm model: how many, their names, kinds and units.

Everything that sizes a signal or labels a joint for a person reads it from
here (through the arm model, :attr:`ArmModel.joints <blocks.model.arm.ArmModel.joints>`),
so that the joint count is a property of the model rather than a number
repeated in many modules.

Examples
--------
>>> from blocks.model.joints import JointSpace, signal_names
>>> slider = JointSpace(names=("q", "s"), kinds=("revolute", "prismatic"), limits=((-3.0, 3.0), (0.0, 0.5)))
>>> slider.count
2
>>> signal_names("tau", slider)
['tau[0]', 'tau[1]']
>>> slider.labels[1]
'Joint 2 (s)'
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["JointSpace", "signal_names"]

_UNITS = {
    # kind: (position, velocity, generalised force)
    "revolute": ("rad", "rad/s", "N m"),
    "prismatic": ("m", "m/s", "N"),
}


@dataclass(frozen=True)
class JointSpace:
    """Names and kinds of an arm's joints, in joint order.

    Parameters
    ----------
    names : tuple of str
        Short names (``"theta1"``, ``"d3"``, ...), used in files and labels.
    kinds : tuple of str
        ``"revolute"`` or ``"prismatic"`` for each joint.
    limits : tuple of (low, high) pairs, optional
        The range each joint can reach, in its position unit (rad, m);
        ``(-inf, inf)`` for a joint that turns without end.  Default: no limits.
    survey_ranges : tuple of (low, high) pairs, optional
        Where the analyses sample each joint, where the arm's source fixed it (the paper's survey); default: from
        the limits (:func:`analysis.linear.arm_terms.workspace_ranges`).  Not part of the joints' identity.
    survey_points : tuple of int, optional
        Points per joint of the analyses' default grid, where the arm's source fixed them; not part of the
        joints' identity.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    limits: tuple[tuple[float, float], ...] | None = None
    survey_ranges: tuple[tuple[float, float], ...] | None = field(default=None, compare=False, repr=False)
    survey_points: tuple[int, ...] | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.kinds) or not self.names:
            raise ValueError(f"joint names {self.names} and kinds {self.kinds} must be non-empty and of one length")
        unknown = sorted(set(self.kinds) - set(_UNITS))
        if unknown:
            raise ValueError(f"joint kinds {unknown} are unknown; choose from {sorted(_UNITS)}")
        limits = ((-math.inf, math.inf),) * len(self.names) if self.limits is None else self.limits
        if len(limits) != len(self.names) or any(len(pair) != 2 or not pair[0] < pair[1] for pair in limits):
            raise ValueError(f"joint limits {self.limits} must be one (low, high) pair with low < high per joint")
        object.__setattr__(self, "limits", tuple((float(lo), float(hi)) for lo, hi in limits))

    def outside_limits(self, q) -> str | None:
        """Where joint positions ``q`` (shape (..., n)) leave the joints' ranges, as a phrase; None if they do not.

        The phrase names the joint, the farthest value reached and the range, e.g.
        ``"d3 reaches 1e+06 m, outside its range 0 to 0.48 m"``.
        """
        q = np.asarray(q, dtype=float).reshape(-1, self.count)
        for i, (lo, hi) in enumerate(self.limits):
            low, high = float(q[:, i].min()), float(q[:, i].max())
            if low < lo or high > hi:
                value = low if lo - low >= high - hi else high
                unit = self.position_units[i]
                return f"{self.names[i]} reaches {value:.6g} {unit}, outside its range {lo:g} to {hi:g} {unit}"
        return None

    @property
    def count(self) -> int:
        """Number of joints."""
        return len(self.names)

    @property
    def position_units(self) -> tuple[str, ...]:
        """Unit of each joint position: ``rad`` or ``m``."""
        return tuple(_UNITS[k][0] for k in self.kinds)

    @property
    def velocity_units(self) -> tuple[str, ...]:
        """Unit of each joint velocity: ``rad/s`` or ``m/s``."""
        return tuple(_UNITS[k][1] for k in self.kinds)

    @property
    def force_units(self) -> tuple[str, ...]:
        """Unit of each generalised force (torque, disturbance): ``N m`` or ``N``."""
        return tuple(_UNITS[k][2] for k in self.kinds)

    @property
    def labels(self) -> tuple[str, ...]:
        """How a person reads each joint: ``Joint 1 (theta1)``, ..."""
        return tuple(f"Joint {i + 1} ({name})" for i, name in enumerate(self.names))

    def signal_names(self, prefix: str) -> list[str]:
        """The per-joint signal names ``prefix[0]`` .. ``prefix[n-1]``."""
        return [f"{prefix}[{i}]" for i in range(self.count)]


def signal_names(prefix: str, joints: JointSpace) -> list[str]:
    """The per-joint signal names ``prefix[i]`` of an arm's joints."""
    return joints.signal_names(prefix)
