"""The Figure-2 loop with the digital controller of :mod:`blocks.digital`: building it and running it.

The continuous plant and trajectory (and the sensor, with measurement
noise) run in continuous time; the encoder, controller, actuator and
observer are sampled at ``controller.sample_rate``.  See
:mod:`blocks.hybrid` for how such a diagram is simulated.
"""
from __future__ import annotations

from collections.abc import Callable

import control as ct
import numpy as np

from .digital import (
    DigitalController,
    actuator,
    digital_controller,
    digital_observer,
    encoder,
    euler_stability_limit,
    quantized,
)
from .hybrid import HybridSystem
from .kernels import arm_constants
from .kernels import lumped_disturbance as lumped_disturbance_rows
from .systems import plant, sensor, signal_names, trajectory_block

__all__ = ["sampled_loop", "sampled_initial_state", "simulate_sampled", "check_observer_rate",
           "SAMPLED_SIGNALS"]

#: The loop's outputs, per joint: the continuous loop's signals and the sampled ones.
SAMPLED_SIGNALS = ("q", "dq", "q_ref", "dq_ref", "ddq_ref", "tau", "d_hat", "tau_dis", "q_s", "dq_s", "tau_cmd")


def sampled_loop(scenario, observer: bool = True, plant_system=None) -> HybridSystem:
    """The digital Figure-2 loop of a scenario with a ``[controller]`` section.

    Parameters
    ----------
    scenario : Scenario
        With ``scenario.controller`` a :class:`~blocks.digital.DigitalController`.
    observer : bool
        With or without the disturbance observer.
    plant_system : control.NonlinearIOSystem, optional
        A replacement for the Python plant (continuous).
    """
    s, settings = scenario, scenario.controller
    if not isinstance(settings, DigitalController):
        raise ValueError(f"scenario '{s.name}' has no [controller] section: it describes a continuous controller")
    measured = "_meas" if s.noise is not None else ""
    blocks = [trajectory_block(s.trajectory), plant(s.robot, s.disturbance) if plant_system is None else plant_system,
              encoder(settings, measured=measured),
              digital_controller(s.nominal, s.kp, s.kd, settings, use_observer=observer), actuator(settings)]
    if observer:
        blocks.append(digital_observer(s.nominal, s.observer_gain, settings, s.observer_variant))
    if s.noise is not None:
        blocks.append(sensor(s.noise))
    signals = [sig for sig in SAMPLED_SIGNALS if observer or sig != "d_hat"]
    if s.noise is not None:
        signals += ["q_meas", "dq_meas"]
    outputs = [n for sig in signals for n in signal_names(sig)]
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
    return np.array([y[names.index(n)] for n in signal_names(prefix)])


def check_observer_rate(scenario, samples: int = 201) -> None:
    """Refuse, before a run, an observer gain that the sample rate makes unstable.

    In the loop -- the controller subtracts ``d_hat`` and the plant
    integrates the held torque -- the estimate's error follows
    ``e_{k+1} = (I - Ts Y M^-1) e_k`` for both discretizations of the
    observer (``docs/model.md``, "Digital observer"): it is stable when
    ``|1 - Ts lambda| < 1`` for every eigenvalue of ``Y M^-1(q)``, checked at
    the configurations of the reference path on the nominal model
    (:func:`blocks.digital.euler_stability_limit`).

    Raises
    ------
    blocks.scenario.ScenarioError
        Naming ``controller.sample_rate`` and ``gains.observer``, with the
        largest stable gain at this rate and the lowest stable rate for this gain.
    """
    from .scenario import ScenarioError
    s, settings = scenario, scenario.controller
    times = np.linspace(0.0, s.simulation.t_final, samples)
    q_path = np.array([s.trajectory.evaluate(float(t))[0] for t in times])
    margin = euler_stability_limit(s.nominal, s.observer_gain, settings.period, q_path)
    if margin["stable"]:
        return
    scale = margin["largest_stable_scale"]
    raise ScenarioError(
        f"{s.source}: 'controller.sample_rate' = {settings.sample_rate:g} Hz makes the observer with "
        f"'gains.observer' unstable in the loop: Ts lambda_max(Y M^-1) = "
        f"{settings.period * margin['largest_eigenvalue']:.3g} > 2 at q = {np.round(margin['q_worst'], 4).tolist()}. "
        f"The largest stable gain at this rate is {scale:.3g} x gains.observer (for a scalar gain: "
        f"{scale * float(np.max(np.diag(s.observer_gain))):.4g}); or raise the rate above "
        f"{settings.sample_rate / scale:.4g} Hz")


def simulate_sampled(scenario, observer: bool = True, plant=None,
                     progress: Callable[[float], None] | None = None, engine: str = "auto") -> ct.TimeResponseData:
    """Simulate the digital loop of a scenario on its output grid (see :func:`blocks.simulate`).

    ``engine="compiled"`` runs the loop's generated, numba-compiled module
    (:class:`blocks.compiled.sampled.SampledEngine`), ``"fast"`` (and
    ``"python-control"``) the numpy hybrid engine
    (:meth:`blocks.hybrid.HybridSystem.simulate`); ``"auto"`` takes the
    compiled one when it can run the loop (:func:`blocks.loop.select_engine`).

    Raises
    ------
    blocks.scenario.ScenarioError
        Before the run, if the observer is unstable at this rate (:func:`check_observer_rate`).
    blocks.compiled.CompiledUnavailable
        If ``engine="compiled"`` cannot run this loop (the message says why).
    """
    s = scenario
    if observer:
        check_observer_rate(s)
    loop = sampled_loop(s, observer=observer, plant_system=plant)
    x0 = sampled_initial_state(loop, s)
    sim = s.simulation
    t_grid = sim.time_grid
    if _sampled_engine(loop, sim.method, engine) == "compiled":
        states, outputs = _simulate_compiled(loop, x0, s, progress)
    else:
        states, outputs = loop.simulate(x0, t_grid, sim.method, rtol=sim.rtol, atol=sim.atol,
                                        max_step=sim.max_step, progress=progress)
    labels = loop.output_labels
    pick = lambda sig: outputs[[labels.index(n) for n in signal_names(sig)]]  # noqa: E731
    d = lumped_disturbance_rows(arm_constants(s.robot), arm_constants(s.nominal), pick("q"), pick("dq"),
                                pick("tau"), pick("tau_dis"))
    rate = s.controller.sample_rate
    title = f"{s.name}: {'with' if observer else 'without'} disturbance observer, sampled at {rate:g} Hz"
    resp = ct.TimeResponseData(t_grid, np.vstack([outputs, d]), states, output_labels=labels + signal_names("d"),
                               state_labels=loop.state_labels, title=title, sysname=loop.name, issiso=False,
                               plot_inputs=False)
    resp.scenario = s
    resp.with_observer = observer
    return resp


def _sampled_engine(loop: HybridSystem, method: str, engine: str) -> str:
    """``"compiled"`` or the numpy hybrid engine for a requested ``engine`` (see :func:`blocks.loop.select_engine`)."""
    from .loop import select_engine
    if engine not in ("auto", "compiled"):
        select_engine(engine, None)             # refuses an unknown name
        return "fast"
    from .compiled.sampled import sampled_unavailable_reason
    return select_engine(engine, sampled_unavailable_reason(loop, method))


def _simulate_compiled(loop: HybridSystem, x0: np.ndarray, s, progress) -> tuple[np.ndarray, np.ndarray]:
    """States and outputs of the compiled sampled engine, divergence judged on :mod:`blocks.divergence`'s bounds."""
    from .compiled.sampled import SampledEngine, bounds_for
    from .integrate import DivergenceError, SolverFailure
    from .loop import SimulationError
    sim, bounds = s.simulation, bounds_for(loop, s)
    try:
        states, outputs = SampledEngine(loop).simulate(x0, sim.time_grid, sim.rtol, sim.atol, sim.max_step,
                                                       bounds.bounds, progress)
    except DivergenceError as err:
        raise SimulationError(f"scenario '{s.name}': the loop diverged at t = {err.time:.6g} s: "
                              f"{bounds.describe(err.state)}; no result is returned") from None
    except SolverFailure as err:
        raise SimulationError(f"scenario '{s.name}': the solver stopped at t = {err.time:.6g} s of "
                              f"{sim.t_final:g} s: {err.reason}") from None
    if progress is not None:
        progress(1.0)
    return states, outputs
