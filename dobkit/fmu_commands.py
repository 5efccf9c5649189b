"""``dobkit fmu ...`` subcommands: export, co-simulate and check the plant FMU.

::

    dobkit fmu export [--scenario S] [--fmi-version 2|3] [--substeps N] --out plant.fmu
    dobkit fmu cosim PLANT.fmu [--scenario S] [--step H] [--out DIR] [--no-figures]
    dobkit fmu convergence PLANT.fmu [--scenario S] [--steps 0.004,0.002,0.001,0.0005] [--out DIR]
    dobkit fmu check PLANT.fmu [--json]

Each is a thin layer over :func:`fmu.export_plant`,
:func:`fmu.cosimulate`, :func:`fmu.cosim_convergence` and
:func:`fmu.check_fmu`.  Each command extracts the FMU once.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["add_fmu_subcommands"]


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def _step_list(text: str) -> tuple[float, ...]:
    steps = tuple(_positive_float(part.strip()) for part in text.split(",") if part.strip())
    if len(set(steps)) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two different steps separated by commas, got {text!r}")
    return steps


def _cmd_export(args) -> int:
    from blocks import load_scenario
    from fmu.export import export_plant

    s = load_scenario(args.scenario)
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    path = export_plant(args.out, params=s.robot, disturbance=s.disturbance, fmi_version=args.fmi_version,
                        substeps=args.substeps, q0=q0, dq0=dq0)
    print(f"wrote {path} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation, scenario {s.name}, "
          f"{args.substeps} RK4 sub-steps per co-simulation step)")
    return 0


def _cmd_cosim(args) -> int:
    from analysis.experiment import comparison_metrics, default_out_dir, format_rms_table, staged_output
    from blocks import load_scenario
    from fmu.archive import extract_fmu
    from fmu.cosim import cosimulate

    s = load_scenario(args.scenario)
    out = Path(args.out) if args.out is not None else default_out_dir("dobkit-cosim")
    staging = staged_output(out)  # refuses a non-empty folder before any work
    runs = {}
    with extract_fmu(args.fmu) as extracted:  # once for both runs
        for key, observer in (("with_dob", True), ("without_dob", False)):
            runs[key] = cosimulate(extracted, s, step=args.step, observer=observer,
                                   side_substeps=args.side_substeps, parameters=args.parameters)
    info = runs["with_dob"].cosim
    metrics = comparison_metrics(s, runs["with_dob"], runs["without_dob"]) | {
        "cosimulation": {k: info[k] for k in ("fmu", "fmi_version", "model", "step", "side_substeps", "method",
                                              "parameters")},
    }
    figures_note = "figures: skipped (--no-figures)"
    with staging as stage:
        (stage / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
        (stage / "scenario.toml").write_text(s.to_toml())
        if not args.no_figures:
            from analysis.figures import paper_figures
            written = paper_figures(runs["with_dob"], runs["without_dob"], stage)
            figures_note = f"figures: {len(written)} files (PNG and SVG)"
    print(f"co-simulated {args.fmu} (FMI {info['fmi_version']}) with scenario {s.name}, h = {args.step:g} s")
    print(format_rms_table(metrics))
    print(figures_note)
    print(f"results written to {out}")
    return 0


def _cmd_convergence(args) -> int:
    from analysis.experiment import default_out_dir, staged_output
    from blocks import load_scenario
    from analysis.figures import convergence_figure
    from fmu.convergence import cosim_convergence

    s = load_scenario(args.scenario)
    out = Path(args.out) if args.out is not None else default_out_dir("dobkit-convergence")
    staging = staged_output(out)  # refuses a non-empty folder before the (long) study
    study = cosim_convergence(args.fmu, s, steps=args.steps, t_final=args.t_final,
                              side_substeps=args.side_substeps)
    figures_note = "figure: skipped (--no-figures)"
    with staging as stage:
        (stage / "convergence.json").write_text(json.dumps(study, indent=2) + "\n")
        (stage / "scenario.toml").write_text(s.to_toml())
        if not args.no_figures:
            convergence_figure(study, stage)
            figures_note = "figure: convergence.png, convergence.svg"
    print(f"co-simulation of {args.fmu} (FMI {study['fmi_version']}) against the monolithic loop, scenario "
          f"{s.name}, t_final = {study['t_final']:g} s")
    print("  h (s)      " + "  ".join(f"{n} ({u})".rjust(14) for n, u in study["units"].items()))
    for k, h in enumerate(study["steps"]):
        print(f"  {h:<10g} " + "  ".join(f"{study['errors'][n][k]:14.4e}" for n in study["units"]))
    print(f"fitted order {study['order']:.3f} (per joint: "
          + ", ".join(f"{v:.3f}" for v in study["order_per_joint"].values()) + ")")
    print(figures_note)
    print(f"results written to {out}")
    return 0


def _cmd_check(args) -> int:
    from fmu.check import check_fmu

    report = check_fmu(args.fmu, t_final=args.t_final, tolerance=args.tolerance)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        v = report["validation"]
        print(f"{report['path']}: FMI {report['fmi_version']}, model {report['model']}")
        print(f"  validation (fmpy): {'passed' if v['passed'] else 'FAILED'}")
        for problem in v["problems"]:
            print(f"    - {problem}")
        for key, label in (("model_exchange", "Model Exchange vs Python plant"),
                           ("co_simulation", "Co-Simulation vs exact ZOH solution")):
            part = report[key]
            if "skipped" in part:
                print(f"  {label}: skipped ({part['skipped']})")
            else:
                print(f"  {label}: max |error| {part['max_abs_error']:.3e} (tolerance {part['tolerance']:g}) "
                      f"{'passed' if part['passed'] else 'FAILED'}")
        print("passed" if report["passed"] else "FAILED")
    return 0 if report["passed"] else 1


def add_fmu_subcommands(subparsers) -> None:
    """Add ``fmu export``, ``fmu cosim``, ``fmu convergence`` and ``fmu check`` to a ``dobkit`` subparsers object."""
    fmu = subparsers.add_parser("fmu", help="export the plant as an FMU, co-simulate against it, check it")
    sub = fmu.add_subparsers(dest="fmu_command", required=True)

    exp = sub.add_parser("export", help="export the scenario's true plant as an FMU (ME + CS)")
    exp.add_argument("--scenario", default="paper", help="scenario name or TOML path (default: paper)")
    exp.add_argument("--fmi-version", type=int, choices=(2, 3), default=2, help="FMI version (default: 2)")
    exp.add_argument("--substeps", type=int, default=4,
                     help="RK4 steps per co-simulation communication step (default: 4)")
    exp.add_argument("--out", required=True, help="path of the .fmu file to write")
    exp.set_defaults(func=_cmd_export)

    cos = sub.add_parser("cosim", help="co-simulate the scenario's controller side against a plant FMU; "
                         "write metrics.json (as 'dobkit simulate') and figures")
    cos.add_argument("fmu", help="plant FMU (Co-Simulation)")
    cos.add_argument("--scenario", default="paper", help="scenario name or TOML path (default: paper)")
    cos.add_argument("--step", type=_positive_float, default=1e-3, help="communication step in s (default: 0.001)")
    cos.add_argument("--side-substeps", type=int, default=1,
                     help="RK4 steps of the Python side per communication step (default: 1)")
    cos.add_argument("--parameters", choices=("scenario", "fmu"), default="scenario",
                     help="set the FMU's plant parameters from the scenario (default) or keep the FMU's own")
    cos.add_argument("--out", default=None, help="output folder (default: a new folder under the current one)")
    cos.add_argument("--no-figures", action="store_true", help="write metrics only")
    cos.set_defaults(func=_cmd_cosim)

    con = sub.add_parser("convergence", help="co-simulate at several steps h against the monolithic loop; "
                         "write convergence.json (errors per h, fitted order) and a log-log figure")
    con.add_argument("fmu", help="plant FMU (Co-Simulation)")
    con.add_argument("--scenario", default="paper", help="scenario name or TOML path (default: paper)")
    con.add_argument("--steps", type=_step_list, default=(0.004, 0.002, 0.001, 0.0005),
                     help="communication steps in s, comma separated; each must divide the largest "
                          "(default: 0.004,0.002,0.001,0.0005)")
    con.add_argument("--t-final", type=_positive_float, default=None,
                     help="simulated time in s (default: the scenario's)")
    con.add_argument("--side-substeps", type=int, default=1,
                     help="RK4 steps of the Python side per communication step (default: 1)")
    con.add_argument("--out", default=None, help="output folder (default: a new folder under the current one)")
    con.add_argument("--no-figures", action="store_true", help="write convergence.json only")
    con.set_defaults(func=_cmd_convergence)

    chk = sub.add_parser("check", help="validate an FMU and compare the plant FMU with the Python plant")
    chk.add_argument("fmu", help="the .fmu file")
    chk.add_argument("--t-final", type=_positive_float, default=1.0, help="comparison length in s (default: 1)")
    chk.add_argument("--tolerance", type=_positive_float, default=1e-6,
                     help="largest allowed Model Exchange difference (default: 1e-6)")
    chk.add_argument("--json", action="store_true", help="print the full report as JSON")
    chk.set_defaults(func=_cmd_check)
