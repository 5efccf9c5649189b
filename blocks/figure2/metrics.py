"""Tracking metrics of a simulated run: the paper's RMS errors (Eq. 13 and 14) and more.

All metrics are per joint, in the joint's unit (rad for a revolute joint, m
for a prismatic one; N m or N for disturbances: the paper's RRPR has rad,
rad, m, rad), computed over the uniform output grid of the response.  The
joint count, names and units are the arm's (``response.scenario.robot.joints``);
the tool-tip errors use the arm's ``tool_position`` row kernel.

There is no "largest disturbance-estimation error": the observer starts from
``d_hat(0) = 0``, so the largest ``|d - d_hat|`` of a run is the disturbance
itself at t = 0 (``f_r`` for the paper's step), before the observer can know
anything, whatever its gain.  ``rms_disturbance_error`` (Eq. 14) measures the
estimate; the analysis report gives the time the estimate takes to get within
2 % of the disturbance.
"""
from __future__ import annotations

import numpy as np

__all__ = ["signal", "tracking_metrics", "rms", "TrackingAccumulator", "METRICS", "OBSERVER_METRICS"]

#: Every tracking metric, per joint in the joint's unit (rad, rad, m, rad; N m or N for the
#: disturbance errors) or, for the tool tip, in mm.
METRICS = ("rms_position_error", "max_abs_position_error", "final_abs_position_error",
           "max_tool_position_error_mm", "rms_tool_position_error_mm",
           "rms_disturbance_error")
#: The metrics of the disturbance estimate, which need the observer.
OBSERVER_METRICS = ("rms_disturbance_error",)



def signal(response, prefix: str, n: int | None = None) -> np.ndarray:
    """The joint signals ``prefix[0..n-1]`` of a response, shape (n, len(time)).

    ``n`` defaults to the joint count of the response's scenario's arm (without a scenario: every
    ``prefix[i]`` the response has, from 0 up).

    Raises
    ------
    KeyError
        If the response has no such signal.
    """
    labels = list(response.output_labels)
    if n is None:
        scenario = getattr(response, "scenario", None)
        n = scenario.robot.joints.count if scenario is not None else \
            next(i for i in range(len(labels) + 1) if f"{prefix}[{i}]" not in labels) or len(labels) + 1
    try:
        rows = [labels.index(f"{prefix}[{i}]") for i in range(n)]
    except ValueError:
        raise KeyError(f"response has no signal '{prefix}[i]'; it has {sorted({l.split('[')[0] for l in labels})}") from None
    return np.asarray(response.outputs)[rows]


def rms(x: np.ndarray) -> np.ndarray:
    """Root mean square over the last axis (the paper's Eq. 13-14 over n samples)."""
    return np.sqrt(np.mean(np.square(x), axis=-1))


class TrackingAccumulator:
    """The tracking metrics, accumulated over the output grid in chunks of points.

    One definition serves a single run (:func:`tracking_metrics`, one chunk)
    and a batch (:func:`blocks.figure2.batch.simulate_batch`, chunks of grid points
    over a member axis).  Signals are rows: ``(n, m, *members)`` for ``m``
    grid points.

    Parameters
    ----------
    kin : numpy.ndarray or object
        The arm's tool parameters (``arm.tool_params()``) for the tool-tip errors; plain numbers get the member
        axes.
    n_points : int
        Grid points in the whole run (the RMS divides by it).
    metrics : sequence of str
        Which of :data:`METRICS` to keep.
    members : tuple of int
        Shape of the member axes (``()`` for a single run).
    n_joints : int
        Joints of the arm (a keyword).
    tool_position : callable, optional
        The arm's ``tool_position(kin, q)`` row kernel (``arm.tool_kernels.tool_position``); needed for the
        tool metrics.
    """

    def __init__(self, kin, n_points: int, metrics=METRICS, members: tuple = (), *, n_joints: int,
                 tool_position=None) -> None:
        if isinstance(kin, (np.ndarray, list)):       # plain numbers get the member axes
            kin = np.asarray(kin, dtype=float)
            kin = kin.reshape(kin.shape + (1,) * (1 + len(members)))
        self.kin = kin
        self.tool_position = tool_position
        self.n_points, self.metrics = n_points, tuple(metrics)
        joints = (n_joints,) + tuple(members)
        self.sum_sq_e, self.max_e, self.final_e = np.zeros(joints), np.zeros(joints), np.zeros(joints)
        self.sum_sq_tool, self.max_tool = np.zeros(members), np.zeros(members)
        self.sum_sq_ed = np.zeros(joints)
        self.wants_tool = any("tool" in m for m in self.metrics)
        if self.wants_tool and tool_position is None:
            raise ValueError(f"tool metrics {[m for m in self.metrics if 'tool' in m]} need the arm's tool_position "
                             "row kernel (arm.tool_kernels.tool_position)")
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
            diff = self.tool_position(self.kin, q_ref) - self.tool_position(self.kin, q)
            dist = np.sqrt(np.sum(diff * diff, axis=0))
            self.sum_sq_tool += np.sum(dist * dist, axis=0)
            np.maximum(self.max_tool, np.max(dist, axis=0), out=self.max_tool)
        if self.wants_disturbance and d is not None:
            ed = d - d_hat
            self.sum_sq_ed += np.sum(ed * ed, axis=1)

    def result(self) -> dict:
        """The kept metrics: per joint ``(n, *members)``, tool errors ``members`` (mm)."""
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
        ``final_abs_position_error`` per joint (the joint's unit: rad or m); with the
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
    if scenario is not None:
        arm = scenario.robot
        acc = TrackingAccumulator(arm.tool_params(), q.shape[1], names, n_joints=arm.joints.count,
                                  tool_position=arm.tool_kernels.tool_position)
    else:                                   # no arm: no tool metrics are kept
        acc = TrackingAccumulator(np.zeros(1), q.shape[1], names, n_joints=q.shape[0])
    d = d_hat = None
    if observer:
        d = signal(response, "d") if "d[0]" in labels else signal(response, "tau_dis")
        d_hat = signal(response, "d_hat")
    acc.add(q_ref, q, d, d_hat, last=True)
    return {name: (value.tolist() if value.ndim else float(value)) for name, value in acc.result().items()}
