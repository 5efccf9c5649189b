"""The trajectory kind ``tool_path``: a task-space path of a URDF arm's tool point as joint references, in the loop."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.scenarios.scenario import ScenarioError, scenario_from_dict

pin = pytest.importorskip("pinocchio")

SCOPE4 = {"urdf": "example:scope4", "tool_frame": "tool_tip"}
WAYPOINTS = [[-0.045, 0.0, -0.148], [-0.03, 0.02, -0.16], [-0.045, 0.0, -0.148]]


@pytest.fixture(scope="module")
def scenario():
    return scenario_from_dict({
        "arm": SCOPE4 | {"nominal_mass_scale": 1.05},
        "gains": {"observer_bandwidth": 10.0},
        "trajectory": {"kind": "tool_path", "waypoints": WAYPOINTS, "duration": 2.0, "sample_period": 0.05},
        "disturbance": {"kind": "step", "f_r": [0.05, 0.1, 0.4, 0.00002]},
        "simulation": {"t_final": 2.5, "output_step": 0.005, "rtol": 1e-10, "atol": 1e-12}})


def _tip(model, data, frame, q):
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[frame].translation.copy()


def test_reference_puts_pinocchios_tool_frame_on_the_path_between_samples(scenario):
    """At times between the IK samples the joint reference puts the tool frame (pinocchio's) on the smoothstep path
    through the waypoints (within 1e-6 m), and holds the last point after the path's duration."""
    path, arm = scenario.trajectory, scenario.robot
    model = arm.pin_model
    data, frame = model.createData(), model.getFrameId("tool_tip")
    w = np.array(WAYPOINTS)
    for t in (0.0, 0.013, 0.377, 0.5, 0.861, 1.0, 1.2345, 1.99, 2.3):
        seg, tau = (0, t) if t < 1.0 else (1, min(t - 1.0, 1.0))
        s = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)               # quintic smoothstep, independently written
        expected = w[seg] + s * (w[seg + 1] - w[seg])
        q = path.evaluate(t)[0]
        np.testing.assert_allclose(_tip(model, data, frame, q), expected, rtol=0, atol=1e-6)


def test_reference_rates_are_the_derivatives_of_its_positions(scenario):
    """Central differences of q_ref and dq_ref (h = 1e-5 s) give dq_ref and ddq_ref between and across samples."""
    path = scenario.trajectory
    h = 1e-5
    for t in (0.011, 0.33, 0.5, 0.77, 1.02, 1.64):
        q_m, dq_m, _ = path.evaluate(t - h)
        q_p, dq_p, _ = path.evaluate(t + h)
        _, dq, ddq = path.evaluate(t)
        np.testing.assert_allclose((q_p - q_m) / (2 * h), dq, rtol=0, atol=1e-7)
        np.testing.assert_allclose((dq_p - dq_m) / (2 * h), ddq, rtol=0, atol=1e-5)


def test_unreachable_waypoint_is_refused_by_name():
    with pytest.raises(ScenarioError, match=r"\[trajectory\]"):
        scenario_from_dict({"arm": SCOPE4, "trajectory": {"kind": "tool_path", "duration": 1.0,
                                                         "waypoints": [WAYPOINTS[0], [0.5, 0.5, 0.5]]}})
    with pytest.raises(ScenarioError, match="'trajectory.waypoints' must be a list of two or more points"):
        scenario_from_dict({"arm": SCOPE4, "trajectory": {"kind": "tool_path", "waypoints": [WAYPOINTS[0]]}})
    with pytest.raises(ScenarioError, match="'trajectory.waypoints' is required"):
        scenario_from_dict({"arm": SCOPE4, "trajectory": {"kind": "tool_path"}})


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_loop_on_a_tool_path_tracks_it_and_the_observer_helps(scenario, engine):
    if engine == "compiled":
        pytest.importorskip("numba")
    with_obs = blocks.simulate(scenario, observer=True, engine=engine)
    without = blocks.simulate(scenario, observer=False, engine=engine)
    assert with_obs.engine == engine
    from blocks.figure2.metrics import tracking_metrics
    m, m0 = tracking_metrics(with_obs), tracking_metrics(without)
    assert m["max_tool_position_error_mm"] < 0.5 * m0["max_tool_position_error_mm"]
    # the tool-tip metric is pinocchio's tool frame distance
    arm = scenario.robot
    model = arm.pin_model
    data, frame = model.createData(), model.getFrameId("tool_tip")
    out, labels = np.asarray(with_obs.outputs), list(with_obs.output_labels)
    q = np.array([out[labels.index(f"q[{i}]")] for i in range(4)])
    q_ref = np.array([out[labels.index(f"q_ref[{i}]")] for i in range(4)])
    dist = [np.linalg.norm(_tip(model, data, frame, q_ref[:, j]) - _tip(model, data, frame, q[:, j]))
            for j in range(q.shape[1])]
    assert m["max_tool_position_error_mm"] == pytest.approx(1e3 * max(dist), rel=1e-8)
