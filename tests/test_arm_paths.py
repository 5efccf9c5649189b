"""The paths of a URDF arm's tool point and the joint paths made from them (blocks/scenarios/tool_path.py,
blocks/model/urdf/ik.py, blocks/model/urdf/resolved_rate.py): derivatives that are the derivatives of the positions, and a
singularity margin on the Jacobian's smallest singular value.

Each test checks a number against a derivation of its own (finite differences, numpy's SVD); each was written
for a wrong change of tests/mutation_probe.py that the rest of the suite let through, named in its docstring.
"""
from __future__ import annotations

import numpy as np
import pytest


def test_the_ik_singularity_margin_is_on_the_smallest_singular_value():
    """ik-sigma-largest: a margin between the Jacobian's smallest and largest singular values (numpy's SVD) along
    the path is a singularity the path's velocity cannot pass; a margin below the smallest passes."""
    pytest.importorskip("pinocchio")
    from blocks.model.urdf import IKUnreachableError, example_arm, joint_path
    arm = example_arm("scope4")
    t = np.linspace(0.0, 0.5, 6)
    p = np.stack([-0.08 + 0.03 * np.sin(t), 0.04 * np.sin(2 * t), -0.12 + 0.01 * np.cos(t)], -1)
    dp = np.stack([0.03 * np.cos(t), 0.08 * np.cos(2 * t), -0.01 * np.sin(t)], -1)
    ddp = np.stack([-0.03 * np.sin(t), -0.16 * np.sin(2 * t), -0.01 * np.cos(t)], -1)
    path = joint_path(arm, t, p, dp, ddp)
    sigmas = np.array([np.linalg.svd(arm.tool_jacobian(q), compute_uv=False) for q in path.q])
    smallest, largest = sigmas.min(axis=1), sigmas.max(axis=1)
    assert smallest.max() < largest.min()
    joint_path(arm, t, p, dp, ddp, min_sigma=0.5 * smallest.min())
    with pytest.raises(IKUnreachableError, match="singularity"):
        joint_path(arm, t, p, dp, ddp, min_sigma=0.5 * (smallest.max() + largest.min()))


def test_the_tool_paths_velocity_and_acceleration_are_the_derivatives_of_its_position():
    """tp-dds-T.  Segments of 1.5 s (not 1 s, where p''/T and p''/T^2 agree): p' and p'' against central
    differences of p and p' (the smoothstep is C2, so inside a segment the differences converge as h^2)."""
    pytest.importorskip("pinocchio")
    from blocks.scenarios.scenario import scenario_from_dict

    s = scenario_from_dict({
        "arm": {"urdf": "example:scope4", "tool_frame": "tool_tip"},
        "trajectory": {"kind": "tool_path", "duration": 3.0, "sample_period": 0.05,
                       "waypoints": [[-0.045, 0.0, -0.148], [-0.03, 0.02, -0.16], [-0.045, 0.0, -0.148]]},
        "simulation": {"t_final": 3.0}})
    path, h = s.trajectory, 1e-5
    t = np.array([0.2, 0.71, 1.1, 1.9, 2.6])                    # inside the two segments of 1.5 s
    p, dp, ddp = path.task_space(t)
    p_plus, dp_plus, _ = path.task_space(t + h)
    p_minus, dp_minus, _ = path.task_space(t - h)
    np.testing.assert_allclose(dp, (p_plus - p_minus) / (2 * h), rtol=0, atol=1e-9)
    np.testing.assert_allclose(ddp, (dp_plus - dp_minus) / (2 * h), rtol=0, atol=1e-8)
    assert np.max(np.abs(ddp)) > 1e-3                          # a path that accelerates: the check means something


def test_the_resolved_rate_acceleration_is_the_derivative_of_the_rate_along_the_motion_off_the_path():
    """rr-dv-feedback.  ``q''`` of ``rates`` is d/dt F(t, q(t)) along q' = F: a central difference of ``rate``
    at (t +- h, q +- h q').  Off the path (a task error of ~1 cm) the feedback's rate K_p (p' - J q') = -K_p^2 e
    is a large part of it (on the path it vanishes, which is why the loop tests cannot see it)."""
    pytest.importorskip("pinocchio")
    from blocks.model.urdf import example_arm
    from blocks.model.urdf.resolved_rate import ResolvedRate

    arm = example_arm("panda")
    q_rest = np.array([0.0, 0.0, 0.0, -1.6, 0.0, 1.6, 0.8])
    law = ResolvedRate(arm, task_gain=10.0, posture_gain=1.0, rest=q_rest, min_sigma=1e-6)
    centre, radius, w = arm.tool_position(q_rest) + np.array([0.0, -0.05, 0.0]), 0.05, 1.3

    def path(t):
        c, s = np.cos(w * t), np.sin(w * t)
        return (centre + radius * np.array([s, c, 0.0]), radius * w * np.array([c, -s, 0.0]),
                -radius * w * w * np.array([s, c, 0.0]))

    q = q_rest + np.array([0.02, -0.03, 0.01, 0.02, -0.02, 0.01, 0.03])
    t, h = 0.0, 1e-6
    assert np.linalg.norm(path(t)[0] - arm.tool_position(q)) > 5e-3             # really off the path
    dq, ddq = law.rates(q, *path(t))
    np.testing.assert_allclose(dq, law.rate(q, *path(t)[:2]), rtol=1e-12, atol=1e-14)
    ahead, behind = law.rate(q + h * dq, *path(t + h)[:2]), law.rate(q - h * dq, *path(t - h)[:2])
    np.testing.assert_allclose(ddq, (ahead - behind) / (2 * h), rtol=0, atol=1e-6 * np.max(np.abs(ddq)))
