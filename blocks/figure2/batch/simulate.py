"""Integrating a batch: the Figure-2 loop over a member axis, fixed-step RK4, metrics on the fly."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from blocks.engines.monitor import Monitor
from blocks.engines.steppers import rk4_step
from blocks.figure2.batch.members import MemberLoop
from blocks.figure2.batch.rows import member_rows
from blocks.figure2.batch.schedule import auto_substeps, batch_schedule
from blocks.figure2.batch.variants import Variants
from blocks.figure2.metrics import METRICS, OBSERVER_METRICS, TrackingAccumulator
from blocks.figure2.physical_bounds import batch_bounds
from blocks.plumbing.workers import worker_pool
from blocks.scenarios.scenario import Scenario, load_scenario

__all__ = ["METRICS", "SIGNALS", "STATE_ATOL", "STATE_ATOL_CONTACT", "STATE_ERROR", "METRIC_RTOL", "METRIC_ATOL",
           "BatchResult", "simulate_batch"]


#: Signals that can be kept on the output grid, each (members, times, joints).
SIGNALS = ("q", "dq", "q_ref", "dq_ref", "ddq_ref", "tau", "d_hat", "tau_dis", "d", "q_meas", "dq_meas")

#: Stated agreement of a batch member with its single run (see :mod:`blocks.figure2.batch`):
#: positions (rad, m), with tissue contact, and metrics (relative, and absolute in the metric's unit).
#: Over the paper's 10 s the single run's own error (RK45, rtol 1e-6) reaches 1.5e-6, hence 3e-6.
STATE_ATOL = 3e-6
STATE_ATOL_CONTACT = 1e-5
#: The batch's own position error (rad, m) against a DOP853 run at rtol 1e-11, paper scenario variants over 10 s.
STATE_ERROR = 2e-7
METRIC_RTOL = 1e-3
METRIC_ATOL = 1e-6

@dataclass
class BatchResult:
    """What a batch run kept.

    Attributes
    ----------
    variants : Variants
        The members, in order.
    observer : bool
        With or without the disturbance observer.
    time : numpy.ndarray
        The output grid (s).
    metrics : dict of str to numpy.ndarray
        Each asked-for metric, shape (N, n) per joint or (N,) (see :data:`METRICS`);
        NaN for members that diverged.
    signals : dict of str to numpy.ndarray
        Each asked-for signal on the grid, shape (N, len(time), n) for n joints.
    failed_at : numpy.ndarray
        Time (s) at which each member diverged, NaN if it did not.
    failures : dict of int to str
        For each member that diverged, which signal left which bound (:mod:`blocks.engines.divergence`, the rule of
        single runs), as a sentence.
    steps : int
        Number of steps taken: RK4's on the shared schedule, or with ``RK45`` the most any member took.
    substeps : int
        RK4 steps per output interval (before breakpoints were added); with ``RK45`` the ``substeps`` asked
        for, 0 when none was (each member takes its own steps).
    method : str
        ``"RK45"`` (each member with its own step control) or ``"RK4"`` (the shared fixed-step schedule).
    evaluations : numpy.ndarray or None
        Right-hand-side calls of each member (N,) (compiled engine).
    """

    variants: Variants
    observer: bool
    time: np.ndarray
    metrics: dict
    signals: dict
    failed_at: np.ndarray
    steps: int
    substeps: int
    failures: dict = field(default_factory=dict)
    method: str = "RK4"
    evaluations: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.variants)

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of the members that finished without diverging."""
        return np.isnan(self.failed_at)

    def member_metrics(self, i: int) -> dict:
        """Metrics of member ``i`` as plain lists and floats, like :func:`~blocks.figure2.metrics.tracking_metrics`."""
        return {name: (value[i].tolist() if value.ndim > 1 else float(value[i])) for name, value in self.metrics.items()}


class _Accumulator:
    """Running metrics (:class:`blocks.figure2.metrics.TrackingAccumulator`) and kept signals at the output grid points.

    The signals are buffered and handed over every ``block`` points, so that
    the reductions and the forward kinematics run over (joints, block, N) arrays
    rather than once per grid point.
    """

    def __init__(self, loop: MemberLoop, metrics, signals, n_grid: int, ref_grid, block: int = 64) -> None:
        self.loop, self.signals, self.n_grid = loop, tuple(signals), n_grid
        self.ref_grid = [np.asarray(a) for a in ref_grid]                                  # each (n_grid, joints)
        n, J = loop.n, loop.joints
        self.tracking = TrackingAccumulator(loop.kin, n_grid, metrics, members=(n,), n_joints=J,
                                            tool_position=loop.arm.tool_kernels.tool_position)
        self.want_d = self.tracking.wants_disturbance or "d" in self.signals
        self.kept = {name: np.empty((n_grid, J, n)) for name in self.signals}
        vectors = {"q"} | {name for name in self.signals if name not in ("q_ref", "dq_ref", "ddq_ref")}
        if self.want_d and loop.observer:
            vectors |= {"d", "d_hat"}
        self.block = block
        # Grid points first: each point's rows are one contiguous copy.
        self.buf = {name: np.empty((block, J, n)) for name in vectors}
        self.index: list[int] = []

    def add(self, k: int, sig: dict) -> None:
        """Buffer the signals of grid point ``k``."""
        j = len(self.index)
        if "d" in self.buf:
            sig["d"] = self.loop.lumped(sig["q"], sig["dq"], sig["tau"], sig["tau_dis"])
        for name, store in self.buf.items():
            store[j] = sig[name]
        self.index.append(k)
        if len(self.index) == self.block or k == self.n_grid - 1:
            self.flush()

    def flush(self) -> None:
        if not self.index:
            return
        ks, m = np.array(self.index), len(self.index)
        rows = {name: np.moveaxis(store[:m], 0, 1) for name, store in self.buf.items()}      # (joints, m, N)
        q_ref = self.ref_grid[0][ks].T[:, :, None]                                           # (joints, m, 1)
        self.tracking.add(q_ref, rows["q"], rows.get("d"), rows.get("d_hat"), last=ks[-1] == self.n_grid - 1)
        for name, store in self.kept.items():
            if name in ("q_ref", "dq_ref", "ddq_ref"):
                store[ks] = self.ref_grid[("q_ref", "dq_ref", "ddq_ref").index(name)][ks][:, :, None]
            else:
                store[ks] = self.buf[name][:m]
        self.index = []

    def result(self, failed: np.ndarray) -> tuple[dict, dict]:
        self.flush()
        out = {}
        for name, value in self.tracking.result().items():
            value = value.T.copy()                      # members first: (N, joints) or (N,)
            value[failed] = np.nan
            out[name] = value
        kept = {name: np.moveaxis(store, 2, 0) for name, store in self.kept.items()}   # (N, T, joints)
        for store in kept.values():
            store[failed] = np.nan
        return out, kept


def simulate_batch(scenario: Scenario | str | None, variants, observer: bool = True,
                   metrics: Sequence[str] | None = None, signals: Sequence[str] = (),
                   substeps: int | None = None, breakpoints: Sequence[float] = (), workers: int | None = None,
                   engine: str = "auto", method: str | None = None, _schedule=None) -> BatchResult:
    """Simulate N variants of a scenario as one vectorised ODE (fixed-step RK4, see :mod:`blocks.figure2.batch`).

    Parameters
    ----------
    scenario : Scenario or str
        The shared base scenario (or its name/path).
    variants : Variants, sequence of mappings or mapping of sequences
        Per-member values by dotted key (see :class:`Variants`).
    observer : bool
        With or without the disturbance observer.
    metrics : sequence of str, optional
        Metrics to accumulate (see :data:`METRICS`); default all that apply
        (the disturbance-estimate metrics need the observer).
    signals : sequence of str
        Signals to keep on the output grid (see :data:`SIGNALS`); none by
        default, since they dominate memory (8 bytes x n joints x grid points x N each).
    substeps : int, optional
        RK4 steps per output interval; the error falls as ``substeps**-4``.
        Default: :func:`auto_substeps` (1 on the paper scenario).
    breakpoints : sequence of float
        Extra times (s) the steps must land on.  A member's result depends on
        its batch only through the shared step schedule (``substeps``, and the
        noise sample times when any member has noise); batches given the same
        ``substeps`` and ``breakpoints`` give every member the same numbers.
    workers : int, optional
        Cores to share the members among: threads for the compiled engine
        (default: every core this process may run on), processes for the
        numpy one (contiguous slices, one per process; default one process,
        since a process takes about a second to start); each member's result
        does not depend on its slice.
    engine : {"auto", "compiled", "fast", "cuda"}
        ``cuda`` runs every member as one GPU thread (:mod:`blocks.engines.gpu`; needs
        ``dobkit[gpu]`` and a CUDA device; fixed-step RK4 only), never picked
        by ``auto``.  ``compiled`` runs the loop's generated module for every member in
        parallel (:mod:`blocks.engines.compiled.batch`; needs ``dobkit[fast]``);
        ``fast`` the numpy batch over a member axis; ``auto`` takes
        ``compiled`` when it can run the batch (numba installed; members
        sharing one generated code, so for a URDF arm one
        ``arm.nominal_mass_scale``) and the loop's generated code is short
        enough to compile now or already cached (the rule of single runs,
        :data:`blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS`), and says once
        why when it does not.  Both integrate the same RK4 schedule and
        agree to rounding with ``method="RK4"`` (the compiled batch
        accumulates the metrics in its driver; members with their own noise
        read their own noise table).
    method : {"RK4", "RK45"}, optional
        ``RK4`` (the default): fixed-step RK4 on one schedule shared by every
        member (``substeps``, ``breakpoints``), the numpy batch's only method.
        ``RK45`` (compiled batch only): each member integrated as its single
        compiled run is -- Dormand-Prince 5(4) with its own step control and
        the scenario's ``rtol``, ``atol``, ``max_step`` -- so it equals that
        run to rounding.  RK4 is the default because on the paper's
        laceration path it is about 4.5 times cheaper: the shared schedule
        evaluates the reference (its inverse kinematics, most of a
        right-hand side's cost) once per step for all members, where each
        adaptive member needs about 5,200 right-hand sides of its own
        (``benchmarks/bench_batch.py``); it is also the more accurate against
        a DOP853 run at rtol 1e-11 (``STATE_ERROR`` against the single run's
        1.5e-6).

    Returns
    -------
    BatchResult

    Raises
    ------
    ScenarioError
        On invalid variants, before anything is simulated.
    ValueError
        On unknown metric or signal names, or an unknown engine.
    blocks.engines.compiled.CompiledUnavailable
        If ``engine="compiled"`` cannot run (numba missing: the message names
        the extra).
    """
    if engine not in ("auto", "compiled", "fast", "cuda"):
        raise ValueError(f"batch engine must be one of ['auto', 'compiled', 'fast', 'cuda'], got {engine!r}")
    if method not in (None, "RK45", "RK4"):
        raise ValueError(f"batch method must be one of ['RK45', 'RK4'], got {method!r}")
    if isinstance(variants, Variants):
        v = variants
        if scenario is not None and scenario is not v.base and \
                (scenario if isinstance(scenario, Scenario) else load_scenario(scenario)).data != v.base.data:
            raise ValueError("simulate_batch: the Variants were made for a different base scenario")
    else:
        v = Variants(scenario, variants)
    metrics = tuple(m for m in METRICS if observer or m not in OBSERVER_METRICS) if metrics is None else tuple(metrics)
    for name in metrics:
        if name not in METRICS:
            raise ValueError(f"unknown metric {name!r}; choose from {list(METRICS)}")
        if name in OBSERVER_METRICS and not observer:
            raise ValueError(f"metric {name!r} needs the observer (observer=True)")
    for name in signals:
        if name not in SIGNALS:
            raise ValueError(f"unknown signal {name!r}; choose from {list(SIGNALS)}")
        if name == "d_hat" and not observer:
            raise ValueError("signal 'd_hat' needs the observer (observer=True)")

    s = v.base
    if engine == "cuda":                # the GPU batch (blocks.engines.gpu): fixed-step RK4, one thread per member
        return _simulate_on_gpu(v, observer, metrics, tuple(signals), substeps, breakpoints, method, _schedule)
    members, compiled = None, None
    if engine != "fast":
        from blocks.engines.compiled.batch import auto_batch_reason, batch_unavailable_reason, run_compiled_batch
        from blocks.engines.engine_choice import select_engine
        reason = batch_unavailable_reason(v)
        if reason is None:
            # the members as rows of numbers (blocks.figure2.batch.rows), or each member's blocks where the trace fails
            members = member_rows(v, observer)
        if reason is None and engine == "auto":
            # the rule of single runs: a loop whose generated code is too long to compile now runs on numpy
            reason, compiled = auto_batch_reason(members)
        engine = select_engine(engine, reason)
    if engine == "compiled":
        method = method or "RK4"
        if method == "RK4":
            substeps = auto_substeps(v, observer) if substeps is None else substeps
            times, grid_index = _schedule if _schedule is not None else batch_schedule(v, substeps, breakpoints)
        else:
            times, grid_index = s.simulation.time_grid, None
        values, kept, failed_at, failures, counts = run_compiled_batch(
            v, members, observer, metrics, tuple(signals), times, grid_index, workers, compiled, method)
        return BatchResult(variants=v, observer=observer, time=s.simulation.time_grid, metrics=values, signals=kept,
                           failed_at=failed_at, steps=int(counts[:, 0].max()),
                           substeps=int(substeps) if substeps is not None else 0, failures=failures, method=method,
                           evaluations=counts[:, 1])
    substeps = auto_substeps(v, observer) if substeps is None else substeps
    if method == "RK45":
        raise ValueError("method='RK45' (each member with its own step control) is the compiled batch's; the numpy "
                         "batch integrates fixed-step RK4 (method='RK4' or engine='compiled')")
    workers = 1 if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if workers > 1 and len(v) > 1:
        return _simulate_in_processes(v, observer, metrics, tuple(signals), substeps, workers,
                                      batch_schedule(v, substeps, breakpoints))
    loop = members if isinstance(members, MemberLoop) else MemberLoop(v, observer)
    sim = s.simulation
    times, grid_index = _schedule if _schedule is not None else batch_schedule(v, substeps, breakpoints)
    mids = 0.5 * (times[:-1] + times[1:])
    # The sources (the reference) are shared: evaluated once at every step end and mid point, as columns.
    src_at, src_mid = loop.source_table(times), loop.source_table(mids)
    n_grid = int(grid_index.max()) + 1
    ref_grid = [np.asarray(a) for a in s.trajectory.evaluate(times[grid_index >= 0])]
    acc = _Accumulator(loop, metrics, signals, n_grid, ref_grid)

    x = loop.initial_state()
    monitor = Monitor(f"batch of scenario '{s.name}'", batch_bounds(loop, loop.state_meanings), x)
    failed_at = np.full(loop.n, np.nan)
    failures: dict[int, str] = {}

    def judge(t: float, x: np.ndarray, failed_at: np.ndarray) -> np.ndarray:
        now = monitor.check_members(t, x, failed_at)
        for m in np.flatnonzero(np.isnan(failed_at) & ~np.isnan(now)):
            failures[int(m)] = f"t = {t:.6g} s: {monitor.member_reason(int(m), x[:, m])}"
        return now
    with np.errstate(all="ignore"):      # a diverging member must not stop the others
        for k in range(times.size - 1):
            t0, t1 = times[k], times[k + 1]
            sig = {} if grid_index[k] >= 0 else None
            k1 = loop.rhs(t0, x, src_at[k], sig)
            if sig is not None:
                failed_at = judge(t0, x, failed_at)
                acc.add(grid_index[k], sig)
            x = rk4_step(loop.rhs, t0, x, t1 - t0, mid=(src_mid[k],), end=(src_at[k + 1],), k1=k1)
            bad = ~np.isnan(failed_at)
            if bad.any():
                x[:, bad] = 0.0         # park diverged members at a harmless finite state
        sig = {}
        k = times.size - 1
        loop.rhs(times[k], x, src_at[k], sig)
        failed_at = judge(times[k], x, failed_at)
        acc.add(grid_index[k], sig)
    values, kept = acc.result(~np.isnan(failed_at))
    return BatchResult(variants=v, observer=observer, time=sim.time_grid, metrics=values, signals=kept,
                       failed_at=failed_at, steps=times.size - 1, substeps=int(substeps), failures=failures)


def _simulate_on_gpu(v: Variants, observer: bool, metrics: tuple, signals: tuple, substeps, breakpoints, method,
                     schedule=None) -> BatchResult:
    """The batch with ``engine="cuda"``: the members' rows and the shared RK4 schedule made here, the loop run by
    :func:`blocks.engines.gpu.batch.run_cuda_batch` (the GPU engine knows nothing of variants' checks or results)."""
    from blocks.engines.compiled.codegen import CompiledUnavailable
    from blocks.engines.gpu.batch import gpu_batch_reason, run_cuda_batch
    if method not in (None, "RK4"):
        raise ValueError(f"engine='cuda' integrates fixed-step RK4 on the shared schedule (method='RK4'), got "
                         f"method={method!r}; each member with its own step control (RK45) runs on engine='compiled'")
    reason = gpu_batch_reason(v)
    if reason is not None:
        raise CompiledUnavailable(f"engine='cuda' cannot run this batch: {reason}")
    substeps = auto_substeps(v, observer) if substeps is None else substeps
    times, grid_index = schedule if schedule is not None else batch_schedule(v, substeps, breakpoints)
    values, kept, failed_at, failures, counts = run_cuda_batch(v, member_rows(v, observer), observer, metrics,
                                                               signals, times, grid_index)
    return BatchResult(variants=v, observer=observer, time=v.base.simulation.time_grid, metrics=values, signals=kept,
                       failed_at=failed_at, steps=int(counts[:, 0].max()), substeps=int(substeps), failures=failures,
                       method="RK4", evaluations=counts[:, 1])


def _simulate_part(job: tuple) -> tuple:
    base, records, observer, metrics, signals, substeps, schedule = job
    r = simulate_batch(None, Variants(base, records), observer, metrics, signals, substeps, engine="fast",
                       _schedule=schedule)
    return r.metrics, r.signals, r.failed_at, r.steps, r.failures


def _simulate_in_processes(v: Variants, observer: bool, metrics: tuple, signals: tuple, substeps: int,
                           workers: int, schedule) -> BatchResult:
    """The batch cut into ``workers`` contiguous slices, simulated in as many processes on the whole
    batch's step schedule, and joined again: the result is that of one process."""
    slices = [idx for idx in np.array_split(np.arange(len(v)), min(workers, len(v)))]
    jobs = [(v.base, [v.records[i] for i in idx], observer, metrics, signals, substeps, schedule) for idx in slices]
    with worker_pool(len(jobs)) as pool:
        parts = list(pool.map(_simulate_part, jobs))
    join = lambda i: {k: np.concatenate([p[i][k] for p in parts]) for k in parts[0][i]}   # noqa: E731
    failures = {int(idx[m]): reason for idx, p in zip(slices, parts) for m, reason in p[4].items()}
    return BatchResult(variants=v, observer=observer, time=v.base.simulation.time_grid, metrics=join(0),
                       signals=join(1), failed_at=np.concatenate([p[2] for p in parts]), steps=parts[0][3],
                       substeps=int(substeps), failures=failures)
