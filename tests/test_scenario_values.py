"""Scenario values and files: what cannot give a run is refused by key when the scenario is read
(docs/hostile-inputs.md, "Scenario files and values")."""
from __future__ import annotations

import pytest

import blocks
from blocks.scenario import ScenarioError

PAPER = blocks.load_scenario("paper")


@pytest.mark.parametrize("changes, words", [
    ({"simulation.t_final": 1e-300, "simulation.output_step": 1e-300}, "output_step' \\(1e-300 s\\) must be at least"),
    ({"simulation.rtol": 0.9}, "simulation.rtol' must be between"),
    ({"simulation.rtol": 1e6}, "simulation.rtol' must be between"),
    ({"simulation.atol": 1e3}, "simulation.atol' must be between"),
    ({"simulation.t_final": 10 ** 400}, "t_final' must be a finite number, got 1.000e\\+400"),
    ({"trajectory.stitches": 10 ** 30}, "trajectory.stitches' = 1.000e\\+30 makes each of the path's"),
    ({"trajectory.stitches": 10 ** 6}, "phases 5e-06 s long, shorter than 0.001 s"),
    ({"noise.sample_period": 1e-6, "noise.q_std": [1e-5] * 4}, "noise.sample_period' \\(1e-06 s\\) asks for 1e\\+07"),
])
def test_scenario_values_that_cannot_give_a_run_are_refused_by_key(changes, words):
    with pytest.raises(ScenarioError, match=words):
        PAPER.with_changes(changes)


def test_a_long_run_without_noise_is_not_refused_for_noise_samples():
    assert PAPER.with_changes({"simulation.t_final": 1e5, "simulation.output_step": 0.05}).noise is None


def test_scenario_files_with_a_byte_order_mark_or_given_as_folders(tmp_path):
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + b'name = "with a mark"\n')
    assert blocks.load_scenario(bom).name == "with a mark"
    with pytest.raises(ScenarioError, match="is a folder, not a scenario file"):
        blocks.load_scenario(tmp_path)
