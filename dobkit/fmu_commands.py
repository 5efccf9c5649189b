"""``dobkit fmu ...`` subcommands: export, co-simulate and check FMUs.

::

    dobkit fmu export [--scenario S | --arm scope4|panda|ur5|X.urdf [--tool-frame F] [--locked J1,J2]]
                      [--fmi-version 2|3] [--substeps N] --out plant.fmu [--force]
    dobkit fmu export-controller --scenario S --out controller.fmu [--fmi-version 2|3] [--force]
    dobkit fmu cosim PLANT.fmu [--scenario S] [--step H] [--coupling zoh|linear] [--out DIR] [--no-figures]
    dobkit fmu convergence PLANT.fmu [--scenario S] [--steps 0.004,0.002,0.001,0.0005] [--coupling ...] [--out DIR]
    dobkit fmu check ANY.fmu [--arm rrpr|scope4|panda|ur5|X.urdf [--tool-frame F] [--locked J1,J2]] [--json]

Each is a thin layer over :func:`fmu.export_plant`,
:func:`fmu.cosimulate`, :func:`fmu.cosim_convergence` and
:func:`fmu.check_fmu`.  Each command extracts the FMU once.  The
long-running ones take ``--max-steps`` and ``--max-seconds``
(:class:`blocks.engines.budget.Budget`): they estimate their steps first and refuse
beyond the budget.  Every JSON file or listing they write is strict JSON:
a value that is not a finite number is written as ``null`` and its place is
listed under ``non_finite_values``.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from dobkit.arguments import positive_number, whole_number

__all__ = ["add_fmu_subcommands", "strict_json"]

_positive_float = positive_number()
_positive_int = whole_number("the value")


def _step_list(text: str) -> tuple[float, ...]:
    steps = tuple(_positive_float(part.strip()) for part in text.split(",") if part.strip())
    if len(set(steps)) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two different steps separated by commas, got {text!r}")
    return steps


def strict_json(data) -> str:
    """``data`` as strict JSON text: non-finite floats become ``null``, listed under ``non_finite_values``
    (:func:`blocks.plumbing.outputs.metrics_json`, the one writer of every results file).

    Examples
    --------
    >>> import json
    >>> data = json.loads(strict_json({"a": [1.0, float("nan")]}))
    >>> data["a"], data["non_finite_values"]["paths"]
    ([1.0, None], ['a/1'])
    """
    from blocks.plumbing.outputs import metrics_json
    return metrics_json(data)[0]


def _budget(args):
    from blocks.engines.budget import Budget
    return Budget.from_env(memory=args.max_memory, steps=args.max_steps, seconds=args.max_seconds)


def _cmd_export(args) -> int:
    from blocks.scenarios.scenario import load_scenario

    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {out} is a folder; give the path of the .fmu file to write")
    if out.exists() and not args.force:
        raise ValueError(f"--out {out} exists; refusing to overwrite it (use --force to replace it)")
    _arm_flags_alone(args, scenario=args.scenario is not None)
    args.scenario = args.scenario or "paper"
    if args.arm is not None:
        arm = _export_arm(args)
        from fmu.export import export_plant
        path = export_plant(out, params=arm, fmi_version=args.fmi_version, substeps=args.substeps, force=args.force)
        print(f"wrote {path} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation, arm {arm.n} joints "
              f"{list(arm.joints.names)}, {args.substeps} RK4 sub-steps per co-simulation step; disturbance models "
              f"off, settable as start values; {_stops_phrase(arm.joints)})")
        return 0
    s = load_scenario(args.scenario)        # a bad scenario is refused before the exporter's heavy imports
    from fmu.export import export_plant
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    path = export_plant(out, params=s.robot, disturbance=s.disturbance, fmi_version=args.fmi_version,
                        substeps=args.substeps, q0=q0, dq0=dq0, force=args.force)
    print(f"wrote {path} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation, scenario {s.name}, "
          f"{args.substeps} RK4 sub-steps per co-simulation step; {_stops_phrase(s.robot.joints)})")
    return 0


def _stops_phrase(joints) -> str:
    """Which joints' ranges the exported plant enforces with end stops (docs/plant-fmu.md)."""
    bounded = [name for name, (lo, hi) in zip(joints.names, joints.limits) if math.isfinite(lo) or math.isfinite(hi)]
    return f"end stops at the range of {', '.join(bounded)}" if bounded else "no joint has a range: no end stops"


def _cmd_export_controller(args) -> int:
    from blocks.scenarios.scenario import load_scenario

    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {out} is a folder; give the path of the .fmu file to write")
    if out.exists() and not args.force:
        raise ValueError(f"--out {out} exists; refusing to overwrite it (use --force to replace it)")
    s = load_scenario(args.scenario)
    from fmu.controller_export import export_controller
    path = export_controller(out, s, fmi_version=args.fmi_version, force=args.force)
    c = s.controller
    print(f"wrote {path} (FMI {args.fmi_version}.0 Co-Simulation, scenario {s.name}: the digital controller at "
          f"{c.sample_rate:g} Hz, observer {c.observer_discretization}, velocity {c.velocity}, delay {c.delay}; "
          f"communication step = sample period {c.period:g} s; reference tabulated to t = "
          f"{s.simulation.t_final:g} s)")
    return 0


def _arm_flags_alone(args, scenario: bool = False) -> None:
    """Refuse flags that would be ignored: ``--tool-frame``/``--locked`` without a URDF ``--arm``, and ``--arm``
    beside ``--scenario`` (each names the plant)."""
    if args.arm is not None and scenario:
        raise ValueError(f"--arm {args.arm} and --scenario {args.scenario} both name the plant to export; give one "
                         "(--scenario exports that scenario's true plant, --arm an arm's plant)")
    if (args.tool_frame or args.locked) and (args.arm is None or args.arm == "rrpr"):
        given = " and ".join(f for f, v in (("--tool-frame", args.tool_frame), ("--locked", args.locked)) if v)
        raise ValueError(f"{given} {'go' if ' and ' in given else 'goes'} with --arm X.urdf (a URDF file's tool frame "
                         f"and locked joints); got {'--arm ' + args.arm if args.arm else 'no --arm'}")


def _export_arm(args):
    """The arm of ``fmu export --arm``: an example name or a URDF path with ``--tool-frame``."""
    from blocks.model.urdf import example_arm, load_urdf_arm
    from blocks.model.urdf.examples import example_names

    names = example_names()             # scope4 and every serial arm of example-robot-data (`dobkit arms`)
    if args.arm in names:
        if args.tool_frame or args.locked:
            raise ValueError(f"--arm {args.arm} is a built-in example with its own tool frame and locked joints; "
                             "--tool-frame and --locked go with a URDF path")
        return example_arm(args.arm)
    if not args.arm.lower().endswith(".urdf"):
        raise ValueError(f"--arm must be one of {names} or a path to a .urdf file, got {args.arm!r}")
    if not args.tool_frame:
        raise ValueError(f"--arm {args.arm} is a URDF file: give its tool frame with --tool-frame")
    locked, values = [], {}
    for entry in (j.strip() for j in (args.locked or "").split(",")):
        if not entry:
            continue
        name, _, value = entry.partition("=")
        locked.append(name.strip())
        if value:                       # NAME=VALUE: held there (rad, m), else at 0
            try:
                values[name.strip()] = float(value)
            except ValueError:
                raise ValueError(f"--locked {entry!r}: the position after '=' must be a number (rad, m), got "
                                 f"{value!r}") from None
    return load_urdf_arm(args.arm, args.tool_frame, locked=locked, locked_values=values)


def _estimate_line(estimate: dict) -> str:
    if "skipped" in estimate:
        return f"error estimate: skipped ({estimate['skipped']})"
    parts = []
    for sig, label in (("q", "q"), ("d_hat", "d_hat")):
        if sig in estimate:
            values = list(estimate[sig].values())
            parts.append(f"{label} " + ", ".join(f"{v:.1e}" for v in values)
                         + f" ({', '.join(estimate['units'][sig])})")
    return (f"estimated coupling error (step doubling over the first {estimate['t_final']:g} s, order "
            f"{estimate['order']}): " + "; ".join(parts))


def _cmd_cosim(args) -> int:
    from analysis.simulation.experiment import comparison_metrics, default_out_dir, format_rms_table, staged_output
    from blocks import load_scenario
    from blocks.plumbing.progress import StageProgress
    from fmu.archive import extract_fmu
    from fmu.cosim import cosimulate

    s = load_scenario(args.scenario)
    if s.controller is not None and args.side_substeps != 1:
        raise ValueError(f"--side-substeps {args.side_substeps}: scenario '{s.name}' has a digital controller "
                         f"([controller]), which is not integrated: its samples are the communication steps "
                         f"(--step {s.controller.period:g}); leave --side-substeps out")
    budget = _budget(args)
    out = Path(args.out) if args.out is not None else default_out_dir("dobkit-cosim")
    staging = staged_output(out)  # refuses a non-empty folder before any work
    runs = {}
    # one stage per run on standard error (a bar on a terminal, a line per stage and every few seconds elsewhere)
    display = StageProgress(enabled=not args.no_progress)
    with display, extract_fmu(args.fmu) as extracted:  # once for both runs
        for key, observer in (("with_dob", True), ("without_dob", False)):
            stage = f"co-simulation {'with' if observer else 'without'} observer"
            runs[key] = cosimulate(extracted, s, step=args.step, observer=observer, coupling=args.coupling,
                                   side_substeps=args.side_substeps, parameters=args.parameters, budget=budget,
                                   progress=lambda fraction, stage=stage: display(stage, fraction))
    info = runs["with_dob"].cosim
    # a digital controller's run (coupling "sampled") has no Python-side sub-steps or output derivatives
    metrics = comparison_metrics(s, runs["with_dob"], runs["without_dob"]) | {
        "cosimulation": {k: info[k] for k in ("fmu", "fmi_version", "model", "step", "side_substeps", "coupling",
                                              "output_derivatives", "output_step", "method", "parameters")
                         if k in info}
        | {"error_estimate": {key: run.cosim["error_estimate"] for key, run in runs.items()}},
    }
    figures_note = "figures: skipped (--no-figures)"
    with staging as stage:
        (stage / "metrics.json").write_text(strict_json(metrics))
        (stage / "scenario.toml").write_text(s.to_toml())
        if not args.no_figures:
            from analysis.simulation.figures import paper_figures
            written = paper_figures(runs["with_dob"], runs["without_dob"], stage)
            figures_note = f"figures: {len(written)} files (PNG and SVG)"
    coupling = ("the digital controller's samples as communication points" if info["coupling"] == "sampled"
                else f"{info['coupling']} coupling")
    print(f"co-simulated {args.fmu} (FMI {info['fmi_version']}) with scenario {s.name}, h = {args.step:g} s, "
          f"{coupling}")
    print(format_rms_table(metrics))
    print(_estimate_line(info["error_estimate"]) + " (with observer)")
    print(figures_note)
    print(f"results written to {out}")
    return 0


def _cmd_convergence(args) -> int:
    from analysis.simulation.experiment import default_out_dir, staged_output
    from analysis.simulation.figures import convergence_figure
    from blocks import load_scenario
    from fmu.convergence import cosim_convergence

    s = load_scenario(args.scenario)
    out = Path(args.out) if args.out is not None else default_out_dir("dobkit-convergence")
    staging = staged_output(out)  # refuses a non-empty folder before the (long) study
    study = cosim_convergence(args.fmu, s, steps=args.steps, t_final=args.t_final, side_substeps=args.side_substeps,
                              coupling=args.coupling, budget=_budget(args))
    figures_note = "figure: skipped (--no-figures)"
    with staging as stage:
        (stage / "convergence.json").write_text(strict_json(study))
        (stage / "scenario.toml").write_text(s.to_toml())
        if not args.no_figures:
            convergence_figure(study, stage, s.robot.joints)
            figures_note = "figure: convergence.png, convergence.svg"
    print(f"co-simulation of {args.fmu} (FMI {study['fmi_version']}, {study['coupling']} coupling) against the "
          f"monolithic loop, scenario {s.name}, t_final = {study['t_final']:g} s")
    print("  h (s)      " + "  ".join(f"{n} ({u})".rjust(14) for n, u in study["units"].items()))
    for k, h in enumerate(study["steps"]):
        print(f"  {h:<10g} " + "  ".join(f"{study['errors'][n][k]:14.4e}" for n in study["units"]))
    print(f"fitted order {study['order']:.3f} (per joint: "
          + ", ".join(f"{v:.3f}" for v in study["order_per_joint"].values()) + ")")
    print(figures_note)
    print(f"results written to {out}")
    return 0


def _verdict(passed: bool) -> str:
    return "passed" if passed else "FAILED"


_STAGE_LABELS = {"archive": "archive", "model_description": "model description", "validation": "validation (fmpy)",
                 "model_exchange": "Model Exchange", "simulate_fmu": "fmu.simulate_fmu (events, arrays)",
                 "co_simulation": "Co-Simulation", "me_vs_cs": "Model Exchange vs Co-Simulation",
                 "plant_comparison": "comparison with the Python plant"}


def _stage_line(report: dict, name: str) -> str:
    from fmu.check import stage
    part = stage(report, name)
    status = {"passed": "passed", "failed": "FAILED", "not applicable": "not applicable"}[part["status"]]
    return f"  {_STAGE_LABELS[name]}: {status} -- {part['why']}"


def _print_check(report: dict) -> None:
    interfaces = ", ".join(report.get("interfaces") or []) or "none"
    print(f"{report['path']}: FMI {report['fmi_version']}, model {report['model']}; interfaces: {interfaces}")
    for name in ("archive", "model_description"):
        if "passed" not in report[name] or not report[name]["passed"]:
            print(_stage_line(report, name))
    v = report["validation"]
    if "skipped" in v:
        print(_stage_line(report, "validation"))
    else:
        note = f" ({len(v['warnings'])} naming-convention warning(s))" if v.get("warnings") else ""
        print(f"  validation (fmpy): {_verdict(v['passed'])}{note}")
        for problem in v.get("errors", []):
            print(f"    - error: {problem.splitlines()[0]}")
        for problem in v.get("warnings", []):
            print(f"    - warning (variable-naming convention only; the FMU can still be used): "
                  f"{problem.splitlines()[0]}")
        if "error" in v:
            print(f"    the validation could not run: {v['error']}")
    me = report["model_exchange"]
    if "skipped" in me:
        print(_stage_line(report, "model_exchange"))
    elif "loads" not in me:
        print(_stage_line(report, "model_exchange"))
    elif not me.get("loads"):
        print(f"  Model Exchange: FAILED, fmu.load refuses it: {me['refused']}")
    else:
        run = me["run"]
        what = (f"loads as a block ({me['states']} states, {len(me['inputs'])} inputs, {len(me['outputs'])} "
                f"outputs, feedthrough {me['feedthrough'] or 'none'})")
        if "error" in run:
            print(f"  Model Exchange: {what}; the run FAILED: {run['error']}")
        else:
            print(f"  Model Exchange: {what}; {run['t_final']:g} s with inputs at their start values: outputs "
                  f"{'finite' if run['finite'] else 'NOT finite'} -- {_verdict(run['passed'])}")
    sim = report["simulate_fmu"]
    if sim.get("runs"):
        ended = f", the FMU ended the run at t = {sim['terminated']:g} s" if sim["terminated"] is not None else ""
        print(f"  fmu.simulate_fmu (events, arrays): {sim['t_final']:g} s, {sim['state_events']} state and "
              f"{sim['time_events']} time events{ended}; outputs {'finite' if sim['finite'] else 'NOT finite'} -- "
              f"{_verdict(sim['passed'])}")
    else:
        print(_stage_line(report, "simulate_fmu"))
    cs = report["co_simulation"]
    if "skipped" in cs:
        print(_stage_line(report, "co_simulation"))
    elif not cs.get("runs"):
        print(f"  Co-Simulation: FAILED to run: {cs['error']}")
    else:
        run = cs["run"]
        print(f"  Co-Simulation: {run['steps']} steps of {run['step']:g} s with inputs at their start values: outputs "
              f"{'finite' if run['finite'] else 'NOT finite'} -- {_verdict(cs['passed'])}")
        if not cs["couples"]:
            print(f"    {cs['refused']}")
    both = report["me_vs_cs"]
    if both.get("trivial"):
        print(f"  Model Exchange vs Co-Simulation: not applicable -- {both['skipped']}")
    elif "max_abs_difference" in both:
        within = both["max_abs_difference"] <= both["tolerance"]
        # the verdict follows the number: beyond the tolerance is never "passed", even when only the FMU's own
        # co-simulation solver is off (a finding, stated below, that does not fail the check)
        word = _verdict(both["passed"]) if within or not both["passed"] else "beyond the tolerance, a finding"
        print(f"  Model Exchange vs Co-Simulation: max |difference| {both['max_abs_difference']:.3e} (tolerance "
              f"{both['tolerance']:.3g}) {word}")
        if "finding" in both:
            print(f"    against the fine reference ({both['reference']}): {both['finding']}")
    elif "error" in both:
        print(_stage_line(report, "me_vs_cs"))
    plant = report["plant_comparison"]
    if "skipped" in plant:
        print(f"  comparison with the Python plant: skipped ({plant['skipped']})")
    elif "error" in plant:
        print(_stage_line(report, "plant_comparison"))
    if "arm" in plant:
        print(f"  comparison with the Python plant of {plant['arm']}:")
    for key, label in (("model_exchange", "Model Exchange vs Python plant"),
                       ("co_simulation", "Co-Simulation vs the same RK4 on the Python plant")):
        part = plant.get(key)
        if part is not None:
            print(f"  {label}: max |error| {part['max_abs_error']:.3e} (tolerance {part['tolerance']:g}) "
                  f"{_verdict(part['passed'])}")
            if part.get("why"):
                print(f"    {part['why']}")
            if "exact_zoh_error" in part:
                within = part["exact_zoh_within_tolerance"]
                print(f"    its integration error vs the exact ZOH solution: {part['exact_zoh_error']:.3e} "
                      f"({'within' if within else 'beyond'} {part['tolerance']:g})"
                      + ("" if within or "finding" not in part else f": a finding -- {part['finding']}"))
    stops = plant.get("end_stops")
    if stops is not None:
        print(f"  end stops ({len(stops['states'])} states beyond the joint ranges) vs their definition: max "
              f"relative error {stops['max_rel_error']:.3e} (tolerance {stops['tolerance']:g}) "
              f"{_verdict(stops['passed'])}")
    if "unusable" in report:
        print(f"  {report['unusable']}")
    print(_verdict(report["passed"]))


def _cmd_check(args) -> int:
    from fmu.check import check_fmu

    _arm_flags_alone(args)
    arm = None
    if args.arm == "rrpr":                 # the default scenario's arm, by its name
        from blocks.scenarios.scenario import default_arm
        arm = default_arm()
    elif args.arm is not None:
        arm = _export_arm(args)
    report = check_fmu(args.fmu, t_final=args.t_final, tolerance=args.tolerance, cs_step=args.cs_step,
                       me_cs_tolerance=args.me_cs_tolerance, budget=_budget(args), arm=arm)
    if args.json:
        print(strict_json(report), end="")
    else:
        _print_check(report)
    return 0 if report["passed"] else 1


def _add_budget(parser) -> None:
    """The project's budget flags (one spelling for every command: :func:`dobkit.arguments.add_budget_flags`)."""
    from dobkit.arguments import add_budget_flags
    add_budget_flags(parser, "the command stops with a clear message when they run out")

def add_fmu_subcommands(subparsers) -> None:
    """Add ``fmu export``, ``fmu cosim``, ``fmu convergence`` and ``fmu check`` to a ``dobkit`` subparsers object."""
    fmu = subparsers.add_parser("fmu", help="export the plant as an FMU, co-simulate against it, check any FMU")
    sub = fmu.add_subparsers(dest="fmu_command", required=True)

    exp = sub.add_parser("export", help="export the scenario's true plant as an FMU (ME + CS)")
    exp.add_argument("--scenario", default=None, help="scenario name or TOML path (default: paper)")
    exp.add_argument("--fmi-version", type=int, choices=(2, 3), default=2, help="FMI version (default: 2)")
    exp.add_argument("--substeps", type=int, default=4,
                     help="RK4 steps per co-simulation communication step (default: 4)")
    exp.add_argument("--out", required=True, help="path of the .fmu file to write (an existing file is refused)")
    exp.add_argument("--force", action="store_true", help="replace an existing --out file")
    exp.add_argument("--arm", default=None,
                     help="export this arm's plant instead of the scenario's: scope4, panda, ur5 or a .urdf path")
    exp.add_argument("--tool-frame", default=None, help="tool frame of a --arm URDF file")
    exp.add_argument("--locked", default=None,
                     help="comma-separated joints of a --arm URDF file to lock, each held at 0 or NAME=VALUE (rad, m)")
    exp.set_defaults(func=_cmd_export)

    ctl = sub.add_parser("export-controller", help="export the scenario's digital controller ([controller]) as a "
                         "Co-Simulation FMU: inputs q[i], dq[i], outputs tau[i], d_hat[i]; one step per sample")
    ctl.add_argument("--scenario", required=True, help="scenario name or TOML path with a [controller] section "
                     "(e.g. paper-digital)")
    ctl.add_argument("--fmi-version", type=int, choices=(2, 3), default=2,
                     help="FMI version (default: 2)")
    ctl.add_argument("--out", required=True, help="path of the .fmu file to write (an existing file is refused)")
    ctl.add_argument("--force", action="store_true", help="replace an existing --out file")
    ctl.set_defaults(func=_cmd_export_controller)

    cos = sub.add_parser("cosim", help="co-simulate the scenario's controller side against a plant FMU; "
                         "write metrics.json (as 'dobkit simulate', plus the coupling and its error estimate) "
                         "and figures")
    cos.add_argument("fmu", help="plant FMU (Co-Simulation)")
    cos.add_argument("--scenario", default="paper", help="scenario name or TOML path (default: paper)")
    cos.add_argument("--step", type=_positive_float, default=1e-3, help="communication step in s (default: 0.001)")
    cos.add_argument("--coupling", choices=("zoh", "linear"), default=None,
                     help="zoh: hold both ways (first order); linear: first-order hold into the FMU, interpolated "
                          "FMU outputs (second order); default: the best the FMU supports")
    cos.add_argument("--side-substeps", type=_positive_int, default=1,
                     help="RK4 steps of the Python side per communication step (default: 1)")
    cos.add_argument("--parameters", choices=("scenario", "fmu"), default="scenario",
                     help="set the FMU's plant parameters from the scenario (default) or keep the FMU's own")
    cos.add_argument("--out", default=None, help="output folder (default: a new folder under the current one)")
    cos.add_argument("--no-figures", action="store_true", help="write metrics only")
    cos.add_argument("--no-progress", action="store_true", help="no progress display on standard error")
    _add_budget(cos)
    cos.set_defaults(func=_cmd_cosim)

    con = sub.add_parser("convergence", help="co-simulate at several steps h against the monolithic loop; "
                         "write convergence.json (errors per h, fitted order) and a log-log figure")
    con.add_argument("fmu", help="plant FMU (Co-Simulation)")
    con.add_argument("--scenario", default="paper", help="scenario name or TOML path (default: paper)")
    con.add_argument("--steps", type=_step_list, default=(0.004, 0.002, 0.001, 0.0005),
                     help="communication steps in s, comma separated; each must divide the largest "
                          "(default: 0.004,0.002,0.001,0.0005)")
    con.add_argument("--coupling", choices=("zoh", "linear"), default=None,
                     help="coupling of every run (default: the best the FMU supports)")
    con.add_argument("--t-final", type=_positive_float, default=None,
                     help="simulated time in s (default: the scenario's)")
    con.add_argument("--side-substeps", type=_positive_int, default=1,
                     help="RK4 steps of the Python side per communication step (default: 1)")
    con.add_argument("--out", default=None, help="output folder (default: a new folder under the current one)")
    con.add_argument("--no-figures", action="store_true", help="write convergence.json only")
    _add_budget(con)
    con.set_defaults(func=_cmd_convergence)

    chk = sub.add_parser("check", help="validate any FMU, say whether it loads and runs with dobkit (and why "
                         "not), compare its interfaces, and compare the plant FMU with the Python plant; runs "
                         "the FMU's native code: check untrusted FMUs in a sandbox")
    chk.add_argument("fmu", help="the .fmu file")
    chk.add_argument("--t-final", type=_positive_float, default=None,
                     help="length of the runs in s (default: 1, or the FMU's default stop time when earlier)")
    chk.add_argument("--cs-step", type=_positive_float, default=None,
                     help="communication step of the Co-Simulation runs in s (default: 0.01, or the FMU's default "
                          "step size when it cannot vary its step, as a sampled controller)")
    chk.add_argument("--tolerance", type=_positive_float, default=1e-6,
                     help="largest allowed difference to the Python plant (default: 1e-6)")
    chk.add_argument("--me-cs-tolerance", type=_positive_float, default=1e-4,
                     help="largest allowed Model Exchange / Co-Simulation difference, relative to max(1, max|y|) "
                          "(default: 1e-4)")
    chk.add_argument("--json", action="store_true", help="print the full report as (strict) JSON")
    chk.add_argument("--arm", default=None,
                     help="hold a dobkit plant FMU against this arm: rrpr (the paper's, Table 1), scope4, panda, "
                          "ur5 or a .urdf path (default: the FMU's own Table-1 values, or the arm its export "
                          "recorded in it)")
    chk.add_argument("--tool-frame", default=None, help="tool frame of a --arm URDF file")
    chk.add_argument("--locked", default=None,
                     help="comma-separated joints of a --arm URDF file to lock, each held at 0 or NAME=VALUE (rad, m)")
    _add_budget(chk)
    chk.set_defaults(func=_cmd_check)
