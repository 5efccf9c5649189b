"""Tracking metrics of a simulated run: the paper's RMS errors (Eq. 13 and 14) and more.

All metrics are per joint, in the joint's unit (rad for joints 1, 2 and 4, m
for the prismatic joint 3; N m or N for disturbances), computed over the
uniform output grid of the response.

There is no "largest disturbance-estimation error": the observer starts from
``d_hat(0) = 0``, so the largest ``|d - d_hat|`` of a run is the disturbance
itself at t = 0 (``f_r`` for the paper's step), before the observer can know
anything, whatever its gain.  ``rms_disturbance_error`` (Eq. 14) measures the
estimate; the analysis report gives the time the estimate takes to get within
2 % of the disturbance.
"""
from __future__ import annotations

import numpy as np

from .joints import RRPR_JOINTS
from .kernels.kinematics import kinematic_lengths, tool_pose

__all__ = ["signal", "tracking_metrics", "rms", "TrackingAccumulator", "METRICS", "OBSERVER_METRICS", "JOINT_UNITS",
           "DISTURBANCE_UNITS", "JOINT_LABELS"]

#: Every tracking metric, per joint in the joint's unit (rad, rad, m, rad; N m or N for the
#: disturbance errors) or, for the tool tip, in mm.
METRICS = ("rms_position_error", "max_abs_position_error", "final_abs_position_error",
           "max_tool_position_error_mm", "rms_tool_position_error_mm",
           "rms_disturbance_error")
#: The metrics of the disturbance estimate, which need the observer.
OBSERVER_METRICS = ("rms_disturbance_error",)

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


class TrackingAccumulator:
    """The tracking metrics, accumulated over the output grid in chunks of points.

    One definition serves a single run (:func:`tracking_metrics`, one chunk)
    and a batch (:func:`blocks.batch.simulate_batch`, chunks of grid points
    over a member axis).  Signals are rows: ``(4, m, *members)`` for ``m``
    grid points.

    Parameters
    ----------
    kin : numpy.ndarray
        Kinematic lengths ``[a1, a2, d1, d4]`` (m) for the tool-tip errors.
    n_points : int
        Grid points in the whole run (the RMS divides by it).
    metrics : sequence of str
        Which of :data:`METRICS` to keep.
    members : tuple of int
        Shape of the member axes (``()`` for a single run).
    """

    def __init__(self, kin, n_points: int, metrics=METRICS, members: tuple = ()) -> None:
        self.kin = np.asarray(kin, dtype=float).reshape((4,) + (1,) * (1 + len(members)))
        self.n_points, self.metrics = n_points, tuple(metrics)
        joints = (4,) + tuple(members)
        self.sum_sq_e, self.max_e, self.final_e = np.zeros(joints), np.zeros(joints), np.zeros(joints)
        self.sum_sq_tool, self.max_tool = np.zeros(members), np.zeros(members)
        self.sum_sq_ed = np.zeros(joints)
        self.wants_tool = any("tool" in m for m in self.metrics)
        self.wants_disturbance = any(m in OBSERVER_METRICS for m in self.metrics)

    def add(self, q_ref, q, d=None, d_hat=None, last: bool = False) -> None:
        """Add ``m`` grid points: references and positions (rad, m), and ``d``, ``d_hat`` (N m, N) if kept.

        ``last`` marks the chunk that ends the run (for the final error).
        """
        e = q_ref - q
        self.sum_sq_e += np.sum(e * e, axis=1)
        np.maximum(self.max_e, np.max(np.abs(e), axis=1), out=self.max_e)
        if last:
            self.final_e[...] = np.abs(e[:, -1])
        if self.wants_tool:
            diff = tool_pose(self.kin, q_ref)[:3] - tool_pose(self.kin, q)[:3]
            dist = np.sqrt(np.sum(diff * diff, axis=0))
            self.sum_sq_tool += np.sum(dist * dist, axis=0)
            np.maximum(self.max_tool, np.max(dist, axis=0), out=self.max_tool)
        if self.wants_disturbance and d is not None:
            ed = d - d_hat
            self.sum_sq_ed += np.sum(ed * ed, axis=1)

    def result(self) -> dict:
        """The kept metrics: per joint ``(4, *members)``, tool errors ``members`` (mm)."""
        n = self.n_points
        values = {
            "rms_position_error": np.sqrt(self.sum_sq_e / n),
            "max_abs_position_error": self.max_e,
            "final_abs_position_error": self.final_e,
            "max_tool_position_error_mm": 1e3 * self.max_tool,
            "rms_tool_position_error_mm": 1e3 * np.sqrt(self.sum_sq_tool / n),
            "rms_disturbance_error": np.sqrt(self.sum_sq_ed / n),
        }
        return {name: values[name].copy() for name in self.metrics}


def tracking_metrics(response) -> dict:
    """Metrics of one run, JSON-ready.

    Returns
    -------
    dict
        ``rms_position_error`` (Eq. 13), ``max_abs_position_error`` and
        ``final_abs_position_error`` per joint (rad, rad, m, rad); with the
        response's scenario, ``max_tool_position_error_mm`` and
        ``rms_tool_position_error_mm`` (tool-tip distance from its reference,
        mm); with the observer also ``rms_disturbance_error`` (Eq. 14,
        ``d - d_hat``, N m / N).
    """
    scenario = getattr(response, "scenario", None)
    labels = list(response.output_labels)
    observer = "d_hat[0]" in labels
    names = [m for m in METRICS if (scenario is not None or "tool" not in m) and (observer or m not in OBSERVER_METRICS)]
    q_ref, q = signal(response, "q_ref"), signal(response, "q")
    kin = kinematic_lengths(scenario.robot) if scenario is not None else np.zeros(4)
    acc = TrackingAccumulator(kin, q.shape[1], names)
    d = d_hat = None
    if observer:
        d = signal(response, "d") if "d[0]" in labels else signal(response, "tau_dis")
        d_hat = signal(response, "d_hat")
    acc.add(q_ref, q, d, d_hat, last=True)
    return {name: (value.tolist() if value.ndim else float(value)) for name, value in acc.result().items()}
