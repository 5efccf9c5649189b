"""Many members of a digital-controller scenario in one call, on the compiled sampled engine.

Members (measurement-noise seeds, or scenarios that differ in numbers only)
run in parallel on numba's threads (:class:`blocks.engines.compiled.sampled.SampledEngine`
runs each); each member's RMS tracking error per joint comes back, and a
member that diverges is reported on its own (time, state and its bound from
the scenario) while the others are kept.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from blocks.engines.compiled.codegen import CompiledUnavailable, sampled_program_for
from blocks.engines.compiled.sampled import (
    FINISHED,
    STEP_TOO_SMALL,
    SampledEngine,
    compilable_loop,
    run_members,
    sampled_unavailable_reason,
)
from blocks.engines.compiled.sampled import threads as numba_threads
from blocks.figure2.physical_bounds import cached_state_bounds
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop

__all__ = ["simulate_sampled_batch", "SampledBatchResult"]


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
    args = (t_grid, engine.base_period, engine.ticks(float(t_grid[-1])), X0, np.zeros(engine.nsignals), theta,
            engine.ext, member_tables, table_row, float(sim.rtol), float(sim.atol), float(sim.max_step),
            bounds.bounds, err_a, err_b, sum_sq, failed_at, failed_state, status)
    run_members(engine, max(1, min(N, numba_threads() if threads is None else int(threads))), args)
    rms = np.sqrt(sum_sq / t_grid.size)
    failed = []
    for m in range(N):
        if status[m] == FINISHED:
            failed.append(None)
            continue
        rms[m] = np.nan
        if status[m] == STEP_TOO_SMALL:
            failed.append(f"the solver's step became too small at t = {failed_at[m]:.6g} s")
        else:
            failed.append(f"diverged by t = {failed_at[m]:.6g} s: {bounds.describe(failed_state[m])}")
    return SampledBatchResult(rms, failed, seeds if seeds is not None else members)



def _same(a, b) -> bool:
    """Whether two kernel parameters hold the same numbers (arrays by value, tuples item by item)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and bool(np.all(np.asarray(a) == np.asarray(b)))
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b
