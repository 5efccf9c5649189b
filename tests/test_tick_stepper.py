"""The numpy sampled engine's own steps (blocks.engines.tick_stepper): one embedded Runge-Kutta step per tick.

References: the zero-order-hold closed form of a first-order sampled loop (written here from the
sampled-data equations) and scipy's solver restarted at every tick (the engine's previous loop, still run
with ``HybridSystem.tick_stepping = False`` and for the methods the stepper does not take).
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

import blocks
from blocks.engines import integrate
from blocks.engines.hybrid import HybridSystem
from blocks.engines.integrate import DivergenceError
from blocks.engines.tick_stepper import TickStepper, tick_stepper_for
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop


def _first_order_loop(a: float, K: float, Ts: float) -> HybridSystem:
    """x' = -a x + u (continuous, a python-control block without kernels), u[k] = -K x[k] (sampled at Ts)."""
    plant = ct.nlsys(lambda t, x, u, p: np.array([-a * x[0] + u[0]]), lambda t, x, u, p: x,
                     inputs=["u"], outputs=["x"], states=["x"], name="plant")
    control = ct.nlsys(None, lambda t, x, u, p: np.array([-K * u[0]]), inputs=["x"], outputs=["u"],
                       name="controller", dt=Ts)
    return HybridSystem([plant, control], outlist=["x", "u"])


def _zoh_reference(a: float, K: float, Ts: float, x0: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The exact response at times ``t``: ``x_{k+1} = phi x_k + (1 - phi) / a u_k``, ``u_k = -K x_k`` held."""
    phi = math.exp(-a * Ts)
    x_tick = [x0]
    for _ in range(int(t[-1] / Ts) + 2):
        x_tick.append(phi * x_tick[-1] + (1.0 - phi) / a * (-K * x_tick[-1]))
    k = np.floor(t / Ts + 1e-9).astype(int)
    u = -K * np.array(x_tick)[k]
    tau = t - k * Ts
    x = np.exp(-a * tau) * np.array(x_tick)[k] + (1.0 - np.exp(-a * tau)) / a * u
    return x, u


def _restarted(loop: HybridSystem, *args, **kwargs):
    """The run with scipy's solver restarted at every tick (the engine's reference loop)."""
    loop.tick_stepping = False
    try:
        return loop.simulate(*args, **kwargs)
    finally:
        del loop.tick_stepping


@pytest.fixture(scope="module")
def paper_digital():
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.2})
    loop = sampled_loop(s)
    return s, loop, sampled_initial_state(loop, s)


def test_one_step_per_tick_gives_the_restarted_solvers_states_on_the_paper_loop(paper_digital):
    s, loop, x0 = paper_digital
    sim = s.simulation
    states, outputs = loop.simulate(x0, sim.time_grid, sim.method, rtol=sim.rtol, atol=sim.atol)
    ref_states, ref_outputs = _restarted(loop, x0, sim.time_grid, sim.method, rtol=sim.rtol, atol=sim.atol)
    np.testing.assert_allclose(states, ref_states, rtol=0, atol=1e-12)
    np.testing.assert_allclose(outputs, ref_outputs, rtol=1e-12, atol=1e-9)     # torques up to 1e4 N m
    stepper = tick_stepper_for(loop, sim.method)
    assert stepper.generated                    # the sampled program's functions on floats
    # 1 ms is shorter than the step RK45 allows at rtol 1e-6: one Dormand-Prince step (7 evaluations) per tick
    ticks = int(round(sim.t_final * s.controller.sample_rate))
    assert stepper.nfev == 7 * ticks


def test_no_solver_is_started_per_tick(paper_digital, monkeypatch):
    s, loop, x0 = paper_digital
    made = []
    for name, cls in list(integrate.SOLVERS.items()):
        monkeypatch.setitem(integrate.SOLVERS, name, lambda *a, _cls=cls, **k: made.append(1) or _cls(*a, **k))
    r = blocks.simulate(s, engine="fast")
    assert np.all(np.isfinite(r.outputs))
    assert made == []


@pytest.mark.parametrize("method, rtol, close", [("RK45", 1e-10, 1e-7), ("RK23", 1e-7, 1e-5)])
def test_ticks_longer_than_the_tolerance_allows_are_substepped_and_match_the_closed_form(method, rtol, close):
    a, K, Ts = 400.0, 300.0, 0.01           # the plant's time constant is 2.5 ms: a 10 ms tick needs substeps
    loop = _first_order_loop(a, K, Ts)
    t = np.arange(0, 61) * (Ts / 3)         # grid points on and between ticks
    states, out = loop.simulate(np.array([1.0]), t, method, rtol=rtol, atol=1e-13)
    x, u = _zoh_reference(a, K, Ts, 1.0, t)
    np.testing.assert_allclose(states[0], x, rtol=close, atol=1e-12)
    np.testing.assert_allclose(out[1], u, rtol=close, atol=1e-12)
    stepper = tick_stepper_for(loop, method)
    assert not stepper.generated            # a block without kernels: the plan with numpy
    steps_per_tick = stepper.nfev / 20 / (4 if method == "RK23" else 7)
    assert steps_per_tick > 3
    ref_states, ref_out = _restarted(loop, np.array([1.0]), t, method, rtol=rtol, atol=1e-13)
    np.testing.assert_allclose(states, ref_states, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(out, ref_out, rtol=1e-13, atol=1e-15)


def test_a_state_beyond_its_bound_stops_the_run_at_the_crossing():
    # an unstable sampled loop (positive feedback): x grows by 1.2 ... per tick; the bound 5 is crossed inside a tick
    a, K, Ts = 1.0, -30.0, 0.01
    loop = _first_order_loop(a, K, Ts)
    t = np.linspace(0.0, 1.0, 101)
    with pytest.raises(DivergenceError) as err:
        loop.simulate(np.array([1.0]), t, "RK45", rtol=1e-10, atol=1e-12, bound=5.0)
    fine = np.linspace(0.0, 1.0, 200001)
    x, _ = _zoh_reference(a, K, Ts, 1.0, fine)
    crossing = fine[np.argmax(np.abs(x) > 5.0)]
    assert err.value.time == pytest.approx(crossing, abs=1e-5)
    assert abs(err.value.state[0]) == pytest.approx(5.0, rel=1e-6)
    with pytest.raises(DivergenceError) as ref:
        _restarted(loop, np.array([1.0]), t, "RK45", rtol=1e-10, atol=1e-12, bound=5.0)
    assert err.value.time == pytest.approx(ref.value.time, abs=1e-12)


def test_other_methods_keep_the_restarted_solver():
    loop = _first_order_loop(3.0, 40.0, 0.01)
    assert tick_stepper_for(loop, "DOP853") is None and tick_stepper_for(loop, "Radau") is None
    with pytest.raises(ValueError, match="RK45"):
        TickStepper(loop, "DOP853")
    t = np.arange(0, 31) * (0.01 / 3)
    states, _ = loop.simulate(np.array([1.0]), t, "DOP853", rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(states[0], _zoh_reference(3.0, 40.0, 0.01, 1.0, t)[0], rtol=1e-10, atol=1e-13)


def test_blocks_at_two_rates_give_the_restarted_solvers_run():
    # a controller at Ts and a slower integrating one at 3 Ts (the plan with numpy; the generator takes one rate)
    Ts = 0.01
    plant = ct.nlsys(lambda t, x, u, p: np.array([-3.0 * x[0] + u[0] + u[1]]), lambda t, x, u, p: x,
                     inputs=["u", "w"], outputs=["x"], states=["x"], name="plant")
    fast = ct.nlsys(None, lambda t, x, u, p: np.array([-40.0 * u[0]]), inputs=["x"], outputs=["u"], name="fast",
                    dt=Ts)
    slow = ct.nlsys(lambda t, x, u, p: np.array([x[0] + u[0]]), lambda t, x, u, p: np.array([-2.0 * x[0]]),
                    inputs=["x"], outputs=["w"], states=["s"], name="slow", dt=3 * Ts)
    loop = HybridSystem([plant, fast, slow], outlist=["x", "u", "w"])
    t = np.linspace(0.0, 1.0, 301)
    states, out = loop.simulate(np.array([1.0, 0.0]), t, "RK45", rtol=1e-9, atol=1e-12)
    ref_states, ref_out = _restarted(loop, np.array([1.0, 0.0]), t, "RK45", rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(states, ref_states, rtol=0, atol=1e-14)
    np.testing.assert_allclose(out, ref_out, rtol=0, atol=1e-13)
    # the slow block's output changes only every third tick
    w = out[2][np.searchsorted(t, np.arange(0, 31) * Ts - 1e-12)]
    assert np.all(w[1:3] == w[0]) and w[3] != w[0]
