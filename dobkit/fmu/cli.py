"""``dobkit fmu ...`` subcommands: export, co-simulate and check the plant FMU.

::

    dobkit fmu export [--scenario S] [--fmi-version 2|3] [--substeps N] --out plant.fmu
    dobkit fmu cosim PLANT.fmu [--scenario S] [--step H] [--out DIR] [--no-figures]
    dobkit fmu check PLANT.fmu [--json]

Each is a thin layer over :func:`dobkit.fmu.export_plant`,
:func:`dobkit.fmu.cosimulate` and :func:`dobkit.fmu.check_fmu`.
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


def _cmd_export(args) -> int:
    from ..blocks import load_scenario
    from .export import export_plant

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
    from .. import __version__
    from ..analysis.experiment import default_out_dir, format_rms_table, staged_output
    from ..analysis.metrics import DISTURBANCE_UNITS, JOINT_UNITS, tracking_metrics
    from ..blocks import load_scenario
    from .cosim import cosimulate

    s = load_scenario(args.scenario)
    out = Path(args.out) if args.out is not None else default_out_dir("dobkit-cosim")
    runs = {}
    for key, observer in (("with_dob", True), ("without_dob", False)):
        runs[key] = cosimulate(args.fmu, s, step=args.step, observer=observer, side_substeps=args.side_substeps,
                               parameters=args.parameters)
    info = runs["with_dob"].cosim
    metrics = {
        "scenario": s.name,
        "dobkit_version": __version__,
        "units": {"position": list(JOINT_UNITS), "disturbance": list(DISTURBANCE_UNITS)},
        "definitions": {
            "rms_position_error": "Eq. 13: sqrt(mean((q_ref - q)^2)) over the output grid, per joint",
            "rms_disturbance_error": "Eq. 14: sqrt(mean((d - d_hat)^2)), d = lumped disturbance on the nominal model",
        },
        "with_dob": tracking_metrics(runs["with_dob"]),
        "without_dob": tracking_metrics(runs["without_dob"]),
        "cosimulation": {k: info[k] for k in ("fmu", "fmi_version", "model", "step", "side_substeps", "method",
                                              "parameters")},
    }
    with staged_output(out) as stage:
        (stage / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
        (stage / "scenario.toml").write_text(s.to_toml())
        if not args.no_figures:
            try:
                from ..analysis.figures import paper_figures
            except ImportError:
                paper_figures = None
            if paper_figures is not None:
                paper_figures(runs["with_dob"], runs["without_dob"], stage)
    print(f"co-simulated {args.fmu} (FMI {info['fmi_version']}) with scenario {s.name}, h = {args.step:g} s")
    print(format_rms_table(metrics))
    print(f"results written to {out}")
    return 0


def _cmd_check(args) -> int:
    from .check import check_fmu

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
    """Add ``fmu export``, ``fmu cosim`` and ``fmu check`` to a ``dobkit`` subparsers object."""
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

    chk = sub.add_parser("check", help="validate an FMU and compare the plant FMU with the Python plant")
    chk.add_argument("fmu", help="the .fmu file")
    chk.add_argument("--t-final", type=_positive_float, default=1.0, help="comparison length in s (default: 1)")
    chk.add_argument("--tolerance", type=_positive_float, default=1e-6,
                     help="largest allowed Model Exchange difference (default: 1e-6)")
    chk.add_argument("--json", action="store_true", help="print the full report as JSON")
    chk.set_defaults(func=_cmd_check)
