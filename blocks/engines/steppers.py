"""Fixed-step integration written once: the classical Runge-Kutta step.

The numpy batch (:mod:`blocks.figure2.batch`) and the co-simulation master
(:mod:`fmu.master`) step with :func:`rk4_step`; the compiled batch runs the
same step in its numba driver (:func:`blocks.engines.compiled.dopri.rk4_batch`),
where a Python callable cannot be passed.  The stage arguments let a caller
hold its inputs (a shared reference, measurement noise, the other FMU's
outputs) at the step's start, middle and end.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["rk4_step"]


def rk4_step(f: Callable[..., np.ndarray], t: float, x: np.ndarray, h: float, start: tuple = (), mid: tuple = (),
             end: tuple = (), k1: np.ndarray | None = None) -> np.ndarray:
    """One classical RK4 step of ``x' = f(t, x, *args)`` from ``t`` to ``t + h`` (s).

    Parameters
    ----------
    f : callable
        ``f(t, x, *args) -> x'``.
    t, h : float
        Start time and step (s).
    x : numpy.ndarray
        The state at ``t`` (any shape ``f`` takes: one state, or rows of a batch).
    start, mid, end : tuple
        The extra arguments of ``f`` at the stage times ``t``, ``t + h/2`` (two stages) and ``t + h``.
    k1 : numpy.ndarray, optional
        ``f(t, x, *start)`` when the caller has evaluated it already (to record the signals there).

    Returns
    -------
    numpy.ndarray
        The state at ``t + h``; its error is of order ``h^5`` per step.
    """
    k1 = f(t, x, *start) if k1 is None else k1
    k2 = f(t + 0.5 * h, x + (0.5 * h) * k1, *mid)
    k3 = f(t + 0.5 * h, x + (0.5 * h) * k2, *mid)
    k4 = f(t + h, x + h * k3, *end)
    return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
