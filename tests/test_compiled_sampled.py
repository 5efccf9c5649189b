"""The compiled sampled engine (blocks.engines.compiled.sampled) against the numpy hybrid engine and a closed form.

* a double integrator under a sampled PD controller and an Euler observer, built from kernel blocks: the
  exact discrete-time solution of the loop (the plant's input held over each sample);
* the arm's digital loop on paper-digital's controller: every output and state equal to the numpy hybrid
  engine's to 1e-9 (Euler and zoh observer, measured and differenced velocity, delay 0 and 2, a torque
  limit that binds, measurement noise, encoder quantization);
* divergence: a state beyond its bound within a step (the crossing time found in the step) and after a
  tick's update (at the tick), and the issue's diverging zoh controller refused by blocks.simulate;
* engine selection: "compiled" and "auto" run it, "fast" runs the numpy hybrid, a solver it lacks is named;
* the batch: members equal to single runs, a diverging member reported on its own.
"""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.diagram.contract import Kernels, kernel_block
from blocks.engines.compiled import CompiledUnavailable, numba_or_none
from blocks.engines.hybrid import HybridSystem
from blocks.engines.integrate import DivergenceError
from blocks.figure2.loop import EngineFallbackWarning, SimulationError
from blocks.figure2.metrics import signal
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop

pytestmark = pytest.mark.skipif(numba_or_none() is None, reason="the compiled engine needs numba")

from blocks.engines.compiled.sampled import SampledEngine  # noqa: E402
from blocks.figure2.sampled_batch import simulate_sampled_batch  # noqa: E402

# paper-digital's encoders: 2^17 counts per turn, 1 um on the prismatic joint
RESOLUTION = [4.793689962142629e-05, 4.793689962142629e-05, 1e-6, 4.793689962142629e-05]
NOISE = {"noise.q_std": [1e-4, 1e-4, 1e-5, 1e-4], "noise.dq_std": [1e-3, 1e-3, 1e-4, 1e-3], "noise.seed": 3}
SHORT = {"simulation.t_final": 0.3}


def _digital(**controller) -> dict:
    return {f"controller.{k}": v for k, v in controller.items()}


CASES = {
    # paper-digital as it is: Euler observer, differenced velocity through a 200 Hz low-pass, no delay
    "euler-difference-delay0": blocks.load_scenario("paper-digital").with_changes(SHORT),
    # output points between ticks (interpolated in a step) and a last tick interval cut short by t_final
    "euler-difference-delay0-offgrid": blocks.load_scenario("paper-digital").with_changes(
        {"simulation.t_final": 0.3005, "simulation.output_step": 0.0005}),
    # the other choices at once: zoh observer, measured velocity, two samples of delay, a torque limit, noise
    "zoh-measured-delay2-limit-noise": blocks.load_scenario("paper").with_changes(
        SHORT | NOISE | _digital(sample_rate=1000, observer_discretization="zoh", velocity="measured", delay=2,
                                 position_resolution=RESOLUTION, torque_limit=[0, 15, 0, 0])),
}


def _both(s: blocks.Scenario):
    loop = sampled_loop(s)
    x0 = sampled_initial_state(loop, s)
    sim = s.simulation
    numpy_run = loop.simulate(x0, sim.time_grid, sim.method, rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step)
    compiled_run = SampledEngine(loop).simulate(x0, sim.time_grid, sim.rtol, sim.atol, sim.max_step)
    return loop, numpy_run, compiled_run


# --------------------------------------------------------------------------------------------------------------
# The zoh observer's matrix exponential (numba subset)
# --------------------------------------------------------------------------------------------------------------
def test_expm_small_against_closed_forms_and_scipy():
    import scipy.linalg

    from blocks.engines.compiled.jit import jit_kernel
    from blocks.kernels.expm import expm_small
    compiled = jit_kernel(expm_small)
    for w in (0.3, 2.0, 40.0):          # a rotation generator: exp = [[cos, -sin], [sin, cos]]; 40 needs squarings
        a = np.array([[0.0, -w], [w, 0.0]])
        want = np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])
        for fn in (expm_small, compiled):
            np.testing.assert_allclose(fn(a), want, rtol=0, atol=1e-13 * max(1.0, w))
    # [[A, c], [0, 0]]: exp gives e^A and (int_0^1 e^(A s) ds) c; for A = diag(l): (e^l - 1) / l c
    lam, c = np.array([-3.0, -0.5, 1e-3, -12.0]), np.array([1.0, -2.0, 0.5, 3.0])
    aug = np.zeros((5, 5))
    aug[:4, :4], aug[:4, 4] = np.diag(lam), c
    step = compiled(aug)
    np.testing.assert_allclose(np.diag(step[:4, :4]), np.exp(lam), rtol=1e-14)
    np.testing.assert_allclose(step[:4, 4], np.expm1(lam) / lam * c, rtol=1e-13)
    rng = np.random.default_rng(5)
    for scale in (1e-3, 1.0, 4.0, 25.0):
        a = rng.standard_normal((5, 5)) * scale
        ref = scipy.linalg.expm(a)
        np.testing.assert_allclose(expm_small(a), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        np.testing.assert_allclose(compiled(a), expm_small(a), rtol=0, atol=1e-14 * np.abs(ref).max())
    assert np.all(np.isnan(expm_small(np.array([[np.inf, 0.0], [0.0, 1.0]]))))


# --------------------------------------------------------------------------------------------------------------
# A closed form: double integrator, sampled PD and Euler observer, from kernel blocks
# --------------------------------------------------------------------------------------------------------------
def _plant_output(t, x, u, m, d):
    return x


def _plant_update(t, x, u, m, d):
    return np.array([x[1], (u[0] + d) / m])


def _pd_output(t, x, u, m, kp, kd):
    return np.array([m * (-kp * u[0] - kd * u[1]) - u[2]])


def _observer_output(t, z, u, m, gain, period):
    return np.array([gain * u[1] + z[0]])


def _observer_update(t, z, u, m, gain, period):
    return np.array([z[0] - period * (gain / m) * (u[0] + gain * u[1] + z[0])])


def test_double_integrator_equals_its_discrete_closed_form():
    m, d, kp, kd, Y, Ts = 2.0, 0.7, 40.0, 9.0, 25.0, 0.01
    plant = kernel_block(Kernels((m, d), _plant_output, _plant_update), name="plant", inputs=["u"],
                         outputs=["q", "v"], states=["q", "v"], state_outputs=[("q", "q"), ("v", "v")])
    control = kernel_block(Kernels((m, kp, kd), _pd_output), name="controller", inputs=["q", "v", "d_hat"],
                           outputs=["u"], feedthrough=["q", "v", "d_hat"], dt=Ts)
    observer = kernel_block(Kernels((m, Y, Ts), _observer_output, _observer_update), name="observer",
                            inputs=["u", "v"], outputs=["d_hat"], states=["z"], feedthrough=["v"], dt=Ts)
    loop = HybridSystem([plant, control, observer], outlist=["q", "v", "u", "d_hat"])
    x0 = np.array([0.1, -0.2, 0.0])
    t = np.arange(0, 101) * Ts
    _, out = SampledEngine(loop).simulate(x0, t, rtol=1e-10, atol=1e-12)

    # the input held over the sample: x_{k+1} = Phi x_k + Gamma (u_k + d)
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


# --------------------------------------------------------------------------------------------------------------
# The arm's digital loop: equal to the numpy hybrid engine
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_sampled_equals_numpy_sampled(case):
    s = CASES[case]
    loop, (X_np, Y_np), (X_c, Y_c) = _both(s)
    assert X_c.shape == X_np.shape and Y_c.shape == Y_np.shape
    np.testing.assert_allclose(Y_c, Y_np, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(X_c, X_np, rtol=1e-9, atol=1e-9)
    labels = loop.output_labels
    if case.startswith("zoh"):      # the case exercises what it names: the limit binds, the delay holds
        tau1 = Y_np[labels.index("tau[1]")]
        assert np.max(np.abs(tau1)) == 15.0
        assert np.count_nonzero(np.abs(tau1) == 15.0) >= 2
        # delay 2 at 1 kHz, output every 5 ms: tau(t) = sat(tau_cmd(t - 2 ms)) is not tau_cmd(t)
        cmd0, tau0 = Y_np[labels.index("tau_cmd[0]")], Y_np[labels.index("tau[0]")]
        assert np.max(np.abs(cmd0 - tau0)) > 1.0


def test_simulate_with_engine_compiled_equals_fast():
    s = CASES["euler-difference-delay0"]
    compiled, fast = blocks.simulate(s, engine="compiled"), blocks.simulate(s, engine="fast")
    assert list(compiled.output_labels) == list(fast.output_labels)
    np.testing.assert_allclose(compiled.outputs, fast.outputs, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(compiled.states, fast.states, rtol=1e-9, atol=1e-9)


# --------------------------------------------------------------------------------------------------------------
# Divergence
# --------------------------------------------------------------------------------------------------------------
def test_a_state_beyond_its_bound_in_a_step_stops_at_the_crossing():
    s = CASES["euler-difference-delay0"]
    loop = sampled_loop(s)
    x0 = sampled_initial_state(loop, s)
    sim = s.simulation
    _, Y = SampledEngine(loop).simulate(x0, sim.time_grid, sim.rtol, sim.atol)
    q0 = Y[loop.output_labels.index("q[0]")]
    # a bound on the plant's q[0] (state 0) that its path crosses between the start and the end
    level = 0.5 * (abs(q0[0]) + np.max(np.abs(q0)))
    bound = np.full(loop.nstates, np.inf)
    bound[0] = level
    with pytest.raises(DivergenceError) as caught:
        SampledEngine(loop).simulate(x0, sim.time_grid, sim.rtol, sim.atol, bound=bound)
    err = caught.value
    first = int(np.argmax(np.abs(q0) > level))           # first grid point beyond: the crossing is before it
    assert sim.time_grid[first - 1] < err.time <= sim.time_grid[first]
    assert abs(abs(err.state[0]) - level) < 1e-9 * level


def test_a_sampled_state_beyond_its_bound_stops_at_the_tick():
    s = CASES["euler-difference-delay0"]
    loop = sampled_loop(s)
    x0 = sampled_initial_state(loop, s)
    z0 = loop.state_labels.index("observer_z[0]")
    bound = np.full(loop.nstates, np.inf)
    bound[z0] = 1e-12                                   # the observer's state moves at the first update
    with pytest.raises(DivergenceError) as caught:
        SampledEngine(loop).simulate(x0, s.simulation.time_grid, bound=bound)
    assert caught.value.time == 0.0
    assert abs(caught.value.state[z0]) > 1e-12


def test_diverging_zoh_controller_is_stopped_with_the_state_named(monkeypatch):
    """The issue's case: 100 Hz, zoh observer, measured velocity, Ts lambda_max(Y M^-1) = 1.95.  The pre-run check
    refuses it (tests/test_sampled_stability.py); with the check bypassed the compiled engine's Monitor stops it."""
    import blocks.figure2.digital_loop
    s = blocks.load_scenario("paper").with_changes(
        {"gains.observer": 48.75, "simulation.t_final": 4.0}
        | _digital(sample_rate=100, observer_discretization="zoh", velocity="measured"))
    with pytest.raises(blocks.scenarios.scenario.ScenarioError, match="the sampled loop is unstable"):
        blocks.simulate(s, engine="compiled")
    monkeypatch.setattr(blocks.figure2.digital_loop, "check_observer_rate", lambda scenario: None)
    with pytest.raises(SimulationError, match=r"diverged at t = [0-9.]+ s: (plant|observer|encoder) .*beyond its "
                                              r"bound"):
        blocks.simulate(s, engine="compiled")


# --------------------------------------------------------------------------------------------------------------
# Engine selection
# --------------------------------------------------------------------------------------------------------------
def _numpy_engine_forbidden(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the numpy hybrid engine ran")
    monkeypatch.setattr(HybridSystem, "simulate", refuse)


@pytest.mark.parametrize("engine", ["compiled", "auto"])
def test_compiled_and_auto_run_the_compiled_sampled_engine(engine, monkeypatch):
    s = CASES["euler-difference-delay0"]
    _numpy_engine_forbidden(monkeypatch)
    resp = blocks.simulate(s, engine=engine)
    assert np.all(np.isfinite(resp.outputs))


def test_fast_runs_the_numpy_hybrid_engine(monkeypatch):
    _numpy_engine_forbidden(monkeypatch)
    with pytest.raises(AssertionError, match="numpy hybrid engine ran"):
        blocks.simulate(CASES["euler-difference-delay0"], engine="fast")


def test_a_solver_the_compiled_engine_lacks_is_named(monkeypatch):
    import blocks.engines.engine_choice
    monkeypatch.setattr(blocks.engines.engine_choice, "_fallbacks_reported", set())
    s = CASES["euler-difference-delay0"].with_changes({"simulation.method": "RK23", "simulation.t_final": 0.02,
                                                      "trajectory.duration": 10.0})
    with pytest.raises(CompiledUnavailable, match="'RK23'"):
        blocks.simulate(s, engine="compiled")
    with pytest.warns(EngineFallbackWarning, match="'RK23'"):
        resp = blocks.simulate(s, engine="auto")
    assert np.all(np.isfinite(resp.outputs))


# --------------------------------------------------------------------------------------------------------------
# The batch
# --------------------------------------------------------------------------------------------------------------
def _rms_error(resp) -> np.ndarray:
    e = signal(resp, "q_ref") - signal(resp, "q")
    return np.sqrt(np.mean(e * e, axis=1))


def test_batch_over_noise_seeds_equals_single_runs():
    s = blocks.load_scenario("paper-digital").with_changes(SHORT | NOISE)
    seeds = [1, 7, 12]
    result = simulate_sampled_batch(s, seeds=seeds)
    assert result.failed == [None, None, None]
    for m, seed in enumerate(seeds):
        member = s.with_changes({"noise.seed": seed})
        np.testing.assert_allclose(result.rms_error[m], _rms_error(blocks.simulate(member, engine="compiled")),
                                   rtol=1e-12)
    # the numpy hybrid engine, for one member
    np.testing.assert_allclose(result.rms_error[1],
                               _rms_error(blocks.simulate(s.with_changes({"noise.seed": 7}), engine="fast")),
                               rtol=1e-9)
    assert len({tuple(r) for r in result.rms_error}) == 3          # the seeds make different runs


def test_batch_reports_a_diverging_member_and_keeps_the_others():
    s = blocks.load_scenario("paper-digital").with_changes(SHORT | NOISE)
    # Euler observer at 1 kHz: Ts lambda_max(Y M^-1) = 4 Y Ts > 2 for Y = 600 (lambda_min(M^) = k4 = 0.25)
    variants = [s, s.with_changes({"gains.observer": 600.0}), s.with_changes({"gains.kp": 150.0})]
    result = simulate_sampled_batch(s, variants=variants)
    assert result.failed[0] is None and result.failed[2] is None
    assert result.failed[1] is not None and "diverged by t = " in result.failed[1]
    assert "beyond its bound" in result.failed[1] or "became" in result.failed[1]
    assert np.all(np.isnan(result.rms_error[1]))
    for m in (0, 2):
        np.testing.assert_allclose(result.rms_error[m], _rms_error(blocks.simulate(variants[m], engine="compiled")),
                                   rtol=1e-12)


def test_batch_refuses_bad_members():
    s = blocks.load_scenario("paper-digital").with_changes(SHORT)
    with pytest.raises(ValueError, match="seeds vary the measurement noise"):
        simulate_sampled_batch(s, seeds=[1, 2])
    with pytest.raises(ValueError, match="seeds must be"):
        simulate_sampled_batch(s.with_changes(NOISE), seeds=[1, -2])
    with pytest.raises(ValueError, match="either seeds .* or variants"):
        simulate_sampled_batch(s)
    other_path = s.with_changes({"trajectory.bulge": 0.02})          # the reference is a called kernel
    with pytest.raises(ValueError, match=r"variants\[1\].*called kernel"):
        simulate_sampled_batch(s, variants=[s, other_path])
    other_structure = s.with_changes(_digital(delay=1))
    with pytest.raises(ValueError, match=r"variants\[1\].*in structure"):
        simulate_sampled_batch(s, variants=[s, other_structure])


def test_progress_is_reported_and_changes_no_number():
    """Progress makes the driver run the ticks in chunks; the chunks must join exactly."""
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 4.5})
    loop = sampled_loop(s)
    x0 = sampled_initial_state(loop, s)
    seen = []
    engine = SampledEngine(loop)
    X1, Y1 = engine.simulate(x0, s.simulation.time_grid)
    X2, Y2 = engine.simulate(x0, s.simulation.time_grid, progress=seen.append)
    np.testing.assert_array_equal(X1, X2)
    np.testing.assert_array_equal(Y1, Y2)
    assert len(seen) >= 2 and seen == sorted(seen) and 0 < seen[0] < 1 and seen[-1] <= 1.0
