"""The paper's experiment end to end: simulate with and without the observer, write results.

:func:`run_experiment` is what ``dobkit simulate`` does; the output folder gets

* ``metrics.json``: per-joint metrics of both runs (Table 3 and more), with units;
* ``timeseries.csv``: every signal of both runs on the uniform output grid;
* ``scenario.toml``: the complete scenario used (re-running it reproduces the numbers);
* ``fig4..fig8`` as PNG and/or SVG (``figure_formats``).

Results are first written to a staging folder beside the target and moved
into place only when everything succeeded, so a failed run leaves no partial
output behind.
"""
from __future__ import annotations

import csv
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blocks import Scenario, __version__, load_scenario, simulate
from blocks.figure2.metrics import tracking_metrics
from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace
from blocks.plumbing.outputs import default_out_dir, metrics_json, staged_output

__all__ = ["ExperimentResult", "run_experiment", "comparison_metrics", "format_rms_table", "default_out_dir",
           "staged_output"]


@dataclass
class ExperimentResult:
    """What :func:`run_experiment` produced."""

    scenario: Scenario
    with_dob: object
    without_dob: object
    metrics: dict
    out_dir: Path | None
    files: list


def run_experiment(scenario: Scenario | str = "paper", out_dir: Path | str | None = None,
                   progress: Callable[[str, float], None] | None = None, figures: bool = True,
                   engine: str = "auto", figure_formats=("png", "svg")) -> ExperimentResult:
    """Simulate a scenario with and without the observer and write the results.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario or its name/path (default: the built-in ``paper``).
    out_dir : path, optional
        Output folder (must not exist or be empty).  None: compute only, write nothing.
    progress : callable, optional
        ``progress(stage, fraction)`` as the simulations advance.
    figures : bool
        Write Figures 4-8.
    engine : {"auto", "compiled", "fast", "python-control"}
        The engine of both runs (see :func:`blocks.simulate`).
    figure_formats : sequence of {"png", "svg"}
        The formats of Figures 4-8 (``dobkit simulate`` writes PNG unless ``--svg``).

    Returns
    -------
    ExperimentResult
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    staging = staged_output(Path(out_dir)) if out_dir is not None else None   # refuse a bad folder before any work
    runs = {}
    for key, with_observer in (("with_dob", True), ("without_dob", False)):
        stage = f"simulating {'with' if with_observer else 'without'} observer"
        runs[key] = simulate(s, observer=with_observer, engine=engine,
                             progress=(lambda f, st=stage: progress(st, f)) if progress else None)
    metrics = comparison_metrics(s, runs["with_dob"], runs["without_dob"])
    metrics["engine"] = getattr(runs["with_dob"], "engine", engine)      # which engine ran both runs
    files: list[Path] = []
    if out_dir is not None:
        target = Path(out_dir)
        with staging as stage:
            # strict JSON, as every results file: an infinite RMS error is null, its place listed (not 'Infinity')
            (stage / "metrics.json").write_text(metrics_json(metrics)[0])
            (stage / "scenario.toml").write_text(s.to_toml())
            _write_timeseries(stage / "timeseries.csv", runs)
            if figures:
                if progress:
                    progress("writing figures", 0.0)
                from analysis.simulation.figures import paper_figures  # matplotlib's setup only when drawing

                paper_figures(runs["with_dob"], runs["without_dob"], stage, formats=figure_formats)
        files = sorted(target.iterdir())
    return ExperimentResult(s, runs["with_dob"], runs["without_dob"], metrics, Path(out_dir) if out_dir else None,
                            files)


def comparison_metrics(scenario: Scenario, with_dob, without_dob) -> dict:
    """The ``metrics.json`` content for a run with and a run without the observer (Table 3 and more).

    Returns
    -------
    dict
        ``scenario``, ``dobkit_version``, ``units`` (per joint of the scenario's arm), ``definitions`` and the
        :func:`~blocks.figure2.metrics.tracking_metrics` of each run under
        ``with_dob`` and ``without_dob``.
    """
    joints = scenario.robot.joints
    return {
        "scenario": scenario.name,
        "dobkit_version": __version__,
        "joints": list(joints.names),
        "units": {"position": list(joints.position_units), "disturbance": list(joints.force_units)},
        "definitions": {
            "rms_position_error": "Eq. 13: sqrt(mean((q_ref - q)^2)) over the output grid, per joint",
            "rms_disturbance_error": "Eq. 14: sqrt(mean((d - d_hat)^2)), d = lumped disturbance on the nominal model",
        },
        "with_dob": tracking_metrics(with_dob),
        "without_dob": tracking_metrics(without_dob),
    }


def _write_timeseries(path: Path, runs: dict) -> None:
    first = next(iter(runs.values()))
    columns, header = [np.asarray(first.time)], ["time_s"]
    for key, resp in runs.items():
        header += [f"{key}.{label}" for label in resp.output_labels]
        columns += list(np.asarray(resp.outputs))
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerow(header)
        # the rows as csv.writer writes floats (repr, comma, CRLF; a float never needs quotes), a third faster
        fh.write("".join(",".join(map(repr, row)) + "\r\n" for row in np.column_stack(columns).tolist()))


def format_rms_table(metrics: dict, arm: ArmModel | None = None) -> str:
    """Table 3 (the RMS errors of both runs, every joint, with units) as plain text.

    Parameters
    ----------
    metrics : dict
        What :func:`comparison_metrics` returns (``units`` and the two runs).
    arm : blocks.model.arm.ArmModel, optional
        The arm.  None or the paper's arm (:attr:`~blocks.model.arm.ArmModel.paper`): the paper's layout, one column
        per joint.  Any other arm: one row per joint, ``Joint i (name)`` with the joint's units, so that any
        number of joints fits.
    """
    if arm is not None and arm.paper is None:
        return _rms_rows(metrics, arm.joints)
    units = metrics["units"]
    width = 37                  # the longest label, "Disturbance tracking, with observer", and two spaces
    head = f"{'RMS error':<{width}}" + "".join(f"{f'Joint {i + 1}':>14}" for i in range(len(units["position"])))
    unit_row = f"{'':<{width}}" + "".join(f"{'(' + u + ')':>14}" for u in units["position"])
    rows = [head, "-" * len(head)]
    for key, label in (("with_dob", "with observer"), ("without_dob", "without observer")):
        m = metrics[key]
        rows.append(f"{'Position tracking, ' + label:<{width}}" + "".join(f"{v:>14.4e}" for v in m["rms_position_error"]))
    rows.append(unit_row)
    if "rms_disturbance_error" in metrics["with_dob"]:
        rows.append(f"{'Disturbance tracking, with observer':<{width}}"
                    + "".join(f"{v:>14.4e}" for v in metrics["with_dob"]["rms_disturbance_error"]))
        rows.append(f"{'':<{width}}" + "".join(f"{'(' + u + ')':>14}" for u in units["disturbance"]))
    return "\n".join(rows + _tool_lines(metrics))


def _tool_lines(metrics: dict) -> list[str]:
    return [f"Worst tool-tip error, {label}: {metrics[key]['max_tool_position_error_mm']:.3f} mm"
            for key, label in (("with_dob", "with observer"), ("without_dob", "without observer"))
            if "max_tool_position_error_mm" in metrics[key]]


def _rms_rows(metrics: dict, joints: JointSpace) -> str:
    """Table 3 turned: one row per joint (any count), position errors in its position unit, d - d_hat in its force
    unit."""
    units = metrics["units"]
    n = joints.count
    if len(units["position"]) != n:
        raise ValueError(f"metrics hold {len(units['position'])} joints, the arm has {n} ({', '.join(joints.names)})")
    with_dob, without_dob = metrics["with_dob"], metrics["without_dob"]
    disturbance = with_dob.get("rms_disturbance_error")
    columns = [("position, with observer", with_dob["rms_position_error"], units["position"]),
               ("position, without observer", without_dob["rms_position_error"], units["position"])]
    if disturbance is not None:
        columns.append(("d - d_hat, with observer", disturbance, units["disturbance"]))
    width = max(len("RMS error"), *(len(label) for label in joints.labels)) + 2
    head = f"{'RMS error':<{width}}" + "".join(f"{title:>{max(len(title), 12) + 2}}{'':<5}" for title, _, _ in columns)
    rows = [head.rstrip(), "-" * len(head.rstrip())]
    for i, label in enumerate(joints.labels):
        rows.append((f"{label:<{width}}" + "".join(f"{values[i]:>{max(len(title), 12) + 2}.4e} {unit[i]:<4}"
                                                     for title, values, unit in columns)).rstrip())
    return "\n".join(rows + _tool_lines(metrics))
