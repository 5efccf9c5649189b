"""``dobkit analyze`` on a URDF arm: its analysis.json checked against pinocchio, read straight from the URDF file.

The reference inertia is pinocchio's ``crba`` on a model built here from
``blocks/model/urdf/data/scope4.urdf`` (not dobkit's arm), scaled by the scenario's
``nominal_mass_scale`` (every mass and inertia times 1.05 scales ``M`` by
1.05); the observer gain of ``observer_bandwidth = 10`` is ``Y = 10 M^(q0)``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks import load_scenario  # noqa: E402
from dobkit.cli import main  # noqa: E402

URDF = Path(__file__).resolve().parents[1] / "blocks" / "model" / "urdf" / "data" / "scope4.urdf"
MASS_SCALE = 1.05          # scope4.toml: nominal_mass_scale
BANDWIDTH = 10.0           # scope4.toml: observer_bandwidth (rad/s)


def _inertia(model, names, q):
    """pinocchio's crba at configurations ``q`` (rows in dobkit's joint order ``names``), symmetric."""
    data = model.createData()
    index = [model.idx_qs[model.getJointId(name)] for name in names]
    out = []
    for row in np.atleast_2d(q):
        q_pin = pin.neutral(model)
        q_pin[index] = row
        m = pin.crba(model, data, q_pin)
        out.append(np.triu(m) + np.triu(m, 1).T)
    return np.array(out)


@pytest.fixture(scope="module")
def analysis_json(tmp_path_factory):
    out = tmp_path_factory.mktemp("scope4") / "analysis"
    assert main(["analyze", "--quick", "--scenario", "scope4", "--out", str(out)]) == 0
    return json.loads((out / "analysis.json").read_text())


def test_observer_bandwidth_on_the_slice_is_eig_of_Y_inverse_M_from_pinocchio(analysis_json):
    model = pin.buildModelFromUrdf(str(URDF))
    names = load_scenario("scope4").robot.joints.names
    bw = analysis_json["observer_bandwidth"]
    k = list(names).index(bw["slice_joint"])
    q = np.tile(bw["q_slice"], (len(bw["theta2"]), 1))
    q[:, k] = bw["theta2"]
    M = MASS_SCALE * _inertia(model, names, q)
    # the scenario's gain: Y = omega M^(q0), q0 the reference at t = 0 (the slice's other joints, its start value)
    q0 = np.array(bw["q_slice"])
    Y_ref = BANDWIDTH * MASS_SCALE * _inertia(model, names, q0)[0]
    assert np.allclose(bw["Y"], Y_ref, rtol=1e-9, atol=1e-12)
    expected = np.sort(np.linalg.eigvals(Y_ref @ np.linalg.inv(M)).real, axis=-1)
    assert np.allclose(bw["eigenvalues"], expected, rtol=1e-8, atol=1e-10)
    # at q0 itself Y M^-1 = omega I: the slice's modes come to the bandwidth where it passes q0
    near = np.argmin(np.abs(np.array(bw["theta2"]) - q0[k]))
    assert np.all(np.abs(np.array(bw["eigenvalues"][near]) - BANDWIDTH) < 0.05 * BANDWIDTH)


def test_the_slice_runs_along_a_joint_of_the_arm_within_its_limits(analysis_json):
    joints = load_scenario("scope4").robot.joints
    bw = analysis_json["observer_bandwidth"]
    k = list(joints.names).index(bw["slice_joint"])
    lo, hi = joints.limits[k]
    assert lo <= min(bw["theta2"]) and max(bw["theta2"]) <= hi
    # the slice joint is the one the eigenvalues change most along over the grid
    assert bw["sensitivity_rad_s"][bw["slice_joint"]] == max(bw["sensitivity_rad_s"].values())


def test_the_analyses_take_the_arm_route(analysis_json):
    n = 4
    mismatch = analysis_json["mismatch"]
    # at the factor 1 (nominal = true inertia) the held loop with the observer has 3 n poles, all stable
    sweep = mismatch["with_dob"]["sweep"]
    one = sweep["factors"].index(1.0)
    assert len(sweep["poles"][one]) == 3 * n and sweep["spectral_abscissa"][one] < 0
    fr = analysis_json["frequency"]
    assert len(fr["tracking_with_dob"]["metrics"]) == n
    crit = analysis_json["observer_design"]["critical_theta2_speed_scenario_gain"]
    direction = np.eye(n)[list(load_scenario("scope4").robot.joints.names).index(
        analysis_json["observer_bandwidth"]["slice_joint"])]
    assert crit["unlimited"] or np.allclose(np.abs(crit["dq_direction_at"]), direction)


def test_the_report_names_the_slice_joint_and_the_arm_joints(analysis_json, tmp_path):
    from analysis.report.build import AnalysisResult
    from analysis.report.view.bandwidth import bandwidth_section
    from analysis.report.view.design import design_section

    s = load_scenario("scope4")
    result = AnalysisResult.from_json(json.dumps(analysis_json))
    along = result.observer_bandwidth.slice_joint
    png = tmp_path / "observer_bandwidth.png"
    png.write_bytes(b"\x89PNG")
    bw = bandwidth_section(result, {"observer_bandwidth": png}, s)
    assert "(yaw, pitch, insertion, roll)" in bw.slowest and "theta" not in bw.slowest
    assert bw.figures[0].caption == f"Observer modes along {along} and the slowest mode's direction"
    design = design_section(result, s, {})
    labels = [row[0].text for row in design.certificate.rows]
    unit = s.robot.joints.velocity_units[list(s.robot.joints.names).index(along)]
    assert f"largest |{along}'| keeping beta > 0 ({unit})" in labels
    assert "speed bound (rad/s, rad/s, m/s, rad/s)" in labels                    # yaw, pitch, insertion, roll
    assert design.gain_units == "kg m^2/s; kg/s on joint 3"


def test_a_quick_preview_keeps_a_seven_joint_grid_small():
    from analysis.report.settings import QUICK_SETTINGS, AnalysisSettings, preview_differences

    try:
        joints = load_scenario("panda").robot.joints
    except ModuleNotFoundError as err:          # example-robot-data is optional
        pytest.skip(str(err))
    assert QUICK_SETTINGS.workspace_points_for(joints) == (3,) * 7           # 2187 configurations
    assert AnalysisSettings().workspace_points_for(joints) == (4,) * 7       # the full grid: 16384
    # and the preview lists the grid the arm gets, not the paper arm's
    assert ("workspace grid (points per joint): 3 x 3 x 3 x 3 x 3 x 3 x 3 (full: 4 x 4 x 4 x 4 x 4 x 4 x 4)"
            in preview_differences(QUICK_SETTINGS, joints=joints))
