"""Forward, differential and inverse kinematics against docs/model.md ("Kinematics") and finite differences."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import D1, D4, L1, L2, fd_jacobian, reference_fk

from blocks import RobotParameters, UnreachableError
from blocks.model.rrpr.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    jacobian,
    jacobian_derivative_times_dq,
    planar_reach,
)

# Unequal, non-paper kinematic lengths catch a swapped a1/a2 or l/a mix-up.
ODD = RobotParameters(a1=0.45, a2=0.25, d1=0.15, d4=0.3)
PAPER = RobotParameters()
CONFIGS = np.random.default_rng(11).uniform([-3, -3, -0.1, -3], [3, 3, 0.4, 3], size=(25, 4))


@pytest.mark.parametrize("params", [PAPER, ODD], ids=["paper", "odd"])
def test_forward_kinematics_formula(params):
    expected = reference_fk(CONFIGS, params.a1, params.a2, params.d1, params.d4)
    np.testing.assert_allclose(forward_kinematics(CONFIGS, params), expected, rtol=1e-13, atol=1e-15)


def test_forward_kinematics_known_points():
    # stretched along x, tool at Table 1's d3 = 0.24 m
    np.testing.assert_allclose(forward_kinematics([0, 0, 0.24, 0], PAPER), [0.7, 0.0, 0.12 - 0.24 - 0.271, 0.0],
                               atol=1e-15)
    # elbow at 90 degrees, base at 90 degrees
    np.testing.assert_allclose(forward_kinematics([np.pi / 2, np.pi / 2, 0.0, 0.3], PAPER),
                               [-0.2, 0.5, 0.12 - 0.271, np.pi - 0.3], atol=1e-15)


@pytest.mark.parametrize("params", [PAPER, ODD], ids=["paper", "odd"])
def test_jacobian_equals_finite_differences(params):
    for q in CONFIGS:
        J_fd = fd_jacobian(lambda x: forward_kinematics(x, params), q)
        np.testing.assert_allclose(jacobian(q, params), J_fd, atol=1e-9)


def test_jacobian_corrected_entries():
    """J[0,1] = -a2 sin(t1+t2) (printed -l2 cos) and last row [1, 1, 0, -1] (printed [1,1,0,1]).

    docs/model.md, "The corrected Jacobian".
    """
    for q in CONFIGS:
        J = jacobian(q, ODD)
        assert J[0, 1] == pytest.approx(-ODD.a2 * np.sin(q[0] + q[1]), abs=1e-15)
        np.testing.assert_array_equal(J[3], [1.0, 1.0, 0.0, -1.0])
        np.testing.assert_array_equal(J[2], [0.0, 0.0, -1.0, 0.0])


def test_jacobian_batched():
    J = jacobian(CONFIGS.reshape(5, 5, 4), ODD)
    assert J.shape == (5, 5, 4, 4)
    np.testing.assert_allclose(J[3, 2], jacobian(CONFIGS[17], ODD))


def test_jacobian_singular_exactly_at_theta2_0_and_pi():
    for t2 in (0.0, np.pi):
        assert abs(np.linalg.det(jacobian([0.4, t2, 0.1, 0.2], PAPER))) < 1e-15
    # |det| = a1 a2 |sin theta2| (the planar block; the z and roll rows are unimodular)
    for q in CONFIGS:
        assert abs(np.linalg.det(jacobian(q, ODD))) == pytest.approx(ODD.a1 * ODD.a2 * abs(np.sin(q[1])), rel=1e-9,
                                                                      abs=1e-14)


def test_jacobian_derivative_times_dq_equals_finite_differences():
    rng = np.random.default_rng(5)
    h = 1e-6
    for q in CONFIGS[:12]:
        dq = rng.uniform(-2, 2, size=4)
        # d/dt [J(q(t))] q' at q(t) = q + t q'
        Jdot = (jacobian(q + h * dq, ODD) - jacobian(q - h * dq, ODD)) / (2 * h)
        np.testing.assert_allclose(jacobian_derivative_times_dq(q, dq, ODD), Jdot @ dq, atol=1e-7)
        # and as the second derivative of FK along the straight joint-space line
        f = lambda s: forward_kinematics(q + s * dq, ODD)  # noqa: E731
        acc = (f(1e-4) - 2 * f(0.0) + f(-1e-4)) / 1e-8
        np.testing.assert_allclose(jacobian_derivative_times_dq(q, dq, ODD), acc, atol=1e-5)


def test_planar_reach():
    assert planar_reach(PAPER) == pytest.approx((0.3, 0.7))
    assert planar_reach(ODD) == pytest.approx((0.2, 0.7))


def _grid_poses(params, n_r=7, n_a=12):
    inner, outer = planar_reach(params)
    r = np.linspace(inner + 0.02, outer - 0.02, n_r)
    a = np.linspace(-np.pi, np.pi, n_a, endpoint=False) + 0.1
    R, A = np.meshgrid(r, a, indexing="ij")
    n = R.size
    z = np.linspace(-0.5, 0.1, n)
    phi = np.linspace(-2.5, 2.5, n)
    return np.column_stack([R.ravel() * np.cos(A.ravel()), R.ravel() * np.sin(A.ravel()), z, phi])


@pytest.mark.parametrize("elbow, sign", [("positive", 1.0), ("negative", -1.0)])
@pytest.mark.parametrize("params", [PAPER, ODD], ids=["paper", "odd"])
def test_ik_fk_round_trip_over_workspace(params, elbow, sign):
    poses = _grid_poses(params)
    q = inverse_kinematics(poses, params, elbow=elbow)
    assert q.shape == poses.shape
    back = reference_fk(q, params.a1, params.a2, params.d1, params.d4)
    np.testing.assert_allclose(back[:, :3], poses[:, :3], atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back[:, 3] - poses[:, 3]))), 0.0, atol=1e-12)
    assert np.all(np.sign(q[:, 1]) == sign)
    # one point at a time gives the same answer as the batch
    for k in (0, 17, len(poses) - 1):
        np.testing.assert_allclose(inverse_kinematics(poses[k], params, elbow=elbow), q[k], atol=1e-14)


def test_ik_q_near_keeps_angles_continuous():
    pose = np.array([-0.5, 0.05, -0.4, 3.0])
    q_near = np.array([3.0, 1.0, 0.2, 6.0])
    q = inverse_kinematics(pose, PAPER, q_near=q_near)
    assert abs(q[0] - q_near[0]) <= np.pi and abs(q[3] - q_near[3]) <= np.pi
    np.testing.assert_allclose(reference_fk(q)[:3], pose[:3], atol=1e-12)
    assert np.cos(reference_fk(q)[3] - pose[3]) == pytest.approx(1.0)


@pytest.mark.parametrize("xy, margin, fragment", [
    ((0.2, 0.0), 0.0, "radius 0.2 m"),            # inside the inner hole
    ((0.0, -0.75), 0.0, "radius 0.75 m"),         # beyond full stretch
    ((0.699, 0.0), 0.2, "singularity"),           # reachable, but almost stretched
    ((0.301, 0.0), 0.2, "singularity"),           # reachable, but almost folded
])
def test_unreachable_points_raise_with_clear_message(xy, margin, fragment):
    pose = np.array([xy[0], xy[1], -0.4, 0.0])
    with pytest.raises(UnreachableError) as info:
        inverse_kinematics(pose, PAPER, min_sin_theta2=margin)
    message = str(info.value)
    assert "not reachable" in message and fragment in message
    assert "0.3 m to 0.7 m" in message


def test_unreachable_point_in_a_batch_is_named():
    poses = np.array([[0.5, 0.0, -0.4, 0.0], [0.4, 0.1, -0.4, 0.0], [0.0, 0.9, -0.4, 0.0]])
    with pytest.raises(UnreachableError, match=r"x=0 m, y=0\.9 m"):
        inverse_kinematics(poses, PAPER)


def test_ik_rejects_bad_input():
    with pytest.raises(ValueError, match="elbow"):
        inverse_kinematics([0.5, 0.0, 0.0, 0.0], PAPER, elbow="up")
    with pytest.raises(ValueError, match="length 4"):
        inverse_kinematics([0.5, 0.0, 0.0], PAPER)
    with pytest.raises(ValueError, match="non-finite"):
        inverse_kinematics([np.nan, 0.0, 0.0, 0.0], PAPER)


Q = np.array([0.4, 1.1, 0.2, 0.3])            # a pose away from every singularity (rad, rad, m, rad)


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_tool_velocity_is_the_time_derivative_of_the_pose():
    """kin-vel-row3: ``tool_velocity`` (exported kernel) is d/dt of Eq. 8 along q', by central differences."""
    from blocks.model.rrpr.tool_kernels import kinematic_lengths, tool_velocity
    dq = np.array([0.7, -1.3, 0.05, 2.1])
    h = 1e-6
    want = (reference_fk(Q + h * dq) - reference_fk(Q - h * dq)) / (2 * h)
    got = tool_velocity(kinematic_lengths(PAPER), Q, dq)
    np.testing.assert_allclose(got, want, atol=1e-8)
    assert got[3] == pytest.approx(dq[0] + dq[1] - dq[3])          # the corrected last row [1, 1, 0, -1]


def test_the_inner_reach_is_the_links_difference_whichever_is_longer():
    """kinpy-reach-abs: with a2 > a1 the annulus is |a1 - a2| to a1 + a2 (law of cosines at theta2 = pi, 0)."""
    from blocks.model.rrpr.kinematics import UnreachableError, inverse_kinematics, planar_reach
    arm = RobotParameters(a1=0.2, a2=0.5)
    inner, outer = planar_reach(arm)
    assert (inner, outer) == pytest.approx((0.3, 0.7))
    # theta2 = pi folds the arm: the tool is then |a1 - a2| from the axis
    assert math.hypot(*reference_fk([0.0, math.pi, 0.0, 0.0], a1=0.2, a2=0.5)[:2]) == pytest.approx(inner)
    q = inverse_kinematics([0.35, 0.0, 0.0, 0.0], arm)
    np.testing.assert_allclose(reference_fk(q, a1=0.2, a2=0.5)[:2], [0.35, 0.0], atol=1e-12)
    with pytest.raises(UnreachableError, match="radii 0.3 m to 0.7 m"):
        inverse_kinematics([0.25, 0.0, 0.0, 0.0], arm)


def test_ik_with_no_singularity_margin_accepts_the_folded_and_the_stretched_arm():
    """kinpy-ik-margin-le: ``min_sin_theta2 = 0`` accepts the workspace boundary itself: r = |a1 - a2| (theta2 = pi)
    and r = a1 + a2 (theta2 = 0; one ulp beyond 0.7 m, where cos(theta2) rounds to 1 and sin(theta2) to 0)."""
    from blocks.model.rrpr.kinematics import inverse_kinematics
    for r, theta2 in ((L1 - L2, math.pi), (np.nextafter(L1 + L2, 1.0), 0.0)):
        pose = np.array([r, 0.0, D1 - 0.1 - D4, 0.2])
        q = inverse_kinematics(pose, PAPER)
        assert q[1] == pytest.approx(theta2, abs=1e-12)
        np.testing.assert_allclose(reference_fk(q), pose, atol=1e-12)
