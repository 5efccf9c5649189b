"""The step schedule of a batch: where RK4 steps end, and how fine they are."""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from blocks.figure2.batch.variants import Variants
from blocks.scenarios.scenario import Scenario

__all__ = ["step_schedule", "auto_substeps", "fastest_rate", "rates_by_source", "noise_breakpoints", "batch_schedule",
           "STEP_LAMBDA", "STEPS_PER_PHASE", "TISSUE_STEP", "INERTIA_SAMPLES"]


def _trajectory_breakpoints(trajectory, t_final: float) -> list[float]:
    """Times (s) where the reference's derivatives jump: a laceration path's phase boundaries."""
    explicit = getattr(trajectory, "breakpoints", None)
    if callable(explicit):
        return [float(t) for t in explicit()]
    if hasattr(trajectory, "phase_duration") and hasattr(trajectory, "stitches"):
        T = trajectory.phase_duration
        return [k * T for k in range(1, 2 * trajectory.stitches - 1)] + [trajectory.duration]
    return []


#: Largest ``h * lambda`` the automatic step allows (RK4 global error then stays below the
#: paper RK45 run's own error, see :mod:`blocks.figure2.batch`).
STEP_LAMBDA = 0.3
#: Steps per phase of the reference (laceration phase or sine period) the automatic step allows.
STEPS_PER_PHASE = 200
#: Step cap (s) with tissue contact, whose kinks no smoothness estimate covers.
TISSUE_STEP = 1e-3


def rates_by_source(variants: Variants, observer: bool = True) -> dict[str, np.ndarray]:
    """Upper estimates (1/s) of the fastest closed-loop rate of each member, by the scenario key that sets it.

    ``"gains.kp"``: the PD poles ``s^2 + kd s + kp`` scaled by the model
    mismatch ``lambda_max(M^-1 M^)``; ``"gains.observer"``: the observer's
    ``Y M^-1`` on the true and nominal inertia; ``"disturbance.friction_velocity"``:
    the friction's ``M^-1 (F_c / v_s + F_v)``.  Inertia is taken at
    ``cos(theta2) = -1, 0, 1`` for the paper's RRPR (its inertia depends on
    theta2 alone), and at :data:`INERTIA_SAMPLES` points of the reference for
    another arm.  Each value has shape (N,).
    """
    q = _inertia_configurations(variants)
    numbers = _column_numbers(variants, q, observer)
    if numbers is None:
        numbers = _member_numbers(variants, q, observer)
    M, M_hat, kp, kd, Y, damping = numbers
    M_inv, M_hat_inv = _each_distinct(np.linalg.inv, M), _each_distinct(np.linalg.inv, M_hat)
    mismatch = np.abs(_each_distinct(np.linalg.eigvals, M_inv @ M_hat)).max(axis=(1, 2))   # (N,)
    disc = kd ** 2 - 4 * kp
    pd = np.where(disc >= 0, 0.5 * (kd + np.sqrt(np.abs(disc))), np.sqrt(kp)).max(axis=1)
    rates = {"gains.kp": pd * np.maximum(mismatch, 1.0)}
    if observer:
        rates["gains.observer"] = np.max([np.abs(_each_distinct(np.linalg.eigvals, Y[:, None] @ inv)).max(axis=(1, 2))
                                          for inv in (M_inv, M_hat_inv)], axis=0)
    if damping is not None:
        D = np.apply_along_axis(np.diag, 1, damping)
        rates["disturbance.friction_velocity"] = np.abs(_each_distinct(np.linalg.eigvals, M_inv @ D[:, None])).max(
            axis=(1, 2))
    return rates


def _each_distinct(fn, A: np.ndarray) -> np.ndarray:
    """``fn`` (a stacked linear-algebra function: ``np.linalg.inv``, ``np.linalg.eigvals``) of every matrix of
    ``A`` (N, ..., n, n), computed once when every member has the same matrices (the true arm, the base's gains):
    3,000 small eigenvalue problems are most of a 1000-member batch's step rule."""
    if A.shape[0] > 1 and np.array_equal(A, np.broadcast_to(A[:1], A.shape)):
        one = fn(A[:1])
        return np.broadcast_to(one, A.shape[:1] + one.shape[1:])
    return fn(A)


def _member_numbers(variants: Variants, q: np.ndarray, observer: bool) -> tuple:
    """What the rates are made of, from each member's model objects: ``(M, M_hat, kp, kd, Y, damping)`` --
    the true and nominal inertia at ``q`` (N, m, n, n), Kp and Kd (N, n), the observer gain (N, n, n) or None
    without the observer, the friction's ``F_c / v_s + F_v`` (N, n) or None without friction."""
    M = _inertia_of_each(q, variants.robots)                        # (N, m, n, n)
    M_hat = _inertia_of_each(q, variants.nominals)
    Y = None
    if observer:
        Y = variants.y_full.transpose(2, 0, 1) if variants.y_full is not None else \
            np.apply_along_axis(np.diag, 1, variants.y_diag.T)                             # (N, n, n)
    damping = None
    if "friction" in variants.base.disturbance.kinds:
        dist = variants.disturbance
        damping = dist.coulomb / dist.friction_velocity + dist.viscous                      # (N, n)
    return M, M_hat, variants.kp.T, variants.kd.T, Y, damping


def _column_numbers(variants: Variants, q: np.ndarray, observer: bool) -> tuple | None:
    """:func:`_member_numbers` from the variants' checked columns (:attr:`Variants.columns`) without making each
    member's model objects (about 0.1 ms per member: 0.1 s of a 1000-member batch's set-up, which no worker
    shares); None where the columns do not give them (no columns, or an observer gain from a bandwidth that the
    nominal arm's scales move).

    The same numbers as the objects give: the nominal arm's constants of Eq. 5-7 in
    the model's own operations over all members at once (:meth:`blocks.model.arm.ArmModel.stacked_kernel_params`, as
    :mod:`blocks.figure2.batch.rows` fills ``theta``), gains as their diagonals, the base's values where no column is
    given.
    """
    columns = getattr(variants, "columns", None)
    s = variants.base
    if columns is None or not s.robot.stacks_constants:
        return None
    N, n = len(variants), s.robot.joints.count
    scales = {k.split(".", 1)[1]: c for k, c in columns.items() if k.startswith("nominal_scale.")}
    if scales and observer and s.data["gains"].get("observer_bandwidth") is not None:
        return None                                 # each member's Y = omega M^(q0) of its own nominal arm
    inertia_matrix = s.robot.kernels.inertia_matrix
    c2 = q.T[:, None, :]
    M = np.broadcast_to(inertia_matrix(s.robot.kernel_params()[:, None, None], c2), (N,) + (q.shape[0], n, n))
    if scales:
        from blocks.figure2.batch.variants import nominal_values
        k = s.nominal.stacked_kernel_params(nominal_values(s, scales))
        k = np.broadcast_to(k.reshape(k.shape[0], -1), (k.shape[0], N))                   # (p, N): a column each
        M_hat = inertia_matrix(k[:, :, None], c2)                                          # (N, m, n, n)
    else:
        M_hat = np.broadcast_to(inertia_matrix(s.nominal.kernel_params()[:, None, None], c2), M.shape)

    def per_joint(key: str, base_value) -> np.ndarray:       # (N, n): a column, else the base's for every member
        col = columns.get(key)
        if col is None:
            return np.broadcast_to(np.asarray(base_value, dtype=float), (N, n))
        return np.broadcast_to(col[:, None] if col.ndim == 1 else col, (N, n))
    kp, kd = per_joint("gains.kp", np.diag(s.kp)), per_joint("gains.kd", np.diag(s.kd))
    Y = np.broadcast_to(np.asarray(s.observer_gain, dtype=float), (N, n, n)) if observer else None
    damping = None
    if "friction" in s.disturbance.kinds:
        d = s.disturbance
        v_s = columns.get("disturbance.friction_velocity", np.full(N, d.friction_velocity))[:, None]
        damping = per_joint("disturbance.coulomb", d.coulomb) / v_s + per_joint("disturbance.viscous", d.viscous)
    return M, M_hat, kp, kd, Y, damping


def fastest_rate(variants: Variants, observer: bool = True) -> float:
    """An upper estimate (1/s) of the fastest closed-loop rate over all members (see :func:`rates_by_source`)."""
    return float(max(r.max() for r in rates_by_source(variants, observer).values()))


#: Points of the reference at which a non-RRPR arm's inertia is sampled for the step-size rule.
INERTIA_SAMPLES = 9


def _inertia_configurations(variants: Variants) -> np.ndarray:
    """Joint positions (m, n) where the step-size rule takes the inertia."""
    s = variants.base
    if s.robot.stacks_constants:
        c2 = np.array([-1.0, 0.0, 1.0])
        q = np.zeros((3, s.robot.joints.count))
        q[:, 1] = np.arccos(c2)
        return q
    times = np.linspace(0.0, s.simulation.t_final, INERTIA_SAMPLES)
    return np.asarray(s.trajectory.evaluate(times)[0], dtype=float).reshape(times.size, -1)


def _inertia_of_each(q: np.ndarray, arms: list) -> np.ndarray:
    """``M(q)`` of every arm at the configurations ``q`` (m, n): (len(arms), m, n, n), the numbers of
    the arm's ``M(q)``, computed once per distinct arm (members often share one) and, for arms of one closed form,
    for all at once."""
    unique: dict[int, object] = {}
    for arm in arms:
        unique.setdefault(id(arm), arm)
    kernels = {id(a.kernels): a.kernels for a in unique.values()}
    if len(kernels) == 1 and all(a.stacks_constants for a in unique.values()):
        # one closed form: the members' constant vectors side by side, one call
        k = np.stack([a.kernel_params() for a in unique.values()], axis=1)[:, :, None]      # (p, U, 1)
        M = next(iter(kernels.values())).inertia_matrix(k, q.T[:, None, :])                 # (U, m, n, n)
    else:                       # any arm through its own row kernel, joint-first rows (n, m)
        M = np.stack([a.kernels.inertia_matrix(a.kernel_params(), q.T) for a in unique.values()])
    index = {key: i for i, key in enumerate(unique)}
    return M[[index[id(a)] for a in arms]]


def auto_substeps(variants: Variants, observer: bool = True) -> int:
    """RK4 steps per output interval so that ``h * fastest_rate <= STEP_LAMBDA``, the reference
    gets at least :data:`STEPS_PER_PHASE` steps per phase, and tissue contact ``h <= TISSUE_STEP``."""
    s = variants.base
    h = STEP_LAMBDA / fastest_rate(variants, observer)
    phase = getattr(s.trajectory, "phase_duration", None)
    if phase is None and hasattr(s.trajectory, "omega"):
        phase = 2 * math.pi / max(max(s.trajectory.omega), 1e-12)
    if phase is not None:
        h = min(h, phase / STEPS_PER_PHASE)
    if "tissue" in s.disturbance.kinds:
        h = min(h, TISSUE_STEP)
    return max(1, int(math.ceil(s.simulation.output_step / h - 1e-9)))


def step_schedule(t_final: float, output_step: float, substeps: int = 1, breakpoints: Iterable[float] = (),
                  merge: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Step end points (s) for fixed-step integration, and which of them lie on the output grid.

    Parameters
    ----------
    t_final, output_step : float
        End time and output grid spacing (s).
    substeps : int
        Steps per output interval, >= 1.
    breakpoints : iterable of float
        Extra times (s) the steps must land on; those outside (0, t_final) are ignored.
    merge : float
        Points closer than this (s) to a grid point are merged into it.

    Returns
    -------
    times : numpy.ndarray
        Increasing, from 0 to ``t_final``.
    grid_index : numpy.ndarray of int
        For each time, its index on the output grid, or -1 if it is not a grid point.
    """
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps must be a whole number >= 1, got {substeps!r}")
    n_grid = int(round(t_final / output_step))
    grid = np.linspace(0.0, n_grid * output_step, n_grid + 1)
    # Subdivide each grid interval so that the grid points themselves are in the schedule exactly.
    frac = np.arange(int(substeps)) / int(substeps)
    fine = np.append((grid[:-1, None] + np.diff(grid)[:, None] * frac).ravel(), grid[-1])
    extra = np.array([b for b in breakpoints if merge < b < grid[-1] - merge], dtype=float)
    if extra.size:
        # nearest fine point by bisection: memory of order len(extra), not len(extra) * len(fine)
        right = np.clip(np.searchsorted(fine, extra), 1, fine.size - 1)
        near = np.minimum(np.abs(extra - fine[right - 1]), np.abs(extra - fine[right])) <= merge
        extra = extra[~near]
    times = np.union1d(fine, extra)
    grid_index = np.full(times.size, -1)
    pos = np.searchsorted(times, grid)
    grid_index[pos] = np.arange(grid.size)
    return times, grid_index


def noise_breakpoints(scenario: Scenario, sample_period: float | None = None) -> list[float]:
    """The noise sample times (s) of a scenario's run, where measurement noise changes slope."""
    period = sample_period if sample_period is not None else scenario.data["noise"]["sample_period"]
    return list(np.arange(1, int(math.ceil(scenario.simulation.t_final / period))) * period)


def batch_schedule(v: Variants, substeps: int, extra: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The batch's step schedule: the output grid, divided by ``substeps``, plus the breakpoints of the
    reference, ``extra`` and, when any member has noise, the noise sample times."""
    sim = v.base.simulation
    breaks = _trajectory_breakpoints(v.base.trajectory, sim.t_final) + [float(b) for b in extra]
    noises = [nz for nz in v.noises if nz is not None]
    if noises:
        breaks += noise_breakpoints(v.base, noises[0].sample_period)
    return step_schedule(sim.t_final, sim.output_step, substeps, breaks)
