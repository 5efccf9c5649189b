"""Co-simulate a scenario's controller side in Python against a plant Co-Simulation FMU.

The Python side is the scenario's trajectory, controller, observer (and
sensor with noise), built by :func:`blocks.build_blocks` and wired
with :func:`control.interconnect`; its external inputs are the plant's
``q[i]`` and ``dq[i]``.  The plant is the FMU, started where the scenario
starts the arm and, by default, given the scenario's true-robot and
disturbance parameters (those the FMU declares).  The coupling is the
fixed-step master of :mod:`fmu.master`: zero-order hold on the
exchanged signals, first-order in the communication step ``h``.

Accuracy.  The zero-order-hold coupling is *first order* in ``h``: the
plant sees the torque of ``t_k`` over the whole step and the controller the
state of ``t_k``, a delay of up to one step in each direction, so the
difference to the monolithic loop (:func:`blocks.simulate`) falls
like ``h``, not like the RK4 integration inside each side: halving ``h``
halves the difference.  The RMS metrics of Eq. 13-14 move with ``h`` as
well; the README (section on the FMU) lists the differences measured on the
``paper`` scenario.  Choose h from a convergence study (``dobkit fmu
convergence``, :func:`fmu.cosim_convergence`) or a comparison with the
monolithic run before trusting co-simulated numbers.

Because the plant has no direct feedthrough (its outputs ``q``, ``dq``,
``tau_dis`` do not depend on ``tau``), a second-order scheme is possible:
advance the plant first over ``[t_k, t_k + h]`` with the torque extrapolated
linearly from the last two communication points (FMI 2
``fmi2SetRealInputDerivatives``, which the exported plant refuses today),
then advance the Python side with the plant outputs interpolated between
``t_k`` and ``t_k + h``, with no algebraic loop to iterate.  It is not
implemented.

The result has the same named outputs as :func:`blocks.simulate`
(``q``, ``dq``, ``q_ref``, ``dq_ref``, ``ddq_ref``, ``tau``, ``tau_dis``,
``d_hat`` with the observer, ``q_meas``/``dq_meas`` with noise, and the
lumped disturbance ``d``), so :func:`blocks.metrics.tracking_metrics`
and the figures work on it unchanged.
"""
from __future__ import annotations

from typing import Callable

import control as ct
import numpy as np

from blocks.loop import LOOP_SIGNALS, build_blocks, initial_state, lumped_disturbance
from blocks.scenario import Scenario, load_scenario
from .archive import ExtractionLimits, open_extracted
from .description import described, require_variables
from .master import CoSimulationError, cosimulate_system
from .scenario_values import plant_start_values
from blocks.joints import RRPR_JOINTS

__all__ = ["cosimulate", "controller_side", "CoSimulationError"]

JOINTS = RRPR_JOINTS.count


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


def _plant_variables(extracted) -> set[str]:
    """Names of the FMU's variables, after checking it has the plant's signals (before instantiating it)."""
    md = described(extracted)
    source = f"{extracted.source} (as the plant of the loop)"
    require_variables(md, _names("q") + _names("dq") + _names("tau_dis"), causality="output", source=source)
    require_variables(md, _names("tau"), causality="input", source=source)
    return {v.name for v in md.modelVariables}


def _record_every(output_step: float, step: float) -> int:
    """How many communication steps make one output step; raises unless it is a whole number."""
    ratio = output_step / step
    k = int(round(ratio))
    if k < 1 or abs(ratio - k) > 1e-9 * max(1.0, ratio):
        raise CoSimulationError(f"the scenario's output step ({output_step:g} s) is not a whole multiple of the "
                                f"communication step h = {step:g} s; choose h = output_step / n (e.g. "
                                f"{output_step / max(1, int(np.ceil(ratio))):g} s) or change simulation.output_step")
    return k


def cosimulate(fmu_path, scenario: Scenario | str = "paper", step: float = 1e-3, observer: bool = True,
               side_substeps: int = 1, parameters: str = "scenario", t_final: float | None = None,
               limits: ExtractionLimits | None = None, extract_to=None,
               progress: Callable[[float], None] | None = None) -> ct.TimeResponseData:
    """Run a scenario's Python side against a plant Co-Simulation FMU.

    Parameters
    ----------
    fmu_path : str, pathlib.Path or ExtractedFMU
        Plant FMU (FMI 2 or 3, Co-Simulation) with inputs ``tau[i]`` and
        outputs ``q[i]``, ``dq[i]``, ``tau_dis[i]`` (e.g. from
        :func:`~fmu.export_plant`), or an extraction of one to reuse
        (several runs of one command then extract the archive once).
    scenario : Scenario or str
        Scenario or its name/path (default ``paper``).
    step : float
        Communication step ``h`` (s); ``t_final`` and the scenario's
        ``simulation.output_step`` must be whole numbers of steps (no
        interpolation: the result is recorded at communication points only).
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
        Outputs named as in :func:`blocks.simulate`, on the scenario's
        output grid; attributes ``scenario``, ``with_observer`` and ``cosim`` (settings).

    Raises
    ------
    CoSimulationError
        If ``output_step`` or ``t_final`` is not a whole number of steps ``h`` (naming both values).
    FMUError
        (a subclass) for a bad FMU, missing variables, or an FMU error status
        during a step (naming the time and status).
    """
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    t_end = s.simulation.t_final if t_final is None else float(t_final)
    side = controller_side(s, observer=observer)
    side_x0 = initial_state(side, s)
    record_every = _record_every(s.simulation.output_step, step)
    extracted, owned = open_extracted(fmu_path, limits=limits, parent=extract_to)
    try:
        start = plant_start_values(s, _plant_variables(extracted), parameters)
        raw = cosimulate_system(extracted, side, t_end, step, side_x0=side_x0, start_values=start,
                                side_substeps=side_substeps, record_every=record_every, progress=progress)
    finally:
        if owned:
            extracted.cleanup()

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
