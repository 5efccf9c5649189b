"""First compiled run of a URDF arm's loop with a fresh cache: numba's compile time against its estimate.

    PYTHONPATH=. python benchmarks/bench_urdf_compile.py [--arms panda ur5] [--inlined]

Each arm's built-in scenario (``panda``, ``ur5``, ``scope4``, ``paper``; or ``example:NAME`` for any example arm, in
its default scenario) runs once with ``engine="compiled"`` in a new Python process whose ``DOBKIT_CACHE_DIR`` is an
empty folder, so the run compiles every function it calls; its CPU time (``time.process_time`` of the child, almost
all numba: the run itself takes milliseconds) is printed beside the generated lines, the estimate of
:func:`blocks.engines.compiled.compile_estimate.estimate_compile_seconds` and the budget ``engine="auto"`` compiles within
(:data:`~blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS`).  With ``--inlined`` each arm runs a second time
with ``blocks.engines.compiled.codegen.ARM_CALLS`` off (M and h inlined into every function, as before): the baseline the
called functions are measured against (ratio called / inlined).  Targets (issue 30): the Panda <= 15 s of CPU
(stretch 8), and the estimate holding (measured <= estimate) for it.  The machine's load is printed: on a shared
machine the wall time is much longer than the CPU time.  No assertion: these are timings.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402

_CHILD = r"""
import json, re, sys, time
t_start = time.process_time()
from blocks import load_scenario, simulate
from blocks.engines.compiled import codegen
codegen.ARM_CALLS = sys.argv[2] == "1"
from blocks.engines.compiled.compile_estimate import estimate_compile_seconds
from blocks.engines.compiled.engine import CompiledLoopEngine
from blocks.figure2.loop import _prepared
name = sys.argv[1]
if name.startswith("example:"):
    from blocks.scenarios.scenario import scenario_from_dict
    s = scenario_from_dict({"arm": {"urdf": name}})
else:
    s = load_scenario(name)
engine = CompiledLoopEngine(_prepared(s, True).loop)
lines = engine.generated_lines
t0, w0 = time.process_time(), time.perf_counter()
simulate(s, engine="compiled")
first, wall = time.process_time() - t0, time.perf_counter() - w0
t0 = time.process_time()
simulate(s, engine="compiled")
second = time.process_time() - t0
print(json.dumps({"lines": lines, "first_s": first, "wall_s": wall, "second_s": second, "cached": engine.cached,
                  "estimate_s": estimate_compile_seconds(lines)}))
"""


def run_child(name: str, calls: bool) -> dict:
    """One first run in a new process with an empty cache folder: lines, CPU and wall seconds, estimate."""
    with tempfile.TemporaryDirectory(prefix="dobkit-bench-compile-") as cache:
        env = dict(os.environ, DOBKIT_CACHE_DIR=cache)
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        out = subprocess.run([sys.executable, "-c", _CHILD, name, "1" if calls else "0"], env=env,
                             capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _load(values) -> str:
    return " ".join(f"{v:.2f}" for v in values)


def main(argv=None) -> int:
    from blocks.engines.compiled.compile_estimate import AUTO_COMPILE_SECONDS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=["panda", "ur5"],
                        help="built-in scenarios or example:NAME (default: panda ur5)")
    parser.add_argument("--inlined", action="store_true", help="also each arm with M and h inlined (the baseline)")
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    rows = []
    for name in args.arms:
        called = run_child(name, True)
        inlined = run_child(name, False) if args.inlined else None
        row = [name, f"{called['lines']:,}", f"{called['first_s']:.1f}", f"{called['estimate_s']:.1f}",
               "yes" if called["first_s"] <= called["estimate_s"] else "NO",
               "yes" if called["estimate_s"] <= AUTO_COMPILE_SECONDS else "no",
               f"{called['wall_s']:.1f}", f"{called['second_s'] * 1e3:.1f}"]
        if inlined is not None:
            row += [f"{inlined['lines']:,}", f"{inlined['first_s']:.1f}", f"{inlined['estimate_s']:.1f}",
                    f"{called['first_s'] / inlined['first_s']:.2f}"]
        rows.append(row)
    print(f"load average (1, 5, 15 min) {_load(load_start)} at the start, {_load(os.getloadavg())} now, on "
          f"{os.cpu_count()} cores")
    header = ["arm", "lines (M, h called)", "first run CPU (s)", "estimate (s)", "estimate holds",
              f"auto compiles (<= {AUTO_COMPILE_SECONDS:g} s)", "first run wall (s)", "cached run CPU (ms)"]
    if args.inlined:
        header += ["lines (inlined)", "first run CPU, inlined (s)", "estimate, inlined (s)", "called / inlined"]
    print(table(header, rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
