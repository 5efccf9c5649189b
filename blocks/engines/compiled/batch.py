"""The compiled batch: the base loop's generated module run for N members in parallel.

Every member runs the same generated right-hand side as a single compiled
run (:mod:`blocks.engines.compiled.codegen`), with its own parameter vector
``theta``: the traced blocks' numbers, filled from the variants' columns
(:class:`blocks.figure2.batch.rows.MemberRows`) or read from each member's own block
parameters (:class:`blocks.figure2.batch.members.MemberLoop`: the member's blocks made
as its single run makes them), the reference's from the shared loop.  Members
with their own measurement noise read their own noise table (``member_ext``),
the others the base's one table.
Members run in parallel over ``workers`` threads (numba ``prange``; default
every core).

``method="RK45"`` (the default) runs each member as ``dopri_run`` runs a
single one (``dopri_batch``: the same Dormand-Prince steps, its own step
control), so a member equals its single compiled run to rounding.
``method="RK4"`` integrates all members on one fixed step schedule
(``rk4_batch``), with the reference evaluated once at every step time and
mid point.

The tracking metrics are accumulated inside the compiled driver: at each
output grid point the flagged row groups of :mod:`blocks.engines.compiled.rows` --
position error, tool-tip distance (against the reference's tool position,
computed once per grid point), disturbance error ``d - d_hat`` with ``d``
traced from the lumped-disturbance kernel -- are evaluated with the outputs,
and the driver adds their squares, keeps their largest magnitude and their
value at the last point.  :func:`_metrics` turns those sums into the metrics
as :class:`blocks.figure2.metrics.TrackingAccumulator` defines them.  No signal is
stored unless asked for, and nothing is allocated per step.
"""
from __future__ import annotations

import os

import numpy as np

from blocks.engines.compiled.codegen import CompiledUnavailable
from blocks.engines.compiled.engine import CompiledLoopEngine
from blocks.engines.compiled.jit import numba_or_none
from blocks.engines.divergence import state_meanings
from blocks.engines.monitor import Monitor
from blocks.kernels.trace import Frozen, param_values

__all__ = ["batch_unavailable_reason", "auto_batch_reason", "run_compiled_batch", "NOISE_CHUNK", "BATCH_METHODS",
           "batch_threads", "available_cores"]

#: The compiled batch's integrators: each member as its single compiled run (``RK45``), or fixed-step RK4.
BATCH_METHODS = ("RK45", "RK4")
# Status codes of dopri_batch (blocks/engines/compiled/dopri.py)
_FINISHED, _DIVERGED, _STEP_TOO_SMALL = 1, 2, 3
#: Members integrated in one call when members have their own noise tables (each about 0.6 MB per 10 s at 1 kHz).
NOISE_CHUNK = 128

# The row groups (blocks.engines.compiled.rows) each metric is made from
_GROUP_OF = {"rms_position_error": "position_error", "max_abs_position_error": "position_error",
             "final_abs_position_error": "position_error", "max_tool_position_error_mm": "tool_distance",
             "rms_tool_position_error_mm": "tool_distance", "rms_disturbance_error": "disturbance_error",
             "max_abs_disturbance_error": "disturbance_error"}


def batch_unavailable_reason(v) -> str | None:
    """Why the compiled batch cannot run these variants, or None when it can."""
    if numba_or_none() is None:
        return "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    if not v.base.robot.stacks_constants and len({id(n) for n in v.nominals}) > 1:
        scales = sorted({float(v.scenario(i).data["arm"]["nominal_mass_scale"]) for i in range(len(v))})
        return (f"'arm.nominal_mass_scale' differs between members ({', '.join(f'{x:g}' for x in scales[:4])}): a "
                f"URDF arm's model is generated into the loop's code as constants, so each nominal arm is a loop "
                f"of its own; the numpy batch runs them together (or vary the scale between batches)")
    return None


def _param_rows(params, n: int) -> np.ndarray:
    """Numbers of per-member parameters (arrays with a trailing member axis of 1 or n, or (n,) / scalars) as
    rows (count, n), in the order :func:`blocks.kernels.trace.param_values` reads one member's."""
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


def member_theta(engine, members) -> np.ndarray:
    """Every member's ``theta`` (N, p): the rows' own (:class:`blocks.figure2.batch.rows.MemberRows`), else
    :func:`_member_theta`."""
    own = getattr(members, "theta", None)
    return own(engine) if own is not None else _member_theta(engine, members)


def _member_theta(engine, members) -> np.ndarray:
    """Every member's ``theta`` (N, p): the traced blocks' numbers read from each member's own kernel parameters
    (:attr:`blocks.figure2.batch.members.MemberLoop.member_params`), in the order the program reads them."""
    program = engine.program
    theta = np.repeat(engine.theta[None, :], members.n, axis=0)
    for name, sl in program.theta_slices.items():
        if name in program.sources:
            continue                            # a shared source (the reference): the loop's own numbers
        params = members.member_params[name]
        for m, p in enumerate(params):
            values = param_values(p, [])
            if len(values) != sl.stop - sl.start:
                raise CompiledUnavailable(f"block '{name}': member {m}'s parameters do not match the loop's "
                                          f"({len(values)} numbers, the loop has {sl.stop - sl.start})")
            theta[m, sl] = values
    for name in program.theta_slices:
        if name not in program.sources and \
                len({_object_ids(p) for p in members.member_params[name]}) > 1:
            raise CompiledUnavailable(f"block '{name}': its model (a URDF arm's structure, generated as constants) "
                                      f"differs between members, so one generated code cannot run them all")
    for name in members.plan.order:
        if name not in program.theta_slices and name not in program.sources and \
                any(not _same_params(p, members.member_params[name][0]) for p in members.member_params[name]):
            raise CompiledUnavailable(f"block '{name}' is called, not traced, so its parameters cannot vary "
                                      f"per member")
    return np.ascontiguousarray(theta)


def _object_ids(params) -> tuple:
    """Identities of the structure objects (generated as constants, not read from ``theta``) in parameters."""
    if isinstance(params, tuple):
        return tuple(i for p in params for i in _object_ids(p))
    return (id(params),) if isinstance(params, Frozen) else ()


def _same_params(a, b) -> bool:
    return param_values(a, []) == param_values(b, [])


def _noise_tables(v, engine) -> tuple[list, np.ndarray]:
    """The noise tables the members read (``member_ext``): the distinct tables, and each member's row among
    them (N,).  Members that share a table (every member without a noise of its own reads the base's one)
    share its row; a member without noise reads a zero table.  ``([], zeros)`` when the loop reads no table."""
    tables = engine.program.tables
    row = np.zeros(len(v), dtype=np.int64)
    if not tables:
        return [], row
    if len(tables) != 1:
        raise CompiledUnavailable("the loop has more than one table parameter; the compiled batch varies one")
    loop_table = engine.ext[tables[0]]
    distinct: list = []
    where: dict = {}
    for m, nz in enumerate(v.noises):
        table = None if nz is None else nz.table
        key = id(table)
        if key not in where:
            where[key] = len(distinct)
            distinct.append(table)
        row[m] = where[key]
    shapes = {t.shape for t in distinct if t is not None}
    if len(shapes) > 1 or (shapes and shapes != {loop_table.shape}):
        raise CompiledUnavailable(f"the members' noise tables differ in shape {sorted(shapes)}; they must share "
                                  f"the sample period and the run's length")
    return [np.zeros(loop_table.shape) if t is None else t for t in distinct], row


def _chunk_tables(distinct: list, row: np.ndarray) -> tuple[tuple, np.ndarray]:
    """The tables members ``row`` (a chunk's rows of :func:`_noise_tables`) read, stacked, and each member's
    row in that stack."""
    if not distinct:
        return (), np.zeros(row.size, dtype=np.int64)
    used, at = np.unique(row, return_inverse=True)
    return (np.stack([distinct[j] for j in used]),), at.astype(np.int64)


def auto_batch_reason(members) -> tuple[str | None, CompiledLoopEngine | None]:
    """Why ``engine="auto"`` runs a batch on numpy (None: compiled), by the rule of single runs: the loop's
    compile is estimated longer than :data:`blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS` and it is not
    cached yet; and the engine made for the question (None when it could not be made)."""
    try:
        engine = CompiledLoopEngine(members.loop)
    except CompiledUnavailable as err:
        return str(err), None
    return engine.auto_reason(), engine


def run_compiled_batch(v, members, observer: bool, metrics: tuple, signals: tuple, times, grid_index,
                       workers: int | None = None, engine: CompiledLoopEngine | None = None, method: str = "RK45"):
    """Integrate the members of ``v`` compiled; return ``(metrics, signals, failed_at, failures, counts)`` as the
    numpy batch does (``failures``: member -> which signal left which bound, the rule of
    :mod:`blocks.engines.divergence`; ``counts`` (N, 2): each member's steps and right-hand-side calls).

    Parameters
    ----------
    v : Variants
    members : blocks.figure2.batch.members.MemberLoop or blocks.figure2.batch.rows.MemberRows
        The shared loop, each member's parameters and start states.
    observer : bool
    metrics, signals : tuple of str
    times, grid_index : numpy.ndarray
        With ``method="RK4"`` the step schedule (see :func:`blocks.figure2.batch.step_schedule`); with ``"RK45"``
        ``times`` is the output grid and ``grid_index`` is not read.
    workers : int, optional
        Threads to run members on; default all the cores numba may use.
    engine : CompiledLoopEngine, optional
        The shared loop's engine, when already made (:func:`auto_batch_reason`).
    method : {"RK45", "RK4"}
        ``RK45``: each member integrated as its single compiled run is (Dormand-Prince 5(4), its own step
        control, the scenario's ``rtol``, ``atol``, ``max_step``); ``RK4``: fixed-step RK4 on ``times``.
    """
    if method not in BATCH_METHODS:
        raise ValueError(f"batch method must be one of {list(BATCH_METHODS)}, got {method!r}")
    reason = batch_unavailable_reason(v)
    if reason is not None:
        raise CompiledUnavailable(f"engine='compiled' cannot run this batch: {reason}")
    numba = numba_or_none()
    loop = members.loop
    engine = CompiledLoopEngine(loop) if engine is None else engine
    if engine._announce:
        engine.warm()
    program, module = engine.program, engine.module
    n, N = members.joints, members.n
    theta = member_theta(engine, members)
    times = np.ascontiguousarray(times, dtype=float)
    rk4 = method == "RK4"
    if rk4:
        grid_index = np.ascontiguousarray(grid_index, dtype=np.int64)
        on_grid = grid_index >= 0
        n_grid = int(grid_index.max()) + 1
    else:
        n_grid = times.size

    # start states in the loop's state order, as each member's single run starts
    X0 = np.ascontiguousarray(member_start_states(members))
    # each member's bounds in the loop's state order (the interconnection's: blocks in order, their own labels)
    labels = state_meanings(loop)
    monitor = Monitor(f"batch of scenario '{v.base.name}'", members_bounds(members, labels), X0.T)
    bound = np.ascontiguousarray(monitor.limits.T)                          # (N, nstates)
    failed_x = np.zeros((N, engine.nstates))

    # the row groups the metrics need, and the reference's tool position at each grid point (shared)
    groups = engine.row_groups
    flags = np.zeros(max(len(groups), 1), dtype=np.int64)
    for name in metrics:
        flags[groups[_GROUP_OF[name]][0]] = 1
    aux = np.zeros((n_grid, max(program.n_aux, 1)))
    if "tool_distance" in groups and any("tool" in m for m in metrics):
        if rk4:
            src = np.empty((times.size, max(program.n_src, 1)))
            module.source_table(times, engine.theta, engine.ext, src)
            q_ref_grid = src[on_grid, :n].T                                 # (joints, n_grid)
        else:
            q_ref_grid = np.asarray(v.base.trajectory.evaluate(times)[0]).T
        aux[:, :3] = reference_tool_positions(members, q_ref_grid)

    keep, keep_rows, at, n_keep = kept_signals(loop, members.arm, signals, groups, flags, n)
    Y = np.empty((N, n_grid if n_keep else 0, n_keep))

    n_rows = max(program.n_rows, 1)
    sum_sq, max_abs, final = np.zeros((N, n_rows)), np.zeros((N, n_rows)), np.zeros((N, n_rows))
    failed_at = np.full(N, np.nan)
    status = np.full(N, _FINISHED, dtype=np.int64)
    counts = np.zeros((N, 3))
    distinct, table_rows = _noise_tables(v, engine)
    # a chunk of members holds the tables it reads: all at once when few are distinct (a shared one)
    chunk = NOISE_CHUNK if len(distinct) > NOISE_CHUNK else N
    # numba's parallel loops take no tuples of numbers among their arguments: such parameters (the laceration
    # path's, used only by the sources) go in as arrays, which the kernels index alike
    ext = tuple(np.array(p, dtype=float) if isinstance(p, tuple) else p for p in engine.ext)
    sim = v.base.simulation
    threads = batch_threads(workers)
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        src_at = np.empty((times.size, max(program.n_src, 1)))
        module.source_table(times, engine.theta, engine.ext, src_at)     # shared: at the steps, or the grid
        if rk4:
            mids = 0.5 * (times[:-1] + times[1:])
            src_mid = np.empty((max(mids.size, 1), max(program.n_src, 1)))
            module.source_table(mids, engine.theta, engine.ext, src_mid)
        for c0 in range(0, N, chunk):
            c1 = min(N, c0 + chunk)
            tables, table_row = _chunk_tables(distinct, table_rows[c0:c1])
            if rk4:
                module.rk4_batch(times, grid_index, src_at, src_mid, aux, X0[c0:c1], theta[c0:c1], ext, tables,
                                 table_row, flags, keep, keep_rows, n_grid - 1, bound[c0:c1], Y[c0:c1],
                                 sum_sq[c0:c1], max_abs[c0:c1], final[c0:c1], failed_at[c0:c1], failed_x[c0:c1])
            else:
                module.dopri_batch(times, src_at, X0[c0:c1], theta[c0:c1], ext, tables, table_row, float(sim.rtol),
                                   float(sim.atol), float(sim.max_step), aux, flags, keep, keep_rows, bound[c0:c1],
                                   Y[c0:c1], sum_sq[c0:c1], max_abs[c0:c1], final[c0:c1], status[c0:c1],
                                   failed_x[c0:c1], counts[c0:c1])
    finally:
        numba.set_num_threads(previous)
    failures = {}
    if rk4:
        counts[:, 0] = times.size - 1
        counts[:, 1] = 4 * (times.size - 1)
    else:
        stopped = status != _FINISHED
        failed_at[stopped] = counts[stopped, 2]
        for m in np.flatnonzero(status == _STEP_TOO_SMALL):
            failures[int(m)] = (f"t = {failed_at[m]:.6g} s: the solver's step became smaller than the spacing of "
                                f"the numbers there (rtol {sim.rtol:g}, atol {sim.atol:g})")
    failed = ~np.isnan(failed_at)
    for m in np.flatnonzero(failed):
        failures.setdefault(int(m), f"t = {failed_at[m]:.6g} s: {monitor.member_reason(int(m), failed_x[m])}")
    values = _metrics(metrics, groups, n_grid, sum_sq, max_abs, final)
    for value in values.values():
        value[failed] = np.nan
    kept = {name: Y[:, :, at[name]].copy() for name in signals}
    for store in kept.values():
        store[failed] = np.nan
    return values, kept, failed_at, failures, counts[:, :2].astype(np.int64)


def reference_tool_positions(members, q_ref_grid: np.ndarray) -> np.ndarray:
    """The reference's tool point (m) at the grid points, (points, 3), from ``q_ref_grid`` (joints, points): computed
    once for all members, for the tool-tip distance metrics."""
    kin = members.kin[:, None] if members.arm.stacks_constants else members.kin     # a closed form's numbers: a column
    return members.arm.tool_kernels.tool_position(kin, q_ref_grid).T


def kept_signals(loop, arm, signals: tuple, groups: dict, flags: np.ndarray, n: int) -> tuple:
    """Where the kept ``signals`` come from and go: ``(keep, keep_rows, at, n_keep)`` -- the loop outputs and the
    row-group rows (``d``) to copy at each grid point, each signal's columns in the kept array, and their count.
    Sets the flag of the ``d`` row group when ``d`` is kept.  Without a sensor the measured signals are the true
    ones."""
    labels = list(loop.output_labels)
    alias = {} if "q_meas[0]" in labels else {"q_meas": "q", "dq_meas": "dq"}
    keep = np.array([labels.index(x) for name in signals if name != "d"
                     for x in arm.joints.signal_names(alias.get(name, name))], dtype=np.int64)
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
    return keep, keep_rows, at, keep.size + keep_rows.size


def batch_threads(workers: int | None) -> int:
    """Threads a compiled batch runs on: ``workers`` (default all the cores this process may use), at most the
    threads numba has."""
    numba = numba_or_none()
    wanted = available_cores() if workers is None else int(workers)
    if wanted < 1:
        raise ValueError(f"workers must be >= 1, got {workers!r}")
    return max(1, min(wanted, numba.config.NUMBA_NUM_THREADS))


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                  # not on Linux
        return os.cpu_count() or 1


def member_start_states(members) -> np.ndarray:
    """Every member's start state (N, nstates) in the loop's state order."""
    own = getattr(members, "start_states", None)
    return own() if own is not None else members.initial_state().T


def members_bounds(members, labels):
    """Every member's divergence bounds in the order of ``labels`` (``(name, meaning)`` pairs of
    :func:`blocks.engines.divergence.state_meanings`): the members give them (the Figure-2 layer's from their scenarios,
    :func:`blocks.figure2.physical_bounds.batch_bounds`); this engine makes none."""
    return members.bounds(labels)


def _metrics(metrics: tuple, groups: dict, n_points: int, sum_sq, max_abs, final) -> dict:
    """The metrics, members first, from the driver's sums, as :class:`blocks.figure2.metrics.TrackingAccumulator` defines
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

