"""Batches as parameter rows: column checks, the traced rows, and each member equal to its single compiled run."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.engines.compiled.jit import numba_or_none
from blocks.figure2 import batch
from blocks.figure2.batch import Variants, simulate_batch
from blocks.figure2.batch.members import MemberLoop
from blocks.figure2.batch.rows import MemberRows, member_rows
from blocks.figure2.batch.variants import column_values
from blocks.figure2.metrics import signal, tracking_metrics
from blocks.scenarios.scenario import ScenarioError

needs_numba = pytest.mark.skipif(numba_or_none() is None, reason="the compiled batch needs numba")


@pytest.fixture(scope="module")
def short():
    return blocks.load_scenario("paper").replace(simulation={"t_final": 1.0}, trajectory={"duration": 10.0})


def _columns(n: int, seed: int = 7) -> dict:
    rng = np.random.default_rng(seed)
    cols = {f"nominal_scale.{k}": rng.uniform(0.8, 1.2, n) for k in ("m1", "m3", "I2", "I4")}
    cols["gains.kp"] = rng.uniform(120.0, 250.0, n)
    cols["gains.kd"] = rng.uniform(30.0, 45.0, (n, 4))
    cols["disturbance.f_r"] = np.array([1.43, 1.6, 1.4, 1.2]) * rng.uniform(0.5, 2.0, (n, 1))
    return cols


def test_columns_are_checked_as_the_members_are(short):
    cols = _columns(5)
    assert column_values(short, cols) is not None
    # a key the columns do not take, a value of the wrong sign, a list of the wrong length: member by member
    assert column_values(short, {"gains.observer": [5.0, 6.0]}) is None
    assert column_values(short, cols | {"gains.kp": np.array([100.0, 100.0, -1.0, 100.0, 100.0])}) is None
    assert column_values(short, {"disturbance.f_r": np.ones((2, 3))}) is None
    assert column_values(short, {"gains.kp": [True, False]}) is None
    # the nominal arm's inertia (Eq. 5-7): with every mass and inertia scaled by s the margin
    # (k1-k3)(k3-k5) - k2^2/4 = 4 l1^2 l2^2 m2 (m3+m4) s^2 + (inertia terms) s^2 is positive while s^2 stays a
    # normal number, and rounds to 0 below: the column check and RobotParameters agree on both sides
    every = lambda s: {f"nominal_scale.{k}": [1.0, s] for k in ("m1", "m2", "m3", "m4", "I1", "I2", "I3", "I4")}  # noqa: E731
    assert column_values(short, every(1e-150)) is not None
    Variants(short, [{k: v[1] for k, v in every(1e-150).items()}])
    assert column_values(short, every(1e-170)) is None
    with pytest.raises(ScenarioError, match="variant 1: robot parameters give an inertia matrix"):
        Variants(short, every(1e-170))
    with pytest.raises(ScenarioError, match=r"variant 2.*gains.kp"):
        Variants(short, cols | {"gains.kp": np.array([100.0, 100.0, -1.0, 100.0, 100.0])})


def test_checked_columns_make_the_members_model_objects_when_asked(short):
    cols = _columns(5)
    fast, slow = Variants(short, cols), Variants(short, [dict(r) for r in Variants(short, cols).records])
    assert fast.columns is not None
    np.testing.assert_array_equal(fast.kp, slow.kp)
    np.testing.assert_array_equal(fast.disturbance.f_r, slow.disturbance.f_r)
    assert [r.kernel_params().tolist() for r in fast.nominals] == [r.kernel_params().tolist() for r in slow.nominals]
    assert fast.noises == [short.noise] * 5 and len(fast) == 5


@needs_numba
def test_traced_rows_are_the_members_own_numbers_bit_for_bit(short):
    from blocks.engines.compiled.batch import _member_theta, auto_batch_reason
    v = Variants(short, _columns(12))
    rows = member_rows(v, True)
    assert isinstance(rows, MemberRows)
    loop = MemberLoop(v, True)
    _, engine = auto_batch_reason(loop)
    np.testing.assert_array_equal(rows.theta(engine), _member_theta(engine, loop))
    np.testing.assert_array_equal(rows.start_states(), loop.initial_state().T)
    from blocks.engines.divergence import state_meanings
    from blocks.figure2.physical_bounds import batch_bounds
    labels = state_meanings(loop.loop)
    np.testing.assert_array_equal(rows.bounds(labels).bounds, batch_bounds(loop, labels).bounds)


@needs_numba
def test_each_member_is_its_single_compiled_run(short):
    cols = _columns(6)
    result = simulate_batch(short, cols, signals=("q", "tau", "d"), method="RK45")
    assert result.method == "RK45" and result.ok.all()
    rk4 = simulate_batch(short, cols, signals=("q",))
    assert rk4.method == "RK4"          # the default: one schedule shared by every member
    for i in (0, 3, 5):
        single = blocks.simulate(result.variants.scenario(i), engine="compiled")
        for name in ("q", "tau", "d"):
            np.testing.assert_allclose(result.signals[name][i], signal(single, name).T, rtol=1e-12, atol=1e-12,
                                       err_msg=f"member {i}, {name}")
        want = tracking_metrics(single)
        for name, value in result.member_metrics(i).items():
            np.testing.assert_allclose(value, want[name], rtol=1e-10, atol=1e-15, err_msg=f"member {i}, {name}")
        # the fixed-step option: within the stated agreement of the single run
        np.testing.assert_allclose(rk4.signals["q"][i], signal(single, "q").T, rtol=0, atol=batch.STATE_ATOL)
    assert result.evaluations.shape == (6,) and np.all(result.evaluations > 100)


@needs_numba
def test_workers_default_to_every_core_and_give_the_same_numbers(short):
    from blocks.engines.compiled.batch import available_cores, batch_threads
    numba = numba_or_none()
    assert batch_threads(None) == min(available_cores(), numba.config.NUMBA_NUM_THREADS)
    assert batch_threads(1) == 1
    with pytest.raises(ValueError, match="workers"):
        batch_threads(0)
    s = short.replace(simulation={"t_final": 0.2})
    one = simulate_batch(s, _columns(8), workers=1)
    every = simulate_batch(s, _columns(8))
    for name, value in one.metrics.items():
        np.testing.assert_array_equal(every.metrics[name], value)


def test_the_numpy_batch_takes_no_adaptive_method(short):
    with pytest.raises(ValueError, match="RK45"):
        simulate_batch(short, [{}], engine="fast", method="RK45")
    with pytest.raises(ValueError, match="method"):
        simulate_batch(short, [{}], method="Euler")


@needs_numba
def test_rows_with_a_bandwidth_observer_gain_are_traced_and_each_member_is_its_single_run(short):
    # With gains.observer_bandwidth each member's Y = omega M^(q0) is of its own nominal arm: the rows carry it
    # (traced from Eq. 5's entries, bit for bit the members' own blocks), and each member equals its single run.
    from blocks.engines.compiled.batch import _member_theta, auto_batch_reason
    from blocks.scenarios.scenario import scenario_from_dict
    data = short.user_data | {"gains": {k: v for k, v in short.user_data.get("gains", {}).items() if k != "observer"}}
    data["gains"]["observer_bandwidth"] = 20.0
    data["simulation"] = dict(data.get("simulation", {}), t_final=0.25)
    base = scenario_from_dict(data, source="bandwidth")
    cols = {k: v for k, v in _columns(6).items() if k.startswith("nominal_scale.")}
    v = Variants(base, cols)
    rows = member_rows(v, True)
    assert isinstance(rows, MemberRows)
    loop = MemberLoop(v, True)
    _, engine = auto_batch_reason(loop)
    np.testing.assert_array_equal(rows.theta(engine), _member_theta(engine, loop))
    result = simulate_batch(base, cols, signals=("q", "d_hat"), method="RK45")
    for i in (0, 5):
        single = blocks.simulate(result.variants.scenario(i), engine="compiled")
        for name in ("q", "d_hat"):
            np.testing.assert_allclose(result.signals[name][i], signal(single, name).T, rtol=1e-12, atol=1e-12,
                                       err_msg=f"member {i}, {name}")
