"""The digital controller and mixed continuous/discrete diagrams, against independent derivations.

* a double integrator under sampled PD + Euler observer: the exact discrete closed form (ZOH) of the loop;
* the arm's digital loop (delay, saturation, quantization, differenced velocity): a sampled implementation
  written here from the [controller] section's definition, with the plant integrated by solve_ivp;
* the Euler observer's stability limit 2 / (Ts lambda_max(Y M^-1)) with measured velocity (docs/model.md:
  lambda_min(M) = k4 = 0.25), refused before the run for both updates beyond it (tests/test_sampled_stability.py
  has the zoh, velocity-difference and delay limits, which are lower);
* convergence to the continuous loop as the rate grows, and the observer fed the saturated torque (no wind-up).
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import blocks
from blocks.diagram.digital import DigitalController
from blocks.engines.hybrid import HybridError, HybridSystem
from blocks.figure2.digital_loop import sampled_initial_state, sampled_loop, simulate_sampled
from blocks.figure2.digital_stability import sampled_stability
from blocks.figure2.metrics import signal
from blocks.scenarios.scenario import ScenarioError

HELD = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.0, 0.0, 0.0, 0.0],
        "trajectory.offset": [0.3, 1.2, 0.1, 0.2]}
SINE = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.2, 0.3, 0.02, 0.5],
        "trajectory.omega": [1.0, 1.5, 2.0, 2.5], "trajectory.offset": [0.3, 1.2, 0.1, 0.2]}
TIGHT = {"simulation.rtol": 1e-10, "simulation.atol": 1e-12}


def _scenario(changes: dict) -> blocks.Scenario:
    return blocks.load_scenario("paper").with_changes(changes)


# --------------------------------------------------------------------------------------------------------------
# The engine: a double integrator with a closed form
# --------------------------------------------------------------------------------------------------------------
def test_sampled_double_integrator_equals_its_discrete_closed_form():
    m, d, kp, kd, Y, Ts = 2.0, 0.7, 40.0, 9.0, 25.0, 0.01
    plant = ct.nlsys(lambda t, x, u, p: np.array([x[1], (u[0] + d) / m]), lambda t, x, u, p: x,
                     inputs=["u"], outputs=["q", "v"], states=["q", "v"], name="plant")
    control = ct.nlsys(None, lambda t, x, u, p: np.array([m * (-kp * u[0] - kd * u[1]) - u[2]]),
                       inputs=["q", "v", "d_hat"], outputs=["u"], name="controller", dt=Ts)
    observer = ct.nlsys(lambda t, z, u, p: z - Ts * (Y / m) * (u[0] + Y * u[1] + z),
                        lambda t, z, u, p: Y * u[1] + z, inputs=["u", "v"], outputs=["d_hat"], states=["z"],
                        name="observer", dt=Ts)
    loop = HybridSystem([plant, control, observer], outlist=["q", "v", "u", "d_hat"])
    x0 = np.array([0.1, -0.2, 0.0])
    t = np.arange(0, 101) * Ts
    _, out = loop.simulate(x0, t, "DOP853", rtol=1e-12, atol=1e-14)

    # ZOH on the input: x_{k+1} = Phi x_k + Gamma (u_k + d)
    Phi, Gamma = np.array([[1.0, Ts], [0.0, 1.0]]), np.array([Ts ** 2 / (2 * m), Ts / m])
    x, z, want = x0[:2].copy(), x0[2], []
    for _ in t:
        d_hat = Y * x[1] + z
        u = m * (-kp * x[0] - kd * x[1]) - d_hat
        want.append([x[0], x[1], u, d_hat])
        z = z - Ts * (Y / m) * (u + Y * x[1] + z)
        x = Phi @ x + Gamma * (u + d)
    np.testing.assert_allclose(out.T, np.array(want), rtol=1e-9, atol=1e-11)
    assert abs(out[3, -1] - d) < 0.05 * d          # the estimate has converged to the disturbance


def test_blocks_at_several_rates_run_at_their_own_instants():
    """A block at twice the base period updates at every other tick and holds its output in between."""
    Ts = 0.01
    src = ct.nlsys(None, lambda t, x, u, p: np.array([t]), inputs=0, outputs=["time"], name="clock")
    fast = ct.nlsys(lambda t, x, u, p: u, lambda t, x, u, p: u, inputs=["time"], outputs=["fast"], states=1,
                    name="fast", dt=Ts)
    slow = ct.nlsys(lambda t, x, u, p: u, lambda t, x, u, p: u, inputs=["time"], outputs=["slow"], states=1,
                    name="slow", dt=2 * Ts)
    loop = HybridSystem([src, fast, slow], outlist=["fast", "slow"])
    t = np.arange(0, 9) * Ts / 2
    _, out = loop.simulate(np.zeros(2), t)
    np.testing.assert_allclose(out[0], np.floor(t / Ts + 1e-9) * Ts, atol=1e-15)
    np.testing.assert_allclose(out[1], np.floor(t / (2 * Ts) + 1e-9) * 2 * Ts, atol=1e-15)


def test_periods_that_are_not_whole_multiples_are_refused():
    a = ct.nlsys(None, lambda t, x, u, p: u, inputs=["x"], outputs=["y"], name="a", dt=0.01)
    b = ct.nlsys(None, lambda t, x, u, p: u, inputs=["y"], outputs=["x"], name="b", dt=0.015)
    with pytest.raises(HybridError, match="0.015 s is not a whole multiple of the base period 0.01"):
        HybridSystem([a, b], outlist=["y"])


# --------------------------------------------------------------------------------------------------------------
# The arm's digital loop against the [controller] section's definition
# --------------------------------------------------------------------------------------------------------------
def _reference_sampled_run(s, n_samples: int) -> np.ndarray:
    """q at the sample instants, from the definition of [controller] (docs in blocks/diagram/digital.py), written here."""
    c = s.controller
    Ts, n = c.period, 4
    res, limit = np.array(c.position_resolution), np.array([v if v > 0 else np.inf for v in c.torque_limit])
    quant = lambda q: np.where(res > 0, np.round(q / np.where(res > 0, res, 1)) * res, q)   # noqa: E731
    a = math.exp(-2 * math.pi * c.velocity_cutoff * Ts) if c.velocity_cutoff else 0.0
    Kp, Kd, Y = np.diag(s.kp), np.diag(s.kd), s.observer_gain
    q, dq, _ = (np.array(v) for v in s.trajectory.evaluate(0.0))
    q_prev, v = quant(q) - Ts * dq, dq.copy()
    z = -Y @ dq

    def command(k, q_s, dq_s, z):
        q_ref, dq_ref, ddq_ref = s.trajectory.evaluate(k * Ts)
        M_hat = blocks.inertia(q_s, s.nominal)
        h_hat = blocks.coriolis_vector(q_s, dq_s, s.nominal) + blocks.gravity(q_s, s.nominal)
        d_hat = Y @ dq_s + z
        return M_hat @ (ddq_ref + Kd * (dq_ref - dq_s) + Kp * (q_ref - q_s)) + h_hat - d_hat, d_hat, M_hat, h_hat

    def sample(q, q_prev, v):
        q_s = quant(q)
        if c.velocity == "difference":
            v = a * v + (1 - a) * (q_s - q_prev) / Ts
            return q_s, v, v
        return q_s, dq, v

    q_s, dq_s, _ = sample(q, q_prev, v)
    buffer = [command(0, q_s, dq_s, z)[0]] * c.delay
    out = []
    for k in range(n_samples):
        out.append(q.copy())
        q_s, dq_s, v = sample(q, q_prev, v)
        tau_cmd, d_hat, M_hat, h_hat = command(k, q_s, dq_s, z)
        buffer.append(tau_cmd)
        tau = np.clip(buffer.pop(0), -limit, limit)
        z = z + Ts * (-Y @ np.linalg.solve(M_hat, tau + d_hat - h_hat))
        q_prev = q_s

        def f(t, x):
            force = tau + blocks.external_disturbance(t, x[:n], x[n:], s.disturbance, s.robot)
            return np.concatenate([x[n:], blocks.forward_dynamics(x[:n], x[n:], force, s.robot)])
        sol = solve_ivp(f, (k * Ts, (k + 1) * Ts), np.concatenate([q, dq]), method="DOP853", rtol=1e-11, atol=1e-13)
        q, dq = sol.y[:n, -1], sol.y[n:, -1]
    return np.array(out).T


@pytest.mark.parametrize("settings", [
    {"controller.sample_rate": 500.0},
    {"controller.sample_rate": 500.0, "controller.delay": 1, "controller.torque_limit": [0, 0, 3.2, 0],
     "controller.position_resolution": [2 * math.pi / 2 ** 12] * 2 + [1e-5, 2 * math.pi / 2 ** 12],
     "controller.velocity": "difference", "controller.velocity_cutoff": 100.0},
], ids=["plain", "delay, limit, encoders, difference"])
def test_digital_loop_follows_the_definition_of_the_controller_section(settings):
    s = _scenario(SINE | TIGHT | {"simulation.t_final": 0.1, "simulation.output_step": 0.002} | settings)
    got = signal(simulate_sampled(s), "q")
    want = _reference_sampled_run(s, got.shape[1])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_observer_discretizations_agree_to_first_order():
    """zoh and Euler differ by O(Ts) in the estimate; both approach the continuous estimate."""
    base = SINE | {"simulation.t_final": 1.0, "simulation.output_step": 0.01}
    cont = signal(blocks.simulate(_scenario(base)), "d_hat")
    gaps = []
    for method in ("euler", "zoh"):
        run = simulate_sampled(_scenario(base | {"controller.sample_rate": 2000.0,
                                                 "controller.observer_discretization": method}))
        gaps.append(np.abs(signal(run, "d_hat") - cont)[:, 20:].max())
    assert max(gaps) < 0.05


# --------------------------------------------------------------------------------------------------------------
# What sampling does: convergence, the Euler observer's limit, saturation
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_sampled_runs_converge_to_the_continuous_run_at_first_order():
    base = SINE | {"simulation.t_final": 1.0, "simulation.output_step": 0.005}
    cont = signal(blocks.simulate(_scenario(base | TIGHT)), "q")
    rates = np.array([250.0, 500.0, 1000.0, 2000.0])
    errors = [np.abs(signal(simulate_sampled(_scenario(base | TIGHT | {"controller.sample_rate": r})), "q")
                     - cont).max() for r in rates]
    order = -np.polyfit(np.log(rates), np.log(errors), 1)[0]
    assert 0.85 < order < 1.2, (errors, order)


def test_the_euler_observer_limit_is_two_over_ts_lambda_max():
    """lambda_max(Y M^-1) = Y / k4 = 500 / 0.25 = 2000 1/s: with measured velocity the Euler update is stable
    below Ts = 1 ms; beyond that rate both updates are refused (zoh's own limit is lower still)."""
    q = np.array([[0.3, 1.2, 0.1, 0.2]])
    nominal, kp, kd = blocks.PAPER_PARAMETERS, 180 * np.eye(4), 36 * np.eye(4)
    for rate, stable in ((950.0, False), (1050.0, True)):
        margin = sampled_stability(nominal, q, kp, kd, 500 * np.eye(4), DigitalController(sample_rate=rate))
        assert margin.stable is stable
        assert margin.ts_lambda_max == pytest.approx(2000.0 / rate, rel=1e-9)
        assert margin.largest_stable_scale == pytest.approx(2 * rate / 2000.0, rel=1e-6)
    s = _scenario(HELD | {"gains.observer": 500.0, "controller.sample_rate": 950.0, "simulation.t_final": 0.2})
    with pytest.raises(ScenarioError, match=r"controller.sample_rate' = 950 Hz.*gains.observer.*< 2, i.e. at most "
                       r"0.95 x gains.observer.*raise 'controller.sample_rate' to 1000 Hz"):
        simulate_sampled(s)
    zoh = s.with_changes({"controller.observer_discretization": "zoh"})
    limit = sampled_stability(nominal, q, kp, kd, 500 * np.eye(4), zoh.controller).largest_stable_scale
    assert limit < 0.95
    with pytest.raises(ScenarioError, match=r"controller.sample_rate' = 950 Hz.*observer_discretization = \"zoh\""
                       r".*gains.observer.*at most 0.9\d* x gains.observer"):
        simulate_sampled(zoh)


def _estimate_error(changes: dict, t_final: float, feedback: bool = True) -> float:
    """Largest |d - d_hat| at the end of a held-arm run (paper step disturbance, Y = 500 I), past the pre-run check.

    ``feedback=False``: the controller does not subtract d_hat (the observer only estimates)."""
    d = np.array([1.43, 1.6, 1.4, 1.2])
    s = _scenario(HELD | {"gains.observer": 500.0, "simulation.output_step": 0.001, "simulation.t_final": t_final,
                          "initial.d_hat": [0.0, 0.0, 0.0, 0.0]} | changes)
    loop = sampled_loop(s)
    if not feedback:
        from blocks.diagram.digital import digital_observer
        plain = sampled_loop(s, observer=False)
        observer = digital_observer(s.nominal, s.observer_gain, s.controller)
        loop = HybridSystem(plain.blocks() + [observer], outlist=plain.output_labels + [f"d_hat[{i}]" for i in range(4)])
    _, out = loop.simulate(sampled_initial_state(loop, s), s.simulation.time_grid)
    d_hat = out[[loop.output_labels.index(f"d_hat[{i}]") for i in range(4)]]
    return float(np.abs(d_hat - d[:, None])[:, -1].max())


def test_in_the_loop_both_discretizations_diverge_beyond_the_euler_limit():
    """With the controller subtracting d_hat and the plant integrating the held torque, Euler's estimate error
    obeys e_{k+1} = (I - Ts Y M^-1) e_k (docs/model.md, "Digital observer"): stable at 1050 Hz (Ts lambda =
    1.905), growing by |1 - Ts lambda| = 1.105 per sample at 950 Hz (110x in 50 ms); zoh, whose loop limit is
    lower, diverges there too."""
    assert _estimate_error({"controller.sample_rate": 1050.0}, 0.5) < 1e-3     # slowest mode 500 x 0.085 = 42 1/s
    for method in ("euler", "zoh"):
        assert _estimate_error({"controller.sample_rate": 950.0, "controller.observer_discretization": method},
                               0.05) > 10.0


def test_alone_the_zoh_observer_is_stable_beyond_the_euler_limit():
    """Estimating only (the torque does not depend on d_hat): the zoh update's error map is e^{-Ts Y M^-1}, stable
    at any rate, plus a term that follows the arm's acceleration (it settles with the PD's slow pole, 6 1/s);
    Euler's is I - Ts Y M^-1, unstable beyond 2 / (Ts lambda_max)."""
    zoh = {"controller.sample_rate": 950.0, "controller.observer_discretization": "zoh"}
    assert _estimate_error(zoh, 2.0, feedback=False) < 1e-4
    assert _estimate_error({"controller.sample_rate": 950.0}, 0.05, feedback=False) > 10.0


def test_the_observer_sees_the_saturated_torque_and_does_not_wind_up():
    """Joint 3 needs k4 g + f_r = 3.85 N to hold; limited to 3 N it sags, and an observer fed the command
    (not the applied torque) would attribute the missing force to the disturbance."""
    s = _scenario(HELD | {"controller.sample_rate": 1000.0, "controller.torque_limit": [0, 0, 3.0, 0],
                          "simulation.t_final": 1.0, "simulation.output_step": 0.01})
    run = simulate_sampled(s)
    d_hat, tau = signal(run, "d_hat"), signal(run, "tau")
    assert np.all(np.abs(tau[2]) <= 3.0 + 1e-12) and np.abs(signal(run, "tau_cmd")[2]).max() > 3.5
    assert d_hat[2, -1] == pytest.approx(1.4, abs=0.02)

    loop = sampled_loop(s)
    wrong = []
    for block in loop.blocks():
        if block.name == "observer":                        # wired to the command instead of the applied torque
            block = block.copy(name="observer")
            block.set_inputs([f"tau_cmd[{i}]" for i in range(4)] + block.input_labels[4:])
        wrong.append(block)
    miswired = HybridSystem(wrong, outlist=loop.output_labels)
    _, out = miswired.simulate(sampled_initial_state(miswired, s), s.simulation.time_grid)
    wound = out[miswired.output_labels.index("d_hat[2]"), -1]
    assert abs(wound - 1.4) > 0.3


# --------------------------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("changes, words", [
    ({"controller.sample_rate": 0}, "controller.sample_rate' must be > 0"),
    ({"controller.sample_rate": -5}, "controller.sample_rate' must be > 0"),
    ({"controller.sample_rate": math.inf}, "controller.sample_rate' must be a finite number"),
    ({"controller.sample_rate": math.nan}, "controller.sample_rate' must be a finite number"),
    ({"controller.sample_rate": 1000, "controller.delay": -1}, "controller.delay' must be a whole number >= 0"),
    ({"controller.sample_rate": 1000, "controller.delay": 1.5}, "controller.delay' must be a whole number >= 0"),
    ({"controller.sample_rate": 1000, "controller.velocity": "difference", "controller.velocity_cutoff": 600},
     "velocity_cutoff' \\(600 Hz\\) must be below the Nyquist frequency"),
    ({"controller.sample_rate": 1000, "controller.velocity_cutoff": 100}, "needs velocity = \"difference\""),
    ({"controller.sample_rate": 1000, "controller.position_resolution": [0, 0, 0]},
     "controller.position_resolution' must be a list of 4 numbers"),
    ({"controller.sample_rate": 1000, "controller.torque_limit": [1, 1, -1, 1]},
     "controller.torque_limit' must be 4 finite numbers >= 0"),
    ({"controller.sample_rate": 1000, "controller.observer_discretization": "tustin"},
     "observer_discretization' must be one of"),
    ({"controller.delay": 1}, "controller.sample_rate' is required"),
])
def test_bad_controller_settings_are_refused_by_key(changes, words):
    with pytest.raises(ScenarioError, match=words):
        _scenario(changes)


def test_without_a_controller_section_the_scenario_is_the_continuous_one():
    s = blocks.load_scenario("paper")
    assert s.controller is None and "controller" not in s.data and "[controller]" not in s.to_toml()
    d = s.with_changes({"controller.sample_rate": 1000})
    assert d.controller.period == pytest.approx(1e-3) and "[controller]" in d.to_toml()
    assert blocks.scenario_from_dict(__import__("tomllib").loads(d.to_toml())).controller == d.controller
