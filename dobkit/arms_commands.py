"""``dobkit arms``: the example arms a scenario names as ``[arm] urdf = "example:NAME"``.

One row per arm: its name, its joint count and kinds, each joint's range and
the default tool frame (and the gripper joints locked by default).  The rows
come from the URDF files' XML (:func:`blocks.model.urdf.examples.example_arms`):
no arm is loaded with pinocchio, so the listing takes a tenth of a second.
"""
from __future__ import annotations

import math

__all__ = ["add_arms_subcommand", "format_arms"]

#: What each URDF joint type is called in the listing (R, P; a continuous joint is a revolute without limits).
_KIND_LETTER = {"revolute": "R", "continuous": "C", "prismatic": "P"}


def add_arms_subcommand(sub) -> None:
    """``dobkit arms [NAME]`` in the subparsers ``sub``."""
    parser = sub.add_parser("arms", help="list the example arms a scenario names as [arm] urdf = \"example:NAME\"",
                            description="List the example arms: dobkit's scope4 and every serial arm of "
                                        "example-robot-data (pip install \"dobkit[urdf]\"), with their joints, "
                                        "ranges and default tool frames.")
    parser.add_argument("name", nargs="?", help="one arm: its joints one per line")
    parser.set_defaults(func=_cmd_arms)


def _range(limits: tuple, kind: str) -> str:
    lower, upper = limits
    if not (math.isfinite(lower) and math.isfinite(upper)):
        return "unlimited"
    unit = "m" if kind == "prismatic" else "rad"
    return f"{lower:.4g} to {upper:.4g} {unit}"


def format_arms(arms: dict) -> str:
    """The listing: a header and one line per arm (sorted by name)."""
    rows = [("name", "joints", "kinds", "tool frame (default)", "locked (default)", "limits")]
    for name in sorted(arms):
        arm = arms[name]
        kinds = "".join(_KIND_LETTER[k] for k in arm.kinds)
        limits = "; ".join(_range(lim, k) for lim, k in zip(arm.limits, arm.kinds))
        rows.append((name, str(len(arm.joints)), kinds, arm.tool_frame, ", ".join(arm.locked) or "-", limits))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]) - 1)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r[:-1], widths)) + "  " + r[-1] for r in rows]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(line.rstrip() for line in lines) + \
        "\nkinds: R revolute, C continuous, P prismatic; in a scenario: [arm] urdf = \"example:NAME\" " \
        "(tool_frame and locked default to the columns above)"


def format_arm(arm) -> str:
    """One arm: its file, tool frame, locked joints and one line per joint."""
    lines = [f"{arm.name}: {len(arm.joints)} joints, from {arm.file}", f"tool frame (default): {arm.tool_frame}",
             f"locked (default): {', '.join(arm.locked) or '-'}"]
    width = max(len(j) for j in arm.joints)
    for j, kind, lim in zip(arm.joints, arm.kinds, arm.limits):
        lines.append(f"  {j.ljust(width)}  {kind:<10}  {_range(lim, kind)}")
    return "\n".join(lines)


def _cmd_arms(args) -> int:
    from blocks.model.urdf.examples import example_arms, example_defaults

    if args.name is not None:                               # "" is a name too (none such), not "all of them"
        print(format_arm(example_defaults(args.name)))      # an unknown name: the error lists the names
        return 0
    print(format_arms(example_arms()))
    return 0
