"""Job files check the scenario values they hold with the scenario's own validator (analysis.jobs.keys)."""
from __future__ import annotations

import pytest
from test_tune import write_problem

from analysis.tune.spec import TuneError, load_tuning
from blocks.scenarios.scenario import ScenarioError, scenario_from_dict


@pytest.mark.parametrize("key, value", [("q_std", "x"), ("dq_std", [True, 1, 2, 3]), ("sample_period", [0.001])])
def test_a_tunings_sensor_noise_is_refused_in_the_scenarios_own_words(tmp_path, key, value):
    # what a scenario file says of the same value in its [noise]
    with pytest.raises(ScenarioError) as scenario:
        scenario_from_dict({"noise": {key: value}})
    words = str(scenario.value).split(f"'noise.{key}", 1)[1]          # "' must be ...", "[0]' must be ..."
    noise = {"q_std": [2e-4] * 4, "dq_std": [5e-3] * 4, "sample_period": 0.001} | {key: value}
    table = "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in noise.items()) + "}"
    path = write_problem(tmp_path, constraints={"sensor_noise": table})
    with pytest.raises(TuneError) as tuning:
        load_tuning(path)
    assert f"'constraints.sensor_noise.{key}{words}" in str(tuning.value)


def test_values_the_scenario_allows_but_a_tuning_does_not_are_still_refused(tmp_path):
    table = "{q_std = [-2e-4, 2e-4, 2e-5, 2e-4], dq_std = [5e-3, 5e-3, 5e-4, 5e-3], sample_period = 0.001}"
    with pytest.raises(TuneError, match=r"'constraints.sensor_noise.q_std' must be 4 numbers >= 0"):
        load_tuning(write_problem(tmp_path, constraints={"sensor_noise": table}))


def _toml(value) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)
