"""The hand-linearized held loop of gain tuning (analysis.tune.linear) against independent references.

* Perfect model: the poles are the roots of ``s^2 + Kd_i s + Kp_i`` and the eigenvalues of ``-Y M^-1(q0)``
  (docs/model.md), with M from ``conftest.reference_inertia`` (Eq. 5).
* Model mismatch: the poles equal those of the python-control linearization of the real nonlinear loop
  (:func:`analysis.linear.loop.spectral_abscissa`), which knows nothing of the hand derivation.
* Torque noise: the stationary value equals ``rms(tau_noisy - tau_clean)`` of nonlinear simulations of the held
  arm with the measurement noise of :class:`blocks.model.noise.MeasurementNoise`, sampled at the noise's sample instants.
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import make_scenario, reference_inertia

from analysis.linear import loop as linear
from analysis.simulation.studies import step_scenario
from analysis.tune.linear import held_loop_matrices, loop_poles, spectral_abscissas, torque_noise_rms
from blocks import inertia, load_scenario, simulate
from blocks.figure2.metrics import signal

Q0 = np.array([0.3, 2.0, 0.24, 0.1])
NOISE = {"q_std": [2e-4, 2e-4, 2e-5, 2e-4], "dq_std": [5e-3, 5e-3, 5e-4, 5e-3], "sample_period": 0.001}
GAINS = [{"kp": 180.0, "kd": 36.0, "observer": 10.0},
         {"kp": [400.0, 300.0, 600.0, 200.0], "kd": [20.0, 25.0, 30.0, 15.0], "observer": [30.0, 10.0, 5.0, 8.0]}]


def _nearest_rel(a, b) -> float:
    """Largest relative distance after pairing each pole of ``a`` with its nearest unused one of ``b``."""
    b = list(np.asarray(b, dtype=complex))
    worst = 0.0
    for z in sorted(np.asarray(a, dtype=complex), key=lambda z: (z.real, z.imag)):
        k = int(np.argmin([abs(w - z) for w in b]))
        worst = max(worst, abs(b.pop(k) - z) / abs(z))
    return worst


@pytest.mark.parametrize("gains", GAINS)
def test_perfect_model_poles_are_the_pd_roots_and_the_observer_modes(gains):
    kp, kd, y = (np.broadcast_to(np.asarray(gains[k], dtype=float), (4,)) for k in ("kp", "kd", "observer"))
    M = reference_inertia(Q0[1])
    expected = np.concatenate([np.concatenate([np.roots([1.0, d, p]) for p, d in zip(kp, kd)]),
                               np.linalg.eigvals(-np.diag(y) @ np.linalg.inv(M))])
    poles = loop_poles(M, M, kp, kd, y)
    assert poles.shape == (12,)
    assert _nearest_rel(poles, expected) < 1e-9
    assert spectral_abscissas(M, M, kp, kd, y) == pytest.approx(expected.real.max(), rel=1e-9)


@pytest.mark.parametrize("gains", GAINS)
@pytest.mark.parametrize("scale", [{"m1": 1.2, "I2": 0.8, "m3": 0.85}, {"m2": 0.7, "I4": 1.3, "I1": 1.1}])
def test_mismatched_poles_equal_the_linearization_of_the_real_loop(gains, scale):
    s = make_scenario(gains=gains, nominal_scale=scale)
    abscissa, numeric = linear.spectral_abscissa(s, Q0, observer=True)
    poles = loop_poles(inertia(Q0, s.robot), inertia(Q0, s.nominal), s.kp, s.kd, s.observer_gain)
    assert _nearest_rel(poles, numeric) < 1e-5
    assert spectral_abscissas(inertia(Q0, s.robot), inertia(Q0, s.nominal), s.kp, s.kd, s.observer_gain) == \
        pytest.approx(abscissa, rel=1e-5, abs=1e-7)


def test_stacks_of_inertia_pairs_give_one_abscissa_each():
    M = np.stack([reference_inertia(t) for t in (0.5, 1.5, 2.5)])
    stacked = spectral_abscissas(M, 0.9 * M, 180.0, 36.0, 10.0)
    assert stacked.shape == (3,)
    assert stacked == pytest.approx([spectral_abscissas(m, 0.9 * m, 180.0, 36.0, 10.0) for m in M])


@pytest.mark.parametrize("gains", GAINS)
def test_torque_noise_equals_nonlinear_simulations_of_the_held_arm(gains):
    base = load_scenario("paper")
    held = step_scenario(base, 4.0, simulation={"max_step": 0.001, "output_step": 0.001}, gains=gains,
                         nominal_scale={"m2": 1.15, "I1": 0.9})
    q0 = np.asarray(base.trajectory.evaluate(0.0)[0], dtype=float)
    expected = torque_noise_rms(inertia(q0, held.robot), inertia(q0, held.nominal), held.kp, held.kd,
                                held.observer_gain, NOISE["q_std"], NOISE["dq_std"], NOISE["sample_period"])
    clean = signal(simulate(held), "tau")
    squares = []
    for seed in (1, 2, 3):
        noisy = signal(simulate(held.replace(noise=dict(NOISE, seed=seed))), "tau")
        squares.append(np.mean((noisy - clean)[:, 500:] ** 2, axis=1))       # from 0.5 s: the noise's own spread
    measured = np.sqrt(np.mean(squares, axis=0))
    # three 3.5-s runs sampled every 1 ms: the RMS of a random signal is known to about 2 % from them
    assert measured == pytest.approx(expected, rel=0.04)


def test_torque_noise_is_mostly_the_direct_feedthrough_and_grows_with_the_gains():
    M = reference_inertia(Q0[1])
    q_std, dq_std = np.array(NOISE["q_std"]), np.array(NOISE["dq_std"])
    rms = torque_noise_rms(M, M, 180.0, 36.0, 10.0, q_std, dq_std, 0.001)
    # the direct path tau = -M Kp n_q - (M Kd + Y) n_dq with independent samples is a floor of the same order
    direct = np.sqrt(np.diag(M @ np.diag((180.0 * q_std) ** 2) @ M.T
                             + (36.0 * M + 10.0 * np.eye(4)) @ np.diag(dq_std ** 2) @ (36.0 * M + 10.0 * np.eye(4)).T))
    assert rms == pytest.approx(direct, rel=0.15)
    assert np.all(torque_noise_rms(M, M, 180.0, 50.0, 10.0, q_std, dq_std, 0.001) > rms)
    assert np.all(torque_noise_rms(M, M, 180.0, 36.0, 30.0, q_std, dq_std, 0.001) > rms)


def test_an_unstable_loop_has_unbounded_torque_noise():
    M = reference_inertia(Q0[1])
    assert spectral_abscissas(M, M, -5.0, 36.0, 10.0) > 0
    assert np.all(np.isinf(torque_noise_rms(M, M, -5.0, 36.0, 10.0, NOISE["q_std"], NOISE["dq_std"], 0.001)))


def test_matrices_have_the_documented_shapes():
    M = reference_inertia(1.0)
    A, B, C, D = held_loop_matrices(M, M, 180.0, 36.0, 10.0)
    assert (A.shape, B.shape, C.shape, D.shape) == ((12, 12), (12, 8), (4, 12), (4, 8))
