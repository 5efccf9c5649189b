"""Observer gain design for a target bandwidth, and the convergence certificate of Mohammadi et al. (2013).

Design
    ``Y = Y_0 + c M_ref`` with ``M_ref`` the nominal inertia averaged over the
    workspace grid, ``Y_0`` a starting gain (for example the scenario's) and
    ``c`` the smallest value for which the slowest eigenvalue of ``Y M^-1(q)`` is
    at least the target at every grid point.  ``M_ref`` has the shape of ``M``,
    so ``c M_ref M^-1(q)`` is close to ``c I`` and adds roughly ``c`` to every
    mode (for the paper's arm and ``Y_0 = 10 I``: ``c = 9.6``, modes raised by
    9.2 to 9.6 rad/s, the slow 0.85 rad/s one the most in relative terms); with
    ``Y_0 = 0`` all four modes end up close to the target.

Certificate
    With ``X = Y^-1`` and ``V = e_d' X' M X e_d``, the estimation error of a
    slowly varying disturbance obeys ``V' = -xi' (Y + Y' - M') xi`` with
    ``xi = X e_d`` (Mohammadi et al. 2013).  If ``Y + Y' - M'(q, q') >= 2 beta M(q)``
    over the states of interest, then ``V(t) <= V(0) exp(-2 beta t)``: the error
    decays at least at rate ``beta`` (rad/s).  The best ``beta`` at one state is
    the smallest generalized eigenvalue of ``((Y + Y')/2 - M'/2, M)``.  ``M'`` is
    linear in the joint velocity, so the smallest eigenvalue is a concave
    function of it and its minimum over a box ``|q_j'| <= v_j`` is attained at a
    vertex: checking the ``2^n`` vertices at each configuration of a grid is exact
    for that grid.  For the paper's arm ``dM/dtheta2`` is the analytic one its
    model gives (``closed_form_inertia_partials``) and the other partials
    (exactly zero) central differences; any other :class:`~blocks.model.arm.ArmModel`
    gives its partials through :func:`analysis.linear.arm_terms.inertia_partials`
    (exact from the model, or central differences).

Everything takes the joint count from the model (``params.n``).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from analysis.linear import arm_terms
from analysis.linear.bandwidth import BandwidthOverview, observer_modes
from analysis.results import JsonResult
from blocks.model.arm import ArmModel

__all__ = ["GainDesign", "Certificate", "CriticalSpeed", "SimulationCheck", "ObserverDesign", "design_observer_gain",
           "inertia_partials", "decay_rates", "convergence_certificate", "critical_speed", "lyapunov_function",
           "confirm_by_simulation"]



@dataclass(frozen=True, eq=False)
class GainDesign:
    """A designed observer gain ``Y = base + c M_ref`` (see :func:`design_observer_gain`).

    Attributes
    ----------
    Y, base, M_ref : numpy.ndarray, shape (n, n)
        The gain, the starting gain and the averaged nominal inertia (kg m^2/s for Y and base; kg m^2, kg for M_ref).
    c_per_s : float
        The factor ``c`` (1/s).
    target_rad_s, slowest_rad_s, fastest_rad_s : float
        The target and the slowest and fastest mode over the grid (rad/s).
    """

    Y: np.ndarray
    base: np.ndarray
    M_ref: np.ndarray
    c_per_s: float
    target_rad_s: float
    slowest_rad_s: float
    fastest_rad_s: float


@dataclass(frozen=True)
class Certificate(JsonResult):
    """The convergence certificate of an observer gain over a grid and a joint-speed box.

    Attributes
    ----------
    beta_min_rad_s : float
        The smallest certified decay rate (rad/s); > 0 means exponential convergence at least that fast.
    holds : bool
        ``beta_min_rad_s > 0``.
    q_at, dq_at : list of float
        The configuration (rad, m) and box vertex (rad/s, m/s) where the minimum is.
    beta_at_rest_min_rad_s : float
        The same minimum with ``q' = 0`` (rad/s).
    speed_bound : list of float
        The box ``|q_j'| <= speed_bound[j]`` (rad/s, m/s).
    configurations : int
        Grid size.
    """

    beta_min_rad_s: float
    holds: bool
    q_at: list[float]
    dq_at: list[float]
    beta_at_rest_min_rad_s: float
    speed_bound: list[float]
    configurations: int


@dataclass(frozen=True)
class CriticalSpeed(JsonResult):
    """The largest speed factor along a direction for which the certificate condition holds.

    Attributes
    ----------
    speed_factor : float
        ``s``; infinity when ``M`` does not change along the direction
        (``unlimited`` True; JSON writes the infinity as null and reading restores it).
    unlimited : bool
    q_at, dq_direction_at : list of float or None
        Where the factor is reached (None when unlimited or when ``Y`` is not positive definite).
    speed_bound : list of float
        ``s * direction`` (rad/s, m/s); infinite entries when unlimited (null in JSON).
    """

    speed_factor: float
    unlimited: bool
    q_at: list[float] | None
    dq_direction_at: list[float] | None
    speed_bound: list[float]

    @classmethod
    def from_dict(cls, data: dict, where: str | None = None) -> CriticalSpeed:
        """Read back, with the infinities of an unlimited speed restored (JSON holds them as null)."""
        out = super().from_dict(data, where)
        if out.unlimited:
            out = cls(speed_factor=math.inf, unlimited=True, q_at=out.q_at, dq_direction_at=out.dq_direction_at,
                      speed_bound=[math.inf if math.isnan(v) else v for v in out.speed_bound])
        return out


@dataclass(frozen=True)
class SimulationCheck(JsonResult):
    """One nonlinear run with an observer gain (see :func:`confirm_by_simulation`).

    Attributes
    ----------
    Y : list of list of float
        The gain (kg m^2/s).
    time, error_norm : list of float
        Output times (s) and ``|d - d_hat|`` over all joints (N m and N together: a rate, not a quantity to read).
    error_per_joint : list of list of float or None
        ``|d_i - d_hat_i|`` per output time and joint (N m or N per joint); None in results written before it was kept.
    lyapunov_ratio : list of float or None
        ``V(t) / V(0)``; None when ``V(0) = 0`` (no estimation error at the start).
    beta_run_rad_s : float
        The certificate over the states the run visited (rad/s).
    convergence_time_s : float or None
        First time after which the error stays within ``threshold`` of the largest disturbance; None: not within
        the run.
    rms_disturbance_error : list of float
        Per joint (N m or N per joint).
    bound_holds : bool or None
        ``V(t) <= V(0) exp(-2 beta_run t)`` on the output grid; None when ``V(0) = 0``.
    threshold : float
        Convergence level, fraction of ``largest_disturbance`` (N m / N).
    largest_disturbance : float
    disturbance_kind : str or list of str
        The disturbance models of the run.
    f_r : list of float
        The run's step amplitudes (N m or N per joint).
    """

    Y: list[list[float]]
    time: list[float]
    error_norm: list[float]
    lyapunov_ratio: list[float] | None
    beta_run_rad_s: float
    convergence_time_s: float | None
    rms_disturbance_error: list[float]
    bound_holds: bool | None
    threshold: float
    largest_disturbance: float
    disturbance_kind: str | list[str]
    f_r: list[float]
    error_per_joint: list[list[float]] | None = None


@dataclass(frozen=True)
class ObserverDesign(JsonResult):
    """The observer gain designed for a target bandwidth, its certificate and its check in simulation.

    Attributes
    ----------
    target_rad_s : float
        Target slowest mode (rad/s).
    base_is_scenario_gain : bool
        Whether the design starts from the scenario's gain.
    Y, base, M_ref : list of list of float
        See :class:`GainDesign`.
    c_per_s, slowest_rad_s, fastest_rad_s : float
        See :class:`GainDesign`.
    speed_bound, reference_speed_max : list of float
        The certificate's joint-speed box and the path's largest reference speed per joint (rad/s, m/s).
    certificate_designed, certificate_scenario_gain : Certificate
    critical_theta2_speed_designed, critical_theta2_speed_scenario_gain : CriticalSpeed
        Along theta2 alone.
    bandwidth_designed : BandwidthOverview
        The observer modes with the designed gain.
    simulation : dict of str to SimulationCheck
        By gain label (``"scenario gain"``, ``"designed"``).
    """

    target_rad_s: float
    base_is_scenario_gain: bool
    Y: list[list[float]]
    base: list[list[float]]
    M_ref: list[list[float]]
    c_per_s: float
    slowest_rad_s: float
    fastest_rad_s: float
    speed_bound: list[float]
    reference_speed_max: list[float]
    certificate_designed: Certificate
    certificate_scenario_gain: Certificate
    critical_theta2_speed_designed: CriticalSpeed
    critical_theta2_speed_scenario_gain: CriticalSpeed
    bandwidth_designed: BandwidthOverview
    simulation: dict[str, SimulationCheck]


def design_observer_gain(params: ArmModel, target_rad_s: float, q_grid, base=None,
                         rtol: float = 1e-10) -> GainDesign:
    """Matrix observer gain whose slowest mode is at least ``target_rad_s`` on every configuration of a grid.

    ``Y = base + c M_ref`` with ``M_ref`` the nominal inertia averaged over the
    grid and ``c >= 0`` (1/s) the smallest value that meets the target.  For a
    symmetric positive semidefinite ``base`` every eigenvalue of ``Y M^-1(q)``
    is at least the corresponding one of ``base M^-1(q)`` (Weyl's inequality on
    ``M^-1/2 Y M^-1/2``): the design only makes the observer faster, in every
    direction.  Without ``base`` all ``n`` modes end up near the target.

    Parameters
    ----------
    params : ArmModel
        The nominal model the observer uses.
    target_rad_s : float
        Required smallest decay rate of the observer error (rad/s), > 0.
    q_grid : array_like, shape (N, n)
        Configurations that must meet the target (see :func:`~analysis.linear.bandwidth.workspace_grid`).
    base : array_like, shape (n, n), optional
        Gain to start from (for example the scenario's), symmetric positive semidefinite.
    rtol : float
        Relative tolerance of the bisection on ``c``.

    Returns
    -------
    GainDesign
        ``Y`` is symmetric positive definite (kg m^2/s, kg/s).
    """
    if not (isinstance(target_rad_s, (int, float)) and np.isfinite(target_rad_s) and target_rad_s > 0):
        raise ValueError(f"target observer bandwidth must be a finite number > 0 rad/s, got {target_rad_s!r}")
    arm = arm_terms.arm_model(params, "params")
    n = arm.n
    q_grid = _grid(arm, q_grid)
    M_ref = arm.inertia(q_grid).mean(axis=0)
    M_ref = (M_ref + M_ref.T) / 2.0
    if base is None:
        base = np.zeros((n, n))
    base = np.asarray(base, dtype=float)
    if base.shape != (n, n) or not np.allclose(base, base.T) or np.linalg.eigvalsh(base).min() < -1e-12:
        raise ValueError(f"base gain must be a symmetric positive semidefinite {n}x{n} matrix, "
                         f"got {base.tolist()!r}")

    def slowest(Y):
        return float(np.real(observer_modes(params, Y, q_grid)[0][:, 0]).min())

    # c M_ref alone meets the target at c_hi, and adding base can only help: bracket [0, c_hi]
    c_hi = target_rad_s / slowest(M_ref)
    c_lo = 0.0
    if slowest(base) >= target_rad_s:
        c_hi = 0.0
    while c_hi - c_lo > rtol * c_hi:
        mid = (c_lo + c_hi) / 2.0
        c_lo, c_hi = (c_lo, mid) if slowest(base + mid * M_ref) >= target_rad_s else (mid, c_hi)
    Y = base + c_hi * M_ref
    rates, _ = observer_modes(params, Y, q_grid)
    return GainDesign(Y=Y, base=base, M_ref=M_ref, c_per_s=c_hi, target_rad_s=float(target_rad_s),
                      slowest_rad_s=float(np.real(rates[:, 0]).min()),
                      fastest_rad_s=float(np.real(rates[:, -1]).max()))


def _grid(arm: ArmModel, q_grid) -> np.ndarray:
    q_grid = np.atleast_2d(np.asarray(q_grid, dtype=float))
    if q_grid.shape[-1] != arm.n:
        raise ValueError(f"q_grid must hold configurations of {arm.n} joints {list(arm.joints.names)} (shape "
                         f"(N, {arm.n})), got shape {q_grid.shape}")
    return q_grid


def _vertices(bound: np.ndarray) -> np.ndarray:
    """The ``2^n`` vertices of the box ``|q_j'| <= bound[j]``."""
    return np.array(list(itertools.product((-1.0, 1.0), repeat=len(bound)))) * bound


def inertia_partials(params: ArmModel, q) -> np.ndarray:
    """``dM/dq_j`` at each configuration, shape (..., n, n, n) (last-but-two axis: j).

    The model's own closed form where it has one (:meth:`~blocks.model.arm.ArmModel.closed_form_inertia_partials`:
    the paper's arm's analytic ``dM/dtheta2``); any other model: :func:`analysis.linear.arm_terms.inertia_partials`.
    """
    q = np.asarray(q, dtype=float)
    exact = arm_terms.arm_model(params, "params").closed_form_inertia_partials(q)
    return arm_terms.inertia_partials(params, q) if exact is None else exact


def decay_rates(params: ArmModel, Y, q, dq) -> np.ndarray:
    """Largest ``beta`` with ``Y + Y' - M'(q, dq) >= 2 beta M(q)`` at each state (rad/s), shape (...).

    Parameters
    ----------
    params : ArmModel
        The model the observer uses.
    Y : array_like, shape (n, n)
    q, dq : array_like, shape (..., n)
        Configurations (rad, m) and joint velocities (rad/s, m/s), broadcast together.
    """
    Y = np.asarray(Y, dtype=float)
    q, dq = np.asarray(q, dtype=float), np.asarray(dq, dtype=float)
    # M and dM/dq at q's own shape (a grid against velocity vertices shares them), then broadcast with dq
    M = params.inertia(q)
    M_dot = np.einsum("...jab,...j->...ab", inertia_partials(params, q), dq)
    M = np.broadcast_to(M, M_dot.shape)
    S = (Y + Y.T) / 2.0 - M_dot / 2.0
    L = np.linalg.cholesky(M)
    # beta = lambda_min(L^-1 S L^-T), the smallest generalized eigenvalue of (S, M)
    Linv_S = np.linalg.solve(L, S)
    K = np.linalg.solve(L, np.swapaxes(Linv_S, -1, -2))
    return np.linalg.eigvalsh((K + np.swapaxes(K, -1, -2)) / 2.0)[..., 0]


def convergence_certificate(params: ArmModel, Y, q_grid, speed_bound) -> Certificate:
    """Smallest certified decay rate of the observer error over a grid and a joint-velocity box.

    Certified at the grid's configurations, for a constant or slowly varying
    disturbance on a perfect model (the assumptions of the Lyapunov argument).

    Parameters
    ----------
    params : ArmModel
        The model the observer uses.
    Y : array_like, shape (n, n)
        Observer gain.
    q_grid : array_like, shape (N, n)
        Configurations (rad, m).
    speed_bound : array_like, shape (n,)
        ``|q_j'| <= speed_bound[j]`` (rad/s, m/s), >= 0.

    Returns
    -------
    Certificate
    """
    arm = arm_terms.arm_model(params, "params")
    bound = np.asarray(speed_bound, dtype=float)
    if bound.shape != (arm.n,) or not np.all(np.isfinite(bound)) or np.any(bound < 0):
        units = ", ".join(arm.joints.velocity_units)
        raise ValueError(f"speed_bound must be {arm.n} finite numbers >= 0 ({units}), got {speed_bound!r}")
    q_grid = _grid(arm, q_grid)
    vertices = _vertices(bound)
    beta = decay_rates(params, Y, q_grid[:, None, :], vertices[None, :, :])
    k, v = np.unravel_index(int(np.argmin(beta)), beta.shape)
    rest = decay_rates(params, Y, q_grid, np.zeros(arm.n))
    return Certificate(beta_min_rad_s=float(beta[k, v]), holds=bool(beta[k, v] > 0), q_at=q_grid[k].tolist(),
                       dq_at=vertices[v].tolist(), beta_at_rest_min_rad_s=float(rest.min()),
                       speed_bound=bound.tolist(), configurations=int(len(q_grid)))


def critical_speed(params: ArmModel, Y, q_grid, direction) -> CriticalSpeed:
    """Largest ``s`` for which the condition holds (``beta > 0``) on the grid for all ``|q'| <= s * direction``.

    ``beta > 0`` exactly when ``S = (Y + Y')/2 - M'/2`` is positive definite.  At a
    velocity ``s v`` that is ``I - s Ys^-1/2 (M'(v)/2) Ys^-1/2 > 0`` with ``Ys`` the
    symmetric part of ``Y``, so the critical speed of one state and one vertex
    ``v`` of the box is ``1 / lambda_max(Ys^-1/2 (M'(v)/2) Ys^-1/2)``; the result is
    the smallest over the grid and the vertices.

    Returns
    -------
    CriticalSpeed
    """
    arm = arm_terms.arm_model(params, "params")
    direction = np.asarray(direction, dtype=float)
    if direction.shape != (arm.n,) or not np.all(np.isfinite(direction)) or np.any(direction < 0):
        raise ValueError(f"direction must be {arm.n} finite numbers >= 0, got {direction!r}")
    Y = np.asarray(Y, dtype=float)
    w, V = np.linalg.eigh((Y + Y.T) / 2.0)
    if w.min() <= 0:
        return CriticalSpeed(speed_factor=0.0, unlimited=False, q_at=None, dq_direction_at=None,
                             speed_bound=[0.0] * arm.n)
    Ys_inv_half = V @ np.diag(w ** -0.5) @ V.T
    q_grid = _grid(arm, q_grid)
    vertices = _vertices(direction)
    M_dot = np.einsum("njab,vj->nvab", inertia_partials(params, q_grid), vertices)
    lam = np.linalg.eigvalsh(Ys_inv_half @ (M_dot / 2.0) @ Ys_inv_half)[..., -1]
    if lam.max() <= 0:
        return CriticalSpeed(speed_factor=math.inf, unlimited=True, q_at=None, dq_direction_at=None,
                             speed_bound=[math.inf if d > 0 else 0.0 for d in direction])
    k, v = np.unravel_index(int(np.argmax(lam)), lam.shape)
    s = 1.0 / float(lam[k, v])
    return CriticalSpeed(speed_factor=s, unlimited=False, q_at=q_grid[k].tolist(),
                         dq_direction_at=vertices[v].tolist(), speed_bound=(s * direction).tolist())


def lyapunov_function(params: ArmModel, Y, q, e_d) -> np.ndarray:
    """``V = e_d' X' M(q) X e_d`` with ``X = Y^-1`` for states ``q`` and estimation errors ``e_d``, shape (...)."""
    xi = np.linalg.solve(np.asarray(Y, dtype=float), np.asarray(e_d, dtype=float)[..., None])[..., 0]
    return np.einsum("...i,...ij,...j->...", xi, params.inertia(q), xi)


def confirm_by_simulation(scenario, gains, t_final: float | None = None, threshold: float = 0.02,
                          disturbance: dict | None = None) -> dict[str, SimulationCheck]:
    """Simulate the scenario with each observer gain and measure how fast the estimate converges.

    Parameters
    ----------
    scenario : Scenario
        Run on its own path and models, noise removed, with each gain in turn.
    gains : sequence of (str, array_like)
        Labels and n x n (or scalar / n-vector) observer gains.
    t_final : float, optional
        Shorter runs (s): the first ``t_final`` seconds of the same path.
    threshold : float
        Convergence level, as a fraction of the largest disturbance of the run.
    disturbance : dict, optional
        Keys of the ``[disturbance]`` table to change for the runs (merged), for
        example ``{"kind": "paper"}``: the constant step ``f_r`` the certificate
        is about, in place of disturbance models that start at zero or vary fast.

    Returns
    -------
    dict of str to SimulationCheck
        Per label.  Convergence: ``max_i |d_i - d_hat_i| <= threshold * max_t
        max_i |d_i(t)|`` from then on; the bound is checked with 0.1% slack
        for the solver, down to ``V = 1e-10 V(0)``.
    """
    from analysis.linear.loop import first_seconds
    from blocks import simulate
    from blocks.figure2.metrics import signal

    out = {}
    n = scenario.nominal.n
    for label, gain in gains:
        Y = np.asarray(gain, dtype=float)
        changes = {"gains": {"observer": Y.tolist() if Y.ndim else float(Y)},
                   "noise": {"q_std": [0.0] * n, "dq_std": [0.0] * n}}
        if disturbance is not None:
            changes["disturbance"] = disturbance
        variant = first_seconds(scenario, t_final, **changes)
        run = simulate(variant, observer=True)
        t = np.asarray(run.time)
        q, dq = signal(run, "q").T, signal(run, "dq").T
        d = signal(run, "d").T
        e_d = d - signal(run, "d_hat").T
        Ymat = variant.observer_gain
        V = lyapunov_function(variant.nominal, Ymat, q, e_d)
        beta = float(decay_rates(variant.nominal, Ymat, q, dq).min())
        scale = float(np.max(np.abs(d)))
        worst = np.max(np.abs(e_d), axis=1)
        above = np.nonzero(worst > threshold * scale)[0]
        conv = None if above.size and above[-1] == len(t) - 1 else float(t[above[-1] + 1] if above.size else 0.0)
        if V[0] > 0:
            bound = V[0] * np.exp(-2.0 * beta * t)
            meaningful = V > 1e-10 * V[0]       # below this the solver's own error dominates
            ratio = (V / V[0]).tolist()
            holds = bool(np.all(V[meaningful] <= bound[meaningful] * 1.001))
        else:
            ratio, holds = None, None
        kind = variant.data["disturbance"]["kind"]
        out[str(label)] = SimulationCheck(
            Y=Ymat.tolist(), time=t.tolist(), error_norm=np.linalg.norm(e_d, axis=1).tolist(),
            lyapunov_ratio=ratio, beta_run_rad_s=beta, convergence_time_s=conv,
            rms_disturbance_error=np.sqrt(np.mean(e_d ** 2, axis=0)).tolist(),
            bound_holds=holds, threshold=float(threshold), largest_disturbance=scale,
            disturbance_kind=kind if isinstance(kind, str) else list(kind),
            f_r=[float(v) for v in variant.disturbance.f_r], error_per_joint=np.abs(e_d).tolist())
    return out
