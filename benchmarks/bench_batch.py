"""Batched simulation: N variants of the paper's 10 s scenario (default N = 1000) against one lean-baseline run.

    PYTHONPATH=. python benchmarks/bench_batch.py [--members 1000] [--repeats 5] [--numpy] [--json out.json]

The variants are a Monte Carlo draw (fixed seed) of the kind a robustness study
uses: every nominal-model mass and inertia scaled by U(0.9, 1.1), Kp ~ U(120, 250),
Kd ~ U(30, 45) and the Eq. 4 amplitudes scaled by U(0.5, 2).  Timed, each
case validating the variants and calling :func:`blocks.figure2.batch.simulate_batch`
(all seven metrics, no signals):

* ``default call``: ``simulate_batch(s, variants)`` -- the compiled engine,
  fixed-step RK4 on one schedule shared by every member, on every core of the machine;
* ``workers=k`` for k = 1, 2, ... up to the cores the process may use: the
  scaling curve (speed-up = the one-worker wall time over k workers');
* ``RK45``: each member integrated as its single compiled run (``method="RK45"``:
  Dormand-Prince 5(4), its own step control) on every core;
* ``set-up``: the same 1000 members of a 0.01 s run (two output steps), so
  nearly all of it is checking the variants and filling the members' rows;
* ``single compiled run``: ``blocks.simulate(s, engine="compiled")`` of the
  paper scenario, the whole call with the response (the figure of
  ``bench_fastpath.py``): the fastest of ten calls in a row in each round
  (after warm-up), and ``cold``: one call after the other cases and a
  garbage collection (its code and data out of the caches: about 0.4 ms more).

The scaling curve comes with where the time goes: for each worker count the
CPU seconds of every thread (from ``/proc``), the wall time outside the
compiled batch driver (the serial part: checking the variants, the members'
rows, the step rule, the shared reference) and the serial fraction that
Amdahl's law gives for the measured speed-up.

The lean hand-fused baseline of ``bench_fastpath.py`` (one 10 s run, signals
included) is timed in the same rounds, interleaved, and the ratios are of the
fastest of each, in wall time and in CPU time (all threads).  On a shared
machine the other cores may be busy: the load average is printed before and
after, and the speed-ups of more workers are only as good as the free cores.
``--numpy`` adds the numpy batch (``engine="fast"``, one process) for scale.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time

import numpy as np

import blocks
from blocks.engines.compiled.batch import available_cores
from blocks.figure2.batch import Variants, simulate_batch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import machine, max_rss_mb, peak_memory, print_and_save, table, time_interleaved  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

#: Targets (issue 28): 1000 members, default call, at most this many lean runs by wall time on 2 cores (stretch),
#: two workers at least this much faster than one, set-up of 1000 members at most this many seconds, and a single
#: compiled run at most this fraction of a lean run.
TARGET_LEAN_RUNS, STRETCH_LEAN_RUNS = 3.0, 2.0
TARGET_TWO_WORKERS = 1.7
TARGET_SETUP_S = 0.1
TARGET_SINGLE = 0.012
#: Calls of the single compiled run in a row per round (its fastest is the run after warm-up).
SINGLE_CALLS = 10
_SCALED = ("m1", "m2", "m3", "m4", "I1", "I2", "I3", "I4")


def paper_variants(n: int, seed: int = 2024) -> dict:
    """N Monte Carlo variants of the paper scenario, as columns of dotted keys."""
    rng = np.random.default_rng(seed)
    f_r = np.array(blocks.load_scenario("paper").disturbance.f_r)
    cols = {f"nominal_scale.{k}": rng.uniform(0.9, 1.1, n) for k in _SCALED}
    cols["gains.kp"] = rng.uniform(120.0, 250.0, n)
    cols["gains.kd"] = rng.uniform(30.0, 45.0, n)
    cols["disturbance.f_r"] = f_r * rng.uniform(0.5, 2.0, (n, 1))
    return cols


def thread_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process by thread id, from /proc (empty elsewhere)."""
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    out = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / ticks      # utime, stime (fields 14, 15)
    return out


def per_thread(fn, rounds: int = 3) -> dict:
    """Where one call's CPU goes: the fastest of ``rounds`` calls of ``fn`` by wall time, with the CPU seconds of
    each thread that ran (main thread first; /proc's clock ticks of 10 ms), and the part of the wall time spent
    outside the compiled batch driver (``rk4_batch`` / ``dopri_batch``: the serial part, timed around the
    driver's call)."""
    from blocks.engines.compiled import codegen
    inside = [0.0]
    wrapped = []
    for module, _ in list(codegen._modules.values()):
        for name in ("rk4_batch", "dopri_batch"):
            driver = getattr(module, name, None)
            if driver is None:
                continue

            def timed(*args, driver=driver):
                t0 = time.perf_counter()
                try:
                    return driver(*args)
                finally:
                    inside[0] += time.perf_counter() - t0
            setattr(module, name, timed)
            wrapped.append((module, name, driver))
    best = None
    try:
        for _ in range(rounds):
            inside[0] = 0.0
            before, t0 = thread_cpu(), time.perf_counter()
            fn()
            wall, after = time.perf_counter() - t0, thread_cpu()
            if best is None or wall < best["wall_s"]:
                main = threading.get_native_id()
                cpu = {tid: after[tid] - before.get(tid, 0.0) for tid in after}
                busy = [cpu.pop(main, 0.0)] + sorted((c for c in cpu.values() if c > 0), reverse=True)
                best = {"wall_s": wall, "driver_wall_s": inside[0], "serial_wall_s": wall - inside[0],
                        "thread_cpu_s": busy}
    finally:
        for module, name, driver in wrapped:
            setattr(module, name, driver)
    return best


def run(members: int = 1000, repeats: int = 5, scenario: str = "paper", numpy_batch: bool = False) -> dict:
    s = blocks.load_scenario(scenario)
    short = s.with_changes({"simulation.t_final": 2 * s.simulation.output_step})
    cols = paper_variants(members)
    cores = available_cores()

    def batch(workers=None, metrics=None, engine="auto", method=None, base=s):
        return simulate_batch(base, Variants(base, cols), workers=workers, metrics=metrics, engine=engine,
                              method=method)

    load_before = os.getloadavg()
    first = batch()                                              # warm-up (loads or compiles); the steps used
    batch(method="RK45")
    hand_fused(s)
    blocks.simulate(s, engine="compiled")
    cases = {"lean": lambda: hand_fused(s), "default call": batch}
    for k in range(1, cores + 1):
        cases[f"workers={k}"] = lambda k=k: batch(k)
    cases["RK45"] = lambda: batch(method="RK45")
    cases["set-up"] = lambda: batch(base=short)
    cases["single compiled run, cold"] = lambda: blocks.simulate(s, engine="compiled")
    warm: list = []
    cases["single compiled run"] = lambda: warm.append(repeated(lambda: blocks.simulate(s, engine="compiled")))
    repeats_of = {}
    if numpy_batch:
        cases["numpy batch, one process"] = lambda: batch(1, engine="fast", method="RK4")
        repeats_of["numpy batch, one process"] = 1
    times = time_interleaved(cases, repeats, repeats_of, clock="both")
    best = {name: (min(w for w, _ in ts), min(c for _, c in ts)) for name, ts in times.items()}
    best["single compiled run"] = (min(w for w, _ in warm), min(c for _, c in warm))
    lean_wall, lean_cpu = best["lean"]
    one = best["workers=1"][0]
    threads = {k: per_thread(lambda k=k: batch(k)) for k in range(1, cores + 1)}
    memory = peak_memory(batch)
    return {"scenario": scenario, "members": members, "machine": machine(), "repeats": repeats, "cores": cores,
            "seconds": {name: {"wall_min": w, "cpu_min": c} for name, (w, c) in best.items()},
            "lean_runs_wall": {name: w / lean_wall for name, (w, c) in best.items()},
            "lean_runs_cpu": {name: c / lean_cpu for name, (w, c) in best.items()},
            "speedup": {k: one / best[f"workers={k}"][0] for k in range(1, cores + 1)},
            "serial_fraction": {k: serial_fraction(k, one / best[f"workers={k}"][0]) for k in range(2, cores + 1)},
            "threads": threads,
            "load_before": load_before, "load_average": os.getloadavg(), "steps": first.steps,
            "evaluations_mean": float(np.mean(first.evaluations)), "failed": int((~first.ok).sum()),
            "peak_python_heap_mb": memory, "max_rss_mb": max_rss_mb(),
            "targets": {"lean_runs": TARGET_LEAN_RUNS, "stretch": STRETCH_LEAN_RUNS, "two_workers": TARGET_TWO_WORKERS,
                        "setup_s": TARGET_SETUP_S, "single": TARGET_SINGLE}}


def repeated(fn, calls: int = SINGLE_CALLS) -> tuple[float, float]:
    """The fastest of ``calls`` calls of ``fn`` one after the other (wall s, CPU s): a run after warm-up, its code
    and data in the caches (the first call after other work, a garbage collection included, is timed as the
    ``cold`` case)."""
    out = []
    for _ in range(calls):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        out.append((time.perf_counter() - w0, time.process_time() - c0))
    return min(w for w, _ in out), min(c for _, c in out)


def serial_fraction(k: int, speedup: float) -> float:
    """Amdahl's serial fraction ``s`` that a speed-up on ``k`` workers implies: ``speedup = 1 / (s + (1 - s) / k)``."""
    return (k / speedup - 1.0) / (k - 1.0)


def report(r: dict) -> str:
    rows = [[name, f"{v['wall_min']:.4f}", f"{r['lean_runs_wall'][name]:.3f}", f"{v['cpu_min']:.4f}",
             f"{r['lean_runs_cpu'][name]:.3f}"] for name, v in r["seconds"].items()]
    t = r["targets"]
    verdict = lambda ok: "met" if ok else "NOT met"      # noqa: E731
    wall = r["lean_runs_wall"]["default call"]
    two = r["speedup"].get(2)
    setup = r["seconds"]["set-up"]["wall_min"]
    single = r["lean_runs_cpu"]["single compiled run"]
    curve = ", ".join(f"{k}: {x:.2f}x" for k, x in r["speedup"].items())
    return "\n".join([
        f"Scenario '{r['scenario']}', {r['members']} variants, default call: RK4 on one shared schedule "
        f"({r['steps']} steps), {r['failed']} diverged; fastest of {r['repeats']}; {r['cores']} cores; {r['machine']}",
        table(["what", "wall min s", "lean runs (wall)", "CPU min s", "lean runs (CPU)"], rows),
        f"scaling (wall time of 1 worker / k workers): {curve}; Amdahl's serial fraction implied: "
        + (", ".join(f"{k} workers {x:.2f}" for k, x in r["serial_fraction"].items()) or "-"),
        *(f"workers={k}: wall {t['wall_s']:.3f} s, of which {t['serial_wall_s']:.3f} s outside the parallel "
          f"driver ({t['serial_wall_s'] / t['wall_s']:.0%}); CPU s per thread (main first): "
          + ", ".join(f"{c:.2f}" for c in t["thread_cpu_s"]) for k, t in r["threads"].items()),
        f"default call: {wall:.2f} lean runs by wall time (target <= {t['lean_runs']:g}: {verdict(wall <= t['lean_runs'])}; "
        f"stretch {t['stretch']:g}: {verdict(wall <= t['stretch'])})",
        (f"two workers {two:.2f}x one (target >= {t['two_workers']:g}: {verdict(two >= t['two_workers'])})"
         if two is not None else "one core: no two-worker figure"),
        f"set-up of {r['members']} members (a run of two output steps, everything included): {setup:.3f} s "
        f"(target <= {t['setup_s']:g} s: {verdict(setup <= t['setup_s'])})",
        f"single compiled run (after warm-up: the fastest of {SINGLE_CALLS} in a row): {single:.4f} lean runs by CPU "
        f"time, {r['lean_runs_wall']['single compiled run']:.4f} by wall (target <= {t['single']:g}: "
        f"{verdict(single <= t['single'])}); cold (the first call after other work and a garbage collection): "
        f"{r['lean_runs_cpu']['single compiled run, cold']:.4f} by CPU time",
        f"peak heap (tracemalloc) {r['peak_python_heap_mb']:.0f} MB; process max RSS {r['max_rss_mb']:.0f} MB; "
        f"load average before {r['load_before'][0]:.2f}, after {r['load_average'][0]:.2f} "
        f"(1-minute; {r['load_average'][1]:.2f} over 5 minutes)"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--members", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--numpy", action="store_true", help="also time the numpy batch once")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    r = run(args.members, args.repeats, args.scenario, args.numpy)
    return print_and_save(report(r), r, args.json)


if __name__ == "__main__":
    sys.exit(main())
