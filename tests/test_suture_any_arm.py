"""The suturing task on any arm: the laceration path of a URDF arm's tool point, its tissue contact, per-link nominal.

The contact force is written here from its definition with pinocchio's kinematics (the tool frame's position
and its linear Jacobian, ``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)``): the depth ``p = skin - z`` below
the skin, the tool velocity ``v = J q'``, ``F = (-c_lat v_x, -c_lat v_y, max(0, k p - c v_z))`` while
``p > 0``, and ``tau = J^T F``; the closed loop's ``tau_dis`` must be that (plus the friction of its
definition) at every output point of a run that stitches.  The path is written here from the laceration's
definition (hover above the skin, a ``64 tau^3 (1 - tau)^3`` dip to ``depth`` below it).  The per-link nominal
model is held against pinocchio's own model with that link's inertia scaled.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

import blocks  # noqa: E402
from blocks.model.urdf import example_arm  # noqa: E402
from blocks.scenarios.scenario import ScenarioError, load_scenario, scenario_from_dict  # noqa: E402

SCOPE4 = {"urdf": "example:scope4", "tool_frame": "tool_tip"}
UR5 = {"urdf": "example:ur5", "tool_frame": "tool0"}


def _tool(arm, q):
    """Pinocchio's tool frame position (m) and linear Jacobian in base axes (3, n)."""
    model = arm.pin_model
    data = model.createData()
    qp = arm.pinocchio_configuration(q)
    pin.framesForwardKinematics(model, data, qp)
    pin.computeJointJacobians(model, data, qp)
    frame = model.getFrameId(arm.tool_frame)
    return data.oMf[frame].translation.copy(), pin.getFrameJacobian(model, data, frame,
                                                                    pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]


def _contact(arm, q, dq, d) -> tuple[np.ndarray, float]:
    """``tau = J^T F`` of the skin contact (N m, N) and the depth below the skin (m), from the definition."""
    p, J = _tool(arm, q)
    depth = d.skin_height - p[2]
    if depth <= 0.0:
        return np.zeros(arm.n), depth
    v = J @ dq
    F = np.array([-d.tissue_drag * v[0], -d.tissue_drag * v[1],
                  max(0.0, d.tissue_stiffness * depth - d.tissue_damping * v[2])])
    return J.T @ F, depth


def _first_stitch(start, skin, hover, depth, T, t):
    """The laceration's first phase, from its definition: at ``start``, ``hover`` above the skin, dipping to
    ``depth`` below it and back over ``T`` s."""
    tau = np.clip(t / T, 0.0, 1.0)
    bump = 64 * tau ** 3 * (1 - tau) ** 3
    z = skin + hover - (hover + depth) * bump
    return np.column_stack([np.full_like(t, start[0]), np.full_like(t, start[1]), z])


def _signals(res, name, n):
    out, labels = np.asarray(res.outputs), list(res.output_labels)
    return np.array([out[labels.index(f"{name}[{i}]")] for i in range(n)]).T


def _check_stitch(s, res):
    """The run follows the first stitch (reference within 1 um, tool within 1 mm) into the skin, and its tau_dis
    is pinocchio's contact plus the friction of its definition at every output point."""
    arm, d, path = s.robot, s.disturbance, s.trajectory
    t = np.asarray(res.time)
    q, dq, q_ref = (_signals(res, k, arm.n) for k in ("q", "dq", "q_ref"))
    tau_dis = _signals(res, "tau_dis", arm.n)
    expected = _first_stitch(path.start, path.skin_height, path.hover, path.depth, path.phase_duration, t)
    refs = np.array([_tool(arm, qk)[0] for qk in q_ref])
    tips = np.array([_tool(arm, qk)[0] for qk in q])
    assert np.max(np.linalg.norm(refs - expected, axis=1)) < 1e-6
    assert np.max(np.linalg.norm(tips - expected, axis=1)) < 1e-3
    friction = np.zeros_like(dq)
    if "friction" in d.kinds:
        friction = -(np.array(d.coulomb) * np.tanh(dq / d.friction_velocity) + np.array(d.viscous) * dq)
    depths = []
    for k in range(t.size):
        tau, depth = _contact(arm, q[k], dq[k], d)
        depths.append(depth)
        scale = max(1.0, float(np.abs(tau).max()))
        np.testing.assert_allclose(tau_dis[k], tau + friction[k], rtol=0, atol=1e-9 * scale)
    depths = np.array(depths)
    # the stitch went into the skin (nearly its full depth) and the tissue pushed back
    assert depths.max() > 0.8 * path.depth and np.mean(depths > 0) > 0.2
    return depths


# --------------------------------------------------------------------------------------------------------------
# scope4 (the built-in scenario) and the UR5 stitch with the tissue contact, against pinocchio
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_scope4_suture_stitches_with_the_tissue_force_of_pinocchio():
    s = load_scenario("scope4-suture")
    assert s.trajectory.skin_height == s.disturbance.skin_height == -0.155
    # the first stitch, with the tissue alone (the friction's stiff tanh asks the numpy engine for many steps)
    first = s.with_changes({"simulation.t_final": s.trajectory.phase_duration, "disturbance.kind": "tissue"})
    res = blocks.simulate(first, engine="fast")
    _check_stitch(first, res)


@pytest.mark.slow
def test_ur5_stitches_with_the_tissue_force_of_pinocchio():
    s = scenario_from_dict({
        "arm": UR5, "gains": {"kp": 400, "kd": 40, "observer_bandwidth": 100.0},
        "trajectory": {"kind": "laceration", "start": [0.45, -0.05], "end": [0.45, 0.05], "stitches": 2,
                       "duration": 1.5, "sample_period": 0.05},
        "disturbance": {"kind": "tissue", "skin_height": 0.2},
        "simulation": {"t_final": 0.5, "output_step": 0.005}})
    assert s.trajectory.method == "resolved_rate"
    res = blocks.simulate(s, engine="fast")
    _check_stitch(s, res)


# --------------------------------------------------------------------------------------------------------------
# The laceration's keys and refusals on another arm
# --------------------------------------------------------------------------------------------------------------
def _lace(trajectory=None, disturbance=None, arm=SCOPE4):
    path = {"kind": "laceration", "start": [-0.04, -0.03], "end": [-0.04, 0.03], "stitches": 2, "duration": 1.5,
            "sample_period": 0.05} | (trajectory or {})
    return scenario_from_dict({"arm": arm, "trajectory": path,
                               "disturbance": {"kind": "tissue", "skin_height": -0.155} | (disturbance or {}),
                               "simulation": {"t_final": 1.5, "output_step": 0.005}})


def test_a_stitch_out_of_reach_is_refused_by_time_point_and_residual():
    # scope4's tool reaches z = 0.30 - 0.35 - 0.20 = -0.25 m at most: the hover point at -0.242 m is reached, the
    # first stitch's bottom at -0.255 m (t = 0.25 s, the middle of its 0.5 s phase) is not
    with pytest.raises(ScenarioError) as err:
        _lace({"depth": 0.01}, {"skin_height": -0.245})
    text = str(err.value)
    assert "(-0.04, -0.03, -0.255) m at t = 0.25 s" in text and "misses it by" in text and "insertion" in text, text


def test_the_laceration_keys_of_another_arm():
    s = _lace()
    assert s.data["trajectory"] == {"kind": "laceration", "start": [-0.04, -0.03], "end": [-0.04, 0.03],
                                    "bulge": 0.0, "stitches": 2, "hover": 0.003, "depth": 0.004, "duration": 1.5,
                                    "sample_period": 0.05}
    assert s.data["disturbance"]["skin_height"] == -0.155
    again = scenario_from_dict(dict(s.data))             # the written scenario reads back to the same path
    assert again.trajectory == s.trajectory and again.disturbance == s.disturbance
    # the skin plane from the path alone is the tissue's too; two planes are refused
    alone = scenario_from_dict({"arm": SCOPE4, "trajectory": dict(s.data["trajectory"], skin_height=-0.15),
                                "disturbance": {"kind": "tissue"}})
    assert alone.disturbance.skin_height == alone.trajectory.skin_height == -0.15
    with pytest.raises(ScenarioError, match="disagrees with 'disturbance.skin_height'"):
        _lace({"skin_height": -0.15})
    with pytest.raises(ScenarioError, match="needs its skin plane: set 'disturbance.skin_height'"):
        scenario_from_dict({"arm": SCOPE4, "trajectory": dict(s.data["trajectory"])})
    # the RRPR's roll and IK-branch keys are not the tool point's
    with pytest.raises(ScenarioError, match=r"unknown key\(s\) trajectory.needle_roll"):
        _lace({"needle_roll": 1.0})
    with pytest.raises(ScenarioError, match=r"trajectory.sample_period \(0.6 s\) is longer than one phase"):
        _lace({"sample_period": 0.6})
    assert s.check_key("trajectory.sample_period") is None


# --------------------------------------------------------------------------------------------------------------
# [nominal_scale] by link: the nominal model is the URDF with those links' masses and inertias scaled
# --------------------------------------------------------------------------------------------------------------
def _pin_dynamics(model, q):
    data = model.createData()
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    return M, pin.computeGeneralizedGravity(model, data, q)


def _scaled(inertia, factor):
    return pin.Inertia(inertia.mass * factor, inertia.lever, inertia.inertia * factor)


def test_per_link_nominal_scale_is_pinocchios_model_with_those_links_scaled():
    s = scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"shaft_link": 1.3, "tool_tip": 2.0}})
    true, nominal = s.robot, s.nominal
    model = true.pin_model.copy()
    ids = {name: model.getJointId(name) for name in ("insertion", "roll")}
    # shaft_link is the insertion joint's body alone
    model.inertias[ids["insertion"]] = _scaled(model.inertias[ids["insertion"]], 1.3)
    # tool_tip (0.01 kg at its origin, 1e-6 kg m^2) hangs 0.30 m below the roll joint: merged into its body, once more
    tool = pin.Inertia(0.01, np.zeros(3), np.eye(3) * 1e-6)
    placed = pin.SE3(np.eye(3), np.array([0.0, 0.0, -0.30])).act(tool)
    model.inertias[ids["roll"]] = model.inertias[ids["roll"]] + placed
    rng = np.random.default_rng(30)
    for _ in range(5):
        q = np.array([rng.uniform(lo, hi) for lo, hi in true.joints.limits])
        M, G = _pin_dynamics(model, q)
        np.testing.assert_allclose(nominal.inertia(q), M, rtol=0, atol=1e-12)
        np.testing.assert_allclose(nominal.gravity_forces(q), G, rtol=0, atol=1e-12)
        assert not np.allclose(true.inertia(q), M, rtol=0, atol=1e-6)
    assert s.data["nominal_scale"] == {"shaft_link": 1.3, "tool_tip": 2.0}


def test_every_link_scaled_is_the_arms_mass_scale_and_both_multiply():
    links = {"yaw_link": 1.1, "pitch_link": 1.1, "shaft_link": 1.1, "roll_link": 1.1, "tool_tip": 1.1}
    by_link = scenario_from_dict({"arm": SCOPE4, "nominal_scale": links}).nominal
    whole = scenario_from_dict({"arm": SCOPE4 | {"nominal_mass_scale": 1.1}}).nominal
    both = scenario_from_dict({"arm": SCOPE4 | {"nominal_mass_scale": 1.1}, "nominal_scale": links}).nominal
    true = example_arm("scope4")
    q = np.array([0.3, -0.2, 0.1, 1.0])
    np.testing.assert_allclose(by_link.inertia(q), whole.inertia(q), rtol=1e-13, atol=0)
    np.testing.assert_allclose(both.inertia(q), 1.21 * true.inertia(q), rtol=1e-13, atol=0)


def test_per_link_nominal_scale_refuses_what_is_not_a_moving_link():
    with pytest.raises(ScenarioError, match=r"unknown key\(s\) nominal_scale.base_link; allowed in \[nominal_scale\]"
                                            r": yaw_link, pitch_link, shaft_link, roll_link, tool_tip"):
        scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"base_link": 1.2}})
    with pytest.raises(ScenarioError, match="'nominal_scale.shaft_link' must be > 0"):
        scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"shaft_link": 0.0}})
    s = scenario_from_dict({"arm": UR5, "nominal_scale": {"wrist_3_link": 1.5}})
    assert s.check_key("nominal_scale.forearm_link") is None
    assert s.with_changes({"nominal_scale.forearm_link": 1.2}).data["nominal_scale"] == {
        "wrist_3_link": 1.5, "forearm_link": 1.2}


def test_a_nominal_scale_that_leaves_no_usable_model_names_the_factors_not_a_temporary_file():
    """shaft_link x 1e300 made M^(q) singular in double precision: the message named '/tmp/dobkit-nominal-....urdf'
    and told the user to give its links <inertial> elements; bad factors are refused by their key as before."""
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"shaft_link": 1e300}})
    text = str(err.value)
    assert "[nominal_scale] {'shaft_link': 1e+300} leaves no usable nominal model" in text, text
    assert "choose factors nearer 1" in text and "dobkit-nominal-" not in text, text
    for factor, message in ((0.0, "must be > 0.0"), (-1.0, "must be > 0.0"), (math.inf, "must be a finite number"),
                            (math.nan, "must be a finite number")):
        with pytest.raises(ScenarioError, match=rf"'nominal_scale.shaft_link' {message}"):
            scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"shaft_link": factor}})
    with pytest.raises(ScenarioError, match=r"unknown key\(s\) nominal_scale.nosuch; allowed in \[nominal_scale\]: "
                                            r"yaw_link"):
        scenario_from_dict({"arm": SCOPE4, "nominal_scale": {"nosuch": 1.2}})
