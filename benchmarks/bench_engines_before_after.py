"""The engines of two source trees timed in one run, in turn: "the other engines no slower" after a change.

    python benchmarks/bench_engines_before_after.py --before /path/to/main --after . [--rounds 5] [--json out.json]

Each round starts one fresh process per tree (``PYTHONPATH`` = the tree, numba
cache per tree) that times, after a warm-up, every case once and prints its
seconds; the rounds alternate the trees, so that load on a shared machine hits
both alike, and the report takes the fastest of each case, in wall time and in
CPU time (of the process, all threads: what waiting for a busy core does not
inflate, the fairer figure on a loaded machine).  Every process also
times the lean hand-fused baseline of ``bench_fastpath.py`` (the same code in
both trees), so each case is given as lean runs as well.

Cases (the paper scenario): ``numpy single`` (``blocks.simulate(engine="fast")``,
10 s), ``python-control`` (``engine="python-control"``, 1 s), ``compiled single``
(10 s), ``numpy batch`` (100 Monte Carlo members of ``bench_batch.py``, one
process, 10 s), ``compiled batch`` (1000 members, both cores, 10 s).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

# The timing done inside each tree's process (kept to what both trees have: blocks.simulate, simulate_batch).
_CHILD = r"""
import json, os, sys, time
sys.path.insert(0, os.path.join(os.environ["TREE"], "benchmarks"))
import blocks
from blocks.figure2.batch import Variants, simulate_batch
from bench_batch import paper_variants
from bench_fastpath import hand_fused
s = blocks.load_scenario("paper")
short = s.replace(simulation={"t_final": 1.0})
small, large = paper_variants(100), paper_variants(1000)
cases = {
    "lean": lambda: hand_fused(s),
    "numpy single": lambda: blocks.simulate(s, engine="fast"),
    "python-control (1 s)": lambda: blocks.simulate(short, engine="python-control"),
    "compiled single": lambda: blocks.simulate(s, engine="compiled"),
    "numpy batch (100)": lambda: simulate_batch(s, Variants(s, small), engine="fast", workers=1),
    "compiled batch (1000)": lambda: simulate_batch(s, Variants(s, large), engine="compiled", workers=2),
}
for fn in cases.values():       # warm-up: numba caches, prepared loops
    fn()
out = {}
for name, fn in cases.items():
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    out[name] = [time.perf_counter() - w0, time.process_time() - c0]
print(json.dumps(out))
"""


def one_round(tree: str, cache: str) -> dict:
    env = dict(os.environ, PYTHONPATH=tree, TREE=tree, DOBKIT_CACHE_DIR=cache)
    done = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", required=True, help="the source tree before the change")
    parser.add_argument("--after", default=".", help="the source tree after the change")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cache-before", help="numba cache folder of the tree before (default: one in TMPDIR)")
    parser.add_argument("--cache-after", help="numba cache folder of the tree after (default: one in TMPDIR)")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    trees = {"before": os.path.abspath(args.before), "after": os.path.abspath(args.after)}
    tmp = os.environ.get("TMPDIR", "/tmp")
    caches = {"before": args.cache_before or os.path.join(tmp, "dobkit-bench-cache-before"),
              "after": args.cache_after or os.path.join(tmp, "dobkit-bench-cache-after")}
    times: dict = {name: {} for name in trees}
    loads = []
    for _ in range(args.rounds):
        for name, tree in trees.items():
            for case, seconds in one_round(tree, caches[name]).items():
                times[name].setdefault(case, []).append(seconds)
            loads.append(os.getloadavg()[0])
    best = {name: {case: [min(w for w, _ in ts), min(c for _, c in ts)] for case, ts in cases.items()}
            for name, cases in times.items()}
    lines = [f"fastest of {args.rounds} rounds; load average (1 min) during the rounds {min(loads):.2f} to "
             f"{max(loads):.2f}",
             "| case | before wall s | after wall s | before CPU s | after CPU s | after / before (CPU) | "
             "before lean runs (CPU) | after lean runs (CPU) |", "|---|---|---|---|---|---|---|---|"]
    lean_b, lean_a = best["before"]["lean"][1], best["after"]["lean"][1]
    for case in best["before"]:
        (bw, bc), (aw, ac) = best["before"][case], best["after"][case]
        lines.append(f"| {case} | {bw:.3f} | {aw:.3f} | {bc:.3f} | {ac:.3f} | {ac / bc:.2f} | {bc / lean_b:.2f} | "
                     f"{ac / lean_a:.2f} |")
    print("\n".join(lines))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"trees": trees, "times": times, "best": best, "load_average": loads}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
