"""FMU blocks with events in closed loops run by the numpy engine (fmu.load + fmu.simulate_loop / integrate_on_grid).

The FMUs are dobkit's own C test models (tests/fmu_models: ball, ball3, stair; tests/fmu_lag with a repeated time
event), the other blocks python-control systems written here; the references are closed forms computed by hand:

* stair -> lag: counter c(t) = floor(t) (steps at time events t = 1, 2, ... s; the FMU ends the run at the step to
  9, t = 9 s) drives y' = (c - y) / T, y(0) = 0, so y(t) = sum over k = 1 .. floor(t) of 1 - exp(-(t - k) / T);
* gravity -> ball -> area: a python-control block gives the ball its gravity g (an input of the ball here: its
  model description is edited so that g is an input); the ball (h0 = 1 m, restitution e = 0.7) falls from rest:
  first impact at t1 = sqrt(2 h0 / g) with speed v1 = g t1, the k-th rebound leaves at e^k v1 and flies
  2 e^k v1 / g.  A python-control integrator accumulates A(t) = integral of h, each arc adding
  h_a s + v_a s^2 / 2 - g s^3 / 6 over its time s.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from fmu_models import build

from blocks.engines.integrate import SimulationTerminated, SolverFailure, integrate_on_grid, loop_events
from fmu import FMUError, load, simulate_loop

pytestmark = pytest.mark.needs_cc

H0, E, V_MIN = 1.0, 0.7, 0.1
T_LAG = 0.5          # s, the python-control lag behind the stair


def arcs(g: float, until: float) -> list[tuple[float, float, float]]:
    """(start time s, height m, upward speed m/s) of each flight of the analytic ball up to ``until``, by hand."""
    t1 = math.sqrt(2 * H0 / g)
    v1 = g * t1
    out, t, k = [(0.0, H0, 0.0)], t1, 1
    while t < until:
        rebound = E ** k * v1
        if rebound < V_MIN:
            out.append((t, 0.0, None))      # resting from here on
            break
        out.append((t, 0.0, rebound))
        t += 2 * rebound / g
        k += 1
    return out


def ball_at(g: float, t: float) -> tuple[float, float, float]:
    """(h m, v m/s, integral of h from 0 to t in m s) of the analytic ball, by hand."""
    area, h, v = 0.0, H0, 0.0
    flights = arcs(g, t + 1.0)
    for i, (start, h_a, v_a) in enumerate(flights):
        if start > t:
            break
        end = flights[i + 1][0] if i + 1 < len(flights) else math.inf
        s = min(t, end) - start
        if v_a is None:                     # at rest on the ground
            return 0.0, 0.0, area
        area += h_a * s + v_a * s * s / 2 - g * s ** 3 / 6
        h, v = h_a + v_a * s - g * s * s / 2, v_a - g * s
    return h, v, area


def impact_times(g: float, until: float) -> list[float]:
    return [start for start, _, v_a in arcs(g, until)[1:] if start < until]


def lag_response(t: float) -> float:
    """y(t) of y' = (floor(t) - y) / T_LAG, y(0) = 0, by hand."""
    return sum(1 - math.exp(-(t - k) / T_LAG) for k in range(1, int(math.floor(t)) + 1))


def g_as_input(xml: str) -> str:
    """The FMI 2 ball with its gravity g as a continuous input (start 9.81) instead of a fixed parameter."""
    old = 'name="g" valueReference="5" causality="parameter" variability="fixed" initial="exact"'
    assert old in xml
    return xml.replace(old, 'name="g" valueReference="5" causality="input" variability="continuous"')


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("loop-event-fmus")
    return {"ball": build("ball", folder), "ball3": build("ball3", folder), "stair": build("stair", folder),
            "ball_g": build("ball", folder, xml_edit=g_as_input, filename="ball_g")}


def area_block() -> ct.NonlinearIOSystem:
    return ct.nlsys(lambda t, x, u, p: [u[0]], lambda t, x, u, p: x, inputs=["h"], outputs=["A"], states=["A"],
                    name="area")


def test_the_hand_computed_ball_matches_the_impact_formula():
    g = 9.81
    t1 = math.sqrt(2 / g)
    expected = [t1 + 2 * t1 * sum(E ** j for j in range(1, k + 1)) for k in range(4)]     # 0.45, 1.08, 1.53, 1.84 s
    assert impact_times(g, 2.0) == pytest.approx(expected, abs=1e-12)
    # the area of the first fall, h0 t1 - g t1^3 / 6, and the continuity of h at the first impact
    assert ball_at(g, t1)[2] == pytest.approx(t1 - g * t1 ** 3 / 6, abs=1e-12)
    assert ball_at(g, t1 - 1e-9)[0] == pytest.approx(0.0, abs=1e-7)


def test_stair_drives_a_python_control_lag_with_time_events_until_it_terminates(fmus):
    stair = load(fmus["stair"], name="stair")
    lag = ct.nlsys(lambda t, x, u, p: [(u[0] - x[0]) / T_LAG], lambda t, x, u, p: x, inputs=["counter"],
                   outputs=["y"], states=["y"], name="lag")
    with stair:
        assert stair.event_source is not None and stair.event_source.next_event_time == 1.0
        loop = ct.interconnect([stair, lag], inplist=[], outlist=["counter", "y"], check_unused=False)
        grid = np.linspace(0.0, 10.0, 201)         # 50 ms; the events at whole seconds fall on grid points
        resp = simulate_loop(loop, grid, rtol=1e-11, atol=1e-13)
    sim = resp.simulation
    assert sim["terminated"] == 9.0
    assert [e["kind"] for e in sim["events"]] == ["time"] * 9
    assert [e["time"] for e in sim["events"]] == [float(k) for k in range(1, 10)]
    # the response stops where the FMU asked to, the point at 9 s included, after the event
    assert resp.time[-1] == 9.0 and resp.time.size == 181
    counter, y = resp.outputs
    np.testing.assert_array_equal(counter, np.floor(resp.time + 1e-12))     # a grid point at an event: after it
    np.testing.assert_allclose(y, [lag_response(t) for t in resp.time], rtol=0, atol=1e-6)
    assert abs(y[-1] - lag_response(9.0)) < 1e-6 and lag_response(9.0) > 7.5


@pytest.mark.parametrize("g", [9.81, 9.81 / 4])
def test_ball_driven_by_a_python_control_gravity_block_matches_the_analytic_ball(fmus, g):
    ball = load(fmus["ball_g"], name="ball")
    gravity = ct.nlsys(None, lambda t, x, u, p: [g], inputs=[], outputs=["g"], name="gravity")
    with ball:
        assert ball.input_labels == ["g"] and ball.event_source.n_indicators == 1
        loop = ct.interconnect([gravity, ball, area_block()], inplist=[], outlist=["h", "v", "A"],
                               check_unused=False)
        grid = np.linspace(0.0, 3.0, 301)
        resp = simulate_loop(loop, grid, method="DOP853", rtol=1e-11, atol=1e-13, max_step=0.01)
    h, v, area = resp.outputs
    expected = np.array([ball_at(g, t) for t in resp.time]).T
    np.testing.assert_allclose(h, expected[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(area, expected[2], rtol=0, atol=1e-6)
    # v jumps at the impacts: compared away from them
    far = np.array([min(abs(t - s) for s in impact_times(g, 3.5)) > 1e-3 for t in resp.time])
    np.testing.assert_allclose(v[far], expected[1][far], rtol=0, atol=1e-6)
    events = resp.simulation["events"]
    assert {e["kind"] for e in events} == {"state"}
    located = [e["time"] for e in events]
    np.testing.assert_allclose(located, impact_times(g, 3.0)[:len(located)], rtol=0, atol=1e-10)
    assert len(located) == len(impact_times(g, 3.0))
    assert resp.simulation["terminated"] is None


def test_fmi3_ball_in_a_loop_matches_the_analytic_ball_until_2_s(fmus):
    with load(fmus["ball3"], name="ball") as ball:
        loop = ct.interconnect([ball, area_block()], inplist=[], outlist=["h", "A"], check_unused=False)
        resp = simulate_loop(loop, np.linspace(0.0, 2.0, 201), method="DOP853", rtol=1e-11, atol=1e-13,
                             max_step=0.01)
    expected = np.array([ball_at(9.81, t) for t in resp.time]).T
    np.testing.assert_allclose(resp.outputs[0], expected[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(resp.outputs[1], expected[2], rtol=0, atol=1e-6)
    np.testing.assert_allclose([e["time"] for e in resp.simulation["events"]], impact_times(9.81, 2.0), rtol=0,
                               atol=1e-10)


def test_the_ball_comes_to_rest_through_re_initialisation(fmus):
    """Impact 11 (2.4991 s) would rebound below v_min: the FMU sets h = v = 0 and the solver takes that state."""
    with load(fmus["ball"], name="ball") as ball:
        loop = ct.interconnect([ball, area_block()], inplist=[], outlist=["h", "v", "A"], check_unused=False)
        resp = simulate_loop(loop, np.linspace(0.0, 3.0, 31), method="DOP853", rtol=1e-11, atol=1e-13, max_step=0.01)
    late = resp.time > 2.5
    assert np.all(resp.outputs[0][late] == 0.0) and np.all(resp.outputs[1][late] == 0.0)
    assert len(resp.simulation["events"]) == 11
    assert resp.outputs[2][-1] == pytest.approx(ball_at(9.81, 3.0)[2], abs=1e-6)


def test_terminate_stops_the_engine_with_a_message_naming_the_block(fmus):
    with load(fmus["stair"], name="stair") as stair:
        lag = ct.nlsys(lambda t, x, u, p: [(u[0] - x[0]) / T_LAG], None, inputs=["counter"], outputs=["y"],
                       states=["y"], name="lag")
        loop = ct.interconnect([stair, lag], inplist=[], outlist=["y"], check_unused=False)
        from blocks.engines.fastsim import CompiledLoop
        compiled = CompiledLoop(loop)
        events = loop_events(loop, compiled.rhs)
        with pytest.raises(SimulationTerminated,
                           match=r"block 'stair' asked to end the simulation \(terminateSimulation\) at t = 9 s") as err:
            integrate_on_grid(compiled.rhs, [0.0], np.linspace(0, 12, 13), events=events)
    assert err.value.time == 9.0 and err.value.done == 10
    np.testing.assert_allclose(err.value.states[0, :10], [lag_response(t) for t in range(10)], atol=1e-4)
    assert isinstance(err.value, SolverFailure)        # blocks.simulate reports it as its SimulationError


def test_a_time_event_announced_again_at_the_same_time_is_refused(tmp_path):
    from pathlib import Path

    from fmu.package import package_fmu
    lag_dir = Path(__file__).parent / "fmu_lag"
    variant = package_fmu(tmp_path / "lag_te.fmu", (lag_dir / "modelDescription.xml").read_text(),
                          {"lag.c": lag_dir / "lag.c", "lag_te.c": '#define LAG_TIME_EVENT\n#include "lag.c"\n'},
                          ["lag_te.c"], "lag", 2)
    with load(variant, name="lag_te") as lag:
        source = ct.nlsys(None, lambda t, x, u, p: [1.0], inputs=[], outputs=["u"], name="one")
        loop = ct.interconnect([source, lag], inplist=[], outlist=["x"], check_unused=False)
        with pytest.raises(SolverFailure, match=r"block\(s\) 'lag_te' announced a time event at t = 1 s after their "
                                                r"event at t = 1 s"):
            simulate_loop(loop, np.linspace(0.0, 2.0, 5))


def test_a_loop_without_event_blocks_runs_as_before(fmus):
    """No hybrid block: loop_events is None and simulate_loop is integrate_on_grid's plain run (lag of a step)."""
    step = ct.nlsys(None, lambda t, x, u, p: [1.0], inputs=[], outputs=["counter"], name="one")
    lag = ct.nlsys(lambda t, x, u, p: [(u[0] - x[0]) / T_LAG], lambda t, x, u, p: x, inputs=["counter"],
                   outputs=["y"], states=["y"], name="lag")
    loop = ct.interconnect([step, lag], inplist=[], outlist=["y"], check_unused=False)
    assert loop_events(loop, lambda t, x: x) is None
    resp = simulate_loop(loop, np.linspace(0.0, 2.0, 21), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(resp.outputs[0], 1 - np.exp(-resp.time / T_LAG), atol=1e-8)
    assert resp.simulation["events"] == []


def test_other_engines_refuse_the_loop_naming_the_block(fmus):
    from blocks.engines.compiled import unavailable_reason
    with load(fmus["ball"], name="ball") as ball:
        loop = ct.interconnect([ball, area_block()], inplist=[], outlist=["h", "A"], check_unused=False)
        assert "block 'ball' has no kernels" in unavailable_reason(loop)


@pytest.mark.parametrize("kwargs, words", [
    ({"method": "Euler"}, "method must be one of"),
    ({"event_tolerance": 0.0}, "event_tolerance must be a finite number > 0"),
    ({"x0": [0.0]}, r"x0 must have 3 elements \(the loop's states\), got 1"),
])
def test_bad_arguments_are_named(fmus, kwargs, words):
    with load(fmus["ball"], name="ball") as ball:
        loop = ct.interconnect([ball, area_block()], inplist=[], outlist=["h", "A"], check_unused=False)
        with pytest.raises(ValueError, match=words):
            simulate_loop(loop, np.linspace(0.0, 1.0, 3), **kwargs)
    assert issubclass(FMUError, ValueError)


def test_an_event_block_runs_once_and_from_its_start_time(fmus):
    """Its discrete states move on with a run (the stair's counter): a second run, or one from another time, is
    refused, naming the block."""
    with load(fmus["stair"], name="stair") as stair:
        lag = ct.nlsys(lambda t, x, u, p: [(u[0] - x[0]) / T_LAG], lambda t, x, u, p: x, inputs=["counter"],
                       outputs=["y"], states=["y"], name="lag")
        loop = ct.interconnect([stair, lag], inplist=[], outlist=["y"], check_unused=False)
        with pytest.raises(FMUError, match=r"block 'stair' .*the run starts at t = 0.5 s, the FMU was initialized "
                                           r"at t = 0 s"):
            simulate_loop(loop, np.linspace(0.5, 2.0, 4))
        stair.event_source.ran = False      # the refused run did not start: this one does
        simulate_loop(loop, np.linspace(0.0, 2.0, 5))
        with pytest.raises(FMUError, match="block 'stair' .*keeps the discrete states of its last run; load it again"):
            simulate_loop(loop, np.linspace(0.0, 2.0, 5))


def test_the_numpy_engine_of_blocks_simulate_stops_at_the_events(fmus):
    """blocks.simulate's numpy engine (simulator.NumpyEngine) takes the loop's event blocks: the stair's outputs are those
    recorded during the run, not a pass over the grid afterwards (which would read the last counter, 8)."""
    from blocks.engines.monitor import Monitor
    from blocks.engines.simulator import NumpyEngine
    with load(fmus["stair"], name="stair") as stair:
        lag = ct.nlsys(lambda t, x, u, p: [(u[0] - x[0]) / T_LAG], lambda t, x, u, p: x, inputs=["counter"],
                       outputs=["y"], states=["y"], name="lag")
        loop = ct.interconnect([stair, lag], inplist=[], outlist=["counter", "y"], check_unused=False)
        engine = NumpyEngine(loop, "RK45")
        grid = np.linspace(0.0, 5.0, 11)
        states, _ = engine.integrate(np.zeros(1), grid, 1e-10, 1e-12, np.inf, Monitor("loop", None, np.zeros(1)))
        outputs = engine.outputs_on_grid(grid, states)
    np.testing.assert_array_equal(outputs[0], np.floor(grid))
    np.testing.assert_allclose(outputs[1], [lag_response(t) for t in grid], atol=1e-7)
    assert [e["time"] for e in engine.events.log] == [1.0, 2.0, 3.0, 4.0, 5.0]


@pytest.mark.parametrize("scenario, engine, words", [
    ("paper", "python-control", "engine 'python-control' cannot run block"),
    ("paper-digital", "auto", "engine 'sampled' cannot run block"),
])
def test_blocks_simulate_refuses_event_blocks_on_engines_that_skip_events(fmus, scenario, engine, words):
    import blocks
    with load(fmus["ball"], name="ball") as ball:
        with pytest.raises(ValueError, match=words + r"\(s\) 'ball': they have events"):
            blocks.simulate(scenario, plant=ball, engine=engine)
