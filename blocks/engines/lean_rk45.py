"""scipy's RK45 with less Python per step: the same steps, the same floats.

:class:`LeanRK45` is :class:`scipy.integrate.RK45` (Dormand-Prince 5(4), its
initial step, step-size control and dense output) with the step and the dense
output written with fewer Python operations: the stage views of ``K`` made once,
the user's right-hand side called directly (not through two wrappers that count
calls and re-wrap the array), the error's RMS norm as ``sqrt(e.e)/sqrt(n)``
(what :func:`numpy.linalg.norm` computes for a vector).  Every arithmetic
operation on arrays is the one scipy performs on the same operands, in the same
order, so its states are scipy's bit for bit (``tests/test_lean_rk45.py``).

Why: once a loop's right-hand side costs about a microsecond (a chain arm's loop
in C, :mod:`blocks.engines.compiled.c_loop`), scipy's own stepping is four fifths
of a run: about 45 us per step, 17 of them in wrappers and slicing.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.integrate import RK45

try:            # scipy's step-size constants, where its RK45 keeps them
    from scipy.integrate._ivp.rk import MAX_FACTOR, MIN_FACTOR, SAFETY
except ImportError:     # pragma: no cover - a scipy that moved them: its own class steps (see stepper_classes)
    MAX_FACTOR = MIN_FACTOR = SAFETY = None

__all__ = ["LeanRK45", "lean_rk45_usable"]


def lean_rk45_usable() -> bool:
    """Whether this scipy's RK45 has what :class:`LeanRK45` restates (its step-size constants, its tableau and the
    step method it replaces); when not, scipy's own class should step (the tests compare the two step by step)."""
    return MAX_FACTOR is not None and all(hasattr(RK45, name) for name in
                                          ("A", "B", "C", "E", "P", "n_stages", "_step_impl", "_dense_output_impl"))


class LeanRK45(RK45):
    """:class:`scipy.integrate.RK45`, step for step and float for float, with less Python per step.

    Takes the arguments of :class:`scipy.integrate.RK45` (``vectorized`` must be false); its attributes
    (``t``, ``y``, ``t_old``, ``status``, ``nfev``, :meth:`dense_output` ...) are scipy's.
    """

    def __init__(self, fun, t0, y0, t_bound, vectorized=False, **options) -> None:
        if vectorized:
            raise ValueError("LeanRK45 calls the right-hand side one state at a time (vectorized=False)")
        super().__init__(fun, t0, y0, t_bound, vectorized=False, **options)
        self._user_fun = fun
        K = self.K
        # the views scipy's rk_step slices at every stage (K[:s].T, A[s][:s]): the same arrays, made once
        self._stages = tuple((s, K[:s].T, self.A[s][:s], self.C[s]) for s in range(1, self.n_stages))
        self._k_body_t, self._k_t = K[:-1].T, K.T
        self._toward = math.copysign(math.inf, float(self.direction))
        self._root_n = self.n ** 0.5

    def _call(self, t, y):
        f = self._user_fun(t, y)
        if type(f) is not np.ndarray or f.dtype != np.float64:      # what scipy's wrapper does to any other
            f = np.asarray(f, dtype=float)
        return f

    def _step_impl(self):
        t, y = self.t, self.y
        max_step, rtol, atol = self.max_step, self.rtol, self.atol
        direction, t_bound = self.direction, self.t_bound
        call, K, B, E = self._call, self.K, self.B, self.E
        dot, absolute, maximum = np.dot, np.abs, np.maximum

        min_step = 10 * abs(math.nextafter(t, self._toward) - t)
        h_abs = self.h_abs
        if h_abs > max_step:
            h_abs = max_step
        elif h_abs < min_step:
            h_abs = min_step

        step_rejected = False
        while True:
            if h_abs < min_step:
                return False, self.TOO_SMALL_STEP
            h = h_abs * direction
            t_new = t + h
            if direction * (t_new - t_bound) > 0:
                t_new = t_bound
            h = t_new - t
            h_abs = abs(h)

            # scipy's rk_step
            K[0] = self.f
            for s, k_t, a, c in self._stages:
                dy = dot(k_t, a) * h
                K[s] = call(t + c * h, y + dy)
            y_new = y + h * dot(self._k_body_t, B)
            f_new = call(t + h, y_new)
            K[-1] = f_new
            self.nfev += len(self._stages) + 1

            scale = atol + maximum(absolute(y), absolute(y_new)) * rtol
            error = dot(self._k_t, E) * h / scale
            error_norm = math.sqrt(error.dot(error)) / self._root_n

            if error_norm < 1:
                if error_norm == 0:
                    factor = MAX_FACTOR
                else:
                    factor = min(MAX_FACTOR, SAFETY * error_norm ** self.error_exponent)
                if step_rejected:
                    factor = min(1, factor)
                h_abs *= factor
                break
            h_abs *= max(MIN_FACTOR, SAFETY * error_norm ** self.error_exponent)
            step_rejected = True

        self.h_previous = h
        self.y_old = y
        self.t = t_new
        self.y = y_new
        self.h_abs = h_abs
        self.f = f_new
        return True, None

    def _dense_output_impl(self):
        return _LeanDense(self.t_old, self.t, self.y_old, self.K.T.dot(self.P))


class _LeanDense:
    """scipy's ``RkDenseOutput`` for one step (the same operations), without its base class's checks."""

    __slots__ = ("t_old", "t", "h", "Q", "y_old", "powers")

    def __init__(self, t_old, t, y_old, Q) -> None:
        self.t_old, self.t, self.h, self.Q, self.y_old = t_old, t, t - t_old, Q, y_old
        self.powers = Q.shape[1]

    def __call__(self, t):
        t = np.asarray(t)
        x = (t - self.t_old) / self.h
        if t.ndim == 0:
            p = np.cumprod(np.tile(x, self.powers))
            y = self.h * np.dot(self.Q, p)
            y += self.y_old
            return y
        if t.ndim > 1:
            raise ValueError("`t` must be a float or a 1-D array.")
        p = np.empty((self.powers, x.size))
        p[:] = x
        p = np.cumprod(p, axis=0)
        y = self.h * np.dot(self.Q, p)
        y += self.y_old[:, None]
        return y
