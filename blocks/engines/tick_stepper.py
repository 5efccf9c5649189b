"""The numpy sampled engine's loop: one embedded Runge-Kutta step of the continuous part per tick.

:meth:`blocks.engines.hybrid.HybridSystem.simulate` runs a sampled diagram as a
sampled-data system: at every tick the blocks' outputs and the sampled
blocks' updates, between ticks the continuous states integrated with the
sampled outputs held, the solver restarted at every tick with the whole
interval as its first step.  Starting a :mod:`scipy.integrate` solver per
tick costs more than the step itself (validation, arrays, the solver
object), so this module takes the step itself: the method's own tableau
(``RK45``: Dormand-Prince 5(4), ``RK23``: Bogacki-Shampine 3(2), read from
scipy's classes) and scipy's step control, as scipy's solver would take it
after a restart.  Where the tick is shorter than the step the tolerances
allow, the embedded error estimate accepts one step per tick; otherwise the
interval is substepped, the step shrunk as scipy shrinks it.  So the states
are those of the restarted solver to rounding (the dot products are summed
in another order), and the grid points come from each step's interpolant
(scipy's ``P`` matrix).

The blocks run as functions on lists of floats (:mod:`blocks.engines.sampled_functions`: the sampled program's
generated functions, else the diagram's plan with numpy).

Methods other than ``RK45`` and ``RK23`` (``DOP853``, the implicit ones)
are left to the restarted scipy solver (:func:`tick_stepper_for` returns None).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import scipy.integrate

from blocks.engines.integrate import DivergenceError, SolverFailure, _crossing_time
from blocks.engines.sampled_functions import SampledFunctions

__all__ = ["TickStepper", "tick_stepper_for", "STEPPED_METHODS"]

#: The methods whose steps this module takes (the others restart scipy's solver at every tick).
STEPPED_METHODS = ("RK45", "RK23")
# scipy's step-size control (scipy/integrate/_ivp/rk.py): the same factors, so the same steps
_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0
_EPS = np.finfo(float).eps
_TOO_SMALL = "Required step size is less than spacing between numbers."
# seconds of wall time between progress reports
_PROGRESS_PERIOD = 0.2


def _stage_source(method: str) -> str:
    """The text of ``step(fun, t, y, f, h) -> (y_new, f_new, err, K)`` for a tableau, on lists of floats.

    Every stage is one comprehension over the states (zero coefficients left out: adding them changes
    nothing); ``err`` is the embedded error estimate ``h K^T E``.
    """
    cls = scipy.integrate.__dict__[method]
    A, B, C, E = cls.A, cls.B, cls.C, cls.E
    s = cls.n_stages
    lines = ["def step(fun, t, y, f, h):", "    k0 = f"]

    def combo(coefs, upto):
        terms = [f"{float(coefs[j])!r} * p{j}" for j in range(upto) if coefs[j] != 0.0]
        return " + ".join(terms) if terms else "0.0"

    def zipped(upto):
        names = ", ".join(f"p{j}" for j in range(upto))
        ks = ", ".join(f"k{j}" for j in range(upto))
        return names, ks

    for i in range(1, s):
        names, ks = zipped(i)
        lines.append(f"    k{i} = fun(t + {float(C[i])!r} * h, [yi + ({combo(A[i], i)}) * h for yi, {names} in "
                     f"zip(y, {ks})])")
    names, ks = zipped(s)
    lines.append(f"    y_new = [yi + h * ({combo(B, s)}) for yi, {names} in zip(y, {ks})]")
    lines.append("    f_new = fun(t + h, y_new)")
    names, ks = zipped(s + 1)
    lines.append(f"    k{s} = f_new")
    lines.append(f"    err = [({combo(E, s + 1)}) * h for {names} in zip({ks})]")
    lines.append(f"    return y_new, f_new, err, ({', '.join(f'k{j}' for j in range(s + 1))})")
    return "\n".join(lines) + "\n"


_steps: dict[str, Callable] = {}


def _step_function(method: str) -> Callable:
    found = _steps.get(method)
    if found is None:
        namespace: dict = {}
        exec(compile(_stage_source(method), f"<dobkit {method} step>", "exec"), namespace)
        found = _steps[method] = namespace["step"]
    return found


class _Step:
    """A step that crossed a bound, as :func:`blocks.engines.integrate._crossing_time` reads a solver."""

    def __init__(self, t_old: float, t: float, y_old: np.ndarray, y: np.ndarray, Q: np.ndarray) -> None:
        self.t_old, self.t, self.y = t_old, t, y
        self._y_old, self._Q, self._h = y_old, Q, t - t_old

    def dense_output(self):
        def dense(t):
            x = (np.asarray(t, dtype=float) - self.t_old) / self._h
            p = np.cumprod(np.repeat(x[..., None], self._Q.shape[1], axis=-1), axis=-1)
            return self._y_old + self._h * (p @ self._Q.T)
        return dense


class TickStepper:
    """Runs a :class:`~blocks.engines.hybrid.HybridSystem` tick by tick with one embedded Runge-Kutta step per tick.

    Parameters
    ----------
    hybrid : blocks.engines.hybrid.HybridSystem
        The diagram.
    method : {"RK45", "RK23"}
        The solver whose steps are taken.

    Attributes
    ----------
    generated : bool
        Whether the blocks run as the generated functions on floats (else the plan with numpy).
    nfev : int
        Right-hand-side evaluations of the last run.
    """

    def __init__(self, hybrid, method: str = "RK45") -> None:
        if method not in STEPPED_METHODS:
            raise ValueError(f"the tick stepper takes {STEPPED_METHODS}, got {method!r}")
        self.hybrid, self.method = hybrid, method
        self.blocks = SampledFunctions(hybrid)
        self.generated = self.blocks.generated
        cls = scipy.integrate.__dict__[method]
        self._step = _step_function(method)
        self._P = np.array(cls.P, dtype=float)
        self._exponent = -1.0 / (cls.error_estimator_order + 1)
        self.nfev = 0

    def simulate(self, x0, t_grid, rtol: float = 1e-6, atol: float = 1e-8, max_step: float = math.inf,
                 bound=math.inf, progress: Callable[[float], None] | None = None,
                 monitor=None) -> tuple[np.ndarray, np.ndarray]:
        """States (n, T) on ``t_grid`` (s, from 0) and the held outputs (nsignals, T) at each grid time.

        As :meth:`blocks.engines.hybrid.HybridSystem.simulate` (whose outputs follow from these): ``bound`` is a
        number or one per state; with a ``monitor`` the step budget (right-hand sides) is judged after every
        step, the wall time and progress at every tick.

        Raises
        ------
        blocks.engines.integrate.DivergenceError
            A state beyond its bound after a tick's update (at the tick) or a step (the crossing within it).
        blocks.engines.integrate.SolverFailure
            When the step became smaller than the spacing of floats.
        """
        hy, bl = self.hybrid, self.blocks
        t_grid = np.asarray(t_grid, dtype=float)
        if t_grid.ndim != 1 or t_grid.size < 2 or t_grid[0] != 0.0 or not np.all(np.isfinite(t_grid)) \
                or np.any(np.diff(t_grid) <= 0):
            raise ValueError("t_grid must be at least two finite, increasing times starting at 0 s")
        from blocks.engines.sampling import tick_count
        n, T = bl.n, t_grid.size
        Ts = hy.base_period
        t_end = float(t_grid[-1])
        n_ticks = tick_count(t_end, Ts)
        bound_arr = np.array(np.broadcast_to(np.asarray(bound, dtype=float), (n,)))
        bounds = bound_arr.tolist()
        cont = bl.cont
        cont_bounds = [bounds[i] for i in cont]
        rtol = max(float(rtol), 100 * _EPS)
        atol = float(atol)
        max_step = float(max_step)
        first_step = min(math.inf, t_end, max_step)
        grid = t_grid.tolist()
        states = np.empty((n, T))
        held_at = np.empty((bl.nsignals, T))
        step, exponent, P = self._step, self._exponent, self._P
        scatter, gather, rhs_full, tick = bl.scatter, bl.gather, bl.rhs_full, bl.tick
        x = np.asarray(x0, dtype=float).tolist()
        held = [0.0] * bl.nsignals
        g, nfev = 0, 0
        last_report = time.monotonic()
        n_sqrt = math.sqrt(n)

        def keep_constant(upto: float, inclusive: bool) -> None:
            nonlocal g
            while g < T and (grid[g] <= upto if inclusive else grid[g] < upto):
                states[:, g] = x
                held_at[:, g] = held
                g += 1

        for k in range(n_ticks + 1):
            t = min(k * Ts, t_end)
            x, held = tick(k, k * Ts, x, held)
            if not all(abs(v) <= b for v, b in zip(x, bounds)):
                raise DivergenceError(t, bound_arr, np.array(x))
            stop = min((k + 1) * Ts, t_end) if k < n_ticks else t_end
            last = k == n_ticks
            if stop > t:
                x_fixed = x

                def fun(s: float, yc: list) -> list:
                    return gather(rhs_full(s, scatter(x_fixed, yc), held))
                y = gather(x)
                f = fun(t, y)
                nfev += 1
                h_abs = min(first_step, stop - t)
                while t < stop:
                    min_step = 10.0 * abs(math.nextafter(t, math.inf) - t)
                    h_abs = min(h_abs, max_step)
                    if h_abs < min_step:
                        h_abs = min_step
                    rejected = False
                    while True:
                        if h_abs < min_step:
                            raise SolverFailure(t, _TOO_SMALL)
                        t_new = t + h_abs
                        if t_new > stop:
                            t_new = stop
                        h = t_new - t
                        h_abs = abs(h)
                        y_new, f_new, err, K = step(fun, t, y, f, h)
                        nfev += len(K) - 1
                        total = 0.0
                        for e, a, b in zip(err, y, y_new):
                            sc = atol + max(abs(a), abs(b)) * rtol
                            total += (e / sc) ** 2
                        error_norm = math.sqrt(total) / n_sqrt
                        if error_norm < 1.0:
                            factor = _MAX_FACTOR if error_norm == 0.0 else \
                                min(_MAX_FACTOR, _SAFETY * error_norm ** exponent)
                            if rejected:
                                factor = min(1.0, factor)
                            h_abs *= factor
                            break
                        if not error_norm == error_norm:        # nan: no step size helps; shrink as scipy does
                            h_abs *= _MIN_FACTOR
                        else:
                            h_abs *= max(_MIN_FACTOR, _SAFETY * error_norm ** exponent)
                        rejected = True
                        if monitor is not None:
                            monitor.check_evaluations(t, nfev)
                    if not all(abs(v) <= b for v, b in zip(y_new, cont_bounds)):
                        raise self._diverged(x_fixed, t, t_new, y, y_new, K, bound_arr)
                    # grid points in the step: the interpolant (a point at the next tick is kept after its update)
                    ends = t_new < stop or last
                    if g < T and (grid[g] < t_new or (ends and grid[g] == t_new)):
                        Q = np.array(K).T @ P
                        y_old = np.array(x_fixed)
                        y_old[cont] = y
                        Qf = np.zeros((n, P.shape[1]))
                        Qf[cont] = Q
                        while g < T and (grid[g] < t_new or (ends and grid[g] == t_new)):
                            r = (grid[g] - t) / h
                            p = np.cumprod(np.full(P.shape[1], r))
                            states[:, g] = y_old + h * (Qf @ p)
                            held_at[:, g] = held
                            g += 1
                    t, y, f = t_new, y_new, f_new
                    if monitor is not None and t < stop:
                        monitor.check_evaluations(t, nfev)
                x = scatter(x_fixed, y)
            if monitor is not None:
                monitor.check_evaluations(t, nfev)
                monitor.check_time(t)
                monitor.report(t)
            if progress is not None and time.monotonic() - last_report > _PROGRESS_PERIOD:
                last_report = time.monotonic()
                progress(min(1.0, t / t_end))
        keep_constant(t_end, inclusive=True)
        self.nfev = nfev
        if g != T:
            raise SolverFailure(t_end, "the output grid was not reached")
        return states, held_at

    def _diverged(self, x_fixed, t_old, t, y_old, y_new, K, bound) -> DivergenceError:
        """The error for a step that left the bound, at the crossing found in the step's interpolant."""
        cont = self.blocks.cont
        old, new = np.array(x_fixed, dtype=float), np.array(x_fixed, dtype=float)
        old[cont], new[cont] = y_old, y_new
        Q = np.zeros((old.size, self._P.shape[1]))
        Q[cont] = np.array(K).T @ self._P
        view = _Step(t_old, t, old, new, Q)
        t_cross = _crossing_time(view, bound)
        state = view.dense_output()(t_cross) if np.all(np.isfinite(new)) else new
        return DivergenceError(t_cross, bound, state)


def tick_stepper_for(hybrid, method: str) -> TickStepper | None:
    """The :class:`TickStepper` of a diagram for ``method``, kept on the diagram; None for a method it does not take."""
    if method not in STEPPED_METHODS:
        return None
    kept = getattr(hybrid, "_tick_steppers", None)
    if kept is None:
        kept = hybrid._tick_steppers = {}
    found = kept.get(method)
    if found is None:
        found = kept[method] = TickStepper(hybrid, method)
    return found
