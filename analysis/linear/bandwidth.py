"""Observer bandwidth across the workspace: eigenvalues and modal directions of ``Y M^-1(q)``.

On a perfect model the estimation error obeys ``e_d' = -Y M^-1(q) e_d``
(docs/model.md, "Observer"), so at a frozen configuration the observer's modes
decay at the eigenvalues of ``Y M^-1(q)`` (rad/s) along its eigenvectors (directions in
disturbance space, N m / N).  The paper's gain ``Y = 10 I`` does not give
"10 rad/s": for this arm one whole-arm mode is below 1 rad/s.

Nothing here assumes the joint count or which joints ``M`` depends on: the
survey evaluates the nominal inertia (any :class:`~blocks.model.arm.ArmModel`) on a
grid over all ``n`` joints, sampled within the joint limits
(:func:`~analysis.linear.arm_terms.workspace_ranges`), and reports how much the
eigenvalues change along each joint axis.  Its slice runs along the joint
that changes them most (theta2 for the paper's arm).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.linear.arm_terms import arm_model, default_points, joint_vector, workspace_ranges
from analysis.results import JsonResult, omitted_if_none
from blocks.model.arm import ArmModel
from blocks.scenarios.scenario import Scenario, default_arm

__all__ = ["DEFAULT_RANGES", "SlowestMode", "FastestMode", "SurveyGrid", "PathModes", "BandwidthOverview",
           "BandwidthSurvey", "workspace_grid", "observer_modes", "bandwidth_survey", "along_trajectory"]

# Joint ranges and point counts of the paper arm's survey grid (rad, rad, m, rad); also the default workspace
# grid of the analyses (analysis.report.build.AnalysisSettings.workspace_points).  Other arms: default_points and
# workspace_ranges of analysis.linear.arm_terms (within the joint limits).
# the default scenario's arm's survey (the paper's)
DEFAULT_RANGES = default_arm().joints.survey_ranges
DEFAULT_POINTS = default_arm().joints.survey_points


def workspace_grid(points=None, ranges=None, arm: ArmModel | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    """A full-factorial grid of configurations.

    Parameters
    ----------
    points : n ints, optional
        Number of values per joint (>= 1; one value takes the range's midpoint).
        Default: :func:`~analysis.linear.arm_terms.default_points` of the arm.
    ranges : n pairs of floats, optional
        ``(low, high)`` per joint (rad or m), both ends included.  Default:
        :func:`~analysis.linear.arm_terms.workspace_ranges` of the arm (within its limits).
    arm : ArmModel, optional
        The arm whose defaults are used; without it, the default scenario's arm.

    Returns
    -------
    q : numpy.ndarray, shape (prod(points), n)
        The configurations, the last joint varying fastest.
    axes : list of numpy.ndarray
        The values along each joint.
    """
    if arm is not None:
        joints = arm_model(arm).joints
        points = default_points(joints) if points is None else points
        ranges = workspace_ranges(joints) if ranges is None else ranges
    points = DEFAULT_POINTS if points is None else points
    ranges = DEFAULT_RANGES if ranges is None else ranges
    n = len(ranges) if arm is None else arm.n
    if len(points) != n or len(ranges) != n or any(int(k) < 1 for k in points) \
            or any(len(r) != 2 or not np.all(np.isfinite(r)) or not r[0] <= r[1] for r in ranges):
        raise ValueError(f"need {n} point counts >= 1 and {n} finite (low, high) ranges, one per joint, "
                         f"got points={points!r}, ranges={ranges!r}")
    axes = [np.linspace(lo, hi, int(n)) if int(n) > 1 else np.array([(lo + hi) / 2.0])
            for n, (lo, hi) in zip(points, ranges)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=-1), axes


def observer_modes(params: ArmModel, Y, q) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and unit eigenvectors of ``Y M^-1(q)`` at each configuration.

    Parameters
    ----------
    params : ArmModel
        The model the observer uses (the nominal one).
    Y : array_like, shape (n, n)
        Observer gain.
    q : array_like, shape (..., n)
        Configurations.

    Returns
    -------
    rates : numpy.ndarray, shape (..., n)
        Eigenvalues (rad/s), sorted by real part, slowest first; complex only
        if ``Y`` makes them so (a symmetric positive definite ``Y`` gives real ones).
    directions : numpy.ndarray, shape (..., n, n)
        ``directions[..., :, k]`` is the unit eigenvector of ``rates[..., k]``,
        signed so that its largest component is positive.
    """
    arm = arm_model(params, "params")
    Y = np.asarray(Y, dtype=float)
    q = np.asarray(q, dtype=float)
    if Y.shape != (arm.n, arm.n) or q.shape[-1:] != (arm.n,):
        raise ValueError(f"observer gain Y must be {arm.n} x {arm.n} and q of shape (..., {arm.n}) for this arm "
                         f"(joints {list(arm.joints.names)}), got Y of shape {Y.shape} and q of shape {q.shape}")
    A = Y @ np.linalg.inv(arm.inertia(q))
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
    """Point count and values along each joint of a workspace grid (rad or m per joint)."""

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
        The slice's values of its joint (rad or m): theta2 for the paper's arm, else
        ``slice_joint`` (the key keeps its name so that older files read the same).
    q_slice : list of float
        The other joints of the slice (rad, m).
    eigenvalues : list of list of float
        Per slice value, the n decay rates (rad/s), slowest first.
    slowest_direction : list of list of float
        Per slice value, the slowest mode's unit eigenvector.
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
    slice_joint : str or None
        The joint of the slice when it is not theta2 (left out of the JSON for theta2).
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
    slice_joint: str | None = omitted_if_none()

    @property
    def slice_joint_name(self) -> str:
        """The joint the slice runs along (``theta2``, the paper arm's, when the JSON leaves it out)."""
        return self.slice_joint or "theta2"

    def overview(self) -> BandwidthOverview:
        """The theta2 slice, slowest mode and ranges of this survey."""
        return BandwidthOverview(theta2=self.theta2, eigenvalues=self.eigenvalues, slowest_rad_s=self.slowest_rad_s,
                                 ranges_rad_s=self.ranges_rad_s)


def bandwidth_survey(scenario: Scenario, Y=None, points=None, ranges=None, q_slice=None,
                     slice_points: int = 181, arm: ArmModel | None = None, slice_joint: int | None = None,
                     ) -> BandwidthSurvey:
    """Observer modes over a grid of the whole workspace and along one joint.

    Parameters
    ----------
    scenario : Scenario or None
        Its nominal model and (unless ``Y`` is given) its observer gain are used;
        None with ``arm`` and ``Y`` given.
    Y : array_like, shape (n, n), optional
        Observer gain to survey instead of the scenario's.
    points, ranges
        The workspace grid (see :func:`workspace_grid`); default from the arm,
        within its joint limits.
    q_slice : array_like, shape (n,), optional
        The other joints of the slice (default: the reference at t = 0, or the
        middle of the ranges without a scenario).
    slice_points : int
        Number of values of the slice over the slice joint's range.
    arm : ArmModel, optional
        The model the observer uses, instead of the scenario's nominal one.
    slice_joint : int, optional
        The joint the slice runs along (index); default the one along which the
        eigenvalues change most over the grid (the first such: theta2 for the paper's arm).

    Returns
    -------
    BandwidthSurvey
        The slice's eigenvalues and slowest direction; the slowest and fastest
        modes over the whole grid (range, where, direction); each mode's range;
        the sensitivity to each joint; the grid.  ``along_trajectory`` is left
        None (see :func:`along_trajectory`).
    """
    model = arm_model(scenario.nominal if arm is None else arm, "arm")
    if Y is None:
        if scenario is None:
            raise ValueError("bandwidth_survey needs the observer gain Y when no scenario is given")
        Y = scenario.observer_gain
    Y = np.asarray(Y, dtype=float)
    n, names = model.n, model.joints.names
    ranges = workspace_ranges(model.joints) if ranges is None else ranges
    q, axes = workspace_grid(points, ranges, arm=model)
    rates, dirs = observer_modes(model, Y, q)
    rates_r = np.real(rates)
    slow, fast = rates_r[:, 0], rates_r[:, -1]
    k_min, k_max = int(np.argmin(slow)), int(np.argmax(slow))
    k_fast = int(np.argmax(fast))
    shaped = rates_r.reshape(tuple(len(a) for a in axes) + (n,))
    sensitivity = [float(np.max(np.ptp(shaped, axis=j))) for j in range(n)]

    if slice_joint is None:
        # the joint the model's inertia depends on, where it knows (the paper's theta2); else the most sensitive,
        # and on a grid too coarse to tell, the second joint
        known = model.inertia_depends_on
        if known:
            slice_joint = known[0]
        else:
            slice_joint = min(1, n - 1) if max(sensitivity) <= 0.0 else int(np.argmax(sensitivity))
    if not (isinstance(slice_joint, (int, np.integer)) and 0 <= slice_joint < n):
        raise ValueError(f"slice_joint must be a joint index 0..{n - 1} ({list(names)}), got {slice_joint!r}")
    if q_slice is None:
        q_slice = (scenario.trajectory.evaluate(0.0)[0] if scenario is not None
                   else [(lo + hi) / 2.0 for lo, hi in ranges])
    q_slice = joint_vector(q_slice, "q_slice", model.joints)
    lo, hi = ranges[slice_joint]
    line = np.linspace(lo, hi, slice_points)
    q_line = np.tile(q_slice, (slice_points, 1))
    q_line[:, slice_joint] = line
    line_rates, line_dirs = observer_modes(model, Y, q_line)
    return BandwidthSurvey(
        Y=Y.tolist(),
        theta2=line.tolist(),
        q_slice=q_slice.tolist(),
        eigenvalues=np.real(line_rates).tolist(),
        slowest_direction=np.real(line_dirs[:, :, 0]).tolist(),
        slowest_rad_s=SlowestMode(min=float(slow[k_min]), max=float(slow[k_max]), q_at_min=q[k_min].tolist(),
                                  q_at_max=q[k_max].tolist(), direction_at_min=np.real(dirs[k_min, :, 0]).tolist()),
        fastest_rad_s=FastestMode(min=float(fast.min()), max=float(fast[k_fast]), q_at_max=q[k_fast].tolist(),
                                  direction_at_max=np.real(dirs[k_fast, :, -1]).tolist()),
        ranges_rad_s=[[float(rates_r[:, k].min()), float(rates_r[:, k].max())] for k in range(n)],
        complex=bool(np.iscomplexobj(rates)),
        sensitivity_rad_s=dict(zip(names, sensitivity)),
        grid=SurveyGrid(points=[len(a) for a in axes], axes=[a.tolist() for a in axes]),
        slice_joint=None if names[slice_joint] == "theta2" else names[slice_joint],
    )


def along_trajectory(scenario: Scenario, Y=None, samples: int = 401) -> PathModes:
    """The slowest observer mode along the scenario's reference path (``samples`` times over the run)."""
    Y = scenario.observer_gain if Y is None else np.asarray(Y, dtype=float)
    # the scenario's nominal model is an ArmModel with its own joint count
    t = np.linspace(0.0, scenario.simulation.t_final, samples)
    q, _, _ = scenario.trajectory.evaluate(t)
    rates, dirs = observer_modes(scenario.nominal, Y, q)
    slow = np.real(rates[:, 0])
    k = int(np.argmin(slow))
    return PathModes(time=t.tolist(), slowest_rad_s=slow.tolist(), min=float(slow.min()), max=float(slow.max()),
                     direction_at_min=np.real(dirs[k, :, 0]).tolist())
