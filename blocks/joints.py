"""The joints of an arm model: how many, their names, kinds and units.

Everything that sizes a signal or labels a joint for a person reads it from
here (through the arm's parameters, :attr:`RobotParameters.joints
<blocks.parameters.RobotParameters.joints>`), so that the joint count is a
property of the model rather than a number repeated in many modules.

Examples
--------
>>> from blocks.joints import RRPR_JOINTS, signal_names
>>> RRPR_JOINTS.count
4
>>> signal_names("tau")
['tau[0]', 'tau[1]', 'tau[2]', 'tau[3]']
>>> RRPR_JOINTS.labels[2]
'Joint 3 (d3)'
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["JointSpace", "RRPR_JOINTS", "D3_STROKE", "signal_names"]

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
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    limits: tuple[tuple[float, float], ...] | None = None

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


#: Stroke of the paper's prismatic joint d3 (m, positive downwards).  The paper gives no stroke; Table 1's
#: d3 = 0.24 m is the stage's working extension (the tool at the skin), and the stroke is taken as 0 to twice that
#: (docs/model.md, "Joint ranges").
D3_STROKE = (0.0, 0.48)

#: The paper's arm: ``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]``.  The revolute
#: joints of a SCARA turn without end (the elbow's singularities are the path's concern); d3 has its stroke.
RRPR_JOINTS = JointSpace(names=("theta1", "theta2", "d3", "theta4"),
                         kinds=("revolute", "revolute", "prismatic", "revolute"),
                         limits=((-math.inf, math.inf), (-math.inf, math.inf), D3_STROKE, (-math.inf, math.inf)))


def signal_names(prefix: str, joints: JointSpace = RRPR_JOINTS) -> list[str]:
    """The per-joint signal names ``prefix[i]`` of an arm (default: the paper's)."""
    return joints.signal_names(prefix)
