"""The compiled sampled engine: a digital controller's loop (:mod:`blocks.figure2.digital_loop`) run by numba.

It runs :meth:`blocks.engines.hybrid.HybridSystem.simulate`'s steps with the same
semantics and the same numbers (to rounding): at each tick ``k Ts`` every
block's output in plan order, the sampled blocks' outputs held from then on
(encoder with quantization and the velocity difference and its low-pass,
controller, actuator with its delay buffer and torque limit, observer) and
their updates (the observer's Euler or zero-order-hold step); between ticks
the continuous states (the plant) integrated by Dormand-Prince 5(4) with the
step control of :class:`scipy.integrate.RK45`, restarted at every tick with
the whole interval as its first step and never stepping across a tick; the
states and outputs on the output grid from each step's interpolant.

Nothing of the blocks is written here: :func:`blocks.engines.compiled.codegen.sampled_program`
traces or calls the blocks' own kernels (those the numpy engine calls) into
``sampled_tick``, ``sampled_rhs`` and ``sampled_outputs``, and the driver
``sampled_ticks`` of :mod:`blocks.engines.compiled.dopri` runs them.

Many members of a scenario in one call (:func:`blocks.figure2.sampled_batch.simulate_sampled_batch`) are the
Figure-2 layer's: this engine imports no scenario.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from blocks.diagram.contract import contract_of
from blocks.engines.compiled.codegen import CompiledUnavailable, load_module, mark_compiled, sampled_program_for
from blocks.engines.compiled.engine import METHODS, _StepView
from blocks.engines.compiled.jit import numba_or_none
from blocks.engines.integrate import DivergenceError, SolverFailure, _crossing_time

__all__ = ["SampledEngine", "sampled_unavailable_reason", "compilable_loop", "threads", "run_members", "FINISHED",
           "STEP_TOO_SMALL"]

# Status codes of sampled_ticks (blocks/engines/compiled/dopri.py)
_RUNNING, _FINISHED, _DIVERGED, _STEP_TOO_SMALL, _TICK_DIVERGED = 0, 1, 2, 3, 4
_S_T, _S_NFEV = 0, 2
#: A member's status after :func:`run_members`: it reached the end, or its step became too small (else it diverged)
FINISHED, STEP_TOO_SMALL = _FINISHED, _STEP_TOO_SMALL
# Ticks per driver call when progress is reported (about 10 ms of work at 1 kHz on the paper's arm)
_PROGRESS_TICKS = 2000
# Sample periods are whole multiples of the base period to this relative tolerance (as blocks.engines.hybrid)
_TICKS_RTOL = 1e-12


def compilable_loop(hybrid):
    """The diagram the compiled engine runs for ``hybrid``: the same, except a zoh observer whose model is structure.

    A zoh observer's update takes a matrix exponential, which does not trace, so the engine calls it with the
    block's parameters; a URDF arm's model (:class:`blocks.kernels.chain.ChainParams`) cannot be passed to
    compiled code.  Such an observer is split into two blocks (:func:`blocks.diagram.digital.zoh_split`): the augmented
    matrix from the arm's model, traced, and the update and estimate, called with numbers only.  The states and
    the outputs keep their order, so the runs are the diagram's.
    """
    from blocks.kernels.trace import Frozen
    blocks, split = [], False
    for block in hybrid.blocks():
        parts = getattr(block, "zoh_split", None)
        kernels = contract_of(block).kernels
        if parts is not None and kernels is not None and any(isinstance(p, Frozen) for p in kernels.params):
            blocks += parts()
            split = True
        else:
            blocks.append(block)
    if not split:
        return hybrid
    found = getattr(hybrid, "_compilable", None)
    if found is not None:
        return found
    from blocks.engines.hybrid import HybridSystem
    loop = HybridSystem(blocks, outlist=hybrid.output_labels, name=hybrid.name)
    if loop.state_labels != hybrid.state_labels or loop.output_labels != hybrid.output_labels:
        raise CompiledUnavailable("splitting the zoh observer changed the loop's states or outputs")
    for attr in ("scenario", "with_observer"):
        if hasattr(hybrid, attr):
            setattr(loop, attr, getattr(hybrid, attr))
    hybrid._compilable = loop
    return loop


def sampled_unavailable_reason(hybrid, method: str = "RK45") -> str | None:
    """Why the compiled sampled engine cannot run the hybrid diagram ``hybrid`` with ``method`` (None: it can)."""
    if numba_or_none() is None:
        return "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    if method not in METHODS:
        return f"solver method {method!r} is not compiled (the compiled engine integrates with {', '.join(METHODS)})"
    for block in hybrid.syslist:
        if contract_of(block).kernels is None:
            return (f"block '{block.name}' has no kernels (a user's own python-control system or an FMU), "
                    f"so the sampled loop cannot be compiled")
    slow = sorted(name for name, m in hybrid.multiples.items() if m != 1)
    if slow:
        return f"blocks {slow} are sampled slower than the base rate; the compiled sampled engine runs one rate"
    if hybrid.plan.fixed_point:
        return "the diagram's blocks declare no evaluation order (a fixed-point plan)"
    return None


class SampledEngine:
    """A hybrid diagram (:class:`blocks.engines.hybrid.HybridSystem`) run by its generated, numba-compiled module.

    Parameters
    ----------
    hybrid : blocks.engines.hybrid.HybridSystem
        Every block must carry kernels and every sampled block run at the base period.

    Raises
    ------
    CompiledUnavailable
        If numba is missing or the diagram cannot be compiled (the message says why).
    """

    #: It stops at the first step (or tick) beyond any state's own bound.
    per_state_bounds = True

    def __init__(self, hybrid) -> None:
        reason = sampled_unavailable_reason(hybrid)
        if reason is not None:
            raise CompiledUnavailable(f"the compiled sampled engine cannot run: {reason}")
        hybrid = compilable_loop(hybrid)
        self.hybrid = hybrid
        self.program, self.kernels = sampled_program_for(hybrid)
        self.theta, self.ext = self.program.numbers(self.kernels)
        self.module, cached = load_module(self.program)
        self._announce = not cached
        self.nstates = hybrid.nstates
        self.nsignals = hybrid.plan.nsignals
        self.base_period = hybrid.base_period

    # -- compiling -------------------------------------------------------------------------------------
    def warm(self) -> None:
        """Compile (or load from numba's cache) the driver and the generated functions; say so the first time."""
        if not self._announce:
            return
        print(f"dobkit: compiling the sampled loop with numba (once per loop structure; cached in "
              f"{self.module.__file__.rsplit('/', 1)[0]}) ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        x0 = np.zeros(self.nstates)
        self._run(x0, np.array([0.0, self.base_period]), 1e-3, 1e-6, math.inf, np.full(self.nstates, np.inf), None)
        print(f"dobkit: compiled in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        self._announce = False
        mark_compiled(self.program)

    def ticks(self, t_end: float) -> int:
        """The last tick at or before ``t_end`` (s), as :meth:`blocks.engines.hybrid.HybridSystem.simulate` counts them."""
        return int(math.floor(t_end / self.base_period * (1 + _TICKS_RTOL)))

    # -- a run -------------------------------------------------------------------------------------------
    def simulate(self, x0, t_grid, rtol: float = 1e-6, atol: float = 1e-8, max_step: float = math.inf,
                 bound=math.inf, progress: Callable[[float], None] | None = None,
                 monitor=None) -> tuple[np.ndarray, np.ndarray]:
        """States (n, T) and outputs (noutputs, T) on ``t_grid`` (s, starting at 0), from ``x0``.

        As :meth:`blocks.engines.hybrid.HybridSystem.simulate`; ``bound`` is the
        largest magnitude of each state (array (n,) or one number): a tick's
        update or a step beyond it stops the run.  ``progress`` is called with
        the fraction of simulated time done.  With a ``monitor``
        (:class:`blocks.engines.monitor.Monitor`) its bounds replace ``bound`` and the
        driver returns to it every few thousand ticks for the step and
        wall-time budgets, Ctrl-C and progress.

        Raises
        ------
        blocks.engines.integrate.DivergenceError
            With the time (the crossing within the step, or the tick) and the state then.
        blocks.engines.integrate.SolverFailure
            If a step became too small.
        ValueError
            If the grid does not start at 0 or is not increasing.
        """
        t_grid = np.ascontiguousarray(t_grid, dtype=float)
        if t_grid.ndim != 1 or t_grid.size < 2 or t_grid[0] != 0.0 or not np.all(np.isfinite(t_grid)) \
                or np.any(np.diff(t_grid) <= 0):
            raise ValueError("t_grid must be at least two finite, increasing times starting at 0 s")
        x0 = np.array(x0, dtype=float)
        if x0.shape != (self.nstates,):
            raise ValueError(f"x0 must have {self.nstates} states, got shape {x0.shape}")
        if monitor is not None:
            bound = monitor.limits
        bound = np.array(np.broadcast_to(np.asarray(bound, dtype=float), x0.shape))
        self.warm()
        return self._run(x0, t_grid, float(rtol), float(atol), float(max_step), bound, progress, monitor)

    def _run(self, x0, t_grid, rtol, atol, max_step, bound, progress, monitor=None):
        n, T = self.nstates, t_grid.size
        n_ticks = self.ticks(float(t_grid[-1]))
        state = np.zeros(6)
        x, held = x0.copy(), np.zeros(self.nsignals)
        X, Y = np.empty((T, n)), np.empty((T, self.program.n_out))
        y_old, Q = np.empty(n), np.empty((n, 4))
        none, sums = np.zeros(0, dtype=np.int64), np.zeros(0)
        run = self.module.sampled_ticks
        # with a Monitor the driver returns every _PROGRESS_TICKS ticks (about 10 ms): the step and wall-time
        # budgets, Ctrl-C and progress are served between calls
        chunk = n_ticks + 1 if progress is None and monitor is None else _PROGRESS_TICKS
        k_stop = 0
        while True:
            k_stop = min(k_stop + chunk, n_ticks + 1)
            status = run(t_grid, self.base_period, n_ticks, k_stop, self.theta, self.ext, rtol, atol, max_step,
                         bound, state, x, held, True, X, Y, none, none, sums, y_old, Q)
            if status != _RUNNING:
                break
            t_done = min(float(t_grid[-1]), k_stop * self.base_period)
            if monitor is not None:
                monitor.check_evaluations(t_done, int(state[_S_NFEV]))
                monitor.check_time(t_done)
                monitor.report(t_done)
            if progress is not None:
                progress(min(1.0, k_stop * self.base_period / t_grid[-1]))
        if status == _FINISHED:
            self.nfev = int(state[_S_NFEV])
            return X.T, Y.T
        if status == _TICK_DIVERGED:
            raise DivergenceError(float(state[_S_T]), bound, x.copy())
        if status == _DIVERGED:
            step = _StepView(state, x, y_old, Q)
            t_cross = _crossing_time(step, bound)
            raise DivergenceError(t_cross, bound, step.dense_output()(t_cross) if np.all(np.isfinite(x)) else x.copy())
        raise SolverFailure(float(state[_S_T]), "Required step size is less than spacing between numbers.")


def threads() -> int:
    """The threads numba runs members on (its thread count: the cores, unless set)."""
    numba = numba_or_none()
    return int(getattr(numba.config, "NUMBA_NUM_THREADS", 1) or 1)


def run_members(engine: SampledEngine, threads: int, args: tuple) -> None:
    """Run every member of ``args`` (the module's ``sampled_members`` arguments after ``start, step``) on
    ``threads`` threads side by side: ``sampled_members`` is compiled to release the GIL (``NOGIL`` in
    :mod:`blocks.engines.compiled.dopri`); each thread takes every ``threads``-th member.  Results land in the arrays of
    ``args`` (sums, failure times and states, statuses)."""
    run = engine.module.sampled_members
    if threads == 1:
        run(0, 1, *args)
        return
    with ThreadPoolExecutor(threads) as pool:
        for done in [pool.submit(run, start, threads, *args) for start in range(threads)]:
            done.result()
