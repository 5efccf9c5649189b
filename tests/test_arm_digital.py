"""The sampled controller and measurement noise for any arm (a URDF arm: scope4, the Panda).

The sampled loop of scope4 is held against a loop written here from pinocchio
and the definitions alone: the plant ``M q'' + h = tau + f_r`` (``crba``,
``nonLinearEffects``) integrated by scipy between ticks under the held
torque; at each tick the computed-torque law and the forward-Euler observer
update written out by hand on a nominal model made here by scaling the URDF's
bodies.  The per-joint settings are checked on both sides of each rule.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from scipy.integrate import solve_ivp  # noqa: E402

from blocks.diagram.digital import DigitalController, actuator, digital_controller, digital_observer, encoder  # noqa: E402
from blocks.engines.compiled import numba_or_none  # noqa: E402
from blocks.figure2.digital_loop import simulate_sampled  # noqa: E402
from blocks.figure2.digital_stability import scenario_stability  # noqa: E402
from blocks.model.noise import MeasurementNoise  # noqa: E402
from blocks.model.rrpr.parameters import PAPER_PARAMETERS  # noqa: E402
from blocks.model.urdf.examples import scope4_urdf  # noqa: E402
from blocks.scenarios.scenario import ScenarioError, load_scenario  # noqa: E402

pytestmark = pytest.mark.slow

# The scenario's numbers, written again here (scope4-digital.toml): the test's loop must not read them from the code
KP, KD, BANDWIDTH, MASS_SCALE = 180.0, 36.0, 10.0, 1.05
AMPLITUDE = np.array([0.3, 0.2, 0.03, 0.8])
OMEGA = np.array([0.8, 1.1, 1.5, 2.0])
OFFSET = np.array([0.0, 0.1, 0.1, 0.0])
F_R = np.array([0.05, 0.1, 0.4, 0.00002])
RATE, T_FINAL, OUTPUT_STEP = 1000.0, 1.0, 0.005
#: The scenario without encoder quantization, torque limits and noise: the loop the test writes out
EXACT = {"simulation.t_final": T_FINAL, "controller.position_resolution": 0.0, "controller.torque_limit": 0.0,
         "noise.q_std": 0.0, "noise.dq_std": 0.0}


def _reference(t):
    """``q_ref = offset + amplitude sin(omega t)`` and its two derivatives."""
    s, c = np.sin(OMEGA * t), np.cos(OMEGA * t)
    return OFFSET + AMPLITUDE * s, AMPLITUDE * OMEGA * c, -AMPLITUDE * OMEGA ** 2 * s


def _models():
    """The true arm from the URDF, and the nominal one with every body's mass and rotational inertia x 1.05."""
    true = pin.buildModelFromUrdf(str(scope4_urdf()))
    nominal = pin.buildModelFromUrdf(str(scope4_urdf()))
    for i in range(1, nominal.njoints):
        body = nominal.inertias[i]
        nominal.inertias[i] = pin.Inertia(body.mass * MASS_SCALE, body.lever.copy(), body.inertia * MASS_SCALE)
    return true, nominal


def _mass(model, data, q):
    M = pin.crba(model, data, q).copy()
    return np.triu(M) + np.triu(M, 1).T          # crba fills the upper triangle


def _hand_loop(t_out):
    """The sampled loop, tick by tick: exact encoders, measured velocity, Euler observer, no delay, no limit."""
    true, nominal = _models()
    d_true, d_nom = true.createData(), nominal.createData()
    Ts = 1.0 / RATE
    q, dq, _ = _reference(0.0)
    Y = BANDWIDTH * _mass(nominal, d_nom, q)                  # observer_bandwidth: Y = omega M^(q_ref(0))
    z = -Y @ dq                                               # d_hat(0) = Y dq(0) + z(0) = 0
    x = np.concatenate((q, dq))
    n = q.size
    out = np.empty((t_out.size, n))
    ticks = int(round(t_out[-1] * RATE))
    for k in range(ticks + 1):
        t_k = k * Ts
        q, dq = x[:n], x[n:]
        q_ref, dq_ref, ddq_ref = _reference(t_k)
        M_nom = _mass(nominal, d_nom, q)
        h_nom = pin.nonLinearEffects(nominal, d_nom, q, dq).copy()
        d_hat = Y @ dq + z
        tau = M_nom @ (ddq_ref + KD * (dq_ref - dq) + KP * (q_ref - q)) + h_nom - d_hat
        z = z + Ts * (-Y @ np.linalg.solve(M_nom, tau + d_hat - h_nom))

        def rhs(_t, xs, tau=tau):
            qs, dqs = xs[:n], xs[n:]
            return np.concatenate((dqs, np.linalg.solve(_mass(true, d_true, qs),
                                                        tau + F_R - pin.nonLinearEffects(true, d_true, qs, dqs))))
        inside = (t_out >= t_k - 1e-12) & (t_out < t_k + Ts - 1e-12)
        if k == ticks:
            out[inside] = q
            break
        sol = solve_ivp(rhs, (t_k, t_k + Ts), x, method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
        assert sol.success
        if inside.any():
            out[inside] = sol.sol(t_out[inside])[:n].T
        x = sol.y[:, -1]
    return out


def _joint_signal(response, prefix, n):
    labels = list(response.output_labels)
    return np.array([response.outputs[labels.index(f"{prefix}[{i}]")] for i in range(n)])


@pytest.mark.parametrize("engine", ["compiled", "fast"])
def test_sampled_scope4_equals_a_loop_written_with_pinocchio(engine):
    if engine == "compiled" and numba_or_none() is None:
        pytest.skip("the compiled engine needs numba")
    s = load_scenario("scope4-digital").with_changes(EXACT)
    assert s.controller.sample_rate == RATE and s.controller.observer_discretization == "euler"
    assert s.noise is None and s.simulation.output_step == OUTPUT_STEP
    r = simulate_sampled(s, engine=engine)
    t = np.asarray(r.time)
    q = _joint_signal(r, "q", 4)
    np.testing.assert_allclose(_joint_signal(r, "tau_dis", 4), np.tile(F_R[:, None], t.size), rtol=0, atol=0)
    q_hand = _hand_loop(t).T
    q_ref = _reference(t[:, None])[0].T
    e_code, e_hand = q - q_ref, q_hand - q_ref
    rms_code, rms_hand = np.sqrt(np.mean(e_code ** 2, axis=1)), np.sqrt(np.mean(e_hand ** 2, axis=1))
    np.testing.assert_allclose(rms_code, rms_hand, rtol=0, atol=1e-6)
    np.testing.assert_allclose(q, q_hand, rtol=0, atol=1e-6)
    # the loop tracks: the errors are those of a 13 rad/s PD loop on a 1 - 2 rad/s path, not of a broken one
    assert np.all(rms_hand < 0.02) and np.all(rms_hand > 1e-6)


@pytest.mark.skipif(numba_or_none() is None, reason="the compiled engine needs numba")
def test_scope4_digital_compiled_equals_numpy_with_noise_encoders_and_limits():
    # a torque limit that acts on the insertion joint, with the quantized encoders and the noise of the scenario
    s = load_scenario("scope4-digital").with_changes({"simulation.t_final": 0.1,
                                                      "controller.torque_limit": [20, 1.5, 40, 0.5]})
    assert s.noise is not None and s.noise.table.shape[0] == 8
    fast = simulate_sampled(s, engine="fast")
    compiled = simulate_sampled(s, engine="compiled")
    for prefix in ("q", "dq", "tau", "tau_cmd", "d_hat", "q_s", "q_meas"):
        np.testing.assert_allclose(_joint_signal(compiled, prefix, 4), _joint_signal(fast, prefix, 4),
                                   rtol=0, atol=1e-9, err_msg=prefix)
    tau = _joint_signal(fast, "tau", 4)
    assert np.max(np.abs(tau[1])) == pytest.approx(1.5)             # the limit acted and held
    cmd = _joint_signal(fast, "tau_cmd", 4)
    assert np.max(np.abs(cmd[1])) > 1.5
    q_s = _joint_signal(fast, "q_s", 4)
    res = np.array(s.controller.position_resolution)
    np.testing.assert_allclose(q_s / res[:, None], np.rint(q_s / res[:, None]), rtol=0, atol=1e-6)


def test_the_pre_run_check_takes_the_arm_euler_limit_is_two():
    # Euler with measured velocity: Ts lambda_max(Y M^-1) < 2 exactly, whatever the arm (docs/model.md)
    s = load_scenario("scope4-digital").with_changes({"simulation.t_final": 0.05, "controller.sample_rate": 100.0,
                                                      "noise.q_std": 0.0})
    verdict = scenario_stability(s)
    assert verdict.ts_lambda_limit == pytest.approx(2.0, rel=1e-5)
    # Y = omega M^(q0): Y M^-1 = omega I at q0, so Ts lambda_max >= omega Ts
    assert verdict.ts_lambda_max >= BANDWIDTH / 100.0 * (1 - 1e-9)
    inside = s.with_changes({"gains.observer_bandwidth": 0.9 * 2.0 / verdict.ts_lambda_max * BANDWIDTH})
    outside = s.with_changes({"gains.observer_bandwidth": 1.1 * 2.0 / verdict.ts_lambda_max * BANDWIDTH})
    assert scenario_stability(inside, limit=False).stable
    assert not scenario_stability(outside, limit=False).stable
    with pytest.raises(ScenarioError, match=r"unstable.*Ts lambda_max\(Y M\^-1\) < 2"):
        simulate_sampled(outside, engine="fast")
    r = simulate_sampled(inside, engine="fast")
    assert np.all(np.isfinite(r.outputs))


# ----------------------------------------------------------------------------------------------------------------
# Per-joint settings: a number or one per joint of the arm, both sides of each rule
# ----------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scope4():
    return load_scenario("scope4-digital").robot


@pytest.mark.parametrize("key, units", [("position_resolution", "rad, rad, m, rad"), ("torque_limit", "N m, N m, N, N m")])
def test_controller_setting_is_a_number_or_one_per_joint(scope4, key, units):
    joints = scope4.joints
    assert getattr(DigitalController(1000.0, joints=joints, **{key: 0.25}), key) == (0.25,) * 4
    assert getattr(DigitalController(1000.0, joints=joints, **{key: [0, 0.1, 0, 2]}), key) == (0.0, 0.1, 0.0, 2.0)
    assert getattr(DigitalController(1000.0, joints=joints, **{key: 0}), key) == (0.0,) * 4     # 0 is allowed
    for bad in ([0.1] * 3, [0.1] * 5, -1e-12, [0, 0, -0.1, 0], [0, math.inf, 0, 0], [True, 0, 0, 0], "x"):
        with pytest.raises(ValueError) as err:
            DigitalController(1000.0, joints=joints, **{key: bad})
        text = str(err.value)
        assert f"'controller.{key}' must be 4 finite numbers >= 0 ({units})" in text
        assert "['yaw', 'pitch', 'insertion', 'roll']" in text and repr(bad) in text


def test_the_default_controller_is_the_default_arms_and_names_its_joints():
    """Without joints the settings are the default scenario's arm's (the paper's RRPR: 4 joints, a slide third);
    a bad per-joint value names the joints, as for any arm."""
    c = DigitalController(1000.0)
    assert c.position_resolution == (0.0,) * 4 and c.torque_limit == (0.0,) * 4 and c.n == 4
    with pytest.raises(ValueError, match=r"^'controller.torque_limit' must be 4 finite numbers >= 0 "
                                         r"\(N m, N m, N, N m\), one per joint of \['theta1', 'theta2', 'd3', "
                                         r"'theta4'\] or one for all, got \[1, 1, -1, 1\]$"):
        DigitalController(1000.0, torque_limit=[1, 1, -1, 1])


def test_scenario_per_joint_settings_name_the_key_n_and_the_arm():
    s = load_scenario("scope4-digital")
    assert s.with_changes({"controller.torque_limit": 3.0}).controller.torque_limit == (3.0,) * 4
    assert s.with_changes({"noise.dq_std": 1e-3}).noise.dq_std == (1e-3,) * 4
    with pytest.raises(ScenarioError, match=r"'controller.position_resolution' has 3 values; the arm 'scope4' has 4 "
                                            r"joints \(yaw, pitch, insertion, roll\)"):
        s.with_changes({"controller.position_resolution": [0, 0, 0]})
    with pytest.raises(ScenarioError, match=r"'controller.torque_limit' must be >= 0.0, got -1.0"):
        s.with_changes({"controller.torque_limit": -1.0})
    with pytest.raises(ScenarioError, match=r"'controller.torque_limit' must be 4 finite numbers >= 0 .* "
                                            r"\(arm 'scope4', 4 joints\)"):
        s.with_changes({"controller.torque_limit": [1, 1, -1, 1]})
    with pytest.raises(ScenarioError, match=r"noise.q_std must be a number or 4 finite numbers >= 0 \(rad, rad, m, rad\)"
                                            r", one per joint of \['yaw', 'pitch', 'insertion', 'roll'\].*"
                                            r"\(arm 'scope4', 4 joints\)"):
        s.with_changes({"noise.q_std": [1e-5] * 5})
    with pytest.raises(ScenarioError, match=r"noise.dq_std must be a number or 4 finite numbers >= 0"):
        s.with_changes({"noise.dq_std": -1e-9})


def test_a_seven_joint_arm_takes_the_controller_and_noise():
    panda = load_scenario("panda")
    n = panda.robot.n
    assert n == 7
    s = panda.with_changes({"controller.sample_rate": 1000.0, "controller.torque_limit": 50.0,
                            "controller.position_resolution": [1e-5] * n, "noise.q_std": 1e-5, "noise.seed": 3})
    c = s.controller
    assert c.n == n and c.torque_limit == (50.0,) * n and c.position_resolution == (1e-5,) * n
    assert s.noise.table.shape[0] == 2 * n
    n_q, n_dq = s.noise.sample(np.array([0.0, 0.0123]))
    assert n_q.shape == (2, n) and n_dq.shape == (2, n) and np.all(n_dq == 0) and np.all(n_q != 0)
    # the blocks are sized and named by the arm
    enc, act = encoder(c), actuator(c)
    ctl = digital_controller(s.nominal, s.kp, s.kd, c)
    obs = digital_observer(s.nominal, s.observer_gain, c)
    assert enc.ninputs == 2 * n and act.noutputs == n and ctl.noutputs == n and obs.nstates == n
    assert ctl.output_labels[-1] == f"tau_cmd[{n - 1}]" and obs.input_labels[-1] == f"dq_s[{n - 1}]"
    with pytest.raises(ScenarioError, match=r"'controller.torque_limit' has 4 values; the arm 'panda' has 7 joints"):
        panda.with_changes({"controller.sample_rate": 1000.0, "controller.torque_limit": [1, 1, 1, 1]})


def test_settings_for_other_joints_are_refused_by_the_blocks(scope4):
    with pytest.raises(ValueError, match=r"controller settings are for the 4 joints \['theta1', 'theta2', 'd3', "
                                         r"'theta4'\], but the arm has the 4 joints \['yaw', 'pitch', 'insertion'"):
        digital_controller(scope4, 180.0, 36.0, DigitalController(1000.0))
    c = DigitalController(1000.0, joints=scope4.joints)
    with pytest.raises(ValueError, match=r"settings are for the 4 joints \['yaw'.*the arm has the 4 joints "
                                         r"\['theta1'"):
        digital_observer(PAPER_PARAMETERS, 10.0, c)
    assert digital_observer(scope4, 1.0, c).nstates == 4


def test_noise_of_n_joints_is_seeded_and_keeps_the_rrpr_draw():
    from blocks.model.joints import JointSpace
    three = JointSpace(("a", "b", "c"), ("revolute", "prismatic", "revolute"))
    noise = MeasurementNoise(q_std=[1e-3, 2e-3, 0.0], dq_std=0.5, seed=11, sample_period=0.01, t_final=1.0,
                             joints=three)
    assert noise.table.shape == (6, 102)
    draws = np.random.default_rng(11).standard_normal((102, 6)) * np.array([1e-3, 2e-3, 0.0, 0.5, 0.5, 0.5])
    np.testing.assert_array_equal(noise.table, draws.T)
    # halfway between two samples: the mean of the two
    n_q, n_dq = noise.sample(0.015)
    np.testing.assert_allclose(n_q, 0.5 * (draws[1, :3] + draws[2, :3]), rtol=1e-12, atol=0)
    np.testing.assert_allclose(n_dq, 0.5 * (draws[1, 3:] + draws[2, 3:]), rtol=1e-12, atol=0)
    rrpr = MeasurementNoise(q_std=(1e-4, 1e-4, 1e-5, 1e-4), seed=2, t_final=0.5, joints=PAPER_PARAMETERS.joints)
    expected = np.random.default_rng(2).standard_normal((502, 8)) * np.array([1e-4, 1e-4, 1e-5, 1e-4, 0, 0, 0, 0])
    np.testing.assert_array_equal(rrpr.table, expected.T)
    with pytest.raises(ValueError, match=r"^noise.q_std must be a number or 4 finite numbers >= 0 \(rad, rad, m, rad\), "
                                         r"one per joint of \['theta1', 'theta2', 'd3', 'theta4'\], got \(1, 2, 3\)$"):
        MeasurementNoise(q_std=(1, 2, 3), joints=PAPER_PARAMETERS.joints)
