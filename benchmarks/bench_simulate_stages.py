"""Where the CPU of ``dobkit simulate`` goes, stage by stage, in lean simulation runs.

    PYTHONPATH=. python benchmarks/bench_simulate_stages.py [--repeats 3] [--no-figures] [--json out.json]

Each repeat runs the paper's whole command (``dobkit.cli.main``, compiled engine, cache warm: run the command once
before) in a new process that stamps its CPU time (:func:`time.process_time`) as it goes:

* ``start-up``: from the process's start to the command line imported (interpreter, numpy, ``dobkit.cli``);
* ``python-control, scipy, matplotlib``: importing :mod:`analysis.simulation.experiment` (python-control imports
  scipy.signal and matplotlib.pyplot);
* ``run with / without observer``: each :func:`blocks.simulate` call (the first one imports numba and loads the
  compiled loop from numba's cache);
* ``time series``, ``figures (each)``: writing ``timeseries.csv`` and Figures 4-8;
* ``rest``: parsing, the scenario, metrics, JSON, TOML, the printed table;
* ``interpreter shutdown``: from the command's return to the process's end (``getrusage`` of the child);
* ``of which cycle collection``: time inside Python's cycle collector, wherever it ran (zero since the command
  switches it off).

The table gives the fastest of ``--repeats`` for each stage and its share in lean runs: the lean hand-fused numpy
run of ``bench_fastpath.py``, timed in this process (fastest of 3), as ``bench_simulate_command.py`` does.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

import blocks  # noqa: E402

# The child: stamps CPU time around the stages of the real command and prints them as JSON on its last line.
_CHILD = r"""
import builtins, gc, json, sys, time
clock = time.process_time
marks, runs, each, collector, started = {"series": 0.0, "imports": 0.0}, [], [], [0.0], []
def _gc(phase, info):
    if phase == "start":
        started.append(clock())
    elif started:
        collector[0] += clock() - started.pop()
gc.callbacks.append(_gc)

def instrument(name, module):
    # wrap the stages of the command's own modules as the command imports them
    if name.endswith("experiment"):
        simulate, write = module.simulate, module._write_timeseries
        def timed_simulate(*args, **kwargs):
            c = clock(); result = simulate(*args, **kwargs); runs.append(clock() - c); return result
        def timed_series(*args):
            c = clock(); write(*args); marks["series"] = clock() - c
        module.simulate, module._write_timeseries = timed_simulate, timed_series
    else:
        draw = module.paper_figures
        def timed_figures(*args, **kwargs):
            stamps = [clock()]
            out = draw(*args, progress=lambda f: stamps.append(clock()), **kwargs)
            each.extend(b - a for a, b in zip(stamps, stamps[1:]))
            return out
        module.paper_figures = timed_figures

real_import = builtins.__import__
def hooked(name, globals=None, locals=None, fromlist=(), level=0):
    if name in ("analysis.simulation.experiment", "analysis.simulation.figures") and name not in sys.modules:
        c = clock()
        module = real_import(name, globals, locals, fromlist, level)
        if name.endswith("experiment"):
            marks["imports"] = clock() - c           # python-control, scipy, matplotlib come in here
        instrument(name, sys.modules[name])
        return module
    return real_import(name, globals, locals, fromlist, level)
builtins.__import__ = hooked

import dobkit.cli
marks["startup"] = c1 = clock()                     # CPU since the process started
sys.argv = ["dobkit", *sys.argv[1:]]
status = dobkit.cli.main()                           # as the dobkit program runs it (then the process ends)
marks["end"] = clock()
marks["command"] = marks["end"] - c1
marks["runs"], marks["figures"], marks["collector"] = runs, each, collector[0]
print(json.dumps(marks))
sys.exit(status)
"""


def _child(argv: list[str]) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, "-c", _CHILD, *argv], check=True, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    marks = json.loads(done.stdout.strip().splitlines()[-1])
    marks["total"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return marks


def _stages(m: dict) -> dict[str, float]:
    runs, figs = m["runs"], m["figures"]
    stages = {"start-up: interpreter, numpy, dobkit.cli": m["startup"],
              "python-control, scipy, matplotlib": m["imports"],
              "run with observer (numba, cache, run)": runs[0], "run without observer": runs[1],
              "time series (CSV)": m["series"]}
    names = ("Figure 4", "Figure 5", "Figure 6", "Figure 7", "Figure 8 (3-D)")
    stages.update({name: value for name, value in zip(names, figs)})
    stages["rest (parse, scenario, metrics, JSON, table)"] = (m["command"] - m["imports"] - sum(runs) - m["series"]
                                                               - sum(figs))
    stages["interpreter shutdown"] = m["total"] - m["end"]
    stages["whole command"] = m["total"]
    stages["of which cycle collection"] = m["collector"]
    return stages


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--json", default=None, help="also write the numbers to this file")
    args = parser.parse_args(argv)

    scenario = blocks.load_scenario("paper")
    lean, best = float("inf"), {}
    with tempfile.TemporaryDirectory() as folder:
        for r in range(args.repeats):
            for _ in range(3):
                c0 = time.process_time()
                hand_fused(scenario)
                lean = min(lean, time.process_time() - c0)
            out = Path(folder) / f"out{r}"
            command = ["simulate", "--out", str(out)] + (["--no-figures"] if args.no_figures else [])
            for name, value in _stages(_child(command)).items():
                best[name] = min(best.get(name, float("inf")), value)
    rows = [[name, f"{value:.3f}", f"{value / lean:.1f}"] for name, value in best.items()]
    print(table(["stage (fastest of each)", "CPU s", "lean runs"], rows))
    print(f"lean hand-fused numpy run: {lean:.3f} s CPU; load average {os.getloadavg()[0]:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cpu_min_s": best, "lean_s": lean}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
