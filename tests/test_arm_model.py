"""The arm-model interface (blocks.model.arm.ArmModel) on the paper's RRPR, held against independent derivations."""
import numpy as np
import pytest
from reference_arm import mass_matrix

from blocks.model.arm import ArmModel
from blocks.model.rrpr.parameters import RobotParameters


@pytest.fixture(scope="module")
def arm():
    return RobotParameters()


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(7)
    return rng.uniform(-2, 2, (3, 6, 4))


def test_the_paper_arm_is_an_arm_model_with_four_named_joints(arm):
    assert isinstance(arm, ArmModel)
    assert arm.n == 4 and arm.joints.names == ("theta1", "theta2", "d3", "theta4")


def test_inertia_agrees_with_the_independent_reference(arm, states):
    q = states[0]
    M = arm.inertia(q)
    for i in range(q.shape[0]):
        np.testing.assert_allclose(M[i], mass_matrix(q[i], arm), rtol=1e-12, atol=1e-12)


def test_forward_and_inverse_dynamics_invert_each_other(arm, states):
    q, dq, tau = states
    np.testing.assert_allclose(arm.inverse_dynamics(q, dq, arm.forward_dynamics(q, dq, tau)), tau, atol=1e-10)


def test_gravity_is_the_bias_at_rest(arm, states):
    q = states[0]
    np.testing.assert_allclose(arm.gravity_forces(q), arm.bias(q, np.zeros_like(q)), atol=0)
    # Eq. 7: only the prismatic stage (m3 + m4) carries weight, d3 positive downwards
    expected = np.zeros_like(q)
    expected[:, 2] = -(arm.m3 + arm.m4) * arm.g
    np.testing.assert_allclose(arm.gravity_forces(q), expected, rtol=1e-14)


def test_tool_jacobian_is_the_derivative_of_the_tool_position(arm, states):
    q = states[0]
    eps = 1e-6
    fd = np.stack([(arm.tool_position(q + eps * e) - arm.tool_position(q - eps * e)) / (2 * eps)
                   for e in np.eye(4)], axis=-1)
    np.testing.assert_allclose(arm.tool_jacobian(q), fd, atol=1e-8)


def test_tool_acceleration_bias_is_the_jacobian_rate_times_the_velocity(arm, states):
    q, dq, _ = states
    h = 1e-5
    dJ = (arm.tool_jacobian(q + h * dq) - arm.tool_jacobian(q - h * dq)) / (2 * h)
    np.testing.assert_allclose(arm.tool_acceleration_bias(q, dq), np.einsum("kij,kj->ki", dJ, dq), atol=1e-8)
