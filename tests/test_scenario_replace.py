"""Deriving scenarios with ``Scenario.replace``, typed value checks and size limits."""
import numpy as np
import pytest

from analysis.experiment import run_experiment
from blocks import ScenarioError, load_scenario, scenario_from_dict
from blocks.noise import MeasurementNoise


def test_derived_defaults_follow_a_replaced_key():
    paper = load_scenario("paper")
    assert paper.trajectory.duration == 10.0
    short = paper.replace(simulation={"t_final": 2.0})
    assert short.trajectory.duration == 2.0             # the path still completes within the run
    moved = paper.replace(disturbance={"skin_height": -0.35})
    assert moved.trajectory.skin_height == -0.35         # the path and the tissue model share the skin
    # a key the user did give is kept
    fixed = paper.replace(trajectory={"duration": 8.0}).replace(simulation={"t_final": 2.0})
    assert fixed.trajectory.duration == 8.0


def test_changing_the_trajectory_kind_starts_the_section_afresh():
    held = load_scenario("paper").replace(trajectory={"kind": "joint_sine", "amplitude": [0, 0, 0, 0],
                                                      "omega": 1.0, "offset": [0.3, 2.0, 0.24, 0.1]})
    q, dq, _ = held.trajectory.evaluate(1.234)
    np.testing.assert_allclose(q, [0.3, 2.0, 0.24, 0.1])
    np.testing.assert_allclose(dq, 0.0)
    assert held.kp[0, 0] == 180.0                         # other sections untouched


def test_scenarios_compare_by_content():
    assert load_scenario("paper") == load_scenario("paper")
    assert load_scenario("paper") != load_scenario("paper").replace(gains={"kp": 100.0})


@pytest.mark.parametrize("section, values, key", [
    ("trajectory", {"stitches": "five"}, "trajectory.stitches"),
    ("trajectory", {"stitches": 2.5}, "trajectory.stitches"),
    ("trajectory", {"start": "abc"}, "trajectory.start"),
    ("trajectory", {"elbow": 1.0}, "trajectory.elbow"),
    ("trajectory", {"hover": [0.1, 0.2]}, "trajectory.hover"),
    ("disturbance", {"f_r": [[1, 2], [3, 4]]}, "disturbance.f_r[0]"),
    ("disturbance", {"tissue_stiffness": "stiff"}, "disturbance.tissue_stiffness"),
    ("noise", {"seed": 1.5}, "noise.seed"),
])
def test_wrongly_typed_values_name_the_key(section, values, key):
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict({section: values}, source="t.toml")
    message = str(err.value)
    assert f"'{key}'" in message or key in message
    assert message.count("t.toml") == 1


def test_grids_too_large_for_memory_are_refused_by_name():
    with pytest.raises(ScenarioError, match="simulation.output_step"):
        scenario_from_dict({"simulation": {"t_final": 1e12}})
    with pytest.raises(ScenarioError, match="noise.sample_period"):
        scenario_from_dict({"noise": {"q_std": [1e-4] * 4, "sample_period": 1e-10}})


def test_noise_off_allocates_nothing_and_is_zero():
    quiet = MeasurementNoise(t_final=1e6)                # a long run without noise costs no memory
    assert not quiet.enabled and quiet._samples is None
    n_q, n_dq = quiet.sample(np.array([0.0, 5.0]))
    assert n_q.shape == (2, 4) and not n_q.any() and not n_dq.any()


def test_noise_rms_matches_linear_interpolation_of_white_samples():
    noise = MeasurementNoise(q_std=(1.0, 1.0, 1.0, 1.0), seed=3, sample_period=0.01, t_final=2000.0)
    n_q, _ = noise.sample(np.linspace(0.0, 2000.0, 1_000_001))
    # E[((1-w) a + w b)^2] averaged over w in [0, 1] = 2/3 for independent unit samples
    assert np.sqrt(np.mean(n_q ** 2)) == pytest.approx(np.sqrt(2 / 3), rel=0.01)


def test_output_folder_is_checked_before_any_simulation(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("x")
    # this scenario would diverge; the folder check must come first
    wild = load_scenario("paper").replace(disturbance={"f_r": [1e12] * 4}, simulation={"t_final": 0.5})
    with pytest.raises(FileExistsError, match="not empty"):
        run_experiment(wild, out)
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(FileExistsError, match="is an existing file"):
        run_experiment(wild, a_file)
