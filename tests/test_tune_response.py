"""The linearized error dynamics of a gain design (analysis.tune.response) against closed forms.

With a perfect model the computed-torque loop's error obeys ``e'' + Kd e' + Kp e = M^-1 (d_hat - d)``
(paper-notes): poles at the roots of ``s^2 + Kd s + Kp`` (-6 and -30 for the paper's Kp = 180, Kd = 36) and at
the eigenvalues of ``-Y M^-1``; a reference step is followed as ``Kp / (s^2 + Kd s + Kp)``, whose step response
is written out here by hand; a disturbance reaches the error as ``-s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1``.
"""
from __future__ import annotations

import numpy as np
import pytest

from analysis.tune.linear import loop_poles
from analysis.tune.response import disturbance_gains, error_dynamics, pd_poles, step_responses
from analysis.tune.spec import damping_ratios, overshoots
from blocks import inertia, load_scenario

Q0 = np.array([0.3, 1.2, 0.2, 0.1])


@pytest.fixture(scope="module")
def M():
    return inertia(Q0, load_scenario("paper").robot)


def _sorted(poles) -> np.ndarray:
    poles = np.asarray(poles).ravel()
    return poles[np.lexsort((poles.imag, poles.real))]


def test_perfect_model_poles_are_the_computed_torque_roots_and_the_observer_modes(M):
    sys = error_dynamics(M, M, 180.0, 36.0, 10.0)
    expected = np.concatenate([np.tile([-6.0, -30.0], 4), np.linalg.eigvals(-10.0 * np.linalg.inv(M))])
    np.testing.assert_allclose(_sorted(sys.poles()), _sorted(expected), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(_sorted(pd_poles(180.0, 36.0, 4)), _sorted(np.tile([-6.0, -30.0], 4)), rtol=1e-12)
    # the paper's 40 1/s prismatic observer mode (Y / m = 10 / 0.25)
    assert np.min(np.abs(sys.poles() + 40.0)) < 1e-9


def test_mismatched_poles_equal_the_held_loop_of_the_tuning_constraints(M):
    Mh = 0.7 * M
    kp, kd, Y = [180.0, 250.0, 120.0, 300.0], [36.0, 20.0, 30.0, 40.0], [10.0, 12.0, 8.0, 10.0]
    np.testing.assert_allclose(_sorted(error_dynamics(M, Mh, kp, kd, Y).poles()),
                               _sorted(loop_poles(M, Mh, kp, kd, Y)), rtol=1e-8, atol=1e-8)


def test_the_step_response_is_the_second_order_closed_form(M):
    t = np.linspace(0.0, 2.0, 401)
    # paper gains: overdamped, roots -6 and -30
    paper = step_responses(error_dynamics(M, M, 180.0, 36.0, 10.0), t)
    np.testing.assert_allclose(paper, np.tile(1 - (30 * np.exp(-6 * t) - 6 * np.exp(-30 * t)) / 24, (4, 1)),
                               atol=1e-9)
    # Kp = 100, Kd = 10: zeta = 0.5, wn = 10 rad/s
    wd = np.sqrt(75.0)
    under = step_responses(error_dynamics(M, M, 100.0, 10.0, 10.0), t)
    closed = 1 - np.exp(-5 * t) * (np.cos(wd * t) + 5 / wd * np.sin(wd * t))
    np.testing.assert_allclose(under, np.tile(closed, (4, 1)), atol=1e-9)
    np.testing.assert_allclose(under.max(axis=1) - 1, overshoots(damping_ratios(np.full(4, 100.0), 10.0)),
                               atol=2e-4)


def test_disturbance_to_error_is_the_closed_form_and_vanishes_at_dc(M):
    kp, kd, Y = np.array([180.0, 400.0, 150.0, 200.0]), np.array([36.0, 30.0, 25.0, 28.0]), 10.0
    sys = error_dynamics(M, M, kp, kd, Y)
    omega = np.geomspace(1e-3, 1e3, 25)
    gains = disturbance_gains(sys, omega)
    for k, w in enumerate(omega):
        s = 1j * w
        E = -s * np.diag(1 / (s ** 2 + kd * s + kp)) @ np.linalg.inv(s * M + Y * np.eye(4))
        np.testing.assert_allclose(gains[:, k], np.abs(np.diag(E)), rtol=1e-9)
    assert np.all(gains[:, 0] < 1e-5)          # the observer removes a constant disturbance
    # without the observer's effect (Y -> 0) the DC gain is M^-1 / Kp, the paper's static offset
    static = disturbance_gains(error_dynamics(M, M, kp, kd, 1e-9), [1e-6])[:, 0]
    np.testing.assert_allclose(static, np.abs(np.diag(np.diag(1 / kp) @ np.linalg.inv(M))), rtol=1e-3)


def test_a_gain_of_the_wrong_shape_is_named():
    with pytest.raises(ValueError, match="4 numbers or a 4 x 4 matrix, got shape \\(3,\\)"):
        error_dynamics(np.eye(4), np.eye(4), [1.0, 2.0, 3.0], 1.0, 1.0)
