"""The observer bandwidth map, gain design and linearization on URDF arms (scope4, Panda), against pinocchio.

The reference inertia is pinocchio's ``crba`` at every grid point, not the
arm's own kernels; the grids are checked to stay within the URDF joint limits.
"""
from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from analysis.linear import bandwidth, gain_design  # noqa: E402
from analysis.linear.arm_linear import arm_linearization  # noqa: E402
from blocks.arms import example_arm  # noqa: E402

#: Grid points per joint (small enough for a test; the default grids hold about 15000 configurations).
GRIDS = {"scope4": (5, 5, 5, 5), "panda": (3,) * 7}


@pytest.fixture(scope="module", params=sorted(GRIDS))
def case(request):
    try:
        arm = example_arm(request.param)
    except ModuleNotFoundError as err:          # example-robot-data is optional
        pytest.skip(str(err))
    q, axes = bandwidth.workspace_grid(GRIDS[request.param], arm=arm)
    data = arm.pin_model.createData()
    M = []
    for qk in q:
        m = pin.crba(arm.pin_model, data, arm.pinocchio_configuration(qk))
        M.append(np.triu(m) + np.triu(m, 1).T)
    return request.param, arm, q, np.array(M)


def _slowest(Y, M):
    return np.linalg.eigvals(Y @ np.linalg.inv(M)).real.min(axis=-1)


def test_the_grid_stays_within_the_joint_limits(case):
    _, arm, q, _ = case
    lo, hi = np.array(arm.joints.limits).T
    assert np.all(q >= lo) and np.all(q <= hi)
    assert arm.joints.outside_limits(q) is None


def test_bandwidth_map_agrees_with_pinocchio(case):
    name, arm, q, M = case
    Y = 10.0 * np.eye(arm.n)
    survey = bandwidth.bandwidth_survey(None, Y=Y, arm=arm, points=GRIDS[name])
    slow = _slowest(Y, M)
    assert survey.slowest_rad_s.min == pytest.approx(slow.min(), rel=1e-9)
    assert survey.slowest_rad_s.max == pytest.approx(slow.max(), rel=1e-9)
    assert set(survey.sensitivity_rad_s) == set(arm.joints.names)
    # the base joint turns about the vertical: M does not change along it (to rounding of the fastest mode)
    assert survey.sensitivity_rad_s[arm.joints.names[0]] <= 1e-11 * survey.fastest_rad_s.max
    assert len(survey.eigenvalues[0]) == arm.n


def test_gain_design_meets_the_target_on_pinocchios_inertia(case):
    _, arm, q, M = case
    design = gain_design.design_observer_gain(arm, 10.0, q)
    slow = _slowest(design.Y, M)
    assert slow.min() >= 10.0 * (1 - 1e-9)
    assert slow.min() == pytest.approx(10.0, rel=1e-8)
    np.testing.assert_allclose(design.M_ref, M.mean(axis=0), rtol=1e-10, atol=1e-12)


def test_linearized_poles_on_a_urdf_arm_are_the_analytic_split(case):
    _, arm, q, M = case
    k = len(q) // 3
    Y = gain_design.design_observer_gain(arm, 10.0, q).Y
    kp, kd = np.linspace(100.0, 200.0, arm.n), np.linspace(25.0, 35.0, arm.n)
    lin = arm_linearization(arm, kp, kd, Y, q[k], d=np.linspace(-1.0, 1.0, arm.n))
    expected = np.concatenate([np.concatenate([np.roots([1.0, kd[i], kp[i]]) for i in range(arm.n)]),
                               np.linalg.eigvals(-Y @ np.linalg.inv(M[k]))])
    poles = list(np.linalg.eigvals(lin.A))
    for e in sorted(expected, key=lambda z: (z.real, z.imag)):
        j = int(np.argmin([abs(p - e) for p in poles]))
        assert abs(poles.pop(j) - e) <= 1e-7 * abs(e)
