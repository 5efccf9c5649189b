"""Block diagrams with continuous and sampled blocks, and their simulation.

python-control refuses to interconnect systems with different time bases.
:class:`HybridSystem` wires continuous blocks (``dt = 0``) and discrete
blocks (``dt = Ts > 0``, python-control's discrete-time
:class:`~control.NonlinearIOSystem`) by signal name, as
:func:`control.interconnect` does, and :meth:`HybridSystem.simulate` runs
them with the semantics of a sampled-data system (as Simulink does):

* time advances in *ticks* of the base period, the smallest discrete period;
  every other period must be a whole multiple of it;
* at a tick, the outputs of all blocks are evaluated in dependency order:
  continuous blocks from their current state, discrete blocks whose sample
  instant it is from their state and current inputs (``y[k] = g(x[k],
  u[k])``); a discrete block between its instants keeps its last output
  (zero-order hold);
* then each discrete block at its instant updates its state,
  ``x[k+1] = f(x[k], u[k])``;
* between ticks the continuous states are integrated with the discrete
  outputs held; the solver is restarted at every tick and never steps
  across one.

With ``RK45`` or ``RK23`` the ticks are run by :mod:`blocks.engines.tick_stepper`:
one embedded Runge-Kutta step of the continuous part per tick (substeps
where the tolerances ask), with scipy's tableau and step control, so the
states are the restarted solver's to rounding at a fraction of its cost.
With another method (or ``tick_stepping = False``) the ticks are scheduled
time events of the numpy engine's one integrator
(:class:`blocks.engines.sampling.TickSource` for
:func:`blocks.engines.integrate.integrate_on_grid`), the mechanism that also stops
at an FMU's events.

A discrete block's own functions are those of python-control
(``updfcn`` gives the next state), so a user's discrete block works the
same way as the built-in sampled controller of :mod:`blocks.diagram.digital`.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Callable

import control as ct
import numpy as np

from blocks.diagram.plan import LoopPlan, make_plan, settle
from blocks.engines.integrate import DivergenceError, LoopEvents, SolverFailure, integrate_on_grid
from blocks.engines.sampling import TickSource
from blocks.engines.tick_stepper import tick_stepper_for

__all__ = ["HybridSystem", "HybridError"]

# Sample periods are whole multiples of the base period to this relative tolerance.
_PERIOD_RTOL = 1e-9


class HybridError(ValueError):
    """A hybrid diagram that cannot be run: a sample period that is not a whole multiple of the base period."""


def _rows(value) -> np.ndarray:
    return value if getattr(value, "ndim", 0) == 1 else np.ravel(value)


class HybridSystem:
    """Continuous and discrete blocks wired by signal name.

    Parameters
    ----------
    syslist : list of control.NonlinearIOSystem
        The blocks; each is continuous (``dt = 0``) or discrete with a sample
        period ``dt > 0`` (s).  ``dt = True`` (unspecified period) is refused.
    inplist, outlist : list of str
        External inputs and the outputs to keep, as for :func:`control.interconnect`.
    name : str
        Name of the diagram.

    Attributes
    ----------
    system : control.InterconnectedSystem
        The wiring (blocks with their time base set aside); use it for signal
        names, not for simulation.
    periods : dict of str to float
        Each block's sample period (s), 0 for continuous blocks.
    base_period : float
        The smallest sample period (s).
    tick_stepping : bool
        Whether :meth:`simulate` takes the steps itself (:mod:`blocks.engines.tick_stepper`) for ``RK45`` and
        ``RK23``; False restarts scipy's solver at every tick (the reference it is tested against).
    """

    tick_stepping = True

    def __init__(self, syslist, inplist=(), outlist=(), name: str = "hybrid") -> None:
        self.periods = {}
        for block in syslist:
            dt = block.dt
            if dt is True or (dt not in (0, None) and not (isinstance(dt, (int, float)) and math.isfinite(dt)
                                                           and dt > 0)):
                raise HybridError(f"block '{block.name}': sample period dt = {dt!r}; give a number of seconds > 0 "
                                  "(or 0 for a continuous block)")
            self.periods[block.name] = float(dt or 0.0)
        discrete = {n: p for n, p in self.periods.items() if p > 0}
        if not discrete:
            raise HybridError("a hybrid diagram needs at least one discrete block (dt > 0)")
        self.base_period = min(discrete.values())
        self.multiples = {}
        for n, p in discrete.items():
            m = p / self.base_period
            if abs(m - round(m)) > _PERIOD_RTOL * m:
                raise HybridError(f"block '{n}': sample period {p:g} s is not a whole multiple of the base period "
                                  f"{self.base_period:g} s")
            self.multiples[n] = int(round(m))
        # python-control wires systems of one time base; the periods are kept here instead
        shadows = []
        for block in syslist:
            shadow = copy.copy(block)
            shadow.dt = None
            shadows.append(shadow)
        self.system = ct.interconnect(shadows, inplist=list(inplist), outlist=list(outlist),
                                      outputs=list(outlist), name=name, check_unused=False)
        self.system.dt = None
        self.name = name
        self.plan: LoopPlan = make_plan(self.system)
        if not self.plan.direct:
            raise HybridError("hybrid diagrams take only connections of one signal with gain 1, and no external "
                              "inputs (every block input named after one output)")
        self.nstates = self.plan.nstates
        self.output_labels = list(self.system.output_labels)
        self.state_labels = list(self.system.state_labels)
        self._discrete = {s.name: self.multiples[s.name] for s in self.plan.steps if s.name in self.multiples}
        self._continuous_updates = [s for s in self.plan.updates if s.name not in self._discrete]
        self._steps_between_ticks = self._interval_steps()

    @property
    def syslist(self) -> list:
        """The blocks as wired (their time base set aside; see :meth:`blocks`)."""
        return list(self.system.syslist)

    def blocks(self) -> list:
        """Copies of the blocks with their own sample periods, ready to be wired again (for example with one
        block replaced) into a new :class:`HybridSystem`."""
        out = []
        for block in self.system.syslist:
            block = copy.copy(block)
            block.dt = self.periods[block.name]
            out.append(block)
        return out

    # -- one tick -------------------------------------------------------------------------------------
    def tick_outputs(self, k: int, x: np.ndarray, held: np.ndarray) -> np.ndarray:
        """All block outputs at tick ``k`` (time ``k * base_period``), refreshing ``held`` for the blocks sampled now.

        Parameters
        ----------
        k : int
            Tick number.
        x : numpy.ndarray
            States of the whole diagram.
        held : numpy.ndarray
            Block outputs held since the previous instants, changed in place for the blocks sampled at ``k``.
        """
        plan, t = self.plan, k * self.base_period
        y = held.copy()
        y[plan.copy_y] = x[plan.copy_x]

        def one_pass(y):
            for s in plan.steps:
                m = self._discrete.get(s.name)
                if m is None or k % m == 0:
                    y[s.y] = _rows(s.output(t, x[s.x], y[s.gather], *s.output_args))
        settle(plan, one_pass, y)
        for s in plan.steps:
            m = self._discrete.get(s.name)
            if m is not None and k % m == 0:
                held[s.y] = y[s.y]
        return y

    def tick_updates(self, k: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The states after the discrete blocks sampled at tick ``k`` have updated (continuous states unchanged)."""
        t = k * self.base_period
        x_next = x.copy()
        for s in self.plan.updates:
            m = self._discrete.get(s.name)
            if m is not None and k % m == 0:
                x_next[s.x] = _rows(s.update(t, x[s.x], y[s.gather], *s.update_args))
        return x_next

    def _interval_steps(self) -> list:
        """The continuous blocks whose outputs a continuous update needs, directly or through other such blocks."""
        plan = self.plan
        continuous = [s for s in plan.rhs_steps if s.name not in self._discrete]
        owner = {j: s for s in continuous for j in range(s.y.start, s.y.stop)}
        needed, stack = set(), []
        for s in self._continuous_updates:
            stack += np.arange(plan.nsignals)[s.gather].tolist()
        while stack:
            step = owner.get(stack.pop())
            if step is not None and step.name not in needed:
                needed.add(step.name)
                stack += np.arange(plan.nsignals)[step.gather].tolist()
        return [s for s in continuous if s.name in needed]

    def continuous_rhs(self, held: np.ndarray) -> Callable[[float, np.ndarray], np.ndarray]:
        """``f(t, x)``: the derivative of the continuous states with the discrete outputs ``held`` (zero for the rest)."""
        plan = self.plan
        steps = self._steps_between_ticks
        updates = self._continuous_updates

        def rhs(t, x):
            y = held.copy()
            y[plan.copy_y] = x[plan.copy_x]

            def one_pass(y):
                for s in steps:
                    y[s.y] = _rows(s.output(t, x[s.x], y[s.gather], *s.output_args))
            settle(plan, one_pass, y)
            dx = np.zeros(plan.nstates)
            for s in updates:
                dx[s.x] = _rows(s.update(t, x[s.x], y[s.gather], *s.update_args))
            return dx
        return rhs

    def outputs_between_ticks(self, t: np.ndarray, X: np.ndarray, held: np.ndarray) -> np.ndarray:
        """The diagram's outputs at times ``t`` (T,), states ``X`` (nstates, T) and held outputs ``held``.

        ``held`` is the discrete blocks' held outputs, (nsignals,) within one tick interval or (nsignals, T)
        at each time.
        """
        plan = self.plan
        Y = np.array(held, dtype=float) if np.ndim(held) == 2 else np.repeat(held[:, None], t.size, axis=1)

        def one_pass(Y):
            for s in plan.steps:
                if s.name in self._discrete:
                    continue
                if s.column_output is not None:
                    Y[s.y] = s.column_output(t, X[s.x], Y[s.gather], *s.column_args)
                else:
                    for j in range(t.size):
                        Y[s.y, j] = _rows(s.output(t[j], X[s.x, j], Y[s.gather, j], *s.output_args))
        return settle(plan, one_pass, Y)[plan.out_index]

    # -- a run --------------------------------------------------------------------------------------
    def simulate(self, x0, t_grid, method: str = "RK45", rtol: float = 1e-6, atol: float = 1e-8,
                 max_step: float = math.inf, bound: float = math.inf,
                 progress: Callable[[float], None] | None = None, monitor=None) -> tuple[np.ndarray, np.ndarray]:
        """States and outputs on ``t_grid`` (s), starting from ``x0`` at ``t_grid[0] = 0``.

        With a ``monitor`` (:class:`blocks.engines.monitor.Monitor`) its bounds replace
        ``bound``, the states are judged after every tick's updates and within
        every interval, the step budget counts the right-hand-side evaluations
        of all intervals together, and the wall time and progress are checked
        at every tick.

        Returns
        -------
        states : numpy.ndarray, shape (nstates, T)
            The states at the grid times; a discrete block's state is its
            latest (updated at its last instant at or before the time).
        outputs : numpy.ndarray, shape (noutputs, T)
            The diagram's outputs, discrete ones held.

        Raises
        ------
        blocks.engines.integrate.DivergenceError, blocks.engines.integrate.SolverFailure
            As :func:`blocks.engines.integrate.integrate_on_grid`, for a continuous interval.
        blocks.engines.monitor.SimulationError, blocks.engines.budget.BudgetError
            With a monitor: divergence (the signal, its bound and the time named), the step or the time budget.
        """
        t_grid = np.asarray(t_grid, dtype=float)
        if t_grid[0] != 0.0:
            raise ValueError("a hybrid run starts at t = 0")
        if monitor is not None:
            bound = monitor.limits
        stepper = tick_stepper_for(self, method) if self.tick_stepping else None
        try:
            if stepper is not None:
                # one embedded step per tick (substeps where the tolerances ask), no solver restarted per tick
                states, held = stepper.simulate(x0, t_grid, rtol, atol, max_step, bound, progress, monitor)
            else:
                ticks = TickSource(self, float(t_grid[-1]))
                # the held outputs are kept at every grid point; the diagram's outputs follow from them after the run
                events = LoopEvents([(ticks, slice(0, self.nstates))], ticks.rhs, ticks.snapshot)
                # a tick's interval is tried in one step first, as the solver's first step after every tick
                states, _ = integrate_on_grid(ticks.rhs, x0, t_grid, method, rtol=rtol, atol=atol, max_step=max_step,
                                              bound=bound, progress=progress, first_step=math.inf, monitor=monitor,
                                              events=events)
                held = np.array(events.outputs).T
        except DivergenceError as err:
            if monitor is None:
                raise
            raise monitor.diverged(err.time, err.state) from None
        if progress is not None:
            progress(1.0)
        return states, self.outputs_between_ticks(t_grid, states, held)


__all__ += ["DivergenceError", "SolverFailure"]
