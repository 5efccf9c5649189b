"""The paths of a URDF arm's tool point and the joint paths made from them (blocks/tool_path.py,
blocks/arms/ik.py, blocks/arms/resolved_rate.py): derivatives that are the derivatives of the positions, and a
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
    from blocks.arms import IKUnreachableError, example_arm, joint_path
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
