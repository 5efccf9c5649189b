"""Integrate a right-hand side onto an output time grid, stopping at the first step that diverges.

:func:`integrate_on_grid` is the output-grid loop of
:func:`scipy.integrate.solve_ivp` -- the same solver classes, options, steps
and dense-output interpolation, so its states equal
``solve_ivp(fun, (t_grid[0], t_grid[-1]), x0, t_eval=t_grid, ...)`` exactly --
with one addition: every accepted step is checked for divergence (a state
beyond a bound, or not finite), and the time the bound was crossed is found in
that step's dense output.  Like a solver event, the check sees the state at
the ends of steps.  ``solve_ivp`` needs a terminal event function for
that, and its event handling costs about 40 microseconds per step: 5 % of the
paper scenario's fast run, for a check that costs 2 microseconds here.

Hybrid blocks (an FMU with event indicators or time events, :mod:`fmu.events`)
carry an ``event_source`` (:class:`EventSource`); :func:`loop_events` gathers
those of an interconnection, and ``integrate_on_grid(..., events=...)`` then
stops at their events: after every accepted step the event indicators are
evaluated at its end; where one changed sign the first crossing is located by
bisection on the step's dense output until the bracket is shorter than
``event_tolerance`` (:func:`locate_crossing`); the solver never steps past an
announced time event; there the blocks' event updates run, states they
re-initialise are taken over, and a new solver starts from the state after the
event.  A block that asks to end the simulation stops the run with
:class:`SimulationTerminated`, carrying the grid filled so far.  Both are
one loop (:func:`_integrate`): without ``events`` there is no event to stop
at, one solver runs from the first grid time to the last, and the loop is
the one above, step for step.

The ticks of a sampled diagram are events of the same kind
(:class:`blocks.engines.sampling.TickSource`): a block whose time events are a fixed
schedule (``scheduled``) is neither logged nor counted as chattering, one
that reads no inputs set by the loop's right-hand side (``needs_inputs``
false) costs no extra evaluation of it, one whose times are exact
(``time_rtol = 0``) keeps a grid point a rounding error before its event in
the interval before, and each block updates only at the events it is ``due``
at.  A state beyond ``bound`` after an event's update stops the run there.
"""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import scipy.integrate
import scipy.optimize

from blocks.engines.lean_rk45 import LeanRK45, lean_rk45_usable

__all__ = ["SOLVERS", "integrate_on_grid", "DivergenceError", "SolverFailure", "SimulationTerminated", "MAX_EVENTS",
           "EventSource", "LoopEvents", "loop_events", "hybrid_blocks", "refuse_hybrid", "locate_crossing"]

#: The :func:`scipy.integrate.solve_ivp` methods, by name.
SOLVERS = {name: getattr(scipy.integrate, name) for name in ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")}
# The classes that step: scipy's, but RK45 as LeanRK45 (the same steps and floats, less Python per step) where this
# scipy's RK45 is the one LeanRK45 restates.
_STEPPERS = dict(SOLVERS, RK45=LeanRK45) if lean_rk45_usable() else dict(SOLVERS)


# Points of a step's dense output searched for the first crossing of the bound (only when a step crossed it).
_CROSSING_SAMPLES = 33


class DivergenceError(RuntimeError):
    """A state left its bound (or became non-finite) at time :attr:`time` (s); :attr:`state` is the state then."""

    def __init__(self, time: float, bound, state: np.ndarray | None = None) -> None:
        shown = f"{bound:g}" if np.ndim(bound) == 0 else "its bound"
        super().__init__(f"a state exceeded {shown} (or became non-finite) at t = {time:.6g} s")
        self.time = time
        self.bound = bound
        self.state = state


class SolverFailure(RuntimeError):
    """The solver stopped at time :attr:`time` (s) before the end of the grid; :attr:`reason` says why."""

    def __init__(self, time: float, reason: str) -> None:
        super().__init__(f"the solver stopped at t = {time:.6g} s: {reason}")
        self.time = time
        self.reason = reason


class SimulationTerminated(SolverFailure):
    """A block asked to end the simulation at :attr:`time` (s) (FMI ``terminateSimulation``).

    :attr:`states` holds the grid's states up to and including :attr:`time`
    (``states[:, :done]``, the rest unset), :attr:`done` how many points,
    :attr:`state` the state at :attr:`time`.
    """

    def __init__(self, time: float, reason: str, states: np.ndarray, done: int, state: np.ndarray) -> None:
        super().__init__(time, reason)
        self.states = states
        self.done = done
        self.state = state


def integrate_on_grid(fun: Callable[[float, np.ndarray], np.ndarray], x0, t_grid, method: str = "RK45",
                      rtol: float = 1e-6, atol: float = 1e-8, max_step: float = np.inf, bound: float = np.inf,
                      progress: Callable[[float], None] | None = None,
                      first_step: float | None = None, monitor=None, events: LoopEvents | None = None,
                      event_tolerance: float = 1e-12) -> tuple[np.ndarray, int]:
    """States of ``x' = fun(t, x)`` at the times of ``t_grid``, integrated from ``x0`` at ``t_grid[0]``.

    Parameters
    ----------
    fun : callable
        Right-hand side ``fun(t, x) -> x'``.
    x0 : array_like, shape (n,)
        State at ``t_grid[0]``.
    t_grid : array_like, shape (T,)
        Increasing output times (s); the integration runs from the first to the last.
    method : str
        A :data:`SOLVERS` name.
    rtol, atol, max_step : float
        Solver options as in :func:`scipy.integrate.solve_ivp` (``max_step`` in s).
    bound : float or array_like, shape (n,)
        Largest magnitude a state (or each state) may reach; a step beyond it
        (or a non-finite state) raises :class:`DivergenceError`.
    progress : callable, optional
        Called with the fraction done (0 to 1), at most every 0.2 s of wall time.
    first_step : float, optional
        The first step to try (s); by default the solver's own estimate.  With
        ``events`` it is the first step of every solver (after every event),
        at most the span to the next announced event (``math.inf``: that span).
    monitor : blocks.engines.monitor.Monitor, optional
        The job's Monitor: after every step it judges the step budget (raising
        :class:`~blocks.engines.monitor.SimulationError`) and the wall time (raising
        :class:`~blocks.engines.budget.BudgetError`), and takes the progress reports.
    events : LoopEvents, optional
        The loop's hybrid blocks (:func:`loop_events`): the run stops at their
        state and time events and lets them update (see the module docstring).
    event_tolerance : float
        With ``events``: length (s) below which a state event's bracket is accepted.

    Returns
    -------
    states : numpy.ndarray, shape (n, T)
    nfev : int
        Right-hand-side calls made.

    Raises
    ------
    DivergenceError, SolverFailure
    SimulationTerminated
        With ``events``, when a block asks to end the simulation.
    """
    t_grid = np.asarray(t_grid, dtype=float)
    if method not in SOLVERS:
        raise ValueError(f"solver method must be one of {list(SOLVERS)}, got {method!r}")
    if t_grid.ndim != 1 or t_grid.size < 2 or not np.all(np.isfinite(t_grid)) or np.any(np.diff(t_grid) <= 0):
        raise ValueError("t_grid must be at least two finite, increasing times")
    t0, t_end = float(t_grid[0]), float(t_grid[-1])
    x0 = np.asarray(x0, dtype=float)
    bound = np.asarray(bound, dtype=float)
    if not np.all(np.isfinite(x0)) or not np.all(np.abs(x0) <= bound):
        raise DivergenceError(t0, bound, x0)
    options = {} if first_step is None else {"first_step": min(first_step, t_end - t0, max_step)}
    return _integrate(fun, x0, t_grid, method, dict(rtol=rtol, atol=atol, max_step=max_step, **options), bound,
                      progress, monitor, events, float(event_tolerance))


def _crossing_time(solver, bound: float) -> float:
    """When, within the step just taken, the largest state magnitude reached ``bound`` (s).

    The end of the step when the state there is not finite (no crossing to interpolate).
    """
    t_old, t_new = float(solver.t_old), float(solver.t)
    if not np.all(np.isfinite(solver.y)):
        return t_new
    dense = solver.dense_output()
    margin = lambda t: np.min(bound - np.abs(dense(t)))     # noqa: E731  > 0 inside the bound
    # the first sample of the step at or beyond the bound brackets the first crossing
    samples = np.linspace(t_old, t_new, _CROSSING_SAMPLES)
    inside = np.array([margin(t) > 0.0 for t in samples])
    if not inside[0]:
        return t_old
    if inside.all():                   # the interpolant ends a rounding error inside: no bracket
        return t_new
    k = int(np.argmin(inside))
    return float(scipy.optimize.brentq(margin, samples[k - 1], samples[k], xtol=1e-12 * max(1.0, abs(t_new))))


# -- hybrid blocks: state and time events -------------------------------------------------------------------

#: More events than this in one run is taken as chattering (a Zeno trajectory).
MAX_EVENTS = 100_000


class EventSource:
    """What a hybrid block offers the integrator (the interface; :class:`fmu.events.FMUEventSource` implements it).

    Every method is called right after the loop's right-hand side was
    evaluated at the time and state concerned, so the block's inputs are set;
    ``x`` is the block's own slice of the loop state.

    Attributes
    ----------
    name : str
        The block's name, for messages.
    n_indicators : int
        Number of event indicators (a state event is a change of sign of one).
    next_event_time : float or None
        The time event the block has announced (s), if any.
    """

    name = "block"
    n_indicators = 0
    next_event_time: float | None = None
    #: Whether its methods read inputs that the loop's right-hand side sets (an FMU's): the rhs is then
    #: evaluated at ``(t, x)`` before they are called.
    needs_inputs = True
    #: Whether its time events are a fixed schedule (sample ticks): they are neither logged nor counted
    #: against :data:`MAX_EVENTS`.
    scheduled = False
    #: Relative tolerance (of the time) within which a grid point counts as at an event's time rather than before.
    time_rtol = 1e-13

    def due(self, t: float, kind: str) -> bool:
        """Whether the block updates at an event of ``kind`` (``"state"``, ``"time"``, ``"step"``) at ``t`` (s).

        An FMU takes part in every event of the loop; a block sampled at ticks only in its own.
        """
        return True

    def begin(self, t: float) -> None:
        """A run starts at ``t`` (s): raise if the block cannot start one there (e.g. it has run already)."""

    def indicators(self, t: float, x: np.ndarray) -> np.ndarray:
        """The event indicators at time ``t`` (s) and block state ``x``."""
        raise NotImplementedError

    def completed_step(self, t: float, x: np.ndarray) -> tuple[bool, bool]:
        """An integrator step ended at ``t``: ``(does the block want an event now?, does it ask to stop?)``."""
        return False, False

    def update(self, t: float, x: np.ndarray) -> tuple[np.ndarray | None, bool]:
        """The block's event update at ``t``: ``(its re-initialised state or None, does it ask to stop?)``."""
        raise NotImplementedError


class LoopEvents:
    """The hybrid blocks of an interconnection, seen as one: concatenated indicators, the earliest time event.

    Parameters
    ----------
    sources : list of (EventSource, slice)
        Each hybrid block with its slice of the loop state.
    rhs : callable
        The loop's right-hand side ``rhs(t, x)``: evaluated before asking the
        blocks, so that their inputs are those of ``(t, x)``.
    output : callable, optional
        ``output(t, x) -> y``, the loop's outputs; with it :meth:`record`
        keeps them at the grid points as the run passes them (the blocks'
        discrete states are then those of that time, which a pass over the
        grid after the run would not see).

    Attributes
    ----------
    log : list of dict
        The events so far: ``{"time": s, "kind": "state" | "time" | "step"}``.
    terminated : float or None
        When a block asked to end the simulation (s).
    outputs : list of numpy.ndarray
        The outputs recorded by :meth:`record`.
    """

    def __init__(self, sources: list, rhs: Callable, output: Callable | None = None) -> None:
        self.sources = list(sources)
        self.rhs, self.output = rhs, output
        self.n_indicators = sum(src.n_indicators for src, _ in self.sources)
        self._inputs = any(src.needs_inputs for src, _ in self.sources)
        self.time_rtol = min((src.time_rtol for src, _ in self.sources), default=1e-13)
        self.log: list[dict] = []
        self.terminated: float | None = None
        self.outputs: list[np.ndarray] = []

    @property
    def names(self) -> str:
        """The hybrid blocks' names, quoted, for messages."""
        return ", ".join(f"'{src.name}'" for src, _ in self.sources)

    def begin(self, t: float) -> None:
        """Tell every block that a run starts at ``t`` (s)."""
        for src, _ in self.sources:
            src.begin(t)

    def next_time(self) -> float | None:
        """The earliest announced time event (s), or None."""
        times = [src.next_event_time for src, _ in self.sources if src.next_event_time is not None]
        return min(times) if times else None

    def indicators(self, t: float, x: np.ndarray) -> np.ndarray:
        """All blocks' event indicators at ``(t, x)`` (loop state)."""
        if self._inputs:
            self.rhs(t, x)
        parts = [src.indicators(t, x[part]) for src, part in self.sources if src.n_indicators]
        return np.concatenate(parts) if parts else np.zeros(0)

    def completed_step(self, t: float, x: np.ndarray) -> tuple[bool, str | None]:
        """``(does a block want an event at t?, the name of a block asking to stop, or None)``."""
        if self._inputs:
            self.rhs(t, x)
        wanted = False
        for src, part in self.sources:
            step_event, stop = src.completed_step(t, x[part])
            if stop:
                return wanted, src.name
            wanted = wanted or step_event
        return wanted, None

    def update(self, t: float, x: np.ndarray, kind: str) -> tuple[np.ndarray, str | None]:
        """Every block's event update at ``(t, x)``: the state after the event, and who asked to stop (or None)."""
        due = [(src, part) for src, part in self.sources if src.due(t, kind)]
        if any(not src.scheduled for src, _ in due):
            self.log.append({"time": float(t), "kind": kind})
            if len(self.log) > MAX_EVENTS:
                raise SolverFailure(t, f"more than {MAX_EVENTS} events of {self.names} (chattering or a Zeno "
                                       "trajectory)")
        x = np.array(x, dtype=float)
        if any(src.needs_inputs for src, _ in due):
            self.rhs(t, x)
        for src, part in due:
            new, stop = src.update(t, x[part])
            if new is not None:
                x[part] = new
            if stop:
                return x, src.name
        return x, None

    def record(self, t: float, x: np.ndarray) -> None:
        """Keep the loop's outputs at grid time ``t`` (when made with ``output``)."""
        if self.output is not None:
            self.outputs.append(np.array(self.output(t, x), dtype=float))


def loop_events(system, rhs: Callable, output: Callable | None = None) -> LoopEvents | None:
    """The :class:`LoopEvents` of an interconnection's hybrid blocks (``event_source`` set), or None if none has one.

    Parameters
    ----------
    system : control.InterconnectedSystem or control.NonlinearIOSystem
        The loop (nested interconnections are searched too).
    rhs, output : callable
        As for :class:`LoopEvents`.
    """
    sources = list(_event_sources(system, 0))
    return LoopEvents(sources, rhs, output) if sources else None


def hybrid_blocks(system) -> list[str]:
    """Names of an interconnection's blocks with events (an ``event_source``)."""
    return [src.name for src, _ in _event_sources(system, 0)]


def refuse_hybrid(system, engine: str) -> None:
    """Raise ``ValueError`` naming the blocks with events when ``engine`` (which cannot stop at events) would run them.

    Parameters
    ----------
    system : control.InterconnectedSystem
    engine : str
        The engine's name, for the message.
    """
    names = hybrid_blocks(system)
    if names:
        raise ValueError(f"engine {engine!r} cannot run block(s) {', '.join(repr(n) for n in names)}: they have "
                         "events (an FMU's event indicators or time events), which only the numpy engine (engine="
                         "'fast', fmu.simulate_loop) stops at")


def _event_sources(system, offset: int):
    source = getattr(system, "event_source", None)
    if source is not None:
        yield source, slice(offset, offset + system.nstates)
    for block, first in zip(getattr(system, "syslist", ()), getattr(system, "state_offset", ())):
        yield from _event_sources(block, offset + first)


def locate_crossing(indicators_at: Callable[[float], np.ndarray], t0: float, t1: float, above: np.ndarray,
                    tol: float) -> float:
    """The right end of a bracket shorter than ``tol`` (s) of the first sign change of any indicator in ``(t0, t1]``.

    ``above`` says which indicators were > 0 at ``t0``; at the returned time
    at least one has crossed (``z > 0`` became ``z <= 0`` or the other way).
    """
    a, b = t0, t1
    while b - a > tol:
        mid = 0.5 * (a + b)
        if mid <= a or mid >= b:    # the bracket is down to adjacent floats
            break
        crossed = np.any((indicators_at(mid) > 0) != above)
        a, b = (a, mid) if crossed else (mid, b)
    return b


def _before(t_grid_value: float, t: float, rtol: float = 1e-13) -> bool:
    """Whether a grid time lies before ``t`` (s), a difference within ``rtol`` counting as the same time."""
    return t_grid_value < t - rtol * max(1.0, abs(t))


def _integrate(fun, x0, t_grid, method, options, bound, progress, monitor, events: LoopEvents | None,
               tol: float) -> tuple[np.ndarray, int]:
    """The one stepping loop of :func:`integrate_on_grid`; ``events`` None is a loop without events.

    Every accepted step is checked (solver failure, the bound, the Monitor's
    budgets, progress) and passes the grid points it covers.  With events a
    new solver starts after each event, and a grid point at an event's time
    gets the state (and outputs) after the event.  Without events the single
    solver runs from the first grid time to the last, the grid points of a
    step filled in one call of its dense output (as ``solve_ivp`` fills them).
    """
    t0, t_end = float(t_grid[0]), float(t_grid[-1])
    states = np.empty((x0.size, t_grid.size))
    t, x = t0, np.array(x0, dtype=float)
    done, nfev = 0, 0
    last_report = time.monotonic()
    hybrid = events is not None
    rtol = events.time_rtol if hybrid else 0.0
    if hybrid:
        events.begin(t0)

    def keep(upto_time: float, state_at, inclusive: bool) -> None:
        """Fill the grid points up to ``upto_time`` (before it, a difference within ``rtol`` counting as at it,
        unless ``inclusive``) from ``state_at``."""
        nonlocal done
        upto = int(np.searchsorted(t_grid, upto_time, side="right")) if inclusive else \
            int(np.searchsorted(t_grid, upto_time - rtol * max(1.0, abs(upto_time)), side="left"))
        if upto <= done:
            return
        if not hybrid:                      # one call for the step's points, as solve_ivp
            states[:, done:upto] = state_at(t_grid[done:upto])
            done = upto
            return
        for k in range(done, upto):         # point by point: the blocks' outputs are recorded as the run passes
            s = float(t_grid[k])
            states[:, k] = state_at(s)
            events.record(s, states[:, k])
        done = upto

    while True:
        upcoming = events.next_time() if hybrid else None
        if upcoming is not None and _before(upcoming, t - tol, rtol):
            raise SolverFailure(t, f"block(s) {events.names} announced a time event at t = {upcoming:.9g} s, before "
                                   f"the current time")
        stop = t_end if upcoming is None else min(t_end, upcoming)
        above = events.indicators(t, x) > 0 if hybrid and events.n_indicators else None
        kind, stopper = None, None
        if stop > t:
            interval = options
            if hybrid and "first_step" in options:   # at most the span to the next event (a tick's interval, say)
                interval = dict(options, first_step=min(options["first_step"], stop - t))
            solver = _STEPPERS[method](fun, t, x, stop, vectorized=False, **interval)
            while solver.status == "running":
                message = solver.step()
                if solver.status == "failed":
                    raise SolverFailure(float(solver.t), str(message))
                if not np.all(np.abs(solver.y) <= bound):
                    t_cross = _crossing_time(solver, bound)
                    raise DivergenceError(t_cross, bound, solver.dense_output()(t_cross)
                                          if np.all(np.isfinite(solver.y)) else solver.y.copy())
                t_new = float(solver.t)
                if monitor is not None:
                    monitor.check_evaluations(t_new, nfev + solver.nfev)
                    monitor.check_time(t_new)
                    monitor.report(t_new)
                if not hybrid:
                    keep(t_new, _Dense(solver), inclusive=True)
                else:
                    dense = solver.dense_output()
                    if above is not None and np.any((events.indicators(t_new, solver.y) > 0) != above):
                        t_new = locate_crossing(lambda s: events.indicators(s, dense(s)), float(solver.t_old), t_new,
                                                above, tol)
                        kind = "state"
                    # a grid point at an event's time is kept after the event
                    keep(t_new, dense, inclusive=kind is None and (upcoming is None or _before(t_new, upcoming, rtol)))
                    t, x = t_new, (solver.y.copy() if kind is None else dense(t_new))
                    if kind is None:
                        step_event, stopper = events.completed_step(t, x)
                        if stopper is not None:
                            break
                        if step_event:
                            kind = "step"
                    if kind is not None:
                        break
                if progress is not None and time.monotonic() - last_report > 0.2:
                    last_report = time.monotonic()
                    progress(min(1.0, (t_new - t0) / (t_end - t0)))
            nfev += solver.nfev
            if not hybrid:
                t = float(solver.t)
        if not hybrid:
            break
        if stopper is None and kind is None and upcoming is not None and not _before(t, upcoming, rtol):
            kind = "time"
        if stopper is None and kind is None:     # t_end reached
            break
        if stopper is None:
            x, stopper = events.update(t, x, kind)
            if not np.all(np.abs(x) <= bound):       # an update (a tick's, a re-initialisation) diverged
                raise DivergenceError(t, bound, x)
            again = events.next_time()
            if stopper is None and again is not None and not _before(t, again, rtol):
                raise SolverFailure(t, f"block(s) {events.names} announced a time event at t = {again:.9g} s after "
                                       f"their event at t = {t:.9g} s: a time event must lie after the current time")
        if stopper is not None:
            keep(t, lambda s: x, inclusive=True)
            events.terminated = t
            raise SimulationTerminated(t, f"block '{stopper}' asked to end the simulation (terminateSimulation) at "
                                          f"t = {t:.9g} s", states, done, x)
    if hybrid:
        keep(t_end, lambda s: x, inclusive=True)
    if done != t_grid.size:                     # not expected: the solver ends exactly at t_end
        raise SolverFailure(t, "the output grid was not reached")
    return states, nfev


class _Dense:
    """A step's dense output, made only when a grid point is filled from it (most steps fill none)."""

    __slots__ = ("solver",)

    def __init__(self, solver) -> None:
        self.solver = solver

    def __call__(self, t):
        return self.solver.dense_output()(t)
