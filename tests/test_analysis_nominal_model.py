"""The observer's analytic modes use the nominal model, pinned with a nominal model that differs from the arm.

With every nominal mass and inertia doubled (``scale_nominal_inertia(s, 2)``),
``M^ = 2 M``: the observer error dynamics are ``e_d' = -Y M^-1 e_d`` with the
model the observer holds, so its analytic poles are the eigenvalues of
``-Y (2 M)^-1`` -- half those of the perfect model (the prismatic one -20 rad/s,
not -40).  ``M`` here is Eq. 5 written out in tests/conftest.py from Table 1,
not the package's.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import PAPER_Y, reference_inertia

import blocks
from analysis.linear.bandwidth import along_trajectory, bandwidth_survey
from analysis.linear.loop import analytic_poles, operating_point_analysis, scale_nominal_inertia

Q0 = np.array([0.3, 1.2, 0.1, 0.2])


@pytest.fixture(scope="module")
def doubled():
    s = scale_nominal_inertia(blocks.load_scenario("paper"), 2.0)
    assert s.robot == blocks.load_scenario("paper").robot          # only the model the controller holds changed
    return s


def _sorted(values) -> np.ndarray:
    values = np.asarray(values, dtype=complex)
    return values[np.lexsort((values.imag, values.real))]


def test_analytic_observer_poles_are_those_of_the_nominal_model(doubled):
    want = np.linalg.eigvals(-PAPER_Y * np.eye(4) @ np.linalg.inv(2.0 * reference_inertia(Q0[1])))
    got = analytic_poles(doubled, Q0)["observer"]
    np.testing.assert_allclose(_sorted(got), _sorted(want), rtol=1e-12, atol=0)
    # the prismatic mode: -Y / (2 k4) = -10 / 0.5
    assert np.min(got.real) == pytest.approx(-PAPER_Y / (2 * 0.25), rel=1e-12)


def test_scaling_twice_multiplies_the_factors(doubled):
    """2 then 1.5: M^ = 3 M, so the observer poles are the eigenvalues of -Y (3M)^-1 (the prismatic one -40/3)."""
    tripled = scale_nominal_inertia(doubled, 1.5)
    want = np.linalg.eigvals(-PAPER_Y * np.eye(4) @ np.linalg.inv(3.0 * reference_inertia(Q0[1])))
    np.testing.assert_allclose(_sorted(analytic_poles(tripled, Q0)["observer"]), _sorted(want), rtol=1e-12)
    with pytest.raises(ValueError, match="inertia scale factor must be a finite number > 0, got 0"):
        scale_nominal_inertia(doubled, 0)


def test_analytic_pd_poles_do_not_depend_on_the_model(doubled):
    # the paper's gains Kp = 180, Kd = 36: s^2 + 36 s + 180 = (s + 6)(s + 30), each joint
    got = analytic_poles(doubled, Q0, observer=False)
    assert set(got) == {"plant"}
    np.testing.assert_allclose(_sorted(got["plant"]), [-30.0] * 4 + [-6.0] * 4, rtol=1e-12)


def test_the_operating_point_compares_with_the_nominal_models_observer_poles(doubled):
    op = operating_point_analysis(doubled, Q0)
    assert op.perfect_model is False
    want = np.linalg.eigvals(-PAPER_Y * np.eye(4) @ np.linalg.inv(2.0 * reference_inertia(Q0[1])))
    np.testing.assert_allclose(_sorted(op.analytic_with_dob["observer"]), _sorted(want), rtol=1e-12)


def test_the_bandwidth_survey_reports_the_nominal_models_rates(doubled):
    """Y (2M)^-1 along theta2 and over the path: half the perfect model's rates (docs: 40 -> 20 rad/s)."""
    survey = bandwidth_survey(doubled, points=(2, 3, 2, 2), slice_points=7)
    for theta2, rates in zip(survey.theta2, survey.eigenvalues):
        want = np.sort(np.linalg.eigvals(PAPER_Y * np.linalg.inv(2.0 * reference_inertia(theta2))).real)
        np.testing.assert_allclose(np.sort(rates), want, rtol=1e-10)
    assert survey.fastest_rad_s.max == pytest.approx(PAPER_Y / (2 * 0.25), rel=1e-12)
    path = along_trajectory(doubled, samples=5)
    q = np.asarray(doubled.trajectory.evaluate(np.asarray(path.time))[0])
    want = [np.linalg.eigvals(PAPER_Y * np.linalg.inv(2.0 * reference_inertia(th))).real.min() for th in q[:, 1]]
    np.testing.assert_allclose(path.slowest_rad_s, want, rtol=1e-10)
