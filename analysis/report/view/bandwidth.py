"""Section 4 of the report: the observer's modes over the workspace and along the path."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .text import Figure, Table, arm_joints, figures, fmt, join, mode_text

__all__ = ["BandwidthSection", "bandwidth_section"]


@dataclass(frozen=True)
class BandwidthSection:
    """4. Observer modes over the workspace and along the path."""

    grid: str
    modes: Table
    slowest: str
    reading: str
    figures: list[Figure]


def bandwidth_section(result, files: dict, scenario=None) -> BandwidthSection:
    """The section's tables and statements; the joints named as the scenario's arm names them."""
    bw = result.observer_bandwidth
    joints = arm_joints(scenario)
    s = bw.slowest_rad_s
    fast = bw.fastest_rad_s
    rows = [[f"mode {k + 1}", fmt(lo, 4), fmt(hi, 4), fmt(1 / hi, 3), fmt(1 / lo, 3)] for k, (lo, hi) in
            enumerate(bw.ranges_rad_s)]
    sens = ", ".join(f"{k}: {fmt(v, 3)}" for k, v in bw.sensitivity_rad_s.items())
    at = bw.along_trajectory
    slowest = (f"Slowest mode: {fmt(s.min, 4)} rad/s at q = [{join(s.q_at_min, 4)}], {fmt(s.max, 4)} rad/s "
               f"at q = [{join(s.q_at_max, 4)}]. Along the scenario's path it is {fmt(at.min, 4)} to "
               f"{fmt(at.max, 4)} rad/s; its direction in disturbance space there is "
               f"[{join(at.direction_at_min, 3)}] ({', '.join(joints.names)}): it moves "
               f"{mode_text(at.direction_at_min)}. Largest change of any eigenvalue along each joint axis of "
               f"the grid (rad/s): {sens}.")
    Y = np.array(bw.Y)
    scalar = np.allclose(Y, Y[0, 0] * np.eye(len(Y)))
    spread = scalar and (s.min < 0.99 * Y[0, 0] or fast.max > 1.01 * Y[0, 0])
    reading = ((f"A gain Y = {fmt(Y[0, 0])} I does not give one bandwidth of {fmt(Y[0, 0])} rad/s: " if spread else "")
               + f"the observer's rates are the gain divided by the inertia seen in each modal direction, from "
                 f"{fmt(s.min, 4)} rad/s (slowest mode, moving {mode_text(s.direction_at_min)}) to "
                 f"{fmt(fast.max, 4)} rad/s (fastest mode, moving {mode_text(fast.direction_at_max)}). A "
                 f"disturbance that acts along the slowest direction is learnt with a time constant of up to "
                 f"{fmt(1 / s.min, 3)} s.")
    return BandwidthSection(
        grid=" x ".join(str(n) for n in bw.grid.points),
        modes=Table.of(["mode", "min (rad/s)", "max (rad/s)", "time constant min (s)", "time constant max (s)"], rows,
                       "Eigenvalues of Y M^-1(q) over the workspace"),
        slowest=slowest, reading=reading,
        figures=figures(files, ("observer_bandwidth",
                                f"Observer modes along {bw.slice_joint_name} and the slowest mode's direction")))

