"""How fast the command line starts: ``dobkit --version`` and a refused scenario against ``import numpy``.

    PYTHONPATH=. python benchmarks/bench_startup.py [--repeats 7] [--json out.json]

Each case is a new Python process, started in turn with the others (so that
load on a shared machine hits them alike), ``--repeats`` times; the table
shows the fastest and median wall time and the child's CPU time (user +
system, from ``getrusage``), and the ratio of each to ``python -c "import
numpy"``.  The target of issue 21: ``--version`` at most 5 x ``import numpy``.
It also lists which heavy libraries ``import dobkit.cli`` loads (none should).

Cases:

* ``import numpy``: the yardstick;
* ``dobkit --version``: ``python -m dobkit --version``;
* ``refused scenario``: ``python -m dobkit simulate --scenario BAD.toml``,
  a scenario with ``t_final = -1``: the time until the user reads the error.
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
from _timing import summary, table  # noqa: E402

HEAVY = ("control", "scipy", "matplotlib", "numba", "fmpy", "dask", "pandas", "jinja2")


def _run(argv: list[str], expect: int) -> tuple[float, float]:
    """Wall and CPU seconds of one child process (CPU: its user + system time)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != expect:
        raise SystemExit(f"{' '.join(argv)} exited {done.returncode}, expected {expect}:\n{done.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def heavy_modules_at_import() -> list[str]:
    """The heavy libraries a fresh ``import dobkit.cli`` loads."""
    code = f"import sys, dobkit.cli; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    return [m for m in out.split(",") if m]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", default=None, help="also write the numbers to this file")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as folder:
        bad = Path(folder) / "bad.toml"
        bad.write_text("[simulation]\nt_final = -1\n")
        cases = {
            "import numpy": ([sys.executable, "-c", "import numpy"], 0),
            "dobkit --version": ([sys.executable, "-m", "dobkit", "--version"], 0),
            "refused scenario": ([sys.executable, "-m", "dobkit", "simulate", "--scenario", str(bad),
                                  "--out", str(Path(folder) / "never")], 2),
        }
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
        for _ in range(args.repeats):
            for name, (cmd, expect) in cases.items():
                times[name].append(_run(cmd, expect))

    base_wall = min(w for w, _ in times["import numpy"])
    base_cpu = min(c for _, c in times["import numpy"])
    rows, numbers = [], {}
    for name, values in times.items():
        wall_min, wall_median = summary([w for w, _ in values])
        cpu_min = min(c for _, c in values)
        numbers[name] = {"wall_min_s": wall_min, "wall_median_s": wall_median, "cpu_min_s": cpu_min,
                         "wall_ratio": wall_min / base_wall, "cpu_ratio": cpu_min / base_cpu}
        rows.append([name, f"{wall_min:.3f}", f"{wall_median:.3f}", f"{cpu_min:.3f}", f"{wall_min / base_wall:.2f}",
                     f"{cpu_min / base_cpu:.2f}"])
    print(table(["case", "wall min s", "wall median s", "CPU min s", "ratio (wall)", "ratio (CPU)"], rows))
    heavy = heavy_modules_at_import()
    print(f"heavy libraries loaded by 'import dobkit.cli': {', '.join(heavy) if heavy else 'none'}")
    ratio = numbers["dobkit --version"]["wall_ratio"]
    print(f"dobkit --version / import numpy: {ratio:.2f} x (target <= 5: {'met' if ratio <= 5 else 'NOT met'})")
    if args.json:
        Path(args.json).write_text(json.dumps({"cases": numbers, "heavy_at_import": heavy}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
