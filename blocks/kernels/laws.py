"""The control laws of Figure 2: computed torque (Eq. 9-11) and the disturbance observer (Eq. 12-16, corrected).

Computed torque on the nominal model ``k^``::

    tau = M^(q) (q_ref'' + Kd e' + Kp e) + N^(q, q') q' + G^(q) - d_hat,   e = q_ref - q

Nonlinear disturbance observer (Chen et al. 2000, in the general form of
Mohammadi et al. 2013)::

    d_hat = Y q' + z
    z' = -Y M^(q)^-1 (tau + d_hat - N^(q, q') q' - G^(q))

so that ``d_hat' = Y M^-1 (d - d_hat)`` on a perfect model.  The paper's
printed Eq. 16 has an extra ``- Y q'`` in ``z'``; ``eq16_weight = 1`` adds
it (to show its bias), ``0`` is the correct law.  See ``docs/model.md``.

Every law that needs the model takes the arm's kernels first, ``model``
(an :class:`~blocks.kernels.model.ArmKernels`: ``model.mass_times``,
``model.mass_solve``, ``model.bias_forces``, ``model.plant_acceleration``),
then their parameters ``k``: one law for every arm, as pinocchio's
algorithms take ``model, data``.
"""
from __future__ import annotations

__all__ = ["gain_times", "computed_torque", "observer_estimate", "observer_rate", "lumped_disturbance"]


def gain_times(gain, v):
    """``Y v`` for a gain given by its diagonal (same number of axes as ``v``) or as a full matrix (one more).

    In the one-point layout a diagonal gain is ``(n,)`` and a full one
    ``(n, n)``; with column signals ``(n, K)`` they are ``(n, 1 or K)`` and
    ``(n, n, 1 or K)``.
    """
    if gain.ndim == v.ndim:
        return gain * v
    return (gain * v).sum(axis=1)


def computed_torque(model, k, kp, kd, q, dq, q_ref, dq_ref, ddq_ref, d_hat):
    """Eq. 11: joint torques (N m; N on a prismatic joint) on the nominal model ``k``.

    Parameters
    ----------
    model : blocks.kernels.model.ArmKernels
        The arm's row kernels.
    k : numpy.ndarray or blocks.kernels.trace.Frozen
        Nominal arm parameters (``arm.kernel_params()``).
    kp, kd : numpy.ndarray
        Diagonals of the proportional (1/s^2) and derivative (1/s) gains.
    q, dq : numpy.ndarray
        Measured joint positions (rad, m) and velocities (rad/s, m/s).
    q_ref, dq_ref, ddq_ref : numpy.ndarray
        Reference positions, velocities and accelerations.
    d_hat : numpy.ndarray or float
        Disturbance estimate (N m, N); 0 without the observer.
    """
    v = ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)
    return model.mass_times(k, q, v) + model.bias_forces(k, q, dq) - d_hat


def observer_estimate(gain, dq, z):
    """The estimate ``d_hat = Y q' + z`` (N m, N) from the observer state ``z``."""
    return gain_times(gain, dq) + z


def observer_rate(model, k, gain, eq16_weight, q, dq, tau, z):
    """The observer's state derivative ``z'`` (N m/s, N/s) on the nominal model ``k``.

    Parameters
    ----------
    model : blocks.kernels.model.ArmKernels
        The arm's row kernels.
    k : numpy.ndarray or blocks.kernels.trace.Frozen
        Nominal arm parameters.
    gain : numpy.ndarray
        Observer gain ``Y`` (kg m^2/s; kg/s on joint 3), diagonal or full (see :func:`gain_times`).
    eq16_weight : float or numpy.ndarray
        0 for the correct law, 1 for the paper's printed Eq. 16.
    q, dq : numpy.ndarray
        Measured joint positions and velocities.
    tau : numpy.ndarray
        The torque the plant receives (N m, N).
    z : numpy.ndarray
        Observer state.
    """
    y_dq = gain_times(gain, dq)
    residual = tau + (y_dq + z) - model.bias_forces(k, q, dq)
    return -gain_times(gain, model.mass_solve(k, q, residual)) - eq16_weight * y_dq


def lumped_disturbance(model, k_true, k_nominal, q, dq, tau, tau_dis):
    """The total disturbance ``d`` the observer estimates (N m, N), Eq. 2-3.

    ``M^ q'' + N^ q' + G^ = tau + d`` with ``q''`` the true arm's acceleration
    under ``tau + tau_dis``; ``d = tau_dis`` when the nominal model is exact.
    The true and the nominal arm share the row kernels ``model`` and differ in
    their parameters ``k_true`` and ``k_nominal``.
    """
    ddq = model.plant_acceleration(k_true, q, dq, tau + tau_dis)
    return model.mass_times(k_nominal, q, ddq) + model.bias_forces(k_nominal, q, dq) - tau
