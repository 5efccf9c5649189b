"""The ticks of a sampled diagram as scheduled time events of the numpy engine's one integrator.

References are closed forms of small sampled-data systems (zero-order hold on a linear plant), written here
from the sampled-data equations, not from the engine.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from blocks.engines import integrate
from blocks.engines.hybrid import HybridSystem
from blocks.engines.integrate import DivergenceError, EventSource, LoopEvents, integrate_on_grid
from blocks.engines.sampling import TickSource, tick_count


def _first_order_loop(a: float, K: float, Ts: float) -> HybridSystem:
    """x' = -a x + u (continuous), u[k] = -K x[k] (sampled at Ts, held)."""
    plant = ct.nlsys(lambda t, x, u, p: np.array([-a * x[0] + u[0]]), lambda t, x, u, p: x,
                     inputs=["u"], outputs=["x"], states=["x"], name="plant")
    control = ct.nlsys(None, lambda t, x, u, p: np.array([-K * u[0]]), inputs=["x"], outputs=["u"],
                       name="controller", dt=Ts)
    return HybridSystem([plant, control], outlist=["x", "u"])


def _zoh_reference(a: float, K: float, Ts: float, x0: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The exact response at times ``t``: u held from the last tick at or before each time."""
    phi = math.exp(-a * Ts)
    x_tick = [x0]
    for _ in range(int(t[-1] / Ts) + 2):
        x_tick.append(phi * x_tick[-1] + (1.0 - phi) / a * (-K * x_tick[-1]))
    k = np.floor(t / Ts + 1e-9).astype(int)
    u = -K * np.array(x_tick)[k]
    tau = t - k * Ts
    x = np.exp(-a * tau) * np.array(x_tick)[k] + (1.0 - np.exp(-a * tau)) / a * u
    return x, u


def test_ticks_as_events_equal_the_zero_order_hold_closed_form_on_and_between_ticks():
    a, K, Ts = 3.0, 40.0, 0.01
    loop = _first_order_loop(a, K, Ts)
    t = np.arange(0, 61) * (Ts / 3)                      # grid points on and between ticks
    states, out = loop.simulate(np.array([1.0]), t, "DOP853", rtol=1e-12, atol=1e-14)
    x, u = _zoh_reference(a, K, Ts, 1.0, t)
    np.testing.assert_allclose(states[0], x, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(out[0], x, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(out[1], u, rtol=1e-10, atol=1e-13)


def test_a_grid_point_a_rounding_error_before_a_tick_keeps_the_held_value_of_the_interval_before():
    a, K, Ts = 1.0, 50.0, 0.01
    loop = _first_order_loop(a, K, Ts)
    before = np.nextafter(3 * Ts, 0.0)               # one float below tick 3
    t = np.array([0.0, Ts, 2 * Ts, before, 3 * Ts, 4 * Ts])
    _, out = loop.simulate(np.array([1.0]), t, "DOP853", rtol=1e-12, atol=1e-14)
    x_ref, _ = _zoh_reference(a, K, Ts, 1.0, np.arange(5) * Ts)
    assert out[1, 3] == pytest.approx(-K * x_ref[2], rel=1e-10)      # held from tick 2
    assert out[1, 4] == pytest.approx(-K * x_ref[3], rel=1e-10)      # refreshed at tick 3
    assert abs(out[1, 4] - out[1, 3]) > 1e-3


def test_the_solver_tries_a_whole_tick_interval_first():
    """A held input on x' = u integrates exactly in one step per tick: a new RK45 solver per tick interval
    evaluates the start once and its one step 6 times, so 7 evaluations per interval."""
    Ts = 0.01
    plant = ct.nlsys(lambda t, x, u, p: np.array([u[0]]), lambda t, x, u, p: x, inputs=["u"], outputs=["x"],
                     states=["x"], name="plant")
    control = ct.nlsys(None, lambda t, x, u, p: np.array([1.0 - u[0]]), inputs=["x"], outputs=["u"],
                       name="controller", dt=Ts)
    loop = HybridSystem([plant, control], outlist=["x"])
    n = 20
    t = np.arange(0, n + 1) * Ts
    ticks = TickSource(loop, t[-1])
    events = LoopEvents([(ticks, slice(0, 1))], ticks.rhs, ticks.snapshot)
    states, nfev = integrate_on_grid(ticks.rhs, np.zeros(1), t, "RK45", rtol=1e-9, atol=1e-12,
                                     first_step=math.inf, events=events)
    assert nfev == n * 7
    np.testing.assert_allclose(states[0], 1.0 - (1.0 - Ts) ** np.arange(n + 1), rtol=1e-12)  # x_{k+1} = x_k + Ts (1 - x_k)
    assert events.log == []                             # scheduled ticks are not logged as events


def test_ticks_are_not_counted_as_chattering(monkeypatch):
    monkeypatch.setattr(integrate, "MAX_EVENTS", 5)
    a, K, Ts = 2.0, 10.0, 0.001
    loop = _first_order_loop(a, K, Ts)
    t = np.linspace(0.0, 0.05, 11)                       # 51 ticks, far more than MAX_EVENTS
    states, _ = loop.simulate(np.array([1.0]), t, "DOP853", rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(states[0], _zoh_reference(a, K, Ts, 1.0, t)[0], rtol=1e-9)


def test_a_tick_update_beyond_the_bound_stops_the_run_at_that_tick():
    """A discrete state multiplied by 10 at every tick passes 1e6 at the update of tick 6 (10**7)."""
    Ts = 0.01
    clock = ct.nlsys(lambda t, x, u, p: np.array([1.0]), lambda t, x, u, p: x, inputs=0, outputs=["c"],
                     states=["c"], name="clock")
    grow = ct.nlsys(lambda t, x, u, p: 10.0 * x, lambda t, x, u, p: x, inputs=["c"], outputs=["g"], states=["g"],
                    name="grow", dt=Ts)
    loop = HybridSystem([clock, grow], outlist=["g"])
    with pytest.raises(DivergenceError) as err:
        loop.simulate(np.array([0.0, 1.0]), np.arange(0, 21) * Ts, bound=1e6)
    assert err.value.time == pytest.approx(6 * Ts, abs=1e-15)
    assert err.value.state[1] == pytest.approx(1e7)


class _Crossing(EventSource):
    """A block with one state event: its indicator c - level changes sign once; it counts its updates."""

    name = "crossing"
    n_indicators = 1
    needs_inputs = False

    def __init__(self, level: float) -> None:
        self.level, self.times = level, []

    def due(self, t, kind):
        return kind == "state"

    def indicators(self, t, x):
        return np.array([x[0] - self.level])

    def update(self, t, x):
        self.times.append(t)
        return None, False


def test_ticks_and_a_state_event_share_one_integrator_and_each_block_updates_only_at_its_own_events():
    """A clock c' = 1 crosses 0.025 between ticks 2 and 3; the sampled block (counting its ticks) is not
    updated there, and the crossing block (due at state events only) not at the ticks."""
    Ts = 0.01
    clock = ct.nlsys(lambda t, x, u, p: np.array([1.0]), lambda t, x, u, p: x, inputs=0, outputs=["c"],
                     states=["c"], name="clock")
    count = ct.nlsys(lambda t, x, u, p: x + 1.0, lambda t, x, u, p: x, inputs=["c"], outputs=["n"], states=["n"],
                     name="count", dt=Ts)
    loop = HybridSystem([clock, count], outlist=["n"])
    t = np.arange(0, 6) * Ts
    ticks, crossing = TickSource(loop, t[-1]), _Crossing(0.025)
    events = LoopEvents([(ticks, slice(0, 2)), (crossing, slice(0, 1))], ticks.rhs, ticks.snapshot)
    states, _ = integrate_on_grid(ticks.rhs, np.zeros(2), t, "RK45", rtol=1e-10, atol=1e-12, first_step=math.inf,
                                  events=events, event_tolerance=1e-12)
    assert crossing.times == [pytest.approx(0.025, abs=1e-11)]
    assert [e["kind"] for e in events.log] == ["state"]
    np.testing.assert_allclose(states[1], np.arange(1, 7))   # ticks 0..5, the one at t_end included
    np.testing.assert_allclose(states[0], t, atol=1e-12)


def test_the_last_tick_a_rounding_error_after_the_end_is_the_end_states_tick():
    Ts = 0.1
    n = tick_count(0.3, Ts)                              # 3 * 0.1 = 0.30000000000000004 > 0.3
    assert n == 3 and n * Ts > 0.3
    loop = _first_order_loop(1.0, 2.0, Ts)
    _, out = loop.simulate(np.array([1.0]), np.array([0.0, 0.15, 0.3]), "DOP853", rtol=1e-12, atol=1e-14)
    x_ref, _ = _zoh_reference(1.0, 2.0, Ts, 1.0, np.arange(4) * Ts)
    assert out[1, 2] == pytest.approx(-2.0 * x_ref[3], rel=1e-10)
