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

from dataclasses import dataclass

import numpy as np

from blocks import inertia
from blocks.parameters import RobotParameters
from blocks.scenario import Scenario

from .results import JsonResult, omitted_if_none

__all__ = ["DEFAULT_RANGES", "SlowestMode", "FastestMode", "SurveyGrid", "PathModes", "BandwidthOverview",
           "BandwidthSurvey", "workspace_grid", "observer_modes", "bandwidth_survey", "along_trajectory"]

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


@dataclass(frozen=True)
class SlowestMode(JsonResult):
    """The slowest observer mode over a grid: its range (rad/s), where it is reached, and its direction there.

    ``direction_at_min`` is the unit eigenvector (disturbance space) where the mode is slowest.
    """

    min: float
    max: float
    q_at_min: list[float]
    q_at_max: list[float]
    direction_at_min: list[float]


@dataclass(frozen=True)
class FastestMode(JsonResult):
    """The fastest observer mode over a grid: its range (rad/s), where it is fastest and its direction there."""

    min: float
    max: float
    q_at_max: list[float]
    direction_at_max: list[float]


@dataclass(frozen=True)
class SurveyGrid(JsonResult):
    """Point count and values along each joint of a workspace grid (rad, rad, m, rad)."""

    points: list[int]
    axes: list[list[float]]


@dataclass(frozen=True)
class PathModes(JsonResult):
    """The slowest observer mode along a reference path.

    Attributes
    ----------
    time : list of float
        Sample times (s).
    slowest_rad_s : list of float
        The slowest mode per sample (rad/s).
    min, max : float
        Its range along the path (rad/s).
    direction_at_min : list of float
        Its unit eigenvector where it is slowest.
    """

    time: list[float]
    slowest_rad_s: list[float]
    min: float
    max: float
    direction_at_min: list[float]


@dataclass(frozen=True)
class BandwidthOverview(JsonResult):
    """The part of a survey kept for a designed gain: the theta2 slice, the slowest mode and every mode's range."""

    theta2: list[float]
    eigenvalues: list[list[float]]
    slowest_rad_s: SlowestMode
    ranges_rad_s: list[list[float]]


@dataclass(frozen=True)
class BandwidthSurvey(JsonResult):
    """Observer modes over the workspace (see :func:`bandwidth_survey`).

    Attributes
    ----------
    Y : list of list of float
        The observer gain surveyed (kg m^2/s).
    theta2 : list of float
        The slice's theta2 values (rad).
    q_slice : list of float
        The other joints of the slice (rad, rad, m, rad).
    eigenvalues : list of list of float
        Per theta2, the 4 decay rates (rad/s), slowest first.
    slowest_direction : list of list of float
        Per theta2, the slowest mode's unit eigenvector.
    slowest_rad_s : SlowestMode
        The slowest mode over the whole grid.
    fastest_rad_s : FastestMode
        The fastest mode over the whole grid.
    ranges_rad_s : list of list of float
        ``[min, max]`` of each mode over the grid (rad/s).
    complex : bool
        Whether any eigenvalue was complex (only the real parts are kept).
    sensitivity_rad_s : dict of str to float
        Per joint, the largest change of any eigenvalue along its axis of the grid (zero: ``M`` does not depend on it).
    grid : SurveyGrid
    along_trajectory : PathModes or None
        The slowest mode along the scenario's path, when it was computed (left out of the JSON otherwise).
    """

    Y: list[list[float]]
    theta2: list[float]
    q_slice: list[float]
    eigenvalues: list[list[float]]
    slowest_direction: list[list[float]]
    slowest_rad_s: SlowestMode
    fastest_rad_s: FastestMode
    ranges_rad_s: list[list[float]]
    complex: bool
    sensitivity_rad_s: dict[str, float]
    grid: SurveyGrid
    along_trajectory: PathModes | None = omitted_if_none()

    def overview(self) -> BandwidthOverview:
        """The theta2 slice, slowest mode and ranges of this survey."""
        return BandwidthOverview(theta2=self.theta2, eigenvalues=self.eigenvalues, slowest_rad_s=self.slowest_rad_s,
                                 ranges_rad_s=self.ranges_rad_s)


def bandwidth_survey(scenario: Scenario, Y=None, points=DEFAULT_POINTS, ranges=DEFAULT_RANGES, q_slice=None,
                     slice_points: int = 181) -> BandwidthSurvey:
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
    BandwidthSurvey
        The slice's eigenvalues and slowest direction; the slowest and fastest
        modes over the whole grid (range, where, direction); each mode's range;
        the sensitivity to each joint; the grid.  ``along_trajectory`` is left
        None (see :func:`along_trajectory`).
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
    return BandwidthSurvey(
        Y=Y.tolist(),
        theta2=theta2.tolist(),
        q_slice=np.asarray(q_slice, dtype=float).tolist(),
        eigenvalues=np.real(line_rates).tolist(),
        slowest_direction=np.real(line_dirs[:, :, 0]).tolist(),
        slowest_rad_s=SlowestMode(min=float(slow[k_min]), max=float(slow[k_max]), q_at_min=q[k_min].tolist(),
                                  q_at_max=q[k_max].tolist(), direction_at_min=np.real(dirs[k_min, :, 0]).tolist()),
        fastest_rad_s=FastestMode(min=float(fast.min()), max=float(fast[k_fast]), q_at_max=q[k_fast].tolist(),
                                  direction_at_max=np.real(dirs[k_fast, :, -1]).tolist()),
        ranges_rad_s=[[float(rates_r[:, k].min()), float(rates_r[:, k].max())] for k in range(4)],
        complex=bool(np.iscomplexobj(rates)),
        sensitivity_rad_s=dict(zip(("theta1", "theta2", "d3", "theta4"), sensitivity)),
        grid=SurveyGrid(points=[len(a) for a in axes], axes=[a.tolist() for a in axes]),
    )


def along_trajectory(scenario: Scenario, Y=None, samples: int = 401) -> PathModes:
    """The slowest observer mode along the scenario's reference path (``samples`` times over the run)."""
    Y = scenario.observer_gain if Y is None else np.asarray(Y, dtype=float)
    t = np.linspace(0.0, scenario.simulation.t_final, samples)
    q, _, _ = scenario.trajectory.evaluate(t)
    rates, dirs = observer_modes(scenario.nominal, Y, q)
    slow = np.real(rates[:, 0])
    k = int(np.argmin(slow))
    return PathModes(time=t.tolist(), slowest_rad_s=slow.tolist(), min=float(slow.min()), max=float(slow.max()),
                     direction_at_min=np.real(dirs[k, :, 0]).tolist())
