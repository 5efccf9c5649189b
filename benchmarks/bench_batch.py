"""Batched simulation: N variants of the paper's 10 s scenario (default N = 1000) against one lean-baseline run.

    PYTHONPATH=. python benchmarks/bench_batch.py [--members 1000] [--repeats 5] [--numpy] [--json out.json]

The variants are a Monte Carlo draw (fixed seed) of the kind a robustness study
uses: every nominal-model mass and inertia scaled by U(0.9, 1.1), Kp ~ U(120, 250),
Kd ~ U(30, 45) and the Eq. 4 amplitudes scaled by U(0.5, 2).  Timed: validating
the variants plus :func:`blocks.batch.simulate_batch` with the compiled engine
(the default with numba) keeping all seven metrics and no signals, on both
cores (``workers=2``) and on one, and keeping only ``rms_position_error``.
The lean hand-fused baseline of ``bench_fastpath.py`` (one 10 s run, signals
included) is timed in the same rounds, interleaved, and the ratios are of the
fastest of each.  The target is at most 5 lean runs for the 1000 variants.

Wall time is what "both cores" buys, but on a shared machine the second core
may be busy: the report gives CPU time too (over all threads), and the ratio
of CPU time to the lean run's CPU time is what the batch would take on one
core.  ``--numpy`` adds the numpy batch (``engine="fast"``, one process) for scale.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import blocks
from blocks.batch import Variants, simulate_batch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import machine, max_rss_mb, peak_memory, print_and_save, table, time_interleaved  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

#: Target: 1000 variants, all metrics, both cores, in at most this many lean-baseline runs (issue 10).
TARGET_LEAN_RUNS = 5.0
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


def run(members: int = 1000, repeats: int = 5, scenario: str = "paper", numpy_batch: bool = False) -> dict:
    s = blocks.load_scenario(scenario)
    cols = paper_variants(members)

    def batch(workers=2, metrics=None, engine="auto"):
        return simulate_batch(s, Variants(s, cols), workers=workers, metrics=metrics, engine=engine)

    first = batch()                                              # warm-up (loads or compiles); the step used
    hand_fused(s)
    cases = {"lean": lambda: hand_fused(s), "two cores": batch, "one core": lambda: batch(1),
             "two cores, rms only": lambda: batch(metrics=("rms_position_error",))}
    repeats_of = {}
    if numpy_batch:
        cases["numpy batch, one process"] = lambda: batch(1, engine="fast")
        repeats_of["numpy batch, one process"] = 1
    times = time_interleaved(cases, repeats, repeats_of, clock="both")
    best = {name: (min(w for w, _ in ts), min(c for _, c in ts)) for name, ts in times.items()}
    lean_wall, lean_cpu = best["lean"]
    memory = peak_memory(batch)
    return {"scenario": scenario, "members": members, "machine": machine(), "repeats": repeats,
            "seconds": {name: {"wall_min": w, "cpu_min": c} for name, (w, c) in best.items()},
            "lean_runs_wall": {name: w / lean_wall for name, (w, c) in best.items()},
            "lean_runs_cpu": {name: c / lean_cpu for name, (w, c) in best.items()},
            "load_average": os.getloadavg(), "substeps": first.substeps, "steps": first.steps,
            "failed": int((~first.ok).sum()), "peak_python_heap_mb": memory, "max_rss_mb": max_rss_mb(),
            "target_lean_runs": TARGET_LEAN_RUNS}


def report(r: dict) -> str:
    rows = [[name, f"{v['wall_min']:.3f}", f"{r['lean_runs_wall'][name]:.2f}", f"{v['cpu_min']:.3f}",
             f"{r['lean_runs_cpu'][name]:.2f}"] for name, v in r["seconds"].items()]
    wall, cpu = r["lean_runs_wall"]["two cores"], r["lean_runs_cpu"]["two cores"]
    target = r["target_lean_runs"]
    return "\n".join([
        f"Scenario '{r['scenario']}', {r['members']} variants, RK4 with {r['substeps']} step(s) per output interval "
        f"({r['steps']} steps), {r['failed']} diverged; fastest of {r['repeats']}; {r['machine']}",
        table(["what", "wall min s", "lean runs (wall)", "CPU min s", "lean runs (CPU)"], rows),
        f"target <= {target:g} lean runs, all metrics, both cores: wall {wall:.2f} "
        f"({'met' if wall <= target else 'NOT met'}), CPU over all threads {cpu:.2f} "
        f"({'met' if cpu <= target else 'NOT met'}; the time on one free core)",
        f"peak heap (tracemalloc) {r['peak_python_heap_mb']:.0f} MB; process max RSS {r['max_rss_mb']:.0f} MB; "
        f"load average during the run {r['load_average'][0]:.2f}"])


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
