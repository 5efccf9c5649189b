"""The ``dobkit sweep`` command: a thin layer over :mod:`~analysis.sweep`, :mod:`~analysis.sweep_runner`
and :mod:`~analysis.sweep_report`.

Wire it into the console script's parser with::

    subparsers = parser.add_subparsers(dest="command")
    add_sweep_subcommand(subparsers)
    args = parser.parse_args()
    sys.exit(args.func(args))
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blocks.scenario import ScenarioError

__all__ = ["add_sweep_subcommand", "sweep_command"]


def add_sweep_subcommand(subparsers) -> argparse.ArgumentParser:
    """Add ``sweep`` to an ``argparse`` subparsers object; its handler is ``args.func`` (returns an exit code)."""
    p = subparsers.add_parser(
        "sweep", help="run a grid / Monte Carlo sweep of scenario values (resumable)",
        description="Run every run of a sweep file that the results file does not hold yet, batched on this "
                    "machine's cores or on a Dask cluster, then write summary statistics and plots.")
    p.add_argument("sweep_file", help="sweep file (TOML); see analysis.sweep")
    p.add_argument("--results", help="JSON-lines results file (default: <sweep name>-results.jsonl beside the sweep "
                                     "file); runs already in it are skipped")
    p.add_argument("--summary-dir", help="where summary.md, summary.json and figures go "
                                         "(default: <sweep name>-summary beside the results)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask distributed scheduler address (tcp://host:8786); needs dask[distributed]")
    p.add_argument("--workers", type=int, help="local worker processes (default: all cores)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--check", action="store_true", help="validate the sweep file, print the run count and stop")
    p.add_argument("--summary-only", action="store_true", help="only (re)write the summary of the results file")
    p.set_defaults(func=sweep_command)
    return p


def sweep_command(args: argparse.Namespace) -> int:
    """Handle ``dobkit sweep``; 0 on success, 2 on a bad sweep file, 1 on other failures."""
    from analysis.sweep import SweepError, load_sweep
    from analysis.sweep_runner import run_sweep
    from analysis.sweep_report import write_summary
    try:
        spec = load_sweep(args.sweep_file)
    except (SweepError, ScenarioError) as err:
        print(f"dobkit sweep: {err}", file=sys.stderr)
        return 2
    folder = Path(args.sweep_file).parent
    results = Path(args.results) if args.results else folder / f"{spec.name}-results.jsonl"
    summary_dir = Path(args.summary_dir) if args.summary_dir else results.parent / f"{spec.name}-summary"
    if args.check:
        print(f"sweep '{spec.name}': {len(spec.runs)} runs, valid")
        return 0
    if not args.summary_only:
        try:
            outcome = run_sweep(spec, results, scheduler=args.scheduler, workers=args.workers,
                                progress=not args.no_progress)
        except SweepError as err:
            print(f"dobkit sweep: {err}", file=sys.stderr)
            return 2
        print(f"sweep '{spec.name}': {outcome.ran} runs done now ({outcome.diverged} diverged), "
              f"{outcome.skipped} already in {results}, {outcome.total} in all; {outcome.seconds:.1f} s")
    files = write_summary(results, summary_dir)
    print(f"summary: {files['markdown']} ({len(files['figures'])} figure files)")
    return 0
