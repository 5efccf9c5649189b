"""Task-space paths of a URDF arm's tool point into joint references: residual, exact derivatives, refusals."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from blocks.model.arm import UnreachableError  # noqa: E402
from blocks.model.urdf import IKUnreachableError, example_arm, joint_path, solve_ik  # noqa: E402
from blocks.model.urdf.ik import jacobian_rate  # noqa: E402

W = 2.0


def _lissajous(t):
    """A figure below scope4's remote centre (m, m/s, m/s^2), its derivatives written out by hand."""
    t = np.asarray(t, dtype=float)
    p = np.stack([-0.08 + 0.03 * np.sin(W * t), 0.04 * np.sin(2 * W * t), -0.12 + 0.01 * np.cos(W * t)], -1)
    dp = np.stack([0.03 * W * np.cos(W * t), 0.08 * W * np.cos(2 * W * t), -0.01 * W * np.sin(W * t)], -1)
    ddp = np.stack([-0.03 * W ** 2 * np.sin(W * t), -0.16 * W ** 2 * np.sin(2 * W * t),
                    -0.01 * W ** 2 * np.cos(W * t)], -1)
    return p, dp, ddp


@pytest.fixture(scope="module")
def scope4():
    return example_arm("scope4")


@pytest.fixture(scope="module")
def path(scope4):
    t = np.linspace(0.0, np.pi / W, 60)
    return joint_path(scope4, t, *_lissajous(t))


def test_positions_hit_the_path(scope4, path):
    p, _, _ = _lissajous(path.t)
    assert np.max(np.linalg.norm(scope4.tool_position(path.q) - p, axis=-1)) < 1e-9
    assert np.max(path.residual) < 1e-9
    assert scope4.joints.outside_limits(path.q) is None


def test_velocities_and_accelerations_map_to_the_path(scope4, path):
    """J q' = p' and J q'' + J' q' = p'' hold exactly for any choice of inverse."""
    _, dp, ddp = _lissajous(path.t)
    J = scope4.tool_jacobian(path.q)
    np.testing.assert_allclose(np.einsum("kij,kj->ki", J, path.dq), dp, atol=1e-12)
    acc = np.einsum("kij,kj->ki", J, path.ddq) + scope4.tool_acceleration_bias(path.q, path.dq)
    np.testing.assert_allclose(acc, ddp, atol=1e-11)


def test_derivatives_against_finite_differences_of_the_ik(scope4, path):
    """q' and q'' against central differences of separate IK solutions at t -+ h (h = 1e-4 s)."""
    h = 1e-4
    for k in (5, 23, 41):
        t = path.t[k]
        qs, dqs = [], []
        for tk in (t - h, t + h):
            one = joint_path(scope4, [tk], *_lissajous([tk]), q0=path.q[k])
            qs.append(one.q[0])
            dqs.append(one.dq[0])
        scale_q, scale_dq = max(1.0, np.abs(path.dq[k]).max()), max(1.0, np.abs(path.ddq[k]).max())
        np.testing.assert_allclose((qs[1] - qs[0]) / (2 * h), path.dq[k], atol=2e-6 * scale_q)
        np.testing.assert_allclose((dqs[1] - dqs[0]) / (2 * h), path.ddq[k], atol=2e-6 * scale_dq)


def test_jacobian_rate_against_finite_differences():
    arm = example_arm("ur5")
    rng = np.random.default_rng(4)
    q, dq = rng.uniform(-1.5, 1.5, arm.n), rng.uniform(-1, 1, arm.n)
    h = 1e-6
    fd = (arm.tool_jacobian(q + h * dq) - arm.tool_jacobian(q - h * dq)) / (2 * h)
    np.testing.assert_allclose(jacobian_rate(arm, q, dq), fd, atol=1e-8)


def test_redundant_arm_acceleration_is_the_derivative_of_the_velocity():
    """UR5's 6 joints for a 3-D point: q'' = d/dt (J^+ p') along the motion, checked at q(t) moved by q' itself."""
    arm = example_arm("ur5")
    q0 = np.array([0.3, -1.0, 1.2, -0.5, 1.2, 0.3])
    p0 = arm.tool_position(q0)

    def point(t):
        return (p0 + 0.05 * np.array([np.sin(t), np.cos(t) - 1, 0.0]), 0.05 * np.array([np.cos(t), -np.sin(t), 0.0]),
                0.05 * np.array([-np.sin(t), -np.cos(t), 0.0]))

    from blocks.model.urdf.ik import _derivatives
    t, h = 0.4, 1e-5
    _, dp, ddp = point(t)
    dq, ddq = _derivatives(arm, q0, dp, ddp, t, 1e-6)
    rates = []
    for s in (-1.0, 1.0):          # follow the minimum-norm velocity itself for +-h
        rates.append(_derivatives(arm, q0 + s * h * dq + 0.5 * h * h * ddq, point(t + s * h)[1], ddp, t, 1e-6)[0])
    np.testing.assert_allclose((rates[1] - rates[0]) / (2 * h), ddq, atol=1e-7)


def test_unreachable_point_is_refused_by_name(scope4):
    t = np.array([0.0, 0.5])
    p = np.array([[-0.08, 0.0, -0.11], [0.0, 0.0, 1.5]])
    with pytest.raises(IKUnreachableError, match=r"\(0, 0, 1.5\) m at t = 0.5 s.*misses it by"):
        joint_path(scope4, t, p, np.zeros((2, 3)), np.zeros((2, 3)))
    assert issubclass(IKUnreachableError, UnreachableError) and issubclass(IKUnreachableError, ValueError)


def test_point_beyond_a_joint_range_is_refused(scope4):
    # straight down 0.7 m below the remote centre needs 0.35 m of insertion; the stroke is 0.20 m
    with pytest.raises(IKUnreachableError, match="misses it by 0.15 m.*end of their ranges: insertion"):
        solve_ik(scope4, [0.0, 0.0, 0.30 - 0.70], [0.0, 0.05, 0.1, 0.0])


def test_bad_arguments_name_themselves(scope4):
    with pytest.raises(ValueError, match="dp must be finite with shape"):
        joint_path(scope4, [0.0], [[0.0, 0.0, -0.1]], [[0.0, 0.0]], [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="q0 must be 4 finite joint positions"):
        solve_ik(scope4, [0.0, 0.0, -0.1], [0.0, 0.0])
    with pytest.raises(ValueError, match="damping"):
        solve_ik(scope4, [0.0, 0.0, -0.1], damping=-1.0)
