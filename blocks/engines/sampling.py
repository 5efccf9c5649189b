"""The ticks of a sampled diagram as scheduled time events of the numpy engine's integrator.

A :class:`TickSource` is the :class:`~blocks.engines.integrate.EventSource` of a
:class:`~blocks.engines.hybrid.HybridSystem`'s discrete blocks: it announces the tick
times ``k * base_period`` (s) as time events, and its update at tick ``k`` is
what a sampled-data system does there -- the outputs of all blocks in
dependency order (discrete blocks sampled now refresh their held outputs),
then the discrete states' updates.  Between ticks
:func:`blocks.engines.integrate.integrate_on_grid` integrates the continuous states
with :meth:`TickSource.rhs`, which reads the held outputs; the integrator
stops at every tick and starts a new solver after it, as it does for an FMU's
time events (one mechanism for both).

Tick times are exact: a grid point before a tick by a rounding error belongs
to the interval before it (as in the compiled sampled engine), so the source
asks for no time tolerance.
"""
from __future__ import annotations

import math

import numpy as np

from blocks.engines.integrate import EventSource

__all__ = ["TickSource", "tick_count"]


def tick_count(t_end: float, base_period: float) -> int:
    """The last tick at or (by a rounding error) just after ``t_end`` (s): ticks run from 0 to this number."""
    return int(math.floor(t_end / base_period * (1 + 1e-12)))


class TickSource(EventSource):
    """The discrete blocks of a hybrid diagram, updating at their ticks as scheduled time events.

    Parameters
    ----------
    system : blocks.engines.hybrid.HybridSystem
        The diagram.
    t_end : float
        The run's last time (s).  The last tick is announced at ``t_end``
        when it falls after it by a rounding error (it is then the end
        state's tick, as in the compiled sampled engine).

    Attributes
    ----------
    held : numpy.ndarray, shape (nsignals,)
        The discrete blocks' outputs held since their last instants (zero
        before the first tick); :meth:`rhs` reads them.
    tick : int
        The next tick to run.
    """

    name = "sampled blocks"
    n_indicators = 0
    needs_inputs = False        # its update reads the state it is given, not inputs the loop's rhs sets
    scheduled = True            # its events are a fixed schedule: no chattering to guard against
    time_rtol = 0.0             # tick times are exact (see the module docstring)

    def __init__(self, system, t_end: float) -> None:
        self.system = system
        self.base_period = system.base_period
        self.t_end = float(t_end)
        self.n_ticks = tick_count(self.t_end, self.base_period)
        self.held = np.zeros(system.plan.nsignals)
        self.tick = 0
        self.rhs = system.continuous_rhs(self.held)      # reads self.held, refreshed in place at every tick

    def begin(self, t: float) -> None:
        if t != 0.0:
            raise ValueError(f"a sampled run starts at t = 0 (its first tick), got t = {t!r} s")
        self.tick = 0
        self.held[:] = 0.0

    @property
    def next_event_time(self) -> float | None:
        if self.tick > self.n_ticks:
            return None
        return min(self.tick * self.base_period, self.t_end)

    def due(self, t: float, kind: str) -> bool:
        upcoming = self.next_event_time
        return kind == "time" and upcoming is not None and not t < upcoming

    def update(self, t: float, x: np.ndarray) -> tuple[np.ndarray, bool]:
        k = self.tick
        y = self.system.tick_outputs(k, x, self.held)
        self.tick = k + 1
        return self.system.tick_updates(k, x, y), False

    def snapshot(self, t: float, x: np.ndarray) -> np.ndarray:
        """The held outputs now (kept at every grid point; the diagram's outputs are computed from them after)."""
        return self.held.copy()
