"""Model Exchange FMUs with events and arrays through fmu.simulate_fmu, on the FMI Reference FMUs built from source.

References are closed forms written here:

* BouncingBall (h0 = 1 m, g = 9.81 m/s^2, e = 0.7): free fall to t1 = sqrt(2 h0 / g), then arcs whose launch speed
  is e times the impact speed, so impact k is at t1 (1 + 2 e + ... + 2 e^(k-1));
* Stair: a counter starting at 1, incremented by a time event every second; the FMU asks to terminate when it
  reaches 10 (t = 9 s);
* StateSpace (FMI 3, arrays sized by structural parameters m = n = r = 3): A = B = C = D = I, x0 = 0, so
  x' = x + u, y = x + u and with u constant y = u e^t; with u0(t) = sin t, y0 = (e^t + sin t - cos t) / 2.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from reference_fmus import reference_fmus  # noqa: F401 - the fixture

from fmu import FMUStartValueError, FMUUnsupportedError, load, simulate_fmu

pytestmark = pytest.mark.needs_cc

G, E, H0 = 9.81, 0.7, 1.0


def ball_impacts(until: float) -> list[float]:
    t1 = math.sqrt(2 * H0 / G)
    times, t, v = [t1], t1, E * G * t1
    while t + 2 * v / G < until:
        t += 2 * v / G
        times.append(t)
        v *= E
    return times


def ball_height(t: float) -> float:
    t1 = math.sqrt(2 * H0 / G)
    if t < t1:
        return H0 - 0.5 * G * t * t
    start, v = t1, E * G * t1
    while t >= start + 2 * v / G:
        start += 2 * v / G
        v *= E
    s = t - start
    return v * s - 0.5 * G * s * s


@pytest.mark.parametrize("version", [2, 3])
def test_bouncing_ball_matches_the_analytic_ball_until_2_s(reference_fmus, version):  # noqa: F811
    resp = simulate_fmu(reference_fmus(version, "BouncingBall"), t_final=2.0, output_step=0.01)
    h = resp.outputs[resp.output_labels.index("h")]
    exact = np.array([ball_height(t) for t in resp.time])
    assert resp.time[0] == 0.0 and resp.time[-1] == 2.0 and resp.time.size == 201
    assert np.max(np.abs(h - exact)) < 1e-6
    events = resp.simulation["events"]
    assert [e["kind"] for e in events] == ["state"] * 4                 # impacts at 0.45, 1.08, 1.53, 1.84 s
    np.testing.assert_allclose([e["time"] for e in events], ball_impacts(2.0), rtol=0, atol=1e-10)
    assert resp.simulation["terminated"] is None


def test_the_ball_is_re_initialised_at_each_impact(reference_fmus):  # noqa: F811
    """Right after impact k the velocity is +e^k sqrt(2 g h0): the FMU's reinit reached the solver's state."""
    resp = simulate_fmu(reference_fmus(3, "BouncingBall"), t_final=1.2, output_step=1e-3)
    v = resp.outputs[resp.output_labels.index("v")]
    t1 = ball_impacts(1.2)[0]
    j = int(np.searchsorted(resp.time, t1))        # first recorded point after the impact
    expected = E * G * t1 - G * (resp.time[j] - t1)
    assert v[j - 1] < -4.0 and v[j] == pytest.approx(expected, abs=1e-8)


@pytest.mark.parametrize("version", [2, 3])
def test_stair_counts_at_its_time_events_and_the_fmu_ends_the_run(reference_fmus, version):  # noqa: F811
    resp = simulate_fmu(reference_fmus(version, "Stair"), t_final=12.0, output_step=0.5)
    assert [e["time"] for e in resp.simulation["events"]] == [float(k) for k in range(1, 10)]
    assert {e["kind"] for e in resp.simulation["events"]} == {"time"}
    assert resp.simulation["terminated"] == 9.0                      # counter reached 10: terminateSimulation
    assert resp.time[-1] == 9.0
    counter = resp.outputs[resp.output_labels.index("counter")]
    # at a grid point on an event the value after the event is recorded: 1 + floor(t)
    np.testing.assert_array_equal(counter, 1 + np.floor(resp.time))


def test_state_space_arrays_give_y_equal_u_e_to_the_t(reference_fmus):  # noqa: F811
    resp = simulate_fmu(reference_fmus(3, "StateSpace"), t_final=2.0, output_step=0.1)
    assert resp.output_labels == ["y[0]", "y[1]", "y[2]"]
    assert resp.state_labels == ["x[0]", "x[1]", "x[2]"] and resp.input_labels == ["u[0]", "u[1]", "u[2]"]
    exact = np.outer([1.0, 2.0, 3.0], np.exp(resp.time))
    np.testing.assert_allclose(resp.outputs, exact, rtol=1e-8, atol=0)


def test_state_space_follows_a_time_varying_array_input(reference_fmus):  # noqa: F811
    resp = simulate_fmu(reference_fmus(3, "StateSpace"), t_final=1.0, output_step=0.05,
                        inputs={"u": lambda t: [math.sin(t), 0.0, 1.0]})
    t = resp.time
    np.testing.assert_allclose(resp.outputs[0], (np.exp(t) + np.sin(t) - np.cos(t)) / 2, atol=1e-8)
    np.testing.assert_allclose(resp.outputs[1], 0.0, atol=1e-12)
    np.testing.assert_allclose(resp.outputs[2], np.exp(t), rtol=1e-8)


def test_array_start_values_are_set_by_element(reference_fmus):  # noqa: F811
    """A = -I: x' = -x + u, so y = u (2 - e^-t) from x0 = 0 (D = I adds u)."""
    resp = simulate_fmu(reference_fmus(3, "StateSpace"), t_final=1.0, output_step=0.5,
                        start_values={"A": -np.eye(3)})
    np.testing.assert_allclose(resp.outputs, np.outer([1, 2, 3], 2 - np.exp(-resp.time)), rtol=1e-8)
    with pytest.raises(FMUStartValueError, match=r"start value of A: 4 value\(s\) given, the variable has 9"):
        simulate_fmu(reference_fmus(3, "StateSpace"), 1.0, 0.5, start_values={"A": [1, 2, 3, 4]})
    with pytest.raises(FMUUnsupportedError, match="structural parameters stay at their start values"):
        simulate_fmu(reference_fmus(3, "StateSpace"), 1.0, 0.5, start_values={"n": 2})


def test_blocks_take_events_but_refuse_arrays_naming_simulate_fmu(reference_fmus):  # noqa: F811
    with load(reference_fmus(2, "BouncingBall")) as ball:
        assert ball.event_source is not None and ball.event_source.n_indicators == 1
    with pytest.raises(FMUUnsupportedError, match=r"array variables .*use fmu\.simulate_fmu"):
        load(reference_fmus(3, "StateSpace"))


@pytest.mark.parametrize("kwargs, words", [
    ({"t_final": 0.0}, "t_final must be after start_time"),
    ({"output_step": -1.0}, "output_step must be a finite number > 0, got -1.0"),
    ({"method": "Euler"}, "method must be one of"),
    ({"inputs": {"w": 1.0}}, r"inputs: \['w'\] are not real inputs"),
    ({"inputs": {"u": [1.0, 2.0]}}, r"inputs\['u'\] must be 3 finite number\(s\)"),
])
def test_bad_arguments_are_named(reference_fmus, kwargs, words):  # noqa: F811
    args = {"t_final": 1.0, "output_step": 0.1} | kwargs
    with pytest.raises(ValueError, match=words):
        simulate_fmu(reference_fmus(3, "StateSpace"), **args)


def with_clock(xml: str) -> str:
    return xml.replace("  </ModelVariables>", '    <Clock name="tick" valueReference="9" causality="input" '
                                             'intervalVariability="constant" intervalDecimal="0.1"/>\n  </ModelVariables>')


def test_clocks_stay_refused_saying_so(tmp_path):
    from fmu_models import build
    path = build("selector", tmp_path, xml_edit=with_clock, filename="clocked")
    with pytest.raises(FMUUnsupportedError, match=r"clocks \(FMI 3 Clock variables, not supported\): tick"):
        simulate_fmu(path, 1.0, 0.1)
    with pytest.raises(FMUUnsupportedError, match=r"clocks \(FMI 3 Clock variables, not supported\): tick"):
        load(path)


def test_a_run_beyond_its_evaluation_budget_stops_saying_so(reference_fmus):  # noqa: F811
    from fmu import Budget, BudgetError
    with pytest.raises(BudgetError, match=r"simulate_fmu of BouncingBall.fmu: \d+ right-hand-side evaluations by "
                                          r"t = .* more than the step budget allows \(300 steps, 1,800 evaluations\)"):
        # the grid's 201 points fit in 300 steps; the ball's 3000-odd evaluations do not fit in 1800
        simulate_fmu(reference_fmus(2, "BouncingBall"), 2.0, 0.01, budget=Budget(steps=300))
