"""The ``dobkit sweep`` command: a thin layer over :mod:`~analysis.sweep.spec`, :mod:`~analysis.sweep.runner`
and :mod:`~analysis.sweep.summary`.

Wire it into the console script's parser with::

    subparsers = parser.add_subparsers(dest="command")
    add_sweep_subcommand(subparsers)
    args = parser.parse_args()
    sys.exit(args.func(args))

Exit status: 0 done, 2 a bad sweep file or setting (or a budget the sweep would
exceed), 1 another failure, 130 interrupted (Ctrl-C).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from blocks.engines.budget import Budget
from dobkit.job_commands import add_job_flags, add_job_parser, run_job

__all__ = ["add_sweep_subcommand", "sweep_command", "default_summary_dir"]


def add_sweep_subcommand(subparsers) -> argparse.ArgumentParser:
    """Add ``sweep`` to an ``argparse`` subparsers object; its handler is ``args.func`` (returns an exit code)."""
    p = add_job_parser(
        subparsers, "sweep", help="run a grid / Monte Carlo sweep of scenario values (resumable)",
        description="Run every run of a sweep file that the results file does not hold yet, batched on this "
                    "machine's cores or on a Dask cluster, then write summary statistics and plots. Before "
                    "anything runs, the sweep's memory and each run's step count are estimated and checked "
                    "against a budget.", file="sweep_file", file_help="sweep file (TOML); see analysis.sweep.spec")
    p.add_argument("--results", help="JSON-lines results file (default: <sweep name>-results.jsonl beside the sweep "
                                     "file); runs already in it are skipped")
    p.add_argument("--summary-dir", help="where summary.md, summary.json and figures go (default: beside the "
                                         "results file, named after it: NAME-results.jsonl -> NAME-summary)")
    p.add_argument("--summary-only", action="store_true", help="only (re)write the summary of the results file")
    add_job_flags(p, workers="local worker processes (default: all cores)",
                  check="validate the sweep file and every run, print the run count and the estimates, and stop",
                  restart="if the results file holds another definition of the sweep, or cannot be used (bytes that "
                          "are not UTF-8, two rows of one run that differ), move it aside (its name then says which "
                          "definition) and start a new one, instead of refusing",
                  seconds="finished runs are kept when it runs out")
    p.set_defaults(func=sweep_command)
    return p


def default_summary_dir(results: Path) -> Path:
    """The summary folder of a results file: ``NAME-results.jsonl`` -> ``NAME-summary`` beside it."""
    stem = results.name[:-len(".jsonl")] if results.name.endswith(".jsonl") else results.stem
    stem = stem[:-len("-results")] if stem.endswith("-results") and len(stem) > len("-results") else stem
    return results.parent / f"{stem}-summary"


def sweep_command(args: argparse.Namespace) -> int:
    """Handle ``dobkit sweep``; 0 on success, 2 on a bad sweep file or budget, 1 on other failures, 130 on Ctrl-C."""
    from analysis.sweep.spec import SweepError

    return run_job("sweep", args, _sweep, (SweepError,), "run", "results")


def _sweep(args: argparse.Namespace, budget: Budget, state: dict) -> int:
    from analysis.sweep.runner import run_sweep
    from analysis.sweep.spec import load_sweep
    from analysis.sweep.summary import write_summary

    spec = load_sweep(args.sweep_file, budget=budget, progress=not args.no_progress)
    folder = Path(args.sweep_file).parent
    results = Path(args.results) if args.results else folder / f"{spec.name}-results.jsonl"
    summary_dir = Path(args.summary_dir) if args.summary_dir else default_summary_dir(results)
    state["results"] = results
    if args.check:
        print(_check_report(spec))
        return 0
    if not args.summary_only:
        outcome = run_sweep(spec, results, scheduler=args.scheduler, workers=args.workers,
                            progress=not args.no_progress, restart=args.restart, budget=budget)
        if outcome.moved_to is not None:
            print(f"results file {results} held another definition of the sweep: moved to {outcome.moved_to}; "
                  "starting anew")
        print(f"sweep '{spec.name}': {outcome.ran} runs done now ({outcome.diverged} diverged), "
              f"{outcome.skipped} already in {results}, {outcome.total} in all; {outcome.seconds:.1f} s")
        if outcome.problems:
            print(f"results file: {len(outcome.problems)} unusable line(s) left out and their runs done again "
                  f"({outcome.problems[0]}{', ...' if len(outcome.problems) > 1 else ''})")
    files = write_summary(results, summary_dir, spec=spec)
    n = len(files["summary"].figures)
    print(f"summary: {files['markdown']} ({n} figure{'s' if n != 1 else ''}, each as PNG and SVG)")
    return 0


def _check_report(spec) -> str:
    """What ``--check`` prints: runs, how they are batched, and the largest run's estimate against the budget."""
    from blocks.engines.budget import format_bytes as size
    lines = [f"sweep '{spec.name}': {len(spec.runs)} runs, valid (definition {spec.definition})"]
    sa = spec.sensitivity
    if sa is not None:
        k = len(sa.distributions)
        lines.append(f"  sensitivity: {sa.method}, " + (f"N = {sa.samples} x (k + 2)" if sa.method == "sobol" else
                                                        f"r = {sa.samples} trajectories of {sa.levels} levels x (k + 1)")
                     + f" = {sa.runs:,} runs for k = {k} values")
    if spec.engine in ("batch", "cuda"):
        classes = ", ".join(f"{n} at {s} substep{'s' if s != 1 else ''}{' with noise' if noisy else ''}"
                            for (s, noisy), n in spec.plan.classes().items())
        lines.append(f"  {spec.engine} engine: {len(spec.plan.shared)} shared scenario(s); runs by step: {classes}")
        largest = spec.plan.largest
        if largest is not None:
            lines.append(f"  largest run: {largest.steps:,} steps (budget {spec.budget.steps:,}); a batch of it alone "
                         f"needs about {size(largest.memory)} (budget {size(spec.budget.memory)})")
    else:
        lines.append("  fast engine: one adaptive simulation per run; its steps are not known before it runs")
    return "\n".join(lines)
