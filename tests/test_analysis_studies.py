"""Gain and noise studies: metric definitions on known signals, steady-state offsets, settling and torque noise.

References: ``exp(-t)`` stays within 2 % of its peak after ``ln 50`` s; without the
observer the held prismatic joint rests ``1.4 / 0.25 / Kp`` m off (docs/model.md,
"Steady error without the observer");
the prismatic joint is decoupled (M has only ``k4 = 0.25`` kg in its row), so after
the step ``f`` its error is the step response of ``-(f / k4) / (s^2 + Kd s + Kp)``
without the observer and of ``-(f / k4) / ((s + Y / k4)(s^2 + Kd s + Kp))`` with it,
computed here with :func:`scipy.signal.step`; velocity noise ``n`` on joint 3
reaches its force directly as ``-(m34 Kd + Y) n`` (controller ``M Kd e'`` and
observer ``d_hat = Y q' + z``).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
from conftest import PAPER_FR, PAPER_K, hold_trajectory, make_scenario

from analysis.simulation import studies
from blocks import RRPR_JOINTS, MeasurementNoise


def test_signal_metrics_on_known_signals():
    t = np.linspace(0.0, 10.0, 100001)
    m = studies.signal_metrics(t, np.exp(-t))
    # the end-of-run mean is exp(-9..-10) ~ 7e-5: the 2 % band sits around it
    final = np.mean(np.exp(-t[90000:]))
    assert m.steady_state_error == pytest.approx(final, rel=1e-9)
    assert m.settling_time_s == pytest.approx(-math.log(final + 0.02 * (1 - final)), abs=1e-3)
    assert m.peak_error == 1.0
    assert m.rms_error == pytest.approx(math.sqrt((1 - math.exp(-20)) / 20), rel=1e-3)
    # a signal still moving at the end has not settled
    assert studies.signal_metrics(t, np.sin(t)).settling_time_s is None
    assert studies.signal_metrics(t, np.full_like(t, 2.0)).settling_time_s == 0.0


def test_gain_grid_steady_state_offset_scales_with_one_over_kp():
    s = make_scenario(trajectory=hold_trajectory(), simulation={"t_final": 1.5, "output_step": 0.005})
    without = studies.gain_grid_study(s, [90.0, 180.0], [18.0], observer=False)   # decay 9 rad/s
    with_dob = studies.gain_grid_study(s, [90.0, 180.0], [18.0], observer=True)
    for i, kp in enumerate(without.kp):
        run = without.runs[i][0]
        assert run.ok
        assert run.joints[2].steady_state_error == pytest.approx(1.4 / 0.25 / kp, rel=1e-4)
        assert run.joints[2].settling_time_s is not None
        # the observer removes the prismatic offset (its mode is 40 rad/s: gone after 1.5 s)
        assert with_dob.runs[i][0].joints[2].steady_state_error < 1e-6
        assert run.tool_mm.peak_error > 10 * with_dob.runs[i][0].tool_mm.steady_state_error
    with pytest.raises(ValueError, match="gain grids"):
        studies.gain_grid_study(s, [], [36.0])


def _settling_reference(t, x, final, fraction=0.02):
    """Last time the dense reference signal is outside the band around its final value."""
    dev = np.abs(x - final)
    return float(t[np.nonzero(dev > fraction * dev.max())[0][-1]])


def test_settling_is_measured_on_a_held_arm_after_a_step():
    # the paper's path scenario: the study holds the arm at q_ref(0) and applies the step f_r
    s = make_scenario(simulation={"t_final": 2.0, "output_step": 0.005})
    kp, kd, y, m, f = 180.0, 36.0, 10.0, PAPER_K["k4"], PAPER_FR[2]
    without = studies.gain_grid_study(s, [kp], [kd], observer=False)
    with_dob = studies.gain_grid_study(s, [kp], [kd], observer=True)
    assert without.q_hold == pytest.approx(s.trajectory.evaluate(0.0)[0].tolist())
    assert without.f_r == pytest.approx(PAPER_FR.tolist()) and without.t_final_s == 2.0
    t = np.linspace(0.0, 2.0, 200001)
    # e = q_ref - q of joint 3 as the step response of E(s) s: -(f/m) / (s^2 + Kd s + Kp) without the observer;
    # with it the estimation error f exp(-(Y/m) t) drives e, so E(s) s = -(f/m) s / ((s + Y/m)(s^2 + Kd s + Kp))
    for study, system in ((without, ([-f / m], [1.0, kd, kp])),
                          (with_dob, ([-f / m, 0.0], np.polymul([1.0, y / m], [1.0, kd, kp])))):
        run = study.runs[0][0].joints[2]
        _, x = scipy.signal.step(system, T=t)
        final = float(np.polyval(system[0], 0) / np.polyval(system[1], 0))      # final value theorem
        assert run.final_value == pytest.approx(final, abs=1e-12)
        assert run.steady_state_error == pytest.approx(abs(final), abs=1e-12)
        assert run.peak_error == pytest.approx(np.max(np.abs(x)), rel=1e-3)
        reference = _settling_reference(t, x, final)
        assert run.settled and reference <= run.settling_time_s <= reference + 0.005 + 1e-9
    assert without.runs[0][0].joints[2].settling_time_s == pytest.approx(np.log(62.5) / 6, abs=0.006)
    # a run that ends before the error has settled says so instead of quoting a time
    short = studies.gain_grid_study(s, [kp], [kd], observer=False, t_final=0.5)
    assert short.runs[0][0].joints[2].settling_time_s is None
    assert not short.runs[0][0].joints[2].settled
    # "not settled" is null in the JSON and None again when read back
    again = studies.GainGridStudy.from_json(short.to_json())
    assert '"settling_time_s": null' in short.to_json() and again.runs[0][0].joints[2].settling_time_s is None


def test_torque_noise_grows_with_the_observer_gain_as_predicted():
    s = make_scenario(trajectory=hold_trajectory(), simulation={"t_final": 0.5, "output_step": 0.001})
    noise = {"q_std": [0.0] * 4, "dq_std": [0.0, 0.0, 5e-4, 0.0], "seed": 3, "sample_period": 0.001}
    study = studies.observer_gain_study(s, [("Y = 30 I", 30.0)], noise=noise)
    assert study.labels == ["none", "Y = 30 I"]
    # the realisation of the noise on the output grid (grid points fall on the noise samples)
    n = MeasurementNoise(dq_std=(0.0, 0.0, 5e-4, 0.0), seed=3, sample_period=0.001, t_final=0.5,
                         joints=RRPR_JOINTS)
    rms = float(np.sqrt(np.mean(n.sample(np.linspace(0.0, 0.5, 501))[1][:, 2] ** 2)))
    none, fast = (r.torque_noise_rms for r in study.runs)
    assert none[2] == pytest.approx(0.25 * 36.0 * rms, rel=0.05)
    assert fast[2] == pytest.approx((0.25 * 36.0 + 30.0) * rms, rel=0.05)
    assert max(none[0], none[1], none[3]) < 1e-4 * none[2]   # joint 3 is decoupled: the noise stays there
