"""The digital controller's loop (paper-digital, 10 s at 1 kHz) against a lean continuous numpy run of the same scenario.

    PYTHONPATH=. python benchmarks/bench_sampled.py [--repeats 9] [--numpy-repeats 1] [--members 200] [--json out.json]

Cases, timed in turn (interleaved) in one run, CPU time and wall time:

* ``lean continuous``: the baseline of every ratio, :func:`bench_fastpath.hand_fused` on the same
  scenario: its continuous Figure-2 loop (no sampling) as one hand-written right-hand side, integrated
  by ``solve_ivp`` (RK45, the scenario's tolerances), signals computed afterwards;
* ``compiled sampled``: ``blocks.simulate(s, engine="compiled")``, the whole call (the loop's set-up,
  the run, the lumped disturbance and the response);
* ``numpy sampled``: ``blocks.simulate(s, engine="fast")``, the numpy hybrid engine (scipy's RK45
  restarted at every tick); slow, so ``--numpy-repeats`` times only;
* ``compiled sampled batch``: :func:`blocks.compiled.sampled.simulate_sampled_batch` over
  ``--members`` measurement-noise seeds (the scenario with position and velocity noise), members on
  both cores; its ratio is per member and by wall time as well.

Target (issue 17): the compiled sampled run at most 0.2 x one lean continuous run (CPU time, fastest of each).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

import blocks

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, bench_fastpath, run from anywhere
from _timing import machine, max_rss_mb, print_and_save, summary, table, time_interleaved  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

#: The compiled sampled run's target, as a multiple of one lean continuous run (issue 17).
TARGET = 0.2
#: Measurement noise of the batch's members (rad, rad, m, rad; per second the same).
NOISE = {"noise.q_std": [1e-4, 1e-4, 1e-5, 1e-4], "noise.dq_std": [1e-3, 1e-3, 1e-4, 1e-3]}


def run(scenario: str = "paper-digital", repeats: int = 9, numpy_repeats: int = 1, members: int = 200) -> dict:
    """Time the cases and return the figures (seconds, ratios, agreement)."""
    from blocks.compiled.sampled import simulate_sampled_batch
    s = blocks.load_scenario(scenario)
    noisy = s.with_changes(NOISE)
    seeds = list(range(members))
    t0 = time.perf_counter()
    compiled = blocks.simulate(s, engine="compiled")          # compiles, or loads numba's cache
    first_call = time.perf_counter() - t0
    t0 = time.perf_counter()
    simulate_sampled_batch(noisy, seeds=seeds[:2])
    batch_first_call = time.perf_counter() - t0
    cases = {
        "lean continuous": lambda: hand_fused(s),
        "compiled sampled": lambda: blocks.simulate(s, engine="compiled"),
        "numpy sampled": lambda: blocks.simulate(s, engine="fast"),
    }
    if members:
        cases["compiled sampled batch"] = lambda: simulate_sampled_batch(noisy, seeds=seeds)
    numpy_run = cases["numpy sampled"]()
    agreement = float(np.max(np.abs(compiled.outputs - numpy_run.outputs)))
    times = time_interleaved(cases, repeats, {"numpy sampled": numpy_repeats}, clock="both")
    out = {"scenario": scenario, "machine": machine(), "repeats": repeats, "members": members,
           "compiled_first_call_s": first_call, "batch_first_call_s": batch_first_call, "target": TARGET,
           "agreement_outputs_max_abs": agreement, "max_rss_mb": max_rss_mb(), "load_average": os.getloadavg()}
    for k, clock in enumerate(("wall", "cpu")):
        best = {name: summary([t[k] for t in ts]) for name, ts in times.items()}
        lean = times["lean continuous"]
        paired = {name: statistics.median([a[k] / b[k] for a, b in zip(ts, lean)]) for name, ts in times.items()}
        out[clock] = {"seconds": {name: {"min": b[0], "median": b[1]} for name, b in best.items()},
                      "ratio_min": {name: b[0] / best["lean continuous"][0] for name, b in best.items()},
                      "ratio_paired_median": paired}
    return out


def report(r: dict) -> str:
    lines = [f"Scenario '{r['scenario']}' (10 s at 1 kHz unless changed); {r['machine']}"]
    header = ["case", "CPU min s", "CPU ratio (min)", "CPU ratio (paired median)", "wall min s", "wall ratio (min)"]
    rows = [[name, f"{r['cpu']['seconds'][name]['min']:.4f}", f"{r['cpu']['ratio_min'][name]:.3f}",
             f"{r['cpu']['ratio_paired_median'][name]:.3f}", f"{r['wall']['seconds'][name]['min']:.4f}",
             f"{r['wall']['ratio_min'][name]:.3f}"] for name in r["cpu"]["seconds"]]
    ratio = r["cpu"]["ratio_min"]["compiled sampled"]
    lines += [table(header, rows),
              f"compiled sampled run {ratio:.3f} x one lean continuous run (target <= {r['target']}: "
              f"{'met' if ratio <= r['target'] else 'NOT met'}); numpy sampled "
              f"{r['cpu']['ratio_min']['numpy sampled']:.1f} x",
              f"first compiled call in this process {r['compiled_first_call_s']:.2f} s (compile or cache load); "
              f"the batch's first call {r['batch_first_call_s']:.2f} s",
              f"compiled vs numpy sampled engine, outputs: max abs difference {r['agreement_outputs_max_abs']:.1e}",
              f"process max RSS {r['max_rss_mb']:.0f} MB; load average during the run {r['load_average'][0]:.2f}"]
    if "compiled sampled batch" in r["cpu"]["seconds"]:
        m = r["members"]
        lines.append(f"batch of {m} noise seeds: {r['wall']['ratio_min']['compiled sampled batch'] / m:.3f} lean "
                     f"runs per member by wall time, {r['cpu']['ratio_min']['compiled sampled batch'] / m:.3f} by CPU "
                     f"time (all threads); {r['wall']['ratio_min']['compiled sampled batch']:.1f} lean runs in all")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="paper-digital")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--numpy-repeats", type=int, default=1, help="repeats of the (slow) numpy sampled engine")
    parser.add_argument("--members", type=int, default=200, help="members of the batch case (0: none)")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    r = run(args.scenario, args.repeats, args.numpy_repeats, args.members)
    return print_and_save(report(r), r, args.json)


if __name__ == "__main__":
    sys.exit(main())
