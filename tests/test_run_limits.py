"""A run's limits before it starts (blocks.figure2.run_limits, blocks.figure2.batch.schedule): its fastest rate, its step
estimate
and the refusal of a run beyond the step budget, naming the key that sets the rate (docs/hostile-inputs.md,
"Single runs" and "Round 3").

Expected numbers are worked by hand: the PD loop's fastest rate with ``kd^2 < 4 kp`` is ``sqrt(kp)``, an explicit
RK45 step is stable for ``h <= 3 / rate``; scipy's RK45 on the fastest mode gives the step count to compare with."""
from __future__ import annotations

import re

import numpy as np
import pytest

import blocks
from blocks.engines.budget import BudgetError

PAPER = blocks.load_scenario("paper")


@pytest.mark.parametrize("changes, key", [
    ({"gains.kp": 1e12, "gains.kd": 2e6}, "gains.kp"),
    ({"gains.observer": 1e6}, "gains.observer"),
    ({"gains.observer": 1e300}, "gains.observer"),
    ({"noise.sample_period": 1e-5, "noise.q_std": [1e-5] * 4}, "noise.sample_period"),
])
def test_runs_that_would_never_finish_are_refused_before_they_start_with_the_key(changes, key, monkeypatch):
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "500000")     # the noisy run's million steps would be allowed by default
    with pytest.raises(BudgetError, match=f"integrator steps per run .*set by '{key}'.*DOBKIT_MAX_STEPS") as err:
        blocks.simulate(PAPER.with_changes(changes), engine="fast")
    assert err.value.key == key


NUMBER = r"([0-9.]+(?:e[+-]?\d+)?)"


def test_the_step_refusal_of_kp_1e308_agrees_with_its_own_rate_and_step():
    with pytest.raises(BudgetError) as err:
        blocks.simulate(PAPER.with_changes({"gains.kp": 1e308}))
    text = str(err.value)
    steps, rate, step = (float(re.search(pattern, text).group(1)) for pattern in (
        rf"needs about {NUMBER} integrator steps", rf"fastest rate, about {NUMBER} 1/s",
        rf"step to {NUMBER} s"))
    # kd^2 < 4 kp: the PD poles have modulus sqrt(kp) = 1e154 1/s (perfect model: no mismatch factor)
    assert rate == pytest.approx(1e154, rel=1e-3)
    assert step == pytest.approx(3.0 / 1e154, rel=1e-3)
    assert steps == pytest.approx(10.0 / step, rel=1e-2)
    assert "'gains.kp'" in text


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_step_rate_takes_the_largest_mismatch_of_a_nominal_model_given_in_python():
    """rl-mismatch-min: a nominal scope4 whose first link (yaw, turning with joint 1 only) is three times heavier:
    M^ - M is positive semidefinite of rank one, so lambda(M^-1 M^) are 1 (three times) and one value in (1, 3]
    (M <= M^ <= 3 M).  The step rate is the fast PD pole times the largest, so strictly above 30 1/s, at most 90."""
    pytest.importorskip("pinocchio")
    import copy
    import dataclasses

    from blocks.figure2.run_limits import arm_rates
    from blocks.scenarios.scenario import scenario_from_dict
    s = blocks.load_scenario("scope4")
    arm, chain = s.robot, s.robot.chain
    heavy = dataclasses.replace(chain, masses=(3.0 * chain.masses[0],) + tuple(chain.masses[1:]),
                                com_inertias=(tuple(tuple(3.0 * x for x in row) for row in chain.com_inertias[0]),)
                                + tuple(chain.com_inertias[1:]))
    nominal = type(arm)(heavy, arm.joints, arm.tool_frame, continuous=arm.continuous, source=arm.source)
    data = copy.deepcopy(dict(s.data))
    data.pop("arm")
    given = scenario_from_dict(data, arm=arm, nominal=nominal)
    q = np.asarray(given.trajectory.evaluate(0.0)[0], dtype=float)
    ratios = np.sort(np.linalg.eigvals(np.linalg.solve(arm.inertia(q), nominal.inertia(q))).real)
    np.testing.assert_allclose(ratios[:3], 1.0, atol=1e-9)
    assert 1.0 < ratios[3] <= 3.0
    rate = float(arm_rates(given, observer=False)["gains.kp"][0])
    assert 30.0 * ratios[3] * (1 - 1e-9) <= rate <= 90.0


def test_the_step_estimate_of_a_stiff_loop_is_scipys_step_count_on_its_fastest_mode():
    """rl-span-times: with Y = 1e5 the observer's fastest mode is Y / k4 = 4e5 1/s (the slide, exact); scipy's
    RK45 on x' = -4e5 x at the scenario's tolerances takes the steps its stability allows, about T lambda / 3.3.
    The estimate is that count to within a factor 2 (a run over budget must be refused, a run within it not)."""
    from scipy.integrate import solve_ivp

    from blocks.figure2.run_limits import estimate_run
    s = blocks.load_scenario("paper").with_changes({"gains.observer": 1e5, "simulation.t_final": 0.05})
    lam = 1e5 / 0.25
    run = solve_ivp(lambda t, x: -lam * x, (0.0, 0.05), [1.0], method="RK45", rtol=s.simulation.rtol,
                    atol=s.simulation.atol)
    taken = len(run.t) - 1
    assert 0.5 <= estimate_run(s).steps / taken <= 2.0


def test_the_observer_rate_bounds_the_slides_fastest_mode_when_the_true_arm_is_lighter():
    """sched-obs-nominal-only: the nominal slide twice as heavy as the true one (m^ = 0.5 kg, m = 0.25 kg), Y = 1e5.

    The slide is decoupled in M (Eq. 5), so its held loop is three states written here by hand, deviations from
    rest: m v' = m^ (-Kp q - Kd v) - (Y v + z) and z' = -(Y / m^) (tau + d_hat) = Y (Kp q + Kd v).  Its fastest
    mode is about Y / m = 4e5 1/s, the true mass's, twice the nominal's: the rate estimate must reach it."""
    from blocks.figure2.batch.schedule import rates_by_source
    from blocks.figure2.batch.variants import Variants
    s = blocks.load_scenario("paper").with_changes({"gains.observer": 1e5, "nominal_scale.m3": 2.0,
                                                     "nominal_scale.m4": 2.0})
    m, m_hat, Y, kp, kd = 0.25, 0.5, 1e5, 180.0, 36.0
    A = np.array([[0.0, 1.0, 0.0],
                  [-m_hat * kp / m, -(m_hat * kd + Y) / m, -1.0 / m],
                  [Y * kp, Y * kd, 0.0]])
    fastest = np.abs(np.linalg.eigvals(A)).max()
    assert fastest == pytest.approx(Y / m, rel=1e-3)
    rate = float(rates_by_source(Variants(s, [{}]))["gains.observer"][0])
    assert rate >= fastest * (1 - 1e-3)
