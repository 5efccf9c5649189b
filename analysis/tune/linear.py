"""The held loop, linearized by hand, for the constraints of gain tuning: stability margin and torque noise.

The loop of Figure 2 with the arm held at a configuration ``q0`` (a constant
reference), a constant disturbance (the paper's Eq. 4 step, as in
:mod:`analysis.simulation.studies`) and the correct observer (Eq. 16 without the printed
extra term).  With ``x = q - q0``, ``v = x'``, ``z`` the observer state's
deviation, measurement noise ``n_q`` on ``q`` and ``n_dq`` on ``q'``, true
inertia ``M`` and nominal inertia ``M^`` at ``q0``::

    tau = -M^ Kp (x + n_q) - (M^ Kd + Y)(v + n_dq) - z
    M v' = tau
    z'  = Y Kp (x + n_q) + Y Kd (v + n_dq)

Every term that the linearization drops multiplies a quantity that is zero at
the held equilibrium (``q'' = 0``, ``e = 0``: with the observer the arm rests
exactly at ``q0``, and ``tau + d_hat - N^ q' - G^ = M^ (Kd e' + Kp e)``
vanishes there), ``N q'`` is quadratic in the velocity, and the arm's gravity
does not depend on ``q``.  Eliminating ``z`` gives the characteristic
polynomial matrix ``s^3 M + s^2 (Y + M^ Kd) + s (M^ Kp + Y Kd) + Y Kp`` of
:func:`analysis.linear.loop.mismatch_polynomial` (there with ``M^ = a M``).  The
tests compare the poles with :func:`analysis.linear.loop.spectral_abscissa` (the
python-control linearization of the real loop) and the torque noise with
nonlinear simulations.

Torque noise
    The measurement noise of :class:`blocks.model.noise.MeasurementNoise`: white
    Gaussian samples every ``sample_period`` seconds, linearly interpolated in
    between.  Over one sample interval the input is therefore a first-order
    hold, and the sampled state obeys ``x[k+1] = Phi x[k] + G0 n[k] + G1 n[k+1]``
    (from one matrix exponential).  With ``n[k+1]`` independent of ``(x[k], n[k])``
    the stationary covariance of ``(x[k], n[k])`` solves a discrete Lyapunov
    equation, and the torque noise is the stationary RMS of ``tau`` at the
    sample instants (N m, N m, N, N m) -- where the noise has its stated
    standard deviation; the paper scenario's output grid (5 ms) falls on
    them.  It is what ``rms(tau_noisy - tau_clean)`` on that grid tends to over a
    long run (:func:`analysis.simulation.studies.observer_gain_study` measures the same
    thing over one second).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from blocks.model.arm import ArmModel

__all__ = ["held_loop_matrices", "loop_poles", "spectral_abscissas", "torque_noise_rms", "inertia_pairs"]


def _as_gain(value, n: int) -> np.ndarray:
    """A scalar, ``n`` numbers (a diagonal) or an ``n x n`` matrix as an ``n x n`` matrix."""
    g = np.asarray(value, dtype=float)
    if g.ndim == 0:
        return g * np.eye(n)
    if g.ndim == 1:
        return np.diag(g)
    return g


def held_loop_matrices(M, M_nominal, kp, kd, Y) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``A, B, C, D`` of the held loop (module docstring): state ``[x, v, z]``, input ``[n_q, n_dq]``, output tau.

    Parameters
    ----------
    M, M_nominal : array_like, shape (n, n)
        True and nominal inertia at the held configuration (kg m^2, kg).
    kp, kd : scalar, n numbers or (n, n)
        PD gains (1/s^2, 1/s).
    Y : scalar, n numbers or (n, n)
        Observer gain (kg m^2/s).

    Returns
    -------
    A : (3n, 3n), B : (3n, 2n), C : (n, 3n), D : (n, 2n)
        Units: tau in N m (N), noise in rad (m) and rad/s (m/s).
    """
    M = np.asarray(M, dtype=float)
    Mh = np.asarray(M_nominal, dtype=float)
    n = M.shape[0]
    Kp, Kd, Yg = _as_gain(kp, n), _as_gain(kd, n), _as_gain(Y, n)
    I, Z = np.eye(n), np.zeros((n, n))
    M_inv = np.linalg.inv(M)
    Cx, Cv = -Mh @ Kp, -(Mh @ Kd + Yg)
    A = np.block([[Z, I, Z], [M_inv @ Cx, M_inv @ Cv, -M_inv], [Yg @ Kp, Yg @ Kd, Z]])
    B = np.block([[Z, Z], [M_inv @ Cx, M_inv @ Cv], [Yg @ Kp, Yg @ Kd]])
    C = np.hstack([Cx, Cv, -I])
    D = np.hstack([Cx, Cv])
    return A, B, C, D


def loop_poles(M, M_nominal, kp, kd, Y) -> np.ndarray:
    """Poles of the held loop (rad/s) for one or a stack of inertia pairs.

    ``M`` and ``M_nominal`` may be stacks ``(..., n, n)``; the gains are shared.
    Returns shape ``(..., 3n)``.
    """
    M = np.asarray(M, dtype=float)
    Mh = np.asarray(M_nominal, dtype=float)
    n = M.shape[-1]
    Kp, Kd, Yg = _as_gain(kp, n), _as_gain(kd, n), _as_gain(Y, n)
    M_inv = np.linalg.inv(M)
    A = np.zeros(M.shape[:-2] + (3 * n, 3 * n))
    A[..., :n, n:2 * n] = np.eye(n)
    A[..., n:2 * n, :n] = -M_inv @ (Mh @ Kp)
    A[..., n:2 * n, n:2 * n] = -M_inv @ (Mh @ Kd + Yg)
    A[..., n:2 * n, 2 * n:] = -M_inv
    A[..., 2 * n:, :n] = Yg @ Kp
    A[..., 2 * n:, n:2 * n] = Yg @ Kd
    return np.linalg.eigvals(A)


def spectral_abscissas(M, M_nominal, kp, kd, Y) -> np.ndarray:
    """Largest real part of the held loop's poles (rad/s; > 0: unstable) for each inertia pair, shape (...)."""
    return loop_poles(M, M_nominal, kp, kd, Y).real.max(axis=-1)


def inertia_pairs(configurations, robots: list[ArmModel], nominals: list[ArmModel]) \
        -> tuple[np.ndarray, np.ndarray]:
    """True and nominal inertia of every (model pair, configuration), each shape (models * configurations, n, n).

    ``robots[i]`` and ``nominals[i]`` are one model pair (a member of a mismatch set); equal pairs are
    computed once.
    """
    q = np.atleast_2d(np.asarray(configurations, dtype=float))
    seen: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    true, nominal = [], []
    for robot, nom in zip(robots, nominals):
        key = (id(robot), id(nom))
        if key not in seen:
            seen[key] = (robot.inertia(q), nom.inertia(q))
        true.append(seen[key][0])
        nominal.append(seen[key][1])
    n = q.shape[-1]
    return np.concatenate(true).reshape(-1, n, n), np.concatenate(nominal).reshape(-1, n, n)


def torque_noise_rms(M, M_nominal, kp, kd, Y, q_std, dq_std, sample_period: float) -> np.ndarray:
    """Stationary RMS torque noise at the noise sample instants (N m or N per joint; module docstring).

    Parameters
    ----------
    M, M_nominal : array_like, shape (n, n)
        True and nominal inertia at the held configuration.
    kp, kd, Y
        Gains as :func:`held_loop_matrices` takes them.
    q_std, dq_std : n numbers
        Standard deviation of the position (rad, m) and velocity (rad/s, m/s) noise samples.
    sample_period : float
        Spacing of the noise samples (s).

    Returns
    -------
    numpy.ndarray, shape (n,)
        Infinite entries when the held loop is not asymptotically stable (the noise then grows without bound).
    """
    A, B, C, D = held_loop_matrices(M, M_nominal, kp, kd, Y)
    nx, nu = B.shape
    if np.linalg.eigvals(A).real.max() >= 0:
        return np.full(C.shape[0], np.inf)
    # exp([[A T, B T, 0], [0, 0, I], [0, 0, 0]]) = [[Phi, G, G1], [0, I, I], [0, 0, I]] with
    # G = int_0^T e^{A(T-s)} B ds and G1 = int_0^T e^{A(T-s)} B s/T ds (first-order hold).
    T = float(sample_period)
    big = np.zeros((nx + 2 * nu, nx + 2 * nu))
    big[:nx, :nx] = A * T
    big[:nx, nx:nx + nu] = B * T
    big[nx:nx + nu, nx + nu:] = np.eye(nu)
    E = scipy.linalg.expm(big)
    Phi, G, G1 = E[:nx, :nx], E[:nx, nx:nx + nu], E[:nx, nx + nu:]
    F = np.zeros((nx + nu, nx + nu))
    F[:nx, :nx], F[:nx, nx:] = Phi, G - G1
    H = np.vstack([G1, np.eye(nu)])
    S = np.diag(np.concatenate([np.asarray(q_std, dtype=float), np.asarray(dq_std, dtype=float)]) ** 2)
    P = scipy.linalg.solve_discrete_lyapunov(F, H @ S @ H.T)
    out = np.hstack([C, D])
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", out, P, out), 0.0))
