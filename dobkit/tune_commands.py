"""The ``dobkit tune`` command: a thin layer over :mod:`~analysis.tune.spec` and :mod:`~analysis.tune.runner`.

Exit status: 0 tuned (the gains meet every constraint); 3 finished without a
feasible point (the outputs are written, the best infeasible point named as
such); 2 a bad tuning file or setting, a budget an evaluation would exceed, or
constraints no gains within the bounds meet (said before the search starts);
1 another failure; 130 interrupted (Ctrl-C: every finished evaluation is kept
and the same command resumes).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from blocks.engines.budget import Budget, format_bytes
from dobkit.arguments import whole_number
from dobkit.job_commands import add_job_flags, add_job_parser, run_job

__all__ = ["add_tune_subcommand", "tune_command", "default_out_dir", "EXIT_INFEASIBLE"]

#: Exit status of a tuning that ended without gains that meet every constraint.
EXIT_INFEASIBLE = 3


def add_tune_subcommand(subparsers) -> argparse.ArgumentParser:
    """Add ``tune`` to an ``argparse`` subparsers object; its handler is ``args.func`` (returns an exit code)."""
    p = add_job_parser(
        subparsers, "tune", help="tune Kp, Kd and the observer gain over a Monte Carlo set under constraints "
                                 "(resumable)",
        description="Choose the gains of a tuning file's [search] to minimise the worst or mean tool-tip error over "
                    "a Monte Carlo set of mismatches and disturbances, under torque-noise, torque-limit, stability "
                    "and damping constraints (the error dynamics' damping ratio >= 0.7 unless the file says "
                    "otherwise): differential evolution, then a Nelder-Mead polish. Every evaluation goes to "
                    "OUT/evaluations.jsonl as it finishes; the same command resumes a stopped tuning. Writes "
                    "OUT/tune.json, the tuned scenario OUT/<scenario>-tuned.toml and figures.",
        file="tuning_file", file_help="tuning file (TOML; see analysis.tune.spec) or a built-in name (paper-tune)")
    p.add_argument("--out", help="output folder, which also holds the evaluation log (default: NAME-results beside "
                                 "the tuning file, or in the current folder for a built-in one)")
    p.add_argument("--max-evaluations", type=whole_number("--max-evaluations"),
                   help="objective evaluations in all (overrides search.max_evaluations; a larger number continues "
                        "a finished tuning)")
    p.add_argument("--compare-unconstrained", action="store_true",
                   help="with a damping (or overshoot) constraint, also run the same search without it and say what "
                        "the constraint costs against that search's answer (about doubles the time; without it the "
                        "cost is measured against the constrained search's own evaluations)")
    p.add_argument("--constraint-costs", action="store_true",
                   help="after the tuning, run the same search again without each active constraint in turn (the "
                        "damping or overshoot, the observer bandwidth ratio, the sampled loop's margin, the "
                        "torque-noise budget) and say for each its margin, whether it binds and what it costs in the "
                        "objective (mm); up to 1 + that many times the time, less where the log holds the "
                        "candidates")
    add_job_flags(p, workers="threads of each batch (default: all cores)",
                  check="validate the file, check that the linear constraints can be met, print the estimates, "
                        "and stop",
                  restart="if the output folder's evaluation log holds another definition of the tuning, or cannot "
                          "be used, move it aside and start anew, instead of refusing",
                  seconds="finished evaluations are kept when it runs out")
    p.set_defaults(func=tune_command)
    return p


def default_out_dir(spec) -> Path:
    """``NAME-results`` beside the tuning file (in the current folder for a built-in tuning)."""
    source = Path(spec.source)
    folder = source.parent if source.suffix == ".toml" else Path(".")
    return folder / f"{spec.name}-results"


def tune_command(args: argparse.Namespace) -> int:
    """Handle ``dobkit tune``; see the module docstring for the exit status."""
    from analysis.tune.spec import TuneError

    return run_job("tune", args, _tune, (TuneError,), "evaluation", "out")


def _tune(args: argparse.Namespace, budget: Budget, state: dict) -> int:
    from analysis.tune.evaluate import Evaluator, evaluation_estimate, measure_evaluation
    from analysis.tune.runner import LOG_NAME, check_linear_feasibility, run_tune
    from analysis.tune.spec import load_tuning, with_evaluations

    spec = load_tuning(args.tuning_file, budget=budget)
    if args.max_evaluations is not None:
        spec = with_evaluations(spec, args.max_evaluations)
    out = Path(args.out) if args.out else default_out_dir(spec)
    state["out"] = out
    if args.check:
        estimate, substeps = evaluation_estimate(spec)
        check_linear_feasibility(spec, Evaluator(spec))
        print(_check_report(spec, estimate, substeps), flush=True)
        print(_time_line(spec, measure_evaluation(spec, workers=args.workers or _cores()), substeps, args))
        if getattr(args, "constraint_costs", False) or getattr(args, "compare_unconstrained", False):
            print(_searches_line(spec, args))
        return 0
    estimate, _ = evaluation_estimate(spec)
    print(f"tuning '{spec.name}': at most {spec.max_evaluations} evaluations, each {spec.runs} runs of at most "
          f"{estimate.steps:,} RK4 steps (about {format_bytes(estimate.memory)}); evaluation log "
          f"{out / LOG_NAME}", flush=True)
    # --no-progress: no bars and no stage lines on standard error (the lines above and below on standard output stay)
    result = run_tune(spec, out, workers=args.workers, progress=not args.no_progress, restart=args.restart,
                      budget=budget, compare_unconstrained=args.compare_unconstrained, scheduler=args.scheduler,
                      constraint_costs=args.constraint_costs)
    print(_summary(result, out))
    return 0 if result.feasible else EXIT_INFEASIBLE


def _cores() -> int:
    import os
    return os.cpu_count() or 1


def _time_line(spec, measured, corner_substeps: int, args) -> str:
    """``--check``'s time estimate: searches x evaluations x the measured cost of one (module
    :mod:`analysis.tune.evaluate`; the searches of :func:`analysis.tune.costs.search_count`)."""
    from analysis.tune.costs import search_count
    from analysis.tune.evaluate import time_bound, time_estimate
    searches = search_count(spec, getattr(args, "constraint_costs", False),
                            getattr(args, "compare_unconstrained", False))
    what = (f"{spec.max_evaluations} evaluations at most" if searches == 1 else
            f"{searches} searches of at most {spec.max_evaluations} evaluations each")
    where = (f"here, not on the Dask cluster at {args.scheduler}" if args.scheduler else
             f"with {args.workers or _cores()} worker thread(s)")
    steps = ("" if corner_substeps <= measured.substeps else
             f"; gains near the high bounds need up to {corner_substeps} substeps: at most about "
             f"{_duration(time_bound(spec, measured, searches, corner_substeps))} if every candidate needed them")
    return (f"  time: one evaluation of the base gains took {measured.seconds:.3g} s ({measured.substeps} substep"
            f"{'s' if measured.substeps != 1 else ''}, {where}): about "
            f"{_duration(time_estimate(spec, measured, searches))} for {what} (candidates the linear constraints "
            f"refuse are not simulated{steps})")


def _searches_line(spec, args) -> str:
    """``--check``'s line on the searches after the tuning's own (``--constraint-costs``, ``--compare-unconstrained``)."""
    from analysis.tune.costs import costed_constraints
    keys = costed_constraints(spec.limits) if args.constraint_costs else \
        [k for k in ("min_damping_ratio", "max_overshoot") if getattr(spec.limits, k) is not None]
    if not keys:
        return "  no constraint to search without: only the tuning's own search runs"
    names = ", ".join(_MARGIN_WORDS[k][0] for k in keys)
    return (f"  then {len(keys)} more search{'es' if len(keys) != 1 else ''}, one without each of: {names} (their "
            "candidates that the evaluation log already holds are not simulated again, so they take less)")


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _gains_text(gains: dict) -> str:
    def fmt(v):
        if isinstance(v, list):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        return f"{v:.6g}"
    return ", ".join(f"{k} = {fmt(v)}" for k, v in gains.items())


def _force_units(units) -> str:
    """Per joint of the tuning's arm, the unit of its torque or force: "N m, N m, N, N m" for the paper's RRPR."""
    return ", ".join(units)


def _numbers(values) -> str:
    return "-" if values is None else "[" + ", ".join("-" if v is None else f"{v:.4g}" for v in values) + "]"


def _summary(result, out: Path) -> str:
    from analysis.tune.report import evaluations_text
    lines = [f"tuning '{result.name}': {evaluations_text(result)}; {result.seconds:.1f} s",
             result.message,
             f"  tuned gains: {_gains_text(result.tuned.gains)}{'' if result.feasible else ' (INFEASIBLE)'}",
             f"  base gains:  {_gains_text(result.base.gains)}"]
    lines += constraint_lines(result)
    if result.log_problems:
        lines.append(f"  evaluation log: {len(result.log_problems)} unusable line(s) left out and their candidates "
                     f"simulated again ({result.log_problems[0]}{', ...' if len(result.log_problems) > 1 else ''})")
    lines.append(f"written to {out}: tune.json, {result.scenario_file} (dobkit simulate --scenario "
                 f"{out / result.scenario_file}), {len(result.figures)} figures (PNG and SVG); "
                 f"dobkit report --tune {out} adds them to a report")
    return "\n".join(lines)


#: Each constraint as stdout names it, with the unit of its margin (analysis.tune.evaluate, "Margins").
_MARGIN_WORDS = {"torque_noise_rms": ("torque noise", "of the budget left", 100.0, "%"),
                 "torque_limit": ("peak torque", "below the limit", 100.0, "%"),
                 "stability_margin": ("stability margin", "beyond it", 1.0, " 1/s"),
                 "min_damping_ratio": ("damping ratio", "above the minimum", 1.0, ""),
                 "max_overshoot": ("overshoot", "below the maximum", 100.0, " % points"),
                 "min_observer_bandwidth_ratio": ("observer bandwidth ratio", "above the minimum", 1.0, ""),
                 "sampled_margin": ("sampled loop", "of its limit free beyond the required share", 100.0,
                                    " % points")}


def constraint_lines(result) -> list[str]:
    """Lines on every constraint of a tuning result: the tuned and base values, the limit and the tuned margin."""
    limits, tuned, base = result.limits, result.tuned, result.base
    lines = []
    if limits.get("torque_noise_rms") is not None:
        lines.append(f"  torque noise RMS [{_force_units(result.force_units)}]: tuned {_numbers(tuned.torque_noise_rms)}, base "
                     f"{_numbers(base.torque_noise_rms)}, budget {_numbers(limits['torque_noise_rms'])}")
    if limits.get("torque_limit") is not None:
        lines.append(f"  peak torque [{_force_units(result.force_units)}]: tuned {_numbers(tuned.peak_torque)}, limit "
                     f"{_numbers(limits['torque_limit'])}")
    if tuned.damping_ratio:
        minimum = limits.get("min_damping_ratio")
        bound = (f", at least {minimum:g}" + (" (the default)" if limits.get("damping_from") == "default" else "")
                 if minimum is not None else f", overshoot at most {100 * limits['max_overshoot']:g} %"
                 if limits.get("max_overshoot") is not None else " (not constrained)")
        lines.append(f"  damping ratio of the error dynamics: tuned {_numbers(tuned.damping_ratio)}, base "
                     f"{_numbers(base.damping_ratio)}{bound}")
    if limits.get("sampled_margin") is not None and tuned.sampled_loop is not None:
        def ts(point):
            return "-" if point.sampled_loop is None else (f"{point.sampled_loop['ts_lambda_max']:.4g} (limit "
                                                           f"{point.sampled_loop['ts_lambda_limit']:.4g})")
        lines.append(f"  sampled loop, Ts lambda_max(Y M^-1) along the path: tuned {ts(tuned)}, base {ts(base)}; at "
                     f"most {1 - limits['sampled_margin']:g} of the limit"
                     + (" (the default)" if limits.get("sampled_from") == "default" else ""))
    if tuned.margins:
        parts = []
        for key, value in tuned.margins.items():
            name, words, scale, unit = _MARGIN_WORDS.get(key, (key, "margin", 1.0, ""))
            parts.append(f"{name} {scale * value:+.3g}{unit} {words}" if value >= 0 else
                         f"{name} MISSED by {-scale * value:.3g}{unit}")
        lines.append("  margins of the tuned gains: " + "; ".join(parts))
    free, cost = result.unconstrained, result.damping_cost
    if result.constraint_costs is not None:
        return lines + cost_lines(result)
    if free is not None and cost is not None:
        how = ("the same search without it reached" if result.unconstrained_from == "search" else
               "the best of this search's own evaluations without it (a lower bound of the cost; "
               "--compare-unconstrained runs the search without it) reached")
        lines.append(f"  the damping constraint costs {cost:.4g} mm: {how} {free.objective:.4g} mm (damping ratio "
                     f"{_numbers(free.damping_ratio)}, {_gains_text(free.gains)})")
    return lines


def cost_lines(result) -> list[str]:
    """Lines on what each constraint costs (``--constraint-costs``): its margin, whether it binds, the cost."""
    costs = result.constraint_costs
    if not costs:
        return ["  what each constraint costs: the tuning has none of the damping, observer bandwidth ratio, sampled "
                "margin or torque-noise constraints"]
    if costs[0].reference is None:
        return ["  what each constraint costs: not known, as no evaluation met every constraint"]
    lines = [f"  what each constraint costs (the same search run again without it; the best with every constraint "
             f"on: {costs[0].reference:.4g} mm):"]
    for c in costs:
        name, words, scale, unit = _MARGIN_WORDS.get(c.constraint, (c.constraint, "margin", 1.0, ""))
        margin = "-" if c.margin is None else f"{scale * c.margin:+.3g}{unit} {words}"
        if c.binds:
            there = "" if c.margin_there is None else f", {name} margin there {scale * c.margin_there:+.3g}{unit}"
            lines.append(f"    {name}: margin {margin}; binds: without it {c.objective:.4g} mm, it costs "
                         f"{c.cost:.4g} mm ({_gains_text(c.gains)}{there})")
        else:
            lines.append(f"    {name}: margin {margin}; does not bind: costs 0 mm")
    return lines


def _check_report(spec, estimate, substeps: int) -> str:
    limits = spec.limits
    lines = [f"tuning '{spec.name}': valid (definition {spec.definition}); base scenario {spec.base.name}, "
             f"{spec.objective} {spec.metric} over {spec.runs} runs",
             "  search: " + ", ".join(f"{p.name} in [{p.low:g}, {p.high:g}] {p.unit}" for p in spec.parameters),
             f"  differential evolution: population {spec.population}, {spec.generations} generations after the "
             f"first; polish: {spec.polish_evaluations} evaluations; at most {spec.max_evaluations} in all"]
    if limits.torque_noise_rms is not None:
        lines.append(f"  torque noise budget [{_force_units(spec.joints.force_units)}]: {_numbers(limits.torque_noise_rms)}"
                     + (" (the base gains' own)" if limits.torque_noise_from == "base" else ""))
    if limits.torque_limit is not None:
        lines.append(f"  torque limit [{_force_units(spec.joints.force_units)}]: {_numbers(limits.torque_limit)}")
    if limits.stability_margin is not None:
        lines.append(f"  stability margin: poles at real part <= -{limits.stability_margin:g} 1/s")
    if limits.min_damping_ratio is not None:
        lines.append(f"  damping ratio of the error dynamics kd / (2 sqrt(kp)) >= {limits.min_damping_ratio:g} on every "
                     "joint" + (" (the default)" if limits.damping_from == "default" else ""))
    if limits.max_overshoot is not None:
        lines.append(f"  overshoot of the error dynamics <= {100 * limits.max_overshoot:g} % on every joint")
    if limits.min_observer_bandwidth_ratio is not None:
        lines.append(f"  slowest observer mode / tracking bandwidth >= {limits.min_observer_bandwidth_ratio:g}")
    if limits.sampled_margin is not None:
        lines.append(f"  sampled loop ([controller] at {spec.base.controller.sample_rate:g} Hz): Ts lambda_max(Y M^-1) "
                     f"<= {1 - limits.sampled_margin:g} x its stability limit for each candidate's Kp, Kd"
                     + (" (the default)" if limits.sampled_from == "default" else "")
                     + "; the set is simulated with the continuous controller")
    lines.append("  the linear constraints can be met within the bounds")
    lines.append(f"  one evaluation: {spec.runs} runs of at most {estimate.steps:,} RK4 steps ({substeps} substeps at "
                 f"the high bounds), about {format_bytes(estimate.memory)}; at most "
                 f"{spec.max_evaluations * spec.runs * estimate.steps:.3g} run-steps in all")
    return "\n".join(lines)
