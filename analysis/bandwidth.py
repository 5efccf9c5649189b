"""Observer bandwidth across the workspace: eigenvalues and modal directions of ``Y M^-1(q)``.

On a perfect model the estimation error obeys ``e_d' = -Y M^-1(q) e_d``
(docs/model.md, "Observer"), so at a frozen configuration the observer's modes
decay at the eigenvalues of ``Y M^-1(q)`` (rad/s) along its eigenvectors (directions in
disturbance space, N m / N).  The paper's gain ``Y = 10 I`` does not give
"10 rad/s": for this arm one whole-arm mode is below 1 rad/s.

Nothing here assumes which joints ``M`` depends on: the survey evaluates the
nominal inertia on a grid over all four joints and reports how much the
eigenvalues change along each joint axis.
"""
from __future__ import annotations

import numpy as np

from blocks import inertia
from blocks.parameters import RobotParameters
from blocks.scenario import Scenario

__all__ = ["DEFAULT_RANGES", "workspace_grid", "observer_modes", "bandwidth_survey", "along_trajectory"]

# Joint ranges and point counts of the default survey grid (rad, rad, m, rad); also the default workspace
# grid of the analyses (analysis.report.AnalysisSettings.workspace_points).  The prismatic range spans the
# laceration path's depths (about 0.24 m) with a wide margin; revolute joints cover a full turn.
DEFAULT_RANGES = ((-np.pi, np.pi), (-np.pi, np.pi), (0.10, 0.35), (-np.pi, np.pi))
DEFAULT_POINTS = (5, 73, 3, 5)


def workspace_grid(points=DEFAULT_POINTS, ranges=DEFAULT_RANGES) -> tuple[np.ndarray, list[np.ndarray]]:
    """A full-factorial grid of configurations.

    Parameters
    ----------
    points : 4 ints
        Number of values per joint (>= 1; one value takes the range's midpoint).
    ranges : 4 pairs of floats
        ``(low, high)`` per joint (rad, rad, m, rad), both ends included.

    Returns
    -------
    q : numpy.ndarray, shape (prod(points), 4)
        The configurations, joint 4 varying fastest.
    axes : list of numpy.ndarray
        The values along each joint.
    """
    if len(points) != 4 or len(ranges) != 4 or any(int(n) < 1 for n in points):
        raise ValueError(f"need 4 point counts >= 1 and 4 ranges, got points={points!r}, ranges={ranges!r}")
    axes = [np.linspace(lo, hi, int(n)) if int(n) > 1 else np.array([(lo + hi) / 2.0])
            for n, (lo, hi) in zip(points, ranges)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=-1), axes


def observer_modes(params: RobotParameters, Y, q) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and unit eigenvectors of ``Y M^-1(q)`` at each configuration.

    Parameters
    ----------
    params : RobotParameters
        The model the observer uses (the nominal one).
    Y : array_like, shape (4, 4)
        Observer gain.
    q : array_like, shape (..., 4)
        Configurations.

    Returns
    -------
    rates : numpy.ndarray, shape (..., 4)
        Eigenvalues (rad/s), sorted by real part, slowest first; complex only
        if ``Y`` makes them so (a symmetric positive definite ``Y`` gives real ones).
    directions : numpy.ndarray, shape (..., 4, 4)
        ``directions[..., :, k]`` is the unit eigenvector of ``rates[..., k]``,
        signed so that its largest component is positive.
    """
    Y = np.asarray(Y, dtype=float)
    A = Y @ np.linalg.inv(inertia(q, params))
    w, v = np.linalg.eig(A)
    order = np.argsort(w.real, axis=-1)
    w = np.take_along_axis(w, order, axis=-1)
    v = np.take_along_axis(v, order[..., None, :], axis=-1)
    if np.all(np.abs(w.imag) <= 1e-12 * np.abs(w)):
        w, v = w.real, v.real
    v = v / np.linalg.norm(v, axis=-2, keepdims=True)
    big = np.take_along_axis(v, np.argmax(np.abs(v), axis=-2)[..., None, :], axis=-2)
    return w, v * np.where(np.real(big) < 0, -1.0, 1.0)


def bandwidth_survey(scenario: Scenario, Y=None, points=DEFAULT_POINTS, ranges=DEFAULT_RANGES, q_slice=None,
                     slice_points: int = 181) -> dict:
    """Observer modes over a grid of the whole workspace and along ``theta2``.

    Parameters
    ----------
    scenario : Scenario
        Its nominal model and (unless ``Y`` is given) its observer gain are used.
    Y : array_like, shape (4, 4), optional
        Observer gain to survey instead of the scenario's.
    points, ranges
        The workspace grid (see :func:`workspace_grid`).
    q_slice : array_like, shape (4,), optional
        The other joints of the ``theta2`` slice (default: the reference at t = 0).
    slice_points : int
        Number of ``theta2`` values of the slice over ``[-pi, pi]``.

    Returns
    -------
    dict
        JSON-ready:

        * ``theta2`` (rad), ``eigenvalues`` (rad/s, 4 per theta2, slowest first)
          and ``slowest_direction`` (unit eigenvector per theta2) on the slice;
        * ``slowest_rad_s``: ``{"min", "max", "q_at_min", "q_at_max",
          "direction_at_min"}`` of the slowest mode over the whole grid (the
          direction: its unit eigenvector where it is slowest);
        * ``fastest_rad_s``: ``{"min", "max", "q_at_max", "direction_at_max"}``
          of the fastest mode;
        * ``ranges_rad_s``: ``[min, max]`` of each mode over the grid;
        * ``sensitivity_rad_s``: per joint, the largest change of any eigenvalue
          along that joint's axis of the grid (zero: ``M`` does not depend on it);
        * ``grid``: the joint values surveyed.
    """
    Y = scenario.observer_gain if Y is None else np.asarray(Y, dtype=float)
    q, axes = workspace_grid(points, ranges)
    rates, dirs = observer_modes(scenario.nominal, Y, q)
    rates_r = np.real(rates)
    slow, fast = rates_r[:, 0], rates_r[:, -1]
    k_min, k_max = int(np.argmin(slow)), int(np.argmax(slow))
    k_fast = int(np.argmax(fast))
    shaped = rates_r.reshape(tuple(len(a) for a in axes) + (4,))
    sensitivity = [float(np.max(np.ptp(shaped, axis=j))) for j in range(4)]

    if q_slice is None:
        q_slice = scenario.trajectory.evaluate(0.0)[0]
    theta2 = np.linspace(-np.pi, np.pi, slice_points)
    q_line = np.tile(np.asarray(q_slice, dtype=float), (slice_points, 1))
    q_line[:, 1] = theta2
    line_rates, line_dirs = observer_modes(scenario.nominal, Y, q_line)
    return {
        "Y": Y.tolist(),
        "theta2": theta2.tolist(),
        "q_slice": np.asarray(q_slice, dtype=float).tolist(),
        "eigenvalues": np.real(line_rates).tolist(),
        "slowest_direction": np.real(line_dirs[:, :, 0]).tolist(),
        "slowest_rad_s": {"min": float(slow[k_min]), "max": float(slow[k_max]),
                          "q_at_min": q[k_min].tolist(), "q_at_max": q[k_max].tolist(),
                          "direction_at_min": np.real(dirs[k_min, :, 0]).tolist()},
        "fastest_rad_s": {"min": float(fast.min()), "max": float(fast[k_fast]), "q_at_max": q[k_fast].tolist(),
                          "direction_at_max": np.real(dirs[k_fast, :, -1]).tolist()},
        "ranges_rad_s": [[float(rates_r[:, k].min()), float(rates_r[:, k].max())] for k in range(4)],
        "complex": bool(np.iscomplexobj(rates)),
        "sensitivity_rad_s": dict(zip(("theta1", "theta2", "d3", "theta4"), sensitivity)),
        "grid": {"points": [len(a) for a in axes], "axes": [a.tolist() for a in axes]},
    }


def along_trajectory(scenario: Scenario, Y=None, samples: int = 401) -> dict:
    """The slowest observer mode along the scenario's reference path.

    Returns
    -------
    dict
        ``time`` (s), ``slowest_rad_s`` per sample, its ``min``/``max`` and the
        slowest mode's direction where it is smallest.
    """
    Y = scenario.observer_gain if Y is None else np.asarray(Y, dtype=float)
    t = np.linspace(0.0, scenario.simulation.t_final, samples)
    q, _, _ = scenario.trajectory.evaluate(t)
    rates, dirs = observer_modes(scenario.nominal, Y, q)
    slow = np.real(rates[:, 0])
    k = int(np.argmin(slow))
    return {"time": t.tolist(), "slowest_rad_s": slow.tolist(), "min": float(slow.min()), "max": float(slow.max()),
            "direction_at_min": np.real(dirs[k, :, 0]).tolist()}
