"""Co-simulate a scenario's controller side in Python against a plant Co-Simulation FMU.

The Python side is the scenario's trajectory, controller, observer (and
sensor with noise), built by :func:`dobkit.blocks.build_blocks` and wired
with :func:`control.interconnect`; its external inputs are the plant's
``q[i]`` and ``dq[i]``.  The plant is the FMU, started where the scenario
starts the arm and, by default, given the scenario's true-robot and
disturbance parameters (those the FMU declares).  The coupling is the
fixed-step master of :mod:`dobkit.fmu.master`: zero-order hold on the
exchanged signals, first-order in the communication step ``h``.

The result has the same named outputs as :func:`dobkit.blocks.simulate`
(``q``, ``dq``, ``q_ref``, ``dq_ref``, ``ddq_ref``, ``tau``, ``tau_dis``,
``d_hat`` with the observer, ``q_meas``/``dq_meas`` with noise, and the
lumped disturbance ``d``), so :func:`dobkit.analysis.metrics.tracking_metrics`
and the figures work on it unchanged.
"""
from __future__ import annotations

import warnings
from typing import Callable

import control as ct
import numpy as np

from ..blocks.loop import LOOP_SIGNALS, build_blocks, initial_state, lumped_disturbance
from ..blocks.scenario import Scenario, load_scenario
from .archive import ExtractionLimits
from .master import CoSimulationError, cosimulate_system
from .variables import plant_parameter_values

__all__ = ["cosimulate", "controller_side", "CoSimulationError"]

JOINTS = 4


def _names(prefix: str) -> list[str]:
    return [f"{prefix}[{i}]" for i in range(JOINTS)]


def controller_side(scenario: Scenario, observer: bool = True) -> ct.InterconnectedSystem:
    """Trajectory, controller, observer (and sensor) of a scenario: inputs ``q[i]``, ``dq[i]``.

    Outputs are the loop signals the Python side produces: ``q_ref``,
    ``dq_ref``, ``ddq_ref``, ``tau``, and ``d_hat`` / ``q_meas`` / ``dq_meas``
    when present.
    """
    blocks = build_blocks(scenario, observer=observer)
    side = [b for key, b in blocks.items() if key != "plant"]
    inputs = _names("q") + _names("dq")
    signals = ["q_ref", "dq_ref", "ddq_ref", "tau"] + (["d_hat"] if observer else [])
    if "sensor" in blocks:
        signals += ["q_meas", "dq_meas"]
    outputs = [n for sig in signals for n in _names(sig)]
    return ct.interconnect(side, inplist=inputs, inputs=inputs, outlist=outputs, outputs=outputs,
                           name="controller_side", check_unused=False)


def _plant_start_values(s: Scenario, fmu_variables: set[str] | None, parameters: str) -> dict:
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    values = {f"q[{i}]": float(q0[i]) for i in range(JOINTS)} | {f"dq[{i}]": float(dq0[i]) for i in range(JOINTS)}
    if parameters == "scenario":
        wanted = plant_parameter_values(s.robot, s.disturbance)
        if fmu_variables is not None:
            absent = sorted(set(wanted) - fmu_variables)
            if absent:
                warnings.warn(f"the FMU does not declare scenario parameter(s) {absent}; it uses its own values",
                              stacklevel=3)
            wanted = {k: v for k, v in wanted.items() if k in fmu_variables}
        values |= wanted
    elif parameters != "fmu":
        raise ValueError(f"parameters must be 'scenario' or 'fmu', got {parameters!r}")
    return values


def _plant_variables(fmu_path, limits, extract_to) -> set[str]:
    """Names of the FMU's variables, after checking it has the plant's signals (before instantiating it)."""
    from .archive import extract_fmu
    from .description import read_description, require_variables
    with extract_fmu(fmu_path, limits=limits, parent=extract_to) as extracted:
        md = read_description(extracted.root, str(fmu_path))
    source = f"{fmu_path} (as the plant of the loop)"
    require_variables(md, _names("q") + _names("dq") + _names("tau_dis"), causality="output", source=source)
    require_variables(md, _names("tau"), causality="input", source=source)
    return {v.name for v in md.modelVariables}


def cosimulate(fmu_path, scenario: Scenario | str = "paper", step: float = 1e-3, observer: bool = True,
               side_substeps: int = 1, parameters: str = "scenario", t_final: float | None = None,
               limits: ExtractionLimits | None = None, extract_to=None,
               progress: Callable[[float], None] | None = None) -> ct.TimeResponseData:
    """Run a scenario's Python side against a plant Co-Simulation FMU.

    Parameters
    ----------
    fmu_path : str or pathlib.Path
        Plant FMU (FMI 2 or 3, Co-Simulation) with inputs ``tau[i]`` and
        outputs ``q[i]``, ``dq[i]``, ``tau_dis[i]`` (e.g. from :func:`~dobkit.fmu.export_plant`).
    scenario : Scenario or str
        Scenario or its name/path (default ``paper``).
    step : float
        Communication step ``h`` (s); ``t_final`` must be a whole number of steps.
    observer : bool
        With or without the disturbance observer.
    side_substeps : int
        RK4 steps of the Python side per communication step.
    parameters : {"scenario", "fmu"}
        ``scenario``: set the FMU's robot and disturbance parameters to the
        scenario's true-plant values (those it declares; a warning lists the
        rest); ``fmu``: keep the FMU's own start values.
    t_final : float, optional
        End time (s); default the scenario's ``simulation.t_final``.
    limits, extract_to :
        Archive size limits and extraction parent folder.
    progress : callable, optional
        Called with the fraction of time done.

    Returns
    -------
    control.TimeResponseData
        Outputs named as in :func:`dobkit.blocks.simulate`, on the scenario's
        output grid when its ``output_step`` is a multiple of ``step`` (else at
        every communication point); attributes ``scenario``, ``with_observer``
        and ``cosim`` (settings).

    Raises
    ------
    FMUError
        (a subclass) for a bad FMU, missing variables, or an FMU error status
        during a step (naming the time and status).
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    t_end = s.simulation.t_final if t_final is None else float(t_final)
    side = controller_side(s, observer=observer)
    side_x0 = initial_state(side, s)
    names = _plant_variables(fmu_path, limits, extract_to)
    start = _plant_start_values(s, names, parameters)
    ratio = s.simulation.output_step / step
    record_every = int(round(ratio)) if abs(ratio - round(ratio)) < 1e-9 * max(1.0, ratio) and ratio >= 1 else 1
    raw = cosimulate_system(fmu_path, side, t_end, step, side_x0=side_x0, start_values=start,
                            side_substeps=side_substeps, record_every=record_every, limits=limits,
                            extract_to=extract_to, progress=progress)

    labels = list(raw.output_labels)
    signals = [sig for sig in LOOP_SIGNALS if observer or sig != "d_hat"]
    if s.noise is not None:
        signals += ["q_meas", "dq_meas"]
    wanted = [n for sig in signals for n in _names(sig)]
    absent = [n for n in wanted if n not in labels]
    if absent:
        raise CoSimulationError(f"the co-simulation did not produce signal(s) {absent}")
    outputs = np.asarray(raw.outputs)[[labels.index(n) for n in wanted]]
    pick = {sig: outputs[[wanted.index(n) for n in _names(sig)]].T for sig in ("q", "dq", "tau", "tau_dis")}
    d = lumped_disturbance(pick["q"], pick["dq"], pick["tau"], pick["tau_dis"], s).T
    title = (f"{s.name}: co-simulation with {raw.cosim['model']} (h = {step:g} s), "
             f"{'with' if observer else 'without'} disturbance observer")
    states = np.asarray(raw.x) if raw.x is not None and np.size(raw.x) else None  # .states fails when None
    resp = ct.TimeResponseData(raw.time, np.vstack([outputs, d]), states, output_labels=wanted + _names("d"),
                               state_labels=list(side.state_labels) if states is not None else None, title=title,
                               sysname="cosim", issiso=False, plot_inputs=False)
    resp.scenario = s
    resp.with_observer = observer
    resp.cosim = dict(raw.cosim, parameters=parameters, t_final=t_end)
    return resp
