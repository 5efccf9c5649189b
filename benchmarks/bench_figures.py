"""Time of Figures 4-8 of ``dobkit simulate``: PNG only (the command's default) and PNG + SVG (``--svg``).

    PYTHONPATH=. python benchmarks/bench_figures.py [--repeats 3] [--json out.json]

The paper scenario is simulated once with and once without the observer
(``engine="fast"``: no numba needed); then :func:`analysis.simulation.figures.paper_figures`
writes the five figures into a temporary folder, each format set in turn,
``--repeats`` times.  The table gives the fastest CPU and wall time of each.
For scale it also times one fast-engine run of the scenario.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table, time_interleaved  # noqa: E402

import blocks  # noqa: E402
from analysis.simulation.figures import paper_figures  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=None, help="also write the numbers to this file")
    args = parser.parse_args(argv)

    scenario = blocks.load_scenario("paper")
    with_dob = blocks.simulate(scenario, observer=True, engine="fast")
    without_dob = blocks.simulate(scenario, observer=False, engine="fast")
    with tempfile.TemporaryDirectory() as folder:
        cases = {
            "Figures 4-8, PNG (dobkit simulate)": lambda: paper_figures(with_dob, without_dob, Path(folder) / "png",
                                                                        formats=("png",)),
            "Figures 4-8, PNG + SVG (--svg)": lambda: paper_figures(with_dob, without_dob, Path(folder) / "both",
                                                                    formats=("png", "svg")),
            "one fast-engine run of the paper scenario": lambda: blocks.simulate(scenario, engine="fast"),
        }
        times = time_interleaved(cases, args.repeats, clock="both")
    rows, numbers = [], {}
    for name, values in times.items():
        wall, cpu = min(w for w, _ in values), min(c for _, c in values)
        numbers[name] = {"wall_min_s": wall, "cpu_min_s": cpu}
        rows.append([name, f"{cpu:.2f}", f"{wall:.2f}"])
    print(table(["case", "CPU min s", "wall min s"], rows))
    if args.json:
        Path(args.json).write_text(json.dumps(numbers, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
