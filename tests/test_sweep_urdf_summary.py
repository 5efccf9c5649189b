"""A sweep over a URDF arm that is not built in: its summary, rebuilt from the results file alone, names the
arm's joints and gives their units.

The scenario is written to a temporary folder with a copy of scope4's URDF
under another name, so the summary cannot find the arm among the built-in
scenarios: it must read it from the results file's header.
"""
from __future__ import annotations

import json
import re
import shutil

import pytest

pytest.importorskip("pinocchio")

from analysis.sweep.runner import read_header, read_results, run_sweep  # noqa: E402
from analysis.sweep.spec import load_sweep  # noqa: E402
from analysis.sweep.summary import column_label, column_unit, key_name, key_unit, summarize, write_summary  # noqa: E402
from blocks.model.urdf.examples import scope4_urdf  # noqa: E402

pytestmark = pytest.mark.slow

# scope4's joints, written again here (blocks/model/urdf/data/scope4.urdf)
NAMES = ["yaw", "pitch", "insertion", "roll"]
POSITION_UNITS = ["rad", "rad", "m", "rad"]
FORCE_UNITS = ["N m", "N m", "N", "N m"]

SCENARIO = """name = "my-arm"
[arm]
urdf = "my_arm.urdf"
tool_frame = "tool_tip"
nominal_mass_scale = 1.05
[gains]
kp = 180
kd = 36
observer_bandwidth = 10.0
[trajectory]
kind = "joint_sine"
amplitude = [0.3, 0.2, 0.03, 0.8]
omega = [0.8, 1.1, 1.5, 2.0]
offset = [0.0, 0.1, 0.1, 0.0]
[disturbance]
kind = "step"
f_r = [0.05, 0.1, 0.4, 0.00002]
[simulation]
t_final = 0.1
output_step = 0.005
"""

SWEEP = """name = "my-arm-sweep"
scenario = "my_arm.toml"
engine = "fast"
[grid]
"disturbance.f_r[2]" = [0.2, 0.6]
[outputs]
metrics = ["rms_position_error", "max_tool_position_error_mm"]
worst_metric = "max_tool_position_error_mm"
worst_count = 2
"""


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    folder = tmp_path_factory.mktemp("my_arm")
    shutil.copy(scope4_urdf(), folder / "my_arm.urdf")
    (folder / "my_arm.toml").write_text(SCENARIO)
    (folder / "sweep.toml").write_text(SWEEP)
    path = folder / "results.jsonl"
    run_sweep(load_sweep(folder / "sweep.toml"), path)
    return path


def test_the_results_header_keeps_the_joints(results):
    joints = read_header(results)["joints"]
    assert joints == {"names": NAMES, "kinds": ["revolute", "revolute", "prismatic", "revolute"],
                      "position_units": POSITION_UNITS, "force_units": FORCE_UNITS}
    _, rows = read_results(results)
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows)
    assert all(len(r["metrics"]["rms_position_error"]) == 4 for r in rows)


def test_a_summary_from_the_results_file_alone_names_the_arms_joints(results, tmp_path):
    summary = summarize(results)                       # no sweep file: the arm comes from the header
    assert summary.joints["names"] == NAMES
    joints = summary.arm_joints
    assert [column_unit(f"rms_position_error[{i}]", joints) for i in range(4)] == POSITION_UNITS
    assert column_label("rms_position_error[2]", joints).endswith("(insertion)")
    assert key_name("disturbance.f_r[2]", joints).endswith("(insertion)")
    assert key_unit("disturbance.f_r[2]", joints) == "N"
    files = write_summary(results, tmp_path / "summary")
    text = files["markdown"].read_text()
    # as words: the sweep's hex id may hold "d3" (it did: fe7f2fd37ac664e5)
    assert "insertion" in text and not re.search(r"\b(d3|theta\d)\b", text)
    assert json.loads(files["json"].read_text())["joints"]["names"] == NAMES


def test_a_header_without_the_joints_falls_back_as_before(results):
    """A results file written before the header kept the joints, of a scenario that is not built in: the
    paper's joints (what summaries did before), so the header entry is what names scope4's joints above."""
    header, rows = read_results(results)
    old = {k: v for k, v in header.items() if k != "joints"}
    assert summarize((old, rows)).joints["names"] == ["theta1", "theta2", "d3", "theta4"]


def test_urdf_scenario_keys_have_units():
    joints = summarize.__globals__["_arm_joints"]({"names": NAMES, "kinds": ["revolute", "revolute", "prismatic",
                                                                              "revolute"]})
    assert key_unit("gains.observer_bandwidth", joints) == "rad/s"
    assert key_unit("arm.nominal_mass_scale", joints) == "factor"
    assert key_unit("gains.observer[2]", joints) == "kg/s" and key_unit("gains.observer[1]", joints) == "kg m^2/s"
    assert key_unit("gains.observer", joints) == "kg m^2/s or kg/s"


def test_the_paper_arm_read_back_from_a_header_keeps_its_robot_units():
    from analysis.sweep.spec import joints_record
    from blocks.model.rrpr.joints import RRPR_JOINTS
    joints = summarize.__globals__["_joints_of_header"]({"joints": joints_record(RRPR_JOINTS), "scenario": "x.toml"})
    assert joints is RRPR_JOINTS
    assert key_unit("robot.m3", joints) == "kg" and key_unit("gains.observer", joints) == "kg m^2/s"
