"""The ``dobkit tune`` command: a thin layer over :mod:`~analysis.tune` and :mod:`~analysis.tune_runner`.

Exit status: 0 tuned (the gains meet every constraint); 3 finished without a
feasible point (the outputs are written, the best infeasible point named as
such); 2 a bad tuning file or setting, a budget an evaluation would exceed, or
constraints no gains within the bounds meet (said before the search starts);
1 another failure; 130 interrupted (Ctrl-C: every finished evaluation is kept
and the same command resumes).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blocks.budget import Budget, format_bytes
from dobkit.arguments import add_budget_flags, whole_number

__all__ = ["add_tune_subcommand", "tune_command", "default_out_dir", "EXIT_INFEASIBLE"]

#: Exit status of a tuning that ended without gains that meet every constraint.
EXIT_INFEASIBLE = 3


def add_tune_subcommand(subparsers) -> argparse.ArgumentParser:
    """Add ``tune`` to an ``argparse`` subparsers object; its handler is ``args.func`` (returns an exit code)."""
    p = subparsers.add_parser(
        "tune", help="tune Kp, Kd and the observer gain over a Monte Carlo set under constraints (resumable)",
        description="Choose the gains of a tuning file's [search] to minimise the worst or mean tool-tip error over "
                    "a Monte Carlo set of mismatches and disturbances, under torque-noise, torque-limit and "
                    "stability constraints: differential evolution, then a Nelder-Mead polish. Every evaluation "
                    "goes to OUT/evaluations.jsonl as it finishes; the same command resumes a stopped tuning. "
                    "Writes OUT/tune.json, the tuned scenario OUT/<scenario>-tuned.toml and figures.")
    p.add_argument("tuning_file", help="tuning file (TOML; see analysis.tune) or a built-in name (paper-tune)")
    p.add_argument("--out", help="output folder, which also holds the evaluation log (default: NAME-results beside "
                                 "the tuning file, or in the current folder for a built-in one)")
    p.add_argument("--workers", type=whole_number("--workers"), help="threads of each batch (default: all cores)")
    p.add_argument("--max-evaluations", type=whole_number("--max-evaluations"),
                   help="objective evaluations in all (overrides search.max_evaluations; a larger number continues "
                        "a finished tuning)")
    p.add_argument("--no-progress", action="store_true", help="no progress display")
    p.add_argument("--check", action="store_true",
                   help="validate the file, check that the linear constraints can be met, print the estimates, "
                        "and stop")
    p.add_argument("--restart", action="store_true",
                   help="if the output folder's evaluation log holds another definition of the tuning, move it "
                        "aside and start anew, instead of refusing")
    add_budget_flags(p, "finished evaluations are kept when it runs out")
    p.set_defaults(func=tune_command)
    return p


def default_out_dir(spec) -> Path:
    """``NAME-results`` beside the tuning file (in the current folder for a built-in tuning)."""
    source = Path(spec.source)
    folder = source.parent if source.suffix == ".toml" else Path(".")
    return folder / f"{spec.name}-results"


def tune_command(args: argparse.Namespace) -> int:
    """Handle ``dobkit tune``; see the module docstring for the exit status."""
    from analysis.tune import TuneError
    from blocks.budget import BudgetError
    from blocks.scenario import ScenarioError

    state: dict = {}
    try:
        budget = Budget.from_env(memory=args.max_memory, steps=args.max_steps, seconds=args.max_seconds)
        return _tune(args, budget, state)
    except (TuneError, ScenarioError, BudgetError, ValueError) as err:
        print(f"dobkit tune: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        where = f" in {state['out']}" if "out" in state else ""
        print(f"dobkit tune: interrupted; every finished evaluation is kept{where}, and the same command resumes",
              file=sys.stderr)
        return 130


def _tune(args: argparse.Namespace, budget: Budget, state: dict) -> int:
    from analysis.tune import load_tuning, with_evaluations
    from analysis.tune_eval import Evaluator, evaluation_estimate
    from analysis.tune_runner import LOG_NAME, check_linear_feasibility, run_tune

    spec = load_tuning(args.tuning_file, budget=budget)
    if args.max_evaluations is not None:
        spec = with_evaluations(spec, args.max_evaluations)
    out = Path(args.out) if args.out else default_out_dir(spec)
    state["out"] = out
    if args.check:
        estimate, substeps = evaluation_estimate(spec)
        check_linear_feasibility(spec, Evaluator(spec))
        print(_check_report(spec, estimate, substeps))
        return 0
    estimate, _ = evaluation_estimate(spec)
    print(f"tuning '{spec.name}': at most {spec.max_evaluations} evaluations, each {spec.runs} runs of at most "
          f"{estimate.steps:,} RK4 steps (about {format_bytes(estimate.memory)}); evaluation log "
          f"{out / LOG_NAME}", flush=True)
    result = run_tune(spec, out, workers=args.workers, progress=not args.no_progress, restart=args.restart,
                      budget=budget)
    print(_summary(result, out))
    return 0 if result.feasible else EXIT_INFEASIBLE


def _gains_text(gains: dict) -> str:
    def fmt(v):
        if isinstance(v, list):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        return f"{v:.6g}"
    return ", ".join(f"{k} = {fmt(v)}" for k, v in gains.items())


def _numbers(values) -> str:
    return "-" if values is None else "[" + ", ".join("-" if v is None else f"{v:.4g}" for v in values) + "]"


def _summary(result, out: Path) -> str:
    e = result.evaluations
    lines = [f"tuning '{result.name}': {e['search']} + {e['polish']} evaluations ({e['simulated']} simulated now, "
             f"{e['from_log']} from the evaluation log, {e['linear_only']} refused by the linear constraints), "
             f"{result.seconds:.1f} s",
             result.message,
             f"  tuned gains: {_gains_text(result.tuned.gains)}{'' if result.feasible else ' (INFEASIBLE)'}",
             f"  base gains:  {_gains_text(result.base.gains)}"]
    if result.limits.get("torque_noise_rms") is not None:
        lines.append(f"  torque noise RMS [N m]: tuned {_numbers(result.tuned.torque_noise_rms)}, base "
                     f"{_numbers(result.base.torque_noise_rms)}, budget {_numbers(result.limits['torque_noise_rms'])}")
    if result.limits.get("torque_limit") is not None:
        lines.append(f"  peak torque [N m]: tuned {_numbers(result.tuned.peak_torque)}, limit "
                     f"{_numbers(result.limits['torque_limit'])}")
    if result.log_problems:
        lines.append(f"  evaluation log: {len(result.log_problems)} unusable line(s) left out and their candidates "
                     f"simulated again ({result.log_problems[0]}{', ...' if len(result.log_problems) > 1 else ''})")
    lines.append(f"written to {out}: tune.json, {result.scenario_file} (dobkit simulate --scenario "
                 f"{out / result.scenario_file}), {len(result.figures)} figures (PNG and SVG); "
                 f"dobkit report --tune {out} adds them to a report")
    return "\n".join(lines)


def _check_report(spec, estimate, substeps: int) -> str:
    limits = spec.limits
    lines = [f"tuning '{spec.name}': valid (definition {spec.definition}); base scenario {spec.base.name}, "
             f"{spec.objective} {spec.metric} over {spec.runs} runs",
             "  search: " + ", ".join(f"{p.name} in [{p.low:g}, {p.high:g}] {p.unit}" for p in spec.parameters),
             f"  differential evolution: population {spec.population}, {spec.generations} generations after the "
             f"first; polish: {spec.polish_evaluations} evaluations; at most {spec.max_evaluations} in all"]
    if limits.torque_noise_rms is not None:
        lines.append(f"  torque noise budget [N m]: {_numbers(limits.torque_noise_rms)}"
                     + (" (the base gains' own)" if limits.torque_noise_from == "base" else ""))
    if limits.torque_limit is not None:
        lines.append(f"  torque limit [N m]: {_numbers(limits.torque_limit)}")
    if limits.stability_margin is not None:
        lines.append(f"  stability margin: poles at real part <= -{limits.stability_margin:g} 1/s")
    lines.append("  the linear constraints can be met within the bounds")
    lines.append(f"  one evaluation: {spec.runs} runs of at most {estimate.steps:,} RK4 steps ({substeps} substeps at "
                 f"the high bounds), about {format_bytes(estimate.memory)}; at most "
                 f"{spec.max_evaluations * spec.runs * estimate.steps:.3g} run-steps in all")
    return "\n".join(lines)
