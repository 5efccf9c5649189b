"""The whole ``dobkit simulate`` of the paper in lean simulation runs, and the share of its outputs.

    PYTHONPATH=. python benchmarks/bench_simulate_command.py [--repeats 3] [--json out.json]

Issue 21's target: the whole command (both runs, metrics, time series, Figures 4-8 as PNG, Table 3) at most
30 lean runs.  Each round runs, in turn: the lean hand-fused numpy loop of ``bench_fastpath.py`` in this
process (fastest of 3), ``python -m dobkit simulate`` in a new process, and the same with ``--no-figures``
(the compiled engine's cache warm: run the command once before).  CPU time of the child processes (user +
system) is read from :func:`resource.getrusage`, so waiting for a core on a shared machine does not count.
The figures' share is the difference of the two commands.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

import blocks  # noqa: E402


def _child_cpu(argv: list[str]) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _lean(scenario) -> float:
    best = float("inf")
    for _ in range(3):
        c0 = time.process_time()
        hand_fused(scenario)
        best = min(best, time.process_time() - c0)
    return best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=None, help="also write the numbers to this file")
    args = parser.parse_args(argv)

    scenario = blocks.load_scenario("paper")
    times = {"lean": [], "whole": [], "no_figures": []}
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "out"
        command = [sys.executable, "-m", "dobkit", "simulate", "--out", str(out)]
        _child_cpu(command)                          # warm the compiled engine's cache
        for _ in range(args.repeats):
            times["lean"].append(_lean(scenario))
            for key, extra in (("whole", []), ("no_figures", ["--no-figures"])):
                shutil.rmtree(out, ignore_errors=True)
                times[key].append(_child_cpu(command + extra))
    lean = min(times["lean"])
    best = {key: min(values) for key, values in times.items()}
    best["figures"] = best["whole"] - best["no_figures"]
    names = {"lean": "lean hand-fused numpy run (baseline)", "whole": "dobkit simulate (paper, PNG figures)",
             "no_figures": "dobkit simulate --no-figures", "figures": "Figures 4-8 (the difference)"}
    rows = [[names[key], f"{value:.2f}", f"{value / lean:.1f}"] for key, value in best.items()]
    print(table(["case", "CPU min s", "lean runs"], rows))
    print(f"target: whole command <= 30 lean runs: {'met' if best['whole'] <= 30 * lean else 'not met'}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cpu_min_s": best, "lean_runs": {k: v / lean for k, v in best.items()},
                                               "all": times}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
