"""Frozen-configuration disturbance responses of the linearized loop against closed forms.

Closed forms (docs/model.md, "Frozen-configuration transfer functions"; perfect model),
written out here with ``conftest.reference_inertia``:
without observer ``E = -(s^2 + Kd s + Kp)^-1 M^-1 W``; with observer
``E = -s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1 W`` and ``E_d = s M (s M + Y)^-1 W``.
For Kp = 180, Kd = 36 the -3 dB frequency of ``1 / (s^2 + 36 s + 180)`` solves
``w^4 + 936 w^2 - 32400 = 0``; the prismatic joint is decoupled, so its
estimation error is ``0.25 s / (0.25 s + 10)`` with its corner at 40 rad/s.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER_FR, PAPER_K, make_scenario, reference_inertia

from analysis.linear import frequency

Q0 = np.array([0.3, 2.0, 0.24, 0.1])
OMEGA = np.logspace(-2, 3, 41)


def _closed_forms(omega, kp=180.0, kd=36.0, y=10.0):
    M = reference_inertia(Q0[1])
    E_without, E_with, E_d = [], [], []
    for w in omega:
        s = 1j * w
        pd = np.linalg.inv((s * s + kd * s + kp) * np.eye(4))
        E_without.append(-pd @ np.linalg.inv(M))
        E_with.append(-s * pd @ np.linalg.inv(s * M + y * np.eye(4)))
        E_d.append(s * M @ np.linalg.inv(s * M + y * np.eye(4)))
    return np.array(E_without), np.array(E_with), np.array(E_d)


def _response(sys, rows, omega):
    return np.moveaxis(np.asarray(sys(1j * omega))[rows], -1, 0)


@pytest.fixture(scope="module")
def systems():
    # no disturbance: every loop rests exactly at q0, where the closed forms hold
    s = make_scenario(disturbance={"kind": "none"})
    return (frequency.frozen_response(s, Q0, observer=True), frequency.frozen_response(s, Q0, observer=False), s)


def test_responses_equal_closed_forms(systems):
    with_dob, without_dob, _ = systems
    E_without, E_with, E_d = _closed_forms(OMEGA)
    assert list(with_dob.input_labels) == [f"w[{i}]" for i in range(4)]
    assert list(with_dob.output_labels) == [f"e[{i}]" for i in range(4)] + [f"e_d[{i}]" for i in range(4)]
    for numeric, exact in ((_response(with_dob, slice(0, 4), OMEGA), E_with),
                           (_response(with_dob, slice(4, 8), OMEGA), E_d),
                           (_response(without_dob, slice(0, 4), OMEGA), E_without)):
        scale = np.abs(exact).max(axis=(1, 2), keepdims=True)
        assert np.max(np.abs(numeric - exact) / scale) < 1e-6


def _displaced_without_observer(omega, f=PAPER_FR, kp=180.0, kd=36.0):
    """Without observer under the constant disturbance f: the linearization at the displaced rest q*.

    docs/model.md ("Frozen-configuration transfer functions"): q* = q0 + Kp^-1 M(q*)^-1 f, and
    E = -(s^2 + Kd s + Kp - P)^-1 M(q*)^-1 W with P = -M^-1 (dM/dtheta2) M^-1 f e2^T at q*.
    """
    q = Q0.copy()
    for _ in range(60):
        q = Q0 + np.linalg.solve(reference_inertia(q[1]), f) / kp
    Minv = np.linalg.inv(reference_inertia(q[1]))
    k2, s2 = PAPER_K["k2"], math.sin(q[1])
    dM = np.zeros((4, 4))
    dM[0, 0], dM[0, 1], dM[1, 0] = -k2 * s2, -0.5 * k2 * s2, -0.5 * k2 * s2
    P = np.zeros((4, 4))
    P[:, 1] = -Minv @ dM @ Minv @ f
    return np.array([-np.linalg.solve(((1j * w) ** 2 + kd * 1j * w + kp) * np.eye(4) - P, Minv) for w in omega])


def test_with_the_scenario_disturbance_the_observer_loop_still_matches(systems):
    s = make_scenario()                              # paper disturbance acting: the observer loop still rests at q0
    result = frequency.frequency_analysis(s, Q0, omega=OMEGA)
    E_without, E_with, E_d = _closed_forms(OMEGA)
    mag = np.array(result.tracking_with_dob.magnitude).T
    assert np.allclose(mag, np.abs(np.diagonal(E_with, axis1=1, axis2=2)), rtol=1e-6, atol=0)
    assert result.tracking_with_dob.closed_form_max_rel_error < 1e-6
    assert result.estimation_with_dob.closed_form_max_rel_error < 1e-6
    # without the observer the arm rests at q* off q0: the response is the displaced closed form ...
    displaced = _displaced_without_observer(OMEGA)
    numeric = _response(frequency.frozen_response(s, Q0, observer=False), slice(0, 4), OMEGA)
    scale = np.abs(displaced).max(axis=(1, 2), keepdims=True)
    assert np.max(np.abs(numeric - displaced) / scale) < 1e-6
    mag = np.array(result.tracking_without_dob.magnitude).T
    assert np.allclose(mag, np.abs(np.diagonal(displaced, axis1=1, axis2=2)), rtol=1e-6, atol=0)
    # ... so the reported distance from the q0 closed form is the distance between the two closed forms,
    # entry by entry relative to the q0 one (entries that are zero there are measured against 1e-9 of the largest)
    floor = np.maximum(np.abs(E_without), np.abs(E_without).max(axis=(1, 2), keepdims=True) * 1e-9)
    expected = np.max(np.abs(displaced - E_without) / floor)
    assert expected > 1e-4                            # the displacement is visible ...
    assert result.tracking_without_dob.closed_form_max_rel_error == pytest.approx(expected, rel=1e-4)


def test_dc_peak_and_bandwidth_metrics(systems):
    with_dob, without_dob, _ = systems
    Minv = np.linalg.inv(reference_inertia(Q0[1]))
    w3db = math.sqrt((-936 + math.sqrt(936 ** 2 + 4 * 32400)) / 2)
    dense = np.logspace(-2, 3, 20001)
    _, E_with, E_d = _closed_forms(dense)
    for i in range(4):
        m = frequency.siso_metrics(without_dob, i, i)
        assert m.kind == "low-pass"
        assert m.dc_gain == pytest.approx(-Minv[i, i] / 180.0, rel=1e-7)
        assert m.band_3db_rad_s[0] == 0.0 and m.band_3db_rad_s[1] == pytest.approx(w3db, rel=1e-6)
        m = frequency.siso_metrics(with_dob, i, i)
        assert m.kind == "band-pass" and abs(m.dc_gain) < 1e-12
        k = int(np.argmax(np.abs(E_with[:, i, i])))
        assert m.peak_gain == pytest.approx(abs(E_with[k, i, i]), rel=1e-6)
        assert m.peak_rad_s == pytest.approx(dense[k], rel=2e-3)
        lo, hi = m.band_3db_rad_s
        assert lo < m.peak_rad_s < hi
    # prismatic joint: 31.1 mm per 1.4 N without observer and an estimation corner at 40 rad/s
    # (docs/model.md, "Frozen-configuration transfer functions")
    assert -frequency.siso_metrics(without_dob, 2, 2).dc_gain * 1.4 == pytest.approx(0.0311, abs=5e-5)
    m = frequency.siso_metrics(with_dob, 6, 2)
    assert m.kind == "high-pass" and m.band_3db_rad_s[0] == pytest.approx(40.0, rel=1e-6)
    assert m.band_3db_rad_s[1] is None and m.hf_gain == pytest.approx(1.0, rel=1e-9)
    # the open upper edge is null in JSON and None again when read back
    assert frequency.ChannelMetrics.from_json(m.to_json()) == m


def test_noise_is_refused_for_the_frequency_loop():
    s = make_scenario(noise={"q_std": [1e-4] * 4})
    with pytest.raises(ValueError, match="measurement noise"):
        frequency.disturbance_loop(s)


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_a_low_pass_band_ends_at_its_first_crossing_of_the_level():
    """fr-lowpass-edge.  G(s) = 1/(s + 1) + 0.8 (10 s) / (s^2 + 10 s + 100^2): low-pass (DC gain 1), below
    1/sqrt(2) from ~1 rad/s, back above it around the resonance at 100 rad/s.  The -3 dB band of a low-pass is
    [0, first crossing]: found here with scipy's freqresp and brentq."""
    import control as ct
    from scipy.optimize import brentq
    from scipy.signal import TransferFunction, freqresp

    from analysis.linear.frequency import siso_metrics

    num = np.polyadd(np.polymul([1.0], [1.0, 10.0, 1e4]), np.polymul([8.0, 0.0], [1.0, 1.0]))
    den = np.polymul([1.0, 1.0], [1.0, 10.0, 1e4])
    ref = TransferFunction(num, den)

    def gain(w):
        return abs(freqresp(ref, [w])[1][0])

    level = 1.0 / np.sqrt(2.0)
    assert gain(100.0) > level                                   # it does come back above the level
    first = brentq(lambda w: gain(w) - level, 0.1, 10.0)
    metrics = siso_metrics(ct.ss(ct.tf(num, den)), 0, 0)
    assert metrics.kind == "low-pass"
    assert metrics.band_3db_rad_s[0] == 0.0
    assert metrics.band_3db_rad_s[1] == pytest.approx(first, rel=1e-6)
