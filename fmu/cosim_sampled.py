"""Co-simulation of a scenario's digital controller against a plant FMU, one communication step per sample.

A scenario with a ``[controller]`` section describes a controller that runs
every ``Ts`` seconds and holds its torque in between (:mod:`blocks.digital`).
With the communication step ``h = Ts`` a co-simulation is then the same
sampled-data system as the monolithic hybrid run
(:func:`blocks.digital_loop.simulate_sampled`): at each sample the FMU's
``q``, ``dq`` are read, the encoder, observer, controller and actuator of the
scenario's digital loop are evaluated and updated exactly as in the
monolithic run (:class:`blocks.hybrid.HybridSystem`'s tick), and the torque
is held over the FMU's step.  No coupling error arises: the two differ only
by the FMU's own integration error over each step (its RK4 sub-steps).
"""
from __future__ import annotations

from collections.abc import Callable

import control as ct
import numpy as np

from blocks.budget import Budget
from blocks.digital_loop import sampled_initial_state, sampled_loop
from blocks.kernels import arm_constants
from blocks.kernels import lumped_disturbance as lumped_disturbance_rows
from blocks.monitor import Monitor
from blocks.scenario import Scenario
from blocks.systems import signal_names

from .errors import FMUMissingVariablesError
from .instance import FMUInstance
from .master import CoSimulationError

__all__ = ["cosimulate_sampled"]

# h = Ts to this relative tolerance
_STEP_RTOL = 1e-9


def _plant_state_positions(loop) -> dict[str, int]:
    """Positions of the plant's states ``q[i]``, ``dq[i]`` in the loop's state."""
    offset, out = 0, {}
    for block in loop.syslist:
        if block.name == "plant":
            for j, label in enumerate(block.state_labels):
                out[label] = offset + j
        offset += block.nstates
    return out


def cosimulate_sampled(extracted, scenario: Scenario, step: float, t_final: float, observer: bool = True,
                       start_values: dict | None = None, record_every: int = 1, budget: Budget | None = None,
                       progress: Callable[[float], None] | None = None) -> ct.TimeResponseData:
    """Run the scenario's digital controller against a plant Co-Simulation FMU at ``h = Ts``.

    Parameters
    ----------
    extracted : ExtractedFMU or path
        The plant FMU (inputs ``tau[i]``, outputs ``q[i]``, ``dq[i]``, ``tau_dis[i]``).
    scenario : Scenario
        With a ``[controller]`` section.
    step : float
        The communication step (s); must equal the controller's sample period.
    t_final : float
        End time (s), a whole number of steps.
    observer : bool
    start_values : dict, optional
        FMU start values.
    record_every : int
        Record every ``record_every``-th sample.
    budget : Budget, optional
    progress : callable, optional

    Returns
    -------
    control.TimeResponseData
        Outputs named as :func:`blocks.simulate`'s for a digital scenario
        (``q_s``, ``dq_s``, ``tau_cmd`` besides the loop's signals, and ``d``);
        attributes ``scenario``, ``with_observer`` and ``cosim``.

    Raises
    ------
    CoSimulationError
        If ``step`` is not the sample period, or a signal becomes non-finite (naming it and the time).
    """
    s = scenario
    Ts = s.controller.period
    if abs(step - Ts) > _STEP_RTOL * Ts:
        raise CoSimulationError(f"scenario '{s.name}' has a digital controller sampled every {Ts:g} s "
                                f"(controller.sample_rate = {s.controller.sample_rate:g} Hz); co-simulate it with "
                                f"the communication step h = {Ts:g} s, got {step:g} s")
    n_steps = int(round(t_final / Ts))
    if abs(n_steps * Ts - t_final) > 1e-9 * max(1.0, t_final):
        raise CoSimulationError(f"t_final = {t_final:g} s is not a whole number of samples of {Ts:g} s")
    budget = Budget.from_env() if budget is None else budget
    budget.check_steps(n_steps, "co-simulation", f"t_final = {t_final:g} s / step h = {Ts:g} s")
    loop = sampled_loop(s, observer=observer)
    x = sampled_initial_state(loop, s)
    positions = _plant_state_positions(loop)
    q_pos = [positions[n] for n in signal_names("q")]
    dq_pos = [positions[n] for n in signal_names("dq")]
    labels = loop.output_labels
    names = [n for block in loop.system.syslist for n in block.output_labels]
    tau_rows = [names.index(n) for n in signal_names("tau")]
    dis_out = [labels.index(n) for n in signal_names("tau_dis")]
    held = np.zeros(loop.plan.nsignals)
    n_rec = n_steps // record_every + 1
    times, outputs = np.empty(n_rec), np.empty((len(labels), n_rec))
    with FMUInstance(extracted, kind="CoSimulation", start_values=start_values) as fmu:
        try:
            out_vr = fmu.value_references(signal_names("q") + signal_names("dq") + signal_names("tau_dis"))
            in_vr = fmu.value_references(signal_names("tau"))
        except KeyError as err:
            raise FMUMissingVariablesError(f"{fmu.source}: the plant FMU lacks {err}") from None
        deadline = Monitor.for_job(f"co-simulation of {fmu.source}", budget)
        n = len(q_pos)
        for k in range(n_steps + 1):
            t = k * Ts
            measured = fmu.get_real(out_vr)
            if not np.all(np.isfinite(measured)):
                bad = (signal_names("q") + signal_names("dq") + signal_names("tau_dis"))[
                    int(np.argmax(~np.isfinite(measured)))]
                raise CoSimulationError(f"the FMU output {bad} became {measured[~np.isfinite(measured)][0]} at "
                                        f"t = {t:.6g} s")
            x[q_pos], x[dq_pos] = measured[:n], measured[n:2 * n]
            y = loop.tick_outputs(k, x, held)
            tau = y[tau_rows]
            if not np.all(np.isfinite(tau)):
                raise CoSimulationError(f"the controller's torque became non-finite at t = {t:.6g} s")
            if k % record_every == 0:
                j = k // record_every
                times[j] = t
                outputs[:, j] = y[loop.plan.out_index]
                outputs[dis_out, j] = measured[2 * n:]            # the plant's own disturbance
            if k == n_steps:
                break
            x = loop.tick_updates(k, x, y)
            fmu.set_real(in_vr, tau)
            fmu.do_step(t, Ts)
            if k % max(1, n_steps // 50) == 0:
                deadline.check_time(where=f"t = {t:.6g} s of {t_final:g} s")
                if progress is not None:
                    progress(k / n_steps)
        info = {"fmu": str(fmu.path), "fmi_version": fmu.fmi_version, "model": fmu.model_identifier, "step": Ts,
                "record_every": record_every, "coupling": "sampled",
                "method": "the digital controller's samples as communication points (h = Ts): the torque is held "
                          "over each step on both sides, as in the monolithic run"}
    if progress is not None:
        progress(1.0)
    pick = lambda sig: outputs[[labels.index(nm) for nm in signal_names(sig)]]   # noqa: E731
    d = lumped_disturbance_rows(arm_constants(s.robot), arm_constants(s.nominal), pick("q"), pick("dq"),
                                pick("tau"), pick("tau_dis"))
    resp = ct.TimeResponseData(times, np.vstack([outputs, d]), None, output_labels=labels + signal_names("d"),
                               title=f"{s.name}: co-simulation of the digital controller at {1 / Ts:g} Hz with "
                                     f"{info['model']}", sysname="cosim", issiso=False, plot_inputs=False)
    resp.scenario, resp.with_observer = s, observer
    resp.cosim = info
    return resp
