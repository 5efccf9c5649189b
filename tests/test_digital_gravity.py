"""Gravity's slope in the sampled loop's stability check, against the sampled loop linearized another way.

The reference here is the sampled closed loop itself, written from pinocchio
and the definitions alone (nothing of dobkit's maths): one sample is the
computed-torque law and the observer update (forward Euler, or the exact
solution with its inputs held) on the nominal model at the sampled state,
the velocity measured or differenced through a low-pass, an optional delay,
and the nonlinear plant ``M q'' + h = tau + d`` integrated over the period
under the held torque by scipy's ``solve_ivp`` (DOP853, rtol 1e-12).  Its
Jacobian at the held rest state, by central differences of that one-sample
map, gives the spectral radius the package's
:func:`blocks.figure2.digital_stability.sampled_stability` must predict, and the
package's largest stable observer-gain scale ``c`` must sit between a
reference radius below 1 (at ``0.999 c``) and above 1 (at ``1.001 c``).

Arms: a 2-joint arm written here (two links pitching under gravity, light
enough that ``dG/dq`` is comparable to ``M Kp``, held near upright at 50 Hz,
where leaving the slope out moves the limit by 0.2 % (Euler, measured
velocity) to 27 % (Euler, differenced velocity), which the reference
refutes), and the
built-in scope4.  The report's digital section for ``scope4-digital`` is
checked the same way: its poles (true arm 5 % lighter than the nominal one,
the step disturbance) and its gain limit.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

pin = pytest.importorskip("pinocchio")

from scipy.integrate import solve_ivp  # noqa: E402

from blocks.diagram.digital import DigitalController  # noqa: E402
from blocks.figure2.digital_stability import largest_stable_scale, sampled_loop_map, sampled_stability  # noqa: E402
from blocks.model.arm_derivatives import gravity_slopes  # noqa: E402
from blocks.model.urdf import load_urdf_arm  # noqa: E402
from blocks.model.urdf.examples import scope4_urdf  # noqa: E402

pytestmark = pytest.mark.slow

# Two links pitching about y under gravity along -z: masses at the links' ends, small rotational inertias.
TWO_LINK_URDF = """<?xml version="1.0"?>
<robot name="two_link_pitch">
  <link name="base"/>
  <link name="upper">
    <inertial><origin xyz="0.1 0 0"/><mass value="1.0"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial>
  </link>
  <link name="fore">
    <inertial><origin xyz="0.06 0 0"/><mass value="0.5"/>
      <inertia ixx="5e-5" ixy="0" ixz="0" iyy="5e-5" iyz="0" izz="5e-5"/></inertial>
  </link>
  <link name="tip"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="0.2 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="fore"/><child link="tip"/><origin xyz="0.12 0 0"/></joint>
</robot>
"""
# Near upright (rotation about +y lifts +x to -z for a negative angle): gravity pulls away from rest, dG/dq < 0.
Q_TWO = np.array([-1.3, 0.4])
RATE_TWO = 50.0                     # Hz
KP, KD = 180.0, 24.0                # 1/s^2, 1/s
BANDWIDTH_TWO = 30.0                # rad/s: Y = 30 M(q0), Ts lambda = 0.6
#: Relative distance from the computed limit at which the reference must be stable (below) and unstable (above).
BRACKET = 1e-3


# ----------------------------------------------------------------------------------------------------------------
# The reference: one sample of the nonlinear loop, from pinocchio and the definitions
# ----------------------------------------------------------------------------------------------------------------
def _mass(model, data, q):
    M = pin.crba(model, data, np.asarray(q, dtype=float)).copy()
    return np.triu(M) + np.triu(M, 1).T          # crba fills the upper triangle


class ReferenceLoop:
    """The sampled loop held at ``q0`` under a constant disturbance ``d``, one sample at a time.

    State ``[q, v, z, (p, w_prev), (b_0 .. b_{delay-1})]``: the arm, the observer, the velocity filter's previous
    position and estimate (difference velocity) and the commands not yet applied (oldest first).
    """

    def __init__(self, true, nominal, q0, d, Y, rate, method="euler", velocity="measured", cutoff=None, delay=0,
                 kp=KP, kd=KD):
        self.true, self.nominal, self.kp, self.kd = true, nominal, kp, kd
        self.dt, self.dn = true.createData(), nominal.createData()
        self.q0, self.d, self.Y = np.asarray(q0, float), np.asarray(d, float), np.asarray(Y, float)
        self.Ts, self.method, self.diff, self.delay = 1.0 / rate, method, velocity == "difference", delay
        self.pole = 0.0 if cutoff is None else np.exp(-2 * np.pi * cutoff / rate)
        self.n = self.q0.size

    def _split(self, x):
        n = self.n
        q, v, z, rest = x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:]
        p = w_prev = None
        if self.diff:
            p, w_prev, rest = rest[:n], rest[n:2 * n], rest[2 * n:]
        return q, v, z, p, w_prev, [rest[j * self.n:(j + 1) * self.n] for j in range(self.delay)]

    def _rate(self, q, w, tau, z):
        """The observer's ``z' = -Y M^-1 (tau + Y w + z - h^(q, w))`` on the nominal model."""
        h = pin.nonLinearEffects(self.nominal, self.dn, q, w)
        return -self.Y @ np.linalg.solve(_mass(self.nominal, self.dn, q), tau + self.Y @ w + z - h)

    def tick(self, x):
        q, v, z, p, w_prev, buffer = self._split(x)
        Ts = self.Ts
        w = self.pole * w_prev + (1 - self.pole) * (q - p) / Ts if self.diff else v
        d_hat = self.Y @ w + z
        command = (_mass(self.nominal, self.dn, q) @ (self.kp * (self.q0 - q) - self.kd * w)
                   + pin.nonLinearEffects(self.nominal, self.dn, q, w) - d_hat)
        tau = buffer[0] if self.delay else command
        if self.method == "euler":
            z_next = z + Ts * self._rate(q, w, tau, z)
        else:                                   # z' = A z + c with the inputs held: the exact step
            c = self._rate(q, w, tau, np.zeros(self.n))
            A = np.column_stack([self._rate(q, w, tau, e) - c for e in np.eye(self.n)])
            aug = np.zeros((self.n + 1, self.n + 1))
            aug[:self.n, :self.n], aug[:self.n, self.n] = A * Ts, c * Ts
            z_next = (scipy.linalg.expm(aug) @ np.append(z, 1.0))[:self.n]

        def arm(_t, s):
            qs, vs = s[:self.n], s[self.n:]
            force = tau + self.d - pin.nonLinearEffects(self.true, self.dt, qs, vs)
            return np.concatenate((vs, np.linalg.solve(_mass(self.true, self.dt, qs), force)))
        sol = solve_ivp(arm, (0.0, Ts), np.concatenate((q, v)), method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        out = [sol.y[:, -1], z_next]
        if self.diff:
            out += [q, w]
        if self.delay:
            out += buffer[1:] + [command]
        return np.concatenate(out)

    def rest(self):
        """The held rest state: the arm at ``q0``, the torque holding it, the estimate matching it."""
        n = self.n
        zero = np.zeros(n)
        tau = pin.computeGeneralizedGravity(self.true, self.dt, self.q0) - self.d
        d_hat = pin.computeGeneralizedGravity(self.nominal, self.dn, self.q0) - tau      # the command is tau
        x = [self.q0, zero, d_hat]
        if self.diff:
            x += [self.q0, zero]
        x += [tau] * self.delay
        x = np.concatenate(x)
        assert np.max(np.abs(self.tick(x) - x)) < 1e-9          # it is a rest state of the sampled loop
        return x

    def jacobian(self, step=1e-5):
        x0 = self.rest()
        cols = []
        for j in range(x0.size):
            e = np.zeros(x0.size)
            e[j] = step * max(1.0, abs(x0[j]))
            cols.append((self.tick(x0 + e) - self.tick(x0 - e)) / (2 * e[j]))
        return np.column_stack(cols)

    def eigenvalues(self):
        return np.linalg.eigvals(self.jacobian())

    def radius(self):
        return float(np.abs(self.eigenvalues()).max())


# ----------------------------------------------------------------------------------------------------------------
# The two-link arm
# ----------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_link(tmp_path_factory):
    path = tmp_path_factory.mktemp("arm") / "two_link.urdf"
    path.write_text(TWO_LINK_URDF)
    return load_urdf_arm(path, "tip"), pin.buildModelFromUrdf(str(path))


def _settings(arm, rate, method, velocity, cutoff, delay):
    return DigitalController(sample_rate=rate, observer_discretization=method, velocity=velocity,
                             velocity_cutoff=cutoff, delay=delay, joints=arm.joints)


CASES = [("euler", "measured", None, 0), ("zoh", "measured", None, 0), ("euler", "difference", 8.0, 0),
         ("zoh", "measured", None, 1)]


def test_the_two_link_arm_has_a_gravity_slope_that_matters(two_link):
    arm, model = two_link
    data = model.createData()
    S = pin.computeGeneralizedGravityDerivatives(model, data, Q_TWO)
    M = _mass(model, data, Q_TWO)
    # dG/dq against M Kp: not a small correction, and pulling away from rest (a negative eigenvalue of M^-1 S)
    ratio = np.linalg.eigvals(np.linalg.solve(M, S)).real
    assert ratio.min() < -0.2 * KP
    np.testing.assert_allclose(arm.inertia(Q_TWO), M, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("method, velocity, cutoff, delay", CASES)
def test_radius_and_limit_match_the_loop_linearized_by_finite_differences(two_link, method, velocity, cutoff,
                                                                         delay):
    arm, model = two_link
    settings = _settings(arm, RATE_TWO, method, velocity, cutoff, delay)
    Y = BANDWIDTH_TWO * arm.inertia(Q_TWO)
    kp, kd = KP * np.eye(2), KD * np.eye(2)
    verdict = sampled_stability(arm, [Q_TWO], kp, kd, Y, settings)
    d = np.array([0.3, -0.1])                   # a constant disturbance moves the rest torque, not the map

    def reference(scale):
        return ReferenceLoop(model, model, Q_TWO, d, scale * Y, RATE_TWO, method, velocity, cutoff, delay)
    assert verdict.spectral_radius == pytest.approx(reference(1.0).radius(), abs=1e-7)
    c = verdict.largest_stable_scale
    assert np.isfinite(c) and c > 0
    # the rule "stable below c": the loop is stable just below it and unstable just above it
    assert reference((1 - BRACKET) * c).radius() < 1.0 < reference((1 + BRACKET) * c).radius()
    # the slope matters here: the map without it has another radius, and its limit is refuted by the loop
    without = sampled_loop_map(arm.inertia(Q_TWO), kp, kd, Y, settings)
    assert abs(np.abs(np.linalg.eigvals(without)).max() - verdict.spectral_radius) > 1e-3
    c_without = largest_stable_scale(arm.inertia(Q_TWO)[None], kp, kd, Y, settings)
    assert abs(c_without / c - 1.0) > BRACKET
    assert abs(reference(c_without).radius() - 1.0) > 1e-3


def test_the_package_map_is_the_finite_difference_jacobian(two_link):
    """Beyond the radius: every eigenvalue of the package's map is one of the reference's (zoh, difference,
    delay 1: every block of the map at once)."""
    arm, model = two_link
    settings = _settings(arm, RATE_TWO, "zoh", "difference", 8.0, 1)
    Y = BANDWIDTH_TWO * arm.inertia(Q_TWO)
    Phi = sampled_loop_map(arm.inertia(Q_TWO), KP * np.eye(2), KD * np.eye(2), Y, settings,
                           gravity_slopes=gravity_slopes(arm, Q_TWO))
    ref = ReferenceLoop(model, model, Q_TWO, np.zeros(2), Y, RATE_TWO, "zoh", "difference", 8.0, 1)
    mine, theirs = np.linalg.eigvals(Phi), ref.eigenvalues()
    assert mine.size == theirs.size
    for z in theirs:
        assert np.min(np.abs(mine - z)) < 1e-5


# ----------------------------------------------------------------------------------------------------------------
# scope4 and the report's digital section of scope4-digital
# ----------------------------------------------------------------------------------------------------------------
# scope4-digital.toml's numbers, written again here: the reference must not read them from the code
S4_RATE, S4_BANDWIDTH, S4_MASS_SCALE, S4_KP, S4_KD = 1000.0, 10.0, 1.05, 180.0, 36.0
S4_Q0 = np.array([0.0, 0.1, 0.1, 0.0])                   # the path's start: its offset
S4_F_R = np.array([0.05, 0.1, 0.4, 0.00002])             # N m, N m, N, N m


def _scope4_models():
    """The true arm from the URDF, and the nominal one with every body's mass and rotational inertia x 1.05."""
    true = pin.buildModelFromUrdf(str(scope4_urdf()))
    nominal = pin.buildModelFromUrdf(str(scope4_urdf()))
    for i in range(1, nominal.njoints):
        body = nominal.inertias[i]
        nominal.inertias[i] = pin.Inertia(body.mass * S4_MASS_SCALE, body.lever.copy(), body.inertia * S4_MASS_SCALE)
    return true, nominal


def test_scope4_pitch_joint_radius_and_limit_match_the_reference():
    model = pin.buildModelFromUrdf(str(scope4_urdf()))
    arm = load_urdf_arm(scope4_urdf(), "tool_tip")
    q = np.array([0.2, 0.7, 0.15, 0.3])                   # pitched: gravity's slope on the pitch joint is not zero
    assert np.max(np.abs(gravity_slopes(arm, q))) > 0.1
    Y = 40.0 * arm.inertia(q)
    settings = _settings(arm, 100.0, "zoh", "difference", 20.0, 0)
    verdict = sampled_stability(arm, [q], KP * np.eye(4), KD * np.eye(4), Y, settings)

    def reference(scale):
        return ReferenceLoop(model, model, q, np.zeros(4), scale * Y, 100.0, "zoh", "difference", 20.0, 0)
    assert verdict.spectral_radius == pytest.approx(reference(1.0).radius(), abs=1e-7)
    c = verdict.largest_stable_scale
    assert reference((1 - BRACKET) * c).radius() < 1.0 < reference((1 + BRACKET) * c).radius()


@pytest.fixture(scope="module")
def scope4_digital():
    from analysis.linear.digital import digital_analysis
    from blocks.scenarios.scenario import load_scenario
    s = load_scenario("scope4-digital")
    return s, digital_analysis(s, rates_hz=(S4_RATE,), simulate_noise=False)


def test_scope4_digital_poles_are_the_sampled_loops(scope4_digital):
    """The report's z-plane poles at the path's start: the true arm (5 % lighter than the nominal) held at q0 under
    the step f_r, every eigenvalue of the reference's one-sample map among them."""
    s, result = scope4_digital
    true, nominal = _scope4_models()
    assert s.controller.sample_rate == S4_RATE and s.controller.observer_discretization == "euler"
    assert s.controller.velocity == "measured" and s.controller.delay == 0
    Y = S4_BANDWIDTH * _mass(nominal, nominal.createData(), S4_Q0)
    ref = ReferenceLoop(true, nominal, S4_Q0, S4_F_R, Y, S4_RATE, kp=S4_KP, kd=S4_KD)
    theirs = ref.eigenvalues()
    mine = np.array([m.z for m in result.poles.modes])
    np.testing.assert_allclose(result.poles.q0, S4_Q0, rtol=0, atol=1e-15)
    assert result.poles.spectral_radius == pytest.approx(np.abs(theirs).max(), abs=1e-7)
    for z in theirs:
        assert np.min(np.abs(mine - z)) < 1e-6


def test_scope4_digital_gain_limit_is_the_loops(scope4_digital):
    """The report's answer "the observer gain may be raised up to c times": at the configurations it checks, the
    loop on the nominal model is stable at 0.999 c and unstable at 1.001 c (at one of them)."""
    s, result = scope4_digital
    _, nominal = _scope4_models()
    Y = S4_BANDWIDTH * _mass(nominal, nominal.createData(), S4_Q0)
    np.testing.assert_allclose(result.gain_limit.observer_gain, Y, rtol=1e-12, atol=1e-15)
    c = result.largest_stable_scale
    assert f"{c:.3g} times the scenario's (Y = {S4_BANDWIDTH:g} M^(q0))" in result.answer

    def worst(scale):
        return max(ReferenceLoop(nominal, nominal, q, S4_F_R, scale * Y, S4_RATE, kp=S4_KP, kd=S4_KD).radius()
                   for q in result.gain_limit.configurations)
    assert worst((1 - BRACKET) * c) < 1.0 < worst((1 + BRACKET) * c)


def test_scope4_digital_section_shows_those_numbers(scope4_digital):
    """The report's section 8 for scope4-digital: the radius, the rule and the limit are the ones checked above,
    and its words say that gravity's slope is in the map."""
    from types import SimpleNamespace

    from analysis.report.view.digital import digital_section
    from analysis.report.view.text import fmt
    s, result = scope4_digital
    section = digital_section(SimpleNamespace(digital=result), {}, s.robot)
    assert f"max |z| = {fmt(result.poles.spectral_radius, 6)}" in section.poles.caption
    assert f"Ts lambda_max(Y M^-1) < {fmt(result.ts_lambda_limit, 5)}" in section.rule_text
    assert "dG/dq" in section.rule_text
    rate_row = next(r for r in section.gain_limit.rows if r[0].text == fmt(S4_RATE, 5))
    assert fmt(result.largest_stable_scale, 4) in [c.text for c in rate_row]
