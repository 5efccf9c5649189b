"""The compiled batch: the base loop's generated module run for N members in parallel, fixed-step RK4.

Every member runs the same generated right-hand side as a single compiled
run (:mod:`blocks.compiled.codegen`), with its own parameter vector
``theta``: the rows of the traced blocks' parameters are filled from the
batch's per-member arrays (:class:`blocks.batch.simulate._BatchLoop`), the
rest (the reference's) from the base loop.  The reference is evaluated once
at every step time and mid point, shared by all members.  Members run in
parallel over ``workers`` threads (numba ``prange``); each keeps only the
outputs the asked-for metrics and signals need at the output grid points,
and the metrics are accumulated with :class:`blocks.metrics.TrackingAccumulator`
chunk by chunk, so memory stays bounded.
"""
from __future__ import annotations

import control as ct
import numpy as np

from ..kernels import lumped_disturbance
from ..loop import DIVERGENCE_BOUND, closed_loop
from ..metrics import TrackingAccumulator
from ..systems import observer as observer_block
from ..systems import signal_names
from .codegen import CompiledUnavailable
from .engine import CompiledLoopEngine
from .jit import numba_or_none

__all__ = ["batch_unavailable_reason", "run_compiled_batch", "CHUNK"]

#: Members integrated between two metric updates (bounds the kept outputs to CHUNK x grid x rows).
CHUNK = 128


def batch_unavailable_reason(variants) -> str | None:
    """Why the compiled batch cannot run these variants, or None when it can."""
    if numba_or_none() is None:
        return "numba is not installed (it comes with the optional extra: pip install \"dobkit[fast]\")"
    if any(nz is not None for nz in variants.noises):
        return "measurement noise differs per member, and the compiled batch shares one noise table"
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


def run_compiled_batch(v, batch_loop, observer: bool, metrics: tuple, signals: tuple, times, grid_index,
                       workers: int = 1):
    """Integrate the members of ``v`` compiled; return ``(metrics, signals, failed_at)`` as the numpy batch does.

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
    loop = closed_loop(v.base, observer=observer)
    if observer and batch_loop.gain.ndim == 3:      # some member's Y is not diagonal: trace Y as a matrix
        loop = _with_matrix_observer_gain(loop)
    engine = CompiledLoopEngine(loop)
    program, module, plan = engine.program, engine.module, engine.plan
    n, N = batch_loop.joints, batch_loop.n
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
    theta = np.ascontiguousarray(theta)

    # the shared reference at step times and mid points
    times = np.ascontiguousarray(times, dtype=float)
    mids = 0.5 * (times[:-1] + times[1:])
    src_at = np.empty((times.size, max(program.n_src, 1)))
    src_mid = np.empty((max(mids.size, 1), max(program.n_src, 1)))
    if engine._announce:
        engine.warm()
    module.source_table(times, engine.theta, engine.ext, src_at)
    module.source_table(mids, engine.theta, engine.ext, src_mid)

    # start states in the loop's state order
    ref0 = [r[:, None] for r in np.split(src_at[0, :3 * n], 3)] if "trajectory" in program.sources else None
    if ref0 is None:
        q0, dq0, _ = v.base.trajectory.evaluate(0.0)
        ref0 = [np.asarray(q0)[:, None], np.asarray(dq0)[:, None]]
    x_rows = batch_loop.initial_state(ref0, None)                  # rows [q; dq; z], (nx, N)
    X0 = np.zeros((N, plan.nstates))
    steps = {s.name: s for s in plan.steps}
    X0[:, steps["plant"].x] = x_rows[:2 * n].T
    if observer:
        X0[:, steps["observer"].x] = x_rows[2 * n:3 * n].T

    # the outputs to keep at the grid points
    labels = list(loop.output_labels)
    tracking = TrackingAccumulator(batch_loop.kin, int(grid_index.max()) + 1, metrics, members=(N,))
    want_d = tracking.wants_disturbance or "d" in signals
    needed = ["q"] + [s for s in signals if s not in ("q", "d")]
    if want_d:
        needed += ["dq", "tau", "tau_dis"] + (["d_hat"] if observer else [])
    needed = list(dict.fromkeys(needed))
    # without a sensor the measured signals are the true ones (as in the numpy batch)
    alias = {} if "q_meas[0]" in labels else {"q_meas": "q", "dq_meas": "dq"}
    rows_of = {sig: [labels.index(x) for x in signal_names(alias.get(sig, sig))] for sig in needed}
    keep = np.array([r for sig in needed for r in rows_of[sig]], dtype=np.int64)
    at = {sig: slice(needed.index(sig) * n, needed.index(sig) * n + n) for sig in needed}
    n_grid = int(grid_index.max()) + 1
    grid_index = np.ascontiguousarray(grid_index, dtype=np.int64)

    failed_at = np.full(N, np.nan)
    kept = {name: np.empty((N, n_grid, n)) for name in signals}
    threads = max(1, min(int(workers), numba.config.NUMBA_NUM_THREADS))
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    sums = []
    t_grid = v.base.simulation.time_grid
    q_ref = np.asarray(v.base.trajectory.evaluate(t_grid)[0]).T[:, :, None]         # (4, T, 1), shared
    try:
        for c0 in range(0, N, CHUNK):
            c1 = min(N, c0 + CHUNK)
            Y = np.empty((c1 - c0, n_grid, keep.size))
            fail = np.full(c1 - c0, np.nan)
            module.rk4_batch(times, grid_index, src_at, src_mid, X0[c0:c1], theta[c0:c1], engine.ext, keep,
                             DIVERGENCE_BOUND, Y, fail)
            failed_at[c0:c1] = fail
            rows = {sig: np.transpose(Y[:, :, at[sig]], (2, 1, 0)) for sig in needed}       # (4, T, C)
            d = d_hat = None
            if want_d:
                k_true, k_nom = batch_loop.k_true[:, None, c0:c1], batch_loop.k_nominal[:, None, c0:c1]
                d = lumped_disturbance(k_true, k_nom, rows["q"], rows["dq"], rows["tau"], rows["tau_dis"])
                d_hat = rows.get("d_hat")
            part = TrackingAccumulator(batch_loop.kin, n_grid, metrics, members=(c1 - c0,))
            with np.errstate(all="ignore"):
                part.add(q_ref, rows["q"], d, d_hat, last=True)
            sums.append(part.result())
            for name in signals:
                kept[name][c0:c1] = np.transpose(d, (2, 1, 0)) if name == "d" else Y[:, :, at[name]]
    finally:
        numba.set_num_threads(previous)
    failed = ~np.isnan(failed_at)
    values = {}
    for name in metrics:
        value = np.concatenate([part[name] for part in sums], axis=-1).T.copy()      # members first
        value[failed] = np.nan
        values[name] = value
    for store in kept.values():
        store[failed] = np.nan
    return values, kept, failed_at
