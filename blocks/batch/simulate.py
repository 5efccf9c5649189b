"""Integrating a batch: the Figure-2 loop over a member axis, fixed-step RK4, metrics on the fly."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..disturbances import external_disturbance
from ..kinematics import forward_kinematics
from ..parameters import InertiaConstants
from ..scenario import Scenario, load_scenario
from ..systems import JOINTS
from ..workers import worker_pool
from .arm import BatchArm, batched_constants
from .schedule import auto_substeps, batch_schedule
from .variants import Variants

__all__ = ["METRICS", "SIGNALS", "STATE_ATOL", "STATE_ATOL_CONTACT", "STATE_ERROR", "METRIC_RTOL", "METRIC_ATOL",
           "BatchResult", "simulate_batch"]

#: Metrics :func:`simulate_batch` can accumulate; the names and definitions of
#: :func:`blocks.metrics.tracking_metrics` (per joint: rad, rad, m, rad;
#: tool errors in mm; disturbance errors in N m or N).
METRICS = ("rms_position_error", "max_abs_position_error", "final_abs_position_error",
           "max_tool_position_error_mm", "rms_tool_position_error_mm",
           "rms_disturbance_error", "max_abs_disturbance_error")
_OBSERVER_METRICS = ("rms_disturbance_error", "max_abs_disturbance_error")

#: Signals that can be kept on the output grid, each (members, times, 4).
SIGNALS = ("q", "dq", "q_ref", "dq_ref", "ddq_ref", "tau", "d_hat", "tau_dis", "d", "q_meas", "dq_meas")

#: Stated agreement of a batch member with its single run (see :mod:`blocks.batch`):
#: positions (rad, m), with tissue contact, and metrics (relative, and absolute in the metric's unit).
#: Over the paper's 10 s the single run's own error (RK45, rtol 1e-6) reaches 1.5e-6, hence 3e-6.
STATE_ATOL = 3e-6
STATE_ATOL_CONTACT = 1e-5
#: The batch's own position error (rad, m) against a DOP853 run at rtol 1e-11, paper scenario variants over 10 s.
STATE_ERROR = 2e-7
METRIC_RTOL = 1e-3
METRIC_ATOL = 1e-6

# A state this large (rad, m, rad/s, N m) means the member has diverged (as in loop.simulate).
DIVERGENCE_BOUND = 1e6


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
        Each asked-for metric, shape (N, 4) per joint or (N,) (see :data:`METRICS`);
        NaN for members that diverged.
    signals : dict of str to numpy.ndarray
        Each asked-for signal on the grid, shape (N, len(time), 4).
    failed_at : numpy.ndarray
        Time (s) at which each member diverged, NaN if it did not.
    steps : int
        Number of RK4 steps taken.
    substeps : int
        RK4 steps per output interval (before breakpoints were added).
    """

    variants: Variants
    observer: bool
    time: np.ndarray
    metrics: dict
    signals: dict
    failed_at: np.ndarray
    steps: int
    substeps: int

    def __len__(self) -> int:
        return len(self.variants)

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of the members that finished without diverging."""
        return np.isnan(self.failed_at)

    def member_metrics(self, i: int) -> dict:
        """Metrics of member ``i`` as plain lists and floats, like :func:`~blocks.metrics.tracking_metrics`."""
        return {name: (value[i].tolist() if value.ndim > 1 else float(value[i])) for name, value in self.metrics.items()}


# --------------------------------------------------------------------------------------------
# The batched loop
# --------------------------------------------------------------------------------------------
class _BatchLoop:
    """The Figure-2 loop over a member axis: states (nx, N), rows q, dq and z (observer)."""

    def __init__(self, variants: Variants, observer: bool) -> None:
        v = variants
        self.v, self.observer, self.n = v, observer, len(v)
        k_true, k_nominal = batched_constants(v.robots), batched_constants(v.nominals)
        self.true, self.nominal = BatchArm(k_true), BatchArm(k_nominal)
        # True and nominal arm side by side (2N members): one numpy call serves both, which
        # halves the per-call overhead that dominates at N ~ 1000.
        self.both = BatchArm(InertiaConstants(**{f.name: np.concatenate([getattr(k_true, f.name),
                                                                          getattr(k_nominal, f.name)])
                                                 for f in dataclasses.fields(InertiaConstants)}))
        ends = sorted({0, self.n - 1})      # a cheap guard that the formulas still match dynamics.py
        self.true.check_against(v.robots, ends)
        self.nominal.check_against(v.nominals, ends)
        self.both.check_against(v.robots + v.nominals, sorted({0, 2 * self.n - 1}))
        self.kinematics = v.base.robot           # a1, a2, d1, d4 are shared by the batch
        self.has_noise = any(nz is not None for nz in v.noises)
        self.nx = 3 * JOINTS if observer else 2 * JOINTS
        self.has_extra = bool(v.extra.any())

    def y_times(self, vec: np.ndarray) -> np.ndarray:
        """Observer gain times a joint vector, ``Y v`` for v (4, N)."""
        if self.v.y_diag is not None:
            return self.v.y_diag * vec
        return np.einsum("ijn,jn->in", self.v.y_full, vec)

    def noise_table(self, times: np.ndarray) -> np.ndarray | None:
        """Noise ``[n_q; n_dq]`` of every member at ``times``: shape (len(times), 8, N), or None."""
        if not self.has_noise:
            return None
        table = np.zeros((times.size, 2 * JOINTS, self.n))
        for i, noise in enumerate(self.v.noises):
            if noise is not None:
                n_q, n_dq = noise.sample(times)
                table[:, :JOINTS, i], table[:, JOINTS:, i] = n_q, n_dq
        return table

    def initial_state(self, ref0, noise0) -> np.ndarray:
        q_ref0, dq_ref0 = ref0[0][:, 0], ref0[1][:, 0]
        x0 = np.zeros((self.nx, self.n))
        d_hat0 = np.zeros((JOINTS, self.n))
        for i, init in enumerate(self.v.initial):
            x0[:JOINTS, i] = init["q"] if init["q"] is not None else q_ref0
            x0[JOINTS:2 * JOINTS, i] = init["dq"] if init["dq"] is not None else dq_ref0
            if init["d_hat"] is not None:
                d_hat0[:, i] = init["d_hat"]
        if self.observer:
            dq_meas0 = x0[JOINTS:2 * JOINTS] + (noise0[JOINTS:] if noise0 is not None else 0.0)
            x0[2 * JOINTS:] = d_hat0 - self.y_times(dq_meas0)    # d_hat = Y dq + z
        return x0

    def rhs(self, t: float, x: np.ndarray, ref, noise, record: dict | None = None) -> np.ndarray:
        """State derivative (nx, N) at time ``t`` with reference ``ref = (q_ref, dq_ref, ddq_ref)`` (4, 1) each.

        With ``record`` (a dict) the loop's signals at this point are stored in it.
        """
        J, n = JOINTS, self.n
        q, dq = x[:J], x[J:2 * J]
        q_ref, dq_ref, ddq_ref = ref
        if noise is not None:
            q_m, dq_m = q + noise[:J], dq + noise[J:]
            angle = np.concatenate((q[1], q_m[1]))
            c2_both, s2_both = np.cos(angle), np.sin(angle)
            c2, s2, c2_m = c2_both[:n], s2_both[:n], c2_both[n:]
            dq_both = np.concatenate((dq, dq_m), axis=1)
        else:
            q_m, dq_m = q, dq
            c2, s2 = np.cos(q[1]), np.sin(q[1])
            c2_m = c2
            c2_both, s2_both = np.concatenate((c2, c2)), np.concatenate((s2, s2))
            dq_both = np.concatenate((dq, dq), axis=1)
        bias_both = self.both.bias(s2_both, dq_both)            # true arm at q, nominal model at q_meas
        bias_true, bias_nom = bias_both[:, :n], bias_both[:, n:]
        d_hat = self.y_times(dq_m) + x[2 * J:] if self.observer else 0.0
        v = ddq_ref + self.v.kd * (dq_ref - dq_m) + self.v.kp * (q_ref - q_m)
        tau = self.nominal.mass_times(c2_m, v) + bias_nom - d_hat                           # Eq. 11
        tau_dis = external_disturbance(t, q.T, dq.T, self.v.disturbance, self.kinematics).T
        dx = np.empty_like(x)
        dx[:J] = dq
        if self.observer:
            rhs_both = np.empty((J, 2 * n))
            np.subtract(tau + tau_dis, bias_true, out=rhs_both[:, :n])                       # Eq. 1
            np.subtract(tau + d_hat, bias_nom, out=rhs_both[:, n:])                          # Eq. 12-16
            solved = self.both.mass_solve(c2_both, rhs_both)
            ddq = solved[:, :n]
            np.negative(self.y_times(solved[:, n:]), out=dx[2 * J:])
            if self.has_extra:                    # the printed Eq. 16's extra - Y q' term
                dx[2 * J:] -= self.v.extra * self.y_times(dq_m)
        else:
            ddq = self.true.mass_solve(c2, tau + tau_dis - bias_true)
        dx[J:2 * J] = ddq
        if record is not None:
            record.update(q=q, dq=dq, tau=tau, tau_dis=tau_dis, q_meas=q_m, dq_meas=dq_m, ddq=ddq,
                          c2=c2, s2=s2, d_hat=d_hat, bias_nom=bias_nom)
        return dx


class _Accumulator:
    """Running metrics and kept signals at the output grid points.

    The lumped disturbance is computed at each grid point over contiguous
    (4, N) rows; the signals are buffered and reduced every ``block`` points,
    so that the forward kinematics run over (block, N) arrays rather than
    once per grid point.
    """

    def __init__(self, loop: _BatchLoop, metrics, signals, n_grid: int, ref_grid, block: int = 64) -> None:
        self.loop, self.metrics, self.signals, self.n_grid = loop, tuple(metrics), tuple(signals), n_grid
        self.ref_grid = [np.asarray(a) for a in ref_grid]                                  # each (n_grid, 4)
        n = loop.n
        self.sum_sq_e, self.max_e, self.final_e = (np.zeros((JOINTS, n)) for _ in range(3))
        self.want_tool = any("tool" in m for m in self.metrics)
        self.want_d = any(m in _OBSERVER_METRICS for m in self.metrics) or "d" in self.signals
        self.sum_sq_tool, self.max_tool = np.zeros(n), np.zeros(n)
        self.sum_sq_ed, self.max_ed = np.zeros((JOINTS, n)), np.zeros((JOINTS, n))
        if self.want_tool:
            self.tool_ref = forward_kinematics(self.ref_grid[0], loop.kinematics)[:, :3]      # (n_grid, 3)
        self.kept = {name: np.empty((n_grid, JOINTS, n)) for name in self.signals}
        vectors = {"q"} | {name for name in self.signals if name not in ("q_ref", "dq_ref", "ddq_ref")}
        if self.want_d:
            vectors |= {"d"} | ({"d_hat"} if loop.observer else set())
        self.block = block
        # Grid points first: the reductions over time then run over contiguous memory.
        self.buf = {name: np.empty((block, JOINTS, n)) for name in vectors}
        self.index: list[int] = []

    def lumped_disturbance(self, sig: dict) -> np.ndarray:
        """``d = M^(q) q'' + N^(q, q') q' + G^(q) - tau`` at the true state of one grid point, (4, N)."""
        nominal = self.loop.nominal
        bias = nominal.bias(sig["s2"], sig["dq"]) if self.loop.has_noise else sig["bias_nom"]
        return nominal.mass_times(sig["c2"], sig["ddq"]) + bias - sig["tau"]

    def add(self, k: int, sig: dict) -> None:
        """Buffer the signals of grid point ``k``."""
        j = len(self.index)
        if self.want_d:
            # over (4, N) here rather than (4, block, N) in flush: contiguous rows, and fewer buffers
            sig["d"] = self.lumped_disturbance(sig)
        for name, store in self.buf.items():
            store[j] = sig[name]
        self.index.append(k)
        if len(self.index) == self.block or k == self.n_grid - 1:
            self.flush()

    def flush(self) -> None:
        if not self.index:
            return
        ks, m = np.array(self.index), len(self.index)
        b = {name: store[:m] for name, store in self.buf.items()}
        q = b["q"]                                                                          # (m, 4, N)
        e = self.ref_grid[0][ks][:, :, None] - q
        self.sum_sq_e += np.einsum("mjn,mjn->jn", e, e)
        np.maximum(self.max_e, np.max(np.abs(e), axis=0), out=self.max_e)
        if ks[-1] == self.n_grid - 1:
            self.final_e[:] = np.abs(e[-1])
        if self.want_tool:
            p = forward_kinematics(np.moveaxis(q, 1, -1), self.loop.kinematics)[..., :3]       # (m, N, 3)
            diff = p - self.tool_ref[ks][:, None, :]
            dist = np.sqrt(np.einsum("mnk,mnk->mn", diff, diff))                             # (m, N)
            self.sum_sq_tool += np.einsum("mn,mn->n", dist, dist)
            np.maximum(self.max_tool, np.max(dist, axis=0), out=self.max_tool)
        if self.want_d and self.loop.observer:
            ed = b["d"] - b["d_hat"]
            self.sum_sq_ed += np.einsum("mjn,mjn->jn", ed, ed)
            np.maximum(self.max_ed, np.max(np.abs(ed), axis=0), out=self.max_ed)
        for name, store in self.kept.items():
            if name in ("q_ref", "dq_ref", "ddq_ref"):
                store[ks] = self.ref_grid[("q_ref", "dq_ref", "ddq_ref").index(name)][ks][:, :, None]
            else:
                store[ks] = b[name]
        self.index = []

    def result(self, failed: np.ndarray) -> tuple[dict, dict]:
        self.flush()
        n = self.n_grid
        values = {
            "rms_position_error": np.sqrt(self.sum_sq_e / n).T,
            "max_abs_position_error": self.max_e.T,
            "final_abs_position_error": self.final_e.T,
            "max_tool_position_error_mm": 1e3 * self.max_tool,
            "rms_tool_position_error_mm": 1e3 * np.sqrt(self.sum_sq_tool / n),
            "rms_disturbance_error": np.sqrt(self.sum_sq_ed / n).T,
            "max_abs_disturbance_error": self.max_ed.T,
        }
        out = {}
        for name in self.metrics:
            value = values[name].copy()
            value[failed] = np.nan
            out[name] = value
        kept = {name: np.moveaxis(store, 2, 0) for name, store in self.kept.items()}   # (N, T, 4)
        for store in kept.values():
            store[failed] = np.nan
        return out, kept


def simulate_batch(scenario: Scenario | str | None, variants, observer: bool = True,
                   metrics: Sequence[str] | None = None, signals: Sequence[str] = (),
                   substeps: int | None = None, breakpoints: Sequence[float] = (), workers: int = 1,
                   _schedule=None) -> BatchResult:
    """Simulate N variants of a scenario as one vectorised ODE (fixed-step RK4, see :mod:`blocks.batch`).

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
        default, since they dominate memory (8 bytes x 4 x grid points x N each).
    substeps : int, optional
        RK4 steps per output interval; the error falls as ``substeps**-4``.
        Default: :func:`auto_substeps` (1 on the paper scenario).
    breakpoints : sequence of float
        Extra times (s) the steps must land on.  A member's result depends on
        its batch only through the shared step schedule (``substeps``, and the
        noise sample times when any member has noise); batches given the same
        ``substeps`` and ``breakpoints`` give every member the same numbers.
    workers : int
        Processes to share the members among (contiguous slices, one per
        process); each member's result does not depend on its slice.

    Returns
    -------
    BatchResult

    Raises
    ------
    ScenarioError
        On invalid variants, before anything is simulated.
    ValueError
        On unknown metric or signal names.
    """
    if isinstance(variants, Variants):
        v = variants
        if scenario is not None and scenario is not v.base and \
                (scenario if isinstance(scenario, Scenario) else load_scenario(scenario)).data != v.base.data:
            raise ValueError("simulate_batch: the Variants were made for a different base scenario")
    else:
        v = Variants(scenario, variants)
    metrics = tuple(m for m in METRICS if observer or m not in _OBSERVER_METRICS) if metrics is None else tuple(metrics)
    for name in metrics:
        if name not in METRICS:
            raise ValueError(f"unknown metric {name!r}; choose from {list(METRICS)}")
        if name in _OBSERVER_METRICS and not observer:
            raise ValueError(f"metric {name!r} needs the observer (observer=True)")
    for name in signals:
        if name not in SIGNALS:
            raise ValueError(f"unknown signal {name!r}; choose from {list(SIGNALS)}")
        if name == "d_hat" and not observer:
            raise ValueError("signal 'd_hat' needs the observer (observer=True)")

    s = v.base
    substeps = auto_substeps(v, observer) if substeps is None else substeps
    if workers > 1 and len(v) > 1:
        return _simulate_in_processes(v, observer, metrics, tuple(signals), substeps, workers,
                                      batch_schedule(v, substeps, breakpoints))
    loop = _BatchLoop(v, observer)
    sim = s.simulation
    times, grid_index = _schedule if _schedule is not None else batch_schedule(v, substeps, breakpoints)
    mids = 0.5 * (times[:-1] + times[1:])
    # The reference is shared: evaluate it once at every step end and mid point, as columns (4, 1).
    refs = [np.asarray(a)[..., None] for a in s.trajectory.evaluate(times)]      # each (T, 4, 1)
    refs_mid = [np.asarray(a)[..., None] for a in s.trajectory.evaluate(mids)]
    noise_at = loop.noise_table(times)
    noise_mid = loop.noise_table(mids)
    n_grid = int(grid_index.max()) + 1
    ref_grid = [a[grid_index >= 0, :, 0] for a in refs]
    acc = _Accumulator(loop, metrics, signals, n_grid, ref_grid)

    x = loop.initial_state([r[0] for r in refs], None if noise_at is None else noise_at[0])
    failed_at = np.full(loop.n, np.nan)
    pick = (lambda tab, k: None) if noise_at is None else (lambda tab, k: tab[k])
    with np.errstate(all="ignore"):      # a diverging member must not stop the others
        for k in range(times.size - 1):
            t0, t1 = times[k], times[k + 1]
            h = t1 - t0
            ref0, refm, ref1 = [r[k] for r in refs], [r[k] for r in refs_mid], [r[k + 1] for r in refs]
            sig = {} if grid_index[k] >= 0 else None
            k1 = loop.rhs(t0, x, ref0, pick(noise_at, k), sig)
            if sig is not None:
                failed_at = _check(x, t0, failed_at)
                acc.add(grid_index[k], sig)
            k2 = loop.rhs(t0 + 0.5 * h, x + (0.5 * h) * k1, refm, pick(noise_mid, k))
            k3 = loop.rhs(t0 + 0.5 * h, x + (0.5 * h) * k2, refm, pick(noise_mid, k))
            k4 = loop.rhs(t1, x + h * k3, ref1, pick(noise_at, k + 1))
            x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
            bad = ~np.isnan(failed_at)
            if bad.any():
                x[:, bad] = 0.0         # park diverged members at a harmless finite state
        sig = {}
        k = times.size - 1
        loop.rhs(times[k], x, [r[k] for r in refs], pick(noise_at, k), sig)
        failed_at = _check(x, times[k], failed_at)
        acc.add(grid_index[k], sig)
    values, kept = acc.result(~np.isnan(failed_at))
    return BatchResult(variants=v, observer=observer, time=sim.time_grid, metrics=values, signals=kept,
                       failed_at=failed_at, steps=times.size - 1, substeps=int(substeps))


def _simulate_part(job: tuple) -> tuple:
    base, records, observer, metrics, signals, substeps, schedule = job
    r = simulate_batch(None, Variants(base, records), observer, metrics, signals, substeps, _schedule=schedule)
    return r.metrics, r.signals, r.failed_at, r.steps


def _simulate_in_processes(v: Variants, observer: bool, metrics: tuple, signals: tuple, substeps: int,
                           workers: int, schedule) -> BatchResult:
    """The batch cut into ``workers`` contiguous slices, simulated in as many processes on the whole
    batch's step schedule, and joined again: the result is that of one process."""
    slices = [idx for idx in np.array_split(np.arange(len(v)), min(workers, len(v)))]
    jobs = [(v.base, [v.records[i] for i in idx], observer, metrics, signals, substeps, schedule) for idx in slices]
    with worker_pool(len(jobs)) as pool:
        parts = list(pool.map(_simulate_part, jobs))
    join = lambda i: {k: np.concatenate([p[i][k] for p in parts]) for k in parts[0][i]}   # noqa: E731
    return BatchResult(variants=v, observer=observer, time=v.base.simulation.time_grid, metrics=join(0),
                       signals=join(1), failed_at=np.concatenate([p[2] for p in parts]), steps=parts[0][3],
                       substeps=int(substeps))


def _check(x: np.ndarray, t: float, failed_at: np.ndarray) -> np.ndarray:
    """Mark members whose state is non-finite or beyond :data:`DIVERGENCE_BOUND` at time ``t``."""
    largest = np.max(np.abs(x), axis=0)
    bad = ~(largest <= DIVERGENCE_BOUND)          # also true for NaN
    new = bad & np.isnan(failed_at)
    if new.any():
        failed_at = failed_at.copy()
        failed_at[new] = t
    return failed_at
