"""The times the README states, measured as a user meets them: each command in a new process, with the load.

    PYTHONPATH=. python benchmarks/bench_readme_times.py [--repeats 3] [--json out.json] [--skip-slow]

Every time or ratio the README gives for a command comes from this script's
output, quoted with the load it printed (``os.getloadavg()`` before and after
each case, and the number of cores).  The commands run in a fresh temporary
folder, as the README's blocks do, with the ``dobkit`` of this interpreter.

Cases (wall time of the whole command, the fastest of ``--repeats`` for the
short ones, one run of the long ones):

* ``import numpy`` and ``dobkit --version``: the start-up ratio;
* ``dobkit simulate`` of the paper scenario with its figures (the quick start's command);
* ``dobkit report --quick`` and ``dobkit report``;
* ``dobkit sweep`` of the README's 100-run Monte Carlo file;
* ``dobkit tune paper-tune --max-evaluations 100 --no-progress``.

numba present or not is printed: the README states both where they differ.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402

MC_TOML = """scenario = "paper"
[grid]
"gains.kp" = [100, 180]
[monte_carlo]
runs = 50
seed = 1
[monte_carlo.distributions]
"nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
"disturbance.f_r[2]" = {kind = "normal", mean = 1.4, std = 0.2}
"""


def _dobkit() -> list[str]:
    """The dobkit command of this interpreter (the console script beside it, else ``python -m dobkit``)."""
    script = Path(sys.executable).parent / "dobkit"
    return [str(script)] if script.exists() else [sys.executable, "-m", "dobkit"]


def _timed(argv: list[str], cwd: Path) -> float:
    """Wall seconds of one command; a failure stops the benchmark with the command's own words."""
    start = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return wall


def _case(name: str, argv_of, repeats: int, folder: Path) -> dict:
    """Run one case ``repeats`` times (``argv_of(i)`` gives the i-th command line) with the load around it."""
    load_before = os.getloadavg()[0]
    walls = [_timed(argv_of(i), folder) for i in range(repeats)]
    load_after = os.getloadavg()[0]
    return {"case": name, "wall_s": min(walls), "repeats": repeats,
            "load": round(max(load_before, load_after), 2)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeats of the short cases (default 3)")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--skip-slow", action="store_true", help="leave out the full report and the tuning")
    args = parser.parse_args()

    try:
        import numba  # noqa: F401
        has_numba = True
    except ImportError:
        has_numba = False
    dobkit = _dobkit()
    folder = Path(tempfile.mkdtemp(prefix="bench-readme-"))
    try:
        (folder / "mc.toml").write_text(MC_TOML, encoding="utf-8")
        short = max(1, args.repeats)
        rows = [
            _case("python -c 'import numpy'", lambda i: [sys.executable, "-c", "import numpy"], short + 2, folder),
            _case("dobkit --version", lambda i: [*dobkit, "--version"], short + 2, folder),
            _case("dobkit simulate (paper, figures)", lambda i: [*dobkit, "simulate", "--out", f"paper-run-{i}"],
                  short, folder),
            _case("dobkit report --quick", lambda i: [*dobkit, "report", "--quick", "--no-progress",
                                                      "--out", f"preview-{i}"], 1, folder),
            _case("dobkit sweep mc.toml (100 runs + summary)",
                  lambda i: [*dobkit, "sweep", "mc.toml", "--results", f"mc-{i}.jsonl",
                             "--summary-dir", f"mc-summary-{i}", "--no-progress"], 1, folder),
        ]
        if not args.skip_slow:
            rows += [
                _case("dobkit report (full)", lambda i: [*dobkit, "report", "--no-progress", "--out", f"report-{i}"],
                      1, folder),
                _case("dobkit tune paper-tune --max-evaluations 100",
                      lambda i: [*dobkit, "tune", "paper-tune", "--max-evaluations", "100", "--no-progress",
                                 "--out", f"tuned-{i}"], 1, folder),
            ]
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    numpy_s = rows[0]["wall_s"]
    rows[1]["ratio_to_import_numpy"] = rows[1]["wall_s"] / numpy_s
    print(f"{os.cpu_count()} cores, numba {'installed' if has_numba else 'not installed'}, "
          f"Python {sys.version.split()[0]}")
    print(table(["case", "wall (s)", "of", "load (1 min)"],
                [[r["case"], f"{r['wall_s']:.2f}", f"best of {r['repeats']}" if r["repeats"] > 1 else "one run",
                  f"{r['load']:.1f}"] for r in rows]))
    print(f"dobkit --version / import numpy: {rows[1]['ratio_to_import_numpy']:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cores": os.cpu_count(), "numba": has_numba, "cases": rows},
                                              indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
