"""The scenario's [arm] section and the per-joint keys checked against the arm: both sides of each rule."""
from __future__ import annotations

import shutil
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from blocks.scenarios.scenario import ScenarioError, load_scenario, scenario_from_dict, to_toml

pytest.importorskip("pinocchio")

SCOPE4 = {"urdf": "example:scope4", "tool_frame": "tool_tip"}


def _scope4(**sections):
    data = {"arm": dict(SCOPE4)}
    for key, value in sections.items():
        data[key] = value
    return scenario_from_dict(data)


def test_without_arm_the_scenario_is_the_papers_rrpr():
    s = load_scenario("paper")
    assert "arm" not in s.data and s.arm_name == "rrpr"
    assert s.robot.joints.names == ("theta1", "theta2", "d3", "theta4")
    assert s.data["disturbance"]["f_r"] == [1.43, 1.6, 1.4, 1.2] and s.data["trajectory"]["kind"] == "laceration"


def test_an_arm_section_loads_the_urdf_with_its_joints_and_defaults():
    s = _scope4()
    assert s.robot.joints.names == ("yaw", "pitch", "insertion", "roll") and s.arm_name == "scope4"
    assert s.kp.shape == (4, 4) and s.trajectory.n == 4
    assert s.data["trajectory"]["kind"] == "joint_sine" and s.data["disturbance"]["kind"] == "none"
    assert "robot" not in s.data and "nominal_scale" not in s.data
    assert s.nominal is s.robot                       # nominal_mass_scale defaults to 1


def test_urdf_path_is_relative_to_the_scenario_file(tmp_path):
    from blocks.model.urdf import scope4_urdf
    (tmp_path / "arms").mkdir()
    shutil.copy(scope4_urdf(), tmp_path / "arms" / "mine.urdf")
    path = tmp_path / "s.toml"
    path.write_text(to_toml({"name": "mine", "arm": {"urdf": "arms/mine.urdf", "tool_frame": "tool_tip"}}))
    assert load_scenario(path).robot.joints.count == 4
    path.write_text(to_toml({"name": "mine", "arm": {"urdf": "mine.urdf", "tool_frame": "tool_tip"}}))
    with pytest.raises(ScenarioError, match=r"\[arm\] urdf = 'mine.urdf'.*does not exist"):
        load_scenario(path)


@pytest.mark.parametrize("arm, fragment", [
    ({"tool_frame": "tool_tip"}, "'arm.urdf' is required"),
    # a URDF file needs its tool frame (an example arm by name has a default: tests/test_example_arms.py)
    ({"urdf": str(Path(__file__).parent / "small_arms" / "two_joints.urdf")}, "'arm.tool_frame' is required"),
    (SCOPE4 | {"tool_frame": "no_such_frame"}, "no_such_frame"),
    (SCOPE4 | {"locked": ["no_such_joint"]}, "no_such_joint"),
    (SCOPE4 | {"locked": ["roll"], "locked_values": [0.1, 0.2]}, "'arm.locked_values' has 2 values for 1"),
    (SCOPE4 | {"nominal_mass_scale": 0.0}, "'arm.nominal_mass_scale' must be > 0"),
    (SCOPE4 | {"gravity": [0.0, 9.81]}, "'arm.gravity' must be a number"),
    (SCOPE4 | {"colour": "red"}, "arm.colour"),
])
def test_bad_arm_keys_are_refused_by_name(arm, fragment):
    with pytest.raises(ScenarioError, match=fragment):
        scenario_from_dict({"arm": arm})


def test_locked_joint_leaves_the_arm_and_its_value_moves_the_tool():
    free = _scope4()
    held = scenario_from_dict({"arm": SCOPE4 | {"locked": ["roll"]}})
    turned = scenario_from_dict({"arm": SCOPE4 | {"locked": ["insertion"], "locked_values": [0.1]}})
    assert held.robot.joints.names == ("yaw", "pitch", "insertion")
    q = np.zeros(3)
    # insertion held at 0.1 m: the tool point is where the free arm puts it with insertion = 0.1 m
    np.testing.assert_allclose(turned.robot.tool_position(q), free.robot.tool_position([0, 0, 0.1, 0]), atol=1e-12)


def test_gravity_key_sets_the_arms_gravity():
    q = np.array([0.0, 0.3, 0.1, 0.0])
    g0 = scenario_from_dict({"arm": SCOPE4 | {"gravity": 0.0}}).robot.gravity_forces(q)
    g = _scope4().robot.gravity_forces(q)
    g_half = scenario_from_dict({"arm": SCOPE4 | {"gravity": [0.0, 0.0, -9.81 / 2]}}).robot.gravity_forces(q)
    np.testing.assert_allclose(g0, 0.0, atol=1e-12)
    assert np.abs(g).max() > 0.1
    np.testing.assert_allclose(g_half, g / 2, rtol=1e-12, atol=1e-12)


def test_nominal_mass_scale_scales_the_nominal_dynamics_only():
    s = scenario_from_dict({"arm": SCOPE4 | {"nominal_mass_scale": 1.2}})
    q, dq = np.array([0.2, -0.3, 0.08, 0.5]), np.array([0.4, -0.2, 0.05, 1.0])
    np.testing.assert_allclose(s.nominal.inertia(q), 1.2 * s.robot.inertia(q), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(s.nominal.bias(q, dq), 1.2 * s.robot.bias(q, dq), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(s.robot.inertia(q), _scope4().robot.inertia(q), rtol=0, atol=0)


@pytest.mark.parametrize("section, key, good, bad", [
    ("gains", "kp", [100, 120, 140, 160], [100, 120, 140]),
    ("gains", "kd", 30, [30] * 7),
    ("gains", "observer", [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 4.0, 0], [0, 0, 0, 0.02]], [[1.0, 0], [0, 1.0]]),
    ("trajectory", "amplitude", [0.1, 0.1, 0.01, 0.1], [0.1, 0.1]),
    ("trajectory", "offset", [0.0, 0.0, 0.1, 0.0], [0.0] * 5),
    ("initial", "q", [0.0, 0.0, 0.1, 0.0], [0.0, 0.0, 0.1]),
    ("initial", "dq", [0.0] * 4, [0.0] * 6),
])
def test_per_joint_keys_have_n_values_and_the_message_names_key_n_and_arm(section, key, good, bad):
    ok = _scope4(**{section: {key: good}})
    assert ok.data[section][key] is not None
    with pytest.raises(ScenarioError) as err:
        _scope4(**{section: {key: bad}})
    text = str(err.value)
    assert f"'{section}.{key}'" in text and "scope4" in text and "4 joints" in text, text


def test_disturbance_step_takes_n_values():
    s = _scope4(disturbance={"kind": "step", "f_r": [0.1, 0.2, 0.3, 0.001]})
    assert s.disturbance.f_r == (0.1, 0.2, 0.3, 0.001) and "coulomb" not in s.data["disturbance"]
    with pytest.raises(ScenarioError, match=r"'disturbance.f_r' has 3 values; the arm 'scope4' has 4 joints"):
        _scope4(disturbance={"kind": "step", "f_r": [0.1, 0.2, 0.3]})
    with pytest.raises(ScenarioError, match=r"'disturbance.coulomb' has 3 values; the arm 'scope4' has 4 joints"):
        _scope4(disturbance={"kind": "friction", "coulomb": [0.1, 0.1, 0.1]})
    friction = _scope4(disturbance={"kind": "friction", "coulomb": [0.1] * 4, "viscous": [0.2] * 4})
    assert friction.disturbance.kinds == ("friction",)


@pytest.mark.parametrize("data, fragment", [
    # a laceration on another arm is its tool point's (tests/test_suture_any_arm.py): its ends have no default
    ({"trajectory": {"kind": "laceration"}}, "'trajectory.start' and 'trajectory.end' required for kind = "
                                             "'laceration' on the arm 'scope4'"),
    ({"robot": {"m1": 5.0}}, r"\[robot\] \(robot.m1\) describes the paper's RRPR"),
    # [nominal_scale] of a URDF arm is by link (tests/test_suture_any_arm.py)
    ({"nominal_scale": {"m1": 1.1}}, r"nominal_scale.m1; allowed in \[nominal_scale\]: yaw_link, pitch_link"),
])
def test_rrpr_only_sections_are_refused_for_another_arm_and_kept_for_the_rrpr(data, fragment):
    with pytest.raises(ScenarioError, match=fragment):
        scenario_from_dict({"arm": SCOPE4} | data)
    scenario_from_dict(data)                    # the paper's RRPR takes them


def test_the_tissue_contact_is_taken_for_another_arm_with_its_skin_at_the_start():
    # the refusal is gone (tests/test_tissue_any_arm.py checks the forces): the plane defaults to the tool
    # height at the reference's start, and a given plane is kept
    s = scenario_from_dict({"arm": SCOPE4, "disturbance": {"kind": "tissue"}})
    z0 = s.robot.tool_position(s.trajectory.evaluate(0.0)[0])[2]
    assert s.disturbance.kinds == ("tissue",) and s.disturbance.skin_height == z0
    assert s.data["disturbance"]["skin_height"] == z0
    given = scenario_from_dict({"arm": SCOPE4, "disturbance": {"kind": "tissue", "skin_height": -0.2}})
    assert given.disturbance.skin_height == -0.2


def test_controller_and_noise_are_taken_for_another_arm():
    # (tests/test_arm_digital.py runs them)
    s = scenario_from_dict({"arm": SCOPE4, "controller": {"sample_rate": 1000.0}, "noise": {"q_std": [1e-4] * 4}})
    assert s.controller.joints == s.robot.joints and s.controller.torque_limit == (0.0,) * 4
    assert s.noise.q_std == (1e-4,) * 4 and s.noise.table.shape[0] == 8


def test_observer_bandwidth_gives_y_equal_omega_times_the_nominal_inertia_at_the_start():
    s = scenario_from_dict({"arm": SCOPE4 | {"nominal_mass_scale": 1.1}, "gains": {"observer_bandwidth": 8.0},
                            "initial": {"q": [0.1, -0.2, 0.05, 0.3]}})
    q0 = np.array([0.1, -0.2, 0.05, 0.3])
    np.testing.assert_allclose(s.observer_gain, 8.0 * 1.1 * s.robot.inertia(q0), rtol=1e-12, atol=1e-15)
    assert "observer" not in s.data["gains"] and s.data["gains"]["observer_bandwidth"] == 8.0
    # without initial.q: the reference at t = 0
    r = _scope4(gains={"observer_bandwidth": 8.0})
    np.testing.assert_allclose(r.observer_gain, 8.0 * r.robot.inertia(r.trajectory.evaluate(0.0)[0]), rtol=1e-12)
    # the RRPR takes it too
    p = scenario_from_dict({"gains": {"observer_bandwidth": 5.0}})
    np.testing.assert_allclose(p.observer_gain, 5.0 * p.nominal.inertia(p.trajectory.evaluate(0.0)[0]), rtol=1e-12)


def test_observer_and_observer_bandwidth_together_are_refused_by_name():
    with pytest.raises(ScenarioError, match=r"'gains.observer' \(10\) and 'gains.observer_bandwidth'"):
        _scope4(gains={"observer": 10, "observer_bandwidth": 8.0})
    with pytest.raises(ScenarioError, match="'gains.observer_bandwidth' must be > 0"):
        _scope4(gains={"observer_bandwidth": 0.0})


def test_a_urdf_scenario_round_trips_through_toml_and_with_changes(tmp_path):
    s = _scope4(disturbance={"kind": "step", "f_r": [0.1, 0.2, 0.3, 0.001]}, gains={"observer_bandwidth": 8.0})
    path = tmp_path / "again.toml"
    path.write_text(s.to_toml())
    again = load_scenario(path)
    assert again.data == s.data | {"name": "<dict>"} or again.data["arm"] == s.data["arm"]
    np.testing.assert_array_equal(again.observer_gain, s.observer_gain)
    changed = s.with_changes({"gains.kp": [100, 110, 120, 130], "disturbance.f_r[1]": 0.5})
    assert changed.disturbance.f_r[1] == 0.5 and float(changed.kp[3, 3]) == 130.0
    with pytest.raises(ScenarioError, match="'gains.kp' has 2 values; the arm 'scope4' has 4 joints"):
        s.with_changes({"gains.kp": [100, 110]})


@pytest.mark.parametrize("name, n", [("scope4", 4), ("ur5", 6), ("panda", 7)])
def test_builtin_urdf_scenarios_load_with_their_joint_counts(name, n):
    if name != "scope4":
        try:
            metadata.distribution("example-robot-data")
        except metadata.PackageNotFoundError:
            pytest.skip("example-robot-data is the extra dobkit[urdf]")
    s = load_scenario(name)
    assert s.robot.joints.count == n and s.kp.shape == (n, n) and len(s.disturbance.f_r) == n
    assert "observer_bandwidth" in s.data["gains"]
    if name == "panda":
        assert not any("finger" in j for j in s.robot.joints.names)


def test_dobkit_simulate_runs_a_urdf_scenario_and_writes_metrics_per_joint(tmp_path):
    """``dobkit simulate`` on a URDF scenario file: metrics.json has the arm's joint names, units and n values."""
    import json

    from dobkit.cli import main
    path = tmp_path / "scope4-short.toml"
    path.write_text(to_toml({"name": "scope4-short", "arm": {"urdf": "example:scope4", "tool_frame": "tool_tip"},
                             "gains": {"observer_bandwidth": 10.0},
                             "disturbance": {"kind": "step", "f_r": [0.05, 0.1, 0.4, 0.00002]},
                             "simulation": {"t_final": 1.0, "output_step": 0.01}}))
    out = tmp_path / "out"
    assert main(["simulate", "--scenario", str(path), "--out", str(out), "--engine", "fast", "--no-figures"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["joints"] == ["yaw", "pitch", "insertion", "roll"]
    assert m["units"] == {"position": ["rad", "rad", "m", "rad"], "disturbance": ["N m", "N m", "N", "N m"]}
    assert all(len(m[run]["rms_position_error"]) == 4 for run in ("with_dob", "without_dob"))
    # the written scenario runs again to the same settings
    assert load_scenario(out / "scenario.toml").data["arm"] == load_scenario(path).data["arm"]
