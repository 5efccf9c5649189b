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

from dataclasses import dataclass

__all__ = ["JointSpace", "RRPR_JOINTS", "signal_names"]

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
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.names) != len(self.kinds) or not self.names:
            raise ValueError(f"joint names {self.names} and kinds {self.kinds} must be non-empty and of one length")
        unknown = sorted(set(self.kinds) - set(_UNITS))
        if unknown:
            raise ValueError(f"joint kinds {unknown} are unknown; choose from {sorted(_UNITS)}")

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


#: The paper's arm: ``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]``.
RRPR_JOINTS = JointSpace(names=("theta1", "theta2", "d3", "theta4"),
                         kinds=("revolute", "revolute", "prismatic", "revolute"))


def signal_names(prefix: str, joints: JointSpace = RRPR_JOINTS) -> list[str]:
    """The per-joint signal names ``prefix[i]`` of an arm (default: the paper's)."""
    return joints.signal_names(prefix)
