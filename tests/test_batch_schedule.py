"""The batch's step rule from the variants' columns: the same rates as each member's model objects give, without
making those objects (they were 0.1 s of a 1000-member batch's set-up, run before any worker starts)."""
import numpy as np
import pytest

import blocks
from blocks.figure2.batch import Variants, schedule


def _column_sets(s, n_members: int = 40) -> list[dict]:
    rng = np.random.default_rng(7)
    n = s.robot.joints.count
    return [
        {f"nominal_scale.{k}": rng.uniform(0.9, 1.1, n_members) for k in ("m1", "m2", "m3", "m4", "I1", "I4")}
        | {"gains.kp": rng.uniform(120.0, 250.0, n_members), "gains.kd": rng.uniform(30.0, 45.0, n_members)},
        {"gains.kp": rng.uniform(100.0, 200.0, (n_members, n)), "gains.kd": rng.uniform(20.0, 40.0, n_members)},
        {"nominal_scale.m2": rng.uniform(0.8, 1.2, n_members), "disturbance.coulomb": rng.uniform(0, 2, (n_members, n)),
         "disturbance.friction_velocity": rng.uniform(0.01, 0.1, n_members),
         "disturbance.viscous": rng.uniform(0, 1, (n_members, n))},
    ]


@pytest.mark.parametrize("name", ["paper", "surgical"])       # surgical: friction, so its rate is in the rule too
@pytest.mark.parametrize("observer", [True, False])
def test_rates_from_columns_equal_the_member_objects_rates(monkeypatch, name, observer):
    s = blocks.load_scenario(name)
    for cols in _column_sets(s):
        v = Variants(s, cols)
        assert v.columns is not None
        fast = schedule.rates_by_source(v, observer)
        assert "members" not in vars(v)             # no member's model objects were made for it
        with monkeypatch.context() as m:
            m.setattr(schedule, "_column_numbers", lambda *args: None)     # each member's objects instead
            slow = schedule.rates_by_source(v, observer)
        assert "members" in vars(v)
        assert fast.keys() == slow.keys() and ("disturbance.friction_velocity" in fast) == (name == "surgical")
        for key in fast:
            np.testing.assert_array_equal(fast[key], slow[key])
            assert fast[key].shape == (len(v),)


def test_rates_follow_each_members_numbers():
    """A member's own Kp, and a lighter nominal arm, move its own rate only (the columns are read per member)."""
    s = blocks.load_scenario("paper")
    v = Variants(s, {"gains.kp": [180.0, 180.0, 2000.0], "nominal_scale.m3": [1.0, 0.5, 1.0]})
    rates = schedule.rates_by_source(v)["gains.kp"]
    # member 2: the PD poles of s^2 + 36 s + 2000 are complex, |s| = sqrt(2000) (no mismatch: nominal = true arm)
    assert rates[2] == pytest.approx(np.sqrt(2000.0), rel=1e-12)
    # member 1: the real pole 0.5 (36 + sqrt(36^2 - 720)) times lambda_max(M^-1 M^) > 1 of a lighter nominal joint 3
    pd = 0.5 * (36.0 + np.sqrt(36.0 ** 2 - 4 * 180.0))
    assert rates[0] == pytest.approx(pd, rel=1e-12)
    assert rates[1] == pytest.approx(pd, rel=1e-12)   # lighter nominal: M^ < M, so lambda_max(M^-1 M^) <= 1


def test_a_bandwidth_observer_with_scaled_nominals_takes_each_members_gain(monkeypatch):
    """With gains.observer_bandwidth each member's Y = omega M^(q0) comes from its own nominal arm: the columns do not
    give it, so the rule reads the members' objects."""
    data = dict(blocks.load_scenario("paper").user_data)
    data["gains"] = {"kp": 180.0, "kd": 36.0, "observer_bandwidth": 40.0}
    s = blocks.scenario_from_dict(data)
    v = Variants(s, {"nominal_scale.m1": [1.0, 0.8, 1.2], "gains.kp": [180.0, 150.0, 200.0]})
    q = schedule._inertia_configurations(v)
    assert schedule._column_numbers(v, q, True) is None
    assert schedule._column_numbers(v, q, False) is not None
    rates = schedule.rates_by_source(v)["gains.observer"]
    assert len(set(rates.tolist())) == 3                  # each member's own Y
