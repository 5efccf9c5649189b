"""What ``blocks.simulate`` and ``simulate_batch`` are given besides a scenario: anything else (not a scenario, a
plant or observer flag of the wrong kind, a progress that cannot be called, variants that are not columns of
values) is named in a TypeError or ScenarioError before the work (docs/hostile-inputs.md, "Single runs" and
"Round 3")."""
from __future__ import annotations

import pytest

import blocks
from blocks import ScenarioError

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.2, "trajectory.duration": 10.0}


@pytest.mark.parametrize("given, words", [(None, "got NoneType"), (123, "got int 123"),
                                          ({"gains": {"kp": 1}}, "scenario_from_dict")])
def test_what_is_not_a_scenario_is_named(given, words):
    with pytest.raises(TypeError, match=words):
        blocks.simulate(given)


def test_bad_arguments_to_simulate_are_named():
    with pytest.raises(TypeError, match="plant must be a python-control NonlinearIOSystem.*str 'x'"):
        blocks.simulate(PAPER.with_changes(SHORT), plant="x")
    with pytest.raises(TypeError, match="observer must be True or False, got 'yes'"):
        blocks.simulate(PAPER.with_changes(SHORT), observer="yes")


def test_a_nested_mapping_of_variants_asks_for_dotted_keys():
    from blocks.figure2.batch import simulate_batch
    with pytest.raises(ScenarioError, match=r"variant column 'gains' must be a list.*write dotted keys, "
                                            r"\{'gains\.kp': \[\.\.\.\]\}"):
        simulate_batch(PAPER, {"gains": {"kp": 100}})
    with pytest.raises(ScenarioError, match=r"variant column 'gains\.kp' must be a list of values, got 100"):
        simulate_batch(PAPER, {"gains.kp": 100})
    with pytest.raises(ScenarioError, match="variants must be a mapping of columns"):
        simulate_batch(PAPER, 5)


def test_a_progress_that_cannot_be_called_is_named():
    with pytest.raises(TypeError, match="progress must be a function \\(or None\\), got int 5"):
        blocks.simulate(PAPER, progress=5)
