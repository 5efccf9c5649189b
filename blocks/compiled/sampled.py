"""The compiled sampled engine: a digital controller's loop (:mod:`blocks.digital_loop`) run by numba.

It runs :meth:`blocks.hybrid.HybridSystem.simulate`'s steps with the same
semantics and the same numbers (to rounding): at each tick ``k Ts`` every
block's output in plan order, the sampled blocks' outputs held from then on
(encoder with quantization and the velocity difference and its low-pass,
controller, actuator with its delay buffer and torque limit, observer) and
their updates (the observer's Euler or zero-order-hold step); between ticks
the continuous states (the plant) integrated by Dormand-Prince 5(4) with the
step control of :class:`scipy.integrate.RK45`, restarted at every tick with
the whole interval as its first step and never stepping across a tick; the
states and outputs on the output grid from each step's interpolant.

Nothing of the blocks is written here: :func:`blocks.compiled.codegen.sampled_program`
traces or calls the blocks' own kernels (those the numpy engine calls) into
``sampled_tick``, ``sampled_rhs`` and ``sampled_outputs``, and the driver
``sampled_ticks`` of :mod:`blocks.compiled.dopri` runs them.

:func:`simulate_sampled_batch` runs many members (measurement-noise seeds,
or scenarios that differ in numbers only) in one call, members in parallel
on numba's threads, and returns each member's RMS tracking error per joint;
a member that diverges is reported on its own and the others are kept.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..contract import contract_of
from ..divergence import cached_state_bounds
from ..integrate import DivergenceError, SolverFailure, _crossing_time
from .codegen import CompiledUnavailable, load_module, mark_compiled, sampled_program_for
from .engine import METHODS, _StepView
from .jit import numba_or_none

__all__ = ["SampledEngine", "sampled_unavailable_reason", "simulate_sampled_batch", "SampledBatchResult",
           "compilable_loop"]

# Status codes of sampled_ticks (blocks/compiled/dopri.py)
_RUNNING, _FINISHED, _DIVERGED, _STEP_TOO_SMALL, _TICK_DIVERGED = 0, 1, 2, 3, 4
_S_T, _S_NFEV = 0, 2
# Ticks per driver call when progress is reported (about 10 ms of work at 1 kHz on the paper's arm)
_PROGRESS_TICKS = 2000
# Sample periods are whole multiples of the base period to this relative tolerance (as blocks.hybrid)
_TICKS_RTOL = 1e-12


def compilable_loop(hybrid):
    """The diagram the compiled engine runs for ``hybrid``: the same, except a zoh observer whose model is structure.

    A zoh observer's update takes a matrix exponential, which does not trace, so the engine calls it with the
    block's parameters; a URDF arm's model (:class:`blocks.kernels.chain.ChainParams`) cannot be passed to
    compiled code.  Such an observer is split into two blocks (:func:`blocks.digital.zoh_split`): the augmented
    matrix from the arm's model, traced, and the update and estimate, called with numbers only.  The states and
    the outputs keep their order, so the runs are the diagram's.
    """
    from ..compiled.trace import Frozen
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
    from ..hybrid import HybridSystem
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
    """A hybrid diagram (:class:`blocks.hybrid.HybridSystem`) run by its generated, numba-compiled module.

    Parameters
    ----------
    hybrid : blocks.hybrid.HybridSystem
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
        """The last tick at or before ``t_end`` (s), as :meth:`blocks.hybrid.HybridSystem.simulate` counts them."""
        return int(math.floor(t_end / self.base_period * (1 + _TICKS_RTOL)))

    # -- a run -------------------------------------------------------------------------------------------
    def simulate(self, x0, t_grid, rtol: float = 1e-6, atol: float = 1e-8, max_step: float = math.inf,
                 bound=math.inf, progress: Callable[[float], None] | None = None,
                 monitor=None) -> tuple[np.ndarray, np.ndarray]:
        """States (n, T) and outputs (noutputs, T) on ``t_grid`` (s, starting at 0), from ``x0``.

        As :meth:`blocks.hybrid.HybridSystem.simulate`; ``bound`` is the
        largest magnitude of each state (array (n,) or one number): a tick's
        update or a step beyond it stops the run.  ``progress`` is called with
        the fraction of simulated time done.  With a ``monitor``
        (:class:`blocks.monitor.Monitor`) its bounds replace ``bound`` and the
        driver returns to it every few thousand ticks for the step and
        wall-time budgets, Ctrl-C and progress.

        Raises
        ------
        blocks.integrate.DivergenceError
            With the time (the crossing within the step, or the tick) and the state then.
        blocks.integrate.SolverFailure
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


# --------------------------------------------------------------------------------------------------------------
# Many members in one call
# --------------------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class SampledBatchResult:
    """Per-member results of :func:`simulate_sampled_batch`.

    Attributes
    ----------
    rms_error : numpy.ndarray, shape (N, n_joints)
        RMS of ``q_ref[i] - q[i]`` over the output grid (rad, rad, m, rad); NaN for a member that failed.
    failed : list of str or None
        Per member: None, or what stopped it (time, state and bound).
    members : list
        The members: the noise seeds, or the variants' scenarios.
    """

    rms_error: np.ndarray
    failed: list
    members: list


def simulate_sampled_batch(scenario, seeds: Sequence[int] | None = None, variants: Sequence | None = None,
                           observer: bool = True, threads: int | None = None) -> SampledBatchResult:
    """Run the digital loop of many members in one compiled call (members in parallel) and return their metrics.

    Parameters
    ----------
    scenario : Scenario
        A scenario with a ``[controller]`` section (the digital controller).
    seeds : sequence of int, optional
        One member per measurement-noise seed (``noise.seed``); the scenario must have noise.
    variants : sequence of Scenario, optional
        The members' scenarios themselves (instead of ``seeds``); they may
        differ from ``scenario`` in the numbers the generated code reads as
        numbers (gains, masses, disturbance, encoder resolution, torque
        limit, the noise table), not in its structure (velocity source,
        observer update, delay, which joints quantize) nor in the parameters
        of the kernels it calls (the reference path; the zoh observer's).
    observer : bool
        With or without the disturbance observer.
    threads : int, optional
        Threads running members at once (default: numba's thread count, the cores).

    Returns
    -------
    SampledBatchResult

    Raises
    ------
    ValueError
        Naming ``seeds`` or ``variants`` when neither or both are given, a seed is not a whole number >= 0, the
        scenario has no noise to seed, or a variant differs in more than numbers.
    CompiledUnavailable
        If the loop cannot be compiled (numba missing, a solver other than RK45).
    """
    from ..sampled_blocks import sampled_initial_state, sampled_loop
    s = scenario
    signal_names = s.robot.joints.signal_names      # the arm's joints: the paper's 4 gave a 6-joint arm 4 errors
    if (seeds is None) == (variants is None):
        raise ValueError("give the members as either seeds (noise seeds) or variants (scenarios), not "
                         f"{'both' if seeds is not None else 'neither'}")
    if s.controller is None:
        raise ValueError(f"scenario '{s.name}' has no [controller] section: the sampled batch runs the digital loop")
    if seeds is not None:
        seeds = list(seeds)
        bad = [v for v in seeds if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0]
        if bad or not seeds:
            raise ValueError(f"seeds must be a non-empty list of whole numbers >= 0, got {bad or seeds!r}")
        if s.noise is None:
            raise ValueError(f"seeds vary the measurement noise, but scenario '{s.name}' has none ([noise] with a "
                             "q_std or dq_std > 0)")
        # the scenario with another noise (its record keeps the seed given; the members are listed as seeds)
        members = [dataclasses.replace(s, noise=dataclasses.replace(s.noise, seed=int(v))) for v in seeds]
    else:
        members = list(variants)
        if not members:
            raise ValueError("variants must be a non-empty list of scenarios")
    sim = s.simulation
    loop = sampled_loop(s, observer=observer)
    reason = sampled_unavailable_reason(loop, sim.method)
    if reason is not None:
        raise CompiledUnavailable(f"the compiled sampled batch cannot run: {reason}")
    engine = SampledEngine(loop)
    program = engine.program
    n, N = loop.nstates, len(members)
    shared_loop = seeds is not None and s.controller.delay == 0      # the start state needs no member's own loop
    X0, theta = np.empty((N, n)), np.empty((N, program.theta.size))
    tables = []
    for m, member in enumerate(members):
        own = loop if shared_loop else sampled_loop(member, observer=observer)
        if seeds is not None:
            X0[m] = sampled_initial_state(own, member)
            theta[m] = engine.theta
            tables.append(member.noise.table)
            continue
        own_program, own_kernels = sampled_program_for(compilable_loop(own))
        if own_program is not program or own.output_labels != loop.output_labels:
            raise ValueError(f"variants[{m}] ('{member.name}') differs from '{s.name}' in structure (blocks, "
                             "observer update, velocity source, delay, noise, which joints quantize): run it in "
                             "its own batch")
        X0[m] = sampled_initial_state(own, member)
        th, ext = own_program.numbers(own_kernels)
        for e, (a, b) in enumerate(zip(ext, engine.ext)):
            if e not in program.tables and not _same(a, b):
                raise ValueError(f"variants[{m}] ('{member.name}') differs from '{s.name}' in a parameter of a "
                                 "called kernel (the reference path, or the zoh observer's gains and model); "
                                 "run it in its own batch")
        theta[m] = th
        tables.append(ext[program.tables[0]] if program.tables else None)
    if program.tables:
        if len(program.tables) != 1:
            raise CompiledUnavailable("the loop has more than one table parameter; the sampled batch varies one")
        member_tables = (np.stack(tables),)
        table_row = np.arange(N, dtype=np.int64)
    else:
        member_tables, table_row = (), np.zeros(N, dtype=np.int64)
    labels = list(loop.output_labels)
    err_a = np.array([labels.index(x) for x in signal_names("q_ref")], dtype=np.int64)
    err_b = np.array([labels.index(x) for x in signal_names("q")], dtype=np.int64)
    bounds = cached_state_bounds(loop, s)
    t_grid = np.ascontiguousarray(sim.time_grid, dtype=float)
    sum_sq = np.zeros((N, err_a.size))
    failed_at, failed_state = np.full(N, np.nan), np.zeros((N, n))
    status = np.zeros(N, dtype=np.int64)
    engine.warm()
    run = _members_without_gil(engine)
    args = (t_grid, engine.base_period, engine.ticks(float(t_grid[-1])), X0, np.zeros(engine.nsignals), theta,
            engine.ext, member_tables, table_row, float(sim.rtol), float(sim.atol), float(sim.max_step),
            bounds.bounds, err_a, err_b, sum_sq, failed_at, failed_state, status)
    threads = max(1, min(N, _threads() if threads is None else int(threads)))
    if threads == 1:
        run(0, 1, *args)
    else:
        with ThreadPoolExecutor(threads) as pool:
            for done in [pool.submit(run, start, threads, *args) for start in range(threads)]:
                done.result()
    rms = np.sqrt(sum_sq / t_grid.size)
    failed = []
    for m in range(N):
        if status[m] == _FINISHED:
            failed.append(None)
            continue
        rms[m] = np.nan
        if status[m] == _STEP_TOO_SMALL:
            failed.append(f"the solver's step became too small at t = {failed_at[m]:.6g} s")
        else:
            failed.append(f"diverged by t = {failed_at[m]:.6g} s: {bounds.describe(failed_state[m])}")
    return SampledBatchResult(rms, failed, seeds if seeds is not None else members)


def _members_without_gil(engine):
    """The module's ``sampled_members``, compiled to release the GIL (``NOGIL`` in :mod:`blocks.compiled.dopri`) so
    that threads run members side by side; cached with the module's other functions."""
    return engine.module.sampled_members


def _threads() -> int:
    numba = numba_or_none()
    return int(getattr(numba.config, "NUMBA_NUM_THREADS", 1) or 1)


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and bool(np.all(np.asarray(a) == np.asarray(b)))
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b
