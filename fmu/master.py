"""A fixed-step co-simulation master: one Co-Simulation FMU coupled to a python-control system.

Signals are exchanged by name: every input of the Python side is read from
the FMU output of the same name, every real input of the FMU from the Python
output of the same name.  With communication step ``h`` and ``t_k = k h``:

1. read the FMU outputs ``y_k`` at ``t_k``;
2. evaluate the Python side's outputs at ``(t_k, x_k, y_k)`` (its direct
   feedthrough is allowed: the FMU outputs are already known);
3. hand the Python outputs to the FMU (outputs that depend directly on FMU
   inputs are read again for the record, so recorded signals are consistent
   at ``t_k``; the Python side used ``y_k``, which breaks a possible
   algebraic loop through both sides by one step) and let the FMU advance
   over ``[t_k, t_k + h]`` -- its inputs are held constant over the step
   (zero-order hold);
4. advance the Python side over the same interval with ``y_k`` held constant,
   by ``side_substeps`` classical RK4 steps.

Both sides therefore see the other's signals through a zero-order hold: the
coupling is first order, its error falls like ``h``.  The Python side is
evaluated through :class:`blocks.fastsim.CompiledLoop` when it is an
interconnection (each block once per evaluation), which gives the same
numbers as python-control's own evaluation.

An error status from the FMU raises :class:`~fmu.errors.FMUStepError`
naming the simulation time and the status; no partial result is returned.
"""
from __future__ import annotations

from typing import Callable

import control as ct
import numpy as np

from blocks.control_compat import fast_dynamics, fast_output
from blocks.fastsim import CompiledLoop
from .archive import ExtractionLimits
from .description import real_variables, require_variables
from .errors import FMUError
from .instance import FMUInstance
from .block import output_feedthrough

__all__ = ["cosimulate_system", "CoSimulationError"]


class CoSimulationError(FMUError):
    """The co-simulation could not run: bad step, diverging Python side, signals that do not match."""


def _evaluator(side: ct.NonlinearIOSystem):
    """``(rhs(t, x, u), out(t, x, u))`` for a system, compiled if it is an interconnection."""
    if isinstance(side, ct.InterconnectedSystem):
        compiled = CompiledLoop(side)
        return compiled.rhs, compiled.output
    return fast_dynamics(side), fast_output(side)


def _grid(t_final: float, step: float) -> int:
    if not (np.isfinite(step) and step > 0):
        raise CoSimulationError(f"communication step must be a finite number > 0 s, got {step!r}")
    if not (np.isfinite(t_final) and t_final > 0):
        raise CoSimulationError(f"t_final must be a finite number > 0 s, got {t_final!r}")
    n = int(round(t_final / step))
    if n < 1 or abs(n * step - t_final) > 1e-9 * max(1.0, t_final):
        raise CoSimulationError(f"t_final = {t_final:g} s is not a whole number of communication steps "
                                f"h = {step:g} s")
    return n


def _rk4(rhs, t: float, x: np.ndarray, u: np.ndarray, h: float, m: int) -> np.ndarray:
    dt = h / m
    for j in range(m):
        tj = t + j * dt
        k1 = rhs(tj, x, u)
        k2 = rhs(tj + 0.5 * dt, x + 0.5 * dt * k1, u)
        k3 = rhs(tj + 0.5 * dt, x + 0.5 * dt * k2, u)
        k4 = rhs(tj + dt, x + dt * k3, u)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def cosimulate_system(fmu_path, side: ct.NonlinearIOSystem, t_final: float, step: float, side_x0=None,
                      start_values: dict | None = None, side_substeps: int = 1, record_every: int = 1,
                      limits: ExtractionLimits | None = None, extract_to=None,
                      progress: Callable[[float], None] | None = None) -> ct.TimeResponseData:
    """Co-simulate a Co-Simulation FMU with a python-control system (see the module docstring).

    Parameters
    ----------
    fmu_path : str, pathlib.Path or ExtractedFMU
        A Co-Simulation FMU (FMI 2.0 or 3.0), or an extraction of one to reuse.
    side : control.NonlinearIOSystem
        The Python side.  Its inputs must all be FMU outputs (by name); every
        real FMU input must be one of its outputs.
    t_final : float
        End time (s), a whole number of steps.
    step : float
        Communication step ``h`` (s).
    side_x0 : array_like, optional
        Initial state of the Python side (zeros by default).
    start_values : dict, optional
        FMU start values (parameters, state start values), set before initialization.
    side_substeps : int
        RK4 steps of the Python side per communication step (>= 1).
    record_every : int
        Record every ``record_every``-th communication point (1: all).
    limits, extract_to :
        Passed to :class:`~fmu.instance.FMUInstance`.
    progress : callable, optional
        Called with the fraction of time done (0..1), about every 2 % of the steps.

    Returns
    -------
    control.TimeResponseData
        Outputs: the FMU outputs, then the Python outputs not already among them,
        at the recorded communication points; states: the Python side's states.
        Attribute ``cosim`` holds the settings (step, sub-steps, FMU, FMI version).

    Raises
    ------
    FMUMissingVariablesError
        If the signal names of the two sides do not match.
    FMUStepError
        If the FMU returns an error status (the message names the time and status).
    CoSimulationError
        On a bad step or if the Python side's state becomes non-finite.
    """
    n_steps = _grid(t_final, step)
    if isinstance(side_substeps, bool) or not isinstance(side_substeps, int) or side_substeps < 1:
        raise CoSimulationError(f"side_substeps must be an integer >= 1, got {side_substeps!r}")
    if isinstance(record_every, bool) or not isinstance(record_every, int) or record_every < 1:
        raise CoSimulationError(f"record_every must be an integer >= 1, got {record_every!r}")
    rhs, out = _evaluator(side)
    x = np.zeros(side.nstates) if side_x0 is None else np.array(side_x0, dtype=float)
    if x.shape != (side.nstates,):
        raise CoSimulationError(f"side_x0 must have {side.nstates} entries, got shape {x.shape}")

    with FMUInstance(fmu_path, kind="CoSimulation", start_values=start_values, limits=limits,
                     extract_to=extract_to) as fmu:
        md = fmu.model_description
        fmu_outputs = [v.name for v in real_variables(md, "output")]
        fmu_inputs = [v.name for v in real_variables(md, "input")]
        side_in, side_out = list(side.input_labels), list(side.output_labels)
        require_variables(md, side_in, causality="output", source=f"{fmu.source} (outputs the Python side reads)")
        missing = [n for n in fmu_inputs if n not in side_out]
        if missing:
            from .errors import FMUMissingVariablesError
            raise FMUMissingVariablesError(f"{fmu.source}: FMU input(s) {missing} are not outputs of the Python "
                                           f"side (it gives {side_out})", missing=missing)
        out_vr = fmu.value_references(fmu_outputs)
        in_vr = fmu.value_references(fmu_inputs)
        side_from_fmu = np.array([fmu_outputs.index(n) for n in side_in], dtype=int)
        fmu_from_side = np.array([side_out.index(n) for n in fmu_inputs], dtype=int)
        extra = [n for n in side_out if n not in fmu_outputs]
        extra_idx = np.array([side_out.index(n) for n in extra], dtype=int)

        n_rec = n_steps // record_every + 1
        times = np.empty(n_rec)
        outputs = np.empty((len(fmu_outputs) + len(extra), n_rec))
        states = np.empty((side.nstates, n_rec))
        y_f = np.empty(len(fmu_outputs))
        y_rec = np.empty(len(fmu_outputs))
        # outputs that depend on the FMU inputs are read again after the new inputs are set
        feedthrough = bool(output_feedthrough(md, fmu_inputs))
        every = max(1, n_steps // 50)
        for k in range(n_steps + 1):
            t = k * step
            fmu.time = t
            fmu.get_real(out_vr, out=y_f)
            u_side = y_f[side_from_fmu]
            y_side = np.asarray(out(t, x, u_side), dtype=float)
            fmu.set_real(in_vr, y_side[fmu_from_side])
            if k % record_every == 0:
                j = k // record_every
                times[j] = t
                outputs[:len(fmu_outputs), j] = fmu.get_real(out_vr, out=y_rec) if feedthrough else y_f
                outputs[len(fmu_outputs):, j] = y_side[extra_idx]
                states[:, j] = x
            if k == n_steps:
                break
            fmu.do_step(t, step)
            x = _rk4(rhs, t, x, u_side, step, side_substeps)
            if not np.all(np.isfinite(x)):
                raise CoSimulationError(f"the Python side's state became non-finite in the step from t = {t:.9g} s; "
                                        "no result is returned")
            if progress is not None and k % every == 0:
                progress(k / n_steps)
        info = {"fmu": str(fmu.path), "fmi_version": fmu.fmi_version, "model": fmu.model_identifier,
                "step": step, "side_substeps": side_substeps, "record_every": record_every,
                "method": "fixed-step Jacobi coupling, zero-order hold on exchanged signals; Python side RK4"}
    if progress is not None:
        progress(1.0)
    resp = ct.TimeResponseData(times, outputs, states if side.nstates else None,
                               output_labels=fmu_outputs + extra,
                               state_labels=list(side.state_labels) if side.nstates else None,
                               sysname=f"cosim[{side.name}]", issiso=False, plot_inputs=False)
    resp.cosim = info
    return resp
