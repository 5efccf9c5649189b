"""The linearized error dynamics of a gain design: step response and disturbance-to-error frequency response.

What an engineer looks at before accepting a tuned design: how the tracking
error answers a step of the reference, and how much of a disturbance reaches
the error at each frequency, both for the tuned gains and the base ones.

The loop of Figure 2 held at a configuration ``q0`` and linearized there (as
in :mod:`analysis.tune.linear`: every dropped term multiplies a quantity that
is zero at the held equilibrium), with the true inertia ``M`` and the nominal
``M^`` at ``q0``, ``x = q - q0``, ``v = x'``, a reference position step ``r``
(``q_ref' = q_ref'' = 0`` after it), a disturbance ``d`` and the observer's
estimate ``d_hat`` as the third state::

    u      = Kp (r - x) - Kd v                  (computed-torque outer loop)
    tau    = M^ u - d_hat
    M v'   = tau + d
    d_hat' = Y v' - Y u                          (d_hat = Y q' + z, z' = -Y M^^-1 (tau + d_hat))

Output: the tracking error ``e = r - x``.  With a perfect model
(``M^ = M``) this is the paper's error dynamics ``e'' + Kd e' + Kp e =
M^-1 (d_hat - d)`` with ``d_hat' = Y M^-1 (d - d_hat)``: its poles are the
roots of ``s^2 + Kd_i s + Kp_i`` per joint and the eigenvalues of
``-Y M^-1``; ``x`` follows a step of ``r`` as ``Kp / (s^2 + Kd s + Kp)``, and
``E(s) = -s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1 D(s)`` (zero at DC: the observer
removes a constant disturbance).  The tests check these closed forms.
"""
from __future__ import annotations

import numpy as np

__all__ = ["error_dynamics", "step_responses", "disturbance_gains", "pd_poles", "as_gain_matrix"]


def as_gain_matrix(value, n: int) -> np.ndarray:
    """A gain given as a scalar, ``n`` numbers (a diagonal) or an ``n x n`` matrix, as an ``n x n`` matrix."""
    g = np.asarray(value, dtype=float)
    if g.ndim == 0:
        return g * np.eye(n)
    if g.ndim == 1 and g.shape == (n,):
        return np.diag(g)
    if g.shape == (n, n):
        return g
    raise ValueError(f"a gain must be a number, {n} numbers or a {n} x {n} matrix, got shape {g.shape}")


def error_dynamics(M, M_nominal, kp, kd, Y):
    """The held, linearized loop (module docstring) as a python-control state space.

    Parameters
    ----------
    M, M_nominal : array_like, shape (n, n)
        True and nominal inertia at the held configuration (kg m^2; kg on a prismatic joint).
    kp, kd : scalar, n numbers or (n, n)
        PD gains (1/s^2, 1/s).
    Y : scalar, n numbers or (n, n)
        Observer gain (kg m^2/s; kg/s on a prismatic joint).

    Returns
    -------
    control.StateSpace
        States ``x[i], v[i], d_hat[i]``; inputs ``r[i]`` (rad, m) then ``d[i]`` (N m, N); outputs ``e[i]``
        (rad, m).
    """
    import control as ct  # only where a design is drawn: the tuning's evaluations do not need it

    M = np.asarray(M, dtype=float)
    Mh = np.asarray(M_nominal, dtype=float)
    n = M.shape[0]
    Kp, Kd, Yg = as_gain_matrix(kp, n), as_gain_matrix(kd, n), as_gain_matrix(Y, n)
    I, Z = np.eye(n), np.zeros((n, n))
    Mi = np.linalg.inv(M)
    # v' = M^-1 (M^ u - d_hat + d), u = Kp r - Kp x - Kd v
    dv_x, dv_v, dv_h, dv_r, dv_d = -Mi @ Mh @ Kp, -Mi @ Mh @ Kd, -Mi, Mi @ Mh @ Kp, Mi
    # d_hat' = Y v' - Y u
    A = np.block([[Z, I, Z],
                  [dv_x, dv_v, dv_h],
                  [Yg @ dv_x + Yg @ Kp, Yg @ dv_v + Yg @ Kd, Yg @ dv_h]])
    B = np.block([[Z, Z],
                  [dv_r, dv_d],
                  [Yg @ dv_r - Yg @ Kp, Yg @ dv_d]])
    C = np.hstack([-I, Z, Z])
    D = np.hstack([I, Z])
    return ct.ss(A, B, C, D, name="error_dynamics",
                 states=[f"x[{i}]" for i in range(n)] + [f"v[{i}]" for i in range(n)]
                 + [f"d_hat[{i}]" for i in range(n)],
                 inputs=[f"r[{i}]" for i in range(n)] + [f"d[{i}]" for i in range(n)],
                 outputs=[f"e[{i}]" for i in range(n)])


def pd_poles(kp, kd, n: int) -> np.ndarray:
    """Roots of ``s^2 + kd_i s + kp_i`` per joint (1/s), shape (n, 2): the computed-torque poles."""
    kp = np.diag(as_gain_matrix(kp, n))
    kd = np.diag(as_gain_matrix(kd, n))
    disc = np.sqrt((kd ** 2 - 4 * kp).astype(complex))
    return np.stack([(-kd - disc) / 2, (-kd + disc) / 2], axis=1)


def step_responses(sys, t) -> np.ndarray:
    """Joint ``j``'s position after a unit step of its own reference, as a fraction of the step.

    Returns
    -------
    numpy.ndarray, shape (n, len(t))
        ``x_j(t) / r_j`` (1 - the tracking error); 1 is reached, the overshoot is above it.
    """
    import control as ct

    n = sys.noutputs
    t = np.asarray(t, dtype=float)
    out = np.empty((n, t.size))
    for j in range(n):
        response = ct.step_response(sys[j, j], T=t)
        out[j] = 1.0 - np.asarray(response.outputs, dtype=float).reshape(-1)
    return out


def disturbance_gains(sys, omega) -> np.ndarray:
    """``|E_j / D_j|(j omega)`` per joint: the tracking error per unit of disturbance on the same joint.

    Returns
    -------
    numpy.ndarray, shape (n, len(omega))
        rad/(N m) on a revolute joint, m/N on a prismatic one.
    """
    n = sys.noutputs
    omega = np.asarray(omega, dtype=float)
    A, B, C, D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    eye = np.eye(A.shape[0])
    out = np.empty((n, omega.size))
    for k, w in enumerate(omega):
        G = C @ np.linalg.solve(1j * w * eye - A, B[:, n:]) + D[:, n:]
        out[:, k] = np.abs(np.diag(G))
    return out
