"""Simulate a Model Exchange FMU on its own, events included: :func:`simulate_fmu`.

The FMU runs as the one hybrid block of a loop, through the event loop of
:func:`blocks.engines.integrate.integrate_on_grid` that also runs FMU blocks with
events in a loop of the numpy engine (:mod:`fmu.events`).  Its continuous
states are integrated by a SciPy solver (DOP853 by default) step by step.
After every accepted step:

1. the event indicators are evaluated at the step's end; where one changed
   sign (``z > 0`` before, ``z <= 0`` after, or the other way) the first
   crossing is located by bisection on the solver's dense output until the
   bracket is shorter than ``event_tolerance`` (1e-12 s by default); the
   step is cut at the bracket's right end (the indicator has crossed there);
2. ``completedIntegratorStep`` is called; a step event it asks for, a time
   event announced by the last event iteration (the solver never steps past
   it) or a located state event puts the FMU into Event Mode at that time
   and state, where the event iteration (``fmi2NewDiscreteStates`` /
   ``fmi3UpdateDiscreteStates``, :func:`fmu.events.event_iteration`) runs
   until no discrete state needs an update; states the FMU re-initialised
   are read back and a new solver starts from them;
3. ``terminateSimulation`` (from the event iteration or from
   ``completedIntegratorStep``) ends the run at that time: the result stops
   there and says so.

Outputs are recorded on the grid ``start_time + k * output_step`` from the
dense output; a grid point that coincides with an event gets the values
after the event.  FMI 3 arrays are flattened (``y[0]``, ``y[1]``, ...,
row-major; ``A[i,j]`` for two dimensions), their sizes taken from the
structural parameters' start values.  Integer, enumeration and Boolean
outputs are recorded as numbers.  Clocks and inputs of discrete variability
are refused, saying so.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK45, Radau

from blocks.engines.budget import Budget
from blocks.engines.integrate import DivergenceError, LoopEvents, SimulationTerminated, SolverFailure, integrate_on_grid
from blocks.engines.monitor import Monitor

from .archive import ExtractionLimits
from .description import array_shape, element_names, state_variables
from .errors import BudgetError, FMUError
from .events import FMUEventSource
from .instance import FMUInstance

__all__ = ["simulate_fmu", "SOLVERS"]

SOLVERS = {"DOP853": DOP853, "RK45": RK45, "LSODA": LSODA, "BDF": BDF, "Radau": Radau}
_NUMERIC_OUTPUTS = ("Real", "Float64", "Float32", "Integer", "Enumeration", "Boolean", "Int8", "UInt8", "Int16",
                    "UInt16", "Int32", "UInt32", "Int64", "UInt64")


def _positive(value, name: str) -> float:
    if isinstance(value, (bool, str, bytes)):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return number


def _grid(start: float, t_final: float, output_step: float) -> np.ndarray:
    span = t_final - start
    if not (math.isfinite(span) and span > 0):
        raise ValueError(f"t_final must be after start_time = {start:g} s, got {t_final!r}")
    n = int(math.floor(span / output_step * (1 + 1e-12)))
    grid = start + output_step * np.arange(n + 1)
    if t_final - grid[-1] > 1e-9 * max(1.0, abs(t_final)):
        grid = np.append(grid, t_final)     # the end is always recorded
    else:
        grid[-1] = t_final
    return grid


class _Inputs:
    """The real inputs as functions of time: constants, callables ``f(t)``, or the FMU's start values."""

    def __init__(self, inst: FMUInstance, inputs: dict | None):
        md = inst.model_description
        self.names = [v.name for v in md.modelVariables if v.causality == "input" and v.type in ("Real", "Float64")]
        given = dict(inputs or {})
        unknown = sorted(set(given) - set(self.names))
        if unknown:
            raise ValueError(f"inputs: {unknown} are not real inputs of {inst.source} (its real inputs: "
                             f"{self.names or 'none'})")
        self.sizes = [inst.size(n) for n in self.names]
        self.labels = [e for n in self.names for e in element_names(inst.variables[n],
                                                                    array_shape(inst.variables[n], inst.source))]
        self.vr = inst.value_references(self.names)
        self.parts: list = []
        for name, size in zip(self.names, self.sizes):
            value = given.get(name)
            if value is None:
                value = _start_array(inst.variables[name], size)
            self.parts.append(value if callable(value) else self._constant(name, value, size))
        self.constant = all(not callable(p) for p in self.parts)
        self._value = (np.concatenate([np.asarray(p, dtype=float).ravel() for p in self.parts]) if self.parts
                       else np.zeros(0)) if self.constant else None

    @staticmethod
    def _constant(name: str, value, size: int) -> np.ndarray:
        arr = np.asarray(value, dtype=float).ravel()
        if arr.size != size or not np.all(np.isfinite(arr)):
            raise ValueError(f"inputs[{name!r}] must be {size} finite number(s) or a function of t, got {value!r}")
        return arr

    def at(self, t: float) -> np.ndarray:
        """All input elements at time ``t`` (s)."""
        if self.constant:
            return self._value
        values = []
        for name, size, part in zip(self.names, self.sizes, self.parts):
            arr = np.asarray(part(t) if callable(part) else part, dtype=float).ravel()
            if arr.size != size or not np.all(np.isfinite(arr)):
                raise ValueError(f"inputs[{name!r}]({t:.9g}) must give {size} finite number(s), got {arr.tolist()}")
            values.append(arr)
        return np.concatenate(values) if values else np.zeros(0)


def _start_array(variable, size: int) -> np.ndarray:
    text = variable.start
    if text is None:
        return np.zeros(size)
    values = [float(s) for s in str(text).split()] if isinstance(text, str) else [float(text)]
    return np.array(values if len(values) == size else values[:1] * size)


class _Model:
    """The FMU seen by the solver: set time, states and inputs, then ask."""

    def __init__(self, inst: FMUInstance, inputs: _Inputs):
        self.inst, self.inputs = inst, inputs
        self.evaluations = 0

    def at(self, t: float, x: np.ndarray) -> None:
        self.inst.set_time(float(t))
        if x.size:
            self.inst.set_states(x)
        if self.inputs.names:
            self.inst.set_real(self.inputs.vr, self.inputs.at(float(t)))

    def rhs(self, t, x):
        self.evaluations += 1
        self.at(t, x)
        return self.inst.derivatives()


def simulate_fmu(path, t_final: float, output_step: float, inputs: dict | None = None,
                 start_values: dict | None = None, *, start_time: float = 0.0, method: str = "DOP853",
                 rtol: float = 1e-10, atol: float = 1e-12, event_tolerance: float = 1e-12,
                 max_step: float | None = None, budget: Budget | None = None, limits: ExtractionLimits | None = None,
                 extract_to=None) -> ct.TimeResponseData:
    """Simulate a Model Exchange FMU (FMI 2 or 3) with its events; outputs on a fixed grid.

    Parameters
    ----------
    path : str, pathlib.Path or ExtractedFMU
        The ``.fmu`` file (Model Exchange).
    t_final : float
        End time (s).
    output_step : float
        Spacing of the recorded points (s); ``t_final`` is always recorded.
    inputs : dict, optional
        Real input name -> constant (a number, or ``size`` numbers for an FMI 3
        array input) or function of ``t`` (s) returning it.  Inputs not given
        keep their start values.
    start_values : dict, optional
        Variable name -> start value set before initialization, checked
        against the variable's type (:mod:`fmu.start_values`).
    start_time : float
        Initial time (s).
    method : {"DOP853", "RK45", "LSODA", "BDF", "Radau"}
        SciPy solver of the continuous states (a stiff FMU wants BDF, Radau or LSODA).
    rtol, atol : float
        Solver tolerances.
    event_tolerance : float
        Length (s) below which a state event's bracket is accepted.
    max_step : float, optional
        Largest solver step (s); default ``output_step`` (an indicator that
        crosses twice within one step would otherwise go unseen).
    budget : Budget, optional
        The recorded points are checked against its ``steps``, the
        right-hand-side evaluations against ``steps`` x 6, and the wall time
        against ``seconds`` (default :meth:`blocks.engines.budget.Budget.from_env`).
    limits, extract_to :
        Passed to :class:`~fmu.instance.FMUInstance`.

    Returns
    -------
    control.TimeResponseData
        Outputs named by the FMU's output variables (arrays as ``y[0]``,
        ``y[1]``, ...), states by its state variables, inputs by its real
        inputs.  Attribute ``simulation``: ``events`` (list of ``{"time",
        "kind"}``, kind ``"state"``, ``"time"`` or ``"step"``), ``terminated``
        (the time the FMU asked to stop, or None), ``method``,
        ``rhs_evaluations``.

    Raises
    ------
    ValueError
        For a bad ``t_final``, ``output_step``, ``method`` or input.
    FMUUnsupportedError
        For clocks or discrete-variability inputs.
    BudgetError
        When the recorded points, the right-hand-side evaluations or the wall time exceed ``budget``.
    FMUError
        (other subclasses) for a bad archive or an error status from the FMU
        (:class:`~fmu.errors.FMUStepError` names the call and the time).

    Examples
    --------
    The FMI Reference FMU BouncingBall (built from its public source)::

        resp = fmu.simulate_fmu("BouncingBall.fmu", t_final=2.0, output_step=0.01)
        height = resp.outputs[resp.output_labels.index("h")]      # m, on the 10 ms grid
        impacts = [e["time"] for e in resp.simulation["events"]]  # s: 0.4515, 1.0837, 1.5261, 1.8359
    """
    output_step = _positive(output_step, "output_step")
    start_time = float(start_time)
    if not math.isfinite(start_time):
        raise ValueError(f"start_time must be a finite number (s), got {start_time!r}")
    try:
        t_final = float(t_final)
    except (TypeError, ValueError):
        raise ValueError(f"t_final must be a finite number (s), got {t_final!r}") from None
    grid = _grid(start_time, t_final, output_step)
    event_tolerance = _positive(event_tolerance, "event_tolerance")
    if method not in SOLVERS:
        raise ValueError(f"method must be one of {list(SOLVERS)}, got {method!r}")
    max_step = output_step if max_step is None else _positive(max_step, "max_step")
    budget = Budget.from_env() if budget is None else budget
    budget.check_steps(grid.size, "simulate_fmu", f"(t_final - start_time) = {t_final - start_time:g} s / "
                       f"output_step = {output_step:g} s")

    with FMUInstance(path, kind="ModelExchange", start_values=start_values,
                     start_time=start_time, limits=limits, extract_to=extract_to, events=True) as inst:
        ins = _Inputs(inst, inputs)
        model = _Model(inst, ins)
        deadline = Monitor.for_job(f"simulate_fmu of {inst.source}", budget)
        outputs = [v.name for v in inst.model_description.modelVariables
                   if v.causality == "output" and v.type in _NUMERIC_OUTPUTS]
        out_labels = [e for n in outputs for e in element_names(inst.variables[n],
                                                                array_shape(inst.variables[n], inst.source))]
        state_vars = state_variables(inst.model_description, inst.source)
        state_labels = [e for v in state_vars for e in element_names(v, array_shape(v, inst.source))]
        x0 = inst.get_states() if inst.n_states else np.zeros(0)

        def rhs(t, x):
            dx = model.rhs(t, x)
            if model.evaluations > deadline.max_evaluations:
                raise BudgetError(f"simulate_fmu of {inst.source}: {model.evaluations} right-hand-side evaluations "
                                  f"by t = {t:.6g} s, more than the step budget allows ({budget.steps:,} steps, "
                                  f"{deadline.max_evaluations:,} evaluations): the FMU is stiff (try "
                                  "method='BDF') or fast there; shorten the run or raise it with --max-steps or "
                                  "DOBKIT_MAX_STEPS", key="", limit="steps")
            if model.evaluations % 200 == 0:
                deadline.check_time(where=f"t = {t:.6g} s of {t_final:g} s")
            return dx

        def observed(t, x):     # outputs and inputs at a grid point, the FMU's discrete states of that time
            model.at(t, x)
            return np.concatenate([inst.read(outputs), ins.at(t)])

        # the FMU as the one hybrid block of a loop: blocks.engines.integrate's event loop, as for FMU blocks in a loop
        events = LoopEvents([(FMUEventSource(inst, inst.model_identifier, start_time), slice(0, x0.size))],
                            lambda t, x: model.at(t, x), observed)
        terminated, end_state = (start_time, x0) if inst.terminate_requested else (None, None)
        try:
            if terminated is None:
                states, _ = integrate_on_grid(rhs, x0, grid, method, rtol=rtol, atol=atol, max_step=max_step,
                                              events=events, event_tolerance=event_tolerance)
            else:
                states = np.zeros((x0.size, 0))
        except SimulationTerminated as stop:
            states, terminated, end_state = stop.states[:, :stop.done], stop.time, stop.state
        except DivergenceError as err:
            raise FMUError(f"{inst.source}: a state became non-finite at t = {err.time:.9g} s") from None
        except SolverFailure as err:
            raise FMUError(f"{inst.source}: the {method} solver stopped at t = {err.time:.9g} s: {err.reason}") \
                from None
        rec_t = list(grid[:states.shape[1]])
        rec_x = list(states.T)
        rows = list(events.outputs)
        # the FMU stopped between grid points: its last point is where it stopped
        if terminated is not None and (not rec_t or rec_t[-1] < terminated):
            rec_t.append(terminated)
            rec_x.append(np.array(end_state))
            rows.append(observed(terminated, end_state))
        n_out = len(out_labels)
        rec_y = [r[:n_out] for r in rows]
        rec_u = [r[n_out:] for r in rows]
        info = {"fmu": str(inst.path), "fmi_version": inst.fmi_version, "model": inst.model_identifier,
                "method": f"SciPy {method}, rtol {rtol:g}, atol {atol:g}; state events located to "
                          f"{event_tolerance:g} s", "events": events.log,
                "terminated": None if terminated is None else float(terminated), "rhs_evaluations": model.evaluations}
    resp = ct.TimeResponseData(np.array(rec_t), np.array(rec_y).T if out_labels else np.zeros((0, len(rec_t))),
                               np.array(rec_x).T if state_labels else None,
                               np.array(rec_u).T if ins.labels else None,
                               output_labels=out_labels, state_labels=state_labels or None,
                               input_labels=ins.labels or None, sysname=inst.model_identifier, issiso=False,
                               plot_inputs=bool(ins.labels))
    resp.simulation = info
    return resp

