"""The ``dobkit`` command line: a thin layer over the Python API.

Subcommands: ``simulate`` (the paper's experiment), ``analyze`` and ``report``
(:mod:`analysis`), ``sweep`` and ``fmu ...`` (:mod:`fmu`).
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import sys
import warnings

from blocks.plumbing.progress import StageProgress

from . import __version__
from .analysis_commands import add_analysis_subcommands
from .arms_commands import add_arms_subcommand
from .fmu_commands import add_fmu_subcommands
from .signals import run_with_signals
from .sweep_commands import add_sweep_subcommand
from .tune_commands import add_tune_subcommand

__all__ = ["main"]


#: The engines of ``dobkit simulate --engine`` (:data:`blocks.figure2.loop.ENGINES`, written here so that the parser
#: does not import python-control; a test keeps the two equal).
SIMULATE_ENGINES = ("auto", "compiled", "fast", "python-control")


#: True while :func:`main` runs as the program (the process ends after the command; see :func:`main`).
_exit_follows = False


@contextlib.contextmanager
def _no_cycle_collection():
    """Python's cycle collector off for a short command, restored afterwards.

    Importing python-control (scipy, matplotlib) and numba and drawing five figures allocate millions of objects
    that live until the process ends; the collector walked them again and again, about a sixth of ``dobkit
    simulate``'s CPU.  Almost none of them are garbage cycles: a run leaves 70-110 objects in cycles whatever its
    length, with every engine, and the command's peak memory is 296 MB against 293 MB with the collector on;
    reference counting still frees everything else at once.  The state is restored so that callers of
    :func:`main` from Python keep their own.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if _exit_follows:
            gc.freeze()     # before the collector is back: else its first act is a full walk of all of it
        if enabled:
            gc.enable()


@_no_cycle_collection()
def _cmd_simulate(args) -> int:
    from blocks.scenarios.scenario import load_scenario

    scenario = load_scenario(args.scenario)      # a bad scenario is refused before the heavy imports below
    from analysis.simulation.experiment import default_out_dir, format_rms_table, run_experiment

    out = args.out if args.out is not None else default_out_dir()
    formats = ("png", "svg") if args.svg else ("png",)
    with StageProgress() as progress:
        result = run_experiment(scenario, out, progress=progress, figures=not args.no_figures, engine=args.engine,
                                figure_formats=formats)
    print(f"scenario: {scenario.name} ({scenario.source}), engine: {result.metrics['engine']}")
    c = scenario.controller
    joints = scenario.robot.joints
    if c is not None:
        encoders = "exact" if not any(c.position_resolution) else \
            "resolution " + ", ".join(f"{r:.3g}" for r in c.position_resolution) \
            + f" ({', '.join(joints.position_units)})"
        velocity = c.velocity if c.velocity_cutoff is None else f"{c.velocity} through a {c.velocity_cutoff:g} Hz low-pass"
        print(f"controller: sampled at {c.sample_rate:g} Hz, {c.observer_discretization} observer update, delay "
              f"{c.delay}, velocity {velocity}, encoders {encoders}")
    print(format_rms_table(result.metrics, scenario.robot))
    figures = "no figures (--no-figures)" if args.no_figures else \
        "Figures 4-8 as " + " and ".join(f.upper() for f in formats)
    print(f"results written to {result.out_dir}: metrics.json, timeseries.csv, scenario.toml, {figures}")
    from blocks.plumbing.outputs import metrics_json
    non_finite = metrics_json(result.metrics)[1]
    if non_finite:
        print(f"note: {len(non_finite)} metric(s) are not finite numbers (written as null in metrics.json, listed "
              f"under non_finite_values): {', '.join(non_finite[:4])}{' ...' if len(non_finite) > 4 else ''}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available subcommand."""
    parser = argparse.ArgumentParser(prog="dobkit", description="Disturbance-observer-based tracking control "
                                     "of a surgical robot arm, on python-control.")
    parser.add_argument("--version", action="version", version=f"dobkit {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="run a scenario with and without the observer; write metrics, "
                         "time series and Figures 4-8 (PNG)")
    sim.add_argument("--scenario", default="paper", help="built-in scenario name or path to a TOML file "
                     "(default: paper)")
    sim.add_argument("--out", default=None, help="output folder (default: a new folder under the current one)")
    sim.add_argument("--engine", choices=SIMULATE_ENGINES, default="auto",
                     help="simulation engine of both runs: compiled (numba), fast (numpy), python-control "
                          "(control.input_output_response); auto takes compiled when it can (default: auto)")
    figures = sim.add_mutually_exclusive_group()
    figures.add_argument("--no-figures", action="store_true", help="write metrics, time series and scenario only")
    figures.add_argument("--svg", action="store_true", help="write each figure as SVG too (default: PNG only)")
    sim.set_defaults(func=_cmd_simulate)
    add_analysis_subcommands(sub)
    add_sweep_subcommand(sub)
    add_tune_subcommand(sub)
    add_fmu_subcommands(sub)
    add_arms_subcommand(sub)
    return parser


@contextlib.contextmanager
def _warnings_as_notes(command: str):
    """Show warnings as one ``dobkit <command>: note: ...`` line each, not Python's two-line form.

    A user of the command line has no use for the source line Python echoes (e.g. which engine
    serves a run when numba is not installed); the hook is restored afterwards so that callers of
    :func:`main` from Python keep their own warning handling.
    """
    def show(message, category, filename, lineno, file=None, line=None):
        print(f"dobkit {command}: note: {message}", file=sys.stderr if file is None else file)

    previous = warnings.showwarning
    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def main(argv=None) -> int:
    """Entry point of the ``dobkit`` console script; returns the exit status (SIGTERM: as Ctrl-C, 143).

    ``argv`` None: the program's own command line (the ``dobkit`` script, ``python -m dobkit``), after which the
    process ends: everything the command made is then frozen (:func:`gc.freeze`), so that the interpreter's
    shutdown frees it by reference counts instead of walking the millions of objects python-control, scipy,
    matplotlib and numba create for garbage cycles (0.8 s of CPU after ``dobkit simulate``, 0.06 s frozen).
    Exit handlers still run (staged folders, extracted FMUs); only cycles left at exit are not collected.
    A list ``argv`` (a caller in Python) leaves the collector as it was.
    """
    global _exit_follows
    _exit_follows = argv is None
    try:
        status = run_with_signals(_main, argv)
    finally:
        _exit_follows = False
    if argv is None:
        gc.freeze()
    return status


def _interrupt_within(err: BaseException) -> bool:
    """Whether ``err`` was caused by a Ctrl-C or SIGTERM (a :class:`KeyboardInterrupt` in its chain)."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def _main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with _warnings_as_notes(args.command):
            return int(args.func(args) or 0)
    except (ValueError, OSError, RuntimeError, TypeError) as err:
        if _interrupt_within(err):
            # Python 3.11 wraps an exception of a descriptor's __set_name__ (a class made while a module is
            # imported) in RuntimeError: Ctrl-C or SIGTERM then, not an error
            print(f"dobkit {args.command}: interrupted; nothing partial was written", file=sys.stderr)
            return 130
        # Expected failures (bad scenario, unreachable path, diverging run, bad FMU, unwritable folder): one line.
        print(f"dobkit {args.command}: error: {err}", file=sys.stderr)
        return 2
    except MemoryError:
        # the jobs estimate their memory before they start; this is what the estimate did not foresee
        print(f"dobkit {args.command}: error: out of memory (the machine had less free memory than the job's "
              "estimate allowed for); nothing was written", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # output folders are staged: an interrupted command leaves no partial results behind
        print(f"dobkit {args.command}: interrupted; nothing partial was written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
