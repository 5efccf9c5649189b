"""Co-simulate a scenario's controller side in Python against a plant Co-Simulation FMU.

The Python side is the scenario's trajectory, controller, observer (and
sensor with noise), built by :func:`blocks.build_blocks` and wired by name
with :func:`control.interconnect`.  Its external inputs are the plant's
``q[i]`` and ``dq[i]`` and, with the observer, the torque ``tau[i]`` *that
the plant receives*: the observer estimates the disturbance from the torque
the plant actually got over each step (held, or following the same slope),
not from the controller's command as it would move within the step.  The
plant is the FMU, started where the scenario starts the arm and, by
default, given the scenario's true-robot and disturbance parameters (those
the FMU declares).

The coupling is the fixed-step master of :mod:`fmu.master`, by default the
best the FMU supports: for the exported plant the ``linear`` coupling
(:mod:`fmu.coupling`) -- a first-order hold on the torque, the plant's
outputs interpolated from their exact derivatives -- which is second order
in the communication step ``h`` because the plant has no direct
feedthrough; ``coupling="zoh"`` holds both ways and is first order.  The
README (section on the FMU) lists the differences to the monolithic loop
(:func:`blocks.simulate`) measured on the ``paper`` scenario.

Each run carries an error estimate from step doubling over its first
seconds: the same co-simulation at ``h`` and ``2 h``, their largest
difference divided by ``2^p - 1`` (``p`` the coupling's order).  A
convergence study (``dobkit fmu convergence``, :func:`fmu.cosim_convergence`)
measures the error against the monolithic loop itself.

The result has the same named outputs as :func:`blocks.simulate`
(``q``, ``dq``, ``q_ref``, ``dq_ref``, ``ddq_ref``, ``tau``, ``tau_dis``,
``d_hat`` with the observer, ``q_meas``/``dq_meas`` with noise, and the
lumped disturbance ``d``), so :func:`blocks.figure2.metrics.tracking_metrics`
and the figures work on it unchanged.
"""
from __future__ import annotations

from collections.abc import Callable

import control as ct
import numpy as np

from blocks.engines.budget import Budget
from blocks.figure2.derived import loop_response
from blocks.figure2.loop import LOOP_SIGNALS, build_blocks, initial_state
from blocks.figure2.physical_bounds import signal_bounds
from blocks.scenarios.scenario import Scenario, load_scenario

from .archive import ExtractionLimits, open_extracted
from .cosim_sampled import cosimulate_sampled
from .coupling import COUPLINGS
from .description import described, require_variables
from .errors import FMUError
from .master import CoSimulationError, cosimulate_system, validated_step, validated_time
from .scenario_values import plant_start_values

__all__ = ["cosimulate", "controller_side", "CoSimulationError"]



def controller_side(scenario: Scenario, observer: bool = True) -> ct.InterconnectedSystem:
    """Trajectory, controller, observer (and sensor) of a scenario, as the Python side of a co-simulation.

    Inputs: ``q[i]``, ``dq[i]`` (the plant's outputs) and, with the
    observer, ``tau[i]``: the torque the plant receives, which feeds the
    observer.  Outputs are the loop signals the Python side produces:
    ``q_ref``, ``dq_ref``, ``ddq_ref``, ``tau`` (the controller's command),
    and ``d_hat`` / ``q_meas`` / ``dq_meas`` when present.  A signal name is
    both an input and an output only for ``tau[i]``: the command goes out,
    the applied torque comes back.
    """
    blocks = build_blocks(scenario, observer=observer)
    names = scenario.robot.joints.signal_names
    side = [b for key, b in blocks.items() if key != "plant"]
    external = names("q") + names("dq") + (names("tau") if observer else [])
    sources = {label: b for b in side for label in b.output_labels}
    connections, consumers = [], {name: [] for name in external}
    for b in side:
        for label in b.input_labels:
            if label in consumers and not (label.startswith("tau[") and b.name == "controller"):
                consumers[label].append(f"{b.name}.{label}")
            elif label in sources:
                connections.append([f"{b.name}.{label}", f"{sources[label].name}.{label}"])
            else:
                raise CoSimulationError(f"block {b.name!r} reads {label!r}, which no block of the Python side gives")
    inputs = [name for name in external if consumers[name]]
    signals = ["q_ref", "dq_ref", "ddq_ref", "tau"] + (["d_hat"] if observer else [])
    if "sensor" in blocks:
        signals += ["q_meas", "dq_meas"]
    outputs = [name for sig in signals for name in names(sig)]
    return ct.interconnect(side, connections=connections, inplist=[consumers[name] for name in inputs], inputs=inputs,
                           outlist=[f"{sources[name].name}.{name}" for name in outputs], outputs=outputs,
                           name="controller_side", check_unused=False)


def _plant_variables(extracted, scenario: Scenario, parameters: str) -> set[str]:
    """Names of the FMU's variables, after checking it has the plant's signals of the scenario's joints and, for a
    dobkit plant FMU, that it is the scenario arm's plant (before instantiating)."""
    from .arm_match import check_scenario_arm
    md = described(extracted)
    source = f"{extracted.source} (as the plant of the loop)"
    names = scenario.robot.joints.signal_names
    require_variables(md, names("q") + names("dq") + names("tau_dis"), causality="output", source=source)
    require_variables(md, names("tau"), causality="input", source=source)
    try:
        check_scenario_arm(extracted, md, scenario, parameters)
    except FMUError as err:
        raise type(err)(f"{source}: {err}") from None
    return {v.name for v in md.modelVariables}


def _record_every(output_step: float, step: float) -> int:
    """How many communication steps make one output step; raises unless it is a whole number."""
    ratio = output_step / step
    k = int(round(ratio)) if np.isfinite(ratio) else 0
    if k < 1 or abs(ratio - k) > 1e-9 * max(1.0, ratio):
        finer = output_step / max(1, int(np.ceil(ratio))) if np.isfinite(ratio) else output_step
        raise CoSimulationError(f"the scenario's output step ({output_step:g} s) is not a whole multiple of the "
                                f"communication step h = {step:g} s; choose h = output_step / n (e.g. "
                                f"{finer:g} s) or change simulation.output_step")
    return k


# step doubling runs over at most this much of the start (s)
ESTIMATE_TIME = 1.0
_ORDER = {"zoh": 1, "linear": 2}


def cosimulate(fmu_path, scenario: Scenario | str = "paper", step: float = 1e-3, observer: bool = True,
               side_substeps: int = 1, parameters: str = "scenario", t_final: float | None = None,
               coupling: str | None = None, error_estimate: bool = True, budget: Budget | None = None,
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
        Communication step ``h`` (s), finite and > 0; ``t_final`` and the
        scenario's ``simulation.output_step`` must be whole numbers of steps
        (no interpolation: the result is recorded at communication points only).
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
    coupling : {"zoh", "linear"}, optional
        See :mod:`fmu.coupling`; default the best the FMU supports.  A scenario
        with a digital controller (``[controller]``) is co-simulated with its
        samples as the communication points (:mod:`fmu.cosim_sampled`): ``step``
        must be its sample period, any ``output_step`` is served (a step is
        split at an output point between samples), and there is no coupling error.
    error_estimate : bool
        Estimate the coupling error by step doubling over the first
        ``min(1 s, t_final)`` (two short extra runs, at ``h`` and ``2 h``).
    budget : Budget, optional
        Limits on steps and wall time (:meth:`blocks.engines.budget.Budget.from_env`).
    limits, extract_to :
        Archive size limits and extraction parent folder.
    progress : callable, optional
        Called with the fraction of time done.

    Returns
    -------
    control.TimeResponseData
        Outputs named as in :func:`blocks.simulate`, on the scenario's
        output grid; attributes ``scenario``, ``with_observer`` and ``cosim``
        (settings, the coupling used, and ``error_estimate``).

    Raises
    ------
    CoSimulationError
        If ``step`` is not a finite number > 0, ``output_step`` or
        ``t_final`` is not a whole number of steps ``h`` (naming both values),
        the coupling is unknown or unsupported, or a signal diverges.
    BudgetError
        If the runs would exceed the budget's steps, or exceed its wall time.
    FMUError
        (a subclass) for a bad FMU, missing variables, or an FMU error status
        during a step (naming the time and status).
    """
    step = validated_step(step)
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    t_end = s.simulation.t_final if t_final is None else validated_time(t_final, "t_final")
    if coupling is not None and coupling not in COUPLINGS:
        raise CoSimulationError(f"coupling must be one of {list(COUPLINGS)}, got {coupling!r}")
    budget = Budget.from_env() if budget is None else budget
    if s.controller is not None:        # a digital controller: its samples are the communication points
        if coupling not in (None, "zoh"):
            raise CoSimulationError(f"a digital controller holds its torque over each sample: the coupling is the "
                                    f"samples themselves, not {coupling!r}")
        extracted, owned = open_extracted(fmu_path, limits=limits, parent=extract_to)
        try:
            start = plant_start_values(s, _plant_variables(extracted, s, parameters), parameters)
            resp = cosimulate_sampled(extracted, s, step, t_end, observer=observer, start_values=start,
                                      output_step=s.simulation.output_step, budget=budget, progress=progress)
        finally:
            if owned:
                extracted.cleanup()
        resp.cosim = dict(resp.cosim, parameters=parameters, t_final=t_end,
                          error_estimate={"skipped": "no coupling error: the FMU's steps are the controller's "
                                                     "samples, with the torque held on both sides"})
        return resp
    record_every = _record_every(s.simulation.output_step, step)
    side = controller_side(s, observer=observer)
    side_x0 = initial_state(side, s)
    extracted, owned = open_extracted(fmu_path, limits=limits, parent=extract_to)
    try:
        start = plant_start_values(s, _plant_variables(extracted, s, parameters), parameters)
        run = dict(side_x0=side_x0, start_values=start, side_substeps=side_substeps, coupling=coupling,
                   budget=budget, bounds=lambda names: signal_bounds(names, s))
        raw = cosimulate_system(extracted, side, t_end, step, record_every=record_every, progress=progress, **run)
        estimate = (_step_doubling(extracted, side, t_end, step, raw.cosim["coupling"], run, s.robot.joints)
                    if error_estimate
                    else {"skipped": "not asked for (error_estimate=False)"})
    finally:
        if owned:
            extracted.cleanup()

    labels = list(raw.output_labels)
    signals = [sig for sig in LOOP_SIGNALS if observer or sig != "d_hat"]
    if s.noise is not None:
        signals += ["q_meas", "dq_meas"]
    wanted = [name for sig in signals for name in s.robot.joints.signal_names(sig)]
    absent = [n for n in wanted if n not in labels]
    if absent:
        raise CoSimulationError(f"the co-simulation did not produce signal(s) {absent}")
    outputs = np.asarray(raw.outputs)[[labels.index(n) for n in wanted]]
    title = (f"{s.name}: co-simulation with {raw.cosim['model']} (h = {step:g} s, {raw.cosim['coupling']} "
             f"coupling), {'with' if observer else 'without'} disturbance observer")
    states = np.asarray(raw.x) if raw.x is not None and np.size(raw.x) else None  # .states fails when None
    resp = loop_response(raw.time, outputs, states, wanted, list(side.state_labels), s, observer, title, "cosim")
    resp.cosim = dict(raw.cosim, parameters=parameters, t_final=t_end, error_estimate=estimate)
    return resp


def _step_doubling(extracted, side, t_end: float, step: float, coupling: str, run: dict, joints) -> dict:
    """Coupling error estimate: runs at ``h`` and ``2 h`` over the first seconds, ``|y_h - y_2h| / (2^p - 1)``."""
    p = _ORDER[coupling]
    n = int(np.floor(min(ESTIMATE_TIME, t_end) / (2 * step) + 1e-9))
    if n < 2:
        return {"skipped": f"t_final = {t_end:g} s is shorter than four steps h = {step:g} s"}
    span = n * 2 * step
    fine = cosimulate_system(extracted, side, span, step, record_every=2, **run)
    coarse = cosimulate_system(extracted, side, span, 2 * step, record_every=1, **run)
    labels = list(fine.output_labels)
    estimate = {"method": f"step doubling: the co-simulation at h and 2h over the first {span:g} s, "
                          f"max |y(h) - y(2h)| / (2^p - 1) with p = {p} ({coupling} coupling)",
                "t_final": span, "order": p, "units": {}}
    for sig in ("q", "d_hat", "tau"):
        names = [name for name in joints.signal_names(sig) if name in labels]
        if not names:
            continue
        rows = [labels.index(n) for n in names]
        gap = np.abs(np.asarray(fine.outputs)[rows] - np.asarray(coarse.outputs)[rows]).max(axis=1) / (2 ** p - 1)
        estimate[sig] = dict(zip(names, gap.tolist()))
        estimate["units"][sig] = list(joints.position_units if sig == "q" else joints.force_units)
    return estimate
