"""Integrate a right-hand side onto an output time grid, stopping at the first step that diverges.

:func:`integrate_on_grid` is the output-grid loop of
:func:`scipy.integrate.solve_ivp` -- the same solver classes, options, steps
and dense-output interpolation, so its states equal
``solve_ivp(fun, (t_grid[0], t_grid[-1]), x0, t_eval=t_grid, ...)`` exactly --
with one addition: every accepted step is checked for divergence (a state
beyond a bound, or not finite), and the time the bound was crossed is found in
that step's dense output.  Like a solver event, the check sees the state at
the ends of steps.  ``solve_ivp`` needs a terminal event function for
that, and its event handling costs about 40 microseconds per step: 5 % of the
paper scenario's fast run, for a check that costs 2 microseconds here.
"""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import scipy.integrate
import scipy.optimize

__all__ = ["SOLVERS", "integrate_on_grid", "DivergenceError", "SolverFailure"]

#: The :func:`scipy.integrate.solve_ivp` methods, by name.
SOLVERS = {name: getattr(scipy.integrate, name) for name in ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")}


# Points of a step's dense output searched for the first crossing of the bound (only when a step crossed it).
_CROSSING_SAMPLES = 33


class DivergenceError(RuntimeError):
    """A state left its bound (or became non-finite) at time :attr:`time` (s); :attr:`state` is the state then."""

    def __init__(self, time: float, bound, state: np.ndarray | None = None) -> None:
        shown = f"{bound:g}" if np.ndim(bound) == 0 else "its bound"
        super().__init__(f"a state exceeded {shown} (or became non-finite) at t = {time:.6g} s")
        self.time = time
        self.bound = bound
        self.state = state


class SolverFailure(RuntimeError):
    """The solver stopped at time :attr:`time` (s) before the end of the grid; :attr:`reason` says why."""

    def __init__(self, time: float, reason: str) -> None:
        super().__init__(f"the solver stopped at t = {time:.6g} s: {reason}")
        self.time = time
        self.reason = reason


def integrate_on_grid(fun: Callable[[float, np.ndarray], np.ndarray], x0, t_grid, method: str = "RK45",
                      rtol: float = 1e-6, atol: float = 1e-8, max_step: float = np.inf, bound: float = np.inf,
                      progress: Callable[[float], None] | None = None,
                      first_step: float | None = None, monitor=None) -> tuple[np.ndarray, int]:
    """States of ``x' = fun(t, x)`` at the times of ``t_grid``, integrated from ``x0`` at ``t_grid[0]``.

    Parameters
    ----------
    fun : callable
        Right-hand side ``fun(t, x) -> x'``.
    x0 : array_like, shape (n,)
        State at ``t_grid[0]``.
    t_grid : array_like, shape (T,)
        Increasing output times (s); the integration runs from the first to the last.
    method : str
        A :data:`SOLVERS` name.
    rtol, atol, max_step : float
        Solver options as in :func:`scipy.integrate.solve_ivp` (``max_step`` in s).
    bound : float or array_like, shape (n,)
        Largest magnitude a state (or each state) may reach; a step beyond it
        (or a non-finite state) raises :class:`DivergenceError`.
    progress : callable, optional
        Called with the fraction done (0 to 1), at most every 0.2 s of wall time.
    first_step : float, optional
        The first step to try (s); by default the solver's own estimate.
    monitor : blocks.monitor.Monitor, optional
        The job's Monitor: after every step it judges the step budget (raising
        :class:`~blocks.monitor.SimulationError`) and the wall time (raising
        :class:`~blocks.budget.BudgetError`), and takes the progress reports.

    Returns
    -------
    states : numpy.ndarray, shape (n, T)
    nfev : int
        Right-hand-side calls made.

    Raises
    ------
    DivergenceError, SolverFailure
    """
    t_grid = np.asarray(t_grid, dtype=float)
    if method not in SOLVERS:
        raise ValueError(f"solver method must be one of {list(SOLVERS)}, got {method!r}")
    if t_grid.ndim != 1 or t_grid.size < 2 or not np.all(np.isfinite(t_grid)) or np.any(np.diff(t_grid) <= 0):
        raise ValueError("t_grid must be at least two finite, increasing times")
    t0, t_end = float(t_grid[0]), float(t_grid[-1])
    x0 = np.asarray(x0, dtype=float)
    bound = np.asarray(bound, dtype=float)
    if not np.all(np.isfinite(x0)) or not np.all(np.abs(x0) <= bound):
        raise DivergenceError(t0, bound, x0)
    options = {} if first_step is None else {"first_step": min(first_step, t_end - t0, max_step)}
    solver = SOLVERS[method](fun, t0, x0, t_end, vectorized=False, rtol=rtol, atol=atol,
                             max_step=max_step, **options)
    states = np.empty((solver.n, t_grid.size))
    done = 0                                    # grid points filled (the first one too from the first step)
    last_report = time.monotonic()
    while solver.status == "running":
        message = solver.step()
        if solver.status == "failed":
            raise SolverFailure(float(solver.t), str(message))
        if not np.all(np.abs(solver.y) <= bound):
            t_cross = _crossing_time(solver, bound)
            raise DivergenceError(t_cross, bound, solver.dense_output()(t_cross) if np.all(np.isfinite(solver.y))
                                  else solver.y.copy())
        if monitor is not None:
            monitor.check_evaluations(float(solver.t), solver.nfev)
            monitor.check_time(float(solver.t))
            monitor.report(float(solver.t))
        # grid times up to and including the new time, interpolated as solve_ivp does
        upto = int(np.searchsorted(t_grid, solver.t, side="right"))
        if upto > done:
            states[:, done:upto] = solver.dense_output()(t_grid[done:upto])
            done = upto
        if progress is not None and time.monotonic() - last_report > 0.2:
            last_report = time.monotonic()
            progress(min(1.0, (solver.t - t0) / (t_end - t0)))
    if done != t_grid.size:                     # not expected: the solver ends exactly at t_end
        raise SolverFailure(float(solver.t), "the output grid was not reached")
    return states, solver.nfev


def _crossing_time(solver, bound: float) -> float:
    """When, within the step just taken, the largest state magnitude reached ``bound`` (s).

    The end of the step when the state there is not finite (no crossing to interpolate).
    """
    t_old, t_new = float(solver.t_old), float(solver.t)
    if not np.all(np.isfinite(solver.y)):
        return t_new
    dense = solver.dense_output()
    margin = lambda t: np.min(bound - np.abs(dense(t)))     # noqa: E731  > 0 inside the bound
    # the first sample of the step at or beyond the bound brackets the first crossing
    samples = np.linspace(t_old, t_new, _CROSSING_SAMPLES)
    inside = np.array([margin(t) > 0.0 for t in samples])
    if not inside[0]:
        return t_old
    if inside.all():                   # the interpolant ends a rounding error inside: no bracket
        return t_new
    k = int(np.argmin(inside))
    return float(scipy.optimize.brentq(margin, samples[k - 1], samples[k], xtol=1e-12 * max(1.0, abs(t_new))))
