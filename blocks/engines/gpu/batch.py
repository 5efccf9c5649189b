"""The GPU batch: every member one thread, the whole fixed-step RK4 loop on the device, metrics summed there.

:func:`run_cuda_batch` runs what :func:`blocks.engines.compiled.batch.run_compiled_batch`
runs with ``method="RK4"`` -- the same generated loop functions (through
:mod:`blocks.engines.gpu.module`), the same shared step schedule, source tables,
row groups and divergence bounds, the same metrics from the same sums -- and
returns what it returns.  The members' numbers (``theta``), start states and
bounds go to the device once, members last so that neighbouring threads read
neighbouring numbers; the metrics' sums (and the kept signals, only when asked
for) come back once.  Before anything is allocated on the device the batch's
device memory is estimated (:func:`estimate_gpu_batch`) and refused over what
the device has free (capped by ``DOBKIT_MAX_GPU_MEMORY``), naming the key that
drives it and the estimate.
"""
from __future__ import annotations

import time

import numpy as np

from blocks.engines.budget import BudgetError, Estimate, format_bytes
from blocks.engines.compiled.batch import (
    _GROUP_OF,
    _metrics,
    _noise_tables,
    batch_unavailable_reason,
    kept_signals,
    member_start_states,
    member_theta,
    members_bounds,
    reference_tool_positions,
)
from blocks.engines.compiled.codegen import CompiledUnavailable
from blocks.engines.compiled.engine import CompiledLoopEngine
from blocks.engines.divergence import state_meanings
from blocks.engines.gpu.device import GPU_MEMORY_VARIABLE, cuda_or_none, cuda_unavailable_reason, device_free_bytes, device_name
from blocks.engines.gpu.module import cuda_module, gpu_program_reason
from blocks.engines.monitor import Monitor

__all__ = ["run_cuda_batch", "estimate_gpu_batch", "gpu_batch_reason", "THREADS_PER_BLOCK", "last_timings"]

#: Threads of a block (members per block): the prototype's measured best on an H200 for the paper's loop.
THREADS_PER_BLOCK = 128

#: Wall seconds of the last :func:`run_cuda_batch` by phase (for benchmarks/bench_gpu.py): ``setup`` (the members'
#: numbers, start states, bounds and the shared tables, on the CPU), ``device`` (transfers in, the kernel -- with its
#: compile on a first launch --, transfers out), ``device_memory`` (bytes estimated on the device).
last_timings: dict = {}


def gpu_batch_reason(v, engine: CompiledLoopEngine | None = None) -> str | None:
    """Why ``engine="cuda"`` cannot run the batch ``v`` (None: it can): numba-cuda, the driver and device, numba
    (the sources are tabulated on the CPU), one generated code for all members, every right-hand-side block traced."""
    reason = cuda_unavailable_reason() or batch_unavailable_reason(v)
    if reason is None and engine is not None:
        reason = gpu_program_reason(engine.program)
    return reason


def estimate_gpu_batch(members: int, steps: int, grid_points: int, kept: int, *, states: int, numbers: int,
                       sources: int, rows: int, shared: int, table: int = 0, tables: int = 0) -> Estimate:
    """Device memory (bytes) of a GPU batch: every array :func:`run_cuda_batch` puts on the device.

    Parameters
    ----------
    members : int
        Runs in the batch.
    steps : int
        Steps of the shared schedule (``steps + 1`` step times).
    grid_points : int
        Points of the output grid.
    kept : int
        Numbers kept per member and grid point (joints x kept signals); 0 for metrics only.
    states, numbers, sources, rows, shared : int
        The loop's states, its ``theta`` numbers per member, its sources, its metric rows and its shared values
        per grid point (``aux``).
    table, tables : int
        Numbers of one noise table, and how many tables go to the device (one per member with its own noise, one
        when all share the loop's, 0 without noise).

    Returns
    -------
    Estimate
        With parts ``the step schedule`` (key ``simulation.output_step``), ``the members' numbers`` (key
        ``batch.size``), ``the kept signals`` (key ``signals``) and ``the noise tables`` (key
        ``noise.sample_period``).
    """
    members, times = int(members), int(steps) + 1
    parts = {
        "the step schedule": 8 * (2 * times + max(sources, 1) * (2 * times - 1) + grid_points * max(shared, 1))
        + 8 * (64 + 4 * max(rows, 1)),
        "the members' numbers": 8 * members * (max(numbers, 1) + 3 * states + 1 + 3 * max(rows, 1)),
        "the kept signals": 8 * members * int(grid_points) * int(kept),
        "the noise tables": 8 * (int(table) * int(tables) + members),
    }
    reasons = {"the step schedule": f"{times - 1:.3g} steps shared by every run",
               "the members' numbers": f"{members} runs of {numbers} numbers and {states} states",
               "the kept signals": f"{kept} numbers at {grid_points:.3g} points for {members} runs",
               "the noise tables": f"{tables} tables of {table:.3g} numbers"}
    keys = {"the step schedule": "simulation.output_step", "the members' numbers": "batch.size",
            "the kept signals": "signals", "the noise tables": "noise.sample_period"}
    return Estimate(memory=int(sum(parts.values())), steps=int(steps), parts=parts, keys=keys, reasons=reasons)


def run_cuda_batch(v, members, observer: bool, metrics: tuple, signals: tuple, times, grid_index,
                   engine: CompiledLoopEngine | None = None):
    """Integrate the members of ``v`` on the GPU, fixed-step RK4 on the schedule ``times``/``grid_index``; return
    ``(metrics, signals, failed_at, failures, counts)`` as :func:`blocks.engines.compiled.batch.run_compiled_batch` does.

    Raises
    ------
    blocks.engines.compiled.CompiledUnavailable
        If numba-cuda, a driver or a device is missing, or the loop cannot run on the device (the reason is named).
    blocks.engines.budget.BudgetError
        If the batch's device memory (:func:`estimate_gpu_batch`) exceeds what the device has free.
    """
    reason = gpu_batch_reason(v)
    if reason is not None:
        raise CompiledUnavailable(f"engine='cuda' cannot run this batch: {reason}")
    started = time.perf_counter()
    cuda = cuda_or_none()
    loop = members.loop
    engine = CompiledLoopEngine(loop) if engine is None else engine
    program, cpu = engine.program, engine.module
    module = cuda_module(program, engine.nstates)            # refuses a loop the device cannot run
    n, N = members.joints, members.n
    theta = member_theta(engine, members)
    times = np.ascontiguousarray(times, dtype=float)
    grid_index = np.ascontiguousarray(grid_index, dtype=np.int64)
    on_grid = grid_index >= 0
    n_grid = int(grid_index.max()) + 1

    X0 = np.ascontiguousarray(member_start_states(members))
    labels = state_meanings(loop)
    monitor = Monitor(f"batch of scenario '{v.base.name}'", members_bounds(members, labels), X0.T)
    bound = monitor.limits                                                   # (nstates, N)

    # the shared tables, on the CPU once for all members: sources at step times and mid points, the reference's
    # tool position at the grid points (the rows' aux)
    mids = 0.5 * (times[:-1] + times[1:])
    n_src = max(program.n_src, 1)
    src_at, src_mid = np.zeros((times.size, n_src)), np.zeros((max(mids.size, 1), n_src))
    cpu.source_table(times, engine.theta, engine.ext, src_at)
    cpu.source_table(mids, engine.theta, engine.ext, src_mid)
    groups = engine.row_groups
    flags = np.zeros(max(len(groups), 1), dtype=np.int64)
    for name in metrics:
        flags[groups[_GROUP_OF[name]][0]] = 1
    aux = np.zeros((n_grid, max(program.n_aux, 1)))
    if "tool_distance" in groups and any("tool" in m for m in metrics):
        q_ref_grid = src_at[on_grid, :n].T                                   # (joints, n_grid)
        aux[:, :3] = reference_tool_positions(members, q_ref_grid)

    keep, keep_rows, at, n_keep = kept_signals(loop, members.arm, signals, groups, flags, n)
    n_rows = max(program.n_rows, 1)

    # the noise: the distinct tables once (member_ext reads row table_row[m]: a shared one for all that share
    # it), or none
    distinct, table_row = _noise_tables(v, engine)
    tables = np.stack(distinct) if distinct else np.zeros((1, 1, 1))
    estimate = estimate_gpu_batch(N, times.size - 1, n_grid, n_keep, states=engine.nstates, numbers=theta.shape[1],
                                  sources=n_src, rows=n_rows, shared=aux.shape[1],
                                  table=tables[0].size if program.tables else 0,
                                  tables=tables.shape[0] if program.tables else 0)
    free = device_free_bytes()
    if estimate.memory > free:
        raise BudgetError(
            f"engine='cuda': a batch of {N} runs needs about {format_bytes(estimate.memory)} of GPU memory (mostly "
            f"{estimate.memory_reason}; set by '{estimate.memory_key}'), more than the {format_bytes(free)} free on "
            f"{device_name()} (or allowed by {GPU_MEMORY_VARIABLE}); keep fewer signals or split the batch",
            estimate, estimate.memory_key, "memory")

    # members last on the device (coalesced reads and writes)
    on_device = time.perf_counter()
    put = lambda a: cuda.to_device(np.ascontiguousarray(a))             # noqa: E731
    d_sum, d_max, d_final = (cuda.device_array((n_rows, N)) for _ in range(3))
    d_failed_at = put(np.full(N, np.nan))
    d_failed_x = cuda.device_array((engine.nstates, N))
    d_Y = cuda.device_array((n_grid, n_keep, N) if n_keep else (1, 1, 1))
    d_tables = put(tables)
    # the called kernels' parameters are not read on the device (the sources are tabulated): a stand-in each, the
    # table where the generated code reads one (member_ext puts each member's in its place)
    dummy = put(np.zeros(1))
    ext = tuple(d_tables[0] if e in program.tables else dummy for e in range(len(engine.ext))) or (dummy,)
    threads = min(THREADS_PER_BLOCK, N)
    blocks = (N + threads - 1) // threads
    module.rk4_members[blocks, threads](
        put(times), put(grid_index), put(src_at), put(src_mid), put(aux), put(X0.T), put(theta.T), ext, (d_tables,),
        put(table_row), put(flags), put(keep), put(keep_rows), n_grid - 1, put(bound), d_Y, d_sum, d_max, d_final, d_failed_at,
        d_failed_x)
    cuda.synchronize()
    sum_sq, max_abs, final = (d.copy_to_host().T for d in (d_sum, d_max, d_final))
    failed_at = d_failed_at.copy_to_host()
    failed_x = d_failed_x.copy_to_host().T
    Y = np.moveaxis(d_Y.copy_to_host(), 2, 0) if n_keep else None             # (N, n_grid, n_keep)
    last_timings.clear()
    last_timings.update(setup=on_device - started, device=time.perf_counter() - on_device,
                        device_memory=estimate.memory)

    counts = np.zeros((N, 2), dtype=np.int64)
    counts[:, 0] = times.size - 1
    counts[:, 1] = 4 * (times.size - 1)
    failed = ~np.isnan(failed_at)
    failures = {int(m): f"t = {failed_at[m]:.6g} s: {monitor.member_reason(int(m), failed_x[m])}"
                for m in np.flatnonzero(failed)}
    values = _metrics(metrics, groups, n_grid, sum_sq, max_abs, final)
    for value in values.values():
        value[failed] = np.nan
    kept = {}
    if n_keep:
        for name in signals:
            kept[name] = Y[:, :, at[name]].copy()
            kept[name][failed] = np.nan
    return values, kept, failed_at, failures, counts
