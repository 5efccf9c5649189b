"""Derivatives of an arm model's dynamics: ``dM/dq``, the forward dynamics' Jacobians and the gravity slope.

One place for the derivatives every layer takes of an
:class:`~blocks.model.arm.ArmModel`: the continuous linearization and the observer
certificate (:mod:`analysis.linear`) and the sampled loop's stability check
(:mod:`blocks.figure2.digital_stability`, which the pre-run check also uses).  Each
is taken from the model when it gives it exactly (a method
``inertia_partials(q)``, ``acceleration_jacobians(q, dq, tau)`` or
``gravity_partials(q)``) and otherwise by central differences of its methods
with :data:`FD_STEP`.

Step of the central differences
    The error of a central difference with step ``h`` is about
    ``h^2 |f'''| / 6`` (truncation) plus ``eps |f| / h`` (rounding); the sum is
    smallest near ``h = (3 eps)^(1/3) ~ 9e-6`` when ``f`` varies on a scale of
    one unit (rad, or m for prismatic joints whose inertia terms are
    polynomial in the extension).  :data:`FD_STEP` = 6e-6 gives a relative
    error near 1e-10 for trigonometric dependences; the tests hold it against
    the paper arm's exact ``dM/dtheta2`` (its model's ``closed_form_inertia_partials``).
    A constant term (the paper arm's gravity) has the exact slope 0.
"""
from __future__ import annotations

import numpy as np

from blocks.model.arm import ArmModel

__all__ = ["FD_STEP", "inertia_partials", "acceleration_jacobians", "gravity_slopes"]

#: Central-difference step (rad, m) of the model's derivatives (see the module docstring).
FD_STEP = 6e-6


def inertia_partials(arm: ArmModel, q, step: float = FD_STEP) -> np.ndarray:
    """``dM/dq_j`` at each configuration, shape ``(..., n, n, n)`` (last-but-two axis: j), kg m^2/rad etc.

    The model's own ``inertia_partials(q)`` when it has one (exact);
    otherwise central differences of :meth:`ArmModel.inertia` with ``step``.
    """
    q = np.asarray(q, dtype=float)
    exact = getattr(arm, "inertia_partials", None)
    if callable(exact):
        return np.asarray(exact(q), dtype=float)
    n = arm.n
    parts = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = step
        parts.append((arm.inertia(q + e) - arm.inertia(q - e)) / (2.0 * step))
    return np.stack(parts, axis=-3)


def acceleration_jacobians(arm: ArmModel, q, dq, tau, step: float = FD_STEP) -> tuple[np.ndarray, ...]:
    """Partials of the forward dynamics ``q'' = M^-1(q) (tau - h(q, q'))`` at one state.

    Parameters
    ----------
    arm : ArmModel
    q, dq, tau : array_like, shape (n,)
        Joint positions (rad, m), velocities (rad/s, m/s) and generalised forces (N m, N).
    step : float
        Central-difference step (rad, m; rad/s, m/s), used unless the model has an
        exact ``acceleration_jacobians(q, dq, tau)``.

    Returns
    -------
    d_q, d_dq, d_tau : numpy.ndarray, shape (n, n)
        ``d q''/d q`` (1/s^2), ``d q''/d q'`` (1/s) and ``d q''/d tau = M^-1``.
        ``d_q`` is ``-M^-1 (dM/dq q'' + dh/dq)``, ``d_dq`` is ``-M^-1 dh/dq'``:
        the derivatives of ``M^-1 h`` the linearization needs.
    """
    q, dq, tau = (np.asarray(v, dtype=float) for v in (q, dq, tau))
    exact = getattr(arm, "acceleration_jacobians", None)
    if callable(exact):
        return tuple(np.asarray(m, dtype=float) for m in exact(q, dq, tau))
    n = arm.n
    E = step * np.eye(n)
    # one batched call per side: rows 0..n-1 move q, rows n..2n-1 move q'
    qs = np.concatenate([q + E, np.broadcast_to(q, (n, n))])
    dqs = np.concatenate([np.broadcast_to(dq, (n, n)), dq + E])
    plus = arm.forward_dynamics(qs, dqs, np.broadcast_to(tau, (2 * n, n)))
    qs = np.concatenate([q - E, np.broadcast_to(q, (n, n))])
    dqs = np.concatenate([np.broadcast_to(dq, (n, n)), dq - E])
    minus = arm.forward_dynamics(qs, dqs, np.broadcast_to(tau, (2 * n, n)))
    d = ((plus - minus) / (2.0 * step)).T            # column k: derivative along state k
    return d[:, :n], d[:, n:], np.linalg.inv(arm.inertia(q))


def gravity_slopes(arm: ArmModel, q, step: float = FD_STEP) -> np.ndarray:
    """``dG/dq`` at each configuration, shape ``(..., n, n)`` (row i: joint i's force; column j: along joint j).

    Units N m/rad, N/m (N m/m, N/rad across kinds).  The model's own
    ``gravity_partials(q)`` when it has one (exact); otherwise central
    differences of :meth:`ArmModel.gravity_forces` with ``step``, every
    configuration and joint in one call.  It is the gravity part of
    :func:`acceleration_jacobians` at rest (``d_q = -M^-1 dG/dq`` there)
    without the inverse; for the paper's arm (gravity constant) it is exactly zero.

    Parameters
    ----------
    arm : ArmModel
    q : array_like, shape (..., n)
        Joint positions (rad, m).
    step : float
        Central-difference step (rad, m).
    """
    q = np.asarray(q, dtype=float)
    exact = getattr(arm, "gravity_partials", None)
    if callable(exact):
        return np.asarray(exact(q), dtype=float)
    E = step * np.eye(arm.n)                                # row j: a step along joint j
    plus = arm.gravity_forces(q[..., None, :] + E)          # (..., j, i)
    minus = arm.gravity_forces(q[..., None, :] - E)
    return np.swapaxes((plus - minus) / (2.0 * step), -1, -2)
