"""The observer bandwidth map, gain design and linearization on URDF arms (scope4, Panda), against pinocchio.

The reference inertia is pinocchio's ``crba`` at every grid point, not the
arm's own kernels; the grids are checked to stay within the URDF joint limits.
"""
from __future__ import annotations

import numpy as np
import pytest
from two_joint_arm import TWO
from two_joint_arm import write_urdf as _urdf

pin = pytest.importorskip("pinocchio")


from analysis.linear import bandwidth, gain_design  # noqa: E402
from analysis.linear.arm_linear import arm_linearization  # noqa: E402
from blocks.model.urdf import example_arm  # noqa: E402

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


def test_a_one_joint_arm_is_analysed(tmp_path):
    # `dobkit analyze` of a one-joint arm: "error: f(a) and f(b) must have different signs" (the mismatch search
    # re-evaluated its bracket's ends one ulp off, where a loop without a resting position jumps), then an
    # IndexError traceback (python-control squeezes the SISO response of the loop without the observer)
    import blocks
    from analysis.report.build import run_analysis
    one = TWO.replace('<joint name="slide"', '<joint name="slide_unused"').split('<joint name="slide_unused"')[0]
    one += '<joint name="tip_joint" type="fixed"><parent link="arm"/><child link="tip"/><origin xyz="0.3 0 0"/>' \
           '</joint><link name="tip"/></robot>\n'
    _urdf(tmp_path, one)
    s = blocks.scenario_from_dict({"arm": {"urdf": str(tmp_path / "arm.urdf"), "tool_frame": "tip",
                                           "nominal_mass_scale": 1.05},
                                   "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
                                   "trajectory": {"kind": "joint_sine", "amplitude": [0.3], "omega": [1.0],
                                                  "offset": [0.1]},
                                   "disturbance": {"kind": "step", "f_r": [0.1]},
                                   "simulation": {"t_final": 0.5, "output_step": 0.01}})
    assert s.robot.n == 1
    result = run_analysis(s)
    f = result.frequency
    # without the observer, w -> e is 1 / (M s^2 + M^ kd s + M^ kp + gravity's stiffness); at 1000 rad/s the
    # gravity term (about 0.06 N m/rad) is 3e-6 of M w^2, so the magnitude there is pinocchio's M and the gains'
    model = s.robot.pin_model
    M = float(pin.crba(model, model.createData(), np.asarray(f.q0))[0, 0])
    w = np.asarray(f.omega_rad_s)
    expected = 1.0 / abs(-M * w ** 2 + 1j * 1.05 * M * 36.0 * w + 1.05 * M * 180.0)
    assert w[-1] == 1000.0 and len(f.tracking_without_dob.magnitude) == 1
    assert f.tracking_without_dob.magnitude[0][-1] == pytest.approx(expected[-1], rel=1e-4)
    assert len(f.tracking_with_dob.magnitude) == 1 and len(f.estimation_with_dob.magnitude) == 1
    without = result.mismatch.without_dob.boundaries
    scan = without.scan
    for boundary in without.boundaries:                     # each boundary lies between scan points of both signs
        k = np.searchsorted(scan.factors, boundary.factor)
        assert (scan.spectral_abscissa[k - 1] < 0) != (scan.spectral_abscissa[k] < 0)
