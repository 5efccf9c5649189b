"""One divergence rule and one budget for every engine (blocks.engines.monitor, blocks.engines.divergence).

Every engine is run on one diverging scenario and one stiff-but-stable one (Y = 1e5) and must give the same
verdict: the diverging one stopped with the same signal, the same bound and a time no later than the first
output point after the crossing; the stiff one completed.  The crossing time is computed here by hand: the
prismatic joint under a constant 1e9 N on its 0.25 kg reaches its velocity bound within nanoseconds.
"""
from __future__ import annotations

import re

import numpy as np
import pytest

import blocks
from blocks.engines.budget import BudgetError
from blocks.figure2.batch import simulate_batch
from blocks.figure2.physical_bounds import VELOCITY_MARGIN

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.02, "simulation.output_step": 0.001, "trajectory.duration": 10.0}
DIVERGING = PAPER.with_changes(SHORT | {"disturbance.f_r": [0.0, 0.0, 1e9, 0.0]})
STIFF = PAPER.with_changes(SHORT | {"gains.observer": 1e5})
# the digital loop at a rate where Ts * lambda_max(Y M^-1) = 1e5 / 0.25 / 1e6 = 0.4 keeps the observer stable
SAMPLED = {"controller.sample_rate": 1e6, "simulation.t_final": 0.002}


def _numba():
    pytest.importorskip("numba")


def _verdict(message: str) -> tuple[str, float, float]:
    """(signal, bound, time) from a divergence message."""
    found = re.search(r"diverged at t = ([0-9.eE+-]+) s: (\w+ \w+\[\d\]) reached .*? beyond its bound "
                      r"([0-9.eE+-]+)", message)
    assert found, message
    return found.group(2), float(found.group(3)), float(found.group(1))


def _bound_by_hand(s) -> float:
    """The prismatic joint's velocity bound: the reference's largest speed plus 100 m/s."""
    _, dq_ref, _ = s.trajectory.evaluate(np.linspace(0.0, s.simulation.t_final, 201))
    return float(np.abs(np.asarray(dq_ref)[:, 2]).max() + VELOCITY_MARGIN["prismatic"])


def _single(engine):
    def run(s):
        if engine == "compiled":
            _numba()
        blocks.simulate(s, engine=engine)
    return run


def _sampled(engine):
    def run(s):
        if engine == "compiled":
            _numba()
        blocks.simulate(s.with_changes(SAMPLED), engine=engine)
    return run


def _batch(engine):
    def run(s):
        if engine == "compiled":
            _numba()
        # a mild member first: each member must be judged on its own bounds, not on the first one's
        result = simulate_batch(s, [{"gains.observer": 10.0}, {}], engine=engine)
        if not result.ok.all():
            # a batch keeps going; the verdict of its first failed member, in the single run's words
            m = int(np.flatnonzero(~result.ok)[0])
            raise blocks.SimulationError(f"member {m}: the loop diverged at {result.failures[m]}")
    return run


_PLANT: dict = {}


def _plant_fmu(tmp_path_factory):
    if "path" not in _PLANT:
        from fmu import export_plant
        _PLANT["path"] = export_plant(tmp_path_factory.mktemp("plant") / "plant.fmu")
    return _PLANT["path"]


def _cosim(sampled: bool):
    def run(s, tmp_path_factory):
        from conftest import c_compiler_available
        if not c_compiler_available():
            pytest.skip("no C compiler to build the plant FMU")
        from fmu import cosimulate
        if sampled:
            s = s.with_changes(SAMPLED | {"simulation.output_step": 1e-5})
            cosimulate(_plant_fmu(tmp_path_factory), s, step=1e-6, parameters="scenario")
        else:
            # h lambda = 0.4 for the observer's 4e5 1/s at Y = 1e5: the coupling and the Python side's RK4 both stable
            cosimulate(_plant_fmu(tmp_path_factory), s, step=1e-6, parameters="scenario", error_estimate=False)
    return run


ENGINES = {"python-control": _single("python-control"), "numpy": _single("fast"), "compiled": _single("compiled"),
           "numpy batch": _batch("fast"), "compiled batch": _batch("compiled"),
           "sampled numpy": _sampled("fast"), "sampled compiled": _sampled("compiled"),
           "co-simulation": _cosim(False), "sampled co-simulation": _cosim(True)}


def _run(engine, s, tmp_path_factory):
    if "co-simulation" in engine:
        ENGINES[engine](s, tmp_path_factory)
    else:
        ENGINES[engine](s)


@pytest.mark.parametrize("engine", list(ENGINES))
def test_every_engine_gives_the_same_verdict_on_a_diverging_loop(engine, tmp_path_factory):
    with pytest.raises(blocks.SimulationError) as err:
        _run(engine, DIVERGING, tmp_path_factory)
    signal, bound, t = _verdict(str(err.value))
    assert signal == "plant dq[2]"
    assert bound == pytest.approx(_bound_by_hand(DIVERGING), rel=1e-3)
    # a = 1e9 N / 0.25 kg: the bound is reached after about bound / a; a fixed-step engine sees it at its first
    # output point after that, the others at the crossing itself
    crossing = bound / (1e9 / 0.25)
    assert crossing * 0.5 <= t <= max(crossing * 2, DIVERGING.simulation.output_step)


@pytest.mark.parametrize("engine", list(ENGINES))
def test_every_engine_runs_a_stiff_but_stable_loop_to_the_end(engine, tmp_path_factory):
    _run(engine, STIFF, tmp_path_factory)


def test_a_diverging_batch_member_is_reported_alone_and_the_others_kept():
    result = simulate_batch(PAPER.with_changes(SHORT), [{}, {"disturbance.f_r": [0.0, 0.0, 1e9, 0.0]}, {}],
                            engine="fast")
    assert result.ok.tolist() == [True, False, True]
    assert "plant dq[2] reached" in result.failures[1] and set(result.failures) == {1}
    assert np.all(np.isfinite(result.metrics["rms_position_error"][[0, 2]]))
    assert np.all(np.isnan(result.metrics["rms_position_error"][1]))


def test_the_observer_state_is_judged_through_the_estimate_not_by_size():
    """At Y = 1e5 the observer's state z = d_hat - Y dq is of order Y |dq| (far beyond 1e6 on the path's start)
    and not divergence: its bound is the estimate's plus Y times the velocity bound."""
    from blocks.figure2.loop import closed_loop
    from blocks.figure2.physical_bounds import state_bounds
    bounds = state_bounds(closed_loop(STIFF), STIFF)
    z = [k for k, name in enumerate(bounds.names) if name.startswith("observer z")]
    assert np.all(bounds.bounds[z] > 1e5 * 100.0)


def test_a_state_without_a_physical_bound_is_judged_by_growth():
    from blocks.engines.divergence import GROWTH_FACTOR, StateBounds
    b = StateBounds(np.array([1.0, np.inf]), ["a", "b"], ["m", ""], ["given", "finite"]).with_growth([0.5, -3.0])
    assert b.bounds.tolist() == [1.0, GROWTH_FACTOR * 4.0]
    assert "no physical bound" in b.reasons[1]
    assert not b.violated([0.9, 3.9e6]).any() and b.violated([0.9, 4.1e6]).tolist() == [False, True]


def test_a_value_beyond_its_bound_prints_beyond_it():
    from blocks.engines.divergence import StateBounds
    b = StateBounds(np.array([100.2]), ["plant dq[2]"], ["m/s"], ["given"])
    text = b.describe(np.array([100.20000001]))
    value, bound = re.search(r"reached ([0-9.]+) m/s, beyond its bound ([0-9.]+)", text).groups()
    assert float(value) > float(bound)


@pytest.mark.parametrize("changes, key", [
    ({"simulation.max_step": 1e-12, "simulation.t_final": 1.0, "simulation.output_step": 0.01},
     "simulation.max_step"),
    ({"controller.sample_rate": 1e9}, "controller.sample_rate"),
    ({"controller.sample_rate": 1e6}, "controller.sample_rate"),
    ({"controller.sample_rate": 1000, "controller.delay": 10 ** 10}, "controller.delay"),
])
def test_runs_beyond_the_budget_are_refused_before_they_start_naming_the_key(changes, key):
    s = PAPER.with_changes({"controller.sample_rate": 1000} | changes) if key.startswith("controller") else \
        PAPER.with_changes(changes)
    with pytest.raises(BudgetError) as err:
        blocks.simulate(s, engine="fast")
    assert err.value.key == key and key in str(err.value)


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_the_wall_time_budget_stops_every_engine(engine, monkeypatch):
    if engine == "compiled":
        _numba()
        blocks.simulate(PAPER.with_changes(SHORT), engine="compiled")          # compile outside the budget
    monkeypatch.setenv("DOBKIT_MAX_SECONDS", "0.3")
    s = PAPER.with_changes({"simulation.max_step": 2e-6, "simulation.t_final": 1.0,
                            "simulation.output_step": 0.01})
    with pytest.raises(BudgetError, match=r"wall-time budget of 0.3 s ran out at t = .* of 1 s"):
        blocks.simulate(s, engine=engine)


def test_the_wall_time_budget_stops_a_sampled_run(monkeypatch):
    monkeypatch.setenv("DOBKIT_MAX_SECONDS", "0.3")
    s = PAPER.with_changes({"controller.sample_rate": 1000})
    # refused before it starts when its measured estimate is over the budget (blocks.engines.sampled_cost), else stopped
    with pytest.raises(BudgetError, match=r"wall-time budget of 0\.3 s( ran out at t = .* of 10 s|; )"):
        blocks.simulate(s, engine="fast")


def test_each_batch_member_is_judged_on_its_own_bounds_as_its_single_run_would_be():
    """Members differ in their disturbance and gain, so their disturbance-estimate bounds differ: each member's
    column equals the bounds of its own scenario run alone."""
    from blocks.figure2.batch.members import MemberLoop
    from blocks.figure2.batch.variants import Variants
    from blocks.figure2.loop import closed_loop
    from blocks.figure2.physical_bounds import batch_bounds, state_bounds
    records = [{}, {"disturbance.f_r": [0.0, 0.0, 300.0, 0.0]}, {"gains.observer": 50.0}]
    v = Variants(PAPER.with_changes(SHORT), records)
    got = batch_bounds(MemberLoop(v, observer=True))
    for m in range(len(records)):
        single = state_bounds(closed_loop(v.scenario(m)), v.scenario(m))
        np.testing.assert_allclose(got.bounds[:, m], single.bounds, rtol=1e-12)
    assert got.bounds[-2, 1] > 30 * got.bounds[-2, 0]           # joint 3 estimate bound follows its 300 N


def test_a_member_that_failed_keeps_its_first_failure_time():
    from blocks.engines.divergence import StateBounds
    from blocks.engines.monitor import Monitor
    monitor = Monitor("batch", StateBounds(np.array([1.0]), ["a"], ["m"], ["given"]), np.zeros((1, 2)))
    failed = monitor.check_members(0.1, np.array([[2.0, 0.0]]), np.full(2, np.nan))
    failed = monitor.check_members(0.2, np.array([[3.0, 5.0]]), failed)
    assert failed.tolist() == [0.1, 0.2]


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_a_batch_member_starting_beyond_its_own_bound_fails_at_once_whatever_the_others_bounds(engine):
    """Member 0 has a loose estimate bound (a 50 N disturbance on joint 3, bound about 5e4 N); member 1 starts with
    d_hat[2] = 2e4 N, beyond its own bound (about 9.3e3 N) but within member 0's: it fails at t = 0 on its own
    observer state, as its single run would."""
    if engine == "compiled":
        _numba()
    result = simulate_batch(PAPER.with_changes(SHORT), [{"disturbance.f_r": [1.43, 1.6, 50.0, 1.2]},
                                                        {"initial.d_hat": [0.0, 0.0, 2e4, 0.0]}], engine=engine)
    assert result.ok.tolist() == [True, False]
    assert result.failed_at[1] == 0.0 and "observer z[2]" in result.failures[1]
