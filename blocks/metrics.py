"""Tracking metrics of a simulated run: the paper's RMS errors (Eq. 13 and 14) and more.

All metrics are per joint, in the joint's unit (rad for joints 1, 2 and 4, m
for the prismatic joint 3; N m or N for disturbances), computed over the
uniform output grid of the response.
"""
from __future__ import annotations

import numpy as np

from .joints import RRPR_JOINTS
from .kinematics import forward_kinematics

__all__ = ["signal", "tracking_metrics", "rms", "JOINT_UNITS", "DISTURBANCE_UNITS", "JOINT_LABELS"]

JOINT_LABELS = RRPR_JOINTS.names
JOINT_UNITS = RRPR_JOINTS.position_units
DISTURBANCE_UNITS = RRPR_JOINTS.force_units


def signal(response, prefix: str) -> np.ndarray:
    """The four joint signals ``prefix[0..3]`` of a response, shape (4, len(time)).

    Raises
    ------
    KeyError
        If the response has no such signal.
    """
    labels = list(response.output_labels)
    try:
        rows = [labels.index(f"{prefix}[{i}]") for i in range(4)]
    except ValueError:
        raise KeyError(f"response has no signal '{prefix}[i]'; it has {sorted({l.split('[')[0] for l in labels})}") from None
    return np.asarray(response.outputs)[rows]


def rms(x: np.ndarray) -> np.ndarray:
    """Root mean square over the last axis (the paper's Eq. 13-14 over n samples)."""
    return np.sqrt(np.mean(np.square(x), axis=-1))


def tracking_metrics(response) -> dict:
    """Metrics of one run, JSON-ready.

    Returns
    -------
    dict
        ``rms_position_error`` (Eq. 13), ``max_abs_position_error`` and
        ``final_abs_position_error`` per joint (rad, rad, m, rad);
        ``max_tool_position_error_mm`` (tool-tip distance from its reference, mm);
        with the observer also ``rms_disturbance_error`` (Eq. 14, ``d - d_hat``,
        N m / N) and ``max_abs_disturbance_error``.
    """
    e = signal(response, "q_ref") - signal(response, "q")
    out = {
        "rms_position_error": rms(e).tolist(),
        "max_abs_position_error": np.max(np.abs(e), axis=1).tolist(),
        "final_abs_position_error": np.abs(e[:, -1]).tolist(),
    }
    scenario = getattr(response, "scenario", None)
    if scenario is not None:
        p_ref = forward_kinematics(signal(response, "q_ref").T, scenario.robot)
        p = forward_kinematics(signal(response, "q").T, scenario.robot)
        out["max_tool_position_error_mm"] = float(1e3 * np.max(np.linalg.norm(p_ref[:, :3] - p[:, :3], axis=1)))
        out["rms_tool_position_error_mm"] = float(1e3 * rms(np.linalg.norm(p_ref[:, :3] - p[:, :3], axis=1)))
    labels = list(response.output_labels)
    if "d_hat[0]" in labels:
        d = signal(response, "d") if "d[0]" in labels else signal(response, "tau_dis")
        ed = d - signal(response, "d_hat")
        out["rms_disturbance_error"] = rms(ed).tolist()
        out["max_abs_disturbance_error"] = np.max(np.abs(ed), axis=1).tolist()
    return out
