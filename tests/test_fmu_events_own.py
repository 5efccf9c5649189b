"""Model Exchange events through fmu.simulate_fmu on dobkit's own C test FMUs (tests/fmu_models): they need only cc.

tests/test_fmu_events.py runs the same kinds of event on the FMI Reference FMUs, which are built from a source
mirror that a fresh machine lacks.  The models here (ball.c, stair.c) are written for these tests; the references
are closed forms computed by hand below, not by the code under test (ball3.c is the ball as an FMI 3 FMU):

* ball (h0 = 1 m, g = 9.81 m/s^2, e = 0.7, v_min = 0.1 m/s): free fall to the first impact at t1 = sqrt(2 h0 / g)
  with speed v1 = g t1; the k-th rebound leaves at e^k v1 and flies 2 e^k v1 / g, so impact k + 1 is at
  t1 + 2 v1 / g (e + ... + e^k); at the first impact whose rebound speed e^k v1 is below v_min the ball rests
  (h = v = 0).  e^10 v1 = 0.1251 m/s > v_min > e^11 v1 = 0.0876 m/s: it rests at impact 11 (t = 2.4991 s);
* stair: counter = floor(t), stepping at time events at 1, 2, ... s; the FMU ends the run at the step to 9 (9 s).

fmpy's own Model Exchange solver (CVode) serves as a second, independent importer: it tells a fault of the FMU
from a fault of simulate_fmu.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from fmu_models import build

from dobkit.cli import main as dobkit_main
from fmu import FMUError, check_fmu, simulate_fmu
from fmu.check import stage

pytestmark = pytest.mark.needs_cc

G, E, H0, V_MIN = 9.81, 0.7, 1.0, 0.1
BALL = {2: "ball", 3: "ball3"}
STAGES = ["archive", "model_description", "validation", "model_exchange", "simulate_fmu", "co_simulation", "me_vs_cs",
          "plant_comparison"]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """name -> path of the FMUs built once for this module."""
    folder = tmp_path_factory.mktemp("own-event-fmus")
    return {name: build(name, folder) for name in ("ball", "ball3", "stair")}


def impacts(e: float = E, until: float = math.inf) -> tuple[list[float], float | None]:
    """(impact times before ``until`` in s, the time the ball comes to rest or None), by hand."""
    t1 = math.sqrt(2 * H0 / G)
    v1 = G * t1
    times, t, k = [t1], t1, 1
    while True:
        rebound = e ** k * v1
        if rebound < V_MIN:
            return times, t
        t += 2 * rebound / G
        if t >= until:
            return times, None
        times.append(t)
        k += 1


def height(t: float, e: float = E) -> float:
    """h(t) in m of the analytic ball, by hand: the arc that contains t."""
    t1 = math.sqrt(2 * H0 / G)
    if t < t1:
        return H0 - 0.5 * G * t * t
    times, rest = impacts(e, until=t + 1.0)
    if rest is not None and t >= rest:
        return 0.0
    k = int(np.searchsorted(times, t, side="right"))      # impacts at or before t
    launch, s = e ** k * G * t1, t - times[k - 1]
    return launch * s - 0.5 * G * s * s


def test_the_hand_computed_ball_is_the_one_in_the_docstring():
    times, rest = impacts()
    assert len(times) == 11 and rest == times[-1]
    assert times[:4] == pytest.approx([0.45152, 1.08366, 1.52615, 1.83590], abs=1e-5)
    assert rest == pytest.approx(2.49911, abs=1e-5)
    assert height(0.5) == pytest.approx(3.0991 * 0.0485 - 0.5 * G * 0.0485 ** 2, abs=1e-3)


@pytest.mark.parametrize("version", [2, 3])
def test_ball_heights_and_impact_times_match_the_analytic_ball_until_2_s(fmus, version):
    resp = simulate_fmu(fmus[BALL[version]], t_final=2.0, output_step=0.01)
    assert resp.output_labels == ["h", "v"] and resp.state_labels == ["h", "v"]
    assert resp.time[0] == 0.0 and resp.time[-1] == 2.0 and resp.time.size == 201
    h = resp.outputs[0]
    np.testing.assert_allclose(h, [height(t) for t in resp.time], rtol=0, atol=1e-6)
    events = resp.simulation["events"]
    assert [e["kind"] for e in events] == ["state"] * 4           # impacts at 0.45, 1.08, 1.53, 1.84 s
    np.testing.assert_allclose([e["time"] for e in events], impacts(until=2.0)[0], rtol=0, atol=1e-9)
    assert resp.simulation["terminated"] is None


@pytest.mark.parametrize("version", [2, 3])
def test_the_ball_is_re_initialised_at_each_impact(fmus, version):
    """Right after impact k the speed is +e^k v1: the event iteration's new state reached the solver."""
    resp = simulate_fmu(fmus[BALL[version]], t_final=1.2, output_step=1e-3)
    v = resp.outputs[1]
    t1, t2 = impacts(until=1.2)[0]
    v1 = G * t1
    for k, tk in ((1, t1), (2, t2)):
        j = int(np.searchsorted(resp.time, tk))                 # first recorded point after impact k
        assert v[j - 1] == pytest.approx(-E ** (k - 1) * v1 + G * (tk - resp.time[j - 1]), abs=1e-8)
        assert v[j] == pytest.approx(E ** k * v1 - G * (resp.time[j] - tk), abs=1e-8)


@pytest.mark.parametrize("version", [2, 3])
def test_the_ball_comes_to_rest_and_has_no_more_events(fmus, version):
    resp = simulate_fmu(fmus[BALL[version]], t_final=3.0, output_step=0.005)
    times, rest = impacts()
    events = resp.simulation["events"]
    assert len(events) == 11 and {e["kind"] for e in events} == {"state"}
    np.testing.assert_allclose([e["time"] for e in events], times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.outputs[0], [height(t) for t in resp.time], rtol=0, atol=1e-6)
    after = resp.time > rest
    assert after.sum() == 101 and np.all(resp.outputs[:, after] == 0.0)   # h = v = 0 exactly, from 2.5 s to 3 s
    assert np.all(resp.outputs[0] >= 0.0)                                # never below the floor on the grid


@pytest.mark.parametrize("version", [2, 3])
def test_the_restitution_is_a_start_value(fmus, version):
    """e = 0.5: flights of 2 (0.5^k) v1 / g; 0.5^5 v1 = 0.138 > v_min > 0.5^6 v1: it rests at impact 6."""
    resp = simulate_fmu(fmus[BALL[version]], t_final=2.0, output_step=0.01, start_values={"e": 0.5})
    times, rest = impacts(e=0.5)
    assert len(times) == 6 and rest == pytest.approx(1.32636, abs=1e-5)
    np.testing.assert_allclose([e["time"] for e in resp.simulation["events"]], times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.outputs[0], [height(t, e=0.5) for t in resp.time], rtol=0, atol=1e-6)


@pytest.mark.parametrize("version", [2, 3])
def test_a_bad_restitution_is_named_by_the_fmu(fmus, version):
    with pytest.raises(FMUError, match=r"parameter e = 1\.5: allowed is 0 <= e <= 1"):
        simulate_fmu(fmus[BALL[version]], 1.0, 0.1, start_values={"e": 1.5})


def test_stair_steps_at_its_time_events_and_the_fmu_ends_the_run_at_9_s(fmus):
    resp = simulate_fmu(fmus["stair"], t_final=12.0, output_step=0.5)
    events = resp.simulation["events"]
    assert [e["time"] for e in events] == [float(k) for k in range(1, 10)]     # exactly, not approximately
    assert {e["kind"] for e in events} == {"time"}
    assert resp.simulation["terminated"] == 9.0 and resp.time[-1] == 9.0
    np.testing.assert_array_equal(resp.time, 0.5 * np.arange(19))
    # a grid point on an event gets the value after it: floor(t)
    np.testing.assert_array_equal(resp.outputs[0], np.floor(resp.time))


def test_stair_stopped_before_9_s_is_not_terminated(fmus):
    resp = simulate_fmu(fmus["stair"], t_final=4.25, output_step=0.25)
    assert [e["time"] for e in resp.simulation["events"]] == [1.0, 2.0, 3.0, 4.0]
    assert resp.simulation["terminated"] is None and resp.time[-1] == 4.25
    np.testing.assert_array_equal(resp.outputs[0], np.floor(resp.time))


def test_fmpys_own_solver_sees_the_same_ball_and_stair(fmus):
    """An independent importer (fmpy, CVode with root finding) on the same FMUs."""
    fmpy = pytest.importorskip("fmpy")
    for name in BALL.values():
        ball = fmpy.simulate_fmu(str(fmus[name]), stop_time=3.0, output_interval=0.01, relative_tolerance=1e-10,
                                 output=["h", "v"])
        early = ball["time"] <= 2.0
        np.testing.assert_allclose(ball["h"][early], [height(t) for t in ball["time"][early]], rtol=0, atol=1e-6)
        assert np.all(ball["h"][ball["time"] > 2.5] == 0.0) and np.all(ball["v"][ball["time"] > 2.5] == 0.0)
    stair = fmpy.simulate_fmu(str(fmus["stair"]), stop_time=12.0, output_interval=0.5)
    assert stair["time"][-1] == 9.0 and stair["counter"].max() >= 8.0


@pytest.mark.parametrize("name, events", [
    ("ball", {"state_events": 1, "time_events": 0}),  # 0.4515 s
    ("ball3", {"state_events": 1, "time_events": 0}),
    ("stair", {"state_events": 0, "time_events": 1}),  # at t_final
])
def test_fmu_check_reports_every_stage_without_aborting(fmus, capsys, name, events):
    report = check_fmu(fmus[name])
    assert [s["stage"] for s in report["stages"]] == STAGES
    status = {s["stage"]: s["status"] for s in report["stages"]}
    assert all(s["why"] for s in report["stages"])
    assert status == {"archive": "passed", "model_description": "passed", "validation": "passed",
                      "model_exchange": "not applicable", "simulate_fmu": "passed",
                      "co_simulation": "not applicable",
                      "me_vs_cs": "not applicable", "plant_comparison": "not applicable"}
    assert report["validation"]["problems"] == []
    # it loads as a block with events (the numpy engine runs them in a loop); its run alone is simulate_fmu's
    assert "loads as a block with events" in stage(report, "model_exchange")["why"]
    assert report["model_exchange"]["loads"] is True
    assert {k: report["simulate_fmu"][k] for k in events} == events
    assert report["simulate_fmu"]["terminated"] is None and report["simulate_fmu"]["finite"] is True
    # an FMU with events passes the check when simulate_fmu runs it (a block's refusal is not a failure)
    assert report["passed"] is True
    code = dobkit_main(["fmu", "check", str(fmus[name])])
    assert code == 0
    printed = capsys.readouterr().out
    assert f"model {name}; interfaces: ModelExchange" in printed and "Traceback" not in printed
    assert "fmu.simulate_fmu (events, arrays): 1 s" in printed
