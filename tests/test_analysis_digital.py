"""The linearized sampled loop against independent derivations: the continuous poles as the rate grows, the
forward-Euler observer bound 2 / (Ts lambda_max(Y M^-1)) with measured velocity (docs/model.md, "Digital
observer"), the stability computation (blocks.figure2.digital_stability) against this module's linearization of the
blocks themselves, and the encoder quantization noise against simulation."""
from __future__ import annotations

import math

import numpy as np
import pytest

import blocks
from analysis.linear.digital import (
    digital_analysis,
    linear_sampled_loop,
    observer_gain_limit,
    quantization_torque_noise,
    sampled_poles,
)
from analysis.linear.digital_figures import digital_figures

Q0 = np.array([0.3, 1.2, 0.1, 0.2])
HELD = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.0] * 4, "trajectory.offset": Q0.tolist()}


def _paper(changes: dict) -> blocks.Scenario:
    return blocks.load_scenario("paper").with_changes(changes)


def test_at_a_high_rate_the_poles_are_the_continuous_ones():
    """s = ln(z) / Ts -> the continuous loop's poles: PD roots 6 and 30 (x4) and the observer's eigenvalues of
    -Y M^-1(q0) (docs/model.md, "Numbers to test against"), to O(Ts)."""
    s = _paper(HELD | {"controller.sample_rate": 10000.0})
    result = sampled_poles(s)
    got = np.sort([-m.s_equivalent.real for m in result.modes if np.isfinite(m.wn_rad_s)])
    observer = np.sort(np.linalg.eigvals(10 * np.linalg.inv(blocks.inertia(Q0, blocks.PAPER_PARAMETERS))).real)
    want = np.sort(np.concatenate([[6.0] * 4, [30.0] * 4, observer]))
    np.testing.assert_allclose(got, want, rtol=0.01)
    assert result.spectral_radius < 1
    owners = {m.block for m in result.modes if abs(-m.s_equivalent.real - 40.0) < 1.0}
    assert owners == {"observer"}


def test_the_euler_gain_limit_is_the_frozen_inertia_bound_and_zoh_is_below():
    """Largest stable c with Y = c 10 I at rate f: Euler with measured velocity c = 2 f / lambda_max(10 M^-1)
    = 2 f / 40 (lambda_min(M) = k4), with or without a delay (its error map I - Ts Y M^-1 does not involve the
    torque); zoh below it, and lower with a delay."""
    s = _paper(HELD | {"controller.sample_rate": 1000.0})
    study = observer_gain_limit(s, rates_hz=(200.0, 1000.0), configurations=[Q0], discretizations=("euler", "zoh"),
                                delays=(0, 1))
    no_delay, one, zoh, zoh_one = study.curves
    np.testing.assert_allclose(no_delay.euler_bound_scale, [10.0, 50.0], rtol=1e-9)
    np.testing.assert_allclose(no_delay.largest_scale, [10.0, 50.0], rtol=1e-6)
    np.testing.assert_allclose(one.largest_scale, [10.0, 50.0], rtol=1e-6)
    np.testing.assert_allclose(no_delay.ts_lambda_limit, [2.0, 2.0], rtol=1e-6)
    assert all(z1 < z0 < e for z1, z0, e in zip(zoh_one.largest_scale, zoh.largest_scale, no_delay.largest_scale))
    assert zoh.ts_lambda_limit[1] == pytest.approx(1.9795, abs=1e-4)          # issue 17, 1 kHz


@pytest.mark.parametrize("changes", [
    {"controller.observer_discretization": "zoh"},
    {"controller.velocity": "difference", "controller.velocity_cutoff": 40.0},
    {"controller.observer_discretization": "zoh", "controller.delay": 1, "controller.velocity": "difference"},
    {"controller.delay": 1, "controller.velocity": "difference", "controller.velocity_cutoff": 20.0},
])
def test_the_stability_computation_is_the_linearization_of_the_blocks(changes):
    """blocks.figure2.digital_stability writes the linearized one-sample map out; linear_sampled_loop linearizes the
    hybrid loop's own blocks numerically (control.linearize, control's ZOH of the plant): same moduli of the
    eigenvalues at 100 Hz with the gain 4 Y (near the limits)."""
    from analysis.linear.digital import _held, _operating_state
    from blocks.figure2.digital_stability import sampled_loop_map
    from blocks.figure2.sampled_blocks import sampled_loop
    s = _paper(HELD | {"controller.sample_rate": 100.0, "gains.observer": 40.0} | changes)
    held = _held(s, Q0)
    loop = sampled_loop(held)
    A, _, _ = linear_sampled_loop(loop, _operating_state(held, loop))
    Phi = sampled_loop_map(blocks.inertia(Q0, s.nominal), s.kp, s.kd, s.observer_gain, s.controller)
    assert A.shape == Phi.shape
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(A))), np.sort(np.abs(np.linalg.eigvals(Phi))),
                               atol=1e-6)


def test_the_gain_limit_agrees_with_simulation():
    """Just below the limit the sampled loop settles; just above it grows (Y = c 10 I at 1 kHz, c_max ~ 50)."""
    from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop
    limit = observer_gain_limit(_paper(HELD | {"controller.sample_rate": 1000.0}), rates_hz=(1000.0,),
                                configurations=[Q0], discretizations=("euler",), delays=(0,)).curves[0]
    c = limit.largest_scale[0]
    for factor, grows in ((0.97, False), (1.03, True)):
        s = _paper(HELD | {"controller.sample_rate": 1000.0, "gains.observer": 10 * c * factor,
                           "simulation.t_final": 0.3, "simulation.output_step": 0.001})
        loop = sampled_loop(s)
        _, out = loop.simulate(sampled_initial_state(loop, s), s.simulation.time_grid)
        d_hat = out[loop.output_labels.index("d_hat[2]")]
        late, early = np.abs(np.diff(d_hat[-20:])).max(), np.abs(np.diff(d_hat[20:40])).max()
        assert bool(late > early) == grows, (factor, early, late)


def test_the_linear_map_holds_the_plant_discretized_exactly():
    """Without observer and without disturbance the arm rests on its reference, where computed torque on a perfect
    model turns each joint into a double integrator: the one-sample map is its ZOH discretization under u = -Kp q -
    Kd dq, per joint, exactly."""
    import scipy.linalg
    s = _paper(HELD | {"controller.sample_rate": 500.0, "disturbance.kind": "none"})
    from analysis.linear.digital import _held, _operating_state
    from blocks.figure2.sampled_blocks import sampled_loop
    held = _held(s, Q0)
    loop = sampled_loop(held, observer=False)
    A, _, _ = linear_sampled_loop(loop, _operating_state(held, loop))
    Ts, kp, kd = 1 / 500.0, 180.0, 36.0
    Phi = scipy.linalg.expm(np.array([[0, 1], [0, 0]]) * Ts)
    Gamma = np.array([Ts ** 2 / 2, Ts])
    want = Phi - np.outer(Gamma, [kp, kd])
    for i in range(4):
        np.testing.assert_allclose(A[np.ix_([i, 4 + i], [i, 4 + i])], want, rtol=1e-6, atol=1e-9)


@pytest.mark.slow
def test_quantization_noise_is_predicted_within_20_percent():
    res = [2 * math.pi / 2 ** 17] * 2 + [1e-6, 2 * math.pi / 2 ** 17]
    s = _paper({"controller.sample_rate": 1000.0, "controller.position_resolution": res,
                "controller.velocity": "difference", "controller.velocity_cutoff": 200.0})
    noise = quantization_torque_noise(s)
    ratio = np.array(noise.simulated_rms) / np.array(noise.predicted_rms)
    assert np.all((0.8 < ratio) & (ratio < 1.2)), ratio


def test_digital_analysis_answers_in_numbers_and_draws(tmp_path):
    s = _paper(HELD | {"controller.sample_rate": 1000.0, "simulation.t_final": 1.0})
    result = digital_analysis(s, rates_hz=(500.0, 2000.0), configurations=[Q0])
    assert result.largest_stable_scale == pytest.approx(50.0, rel=1e-6)        # Euler, measured: 2 f / 40
    assert result.ts_lambda_limit == pytest.approx(2.0, rel=1e-6)
    assert "1000 Hz" in result.answer and f"{result.largest_stable_scale:.3g} times" in result.answer
    assert f"Ts lambda_max(Y M^-1) < {result.ts_lambda_limit:.4g}" in result.answer
    assert result.quantization is None                   # exact encoders: nothing to add
    assert type(result).from_json(result.to_json()).largest_stable_scale == result.largest_stable_scale
    paths = digital_figures(result, tmp_path, blocks.RRPR_JOINTS)
    assert {p.name for p in paths} == {"digital_poles.png", "digital_poles.svg", "digital_gain_limit.png",
                                       "digital_gain_limit.svg"}
    with pytest.raises(ValueError, match="no \\[controller\\] section"):
        digital_analysis(blocks.load_scenario("paper"))


def test_a_report_of_a_digital_scenario_has_the_digital_section(tmp_path):
    """A tiny analysis (small grids, short runs) of a 1 kHz scenario: the section, its numbers and figures."""
    from analysis.report.build import write_report
    from analysis.report.settings import AnalysisSettings
    s = _paper({"controller.sample_rate": 1000.0, "simulation.t_final": 1.0, "trajectory.duration": 10.0,
                "controller.position_resolution": [1e-4, 1e-4, 1e-6, 1e-4]})
    tiny = AnalysisSettings(quick=True, mismatch_factors=(1.0,), boundary_points=3, workspace_points=(2, 5, 2, 2),
                            kp_values=(180.0,), kd_values=(36.0,), observer_values=(10.0,), study_t_final=0.5,
                            design_t_final=0.5, noise_t_final=0.1, digital_rates_hz=(1000.0,))
    page = write_report(s, tmp_path / "report", tiny).read_text(encoding="utf-8")
    assert "8. Digital implementation" in page and "href='#digital'" in page
    result = __import__("json").loads((tmp_path / "report" / "analysis.json").read_text())
    assert result["digital"]["largest_stable_scale"] == pytest.approx(50.0, rel=0.01)     # 2 f / lambda_max, f = 1 kHz
    assert f"{result['digital']['largest_stable_scale']:.3g} times" in page
    # the rule the section states is the computed one, not prose
    from analysis.report.view.text import fmt
    assert f"the rule is Ts lambda_max(Y M^-1) &lt; {fmt(result['digital']['ts_lambda_limit'], 5)}." in page
    assert "lambda_max(Y M^-1) &lt; 2 for both" not in page
    assert (tmp_path / "report" / "figures" / "digital_gain_limit.png").exists()
