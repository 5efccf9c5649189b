"""The compiled batch: the base loop's generated module run for N members in parallel, fixed-step RK4.

Every member runs the same generated right-hand side as a single compiled
run (:mod:`blocks.compiled.codegen`), with its own parameter vector
``theta``: the rows of the traced blocks' parameters are filled from the
batch's per-member arrays (:class:`blocks.batch.simulate._BatchLoop`), the
rest (the reference's) from the base loop.  The reference is evaluated once
at every step time and mid point, shared by all members.  Members with
their own measurement noise read their own noise table (``member_ext``).
Members run in parallel over ``workers`` threads (numba ``prange``).

The tracking metrics are accumulated inside the compiled driver: at each
output grid point the step's first stage also evaluates the row groups of
:mod:`blocks.compiled.rows` -- position error, tool-tip distance (against
the reference's tool position, computed once per grid point), disturbance
error ``d - d_hat`` with ``d`` traced from the lumped-disturbance kernel --
and the driver adds their squares, keeps their largest magnitude and their
value at the last point.  :func:`_metrics` turns those sums into the metrics
as :class:`blocks.metrics.TrackingAccumulator` defines them.  No signal is
stored unless asked for, and nothing is allocated per step.
"""
from __future__ import annotations

import control as ct
import numpy as np

from ..divergence import batch_bounds
from ..kernels import tool_pose
from ..loop import _prepared, closed_loop
from ..monitor import Monitor
from ..systems import observer as observer_block
from ..systems import signal_names
from .codegen import CompiledUnavailable
from .engine import CompiledLoopEngine
from .jit import numba_or_none

__all__ = ["batch_unavailable_reason", "run_compiled_batch", "NOISE_CHUNK"]

#: Members integrated in one call when members have their own noise tables (each about 0.6 MB per 10 s at 1 kHz).
NOISE_CHUNK = 128

# The row groups (blocks.compiled.rows) each metric is made from
_GROUP_OF = {"rms_position_error": "position_error", "max_abs_position_error": "position_error",
             "final_abs_position_error": "position_error", "max_tool_position_error_mm": "tool_distance",
             "rms_tool_position_error_mm": "tool_distance", "rms_disturbance_error": "disturbance_error",
             "max_abs_disturbance_error": "disturbance_error"}


def batch_unavailable_reason(variants) -> str | None:
    """Why the compiled batch cannot run these variants, or None when it can."""
    if numba_or_none() is None:
        return "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    return None


def _param_rows(params, n: int) -> np.ndarray:
    """Numbers of per-member parameters (arrays with a trailing member axis of 1 or n, or (n,) / scalars) as
    rows (count, n), in the order :func:`blocks.compiled.trace.param_values` reads one member's."""
    rows = []
    for value in params:
        if isinstance(value, (bool, np.bool_, str, type(None))):
            continue
        if isinstance(value, tuple):
            rows.append(_param_rows(value, n))
        elif isinstance(value, np.ndarray):
            a = value.reshape(-1, value.shape[-1]) if value.ndim > 1 else value.reshape(1, -1)
            if a.shape[1] == 1 and value.ndim > 1:
                a = np.broadcast_to(a, (a.shape[0], n))
            rows.append(np.asarray(a, dtype=float))
        else:
            rows.append(np.full((1, n), float(value)))
    return np.vstack(rows) if rows else np.zeros((0, n))


def _with_matrix_observer_gain(loop):
    """The same loop with an observer whose kernels take ``Y`` as a 4x4 matrix (one layout for every member)."""
    s = loop.scenario
    parts = [observer_block(s.nominal, s.observer_gain, s.observer_variant, matrix_gain=True,
                            measured="_meas" if s.noise is not None else "") if b.name == "observer" else b
             for b in loop.syslist]
    outputs = list(loop.output_labels)
    matrix_loop = ct.interconnect(parts, inplist=[], outlist=outputs, outputs=outputs, name=loop.name,
                                  check_unused=False)
    matrix_loop.scenario, matrix_loop.with_observer = s, loop.with_observer
    return matrix_loop


def _loop_for(v, batch_loop, observer: bool):
    """The loop whose structure every member shares: the base's, with a sensor when any member has noise, and
    with a matrix observer gain when any member's gain is not diagonal."""
    noisy = [i for i, nz in enumerate(v.noises) if nz is not None]
    if noisy and v.base.noise is None:
        loop = closed_loop(v.scenario(noisy[0]), observer=observer)
    else:
        loop = _prepared(v.base, observer).loop
    if observer and batch_loop.gain.ndim == 3:      # some member's Y is not diagonal: trace Y as a matrix
        loop = _with_matrix_observer_gain(loop)
    return loop


def _member_theta(engine, batch_loop, N: int) -> np.ndarray:
    """Every member's ``theta`` (N, p): the traced blocks' rows from the batch's per-member arrays."""
    program, plan = engine.program, engine.plan
    per_block = {"plant": (batch_loop.k_true, batch_loop.disturbance),
                 "controller": (batch_loop.k_nominal, batch_loop.kp, batch_loop.kd),
                 "observer": (batch_loop.k_nominal, batch_loop.gain, batch_loop.eq16_weight)}
    theta = np.repeat(engine.theta[None, :], N, axis=0)
    for name, params in per_block.items():
        if name not in plan.order:
            continue
        if name not in program.traced:
            raise CompiledUnavailable(f"block '{name}' is called, not traced, so its parameters cannot vary per member")
        rows = _param_rows(params, N)
        sl = program.theta_slices[name]
        if rows.shape[0] != sl.stop - sl.start:
            raise CompiledUnavailable(f"block '{name}': the batch's parameters do not match the loop's "
                                      f"({rows.shape[0]} numbers per member, the loop has {sl.stop - sl.start})")
        theta[:, sl] = rows.T
    return np.ascontiguousarray(theta)


def _noise_tables(v, engine) -> tuple[list, np.ndarray | None]:
    """The members' noise tables when they differ from the loop's (``member_ext``), as a list (None for a member
    without noise) and the zero table those read; ``([], None)`` when every member reads the loop's."""
    tables = engine.program.tables
    if not tables:
        return [], None
    if len(tables) != 1:
        raise CompiledUnavailable("the loop has more than one table parameter; the compiled batch varies one")
    loop_table = engine.ext[tables[0]]
    members = [None if nz is None else nz.table for nz in v.noises]
    if all(m is not None and m is loop_table for m in members):
        return [], None
    shapes = {m.shape for m in members if m is not None}
    if len(shapes) > 1 or (shapes and shapes != {loop_table.shape}):
        raise CompiledUnavailable(f"the members' noise tables differ in shape {sorted(shapes)}; they must share "
                                  f"the sample period and the run's length")
    return members, np.zeros(loop_table.shape)


def run_compiled_batch(v, batch_loop, observer: bool, metrics: tuple, signals: tuple, times, grid_index,
                       workers: int = 1):
    """Integrate the members of ``v`` compiled; return ``(metrics, signals, failed_at, failures)`` as the numpy
    batch does (``failures``: member -> which signal left which bound, the rule of :mod:`blocks.divergence`).

    Parameters
    ----------
    v : Variants
    batch_loop : blocks.batch.simulate._BatchLoop
        The members' parameter arrays and start states.
    observer : bool
    metrics, signals : tuple of str
    times, grid_index : numpy.ndarray
        The step schedule (see :func:`blocks.batch.step_schedule`).
    workers : int
        Threads to run members on.
    """
    reason = batch_unavailable_reason(v)
    if reason is not None:
        raise CompiledUnavailable(f"engine='compiled' cannot run this batch: {reason}")
    numba = numba_or_none()
    loop = _loop_for(v, batch_loop, observer)
    engine = CompiledLoopEngine(loop)
    if engine._announce:
        engine.warm()
    program, module, plan = engine.program, engine.module, engine.plan
    n, N = batch_loop.joints, batch_loop.n
    theta = _member_theta(engine, batch_loop, N)

    # the shared reference at step times and mid points
    times = np.ascontiguousarray(times, dtype=float)
    mids = 0.5 * (times[:-1] + times[1:])
    src_at = np.empty((times.size, max(program.n_src, 1)))
    src_mid = np.empty((max(mids.size, 1), max(program.n_src, 1)))
    module.source_table(times, engine.theta, engine.ext, src_at)
    module.source_table(mids, engine.theta, engine.ext, src_mid)
    grid_index = np.ascontiguousarray(grid_index, dtype=np.int64)
    on_grid = grid_index >= 0
    n_grid = int(grid_index.max()) + 1

    # start states in the loop's state order
    if "trajectory" in program.sources:
        ref0 = [r[:, None] for r in np.split(src_at[0, :3 * n], 3)]
    else:
        q0, dq0, _ = v.base.trajectory.evaluate(0.0)
        ref0 = [np.asarray(q0)[:, None], np.asarray(dq0)[:, None]]
    noise0 = batch_loop.noise_table(times[:1])
    x_rows = batch_loop.initial_state(ref0, None if noise0 is None else noise0[0])     # rows [q; dq; z], (nx, N)
    X0 = np.zeros((N, plan.nstates))
    steps = {s.name: s for s in plan.steps}
    X0[:, steps["plant"].x] = x_rows[:2 * n].T
    if observer:
        X0[:, steps["observer"].x] = x_rows[2 * n:3 * n].T
    # each member's bounds in the loop's state order (the interconnection's: blocks in order, their own labels)
    labels = [(block.name, label) for block in loop.syslist for label in block.state_labels]
    monitor = Monitor(f"batch of scenario '{v.base.name}'", batch_bounds(batch_loop, labels), X0.T)
    bound = np.ascontiguousarray(monitor.limits.T)                          # (N, nstates)
    failed_x = np.zeros((N, plan.nstates))

    # the row groups the metrics need, and the reference's tool position at each grid point (shared)
    groups = engine.row_groups
    flags = np.zeros(max(len(groups), 1), dtype=np.int64)
    for name in metrics:
        flags[groups[_GROUP_OF[name]][0]] = 1
    aux = np.zeros((n_grid, max(program.n_aux, 1)))
    if "tool_distance" in groups and any("tool" in m for m in metrics):
        q_ref_grid = src_at[on_grid, :n].T                                  # (4, n_grid)
        aux[:, :3] = tool_pose(batch_loop.kin[:, None], q_ref_grid)[:3].T

    # the outputs (and rows) to keep at the grid points; without a sensor the measured signals are the true ones
    labels = list(loop.output_labels)
    alias = {} if "q_meas[0]" in labels else {"q_meas": "q", "dq_meas": "dq"}
    keep = np.array([labels.index(x) for name in signals if name != "d" for x in signal_names(alias.get(name, name))],
                    dtype=np.int64)
    keep_rows = np.arange(groups["d"][1].start, groups["d"][1].stop, dtype=np.int64) if "d" in signals else \
        np.zeros(0, dtype=np.int64)
    if "d" in signals:
        flags[groups["d"][0]] = 1
    at, col = {}, 0
    for name in signals:
        if name != "d":
            at[name] = slice(col, col + n)
            col += n
    if "d" in signals:
        at["d"] = slice(col, col + n)
    n_keep = keep.size + keep_rows.size
    Y = np.empty((N, n_grid if n_keep else 0, n_keep))

    n_rows = max(program.n_rows, 1)
    sum_sq, max_abs, final = np.zeros((N, n_rows)), np.zeros((N, n_rows)), np.zeros((N, n_rows))
    failed_at = np.full(N, np.nan)
    members, zero_table = _noise_tables(v, engine)
    chunk = NOISE_CHUNK if members else N
    # numba's parallel loops take no tuples of numbers among their arguments: such parameters (the laceration
    # path's, used only by the sources, evaluated above) go in as arrays, which the kernels index alike
    ext = tuple(np.array(p, dtype=float) if isinstance(p, tuple) else p for p in engine.ext)
    threads = max(1, min(int(workers), numba.config.NUMBA_NUM_THREADS))
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        for c0 in range(0, N, chunk):
            c1 = min(N, c0 + chunk)
            if members:
                tables = (np.stack([zero_table if t is None else t for t in members[c0:c1]]),)
                table_row = np.arange(c1 - c0, dtype=np.int64)
            else:
                tables, table_row = (), np.zeros(c1 - c0, dtype=np.int64)
            module.rk4_batch(times, grid_index, src_at, src_mid, aux, X0[c0:c1], theta[c0:c1], ext, tables,
                             table_row, flags, keep, keep_rows, n_grid - 1, bound[c0:c1], Y[c0:c1],
                             sum_sq[c0:c1], max_abs[c0:c1], final[c0:c1], failed_at[c0:c1], failed_x[c0:c1])
    finally:
        numba.set_num_threads(previous)
    failed = ~np.isnan(failed_at)
    failures = {int(m): f"t = {failed_at[m]:.6g} s: {monitor.member_reason(int(m), failed_x[m])}"
                for m in np.flatnonzero(failed)}
    values = _metrics(metrics, groups, n_grid, sum_sq, max_abs, final)
    for value in values.values():
        value[failed] = np.nan
    kept = {name: Y[:, :, at[name]].copy() for name in signals}
    for store in kept.values():
        store[failed] = np.nan
    return values, kept, failed_at, failures


def _metrics(metrics: tuple, groups: dict, n_points: int, sum_sq, max_abs, final) -> dict:
    """The metrics, members first, from the driver's sums, as :class:`blocks.metrics.TrackingAccumulator` defines
    them (RMS over the ``n_points`` grid points; tool-tip errors in mm)."""
    out = {}
    for name in metrics:
        rows = groups[_GROUP_OF[name]][1]
        if name.startswith("rms"):
            value = np.sqrt(sum_sq[:, rows] / n_points)
        elif name.startswith("max"):
            value = max_abs[:, rows].copy()
        else:
            value = np.abs(final[:, rows])
        if "tool" in name:
            value = 1e3 * value[:, 0]
        out[name] = value
    return out

