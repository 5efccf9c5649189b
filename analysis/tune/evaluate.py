"""Evaluating candidate gains of a tuning: the linear constraints first, then one batch of the set per candidate.

An *evaluation* of a candidate (a set of gains) is one batch of the tuning's
set (:attr:`analysis.tune.spec.TuneSpec.records`, every run with the candidate's
gains) through :func:`blocks.figure2.batch.simulate_batch`; the objective is the worst
or the mean of the metric over the runs, and the peak ``|tau|`` per joint over
every run's output grid is kept for the torque limit.  Before that, the linear
constraints (torque noise, stability margin; :mod:`analysis.tune.linear`) are
computed in milliseconds; a candidate that fails the torque noise, the
stability margin or the observer bandwidth ratio (:data:`SIMULATION_GATES`) is
not simulated.  One that misses only the damping (or overshoot) constraint is
simulated all the same and ranked infeasible: the log then holds what the
search found without that constraint, and the result can say what it costs.

Step sizes
    Each candidate's runs are integrated with the RK4 step its own gains need
    (:func:`blocks.figure2.batch.auto_substeps` over its runs, rounded up to a power of
    two), and candidates are batched together only when they need the same
    step, so a candidate's numbers do not depend on which others shared its
    batch: evaluating the tuned scenario file again gives the same numbers.

Ranking (what the search minimises, :attr:`Evaluation.energy`)
    A feasible candidate scores its objective (mm).  Any other scores
    ``INFEASIBLE * (1 + total violation)``: worse than every feasible one, and
    among infeasible ones the smaller violation wins.  Violations are relative
    (``noise / budget - 1``, ``peak / limit - 1``) except the stability margin's
    (``abscissa + margin``, 1/s) and the damping's (``zeta_min / min zeta - 1``);
a diverged run adds 1 plus the diverged fraction.

Margins (:meth:`Evaluator.margins`, what ``tune.json`` reports per constraint; < 0: missed)
    ``torque_noise_rms``, ``torque_limit``: the smallest ``1 - value / limit`` over
    the joints (a fraction of the budget left); ``stability_margin``:
    ``-abscissa - margin`` (1/s); ``min_damping_ratio``: ``min zeta - zeta_min``;
    ``max_overshoot``: ``limit - largest overshoot``; ``min_observer_bandwidth_ratio``:
    ``ratio - minimum``; ``sampled_margin``: ``1 - Ts lambda_max / limit - margin`` (the
    fraction of the sampled loop's limit left beyond the required one).
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from analysis.jobs.cluster import dask_threads, run_on_dask
from analysis.sweep.spec import json_default, run_schedule
from analysis.tune.linear import inertia_pairs, spectral_abscissas, torque_noise_rms
from analysis.tune.response import as_gain_matrix, error_dynamics
from analysis.tune.spec import TuneError, TuneSpec, damping_ratios, overshoots
from blocks import inertia
from blocks.engines.budget import Budget, BudgetError, Estimate, estimate_batch, largest_batch
from blocks.figure2.batch import Variants, auto_substeps, simulate_batch
from blocks.figure2.batch.schedule import rates_by_source
from blocks.figure2.digital_stability import largest_stable_scale, spectral_radius

__all__ = ["Evaluation", "Evaluator", "evaluation_estimate", "measure_evaluation", "time_estimate",
           "simulate_candidates", "gains_key", "INFEASIBLE",
           "MAX_CANDIDATES_PER_BATCH",
           "SIMULATION_GATES", "DAMPING_CONSTRAINTS"]

#: The score of an infeasible candidate starts here (mm; far above any tracking error).
INFEASIBLE = 1e9
#: Largest single violation counted in a score (keeps scores finite for unstable loops).
_VIOLATION_CAP = 1e6
#: Candidates simulated in one batch at most (fewer when the memory budget asks for it).
MAX_CANDIDATES_PER_BATCH = 16
#: Linear constraints whose failure spares a candidate its simulation.
SIMULATION_GATES = ("torque_noise_rms", "stability_margin", "min_observer_bandwidth_ratio", "sampled_margin")
#: The damping constraint, as a minimum ratio or a maximum overshoot (its cost is reported).
DAMPING_CONSTRAINTS = ("min_damping_ratio", "max_overshoot")


def gains_key(gains: dict) -> str:
    """The text that identifies a candidate (its gains, sorted), as the evaluation log stores it."""
    return json.dumps(gains, sort_keys=True, default=json_default)


@dataclass
class Evaluation:
    """One candidate's evaluation.

    Attributes
    ----------
    gains : dict
        Scenario changes (``"gains.kp"`` -> value).
    torque_noise_rms : numpy.ndarray
        Linear torque noise per joint of the arm (N m for a revolute joint, N for a prismatic one).
    spectral_abscissa : float
        Largest real part of the linearized loop's poles over configurations and models (1/s).
    damping_ratio : numpy.ndarray
        Of the error dynamics per joint, ``kd / (2 sqrt(kp))`` (one NaN, for any arm, when not computed).
    bandwidth_ratio : float
        Slowest observer mode over the tracking bandwidth (:mod:`analysis.tune.spec`).
    sampled_radius : float
        With a sampled-loop constraint: the sampled map's largest spectral radius along the path with the
        observer gain raised by ``1 / (1 - sampled_margin)`` (below 1: met); NaN without one.
    simulated : bool
        False when the linear constraints failed and the set was not run.
    values : numpy.ndarray or None
        The metric of each run of the set (mm; NaN for a diverged run).
    peak_torque : numpy.ndarray or None
        Peak ``|tau|`` per joint over the set (N m or N).
    diverged : int
        Runs of the set that diverged.
    substeps : int
        RK4 steps per output interval of the candidate's batch (0 when not simulated).
    seconds : float
        Simulation time of the candidate's share of its batch (s).
    from_log : bool
        Whether the simulation result came from the evaluation log (a resumed tuning).
    objective : float
        Worst or mean of ``values`` (mm); infinity when not simulated or a run diverged.
    violations : dict of str to float
        Per constraint, how far it is violated (0: met).
    feasible : bool
    energy : float
        What the search minimises (module docstring).
    """

    gains: dict
    torque_noise_rms: np.ndarray
    spectral_abscissa: float
    damping_ratio: np.ndarray = field(default_factory=lambda: np.full(1, np.nan))
    bandwidth_ratio: float = math.nan
    sampled_radius: float = math.nan
    simulated: bool = False
    values: np.ndarray | None = None
    peak_torque: np.ndarray | None = None
    diverged: int = 0
    substeps: int = 0
    seconds: float = 0.0
    from_log: bool = False
    phase: str = ""
    objective: float = math.inf
    violations: dict = field(default_factory=dict)
    feasible: bool = False
    energy: float = math.inf

    @property
    def key(self) -> str:
        return gains_key(self.gains)

    def row(self) -> dict:
        """The evaluation log's line for a simulated evaluation (strict JSON values)."""
        fin = lambda v: float(v) if math.isfinite(v) else None                       # noqa: E731
        return {"key": self.key, "gains": self.gains, "phase": self.phase,
                "status": "ok" if self.diverged == 0 else "diverged", "objective": fin(self.objective),
                "values": [fin(v) for v in self.values], "peak_torque": [fin(v) for v in self.peak_torque],
                "torque_noise_rms": [fin(v) for v in self.torque_noise_rms],
                "spectral_abscissa": fin(self.spectral_abscissa), "diverged": int(self.diverged),
                "substeps": int(self.substeps), "seconds": round(self.seconds, 6)}


def _pow2(n: int) -> int:
    return 1 << max(0, math.ceil(math.log2(max(1, n))))


class Evaluator:
    """Evaluates candidates of one tuning, remembers every evaluation, and simulates each candidate at most once.

    Parameters
    ----------
    spec : TuneSpec
    workers : int
        Threads (compiled engine) or processes (numpy engine) of each batch.
    log_rows : dict, optional
        Rows of the evaluation log by :func:`gains_key`: candidates found there are not simulated again.
    record : callable, optional
        Called with the rows of every batch once it is simulated (the evaluation log's writer).
    after_batch : callable, optional
        Called with the number of candidates simulated, after every batch (progress, wall-time budget).
    engine : str
        :func:`blocks.figure2.batch.simulate_batch`'s engine.
    client : distributed.Client, optional
        Simulate on this Dask cluster (:mod:`analysis.jobs.cluster`), each batch on one worker thread.
    """

    def __init__(self, spec: TuneSpec, workers: int = 1, log_rows: dict | None = None,
                 record: Callable[[list[dict]], None] | None = None,
                 after_batch: Callable[[int], None] | None = None, engine: str = "auto", client=None) -> None:
        self.spec, self.workers, self.engine, self.client = spec, int(workers), engine, client
        self.log_rows = dict(log_rows or {})
        self.record, self.after_batch = record, after_batch
        self.history: list[Evaluation] = []          # every evaluation asked for, in order
        self.simulated_now = 0
        self._known: dict[str, Evaluation] = {}
        base = spec.base
        members = Variants(base, spec.records)
        robots, nominals = [base.robot] + members.robots, [base.nominal] + members.nominals
        self._M, self._M_nominal = inertia_pairs(spec.configurations, robots, nominals)
        self._hold = (inertia(spec.hold, base.robot), inertia(spec.hold, base.nominal))
        self._M_observer = inertia(spec.configurations, base.nominal)       # the base model along the path
        # the sampled loop's check: the nominal inertia at the path's distinct configurations
        M = self._M_observer.reshape(len(spec.configurations), -1)
        self._M_sampled = self._M_observer[np.sort(np.unique(np.round(M, 12), axis=0, return_index=True)[1])]

    # -- the linear constraints ------------------------------------------------------------------
    def linear(self, gains: dict) -> tuple[np.ndarray, float]:
        """Torque noise per joint (N m) and spectral abscissa (1/s) of a candidate."""
        s = self.spec.base
        kp = gains.get("gains.kp", np.diag(s.kp))
        kd = gains.get("gains.kd", np.diag(s.kd))
        Y = gains.get("gains.observer", s.observer_gain)
        abscissa = float(spectral_abscissas(self._M, self._M_nominal, kp, kd, Y).max())
        noise = self.spec.limits.sensor_noise
        rms = torque_noise_rms(*self._hold, kp, kd, Y, noise["q_std"], noise["dq_std"], noise["sample_period"])
        return rms, abscissa

    def design(self, gains: dict) -> tuple[np.ndarray, float, float]:
        """Damping ratio of the error dynamics per joint, the observer bandwidth ratio and the sampled loop's
        spectral radius (NaN without a sampled-loop constraint; :attr:`Evaluation.sampled_radius`) of a candidate."""
        s = self.spec.base
        kp = np.broadcast_to(np.asarray(gains.get("gains.kp", np.diag(s.kp)), dtype=float), (self.spec.n,))
        kd = gains.get("gains.kd", np.diag(s.kd))
        Y = self._observer_matrix(gains)
        slowest = float(np.linalg.eigvals(Y @ np.linalg.inv(self._M_observer)).real.min())
        radius = math.nan
        margin = self.spec.limits.sampled_margin
        if margin is not None:
            Kp, Kd = self._pd_matrices(gains)
            radius = float(spectral_radius(self._M_sampled, Kp, Kd, Y / (1.0 - margin), s.controller).max())
        return damping_ratios(kp, kd, self.spec.n), slowest / float(np.sqrt(kp.max())), radius

    def _observer_matrix(self, gains: dict) -> np.ndarray:
        n = self._M_observer.shape[-1]
        return as_gain_matrix(gains.get("gains.observer", self.spec.base.observer_gain), n)

    def _pd_matrices(self, gains: dict) -> tuple[np.ndarray, np.ndarray]:
        s, n = self.spec.base, self._M_observer.shape[-1]
        return as_gain_matrix(gains.get("gains.kp", s.kp), n), as_gain_matrix(gains.get("gains.kd", s.kd), n)

    def sampled_loop(self, gains: dict) -> dict | None:
        """``Ts lambda_max(Y M^-1)`` of a candidate along the path and the sampled loop's limit on it for its
        ``Kp``, ``Kd`` (:func:`blocks.figure2.digital_stability.largest_stable_scale`: a bisection); None without a
        sampled-loop constraint."""
        if self.spec.limits.sampled_margin is None:
            return None
        settings = self.spec.base.controller
        Y = self._observer_matrix(gains)
        Kp, Kd = self._pd_matrices(gains)
        ts_lam = settings.period * float(np.abs(np.linalg.eigvals(Y @ np.linalg.inv(self._M_sampled))).max())
        scale = largest_stable_scale(self._M_sampled, Kp, Kd, Y, settings)
        return {"ts_lambda_max": ts_lam, "ts_lambda_limit": ts_lam * scale}

    def error_dynamics(self, gains: dict):
        """The candidate's linearized error dynamics at the held configuration with the base scenario's true and
        nominal models (:func:`analysis.tune.response.error_dynamics`): for the step and Bode figures."""
        s = self.spec.base
        kp = gains.get("gains.kp", np.diag(s.kp))
        kd = gains.get("gains.kd", np.diag(s.kd))
        Y = gains.get("gains.observer", s.observer_gain)
        return error_dynamics(*self._hold, kp, kd, Y), (kp, kd)

    def linear_violations(self, noise: np.ndarray, abscissa: float, zeta=None, ratio: float | None = None,
                          radius: float | None = None) -> dict:
        """The linear constraints' violations (0: met); the damping, ratio and sampled-loop ones when ``zeta``,
        ``ratio``, ``radius`` are given."""
        limits = self.spec.limits
        out = {}
        if limits.torque_noise_rms is not None:
            out["torque_noise_rms"] = _relative_excess(noise, limits.torque_noise_rms)
        if limits.stability_margin is not None:
            out["stability_margin"] = min(_VIOLATION_CAP, max(0.0, abscissa + limits.stability_margin))
        if zeta is not None and limits.min_damping_ratio is not None:
            out["min_damping_ratio"] = min(_VIOLATION_CAP, max(0.0, limits.min_damping_ratio / float(np.min(zeta))
                                                              - 1.0))
        if zeta is not None and limits.max_overshoot is not None:
            out["max_overshoot"] = _relative_excess(overshoots(zeta), np.full(np.shape(zeta), limits.max_overshoot))
        if ratio is not None and limits.min_observer_bandwidth_ratio is not None:
            out["min_observer_bandwidth_ratio"] = min(_VIOLATION_CAP, max(
                0.0, limits.min_observer_bandwidth_ratio / ratio - 1.0 if ratio > 0 else _VIOLATION_CAP))
        if radius is not None and limits.sampled_margin is not None:
            out["sampled_margin"] = min(_VIOLATION_CAP, max(0.0, radius - 1.0)) if math.isfinite(radius) \
                else _VIOLATION_CAP
        return out

    def margins(self, ev: Evaluation) -> dict:
        """Per constraint, by how much the evaluation meets it (< 0: missed; module docstring)."""
        limits, out = self.spec.limits, {}
        if limits.torque_noise_rms is not None:
            out["torque_noise_rms"] = float(np.min(1.0 - ev.torque_noise_rms / limits.torque_noise_rms))
        if limits.torque_limit is not None and ev.peak_torque is not None:
            out["torque_limit"] = float(np.min(1.0 - ev.peak_torque / limits.torque_limit))
        if limits.stability_margin is not None:
            out["stability_margin"] = float(-ev.spectral_abscissa - limits.stability_margin)
        if limits.min_damping_ratio is not None:
            out["min_damping_ratio"] = float(np.min(ev.damping_ratio) - limits.min_damping_ratio)
        if limits.max_overshoot is not None:
            out["max_overshoot"] = float(limits.max_overshoot - np.max(overshoots(ev.damping_ratio)))
        if limits.min_observer_bandwidth_ratio is not None:
            out["min_observer_bandwidth_ratio"] = float(ev.bandwidth_ratio - limits.min_observer_bandwidth_ratio)
        sampled = self.sampled_loop(ev.gains)
        if sampled is not None:
            left = 1.0 - sampled["ts_lambda_max"] / sampled["ts_lambda_limit"] if sampled["ts_lambda_limit"] > 0 \
                else -math.inf
            out["sampled_margin"] = float(left - limits.sampled_margin)
        return out

    def judged(self, ev: Evaluation) -> Evaluation:
        """A copy of an evaluation of this tuning made under other constraints (a search with one of them
        dropped), with this evaluator's violations, feasibility and score.  The sampled loop's radius, which a
        search without that constraint does not compute, is computed here."""
        out = dataclasses.replace(ev, violations={})
        if self.spec.limits.sampled_margin is not None and not math.isfinite(out.sampled_radius):
            out.sampled_radius = self.design(out.gains)[2]
        out.violations = self.linear_violations(out.torque_noise_rms, out.spectral_abscissa, out.damping_ratio,
                                                out.bandwidth_ratio, out.sampled_radius)
        self._finish(out)
        return out

    # -- evaluations -------------------------------------------------------------------------------
    def evaluate(self, candidates: list[dict], phase: str, force: bool = False) -> list[Evaluation]:
        """Evaluate candidates (gains dicts) in order; ``force`` simulates them even when the linear constraints
        fail (the base gains, the final answer).  Each is appended to :attr:`history`."""
        out = [self._prepare(g, phase) for g in candidates]
        pending: dict[str, Evaluation] = {}
        for ev in out:
            if ev.simulated or ev.key in pending:
                continue
            if force or all(ev.violations.get(k, 0) == 0 for k in SIMULATION_GATES):
                row = self.log_rows.get(ev.key)
                if row is not None:
                    self._take_row(ev, row)
                else:
                    pending[ev.key] = ev
        if pending:
            self._simulate(list(pending.values()))
        for ev in out:
            if not ev.simulated and ev.key in self._known and self._known[ev.key].simulated:
                self._copy(self._known[ev.key], ev)
            self._finish(ev)
            self._known[ev.key] = ev
            self.history.append(ev)
        return out

    def _prepare(self, gains: dict, phase: str) -> Evaluation:
        key = gains_key(gains)
        known = self._known.get(key)
        if known is not None:
            ev = Evaluation(gains=gains, torque_noise_rms=known.torque_noise_rms,
                            spectral_abscissa=known.spectral_abscissa, damping_ratio=known.damping_ratio,
                            bandwidth_ratio=known.bandwidth_ratio, sampled_radius=known.sampled_radius, phase=phase)
            if known.simulated:
                self._copy(known, ev)
        else:
            noise, abscissa = self.linear(gains)
            zeta, ratio, radius = self.design(gains)
            ev = Evaluation(gains=gains, torque_noise_rms=noise, spectral_abscissa=abscissa, damping_ratio=zeta,
                            bandwidth_ratio=ratio, sampled_radius=radius, phase=phase)
        ev.violations = self.linear_violations(ev.torque_noise_rms, ev.spectral_abscissa, ev.damping_ratio,
                                               ev.bandwidth_ratio, ev.sampled_radius)
        return ev

    @staticmethod
    def _copy(src: Evaluation, dst: Evaluation) -> None:
        dst.simulated, dst.values, dst.peak_torque = True, src.values, src.peak_torque
        dst.diverged, dst.substeps, dst.seconds, dst.from_log = src.diverged, src.substeps, src.seconds, src.from_log

    def _take_row(self, ev: Evaluation, row: dict) -> None:
        ev.simulated, ev.from_log = True, True
        ev.values = np.array([np.nan if v is None else v for v in row["values"]], dtype=float)
        ev.peak_torque = np.array([np.nan if v is None else v for v in row["peak_torque"]], dtype=float)
        ev.diverged, ev.substeps, ev.seconds = int(row["diverged"]), int(row["substeps"]), float(row["seconds"])

    def _finish(self, ev: Evaluation) -> None:
        """Objective, violations, feasibility and score of an evaluation."""
        limits = self.spec.limits
        if ev.simulated:
            finite = ev.values[np.isfinite(ev.values)]
            if ev.diverged or finite.size < ev.values.size:
                ev.objective = math.inf
                ev.violations["diverged"] = 1.0 + ev.diverged / max(1, ev.values.size)
            else:
                ev.objective = float(finite.max() if self.spec.objective == "worst" else finite.mean())
            if limits.torque_limit is not None:
                ev.violations["torque_limit"] = _relative_excess(ev.peak_torque, limits.torque_limit)
        total = float(sum(ev.violations.values()))
        ev.feasible = ev.simulated and total == 0 and math.isfinite(ev.objective)
        ev.energy = ev.objective if ev.feasible else INFEASIBLE * (1.0 + total)

    def _substeps(self, gains: dict) -> int:
        variants = Variants(self.spec.base, [rec | gains for rec in self.spec.records])
        return _pow2(auto_substeps(variants, True))

    def _simulate(self, pending: list[Evaluation]) -> None:
        """Run the pending candidates' sets, batched by step; record each batch's rows as it finishes (on the
        Dask cluster of :attr:`client` when there is one, the batches then spread over its workers)."""
        spec = self.spec
        groups: dict[int, list[Evaluation]] = {}
        for ev in pending:
            groups.setdefault(self._substeps(ev.gains), []).append(ev)
        runs = spec.runs
        threads = dask_threads(self.client) if self.client is not None else 1
        chunks: list[tuple[int, list[Evaluation]]] = []
        for substeps, evs in sorted(groups.items()):
            size = run_schedule(spec.base, substeps, _noisy(spec))
            fits = largest_batch(spec.budget.memory, steps=size.steps, grid_points=size.grid_points, signals=1,
                                 noise=_noisy(spec), noise_samples=size.noise_samples, joints=spec.base.robot.n)
            per_batch = max(1, min(MAX_CANDIDATES_PER_BATCH, fits // runs))
            if self.client is not None:          # every worker a share of the candidates
                per_batch = max(1, min(per_batch, math.ceil(len(evs) / threads)))
            chunks += [(substeps, evs[start:start + per_batch]) for start in range(0, len(evs), per_batch)]
        payloads = [self._payload(i, substeps, chunk) for i, (substeps, chunk) in enumerate(chunks)]
        take = lambda done: self._take(chunks[done["chunk"]][1], done)            # noqa: E731
        if self.client is None:
            for payload in payloads:
                take(_simulate_payload(spec.base, payload))
        else:
            run_on_dask(self.client, simulate_candidates, iter(payloads), take, threads, TuneError)

    def _payload(self, index: int, substeps: int, chunk: list[Evaluation]) -> dict:
        """What :func:`simulate_candidates` needs for one chunk of candidates (picklable)."""
        spec = self.spec
        return {"chunk": index, "scenario": spec.base.data, "source": spec.base.source,
                "records": [rec | ev.gains for ev in chunk for rec in spec.records], "candidates": len(chunk),
                "metric": spec.metric, "substeps": substeps, "engine": self.engine,
                "workers": 1 if self.client is not None else self.workers}

    def _take(self, chunk: list[Evaluation], done: dict) -> None:
        """One finished chunk: its evaluations filled in, its rows recorded, the batch reported."""
        runs = self.spec.runs
        values = done["values"].reshape(len(chunk), runs)
        ok = done["ok"].reshape(len(chunk), runs)
        peaks = done["peaks"].reshape(len(chunk), runs, -1)
        for i, ev in enumerate(chunk):
            ev.simulated, ev.substeps, ev.seconds = True, done["substeps"], done["seconds"]
            ev.values = np.where(ok[i], values[i], np.nan)
            ev.diverged = int((~ok[i]).sum())
            ev.peak_torque = peaks[i].max(axis=0)
            self._known[ev.key] = ev
        self.simulated_now += len(chunk)
        if self.record is not None:
            self.record([ev.row() for ev in chunk])
        if self.after_batch is not None:
            self.after_batch(len(chunk))


def simulate_candidates(payload: dict) -> dict:
    """Simulate one chunk of candidates' sets (picklable in and out: run on a Dask worker).

    ``payload``: ``scenario`` (data dict), ``source``, ``records`` (every run of every candidate, candidate by
    candidate), ``candidates``, ``metric``, ``substeps``, ``engine``, ``workers`` and ``chunk`` (returned as is).
    Returns ``chunk``, ``values`` (the metric per run, mm), ``ok`` (per run), ``peaks`` (peak ``|tau|`` per run
    and joint), ``substeps`` and ``seconds`` (per candidate).
    """
    from blocks.scenarios.scenario import scenario_from_dict
    return _simulate_payload(scenario_from_dict(payload["scenario"], source=payload["source"]), payload)


def _simulate_payload(base, payload: dict) -> dict:
    t0 = time.perf_counter()
    result = simulate_batch(None, Variants(base, payload["records"]), observer=True, metrics=[payload["metric"]],
                            signals=("tau",), substeps=payload["substeps"], workers=payload["workers"],
                            engine=payload["engine"], method="RK4")
    seconds = (time.perf_counter() - t0) / payload["candidates"]
    tau = result.signals["tau"]
    tau[~result.ok] = 0.0                  # a diverged run's torques are NaN; it counts as diverged
    return {"chunk": payload["chunk"], "values": np.asarray(result.metrics[payload["metric"]], dtype=float),
            "ok": np.asarray(result.ok, dtype=bool), "peaks": np.abs(tau).max(axis=1),
            "substeps": payload["substeps"], "seconds": seconds}


def _relative_excess(values: np.ndarray, limits: np.ndarray) -> float:
    """``max_j (values_j / limits_j - 1)``, at least 0 (absolute excess where a limit is 0), capped."""
    values, limits = np.asarray(values, dtype=float), np.asarray(limits, dtype=float)
    if np.any(np.isnan(values)):
        return _VIOLATION_CAP
    excess = np.where(limits > 0, values / np.where(limits > 0, limits, 1.0) - 1.0, values - limits)
    return float(min(_VIOLATION_CAP, max(0.0, float(excess.max()))))


def _noisy(spec: TuneSpec) -> bool:
    return spec.base.noise is not None or any(k.startswith("noise.") for rec in spec.records for k in rec)


def evaluation_estimate(spec: TuneSpec) -> tuple[Estimate, int]:
    """One evaluation's steps and memory at the bounds' fastest gains (every gain at its high bound), checked
    against the tuning's budget, and the substeps there.

    Raises
    ------
    blocks.engines.budget.BudgetError
        Naming the ``[search]`` gain whose high bound makes the step small, or ``monte_carlo.runs``.
    """
    corner = spec.gains(np.ones(len(spec.parameters)))
    variants = Variants(spec.base, [rec | corner for rec in spec.records])
    substeps = _pow2(auto_substeps(variants, True))
    rates = {k: float(v.max()) for k, v in rates_by_source(variants, True).items()}
    source = max(rates, key=rates.get)
    tuned = {p.key for p in spec.parameters}
    key = f'search."{source}"' if source in tuned else ("search.\"gains.kd\"" if source == "gains.kp" and
                                                         "gains.kd" in tuned else source)
    size = run_schedule(spec.base, substeps, _noisy(spec))
    reason = (f"{size.grid_points - 1:.3g} output intervals x {substeps} substeps, as the fastest rate at the high "
              f"bounds is {rates[source]:.3g} 1/s ({source})")
    estimate = estimate_batch(spec.runs, steps=size.steps, grid_points=size.grid_points, signals=1,
                              noise=_noisy(spec), noise_samples=size.noise_samples,
                              keys={"steps": key, "members": "monte_carlo.runs"}, steps_reason=reason,
                              joints=spec.base.robot.n)
    spec.budget.check(estimate, f"{spec.name}: one evaluation ({spec.runs} runs) at the high bounds")
    return estimate, substeps


def measure_evaluation(spec: TuneSpec, workers: int = 1, engine: str = "auto", repeats: int = 2) -> Evaluation:
    """Simulate the base gains' set ``repeats`` times and return the last evaluation: its ``seconds`` is the
    wall time of one evaluation on this machine (the first also loads or compiles the engine's loop), its
    ``substeps`` the RK4 steps per output interval it took.  For ``dobkit tune --check``'s time estimate."""
    ev = None
    for _ in range(max(1, int(repeats))):
        ev = Evaluator(spec, workers=workers, engine=engine).evaluate([spec.gains_of_base()], "base", force=True)[0]
    return ev


def time_estimate(spec: TuneSpec, measured: Evaluation, searches: int = 1) -> float:
    """The tuning's simulation time (s) from one measured evaluation: ``max_evaluations`` evaluations at its
    cost for each of ``searches`` searches (:func:`analysis.tune.costs.search_count`).  Candidates that need
    smaller steps cost more, those the linear constraints refuse (or the log holds, as it holds much of a search
    without one constraint) next to nothing: an estimate, not a bound."""
    return int(searches) * spec.max_evaluations * float(measured.seconds)


def time_bound(spec: TuneSpec, measured: Evaluation, searches: int, corner_substeps: int) -> float:
    """The tuning's simulation time (s) if every evaluation needed ``corner_substeps`` RK4 steps per output
    interval, as gains at the high bounds do: :func:`time_estimate` scaled by ``corner_substeps / substeps``
    (an evaluation's cost grows with its steps), never below it."""
    scale = max(1.0, int(corner_substeps) / max(1, int(measured.substeps)))
    return time_estimate(spec, measured, searches) * scale


def check_seconds(budget: Budget, started: float, what: str) -> None:
    """Raise :class:`~blocks.engines.budget.BudgetError` when the wall-time budget has run out."""
    if budget.seconds is not None and time.perf_counter() - started > budget.seconds:
        raise BudgetError(f"{what}: the wall-time budget of {budget.seconds:g} s ran out; every finished "
                          "evaluation is kept in the evaluation log: run the same command again to go on, or raise "
                          "--max-seconds", key="seconds", limit="seconds")
