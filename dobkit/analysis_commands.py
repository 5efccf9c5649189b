"""``dobkit analyze`` and ``dobkit report``: the analyses of :mod:`analysis.report.build` from the command line.

Registered on the main ``dobkit`` parser by :func:`add_analysis_subcommands`.
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path

from blocks.plumbing.progress import StageProgress
from dobkit.arguments import positive_number, whole_number

__all__ = ["add_analysis_subcommands", "ANALYSIS_PREFIX", "REPORT_PREFIX"]

# Default output folders: PREFIX-YYYYmmdd-HHMMSS under the current folder.
ANALYSIS_PREFIX = "dobkit-analysis"
REPORT_PREFIX = "dobkit-report"


def _add_common(parser: argparse.ArgumentParser, prefix: str) -> None:
    parser.add_argument("--scenario", default="paper", help="built-in scenario name or path to a TOML file "
                        "(default: paper)")
    parser.add_argument("--out", default=None, help="output folder, must not exist or be empty (default: a new "
                        f"folder {prefix}-YYYYmmdd-HHMMSS under the current one)")
    parser.add_argument("--observer-target", type=positive_number("rad/s"), default=None, metavar="RAD_S",
                        help="target slowest observer mode of the gain design in rad/s, finite and > 0 (default: 10)")
    parser.add_argument("--quick", action="store_true", help="a quick preview: small grids and short runs, in well "
                        "under a minute; its numbers differ from the full analysis (the report lists how)")
    parser.add_argument("--jobs", type=whole_number("--jobs"), default=None, help="worker processes for the studies "
                        "(default: the number of CPUs; results do not depend on it)")
    parser.add_argument("--no-progress", action="store_true", help="no progress display and no stage lines on "
                        "standard error (errors and the notes that change a result still appear)")


def _settings(args):
    from analysis.report.build import QUICK_SETTINGS, AnalysisSettings

    settings = QUICK_SETTINGS if args.quick else AnalysisSettings()
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    changes = {"workers": jobs}
    if args.observer_target is not None:
        changes["observer_target_rad_s"] = args.observer_target
    return replace(settings, **changes)


def _refuse_used_out(out) -> None:
    """An ``--out`` that is a file or a non-empty folder, refused in the first instant: before the scenario is
    read (an arm's URDF brings pinocchio), not after it (the staged folder checks again, and everything else)."""
    if out is None:
        return
    target = Path(out)
    if target.exists() and not target.is_dir():
        raise FileExistsError(f"output folder '{target}' is an existing file, not a folder; choose a new --out")
    if target.is_dir() and any(target.iterdir()):
        raise FileExistsError(f"output folder '{target}' exists and is not empty; choose a new --out")


def _cmd_analyze(args) -> int:
    from blocks.plumbing.outputs import default_out_dir
    from blocks.scenarios.scenario import load_scenario

    _refuse_used_out(args.out)
    scenario = load_scenario(args.scenario)      # a bad scenario is refused before the heavy imports below
    from analysis.report.build import analyze

    out = args.out if args.out is not None else default_out_dir(ANALYSIS_PREFIX)
    with StageProgress(enabled=not args.no_progress) as progress:
        result, files = analyze(scenario, out, _settings(args), progress=progress)
    slow = result.observer_bandwidth.slowest_rad_s
    print(f"scenario: {scenario.name} ({scenario.source})")
    print(f"slowest observer mode over the workspace: {slow.min:.4g} to {slow.max:.4g} rad/s")
    for observer, label in ((True, "with observer"), (False, "without observer")):
        found = result.mismatch.loop(observer).boundaries.factors
        print(f"inertia-mismatch stability boundary {label}: "
              + (", ".join(f"a = {a:.6g}" for a in found) if found else "none in the searched range"))
    for line in result.not_done:                 # analyses this arm does not allow, each with its reason
        print(f"not computed: {line}")
    figures = sorted({Path(name).stem for name in result.figures})
    print(f"analysis written to {out}: analysis.json and {len(figures)} figures, each as PNG and SVG")
    return 0


def _cmd_report(args) -> int:
    from blocks.plumbing.outputs import default_out_dir
    from blocks.scenarios.scenario import load_scenario

    _refuse_used_out(args.out)
    scenario = load_scenario(args.scenario)      # a bad scenario is refused before the heavy imports below
    from analysis.report.build import write_report
    from blocks.engines.budget import Budget

    seconds = Budget.from_env(seconds=args.max_seconds).seconds
    out = args.out if args.out is not None else default_out_dir(REPORT_PREFIX)
    with StageProgress(enabled=not args.no_progress) as progress:
        def notify(text):            # the estimate, once the scenario's own run has given the pace
            print(f"dobkit report: estimated time of the studies: {text}", file=sys.stderr, flush=True)
        path = write_report(scenario, out, _settings(args), progress=progress, sweep_summaries=args.sweep,
                            tunings=args.tune, budget_seconds=seconds, notify=None if args.no_progress else notify)
    import json
    for line in json.loads((Path(path).parent / "analysis.json").read_text()).get("not_done", []):
        print(f"not computed: {line}")
    print(f"{'quick preview of the report' if args.quick else 'report'} written to {path}")
    return 0


def add_analysis_subcommands(subparsers) -> None:
    """Register ``analyze`` and ``report`` on the ``dobkit`` sub-parsers."""
    p = subparsers.add_parser("analyze", help="linearized poles, observer bandwidth, gain design, frequency "
                              "responses and gain studies; writes analysis.json and figures")
    _add_common(p, ANALYSIS_PREFIX)
    p.set_defaults(func=_cmd_analyze)
    p = subparsers.add_parser("report", help="simulate and analyze a scenario; writes one self-contained "
                              "report.html (plus analysis.json and the figures)")
    _add_common(p, REPORT_PREFIX)
    p.add_argument("--sweep", action="append", default=[], metavar="SUMMARY_DIR",
                   help="include the summary of a 'dobkit sweep' run (its summary folder); may be repeated")
    p.add_argument("--tune", action="append", default=[], metavar="FOLDER",
                   help="include a 'dobkit tune' result (its output folder); may be repeated")
    p.add_argument("--max-seconds", metavar="S", default=None,
                   help="wall-clock seconds for the report: the studies' time is estimated after the scenario's "
                        "own run and a report that would take longer is refused then (default: no limit, or "
                        "$DOBKIT_MAX_SECONDS)")
    p.set_defaults(func=_cmd_report)

