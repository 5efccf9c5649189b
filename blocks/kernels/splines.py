"""Polynomial pieces of the reference paths, as kernel helpers (numba and the tracer take them as their callers).

Quintic Hermite segments join path samples with continuous position, rate
and acceleration; the smoothstep and the bump shape a path's start and a
stitch's dip.  Written for scalars and rows alike.
"""
from __future__ import annotations

__all__ = ["quintic_hermite", "smoothstep5", "bump6"]


def quintic_hermite(s, h, q0, v0, a0, q1, v1, a1):
    """The quintic through ``(q, v, a)`` at both ends of an interval of ``h`` s, at ``s`` in [0, 1].

    ``v`` and ``a`` are given per unit ``s`` (the rate times ``h``, the acceleration times ``h^2``), so the
    coefficients are the pure numbers of the unit interval; returns the value, its rate (per s) and its
    acceleration (per s^2).  A kernel helper (numba and the tracer take it as they take its callers).
    """
    d = q1 - q0 - v0 - 0.5 * a0
    dv = v1 - v0 - a0
    da = a1 - a0
    c3 = 10.0 * d - 4.0 * dv + 0.5 * da
    c4 = -15.0 * d + 7.0 * dv - da
    c5 = 6.0 * d - 3.0 * dv + 0.5 * da
    q = q0 + s * (v0 + s * (0.5 * a0 + s * (c3 + s * (c4 + s * c5))))
    dq = (v0 + s * (a0 + s * (3.0 * c3 + s * (4.0 * c4 + s * (5.0 * c5))))) / h
    ddq = (a0 + s * (6.0 * c3 + s * (12.0 * c4 + s * (20.0 * c5)))) / (h * h)
    return q, dq, ddq


def smoothstep5(tau: float):
    """Quintic smoothstep ``10 tau^3 - 15 tau^4 + 6 tau^5`` on [0, 1] and its two derivatives (per unit tau)."""
    return (tau ** 3 * (10 - 15 * tau + 6 * tau ** 2), 30 * tau ** 2 * (1 - tau) ** 2,
            60 * tau * (1 - tau) * (1 - 2 * tau))


def bump6(tau: float):
    """Bump ``64 tau^3 (1 - tau)^3`` (peak 1 at tau = 1/2, C2 at both ends) and its two derivatives."""
    u, du = tau * (1 - tau), 1 - 2 * tau
    return 64 * u ** 3, 192 * u ** 2 * du, 384 * u * du ** 2 - 384 * u ** 2
