"""Co-simulation of a scenario's digital controller against a plant FMU, one communication step per sample.

A scenario with a ``[controller]`` section describes a controller that runs
every ``Ts`` seconds and holds its torque in between (:mod:`blocks.diagram.digital`).
With the communication step ``h = Ts`` a co-simulation is then the same
sampled-data system as the monolithic hybrid run
(:func:`blocks.figure2.digital_loop.simulate_sampled`): at each sample the FMU's
``q``, ``dq`` are read, the encoder, observer, controller and actuator of the
scenario's digital loop are evaluated and updated exactly as in the
monolithic run (:class:`blocks.engines.hybrid.HybridSystem`'s tick), and the torque
is held over the FMU's step.  No coupling error arises: the two differ only
by the FMU's own integration error over each step (its RK4 sub-steps).
"""
from __future__ import annotations

from collections.abc import Callable

import control as ct
import numpy as np

from blocks.engines.budget import Budget
from blocks.engines.monitor import Monitor
from blocks.figure2.derived import loop_response
from blocks.figure2.physical_bounds import signal_bounds
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop
from blocks.scenarios.scenario import Scenario

from .errors import FMUMissingVariablesError
from .instance import FMUInstance
from .master import CoSimulationError

__all__ = ["cosimulate_sampled", "output_times"]

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


def output_times(t_final: float, output_step: float) -> np.ndarray:
    """The output grid ``0, output_step, ..., t_final`` (s), as a scenario's ``simulation.time_grid`` builds it."""
    n = int(round(t_final / output_step))
    return np.linspace(0.0, n * output_step, n + 1)


def _visits(times: np.ndarray, Ts: float) -> tuple[int, list[list[int]], list[list[int]]]:
    """The last tick and, for every tick interval ``k``, the output points at tick ``k`` and those inside it."""
    n_ticks = int(np.floor(times[-1] / Ts * (1 + 1e-12)))
    at_tick = [[] for _ in range(n_ticks + 1)]
    inside = [[] for _ in range(n_ticks + 1)]
    for j, t in enumerate(times):
        k = int(round(t / Ts))
        if abs(t - k * Ts) <= _STEP_RTOL * Ts and k <= n_ticks:
            at_tick[k].append(j)
        else:
            inside[min(int(np.floor(t / Ts)), n_ticks)].append(j)
    return n_ticks, at_tick, inside


def cosimulate_sampled(extracted, scenario: Scenario, step: float, t_final: float, observer: bool = True,
                       start_values: dict | None = None, output_step: float | None = None,
                       budget: Budget | None = None,
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
        End time (s).
    observer : bool
    start_values : dict, optional
        FMU start values.
    output_step : float, optional
        Spacing of the output grid (s), any value > 0 (default: every sample).
        An output point between two samples splits the FMU's step there: the
        torque is held over the whole step, so two shorter steps integrate
        the same sampled-data system, and the point is served exactly (no
        interpolation), as the monolithic run serves it.
    budget : Budget, optional
    progress : callable, optional

    Returns
    -------
    control.TimeResponseData
        Outputs named as :func:`blocks.simulate`'s for a digital scenario
        (``q_s``, ``dq_s``, ``tau_cmd`` besides the loop's signals, and ``d``)
        on the output grid; between samples the controller's outputs are those
        held since the last sample; attributes ``scenario``, ``with_observer``
        and ``cosim``.

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
    grid = output_times(t_final, Ts if output_step is None else output_step)
    n_ticks, at_tick, inside = _visits(grid, Ts)
    n_split = sum(len(j) for j in inside)
    budget = Budget.from_env() if budget is None else budget
    budget.check_steps(n_ticks + n_split, "co-simulation",
                       f"t_final = {t_final:g} s / step h = {Ts:g} s" + (
                           f" + {n_split} output points between samples (output_step = {output_step:g} s)"
                           if n_split else ""))
    loop = sampled_loop(s, observer=observer)
    x = sampled_initial_state(loop, s)
    signal_names = s.robot.joints.signal_names        # the scenario arm's joints (the paper's 4 by default)
    positions = _plant_state_positions(loop)
    q_pos = [positions[n] for n in signal_names("q")]
    dq_pos = [positions[n] for n in signal_names("dq")]
    labels = loop.output_labels
    names = [n for block in loop.system.syslist for n in block.output_labels]
    tau_rows = [names.index(n) for n in signal_names("tau")]
    dis_out = [labels.index(n) for n in signal_names("tau_dis")]
    measured_names = signal_names("q") + signal_names("dq") + signal_names("tau_dis")
    held = np.zeros(loop.plan.nsignals)
    outputs = np.empty((len(labels), grid.size))
    with FMUInstance(extracted, kind="CoSimulation", start_values=start_values) as fmu:
        try:
            out_vr = fmu.value_references(measured_names)
            in_vr = fmu.value_references(signal_names("tau"))
        except KeyError as err:
            raise FMUMissingVariablesError(f"{fmu.source}: the plant FMU lacks {err}") from None
        n = len(q_pos)
        first = fmu.get_real(out_vr)
        # the plant's outputs judged as every engine judges its states (blocks.engines.divergence, blocks.engines.monitor)
        deadline = Monitor(f"co-simulation of {fmu.source}", signal_bounds(measured_names, s), first, budget,
                           t_final)

        def measure(t: float) -> np.ndarray:
            measured = fmu.get_real(out_vr)
            if not np.all(np.isfinite(measured)):
                bad = int(np.argmax(~np.isfinite(measured)))
                raise CoSimulationError(f"the FMU output {measured_names[bad]} became {measured[bad]} at "
                                        f"t = {t:.6g} s")
            deadline.check(t, measured)
            return measured

        for k in range(n_ticks + 1):
            t = k * Ts
            measured = measure(t)
            x[q_pos], x[dq_pos] = measured[:n], measured[n:2 * n]
            y = loop.tick_outputs(k, x, held)
            tau = y[tau_rows]
            if not np.all(np.isfinite(tau)):
                raise CoSimulationError(f"the controller's torque became non-finite at t = {t:.6g} s")
            for j in at_tick[k]:
                outputs[:, j] = y[loop.plan.out_index]
                outputs[dis_out, j] = measured[2 * n:]            # the plant's own disturbance
            x = loop.tick_updates(k, x, y)
            fmu.set_real(in_vr, tau)
            # output points before the next sample: the FMU's step split there, the torque held over both parts
            t_now = t
            for j in inside[k]:
                fmu.do_step(t_now, grid[j] - t_now)
                t_now = grid[j]
                measured = measure(t_now)
                x_j = x.copy()
                x_j[q_pos], x_j[dq_pos] = measured[:n], measured[n:2 * n]
                outputs[:, j] = loop.outputs_between_ticks(grid[j:j + 1], x_j[:, None], held)[:, 0]
                outputs[dis_out, j] = measured[2 * n:]
            if k == n_ticks:
                break
            fmu.do_step(t_now, (k + 1) * Ts - t_now)
            if k % max(1, n_ticks // 50) == 0:
                deadline.check_time(where=f"t = {t:.6g} s of {t_final:g} s")
                if progress is not None:
                    progress(k / n_ticks)
        info = {"fmu": str(fmu.path), "fmi_version": fmu.fmi_version, "model": fmu.model_identifier, "step": Ts,
                "output_step": float(grid[1] - grid[0]) if grid.size > 1 else None, "coupling": "sampled",
                "side_substeps": None, "output_derivatives": False,
                "method": "the digital controller's samples as communication points (h = Ts): the torque is held "
                          "over each step on both sides, as in the monolithic run"
                          + ("; a step is split at each output point between samples" if n_split else "")}
    if progress is not None:
        progress(1.0)
    resp = loop_response(grid, outputs, None, labels, None, s, observer,
                         f"{s.name}: co-simulation of the digital controller at {1 / Ts:g} Hz with {info['model']}",
                         "cosim")
    resp.cosim = info
    return resp
