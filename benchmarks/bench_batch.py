"""Batched simulation: N variants of the paper's 10 s scenario as one vectorised ODE (default N = 1000).

    PYTHONPATH=. python benchmarks/bench_batch.py [--members 1000] [--repeats 3] [--json out.json]

The variants are a Monte Carlo draw (fixed seed) of the kind a robustness study
uses: every nominal-model mass and inertia scaled by U(0.9, 1.1), Kp ~ U(120, 250),
Kd ~ U(30, 45) and the Eq. 4 amplitudes scaled by U(0.5, 2).  Timed: validating
the variants plus :func:`blocks.batch.simulate_batch` keeping the default
metrics (all seven, no signals), in one process and in two (``workers=2``, both
cores; what ``dobkit sweep`` does by default).  Peak memory is measured in a
separate one-process run with :mod:`tracemalloc`.  For scale, the table also
shows N times one single run of the fast path (timed once).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

import blocks
from blocks.batch import Variants, simulate_batch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import print_and_save, machine, max_rss_mb, peak_memory, summary, table, time_interleaved  # noqa: E402

#: Target (s) for 1000 variants on the 2-core machine (issue "Speed and scale").
TARGET_SECONDS = 3.0
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


def run(members: int = 1000, repeats: int = 3, scenario: str = "paper") -> dict:
    s = blocks.load_scenario(scenario)
    cols = paper_variants(members)

    def batch(workers=1, metrics=None):
        return simulate_batch(s, Variants(s, cols), workers=workers, metrics=metrics)

    first = batch()                                              # warm-up; also the step actually used
    all_times = time_interleaved({"batch": batch, "two": lambda: batch(2),
                                  "rms only": lambda: batch(metrics=("rms_position_error",))}, repeats, clock="both")
    rms_only = min(w for w, _ in all_times["rms only"])
    times = [w for w, _ in all_times["batch"]]
    cpu = [c for _, c in all_times["batch"]]
    two = [w for w, _ in all_times["two"]]          # wall only: the work is in the child processes
    memory = peak_memory(batch)
    t0 = time.perf_counter()
    blocks.simulate(s, engine="fast")
    single = time.perf_counter() - t0
    best, median = summary(times)
    best2, median2 = summary(two)
    return {"scenario": scenario, "members": members, "machine": machine(), "seconds": times, "min": best,
            "median": median, "cpu_seconds": cpu, "cpu_min": min(cpu), "rms_only_min": rms_only, "two_process_seconds": two, "two_min": best2, "two_median": median2,
            "load_average": os.getloadavg(), "per_member_ms": 1e3 * best / members, "single_fast_s": single,
            "speedup_vs_single_fast": single * members / best, "substeps": first.substeps, "steps": first.steps,
            "failed": int((~first.ok).sum()), "peak_python_heap_mb": memory, "max_rss_mb": max_rss_mb(),
            "target_seconds": TARGET_SECONDS}


def report(r: dict) -> str:
    rows = [[f"{r['members']} variants, batched, one process", f"{r['min']:.2f}", f"{r['median']:.2f}",
             f"{r['cpu_min']:.2f}", f"{r['per_member_ms']:.2f}", f"{r['peak_python_heap_mb']:.0f}"],
            [f"{r['members']} variants, one process, only rms_position_error kept", f"{r['rms_only_min']:.2f}", "",
             "", f"{1e3 * r['rms_only_min'] / r['members']:.2f}", ""],
            [f"{r['members']} variants, batched, two processes (workers=2)", f"{r['two_min']:.2f}",
             f"{r['two_median']:.2f}", "", f"{1e3 * r['two_min'] / r['members']:.2f}", ""],
            [f"{r['members']} x one fast-path run (estimate)", f"{r['single_fast_s'] * r['members']:.0f}", "", "",
             f"{1e3 * r['single_fast_s']:.0f}", ""]]
    best = min(r["min"], r["two_min"])          # all seven metrics kept
    verdict = "met" if best < r["target_seconds"] else "NOT met"
    return "\n".join([
        f"Scenario '{r['scenario']}', RK4 with {r['substeps']} step(s) per output interval ({r['steps']} steps), "
        f"{r['failed']} diverged; {r['machine']}",
        table(["what", "wall min s", "wall median s", "CPU min s", "ms per member", "peak heap MB"], rows),
        f"target < {r['target_seconds']:.0f} s for 1000 variants on the 2-core machine: "
        f"{verdict if r['members'] == 1000 else 'n/a'} (one process {r['min']:.2f} s, two {r['two_min']:.2f} s); "
        f"one process is {r['speedup_vs_single_fast']:.0f}x the fast path run one by one",
        f"peak heap (one process, tracemalloc) {r['peak_python_heap_mb']:.0f} MB; process max RSS "
        f"{r['max_rss_mb']:.0f} MB; load average during the run {r['load_average'][0]:.2f}"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--members", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    r = run(args.members, args.repeats, args.scenario)
    return print_and_save(report(r), r, args.json)


if __name__ == "__main__":
    sys.exit(main())
