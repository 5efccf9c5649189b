"""The loop's maths, written once in blocks.kernels, checked where it is used against one independent reference.

Every implementation the toolkit runs -- the python-control blocks, the batch engine, the public model functions
and the exported C plant -- is evaluated at random states and parameters and compared with tests/reference_arm.py,
which derives the dynamics from the arm's bodies and writes the control laws directly.
"""
from __future__ import annotations

import numpy as np
import pytest
import reference_arm as ref

import blocks
from blocks import kernels
from blocks.diagram.systems import controller, observer, plant
from blocks.figure2.batch import Variants
from blocks.figure2.batch.members import MemberLoop
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.rrpr import dynamics_kernels
from blocks.model.rrpr.parameters import PAPER_PARAMETERS, RobotParameters

RNG = np.random.default_rng(20261201)
ALL_KINDS = DisturbanceSpec(kinds=("paper", "friction", "tissue"), skin_height=-0.25)
RTOL, ATOL = 1e-7, 1e-8      # the reference differentiates numerically (central differences, about 1e-9 relative)


def _random_state(rng, depth_below_skin: bool = False):
    q = rng.uniform([-np.pi, 0.3, 0.05, -np.pi], [np.pi, 2.8, 0.3, np.pi])
    if depth_below_skin:
        q[2] = 0.45            # the tool below the skin plane, so the tissue model acts
    return q, rng.uniform(-2, 2, 4)


def _random_arm(rng) -> RobotParameters:
    return PAPER_PARAMETERS.scaled(**{k: float(rng.uniform(0.8, 1.25)) for k in ("m1", "m2", "m3", "I2", "l2")})


def test_the_reference_reproduces_the_papers_inertia_constants():
    """Independent of both: Table 1 gives k1 = 7.88827, k2 = 0.4756, k3 = 4.36971, k4 = 0.25, k5 = 1.47486 (docs/model.md)."""
    M = ref.mass_matrix(np.array([0.3, np.pi / 2, 0.1, -0.4]), PAPER_PARAMETERS)   # cos(theta2) = 0
    np.testing.assert_allclose([M[0, 0], M[0, 1], M[1, 1], M[2, 2], M[3, 3], -M[0, 3], -M[1, 3]],
                               [7.88827, 4.36971, 4.36971, 0.25, 1.47486, 1.47486, 1.47486], rtol=1e-6)
    M0 = ref.mass_matrix(np.array([0.3, 0.0, 0.1, -0.4]), PAPER_PARAMETERS)          # cos(theta2) = 1
    assert M0[0, 0] - M[0, 0] == pytest.approx(0.4756, rel=1e-6)


@pytest.mark.parametrize("trial", range(4))
def test_model_functions_match_the_reference(trial):
    rng = np.random.default_rng(trial)
    p = _random_arm(rng)
    q, dq = _random_state(rng)
    np.testing.assert_allclose(blocks.inertia(q, p), ref.mass_matrix(q, p), rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(blocks.coriolis_vector(q, dq, p), ref.coriolis(q, dq, p), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(blocks.gravity(q, p), ref.gravity(q, p), rtol=1e-12)
    np.testing.assert_allclose(blocks.forward_kinematics(q, p), ref.tool_pose(q, p), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(blocks.jacobian(q, p), ref.tool_jacobian(q, p), rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("trial", range(4))
def test_blocks_match_the_reference(trial):
    rng = np.random.default_rng(100 + trial)
    true, nominal = _random_arm(rng), _random_arm(rng)
    q, dq = _random_state(rng, depth_below_skin=trial % 2 == 1)
    t = float(rng.uniform(0, 5))
    tau, z = rng.uniform(-5, 5, 4), rng.uniform(-2, 2, 4)
    q_ref, dq_ref, ddq_ref = rng.uniform(-1, 1, (3, 4))
    kp, kd = rng.uniform(50, 300, 4), rng.uniform(10, 50, 4)
    Y = np.diag(rng.uniform(2, 40, 4)) + (0.5 * np.eye(4)[::-1] if trial >= 2 else 0.0)     # full gains too

    arm = plant(true, ALL_KINDS)
    tau_dis = ref.disturbance(t, q, dq, ALL_KINDS, true)
    x = np.concatenate([q, dq])
    np.testing.assert_allclose(arm.updfcn(t, x, tau, {}),
                               np.concatenate([dq, ref.plant_acceleration(q, dq, tau + tau_dis, true)]),
                               rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(arm.outfcn(t, x, tau, {}), np.concatenate([q, dq, tau_dis]), rtol=1e-7, atol=1e-9)

    d_hat = Y @ dq + z
    ctrl = controller(nominal, kp, kd, use_observer=True)
    u = np.concatenate([q_ref, dq_ref, ddq_ref, q, dq, d_hat])
    np.testing.assert_allclose(ctrl.outfcn(t, [], u, {}),
                               ref.computed_torque(q, dq, q_ref, dq_ref, ddq_ref, d_hat, kp, kd, nominal),
                               rtol=1e-6, atol=1e-7)
    ctrl_free = controller(nominal, kp, kd, use_observer=False)
    np.testing.assert_allclose(ctrl_free.outfcn(t, [], u[:20], {}),
                               ref.computed_torque(q, dq, q_ref, dq_ref, ddq_ref, 0.0, kp, kd, nominal),
                               rtol=1e-6, atol=1e-7)

    obs = observer(nominal, Y)
    u_obs = np.concatenate([tau, q, dq])
    np.testing.assert_allclose(obs.outfcn(t, z, u_obs, {}), d_hat, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(obs.updfcn(t, z, u_obs, {}), ref.observer_rate(q, dq, tau, z, Y, nominal),
                               rtol=1e-6, atol=1e-7)
    # the printed Eq. 16 adds -Y q' to the correct law (docs/model.md)
    printed = observer(nominal, Y, variant="paper-eq16")
    np.testing.assert_allclose(printed.updfcn(t, z, u_obs, {}) - obs.updfcn(t, z, u_obs, {}), -Y @ dq,
                               rtol=1e-12, atol=1e-12)


def test_batch_engine_matches_the_reference_member_by_member():
    base = blocks.load_scenario("paper").replace(disturbance={"kind": ["paper", "friction"]})
    records = [{"robot.m1": 6.0, "nominal_scale.I2": 1.2, "gains.kp": 150, "gains.observer": [5, 10, 20, 8]},
               {"robot.l2": 0.25, "nominal_scale.m3": 0.7, "gains.kd": [30, 36, 40, 36], "disturbance.f_r": [2, -1, 0, 3]},
               {"gains.observer": [[10, 1, 0, 0], [1, 10, 0, 0], [0, 0, 10, 0], [0, 0, 0, 10]],
                "disturbance.coulomb": [0.2, 0.1, 0.3, 0.0]}]
    v = Variants(base, records)
    loop = MemberLoop(v, observer=True)
    assert [name.split()[1] for name, _ in loop.state_meanings] == \
        [f"{s}[{i}]" for s in ("q", "dq", "z") for i in range(4)]
    assert [meaning for _, meaning in loop.state_meanings] == \
        [(quantity, i) for quantity in ("position", "velocity", "observer_state") for i in range(4)]
    rng = np.random.default_rng(7)
    x = np.empty((12, len(v)))
    states = [_random_state(rng) for _ in range(len(v))]
    for i, (q, dq) in enumerate(states):
        x[:4, i], x[4:8, i], x[8:, i] = q, dq, rng.uniform(-1, 1, 4)
    refs = [rng.uniform(-1, 1, (4, 1)) for _ in range(3)]
    t = 1.3
    dx = loop.rhs(t, x, np.vstack(refs))        # the reference is the loop's one source: q_ref; dq_ref; ddq_ref
    for i in range(len(v)):
        s = v.scenario(i)
        q, dq, z = x[:4, i], x[4:8, i], x[8:, i]
        Y = s.observer_gain
        d_hat = Y @ dq + z
        tau = ref.computed_torque(q, dq, *(r[:, 0] for r in refs), d_hat, np.diag(s.kp), np.diag(s.kd), s.nominal)
        tau_dis = ref.disturbance(t, q, dq, s.disturbance, s.robot)
        want = np.concatenate([dq, ref.plant_acceleration(q, dq, tau + tau_dis, s.robot),
                               ref.observer_rate(q, dq, tau, z, Y, s.nominal)])
        np.testing.assert_allclose(dx[:, i], want, rtol=1e-6, atol=1e-6, err_msg=f"member {i}")


def test_kernels_give_the_same_numbers_for_one_point_a_grid_and_a_batch():
    """The row layout: one point (4,), columns sharing parameters (4, K), columns with their own (4, K)."""
    rng = np.random.default_rng(3)
    members = [_random_arm(rng) for _ in range(5)]
    k = np.stack([dynamics_kernels.arm_constants(p) for p in members], axis=1)
    q, dq, v = rng.uniform(-2, 2, (3, 4, 5))
    per_member = dynamics_kernels.mass_solve(k, q, v)
    shared = dynamics_kernels.mass_solve(kernels.column_params((k[:, 0],))[0], q, v)
    for i in range(5):
        one = dynamics_kernels.mass_solve(k[:, i], q[:, i], v[:, i])
        np.testing.assert_array_equal(per_member[:, i], one)
        np.testing.assert_array_equal(shared[:, 0], dynamics_kernels.mass_solve(k[:, 0], q[:, 0], v[:, 0]))
        np.testing.assert_allclose(np.linalg.solve(ref.mass_matrix(q[:, i], members[i]), v[:, i]), one, rtol=1e-7)


@pytest.mark.needs_cc
@pytest.mark.parametrize("fmi_version", [2, 3])
def test_the_c_plant_matches_the_reference(tmp_path, fmi_version):
    """The exported FMU's derivatives and outputs at random states, parameters set from a mismatched arm."""
    import fmu
    spec = ALL_KINDS
    rng = np.random.default_rng(fmi_version)
    true = _random_arm(rng)
    scenario = blocks.load_scenario("paper").replace(
        robot={k: getattr(true, k) for k in ("m1", "m2", "m3", "I2", "l2")},
        disturbance={"kind": list(spec.kinds), "skin_height": spec.skin_height})
    path = fmu.export_plant(tmp_path / "plant.fmu", fmi_version=fmi_version)
    with fmu.load(path, scenario=scenario) as block:
        for _ in range(3):
            q, dq = _random_state(rng, depth_below_skin=True)
            tau, t = rng.uniform(-5, 5, 4), float(rng.uniform(0, 3))
            x = np.concatenate([q, dq])
            tau_dis = ref.disturbance(t, q, dq, scenario.disturbance, true)
            np.testing.assert_allclose(block.updfcn(t, x, tau, {}),
                                       np.concatenate([dq, ref.plant_acceleration(q, dq, tau + tau_dis, true)]),
                                       rtol=1e-6, atol=1e-7)
            out = dict(zip(block.output_labels, block.outfcn(t, x, tau, {})))
            np.testing.assert_allclose([out[f"tau_dis[{i}]"] for i in range(4)], tau_dis, rtol=1e-7, atol=1e-9)
