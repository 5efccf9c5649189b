"""A run's limits before it starts (blocks.run_limits): its fastest rate, its step estimate and the refusal of
a run beyond the step budget, naming the key that sets the rate (docs/hostile-inputs.md, "Single runs")."""
from __future__ import annotations

import re

import pytest

import blocks
from blocks.budget import BudgetError

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
