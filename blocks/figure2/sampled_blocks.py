"""The digital Figure-2 loop's blocks: the sampled diagram of a scenario with a ``[controller]``, and its start state.

Built here and run by :func:`blocks.figure2.digital_loop.simulate_sampled` (numpy) or
:class:`blocks.engines.compiled.sampled.SampledEngine` (compiled); this module imports neither, so the
engines import it without importing each other.
"""
from __future__ import annotations

import numpy as np

from blocks.diagram.digital import (
    DigitalController,
    actuator,
    digital_controller,
    digital_observer,
    encoder,
    quantized,
)
from blocks.diagram.systems import plant, sensor, signal_names, trajectory_block
from blocks.engines.hybrid import HybridSystem

__all__ = ["sampled_loop", "sampled_initial_state", "SAMPLED_SIGNALS"]


#: The loop's outputs, per joint: the continuous loop's signals and the sampled ones.
SAMPLED_SIGNALS = ("q", "dq", "q_ref", "dq_ref", "ddq_ref", "tau", "d_hat", "tau_dis", "q_s", "dq_s", "tau_cmd")


def sampled_loop(scenario, observer: bool = True, plant_system=None) -> HybridSystem:
    """The digital Figure-2 loop of a scenario with a ``[controller]`` section.

    Parameters
    ----------
    scenario : Scenario
        With ``scenario.controller`` a :class:`~blocks.diagram.digital.DigitalController`.
    observer : bool
        With or without the disturbance observer.
    plant_system : control.NonlinearIOSystem, optional
        A replacement for the Python plant (continuous).
    """
    s, settings = scenario, scenario.controller
    if not isinstance(settings, DigitalController):
        raise ValueError(f"scenario '{s.name}' has no [controller] section: it describes a continuous controller")
    measured = "_meas" if s.noise is not None else ""
    blocks = [trajectory_block(s.trajectory, arm=s.robot),
              plant(s.robot, s.disturbance) if plant_system is None else plant_system,
              encoder(settings, measured=measured),
              digital_controller(s.nominal, s.kp, s.kd, settings, use_observer=observer), actuator(settings)]
    if observer:
        blocks.append(digital_observer(s.nominal, s.observer_gain, settings, s.observer_variant))
    if s.noise is not None:
        blocks.append(sensor(s.noise, arm=s.robot))
    signals = [sig for sig in SAMPLED_SIGNALS if observer or sig != "d_hat"]
    if s.noise is not None:
        signals += ["q_meas", "dq_meas"]
    outputs = [n for sig in signals for n in signal_names(sig, s.robot)]
    loop = HybridSystem(blocks, outlist=outputs, name="digital_dob_loop" if observer else "digital_ctc_loop")
    loop.scenario = s
    loop.with_observer = observer
    return loop


def sampled_initial_state(loop: HybridSystem, scenario) -> np.ndarray:
    """Start state: the arm on its reference (or the scenario's ``initial``), the encoder's previous sample
    consistent with the start velocity, ``d_hat(0)`` as for the continuous loop, and the actuator's buffer
    holding the torque computed at ``t = 0`` (the arm was being held by it).
    """
    s, settings = scenario, scenario.controller
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    d_hat0 = s.initial["d_hat"] if s.initial["d_hat"] is not None else np.zeros(s.robot.joints.count)
    x0 = np.zeros(loop.nstates)
    index, offset = {}, 0           # each block's own state names -> position in the loop's state
    for block in loop.syslist:
        for j, label in enumerate(block.state_labels):
            index.setdefault(label, offset + j)
        offset += block.nstates

    def put(prefix: str, values) -> None:
        for i, v in enumerate(values):
            if f"{prefix}[{i}]" in index:
                x0[index[f"{prefix}[{i}]"]] = v
    put("q", q0)
    put("dq", dq0)
    noise_q, noise_dq = s.noise.sample(0.0) if s.noise is not None else (0.0, 0.0)
    q_s0 = quantized(np.asarray(q0) + noise_q, np.array(settings.position_resolution))
    dq_s0 = np.asarray(dq0) + noise_dq
    put("q_prev", q_s0 - settings.period * dq_s0)          # the first difference is the start velocity
    put("v_prev", dq_s0)
    put("z", d_hat0 - s.observer_gain @ dq_s0)            # d_hat = Y dq + z
    if settings.delay:
        held = np.zeros(loop.plan.nsignals)
        y = loop.tick_outputs(0, x0, held)
        tau0 = _signal(loop, y, "tau_cmd")
        for j in range(settings.delay):
            put(f"buffer{j}", tau0)
    return x0


def _signal(loop: HybridSystem, y: np.ndarray, prefix: str) -> np.ndarray:
    """The block outputs ``prefix[i]`` from the vector of all block outputs."""
    names = [name for block in loop.system.syslist for name in block.output_labels]
    return np.array([y[names.index(n)] for n in signal_names(prefix, loop.scenario.robot)])
