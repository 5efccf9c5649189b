"""Deriving scenarios with ``Scenario.with_changes`` (and ``replace``, written by section), typed value checks
and size limits."""
import copy
import doctest
import tomllib
from importlib import resources

import numpy as np
import pytest
from conftest import PAPER_FR, paper_toml_dict
from two_joint_arm import TWO, needs_pinocchio
from two_joint_arm import write_urdf as _urdf

import blocks.scenarios.scenario
from analysis.simulation.experiment import run_experiment
from blocks import ScenarioError, load_scenario, scenario_from_dict
from blocks.figure2.batch import Variants
from blocks.model.noise import MeasurementNoise


def test_derived_defaults_follow_a_replaced_key():
    paper = load_scenario("paper")
    assert paper.trajectory.duration == 10.0
    short = paper.replace(simulation={"t_final": 2.0})
    assert short.trajectory.duration == 10.0            # the run ends early; the path is not rescaled
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
    quiet = MeasurementNoise(t_final=1e6, joints=blocks.RRPR_JOINTS)                # a long run without noise costs no memory
    assert not quiet.enabled and quiet._samples is None
    n_q, n_dq = quiet.sample(np.array([0.0, 5.0]))
    assert n_q.shape == (2, 4) and not n_q.any() and not n_dq.any()


def test_noise_rms_matches_linear_interpolation_of_white_samples():
    noise = MeasurementNoise(q_std=(1.0, 1.0, 1.0, 1.0), seed=3, sample_period=0.01, t_final=2000.0,
                             joints=blocks.RRPR_JOINTS)
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


# --- with_changes: the one way to vary a scenario ---------------------------------------------
ROTATING_Y = [[10.0, 2.0, 0.0, 0.0], [-2.0, 10.0, 0.0, 0.0], [0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 10.0]]


def _file(edit, raw=None) -> blocks.scenarios.scenario.Scenario:
    """The paper scenario file (or ``raw``), edited by hand as a person would edit the TOML, then loaded."""
    data = copy.deepcopy(paper_toml_dict() if raw is None else raw)
    edit(data)
    return scenario_from_dict(data, source="paper")


def _set(section, **values):
    return lambda data: data.setdefault(section, {}).update(values)


def _both(*edits):
    def edit(data):
        for e in edits:
            e(data)
    return edit


# changes -> the same edit made by hand in the file (an element key becomes its whole list written out)
CHANGES = {
    "name": ({"name": "mine"}, lambda d: d.update(name="mine")),
    "description": ({"description": "a test"}, lambda d: d.update(description="a test")),
    "robot": ({"robot.m1": 6.0, "robot.I4": 1.5}, _set("robot", m1=6.0, I4=1.5)),
    "nominal_scale": ({"nominal_scale.I2": 1.3}, _set("nominal_scale", I2=1.3)),
    "gains": ({"gains.kp": 100.0, "gains.kd": [30.0, 31.0, 32.0, 33.0], "gains.observer": ROTATING_Y},
              _set("gains", kp=100.0, kd=[30.0, 31.0, 32.0, 33.0], observer=ROTATING_Y)),
    "observer": ({"observer.variant": "paper-eq16"}, _set("observer", variant="paper-eq16")),
    "trajectory": ({"trajectory.stitches": 3, "trajectory.hover": 0.002}, _set("trajectory", stitches=3, hover=0.002)),
    "trajectory element": ({"trajectory.start[1]": -0.04}, _set("trajectory", start=[0.36, -0.04])),
    "disturbance": ({"disturbance.kind": ["paper", "friction"], "disturbance.coulomb[3]": 0.2},
                    _set("disturbance", kind=["paper", "friction"], coulomb=[0.8, 0.6, 0.5, 0.2])),
    "disturbance element": ({"disturbance.f_r[2]": 1.5},
                            _set("disturbance", f_r=[PAPER_FR[0], PAPER_FR[1], 1.5, PAPER_FR[3]])),
    "element after its list": ({"disturbance.f_r": [1.0, 1.0, 1.0, 1.0], "disturbance.f_r[0]": 2.0},
                               _set("disturbance", f_r=[2.0, 1.0, 1.0, 1.0])),
    "noise": ({"noise.q_std": [1e-4, 1e-4, 1e-5, 1e-4], "noise.seed": 4},
              _set("noise", q_std=[1e-4, 1e-4, 1e-5, 1e-4], seed=4)),
    "initial": ({"initial.q": [0.1, 1.0, 0.2, 0.0], "initial.d_hat": [1.0, 1.0, 1.0, 1.0]},
                _set("initial", q=[0.1, 1.0, 0.2, 0.0], d_hat=[1.0, 1.0, 1.0, 1.0])),
    "simulation": ({"simulation.t_final": 2.0, "simulation.method": "DOP853", "simulation.max_step": 0.01},
                   _set("simulation", t_final=2.0, method="DOP853", max_step=0.01)),
    "several sections": ({"gains.kp": 150.0, "nominal_scale.m1": 0.9, "noise.seed": 2},
                         _both(_set("gains", kp=150.0), _set("nominal_scale", m1=0.9), _set("noise", seed=2))),
}


@pytest.mark.parametrize("case", list(CHANGES))
def test_with_changes_equals_the_file_edited_by_hand(case):
    changes, edit = CHANGES[case]
    paper = load_scenario("paper")
    changed = paper.with_changes(changes)
    assert changed == _file(edit)
    assert changed != paper and paper == load_scenario("paper")     # the base is untouched


def test_with_changes_reaches_the_model_objects():
    s = load_scenario("paper").with_changes({"disturbance.f_r[2]": 1.5, "nominal_scale.I2": 1.3,
                                             "gains.kd": [30.0, 31.0, 32.0, 33.0], "initial.q": [0.1, 1.0, 0.2, 0.0]})
    assert s.disturbance.f_r == (PAPER_FR[0], PAPER_FR[1], 1.5, PAPER_FR[3])
    assert s.nominal.I2 == pytest.approx(1.3 * s.robot.I2) and s.nominal.I1 == s.robot.I1
    np.testing.assert_array_equal(np.diag(s.kd), [30.0, 31.0, 32.0, 33.0])
    np.testing.assert_array_equal(s.initial["q"], [0.1, 1.0, 0.2, 0.0])
    assert s.initial["dq"] is None


def test_with_changes_derives_defaults_again():
    paper = load_scenario("paper")
    assert paper.with_changes({"simulation.t_final": 2.0}).trajectory.duration == 10.0
    assert paper.with_changes({"disturbance.skin_height": -0.35}).trajectory.skin_height == -0.35
    pinned = paper.with_changes({"trajectory.duration": 8.0}).with_changes({"simulation.t_final": 2.0})
    assert pinned.trajectory.duration == 8.0 and pinned.simulation.t_final == 2.0
    # t_final never rescales the path, whatever was changed before
    assert paper.with_changes({"gains.kp": 100.0}).with_changes({"simulation.t_final": 4.0}).trajectory.duration == 10.0


def test_a_new_trajectory_kind_starts_the_section_afresh():
    held = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.0] * 4, "trajectory.omega": 1.0,
            "trajectory.offset": [0.3, 2.0, 0.24, 0.1]}
    by_hand = _file(lambda d: d.update(trajectory={"kind": "joint_sine", "amplitude": [0.0] * 4, "omega": 1.0,
                                                   "offset": [0.3, 2.0, 0.24, 0.1]}))
    assert load_scenario("paper").with_changes(held) == by_hand
    raw = tomllib.loads((resources.files("blocks") / "scenarios" / "joint-sine.toml").read_text(encoding="utf-8"))
    back = load_scenario("joint-sine").with_changes({"trajectory.kind": "laceration"})
    expected = copy.deepcopy(raw)
    expected["trajectory"] = {"kind": "laceration"}
    assert back.data == scenario_from_dict(expected, source="joint-sine").data
    assert back.trajectory.duration == 10.0 and back.trajectory.stitches == 5          # LacerationPath defaults
    same_kind = load_scenario("paper").with_changes({"trajectory.kind": "laceration"})
    assert same_kind.trajectory.stitches == 5 and same_kind.data == load_scenario("paper").data


def test_replace_is_with_changes_by_section():
    paper = load_scenario("paper")
    assert paper.replace(gains={"kp": 100.0}, name="x") == paper.with_changes({"gains.kp": 100.0, "name": "x"})
    assert paper.with_changes({}) is paper


BAD_CHANGES = {
    "bad value": ({"gains.kp": -1.0}, ["'gains.kp'", "> 0"]),
    "unknown section": ({"gain.kp": 1.0}, ["'gain.kp'", "no section [gain]"]),
    "a whole section": ({"gains": 1.0}, ["'gains'", "section.key"]),
    "unknown key": ({"robot.mass": 1.0}, ["robot.mass"]),
    "key of another trajectory kind": ({"trajectory.amplitude": [0.1] * 4}, ["trajectory.amplitude", "laceration"]),
    "element out of range": ({"disturbance.f_r[7]": 1.0}, ["'disturbance.f_r[7]'", "element 7", "a list of 4"]),
    "bad element value": ({"disturbance.f_r[1]": "x"}, ["'disturbance.f_r[1]'", "'x'"]),
    "malformed element": ({"disturbance.f_r[x]": 1.0}, ["disturbance.f_r[x]"]),
    "element of a number": ({"gains.kp[0]": 1.0}, ["'gains.kp[0]'", "not a list"]),
    "element of a value not given": ({"initial.q[0]": 0.1}, ["'initial.q[0]'", "not given"]),
    "derived check": ({"simulation.t_final": 1.0, "simulation.output_step": 0.3}, ["simulation.output_step"]),
}


@pytest.mark.parametrize("case", list(BAD_CHANGES))
def test_bad_changes_name_the_dotted_key(case):
    changes, fragments = BAD_CHANGES[case]
    with pytest.raises(ScenarioError) as err:
        load_scenario("paper").with_changes(changes)
    message = str(err.value)
    assert message.startswith("paper: ") and message.count("paper: ") == 1, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_changes_must_be_a_mapping():
    with pytest.raises(ScenarioError, match="mapping of dotted keys"):
        load_scenario("paper").with_changes([("gains.kp", 100.0)])


def test_batch_members_are_the_files_edited_by_hand():
    paper = load_scenario("paper")
    records = [{"gains.kp": 120.0, "disturbance.f_r[2]": 1.0},
               {"nominal_scale.m1": 1.2, "noise.seed": 5, "noise.q_std": [1e-4, 1e-4, 1e-5, 1e-4]},
               {"observer.variant": "paper-eq16", "gains.observer": ROTATING_Y, "initial.d_hat": [0.5] * 4}]
    by_hand = [_set("gains", kp=120.0), _set("disturbance", f_r=[PAPER_FR[0], PAPER_FR[1], 1.0, PAPER_FR[3]]),
               _both(_set("nominal_scale", m1=1.2), _set("noise", seed=5, q_std=[1e-4, 1e-4, 1e-5, 1e-4])),
               _both(_set("observer", variant="paper-eq16"), _set("gains", observer=ROTATING_Y),
                     _set("initial", d_hat=[0.5] * 4))]
    v = Variants(paper, records)
    assert v.scenario(0) == _file(_both(by_hand[0], by_hand[1]))
    assert v.scenario(1) == _file(by_hand[2])
    assert v.scenario(2) == _file(by_hand[3])
    # the batch's own arrays hold the same values
    np.testing.assert_array_equal(v.kp[:, 0], [120.0] * 4)
    np.testing.assert_array_equal(v.disturbance.f_r[0], [PAPER_FR[0], PAPER_FR[1], 1.0, PAPER_FR[3]])
    np.testing.assert_array_equal(v.disturbance.f_r[1], PAPER_FR)
    assert v.nominals[1].m1 == pytest.approx(1.2 * paper.robot.m1) and v.robots[1] == paper.robot
    assert v.noises[0] is None and v.noises[1].seed == 5 and v.noises[1].q_std == (1e-4, 1e-4, 1e-5, 1e-4)
    np.testing.assert_array_equal(v.extra, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(v.y_full[:, :, 2], ROTATING_Y)
    np.testing.assert_array_equal(v.y_full[:, :, 0], 10.0 * np.eye(4))
    np.testing.assert_array_equal(v.initial[2]["d_hat"], [0.5] * 4)
    assert v.initial[0]["d_hat"] is None


def test_batch_element_keys_are_refused_out_of_range_and_outside_the_batch():
    paper = load_scenario("paper")
    with pytest.raises(ScenarioError, match=r"variant 1: 'disturbance.f_r\[4\]' indexes element 4"):
        Variants(paper, [{}, {"disturbance.f_r[4]": 1.0}])
    with pytest.raises(ScenarioError, match=r"variant 0: key\(s\) \['trajectory.start'\] cannot vary"):
        Variants(paper, [{"trajectory.start[0]": 0.4}])


def test_module_examples_run():
    assert doctest.testmod(blocks.scenarios.scenario).failed == 0


@needs_pinocchio
def test_a_scenario_with_a_relative_urdf_path_changes_after_the_working_folder_does(tmp_path, monkeypatch):
    # scenario_from_dict with urdf = "arm.urdf" read the file; after os.chdir, with_changes read the user's data
    # again, relative to the new folder: "URDF file 'arm.urdf' does not exist"
    import blocks
    _urdf(tmp_path, TWO)
    data = {"arm": {"urdf": "arm.urdf", "tool_frame": "rod"}, "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
            "trajectory": {"kind": "joint_sine"}, "simulation": {"t_final": 0.1, "output_step": 0.01}}
    monkeypatch.chdir(tmp_path)
    s = blocks.scenario_from_dict(data)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    changed = s.with_changes({"gains.kp": 100})
    assert changed.robot is s.robot and float(changed.kp[0, 0]) == 100.0
    assert changed.data["arm"]["urdf"] == str(tmp_path / "arm.urdf")
    with pytest.raises(blocks.ScenarioError, match=r"URDF file .*other.urdf' does not exist"):
        s.with_changes({"arm.urdf": "other.urdf"})      # a path given now is relative to the folder of now
