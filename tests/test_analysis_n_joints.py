"""The analyses on arms that are not the paper's: a 2-link planar arm and a 3-joint cylindrical arm.

The arms (tests/small_arms) are written by hand in closed form.  Every number
they are held against is derived here again, independently of the package:

* linearized error dynamics, perfect model: the roots of ``s^2 + kd_i s + kp_i``
  per joint and the eigenvalues of ``-Y M^-1(q0)`` (paper-notes, "Control law");
  with ``M^ = a M`` and ``Y = r M(q0)``: the cubic ``s^3 + (r + a kd) s^2 +
  (a kp + r kd) s + r kp`` (tests/test_analysis_linear.py derives it);
* observer bandwidth: eigenvalues of ``Y M^-1`` with ``M`` written out below;
* gain design and certificate of the cylindrical arm, whose ``M`` is diagonal:
  in closed form;
* frequency responses: the transfer matrices of paper-notes ("Frozen configuration");
* the sampled loop's stability limit: Euler with measured velocity at
  ``Ts lambda_max(Y M^-1) = 2``; the zoh limit checked by a sampled simulation
  of the nonlinear arm written here, at 0.99 and 1.01 of the computed limit;
* the model's derivatives: the paper arm's exact ``dM/dtheta2`` (Eq. 5) and
  Coriolis vector (paper-notes, C with ``h = k2 sin(theta2) / 2``).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER_K, reference_inertia
from small_arms import Cylindrical, PlanarTwoLink

from analysis.linear import arm_terms, bandwidth, gain_design
from analysis.linear.arm_linear import arm_linearization
from analysis.linear.frequency import arm_frequency_analysis
from blocks.diagram.digital import DigitalController
from blocks.figure2.digital_stability import largest_stable_scale, sampled_stability
from blocks.model.rrpr.parameters import RobotParameters

PLANAR = PlanarTwoLink()
CYL = Cylindrical()


def planar_M(q, p=PLANAR.p):
    """The textbook inertia of the 2-link arm (Spong et al., Sec. 7.3)."""
    c2 = math.cos(q[1])
    m11 = p["m1"] * p["lc1"] ** 2 + p["m2"] * (p["l1"] ** 2 + p["lc2"] ** 2 + 2 * p["l1"] * p["lc2"] * c2) \
        + p["I1"] + p["I2"]
    m12 = p["m2"] * (p["lc2"] ** 2 + p["l1"] * p["lc2"] * c2) + p["I2"]
    return np.array([[m11, m12], [m12, p["m2"] * p["lc2"] ** 2 + p["I2"]]])


def cyl_M(q, p=CYL.p):
    return np.diag([p["J"] + p["m3"] * q[2] ** 2, p["m2"] + p["m3"], p["m3"]])


def hand_M(arm, q):
    return planar_M(q) if arm is PLANAR else cyl_M(q)


def _match(numeric, expected):
    """Largest relative distance after pairing each pole with its nearest unused partner."""
    numeric = list(np.asarray(numeric, dtype=complex))
    worst = 0.0
    for e in sorted(np.asarray(expected, dtype=complex), key=lambda z: (z.real, z.imag)):
        k = int(np.argmin([abs(n - e) for n in numeric]))
        worst = max(worst, abs(numeric.pop(k) - e) / abs(e))
    assert not numeric
    return worst


CASES = [
    (PLANAR, np.array([0.4, 1.1]), [120.0, 200.0], [22.0, 30.0], np.array([[6.0, 1.0], [1.0, 4.0]]), [1.5, -0.7]),
    (CYL, np.array([0.3, 0.25, 0.45]), [180.0, 90.0, 300.0], [36.0, 20.0, 40.0], np.diag([5.0, 30.0, 12.0]),
     [0.8, 3.0, -1.2]),
]


# --- the model's derivatives ----------------------------------------------------------------------------------
def test_central_difference_partials_of_M_equal_the_paper_arms_exact_ones():
    arm = RobotParameters()
    q = np.array([[0.3, 1.2, 0.2, -0.4], [1.0, -2.5, 0.1, 2.0], [0.0, 0.05, 0.3, 0.7]])
    dM = arm_terms.inertia_partials(arm, q)
    exact = np.zeros_like(dM)
    s2 = PAPER_K["k2"] * np.sin(q[:, 1])                   # Eq. 5: m00 = ... + k2 c2, m01 = ... + k2 c2 / 2
    exact[:, 1, 0, 0], exact[:, 1, 0, 1], exact[:, 1, 1, 0] = -s2, -s2 / 2, -s2 / 2
    # the step's truncation error h^2/6 |M'''| ~ 3e-12 and rounding eps |M| / h ~ 4e-10 (|M| ~ 12 kg m^2)
    np.testing.assert_allclose(dM, exact, rtol=0, atol=1e-9)


def test_acceleration_jacobians_equal_the_paper_arms_exact_derivatives():
    arm = RobotParameters()
    q, dq, tau = np.array([0.3, 1.2, 0.2, -0.4]), np.array([0.7, -1.1, 0.05, 0.4]), np.array([2.0, -1.0, 3.0, 0.5])
    a_q, a_v, m_inv = arm_terms.acceleration_jacobians(arm, q, dq, tau)
    M = reference_inertia(q[1])
    hh = PAPER_K["k2"] * math.sin(q[1]) / 2.0
    n_vec = np.array([-hh * (2 * dq[0] * dq[1] + dq[1] ** 2), hh * dq[0] ** 2, 0.0, 0.0])     # C q' of paper-notes
    G = np.array([0.0, 0.0, -arm.g * (arm.m3 + arm.m4), 0.0])
    qdd = np.linalg.solve(M, tau - n_vec - G)
    dM2 = np.zeros((4, 4))
    dM2[0, 0], dM2[0, 1], dM2[1, 0] = -2 * hh, -hh, -hh
    dn2 = n_vec * (math.cos(q[1]) / math.sin(q[1]))        # every term of C q' carries sin(theta2)
    exact_q = np.zeros((4, 4))
    exact_q[:, 1] = -np.linalg.solve(M, dM2 @ qdd + dn2)
    dn_dv = np.array([[-2 * hh * dq[1], -2 * hh * (dq[0] + dq[1]), 0, 0], [2 * hh * dq[0], 0, 0, 0],
                      [0, 0, 0, 0], [0, 0, 0, 0]])
    np.testing.assert_allclose(a_q, exact_q, rtol=0, atol=1e-8)
    np.testing.assert_allclose(a_v, -np.linalg.solve(M, dn_dv), rtol=0, atol=1e-8)
    np.testing.assert_allclose(m_inv, np.linalg.inv(M), rtol=1e-12)


def test_central_difference_partials_of_the_planar_arm_and_the_models_exact_hook():
    p = PLANAR.p
    q = np.array([[0.3, 1.1], [-1.0, 2.4]])
    hs = p["m2"] * p["l1"] * p["lc2"] * np.sin(q[:, 1])
    exact = np.zeros((2, 2, 2, 2))
    exact[:, 1] = np.stack([np.stack([-2 * hs, -hs], -1), np.stack([-hs, 0 * hs], -1)], -2)   # d/d elbow
    np.testing.assert_allclose(arm_terms.inertia_partials(PLANAR, q), exact, rtol=0, atol=1e-10)

    class Exact(PlanarTwoLink):
        def inertia_partials(self, q):          # the model's own derivative is used when it has one
            return np.full(np.shape(q)[:-1] + (2, 2, 2), 7.0)
    assert np.all(arm_terms.inertia_partials(Exact(), q) == 7.0)
    assert np.all(gain_design.inertia_partials(Exact(), q) == 7.0)


def test_defaults_follow_the_joints():
    from analysis.report.settings import AnalysisSettings
    from analysis.simulation.studies import DEFAULT_NOISE, default_noise
    from blocks.model.joints import JointSpace

    settings = AnalysisSettings()
    assert settings.workspace_points_for(CYL.joints) == (27, 27, 27)
    assert settings.min_speed_for(CYL.joints) == (0.5, 0.05, 0.05)
    assert settings.min_speed_for(RobotParameters().joints) == settings.min_speed
    assert default_noise(CYL.joints)["q_std"] == [2e-4, 2e-5, 2e-5]
    assert default_noise(RobotParameters().joints) == DEFAULT_NOISE
    one_sided = JointSpace(names=("a", "b"), kinds=("revolute", "revolute"), limits=((-1.0, math.inf), (-3.0, 2.0)))
    assert arm_terms.workspace_ranges(one_sided) == ((-1.0, -1.0 + 2 * math.pi), (-3.0, 2.0))


# --- linearized error dynamics -------------------------------------------------------------------------------
@pytest.mark.parametrize("arm, q0, kp, kd, Y, d", CASES, ids=["planar2", "cylinder3"])
def test_linearized_poles_are_the_computed_torque_and_observer_poles(arm, q0, kp, kd, Y, d):
    lin = arm_linearization(arm, kp, kd, Y, q0, d=d)
    assert lin.nstates == 3 * arm.n and lin.ninputs == arm.n
    pd = np.concatenate([np.roots([1.0, kd[i], kp[i]]) for i in range(arm.n)])
    observer = np.linalg.eigvals(-Y @ np.linalg.inv(hand_M(arm, q0)))
    assert _match(np.linalg.eigvals(lin.A), np.concatenate([pd, observer])) < 1e-8
    # without the observer (no disturbance: the arm rests at q0) only the PD roots remain
    lin0 = arm_linearization(arm, kp, kd, Y, q0, observer=False)
    assert _match(np.linalg.eigvals(lin0.A), pd) < 1e-8


def test_mismatched_inertia_gives_the_hand_derived_cubic():
    a, r, kp, kd = 1.6, 3.0, 180.0, 36.0
    flat = PlanarTwoLink(g=0.0)                           # horizontal plane: gravity's slope does not enter
    p = dict(flat.p)
    nominal = PlanarTwoLink(**{k: (v * a if k in ("m1", "m2", "I1", "I2") else v) for k, v in p.items()})
    q0 = np.array([0.2, 0.9])
    Y = r * planar_M(q0)
    lin = arm_linearization(flat, kp, kd, Y, q0, d=[0.5, -0.3], nominal=nominal)
    cubic = np.roots([1.0, r + a * kd, a * kp + r * kd, r * kp])
    assert _match(np.linalg.eigvals(lin.A), np.concatenate([cubic, cubic])) < 1e-7


def test_mismatch_study_finds_the_routh_boundary():
    from analysis.linear.loop import arm_mismatch_analysis

    kp, kd, r = 180.0, 36.0, 2.0
    flat = PlanarTwoLink(g=0.0)
    q0 = np.array([0.2, 0.9])
    study = arm_mismatch_analysis(flat, kp, kd, r * planar_M(q0), q0, [0.5, 1.0, 2.0], d=[0.5, -0.3])
    # Routh on the cubic: stable iff a^2 kd kp + a r (kp + kd^2) + r (r kd - kp) > 0
    a_star = max(np.roots([kd * kp, r * (kp + kd ** 2), r * (r * kd - kp)]).real)
    found = study.with_dob.boundaries.boundaries
    assert len(found) == 1 and found[0].stable_side == "above"
    assert found[0].factor == pytest.approx(a_star, rel=1e-6)
    assert study.without_dob.boundaries.boundaries == []         # s^2 + a kd s + a kp: stable for every a > 0
    assert all(v < 0 for v in study.with_dob.sweep.spectral_abscissa)


def test_the_arm_linearization_equals_the_scenario_loops_on_the_paper_arm():
    """Two linearizations written apart: the chain rule on the model and ct.linearize of the Figure-2 loop."""
    from conftest import make_scenario

    from analysis.linear import loop as linear

    s = make_scenario(nominal_scale={k: 1.3 for k in linear.INERTIA_PARAMETERS})
    q0 = np.array([0.3, 2.0, 0.24, 0.1])
    for observer in (True, False):
        _, loop_poles = linear.spectral_abscissa(s, q0, observer)
        lin = arm_linearization(s.robot, s.kp, s.kd, s.observer_gain, q0, d=s.disturbance.f_r, nominal=s.nominal,
                                observer=observer)
        assert _match(np.linalg.eigvals(lin.A), loop_poles) < 1e-9


def test_bad_arguments_are_refused_by_name():
    with pytest.raises(ValueError, match=r"q0 must be 2 finite numbers \(rad, rad\)"):
        arm_linearization(PLANAR, 1.0, 1.0, 1.0, [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="kd must be a finite scalar, 3 numbers or an 3 x 3"):
        arm_linearization(CYL, 1.0, [1.0, 2.0], 1.0, [0.1, 0.2, 0.3])
    with pytest.raises(TypeError, match="arm must be a blocks.model.arm.ArmModel"):
        arm_linearization("panda", 1.0, 1.0, 1.0, [0.1])
    with pytest.raises(ValueError, match="'z' is prismatic"):
        arm_terms.workspace_ranges(type(CYL.joints)(names=("theta", "z"), kinds=("revolute", "prismatic")))


# --- observer bandwidth over the workspace --------------------------------------------------------------------
def test_workspace_is_sampled_within_the_joint_limits():
    q, axes = bandwidth.workspace_grid(arm=CYL)
    assert [len(a) for a in axes] == [27, 27, 27]            # floor(20000^(1/3)) per joint
    assert axes[0][0] == -np.pi and axes[0][-1] == np.pi     # unlimited revolute: a full turn
    assert (axes[1][0], axes[1][-1], axes[2][0], axes[2][-1]) == (0.0, 0.5, 0.2, 0.6)
    assert q.shape == (27 ** 3, 3)


@pytest.mark.parametrize("arm", [PLANAR, CYL], ids=["planar2", "cylinder3"])
def test_observer_modes_are_the_eigenvalues_of_Y_M_inverse(arm):
    rng = np.random.default_rng(3)
    Y = np.diag(rng.uniform(2.0, 20.0, arm.n))
    q = rng.uniform(0.2, 0.5, (6, arm.n))
    rates, dirs = bandwidth.observer_modes(arm, Y, q)
    for k in range(len(q)):
        expected = np.sort(np.linalg.eigvals(Y @ np.linalg.inv(hand_M(arm, q[k]))).real)
        np.testing.assert_allclose(rates[k], expected, rtol=1e-12)
        A = Y @ np.linalg.inv(hand_M(arm, q[k]))
        np.testing.assert_allclose(A @ dirs[k], dirs[k] * rates[k], atol=1e-9)


def test_bandwidth_survey_of_the_planar_arm_against_its_closed_form():
    y = 10.0
    survey = bandwidth.bandwidth_survey(None, Y=y * np.eye(2), arm=PLANAR)
    # Y = y I: rates y / eig(M); M depends on the elbow only, slowest where cos(elbow) is largest (elbow = 0)
    slow_at = [y / np.linalg.eigvalsh(planar_M([0.0, e])).max() for e in (0.0, 2.6)]
    assert survey.slowest_rad_s.min == pytest.approx(slow_at[0], rel=1e-12)
    assert survey.slowest_rad_s.max == pytest.approx(slow_at[1], rel=1e-12)
    assert survey.sensitivity_rad_s["shoulder"] == 0.0 and survey.sensitivity_rad_s["elbow"] > 1.0
    assert survey.slice_joint == "elbow" and survey.theta2[0] == -2.6 and survey.theta2[-1] == 2.6
    fast = [y / np.linalg.eigvalsh(planar_M([0.0, e])).min() for e in np.asarray(survey.grid.axes[1])]
    assert survey.fastest_rad_s.max == pytest.approx(max(fast), rel=1e-12)


# --- gain design and the convergence certificate --------------------------------------------------------------
def test_gain_design_for_the_cylindrical_arm_has_its_closed_form():
    p, target = CYL.p, 8.0
    q, axes = bandwidth.workspace_grid((3, 3, 5), arm=CYL)
    design = gain_design.design_observer_gain(CYL, target, q)
    r = np.asarray(axes[2])
    # Y = c M_ref with M_ref = diag(J + m3 mean r^2, m2 + m3, m3): mode 1 is slowest at the largest r
    ratio = (p["J"] + p["m3"] * np.mean(r ** 2)) / (p["J"] + p["m3"] * r.max() ** 2)
    assert design.c_per_s == pytest.approx(target / ratio, rel=1e-9)
    assert design.slowest_rad_s == pytest.approx(target, rel=1e-9)
    assert design.fastest_rad_s == pytest.approx(design.c_per_s * (p["J"] + p["m3"] * np.mean(r ** 2))
                                                 / (p["J"] + p["m3"] * r.min() ** 2), rel=1e-9)


def test_certificate_and_critical_speed_for_the_cylindrical_arm():
    p = CYL.p
    Y = np.diag([4.0, 30.0, 12.0])
    q, axes = bandwidth.workspace_grid((3, 2, 5), arm=CYL)
    bound = [1.0, 0.1, 0.3]
    cert = gain_design.convergence_certificate(CYL, Y, q, bound)
    # M diagonal, M' = diag(2 m3 r r', 0, 0): beta = min_i (Y_ii - M'_ii / 2) / M_ii, worst at r' = +bound
    r = np.asarray(axes[2])
    first = (Y[0, 0] - p["m3"] * r * bound[2]) / (p["J"] + p["m3"] * r ** 2)
    expected = min(first.min(), Y[1, 1] / (p["m2"] + p["m3"]), Y[2, 2] / p["m3"])
    assert cert.beta_min_rad_s == pytest.approx(expected, rel=1e-8)
    assert len(cert.dq_at) == 3 and cert.configurations == len(q)
    crit = gain_design.critical_speed(CYL, Y, q, [0.0, 0.0, 1.0])
    assert crit.speed_factor == pytest.approx(Y[0, 0] / (p["m3"] * r.max()), rel=1e-8)    # 1 / (m3 r / y1)
    with pytest.raises(ValueError, match=r"speed_bound must be 3 finite numbers >= 0 \(rad/s, m/s, m/s\)"):
        gain_design.convergence_certificate(CYL, Y, q, [1.0, 1.0, 1.0, 1.0])


# --- frequency responses --------------------------------------------------------------------------------------
@pytest.mark.parametrize("arm, q0, kp, kd, Y, d", CASES, ids=["planar2", "cylinder3"])
def test_frequency_responses_equal_the_transfer_functions_written_by_hand(arm, q0, kp, kd, Y, d):
    omega = np.array([0.05, 0.7, 3.0, 13.0, 80.0, 900.0])
    # no disturbance: without the observer the arm then rests at q0, where the closed forms hold
    result = arm_frequency_analysis(arm, kp, kd, Y, q0, omega)
    M, Kp, Kd = hand_M(arm, q0), np.diag(kp), np.diag(kd)
    lin = arm_linearization(arm, kp, kd, Y, q0, d=d)
    n = arm.n
    for w in omega:
        s = 1j * w
        pd = np.linalg.inv(s * s * np.eye(n) + s * Kd + Kp)
        E = -s * pd @ np.linalg.inv(s * M + Y)
        Ed = s * M @ np.linalg.inv(s * M + Y)
        G = np.asarray(lin(s))
        np.testing.assert_allclose(G[:n], E, rtol=1e-7, atol=1e-9 * np.abs(E).max())
        np.testing.assert_allclose(G[n:], Ed, rtol=1e-7, atol=1e-9)
    for i in range(n):
        # without observer the tracking channel's DC gain is -(Kp^-1 M^-1)_ii
        dc = result.tracking_without_dob.metrics[i].dc_gain
        assert dc == pytest.approx(-(np.linalg.inv(Kp) @ np.linalg.inv(M))[i, i], rel=1e-8)
        assert result.tracking_with_dob.metrics[i].dc_gain == pytest.approx(0.0, abs=1e-9)
    assert result.tracking_with_dob.closed_form_max_rel_error < 1e-7
    assert result.tracking_without_dob.closed_form_max_rel_error < 1e-7
    units = result.units["tracking"]
    assert units == (["rad/(N m)"] * 2 if arm is PLANAR else ["rad/(N m)", "m/N", "m/N"])


# --- the sampled loop's stability limit -----------------------------------------------------------------------
@pytest.mark.parametrize("arm", [PLANAR, CYL], ids=["planar2", "cylinder3"])
def test_euler_limit_is_ts_lambda_max_two(arm):
    q = np.array([[0.2, 0.5], [0.1, 2.0]]) if arm is PLANAR else np.array([[0.0, 0.1, 0.25], [0.5, 0.2, 0.55]])
    Y = np.diag(np.linspace(3.0, 9.0, arm.n))
    settings = DigitalController(sample_rate=200.0)      # its encoder and torque fields are not used here
    res = sampled_stability(arm, q, 180.0 * np.eye(arm.n), 36.0 * np.eye(arm.n), Y, settings)
    lam = max(np.abs(np.linalg.eigvals(Y @ np.linalg.inv(hand_M(arm, qk)))).max() for qk in q)
    assert res.ts_lambda_max == pytest.approx(lam / 200.0, rel=1e-12)
    # Euler's 2 is exact without gravity's slope; the slope (the planar arm pitches under gravity) moves it by
    # O(Ts^2 dG/dq / M), here below 1e-3 (tests/test_digital_gravity.py holds it against the sampled loop)
    flat = largest_stable_scale(np.array([hand_M(arm, qk) for qk in q]), 180.0 * np.eye(arm.n),
                                36.0 * np.eye(arm.n), Y, settings)
    assert flat == pytest.approx(2.0 / (lam / 200.0), rel=1e-6)
    assert res.largest_stable_scale == pytest.approx(2.0 / (lam / 200.0), rel=1e-3)


def _sampled_run(arm, q0, d, kp, kd, Y, rate, steps):
    """The digital loop of the nonlinear arm, written from the paper's laws: zoh observer, measured velocity.

    The plant is integrated with RK4 under the held torque, 2 substeps of 5 ms (0.15 rad per step at the
    30 rad/s PD pole); returns |d - d_hat| per sample.
    """
    n, Ts = arm.n, 1.0 / rate
    q, dq = q0 + 1e-4, np.zeros(n)
    d_hat_0 = d + 1e-3
    z = d_hat_0.copy()
    out = []
    for _ in range(steps):
        M, h = arm.inertia(q), arm.bias(q, dq)
        d_hat = Y @ dq + z
        out.append(np.abs(d - d_hat).max())
        tau = M @ (kp * (q0 - q) - kd * dq) + h - d_hat
        # z' = A z + A (tau + Y q' - h) with the sample's values held: exact by A's eigenvalues (real: Y, M SPD)
        lam, V = np.linalg.eig(-Y @ np.linalg.inv(M))
        lam, V = lam.real, V.real
        V_inv = np.linalg.inv(V)
        forced = V_inv @ ((-Y @ np.linalg.inv(M)) @ (tau + Y @ dq - h))
        z = V @ (np.exp(lam * Ts) * (V_inv @ z) + (np.exp(lam * Ts) - 1.0) / lam * forced)
        sub = Ts / 2
        for _ in range(2):
            def f(x):
                return np.concatenate([x[n:], arm.forward_dynamics(x[:n], x[n:], tau + d)])
            x = np.concatenate([q, dq])
            k1 = f(x)
            k2 = f(x + sub / 2 * k1)
            k3 = f(x + sub / 2 * k2)
            k4 = f(x + sub * k3)
            x = x + sub / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            q, dq = x[:n], x[n:]
    return np.array(out)


def test_zoh_limit_holds_in_a_sampled_run_of_the_nonlinear_arm():
    arm = PlanarTwoLink(g=0.0)                       # the map leaves out gravity's slope
    q0, d, rate = np.array([0.3, 1.2]), np.array([0.4, -0.2]), 100.0
    kp, kd, Y = np.array([180.0, 180.0]), np.array([36.0, 36.0]), 10.0 * np.eye(2)
    settings = DigitalController(sample_rate=rate, observer_discretization="zoh")
    res = sampled_stability(arm, q0[None], np.diag(kp), np.diag(kd), Y, settings)
    c = res.largest_stable_scale
    assert 1.0 < res.ts_lambda_limit < 2.0             # below Euler's 2, as the zoh limit is (digital_stability)
    # the map's radius is about 0.98 and 1.02 there: over 400 samples the error shrinks or grows ~2000 times
    inside = _sampled_run(arm, q0, d, kp, kd, 0.99 * c * Y, rate, 400)
    outside = _sampled_run(arm, q0, d, kp, kd, 1.01 * c * Y, rate, 400)
    assert inside[-20:].max() < 0.01 * inside[:10].max()
    assert outside[-20:].max() > 100.0 * outside[:10].max()
