"""Tuning and sweep summaries of an arm that is not the paper's: n, names and units from the base scenario's arm.

The arm is the built-in ``scope4`` (a URDF arm: yaw, pitch, insertion, roll; the insertion prismatic), on a
half-second run so that a tuning of a few evaluations takes seconds on the numpy batch engine; the UR5 (6 joints)
shows that a per-joint key is sized by the arm, not by the paper's four.  The paper's messages stay as they were.
"""
from __future__ import annotations

import json
import math
from importlib import resources

import numpy as np
import pytest
from two_joint_arm import needs_pinocchio

from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import load_sweep
from analysis.sweep.summary import column_label, column_unit, key_name, key_unit, summarize, write_summary
from analysis.tune.report import html_section
from analysis.tune.runner import RESULT_NAME, run_tune
from analysis.tune.spec import TuneError, damping_ratios, tuning_from_dict
from blocks import load_scenario, simulate
from blocks.figure2.batch import METRIC_ATOL, METRIC_RTOL
from blocks.figure2.metrics import tracking_metrics
from blocks.model.joints import JointSpace
from dobkit.tune_commands import constraint_lines

SCOPE4_NAMES = ["yaw", "pitch", "insertion", "roll"]
SCOPE4_FORCE_UNITS = ["N m", "N m", "N", "N m"]
SCOPE4_POSITION_UNITS = ["rad", "rad", "m", "rad"]


@pytest.fixture(scope="module")
def short_scope4(tmp_path_factory):
    """The built-in scope4 scenario cut to 0.5 s, as a file (its URDF is the package's)."""
    folder = tmp_path_factory.mktemp("scope4")
    text = (resources.files("blocks") / "scenarios" / "scope4.toml").read_text(encoding="utf-8")
    assert "t_final = 10.0" in text and 'name = "scope4"' in text
    text = text.replace("t_final = 10.0", "t_final = 0.5").replace("output_step = 0.005", "output_step = 0.01")
    (folder / "scope4-short.toml").write_text(text.replace('name = "scope4"', 'name = "scope4-short"'))
    return folder


def _tuning(**changes) -> dict:
    data = {"name": "scope4-tune", "scenario": "scope4-short.toml",
            "search": {"gains.kp": [50, 1000], "gains.kd": [[5, 80], [5, 80], [5, 80], [5, 80]], "population": 5,
                       "max_evaluations": 12, "polish_evaluations": 2},
            "constraints": {"torque_noise_rms": "base", "torque_limit": [40, 40, 10, 40], "stability_margin": 0.1},
            "monte_carlo": {"runs": 2, "seed": 1, "distributions": {
                "disturbance.f_r[2]": {"kind": "uniform", "low": 0.2, "high": 0.6}}}}
    for key, value in changes.items():
        section, _, name = key.partition(".")
        data[section][name] = value
    return data


def _spec(folder, **changes):
    return tuning_from_dict(_tuning(**changes), source=str(folder / "scope4-tune.toml"), folder=folder)


@pytest.fixture(scope="module")
def tuned(short_scope4):
    out = short_scope4 / "out"
    result = run_tune(_spec(short_scope4), out, workers=1, progress=False, engine="fast")
    return short_scope4, out, result


def test_a_scope4_tuning_writes_one_entry_per_joint_of_the_arm(tuned):
    _, out, result = tuned
    data = json.loads((out / RESULT_NAME).read_text())
    assert data["joints"] == SCOPE4_NAMES and data["force_units"] == SCOPE4_FORCE_UNITS
    assert data["parameters"] == ["gains.kp"] + [f"gains.kd[{j}]" for j in range(4)]
    for point in (data["base"], data["tuned"]):
        assert len(point["torque_noise_rms"]) == len(point["peak_torque"]) == len(point["damping_ratio"]) == 4
        # the damping ratio of e'' + kd e' + kp e = 0, from the point's own gains
        kp, kd = point["gains"]["gains.kp"], point["gains"]["gains.kd"]
        kp = np.full(4, kp) if np.ndim(kp) == 0 else np.asarray(kp)
        kd = np.full(4, kd) if np.ndim(kd) == 0 else np.asarray(kd)
        np.testing.assert_allclose(point["damping_ratio"], kd / (2 * np.sqrt(kp)), rtol=1e-12)
    assert len(data["limits"]["torque_noise_rms"]) == 4 and data["limits"]["torque_limit"] == [40, 40, 10, 40]
    # the base gains' own noise is the budget ("base"): the base point meets it exactly
    np.testing.assert_allclose(data["base"]["torque_noise_rms"], data["limits"]["torque_noise_rms"], rtol=1e-12)
    # the set's worst peak torque is a real peak of the simulated arm: at least the base scenario's own peak
    assert result.feasible == all(np.asarray(data["tuned"]["peak_torque"]) <= [40, 40, 10, 40])


def test_the_tuned_scope4_file_reproduces_its_nominal_metric(tuned):
    _, out, result = tuned
    scenario = load_scenario(out / result.scenario_file)
    assert scenario.robot.joints.names == tuple(SCOPE4_NAMES)
    alone = tracking_metrics(simulate(scenario))["rms_tool_position_error_mm"]     # adaptive RK45, one run
    assert alone == pytest.approx(result.tuned.nominal, rel=METRIC_RTOL, abs=METRIC_ATOL)


def test_the_tuning_report_names_the_arms_joints_and_units(tuned):
    _, out, _ = tuned
    section = html_section(out)
    assert "torque noise RMS [N m, N m, N, N m]" in section
    assert "N m; N for the prismatic joint insertion" in section
    assert "(d3)" not in section and "theta" not in section


@pytest.mark.parametrize("key, value", [("constraints.torque_limit", [40, 40, 10]),
                                        ("constraints.torque_noise_rms", [1, 1, 1])])
def test_a_per_joint_constraint_of_three_values_is_refused_naming_four_and_the_arm(short_scope4, key, value):
    with pytest.raises(TuneError) as err:
        _spec(short_scope4, **{key: value})
    text = str(err.value)
    assert f"'{key}' must be" in text and "4 numbers > 0 (N m, N m, N, N m)" in text
    assert "the arm 'scope4'" in text and "yaw, pitch, insertion, roll" in text and repr(value) in text


def test_per_joint_bounds_and_sensor_noise_of_three_are_refused_naming_four_and_the_arm(short_scope4):
    with pytest.raises(TuneError) as err:
        _spec(short_scope4, **{"search.gains.kd": [[5, 80]] * 3})
    text = str(err.value)
    assert "search.\"gains.kd\" gives 3 bounds" in text and "the arm 'scope4' has 4 joints" in text
    assert "yaw, pitch, insertion, roll" in text
    with pytest.raises(TuneError) as err:
        _spec(short_scope4, **{"constraints.sensor_noise": {"q_std": [1e-4] * 3}})
    text = str(err.value)
    assert "'constraints.sensor_noise.q_std' must be 4 numbers >= 0 (rad, rad, m, rad)" in text
    assert "the arm 'scope4'" in text and "[0.0001, 0.0001, 0.0001]" in text


def test_a_scalar_or_four_values_per_joint_key_is_taken(short_scope4):
    spec = _spec(short_scope4, **{"constraints.torque_limit": 7.0,
                                  "constraints.sensor_noise": {"q_std": [1e-4, 1e-4, 1e-5, 1e-4]}})
    assert spec.n == 4 and spec.limits.torque_limit.tolist() == [7.0] * 4
    assert spec.limits.sensor_noise["q_std"] == [1e-4, 1e-4, 1e-5, 1e-4]
    assert spec.configurations.shape[1] == 4


def test_a_six_joint_arm_sizes_the_per_joint_keys():
    data = {"name": "ur5-tune", "scenario": "ur5",
            "search": {"gains.kp": [50, 1000], "population": 5, "max_evaluations": 12},
            "constraints": {"torque_limit": [150, 150, 150, 28, 28, 28]}}
    spec = tuning_from_dict(data)
    joints = load_scenario("ur5").robot.joints
    assert spec.n == 6 and spec.limits.torque_limit.tolist() == [150, 150, 150, 28, 28, 28]
    assert spec.limits.torque_noise_rms is None and spec.configurations.shape[1] == 6
    data["constraints"]["torque_limit"] = [40, 40, 10, 40]
    with pytest.raises(TuneError, match=r"6 numbers > 0 \(N m, N m, N m, N m, N m, N m\), one per joint of the "
                                        r"arm 'ur5' \(" + ", ".join(joints.names)):
        tuning_from_dict(data)


def test_a_ur5_tuning_runs_on_six_joints(tmp_path):
    text = (resources.files("blocks") / "scenarios" / "ur5.toml").read_text(encoding="utf-8")
    assert "t_final = 10.0" in text
    (tmp_path / "ur5-short.toml").write_text(text.replace("t_final = 10.0", "t_final = 0.3")
                                             .replace("output_step = 0.005", "output_step = 0.01"))
    data = _tuning()
    data["scenario"] = "ur5-short.toml"
    data["search"]["gains.kd"] = [[5, 80]] * 6
    data["constraints"] = {"torque_noise_rms": "base", "torque_limit": [150, 150, 150, 28, 28, 28],
                           "sensor_noise": {"q_std": [1e-4] * 6, "dq_std": [1e-3] * 6, "sample_period": 0.001}}
    spec = tuning_from_dict(data, source=str(tmp_path / "t.toml"), folder=tmp_path)
    result = run_tune(spec, tmp_path / "out", workers=1, progress=False, engine="fast")
    names = list(load_scenario("ur5").robot.joints.names)
    assert result.joints == names and result.force_units == ["N m"] * 6
    assert len(result.tuned.torque_noise_rms) == len(result.tuned.peak_torque) == 6
    # the base gains kp = 180, kd = 36: zeta = 36 / (2 sqrt(180)) on every joint
    np.testing.assert_allclose(result.base.damping_ratio, np.full(6, 36 / (2 * math.sqrt(180))), rtol=1e-12)
    assert "torque noise RMS [N m, N m, N m, N m, N m, N m]" in html_section(tmp_path / "out")
    lines = "\n".join(constraint_lines(result))            # what `dobkit tune` prints
    assert "torque noise RMS [N m, N m, N m, N m, N m, N m]: tuned [" in lines
    assert "peak torque [N m, N m, N m, N m, N m, N m]: tuned [" in lines


def test_damping_ratios_take_the_joint_count():
    # kd / (2 sqrt(kp)) = 0.5 for kp = 100, kd = 10, on each of six joints
    np.testing.assert_allclose(damping_ratios(100.0, 10.0, 6), np.full(6, 0.5))
    np.testing.assert_allclose(damping_ratios([100.0, 400.0], 10.0), [0.5, 0.25])
    assert damping_ratios(100.0, 10.0).shape == (4,)                 # the paper's RRPR by default


def test_the_paper_tunings_messages_are_as_they_were():
    data = {"name": "p", "scenario": "paper", "search": {"gains.kp": [50, 1000]}, "constraints": {"torque_limit": [40, 40, 10]}}
    with pytest.raises(TuneError) as err:
        tuning_from_dict(data)
    assert str(err.value) == ("<dict>: 'constraints.torque_limit' must be a number > 0 or 4 numbers > 0 "
                              "(N m, N m, N, N m), got [40, 40, 10]")
    data["constraints"] = {"sensor_noise": {"q_std": [1e-4, 1e-4, 1e-4, -1e-4]}}
    with pytest.raises(TuneError, match=r"q_std"):
        tuning_from_dict(data)


# --------------------------------------------------------------------------------------------
# The sweep summary of scope4
# --------------------------------------------------------------------------------------------
SWEEP = """scenario = "scope4"
[grid]
"simulation.t_final" = [0.3]
"disturbance.f_r[2]" = [0.2, 0.4, 0.6]
[outputs]
metrics = ["rms_position_error", "max_tool_position_error_mm"]
worst_metric = "rms_position_error[2]"
"""


@pytest.fixture(scope="module")
def scope4_sweep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    (folder / "s.toml").write_text(SWEEP)
    spec = load_sweep(folder / "s.toml")
    run_sweep(spec, folder / "r.jsonl", workers=1, progress=False)
    return folder, spec


def test_the_sweep_summary_of_scope4_labels_its_columns_with_the_arms_joints(scope4_sweep):
    folder, spec = scope4_sweep
    files = write_summary(folder / "r.jsonl", folder / "summary", spec=spec, formats=("png",))
    summary = files["summary"]
    assert summary.joints == {"names": SCOPE4_NAMES, "kinds": ["revolute", "revolute", "prismatic", "revolute"]}
    for j, unit in enumerate(SCOPE4_POSITION_UNITS):
        assert summary.statistics[f"rms_position_error[{j}]"].unit == unit
    markdown = files["markdown"].read_text()
    for j, name in enumerate(SCOPE4_NAMES):
        assert f"RMS position error, Joint {j + 1} ({name})" in markdown
    assert "Joint 3 (insertion)" in markdown and "Eq. 4 amplitude f_r, Joint 3 (insertion) [N]" in markdown
    assert "(d3)" not in markdown and "theta" not in markdown
    # read back from summary.json (the report's path): the same arm
    again = json.loads((folder / "summary" / "summary.json").read_text())
    assert again["joints"]["names"] == SCOPE4_NAMES


def test_a_results_file_alone_finds_its_built_in_arm(scope4_sweep):
    folder, spec = scope4_sweep
    alone = summarize(folder / "r.jsonl")                 # no sweep file: the header's built-in scenario
    assert alone.joints == summarize(folder / "r.jsonl", spec=spec).joints
    assert alone.arm_joints.names == tuple(SCOPE4_NAMES)
    # the worst metric is the insertion's RMS error (m): its worst run has the largest step on it (f_r[2])
    worst = alone.worst[0]
    assert worst.values["disturbance.f_r[2]"] == 0.6 and math.isfinite(worst.value)


def test_column_and_key_words_come_from_the_given_joints():
    joints = JointSpace(names=("a", "b"), kinds=("prismatic", "revolute"))
    assert column_label("rms_position_error[1]", joints) == "RMS position error, Joint 2 (b)"
    assert column_unit("rms_position_error[0]", joints) == "m"
    assert column_unit("rms_disturbance_error[1]", joints) == "N m"
    assert key_name("disturbance.f_r[0]", joints) == "Eq. 4 amplitude f_r, Joint 1 (a)"
    assert key_unit("disturbance.f_r[0]", joints) == "N" and key_unit("initial.q[1]", joints) == "rad"
    # the paper's words on the paper's arm, as they were
    paper = load_scenario("paper").robot.joints
    assert column_label("rms_position_error[2]", paper) == "RMS position error, Joint 3 (d3)"
    assert key_unit("disturbance.f_r", paper) == "N m or N" and key_unit("noise.q_std", paper) == "rad or m"
    assert key_unit("robot.I2", paper) == "kg m^2" and key_unit("gains.observer", paper) == "kg m^2/s"


DRAWS = '[monte_carlo.distributions]\n"disturbance.f_r[0]" = {kind = "uniform", low = 0.01, high = 0.1}\n'


@needs_pinocchio
def test_tuning_a_six_joint_arm_without_a_noise_section_takes_the_arms_own_default_noise(tmp_path):
    # the paper's 4-joint default sensor noise was taken for any arm: tuning the UR5 (or the Panda) stopped with
    # "matmul: Input operand 1 has a mismatch in its core dimension 0 ... (size 8 is different from 12)"
    import blocks
    from analysis.simulation.studies import default_noise
    from analysis.tune.evaluate import Evaluator
    from analysis.tune.linear import torque_noise_rms
    from analysis.tune.runner import check_linear_feasibility
    from analysis.tune.spec import load_tuning
    ur5 = blocks.load_scenario("ur5").with_changes({"simulation.t_final": 0.2})
    assert ur5.noise is None
    (tmp_path / "ur5.toml").write_text(ur5.to_toml(), encoding="utf-8")
    path = tmp_path / "t.toml"
    path.write_text('scenario = "ur5.toml"\n[search]\n"gains.kp" = [50, 400]\n[monte_carlo]\nruns = 2\n' + DRAWS,
                    encoding="utf-8")
    spec = load_tuning(path)
    expected = default_noise(ur5.robot.joints)            # six revolute joints: the revolute default six times
    assert spec.limits.sensor_noise["q_std"] == expected["q_std"] and len(expected["q_std"]) == 6
    assert len(set(expected["q_std"])) == 1 and len(set(expected["dq_std"])) == 1
    check_linear_feasibility(spec, Evaluator(spec, workers=1, engine="fast"))      # the matmul error was here
    q0 = np.asarray(ur5.trajectory.evaluate(0.0)[0])
    M, M_hat = ur5.robot.inertia(q0), ur5.nominal.inertia(q0)
    rms = torque_noise_rms(M, M_hat, ur5.kp, ur5.kd, ur5.observer_gain, expected["q_std"], expected["dq_std"], 0.001)
    assert rms.shape == (6,) and np.all(np.isfinite(rms)) and np.all(rms > 0)
