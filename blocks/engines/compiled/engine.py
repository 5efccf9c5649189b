"""The compiled engine for one interconnection: its generated module, its numbers, and a run on a grid."""
from __future__ import annotations

import copy
import sys
import time
from collections.abc import Callable

import numpy as np

from blocks.diagram.contract import contract_of
from blocks.diagram.control_compat import subsystems
from blocks.diagram.plan import make_plan
from blocks.engines.compiled.codegen import CompiledUnavailable, load_module, mark_compiled, program_for
from blocks.engines.compiled.compile_estimate import AUTO_COMPILE_SECONDS, estimate_compile_seconds, generated_lines
from blocks.engines.compiled.jit import numba_or_none
from blocks.engines.compiled.rows import loop_rows_of
from blocks.engines.integrate import DivergenceError, SolverFailure, _crossing_time

__all__ = ["AUTO_COMPILE_SECONDS", "CompiledLoopEngine", "unavailable_reason", "METHODS"]

#: The solver methods the compiled engine implements (with scipy's step control).
METHODS = ("RK45",)

# Status codes and state slots of dopri_run (blocks/engines/compiled/dopri.py)
_RUNNING, _FINISHED, _DIVERGED, _STEP_TOO_SMALL = 0, 1, 2, 3
_S_T, _S_NFEV, _S_T_OLD = 0, 2, 5
# Progress is reported at most this often (s of wall time), as integrate_on_grid reports it
_PROGRESS_PERIOD = 0.2
# Accepted steps of the first call when progress is reported; later calls are sized to last about a period
_FIRST_STEPS = 64


def unavailable_reason(system, method: str = "RK45") -> str | None:
    """Why the compiled engine cannot run ``system`` with solver ``method``, or None when it can."""
    if numba_or_none() is None:
        return "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    if method not in METHODS:
        return f"solver method {method!r} is not compiled (the compiled engine integrates with {', '.join(METHODS)})"
    for block in subsystems(system):
        if contract_of(block).kernels is None:
            return (f"block '{block.name}' has no kernels (a user's own python-control system or an FMU), "
                    f"so the loop cannot be compiled (blocks.simulate_system gives a user's own ct.nlsys, ct.ss "
                    f"and ct.tf blocks kernels)")
    from blocks.diagram.plan import AlgebraicLoopError
    try:
        plan = make_plan(system)
    except AlgebraicLoopError as err:
        return str(err)
    if plan.fixed_point:
        return (f"the blocks {plan.order} cannot be put in an order (a cycle through blocks whose feedthrough is "
                "not declared), so the compiled engine cannot run them; the numpy engine iterates them as "
                "python-control does")
    return None




class CompiledLoopEngine:
    """An interconnection run by its generated, numba-compiled module.

    Parameters
    ----------
    system : control.InterconnectedSystem
        The loop; every block must carry kernels (see :mod:`blocks.diagram.contract`).
    rows : tuple of RowGroup, optional
        The row groups to generate beside the outputs (:mod:`blocks.engines.compiled.rows`); default those of the
        Figure-2 loop (:func:`~blocks.engines.compiled.rows.loop_rows_of`), ``()`` for a diagram of other signals.

    Raises
    ------
    CompiledUnavailable
        If numba is missing, the interconnection is not direct, or a block has no kernels.
    """

    #: It stops at the first step beyond any state's own bound.
    per_state_bounds = True

    def __init__(self, system, rows: tuple | None = None) -> None:
        if numba_or_none() is None:
            raise CompiledUnavailable("engine='compiled' needs numba, the optional extra: "
                                      "pip install \"dobkit[fast]\"")
        self.system = system
        self.plan = make_plan(system)
        self.program, self.kernels = program_for(self.plan, system, loop_rows_of(system) if rows is None else rows)
        # this loop's numbers: the traced blocks' into theta, the called kernels' parameters into ext
        self.theta, self.ext = self.program.numbers(self.kernels)
        self.module, cached = load_module(self.program)
        self._announce = not cached
        self.nstates = self.plan.nstates
        self._pace: float | None = None             # accepted steps per second of a monitored run, once measured
        self._output_flags: dict = {}               # row groups asked -> (flags, rows in the order asked)

    def with_params(self, params) -> CompiledLoopEngine:
        """This engine running its loop with the kernel parameters ``params`` (block name -> tuple, a
        :attr:`blocks.engines.context.Context.params`) in place of the blocks' own: the same compiled code, other
        numbers (``theta``, ``ext``); a structure other than the traced one is refused
        (:func:`blocks.engines.context.kernels_with_params`)."""
        from blocks.engines.context import kernels_with_params
        twin = copy.copy(self)
        twin.kernels = kernels_with_params(self.kernels, params)
        twin.theta, twin.ext = self.program.numbers(twin.kernels)
        twin._output_flags = {}
        return twin

    @property
    def row_groups(self) -> dict:
        """The row groups this loop has (:mod:`blocks.engines.compiled.rows`): name -> (flag index, rows)."""
        return self.program.row_groups

    @property
    def cached(self) -> bool:
        """Whether this loop structure's compiled code is in the cache (a run starts without compiling)."""
        return not self._announce

    @property
    def generated_lines(self) -> int:
        """Lines of the generated loop functions (what numba compiles for this loop)."""
        return generated_lines(self.program.source)

    @property
    def compile_estimate(self) -> float:
        """Estimated CPU seconds of this loop's first compile (:mod:`blocks.engines.compiled.compile_estimate`)."""
        return estimate_compile_seconds(self.generated_lines)

    def auto_reason(self) -> str | None:
        """Why ``engine="auto"`` should not compile this loop now (None: it may): its compile is estimated longer
        than :data:`~blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS` and it is not cached yet."""
        if self.cached:
            return None
        estimate = self.compile_estimate
        if estimate <= AUTO_COMPILE_SECONDS:
            return None
        return (f"this loop's generated code has {self.generated_lines} lines: numba would take about "
                f"{estimate:.0f} s of CPU to compile it (more than {AUTO_COMPILE_SECONDS:g} s, the most 'auto' "
                f"spends); run it once with engine='compiled' (--engine compiled) to compile and cache it, after "
                f"which 'auto' uses it")

    # -- compiling -------------------------------------------------------------------------------------
    def _first_call(self, fn: Callable[[], object]):
        """Run ``fn``; when this loop structure was never compiled here, say so and how long it took."""
        if not self._announce:
            return fn()
        print(f"dobkit: compiling the loop with numba (about {self.compile_estimate:.0f} s of CPU, once per loop "
              f"structure; {self.module.CACHE_NOTE}) ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        out = fn()
        print(f"dobkit: compiled in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        self._announce = False
        return out

    def warm(self) -> None:
        """Compile (or load from the cache) every function a run calls, on a two-point grid."""
        x0, unbounded = np.zeros(self.nstates), np.full(self.nstates, np.inf)
        self._first_call(lambda: (self._integrate(x0, np.array([0.0, 1e-9]), 1e-3, 1e-6, np.inf, unbounded, None),
                                  self.outputs_on_grid(np.array([0.0]), x0[:, None],
                                                       rows=("d",) if "d" in self.row_groups else ())))
        mark_compiled(self.program)

    # -- a run -------------------------------------------------------------------------------------------
    def integrate(self, x0, t_grid, rtol: float = 1e-6, atol: float = 1e-8, max_step: float = np.inf,
                  bound=np.inf, progress: Callable[[float], None] | None = None,
                  monitor=None) -> tuple[np.ndarray, int]:
        """States on ``t_grid`` (n, T) from ``x0`` and the number of right-hand-side calls.

        Dormand-Prince 5(4) with the step control of :class:`scipy.integrate.RK45`
        (see :mod:`blocks.engines.compiled.dopri`); the arguments are those of
        :func:`blocks.engines.integrate.integrate_on_grid`.  ``progress`` is called
        with the fraction of simulated time done at most every 0.2 s of wall time.
        With a ``monitor`` (:class:`blocks.engines.monitor.Monitor`) its bounds replace
        ``bound`` and the run returns to it at least every
        :data:`blocks.engines.monitor.CHUNK_SECONDS`: it enforces the step and wall-time
        budgets, takes the progress reports, and lets Ctrl-C through.

        Raises
        ------
        DivergenceError, SolverFailure
            And with a monitor :class:`~blocks.engines.monitor.SimulationError` (step budget) and
            :class:`~blocks.engines.budget.BudgetError` (wall time).
        """
        t_grid = np.ascontiguousarray(t_grid, dtype=float)
        if t_grid.ndim != 1 or t_grid.size < 2 or not np.all(np.isfinite(t_grid)) or np.any(np.diff(t_grid) <= 0):
            raise ValueError("t_grid must be at least two finite, increasing times")
        x0 = np.array(x0, dtype=float)
        if monitor is not None:
            bound = monitor.limits
        bound = np.array(np.broadcast_to(np.asarray(bound, dtype=float), x0.shape))      # writable, like warm()'s
        if not np.all(np.isfinite(x0)) or not np.all(np.abs(x0) <= bound):
            raise DivergenceError(float(t_grid[0]), bound, x0)
        if self._announce:
            self.warm()
        return self._integrate(x0, t_grid, float(rtol), float(atol), float(max_step), bound, progress, monitor)

    def _integrate(self, x0, t_grid, rtol, atol, max_step, bound, progress, monitor=None):
        n = x0.size
        state = np.zeros(6)
        y, f, K, Q = x0.copy(), np.empty(n), np.empty((7, n)), np.empty((n, 4))
        y_old, X = np.empty(n), np.empty((n, t_grid.size))
        run = self.module.dopri_run
        if monitor is not None:
            status = self._integrate_monitored(run, t_grid, rtol, atol, max_step, bound, monitor, state,
                                               (y, f, K, Q, y_old, X))
        elif progress is None:
            status = run(t_grid, self.theta, self.ext, rtol, atol, max_step, bound, 2 ** 62, state, y, f, K, Q,
                         y_old, X)
        else:
            status = self._integrate_reporting(run, t_grid, rtol, atol, max_step, bound, progress, state,
                                               (y, f, K, Q, y_old, X))
        if status == _FINISHED:
            return X, int(state[_S_NFEV])
        if status == _DIVERGED:
            step = _StepView(state, y, y_old, Q)
            t_cross = _crossing_time(step, bound)
            raise DivergenceError(t_cross, bound, step.dense_output()(t_cross) if np.all(np.isfinite(y)) else y.copy())
        raise SolverFailure(float(state[_S_T]), "Required step size is less than spacing between numbers.")

    def _integrate_monitored(self, run, t_grid, rtol, atol, max_step, bound, monitor, state, arrays) -> int:
        """``dopri_run`` in calls of as many steps as take about :data:`~blocks.engines.monitor.CHUNK_SECONDS`, the
        Monitor judging the step budget and the wall time and taking the progress between calls."""
        from blocks.engines.monitor import CHUNK_SECONDS
        # the first call as long as the previous run's pace allows (a short run is one call), else a few steps
        steps = _FIRST_STEPS if self._pace is None else max(1, int(self._pace * CHUNK_SECONDS))
        while True:
            started = time.monotonic()
            status = run(t_grid, self.theta, self.ext, rtol, atol, max_step, bound, steps, state, *arrays)
            t = float(state[_S_T])
            if status != _RUNNING:
                return status
            monitor.check_evaluations(t, int(state[_S_NFEV]))
            monitor.check_time(t)
            monitor.report(t)
            took = time.monotonic() - started
            self._pace = steps / max(took, 1e-6)              # accepted steps per second
            # size the next call from this one's pace, within a factor of 8 of it
            steps = max(1, int(min(8 * steps, max(steps / 8, steps * CHUNK_SECONDS / max(took, 1e-6)))))

    def _integrate_reporting(self, run, t_grid, rtol, atol, max_step, bound, progress, state, arrays) -> int:
        """``dopri_run`` in calls of as many steps as take about 0.1 s, reporting the fraction of simulated
        time done at most every 0.2 s of wall time."""
        t0, t_end = t_grid[0], t_grid[-1]
        steps, last_report = _FIRST_STEPS, time.monotonic()
        while True:
            started = time.monotonic()
            status = run(t_grid, self.theta, self.ext, rtol, atol, max_step, bound, steps, state, *arrays)
            if status != _RUNNING:
                return status
            now = time.monotonic()
            # size the next call from this one's pace, within a factor of 8 of it
            steps = int(min(8 * steps, max(steps / 8, steps * 0.5 * _PROGRESS_PERIOD / max(now - started, 1e-6))))
            steps = max(steps, 1)
            if now - last_report >= _PROGRESS_PERIOD:
                last_report = now
                progress(min(1.0, (state[_S_T] - t0) / (t_end - t0)))

    def outputs_on_grid(self, t_grid, X, rows: tuple = (), stacked: bool = False):
        """The interconnection's outputs (noutputs, T) at the times ``t_grid`` from the states ``X`` (n, T).

        With ``rows`` (names of row groups, see :mod:`blocks.engines.compiled.rows`)
        also those groups' rows in the same pass: ``(outputs, {name: (rows, T)})``,
        or with ``stacked`` one array, the outputs and then the groups' rows in
        the order asked (no copy to join them).
        """
        t_grid = np.ascontiguousarray(t_grid, dtype=float)
        X = np.ascontiguousarray(X, dtype=float)
        if X.shape != (self.nstates, t_grid.size):
            raise ValueError(f"states must have shape ({self.nstates}, {t_grid.size}), got {X.shape}")
        groups = self.program.row_groups
        rows = tuple(rows)
        found = self._output_flags.get(rows)
        if found is None:
            unknown = [name for name in rows if name not in groups]
            if unknown:
                raise ValueError(f"this loop has no row group {unknown}; it has {sorted(groups)}")
            flags = np.zeros(max(len(groups), 1), dtype=np.int64)
            for name in rows:
                flags[groups[name][0]] = 1
            n_out = self.program.n_out
            order = np.concatenate([np.arange(n_out)] + [n_out + np.arange(groups[name][1].start,
                                                                           groups[name][1].stop) for name in rows])
            # the stacked rows as a slice where they are the first rows in order (no copy), else an index
            found = self._output_flags[rows] = (flags, slice(0, order.size) if np.array_equal(
                order, np.arange(order.size)) else order)
        flags, order = found
        n_out = self.program.n_out
        # rows asked that are the first rows of the row groups: only those are written (the driver copies the first
        # R.shape[0] rows), else all of them
        n_rows = 0 if not rows else (order.stop - n_out if stacked and isinstance(order, slice) else self.program.n_rows)
        out = np.empty((n_out + n_rows, t_grid.size))
        aux = np.zeros((1, max(self.program.n_aux, 1)))
        self.module.grid_outputs(t_grid, X, self.theta, self.ext, aux, flags, out[:n_out], out[n_out:])
        if not rows:
            return out
        if stacked:
            return out[order]
        return out[:n_out], {name: out[n_out + groups[name][1].start:n_out + groups[name][1].stop] for name in rows}

    def rhs(self, t: float, x) -> np.ndarray:
        """The loop's state derivative at one point (for checks; the integrator calls the compiled code directly)."""
        dx = np.empty(self.nstates)
        src, work = np.empty(self.program.n_src), np.empty(self.program.n_work)
        self.module.loop_derivative(float(t), np.asarray(x, dtype=float), self.theta, self.ext, src, work, dx)
        return dx


class _StepView:
    """The step that crossed the bound, as :func:`blocks.engines.integrate._crossing_time` reads a solver."""

    def __init__(self, state, y_new, y_old, Q) -> None:
        self.t_old, self.t, self.y = float(state[_S_T_OLD]), float(state[_S_T]), y_new.copy()
        self._y_old, self._Q, self._h = y_old.copy(), Q.copy(), self.t - self.t_old

    def dense_output(self):
        def dense(t):
            x = (np.asarray(t, dtype=float) - self.t_old) / self._h
            p = np.cumprod(np.repeat(x[..., None], 4, axis=-1), axis=-1)
            return self._y_old + self._h * (p @ self._Q.T)
        return dense
