"""Model Exchange events: the event iteration, and FMUs with events as blocks of a loop the numpy engine runs.

:func:`event_iteration` is the one place where dobkit enters Event Mode,
iterates ``fmi2NewDiscreteStates`` / ``fmi3UpdateDiscreteStates`` and goes
back to Continuous-Time Mode; :func:`fmu.simulate_fmu` (an FMU on its own)
and :class:`FMUEventSource` (an FMU block in a loop) both use it, and both
locate state events with :func:`blocks.engines.integrate.locate_crossing`.

An FMU block (:func:`fmu.load`) with event indicators or a time event
announced at initialization carries an :class:`FMUEventSource` as its
``event_source``; the numpy engine (:func:`blocks.engines.integrate.integrate_on_grid`
with :func:`blocks.engines.integrate.loop_events`) then stops at its events, runs
the event iteration, takes over the states the FMU re-initialised and starts
a new solver.  :func:`simulate_loop` runs any interconnection that way.  The
compiled and batch engines cannot run such a loop (the compiled engine names
the FMU block, which has no kernels; the batch engine takes no plant block),
and python-control's own ``input_output_response`` would step over the
events: ``blocks.simulate(..., engine="python-control")`` refuses a loop with
one, naming the blocks.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np

from blocks.engines.integrate import SOLVERS, DivergenceError, EventSource, SimulationTerminated, integrate_on_grid, loop_events

from .errors import FMUError
from .instance import FMUInstance

__all__ = ["event_iteration", "FMUEventSource", "simulate_loop", "has_events"]


def event_iteration(inst: FMUInstance) -> tuple[bool, bool]:
    """Enter Event Mode at the time, states and inputs last set; iterate; leave it unless the FMU asks to stop.

    Returns
    -------
    changed : bool
        Whether the FMU re-initialised its continuous states (read them back).
    terminate : bool
        Whether it asked to end the simulation (it is then left in Event Mode).
    """
    inst.enter_event_mode()
    changed = inst.update_discrete_states()
    if inst.terminate_requested:
        return changed, True
    inst.enter_continuous_time_mode()
    return changed, False


def has_events(inst: FMUInstance) -> bool:
    """Whether an initialized Model Exchange FMU can have events: event indicators or an announced time event."""
    return inst.n_event_indicators > 0 or inst.next_event_time is not None


class FMUEventSource(EventSource):
    """A Model Exchange FMU block's events, for :class:`blocks.engines.integrate.LoopEvents`.

    The loop's right-hand side has just set the FMU's inputs (and time and
    states) when a method is called; each method sets time and states again
    from its arguments, so that it does not depend on the order in which the
    loop evaluated its blocks.

    Parameters
    ----------
    inst : FMUInstance
        Initialized with ``events=True``.
    name : str
        The block's name.
    start_time : float
        The time (s) the FMU was initialized at: a run must start there, and
        only one run is possible (its discrete states move on).
    """

    def __init__(self, inst: FMUInstance, name: str, start_time: float) -> None:
        self.inst, self.name, self.start_time = inst, name, float(start_time)
        self.n_indicators = inst.n_event_indicators
        self.ran = False

    def begin(self, t: float) -> None:
        # the FMU's discrete states move on with a run and cannot be set back
        if self.ran:
            raise FMUError(f"block '{self.name}' ({self.inst.source}): an FMU with events keeps the discrete states "
                           "of its last run; load it again (fmu.load) for another run")
        if abs(t - self.start_time) > 1e-12 * max(1.0, abs(t)):
            raise FMUError(f"block '{self.name}' ({self.inst.source}): the run starts at t = {t:.9g} s, the FMU was "
                           f"initialized at t = {self.start_time:.9g} s (fmu.load's start_time)")
        self.ran = True

    @property
    def next_event_time(self) -> float | None:
        return self.inst.next_event_time

    def _at(self, t: float, x: np.ndarray) -> None:
        self.inst.set_time(float(t))
        if self.inst.n_states:
            self.inst.set_states(x)

    def indicators(self, t: float, x: np.ndarray) -> np.ndarray:
        self._at(t, x)
        return self.inst.event_indicators()

    def completed_step(self, t: float, x: np.ndarray) -> tuple[bool, bool]:
        self._at(t, x)
        return self.inst.completed_integrator_step()

    def update(self, t: float, x: np.ndarray) -> tuple[np.ndarray | None, bool]:
        self._at(t, x)
        changed, terminate = event_iteration(self.inst)
        return (self.inst.get_states() if changed and self.inst.n_states else None), terminate


def simulate_loop(system, t_grid, x0=None, *, method: str = "RK45", rtol: float = 1e-6, atol: float = 1e-8,
                  max_step: float = np.inf, event_tolerance: float = 1e-12) -> ct.TimeResponseData:
    """Simulate an interconnection with the numpy engine, stopping at its FMU blocks' events.

    Parameters
    ----------
    system : control.InterconnectedSystem
        A loop without external inputs; some blocks may be FMUs with events (:func:`fmu.load`).
    t_grid : array_like
        Increasing output times (s).
    x0 : array_like, optional
        Loop state at ``t_grid[0]``; by default each block's ``initial_state``
        (an FMU block's is its state after initialization) or zeros.
    method : str
        A SciPy solver (:data:`blocks.engines.integrate.SOLVERS`).
    rtol, atol, max_step : float
        Solver options (``max_step`` in s; an indicator that crosses zero
        twice within one step goes unseen, so keep it below the shortest flight).
    event_tolerance : float
        Length (s) below which a state event's bracket is accepted.

    Returns
    -------
    control.TimeResponseData
        The loop's outputs and states on ``t_grid`` (outputs recorded during
        the run, with the FMUs' discrete states of that time; a grid point at
        an event's time has the values after it).  Attribute ``simulation``:
        ``events`` (``{"time", "kind"}``, kind ``"state"``, ``"time"`` or
        ``"step"``), ``terminated`` (when an FMU asked to stop, or None: the
        response then ends there), ``rhs_evaluations``.

    Raises
    ------
    ValueError
        For a bad ``method``, grid or ``x0``, or a loop with external inputs.
    FMUError
        If the solver fails or a state becomes non-finite; the message says when.
    """
    from blocks.engines.fastsim import CompiledLoop  # the numpy engine: built on first use only

    if method not in SOLVERS:
        raise ValueError(f"method must be one of {list(SOLVERS)}, got {method!r}")
    if not (isinstance(event_tolerance, (int, float)) and math.isfinite(event_tolerance) and event_tolerance > 0):
        raise ValueError(f"event_tolerance must be a finite number > 0 (s), got {event_tolerance!r}")
    if system.ninputs:
        raise ValueError(f"system '{system.name}' has {system.ninputs} external input(s) "
                         f"({', '.join(system.input_labels)}): simulate_loop runs a closed loop without inputs")
    t_grid = np.asarray(t_grid, dtype=float)
    x0 = _initial_state(system) if x0 is None else np.asarray(x0, dtype=float).ravel()
    if x0.size != system.nstates:
        raise ValueError(f"x0 must have {system.nstates} elements (the loop's states), got {x0.size}")
    loop = CompiledLoop(system)
    events = loop_events(system, loop.rhs, loop.output)
    if events is None:
        states, nfev = integrate_on_grid(loop.rhs, x0, t_grid, method, rtol=rtol, atol=atol, max_step=max_step)
        outputs, times, terminated = loop.outputs_on_grid(t_grid, states), t_grid, None
        log: list = []
    else:
        try:
            states, nfev = integrate_on_grid(loop.rhs, x0, t_grid, method, rtol=rtol, atol=atol, max_step=max_step,
                                             events=events, event_tolerance=event_tolerance)
            times, terminated = t_grid, None
        except SimulationTerminated as stop:
            states, times, terminated, nfev = stop.states[:, :stop.done], t_grid[:stop.done], stop.time, None
        except DivergenceError as err:
            raise FMUError(f"loop '{system.name}': a state became non-finite at t = {err.time:.9g} s") from None
        outputs = np.array(events.outputs).T if events.outputs else np.zeros((system.noutputs, times.size))
        log = events.log
    resp = ct.TimeResponseData(times, outputs, states, None, output_labels=list(system.output_labels),
                               state_labels=list(system.state_labels), sysname=system.name, issiso=False)
    resp.simulation = {"events": log, "terminated": terminated, "rhs_evaluations": nfev,
                       "method": f"SciPy {method}, rtol {rtol:g}, atol {atol:g}; state events located to "
                                 f"{event_tolerance:g} s"}
    return resp


def _initial_state(system) -> np.ndarray:
    blocks = getattr(system, "syslist", [system])
    parts = []
    for block in blocks:
        start = getattr(block, "initial_state", None)
        parts.append(np.zeros(block.nstates) if start is None else np.asarray(start, dtype=float).ravel())
    return np.concatenate(parts) if parts else np.zeros(0)
