"""A fixed-step co-simulation master: one Co-Simulation FMU coupled to a python-control system.

Signals are exchanged by name.  Every real FMU input must be an output of
the Python side.  Every input of the Python side must be either an FMU
*output* (the side reads what the FMU computes) or an FMU *input* (the side
reads exactly what the FMU receives -- for example an observer fed the
torque that the plant gets, not the controller's command as it would move
within the step).  With communication step ``h`` and ``t_k = k h``:

1. read the FMU outputs ``y_k`` at ``t_k``;
2. evaluate the Python side's outputs ``c_k`` at ``(t_k, x_k, y_k)``: its
   direct feedthrough is allowed, the FMU outputs are already known (an
   algebraic path through both sides is broken by one step);
3. set ``c_k`` as the FMU's inputs; with the ``linear`` coupling read the
   FMU's output derivatives now (an acceleration depends on the new torque),
   compute the slope ``c'_k`` (see :mod:`fmu.coupling`) and hand it over;
   let the FMU advance over ``[t_k, t_k + h]``;
4. read ``y_{k+1}`` (and the output derivatives the FMU offers);
5. advance the Python side over the same interval by ``side_substeps``
   classical RK4 steps, its inputs held (``zoh``) or interpolated
   (``linear``) as :mod:`fmu.coupling` describes.

The zero-order hold is first order in ``h``; the linear coupling second
order when no algebraic path runs through both sides (measured in the
README).  The Python side is evaluated through
:class:`blocks.engines.fastsim.CompiledLoop` when it is an interconnection.

Every step checks the exchanged signals, the FMU outputs and the Python
state: the first non-finite value stops the run with a
:class:`CoSimulationError` naming the signal and the time; an error status
from the FMU raises :class:`~fmu.errors.FMUStepError`.  An FMU output that
grows more than tenfold in each of three consecutive steps stops the run
too, saying that the FMU's own co-simulation solver (or the loop) is
unstable at this step -- an unstable solver returns huge but finite numbers
long before it overflows.  Output derivatives that are not finite (some
FMUs declare them and return NaN with status OK) switch the ``linear``
coupling to ``zoh`` for the rest of the run, with one
:class:`~fmu.coupling.CouplingFallbackWarning` naming the FMU and why.  No partial result
is returned.  The number of steps is checked against a
:class:`~blocks.engines.budget.Budget` before the run, the wall time during it.
"""
from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import control as ct
import numpy as np

from blocks.diagram.control_compat import fast_dynamics, fast_output
from blocks.engines.budget import Budget
from blocks.engines.divergence import RUNAWAY_FACTOR, RUNAWAY_STEPS, Runaway
from blocks.engines.fastsim import CompiledLoop
from blocks.engines.monitor import Monitor
from blocks.engines.steppers import rk4_step

from .archive import ExtractionLimits
from .block import output_feedthrough
from .coupling import CouplingFallbackWarning, choose_coupling, describe, hermite
from .description import real_variables, require_variables
from .errors import CoSimulationError, FMUMissingVariablesError
from .instance import FMUInstance

__all__ = ["cosimulate_system", "CoSimulationError", "validated_step", "validated_time"]

# one-sided difference for the time derivative of the Python outputs: a small fraction of the step
_DERIVATIVE_FRACTION = 1e-4


def _evaluator(side: ct.NonlinearIOSystem):
    """``(rhs(t, x, u), out(t, x, u))`` for a system, compiled if it is an interconnection."""
    if isinstance(side, ct.InterconnectedSystem):
        compiled = CompiledLoop(side)
        return compiled.rhs, compiled.output
    return fast_dynamics(side), fast_output(side)


def validated_time(value, name: str) -> float:
    """``value`` as a finite float > 0 (s); raises :class:`CoSimulationError` naming ``name`` otherwise."""
    if isinstance(value, (bool, str, bytes)):
        raise CoSimulationError(f"{name} must be a finite number > 0 s, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise CoSimulationError(f"{name} must be a finite number > 0 s, got {value!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise CoSimulationError(f"{name} must be a finite number > 0 s, got {value!r}")
    return number


def validated_step(step) -> float:
    """The communication step ``h`` as a finite float > 0 (s), checked before anything divides by it."""
    return validated_time(step, "the communication step h")


def _grid(t_final: float, step: float) -> int:
    step = validated_step(step)
    t_final = validated_time(t_final, "t_final")
    ratio = t_final / step
    if not math.isfinite(ratio):
        raise CoSimulationError(f"t_final = {t_final:g} s / h = {step:g} s is not a finite number of steps")
    n = int(round(ratio))
    if n < 1 or abs(n * step - t_final) > 1e-9 * max(1.0, t_final):
        raise CoSimulationError(f"t_final = {t_final:g} s is not a whole number of communication steps "
                                f"h = {step:g} s")
    return n


def _first_bad(values: np.ndarray, names: list[str]) -> str | None:
    """The first non-finite entry as ``"name = value"``, or None if all are finite."""
    if np.all(np.isfinite(values)):
        return None
    j = int(np.flatnonzero(~np.isfinite(values))[0])
    return f"{names[j]} = {values[j]}"


def _stop(what: str, bad: str, t: float) -> CoSimulationError:
    return CoSimulationError(f"the co-simulation stopped: {what} {bad} at t = {t:.9g} s is not finite; no result "
                             "is returned (a diverging loop -- an unstable one, or a loop gain above 1 through both "
                             "sides at this step -- is the usual cause)")


def _rk4(rhs, t: float, x: np.ndarray, inputs_at, h: float, m: int) -> np.ndarray:
    """``m`` classical RK4 steps (:func:`blocks.engines.steppers.rk4_step`) over ``[t, t + h]``, the inputs
    ``inputs_at(s)`` at each stage time ``s``."""
    dt = h / m
    u_start = inputs_at(t)
    for j in range(m):
        tj = t + j * dt
        u_end = inputs_at(t + h if j + 1 == m else tj + dt)
        x = rk4_step(rhs, tj, x, dt, (u_start,), (inputs_at(tj + 0.5 * dt),), (u_end,))
        u_start = u_end
    return x


class _Wiring:
    """Which signal goes where: FMU outputs and inputs, Python inputs and outputs, by name."""

    def __init__(self, fmu: FMUInstance, side: ct.NonlinearIOSystem):
        md = fmu.model_description
        self.fmu_outputs = [v.name for v in real_variables(md, "output")]
        self.fmu_inputs = [v.name for v in real_variables(md, "input")]
        self.side_in, self.side_out = list(side.input_labels), list(side.output_labels)
        unknown = [n for n in self.side_in if n not in self.fmu_outputs and n not in self.fmu_inputs]
        if unknown:
            require_variables(md, unknown, source=f"{fmu.source} (signals the Python side reads)")
            raise FMUMissingVariablesError(
                f"{fmu.source}: the Python side reads {unknown}, which are neither real outputs nor real inputs of "
                f"the FMU (outputs {self.fmu_outputs}, inputs {self.fmu_inputs})", missing=unknown)
        missing = [n for n in self.fmu_inputs if n not in self.side_out]
        if missing:
            raise FMUMissingVariablesError(f"{fmu.source}: FMU input(s) {missing} are not outputs of the Python "
                                           f"side (it gives {self.side_out})", missing=missing)
        self.out_vr = fmu.value_references(self.fmu_outputs)
        self.in_vr = fmu.value_references(self.fmu_inputs)
        # Python inputs read from FMU outputs ("measured") and from FMU inputs ("applied")
        self.meas_pos = np.array([j for j, n in enumerate(self.side_in) if n in self.fmu_outputs], dtype=int)
        self.meas_src = np.array([self.fmu_outputs.index(self.side_in[j]) for j in self.meas_pos], dtype=int)
        self.appl_pos = np.array([j for j, n in enumerate(self.side_in) if n in self.fmu_inputs], dtype=int)
        self.appl_src = np.array([self.fmu_inputs.index(self.side_in[j]) for j in self.appl_pos], dtype=int)
        self.meas_vr = fmu.value_references([self.fmu_outputs[i] for i in self.meas_src])
        self.fmu_from_side = np.array([self.side_out.index(n) for n in self.fmu_inputs], dtype=int)
        self.extra = [n for n in self.side_out if n not in self.fmu_outputs]
        self.extra_idx = np.array([self.side_out.index(n) for n in self.extra], dtype=int)
        # outputs that depend on the FMU inputs are read again after new inputs are set, for the record
        self.feedthrough = bool(output_feedthrough(md, self.fmu_inputs))


def cosimulate_system(fmu_path, side: ct.NonlinearIOSystem, t_final: float, step: float, side_x0=None,
                      start_values: dict | None = None, side_substeps: int = 1, record_every: int = 1,
                      coupling: str | None = None, budget: Budget | None = None,
                      limits: ExtractionLimits | None = None, extract_to=None,
                      progress: Callable[[float], None] | None = None, bounds=None) -> ct.TimeResponseData:
    """Co-simulate a Co-Simulation FMU with a python-control system (see the module docstring).

    Parameters
    ----------
    fmu_path : str, pathlib.Path or ExtractedFMU
        A Co-Simulation FMU (FMI 2.0 or 3.0), or an extraction of one to reuse.
    side : control.NonlinearIOSystem
        The Python side.  Each of its inputs is an FMU output or an FMU input
        (by name); every real FMU input must be one of its outputs.
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
    coupling : {"zoh", "linear"}, optional
        See :mod:`fmu.coupling`; default the best the FMU supports
        (``linear`` when its inputs can follow a slope over a step).
    budget : Budget, optional
        Limits on steps and wall time (:meth:`blocks.engines.budget.Budget.from_env`).
    limits, extract_to :
        Passed to :class:`~fmu.instance.FMUInstance`.
    progress : callable, optional
        Called with the fraction of time done (0..1), about every 2 % of the steps.
    bounds : callable, optional
        ``bounds(names) -> blocks.engines.divergence.StateBounds`` for the FMU's outputs (for a plant FMU,
        :func:`blocks.figure2.physical_bounds.signal_bounds` of the scenario): the run's
        :class:`~blocks.engines.monitor.Monitor`
        judges them after every step, as every engine judges its states.  Without it the outputs are judged
        for being finite and for runaway growth only.

    Returns
    -------
    control.TimeResponseData
        Outputs: the FMU outputs, then the Python outputs not already among them,
        at the recorded communication points; states: the Python side's states.
        Attribute ``cosim`` holds the settings (step, sub-steps, coupling, FMU, FMI version).

    Raises
    ------
    FMUMissingVariablesError
        If the signal names of the two sides do not match.
    FMUStepError
        If the FMU returns an error status (the message names the time and status).
    CoSimulationError
        On a bad step or coupling, or when a signal or the Python state becomes non-finite or runs away.
    blocks.engines.monitor.SimulationError
        With ``bounds``: when an FMU output leaves its bound (the signal, the bound and the time named).
    BudgetError
        If the run would exceed the budget's steps, or exceeds its wall time.
    """
    n_steps = _grid(t_final, step)
    step = float(step)
    if isinstance(side_substeps, bool) or not isinstance(side_substeps, int) or side_substeps < 1:
        raise CoSimulationError(f"side_substeps must be an integer >= 1, got {side_substeps!r}")
    if isinstance(record_every, bool) or not isinstance(record_every, int) or record_every < 1:
        raise CoSimulationError(f"record_every must be an integer >= 1, got {record_every!r}")
    budget = Budget.from_env() if budget is None else budget
    budget.check_steps(n_steps * side_substeps, "co-simulation",
                       f"t_final = {float(t_final):g} s / step h = {step:g} s"
                       + (f" x side_substeps = {side_substeps}" if side_substeps > 1 else ""))
    rhs, out = _evaluator(side)
    x = np.zeros(side.nstates) if side_x0 is None else np.array(side_x0, dtype=float)
    if x.shape != (side.nstates,):
        raise CoSimulationError(f"side_x0 must have {side.nstates} entries, got shape {x.shape}")

    with FMUInstance(fmu_path, kind="CoSimulation", start_values=start_values, limits=limits,
                     extract_to=extract_to) as fmu:
        w = _Wiring(fmu, side)
        coupling = choose_coupling(fmu, coupling, bool(w.fmu_inputs))
        linear = coupling == "linear"
        derivatives = bool(linear and fmu.max_output_derivative_order >= 1 and len(w.meas_vr))

        n_rec = n_steps // record_every + 1
        times = np.empty(n_rec)
        outputs = np.empty((len(w.fmu_outputs) + len(w.extra), n_rec))
        states = np.empty((side.nstates, n_rec))
        y_rec = np.empty(len(w.fmu_outputs))
        y_f = fmu.get_real(w.out_vr)
        bad = _first_bad(y_f, w.fmu_outputs)
        if bad:
            raise _stop("the FMU output", bad, 0.0)
        y_m = y_f[w.meas_src]
        dy_m = np.zeros(len(w.meas_src))
        y_m_prev = None
        # what the FMU inputs hold until the first command: the start values set, else the model description's
        applied = _start_values(fmu, w.fmu_inputs, start_values or {})
        u = np.empty(len(w.side_in))
        every = max(1, n_steps // 50)
        fallback = None
        growth = _Growth(fmu.source, w.fmu_outputs)
        deadline = Monitor(f"co-simulation of {fmu.source}", bounds(w.fmu_outputs) if bounds is not None else None,
                           y_f, budget, float(t_final))
        h = step
        for k in range(n_steps + 1):
            t = k * h
            fmu.time = t
            u[w.meas_pos] = y_m
            u[w.appl_pos] = applied[w.appl_src]
            y_side = np.asarray(out(t, x, u), dtype=float)
            bad = _first_bad(y_side, w.side_out)
            if bad:
                raise _stop("the Python side's output", bad, t)
            cmd = y_side[w.fmu_from_side]
            u[w.appl_pos] = cmd[w.appl_src]
            fmu.set_real(w.in_vr, cmd)
            if derivatives:    # at t_k with the new inputs: an acceleration, say, depends on the new torque
                dy_m = fmu.get_output_derivatives(w.meas_vr)
                if not np.all(np.isfinite(dy_m)):
                    fallback = _fall_back(fmu, w, dy_m, t, k > 0)
                    linear = derivatives = False
            if linear:
                slope_m = dy_m if derivatives else ((y_m - y_m_prev) / h if y_m_prev is not None else 0.0 * y_m)
                dcmd = _output_slope(rhs, out, t, x, u, w, slope_m, cmd, h)
                bad = _first_bad(dcmd, [f"d({n})/dt" for n in w.fmu_inputs])
                if bad:
                    raise _stop("the slope of the Python side's output", bad, t)
            if linear and len(w.fmu_inputs):
                if fmu.fmi_version == 2:
                    fmu.set_input_derivatives(w.in_vr, dcmd)
                else:
                    fmu.set_input_provider(w.in_vr, lambda s, c=cmd, d=dcmd, t0=t: c + (s - t0) * d)
            if k % record_every == 0:
                j = k // record_every
                times[j] = t
                outputs[:len(w.fmu_outputs), j] = fmu.get_real(w.out_vr, out=y_rec) if w.feedthrough else y_f
                outputs[len(w.fmu_outputs):, j] = y_side[w.extra_idx]
                states[:, j] = x
            if k == n_steps:
                break
            fmu.do_step(t, h)
            y_next = fmu.get_real(w.out_vr)
            bad = _first_bad(y_next, w.fmu_outputs)
            if bad:
                raise _stop("the FMU output", bad, t + h)
            growth.check(y_f, y_next, t, h, coupling if fallback is None else "zoh")
            if bounds is not None:
                deadline.check(t + h, y_next)
            y_m_next = y_next[w.meas_src]
            ended = cmd + h * dcmd if linear else cmd     # what the FMU inputs hold at the end of the step
            dy_next = fmu.get_output_derivatives(w.meas_vr) if derivatives else None
            if dy_next is not None and not np.all(np.isfinite(dy_next)):
                fallback = _fall_back(fmu, w, dy_next, t + h, True)
                linear = derivatives = False
            if linear:
                inputs_at = _interpolated_inputs(u, w, t, h, y_m, dy_m, y_m_next, dy_next, cmd, dcmd)
            else:
                held = u.copy()
                inputs_at = lambda s, held=held: held          # noqa: E731 - one line per coupling
            if x.size:
                x = _rk4(rhs, t, x, inputs_at, h, side_substeps)
            bad = _first_bad(x, list(side.state_labels))
            if bad:
                raise _stop("the Python side's state", bad, t + h)
            applied = ended
            y_m_prev, y_m, y_f = y_m, y_m_next, y_next
            if k % every == 0:
                deadline.check_time(where=f"t = {t:.6g} s of {float(t_final):g} s")
                if progress is not None:
                    progress(k / n_steps)
        if linear and fmu.fmi_version == 3:
            fmu.set_input_provider(None)
        if fallback is not None:
            coupling = "zoh"
        info = {"fmu": str(fmu.path), "fmi_version": fmu.fmi_version, "model": fmu.model_identifier,
                "step": step, "side_substeps": side_substeps, "record_every": record_every, "coupling": coupling,
                "output_derivatives": bool(derivatives), "coupling_fallback": fallback,
                "method": "fixed-step coupling, FMU first; " + describe(coupling, bool(derivatives), fmu.fmi_version)
                          + "; Python side classical RK4"}
    if progress is not None:
        progress(1.0)
    resp = ct.TimeResponseData(times, outputs, states if side.nstates else None,
                               output_labels=w.fmu_outputs + w.extra,
                               state_labels=list(side.state_labels) if side.nstates else None,
                               sysname=f"cosim[{side.name}]", issiso=False, plot_inputs=False)
    resp.cosim = info
    return resp


def _fall_back(fmu: FMUInstance, w: _Wiring, values: np.ndarray, t: float, slopes_set: bool) -> str:
    """Switch an FMU whose output derivatives are not finite to the zero-order hold; one warning says why."""
    function = "fmi2GetRealOutputDerivatives" if fmu.fmi_version == 2 else "fmi3GetOutputDerivatives"
    bad = _first_bad(values, [w.fmu_outputs[i] for i in w.meas_src])
    note = (f"{fmu.source}: {function} returned d({bad.replace(' = ', ')/dt = ')} at t = {t:.9g} s (the FMU declares "
            f"maxOutputDerivativeOrder = {fmu.max_output_derivative_order}); its output derivatives are unusable, so "
            "the co-simulation uses coupling 'zoh' (first order in h) from there")
    if slopes_set and len(w.fmu_inputs):    # the inputs stop following the last slope
        if fmu.fmi_version == 2:
            fmu.set_input_derivatives(w.in_vr, np.zeros(len(w.fmu_inputs)))
        else:
            fmu.set_input_provider(None)
    warnings.warn(note, CouplingFallbackWarning, stacklevel=3)
    return note


class _Growth:
    """Stops a run whose FMU outputs run away (:class:`blocks.engines.divergence.Runaway`), saying what that means here."""

    def __init__(self, source: str, names: list[str]):
        self.source, self.names = source, names
        self.watch = Runaway(len(names))

    def check(self, y: np.ndarray, y_next: np.ndarray, t: float, h: float, coupling: str) -> None:
        j = self.watch.update(y, y_next)
        if j is None:
            return
        held = "held" if coupling == "zoh" else "following a first-order hold"
        raise CoSimulationError(
            f"the co-simulation stopped: the FMU output {self.names[j]} grew more than {RUNAWAY_FACTOR:g}-fold in each "
            f"of {RUNAWAY_STEPS} consecutive communication steps, from |{self.names[j]}| = {self.watch.first[j]:.3g} "
            f"to {y_next[j]:.3g} at t = {t + h:.9g} s; with its inputs {held} over each step this is {self.source}'s "
            f"own co-simulation solver being unstable at h = {h:g} s (or a loop unstable at this step): choose a "
            "smaller step, or use the FMU's Model Exchange interface with dobkit's solver; no result is returned")

def _start_values(fmu: FMUInstance, names: list[str], given: dict) -> np.ndarray:
    """Start values of real variables: the one set (``given``, as ``start_values`` set it before initialization),
    else the model description's (0 where none is given)."""
    values = []
    for name in names:
        start = given[name] if name in given else fmu.variables[name].start
        try:
            values.append(float(start) if start is not None else 0.0)
        except (TypeError, ValueError):
            values.append(0.0)
    return np.array(values)


def _output_slope(rhs, out, t, x, u, w: _Wiring, slope_m, cmd, h) -> np.ndarray:
    """Time derivative at ``t`` of the Python outputs the FMU receives, along the solution (one-sided difference).

    The FMU outputs move with ``slope_m``; the commanded FMU inputs are held
    (a Python output that depends directly on what the FMU receives would
    make the derivative circular).
    """
    delta = _DERIVATIVE_FRACTION * h
    u_d = u.copy()
    u_d[w.meas_pos] = u[w.meas_pos] + delta * slope_m
    x_d = x + delta * rhs(t, x, u) if x.size else x
    ahead = np.asarray(out(t + delta, x_d, u_d), dtype=float)[w.fmu_from_side]
    return (ahead - cmd) / delta


def _interpolated_inputs(u, w: _Wiring, t, h, y0, d0, y1, d1, cmd, dcmd):
    """The Python side's inputs over ``[t, t + h]`` for the linear coupling (see :mod:`fmu.coupling`)."""
    base = u.copy()
    applied0 = cmd[w.appl_src]
    applied_slope = dcmd[w.appl_src]

    def inputs_at(s: float) -> np.ndarray:
        v = base.copy()
        r = s - t
        v[w.meas_pos] = hermite(r, h, y0, d0, y1, d1) if d1 is not None else y0 + (r / h) * (y1 - y0)
        v[w.appl_pos] = applied0 + r * applied_slope
        return v

    return inputs_at
