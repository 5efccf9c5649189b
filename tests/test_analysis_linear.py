"""Linearized Figure-2 loop: poles against the analytic split, mode attribution, inertia mismatch.

Reference values come from docs/model.md ("Numbers to test against") and hand derivations written out here
with ``conftest.reference_inertia`` (Eq. 5), never from the package's maths:

* perfect model: poles = roots of ``s^2 + Kd_i s + Kp_i`` and eig(-Y M^-1(q0));
* without observer, held against a constant disturbance ``f``, the arm rests at
  ``q* = q0 + Kp^-1 M(q*)^-1 f`` and ``A_qq = -Kp + P`` with
  ``P = -M^-1 (dM/dtheta2) M^-1 f e_2^T``;
* nominal inertia ``a M``: ``det[s^2 (s M + Y) + (a s M + Y)(s Kd + Kp)] = 0``;
  with ``Y = r M`` and scalar gains it factors into the cubic
  ``s^3 + (r + a kd) s^2 + (a kp + r kd) s + r kp``, stable (Routh) iff
  ``a^2 kd kp + a r (kp + kd^2) + r (r kd - kp) > 0``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER_FR, PAPER_K, hold_trajectory, make_scenario, reference_inertia

from analysis.linear import loop as linear

Q0 = np.array([0.3, 2.0, 0.24, 0.1])


def _match_rel(numeric, expected):
    """Largest relative distance after pairing each numeric pole with its nearest unused expected one."""
    numeric = list(np.asarray(numeric, dtype=complex))
    worst = 0.0
    for e in sorted(np.asarray(expected, dtype=complex), key=lambda z: (z.real, z.imag)):
        k = int(np.argmin([abs(n - e) for n in numeric]))
        worst = max(worst, abs(numeric.pop(k) - e) / abs(e))
    assert not numeric
    return worst


def _pd_roots(kp, kd):
    return np.concatenate([np.roots([1.0, d, p]) for p, d in zip(kp, kd)])


@pytest.mark.parametrize("gains", [
    {"kp": 180.0, "kd": 36.0, "observer": 10.0},                                       # the paper's
    {"kp": [100.0, 150.0, 400.0, 60.0], "kd": [10.0, 12.0, 30.0, 8.0], "observer": [5.0, 8.0, 20.0, 3.0]},
])
def test_linearized_poles_equal_analytic_split(gains):
    s = make_scenario(gains=gains)
    result = linear.operating_point_analysis(s, Q0)
    kp, kd, y = (np.broadcast_to(np.asarray(gains[k], dtype=float), (4,)) for k in ("kp", "kd", "observer"))
    pd = _pd_roots(kp, kd)
    observer = np.linalg.eigvals(-np.diag(y) @ np.linalg.inv(reference_inertia(Q0[1])))
    with_dob = np.array(result.poles_with_dob)
    assert len(with_dob) == 12
    assert _match_rel(with_dob, np.concatenate([pd, observer])) < 1e-6
    assert result.q0 == pytest.approx(Q0.tolist())
    assert result.q_equilibrium_with_dob == pytest.approx(Q0.tolist(), abs=1e-9)
    # each mode is owned by the block of its analytic partner, wholly so on a perfect model
    assert result.attribution_agrees_with_dob
    for mode in result.modes_with_dob:
        assert mode.participation[mode.block] > 1 - 1e-6
    assert sorted(m.block for m in result.modes_with_dob).count("observer") == 4


def test_without_observer_without_disturbance_gives_pd_poles():
    gains = {"kp": [100.0, 150.0, 400.0, 60.0], "kd": [10.0, 12.0, 30.0, 8.0]}
    s = make_scenario(gains=gains, disturbance={"kind": "none"})
    result = linear.operating_point_analysis(s, Q0)
    without = np.array(result.poles_without_dob)
    assert len(without) == 8
    assert _match_rel(without, _pd_roots(gains["kp"], gains["kd"])) < 1e-6
    assert np.any(np.abs(without.imag) > 1)          # this gain set has oscillatory modes
    zeta = {round(m.zeta, 9) for m in result.modes_without_dob}
    expected = {round(d / (2 * math.sqrt(p)), 9) for p, d in zip(gains["kp"], gains["kd"]) if d * d < 4 * p}
    assert expected <= zeta


def test_without_observer_rests_off_target_and_poles_follow_hand_linearization():
    s = make_scenario()
    result = linear.operating_point_analysis(s, Q0)
    kp = 180.0
    q = Q0.copy()
    for _ in range(50):                               # q* = q0 + Kp^-1 M(q*)^-1 f
        q = Q0 + np.linalg.solve(reference_inertia(q[1]), PAPER_FR) / kp
    assert result.q_equilibrium_without_dob == pytest.approx(q.tolist(), abs=1e-10)
    assert (q - Q0)[2] == pytest.approx(1.4 / 0.25 / 180)          # docs/model.md: 31.1 mm on the prismatic joint
    M = reference_inertia(q[1])
    s2 = math.sin(q[1])
    dM = np.zeros((4, 4))
    dM[0, 0], dM[0, 1], dM[1, 0] = -PAPER_K["k2"] * s2, -0.5 * PAPER_K["k2"] * s2, -0.5 * PAPER_K["k2"] * s2
    Minv = np.linalg.inv(M)
    P = np.zeros((4, 4))
    P[:, 1] = -Minv @ dM @ Minv @ PAPER_FR
    A = np.block([[np.zeros((4, 4)), np.eye(4)], [-kp * np.eye(4) + P, -36.0 * np.eye(4)]])
    without = np.array(result.poles_without_dob)
    assert _match_rel(without, np.linalg.eigvals(A)) < 1e-6
    assert result.max_rel_error_without_dob > 1e-5          # visibly off the ideal PD roots
    # the disturbance the held arm feels is the paper's step f_r (read from the observer's estimate at rest)
    assert result.disturbance_at_rest == pytest.approx(PAPER_FR.tolist(), rel=1e-9)


@pytest.mark.parametrize("a", [0.5, 2.0])
def test_mismatch_poles_solve_hand_derived_polynomial(a):
    s = make_scenario()
    _, poles = linear.spectral_abscissa(linear.scale_nominal_inertia(s, a), Q0, observer=True)
    assert len(poles) == 12
    M, Y = reference_inertia(Q0[1]), 10.0 * np.eye(4)
    for lam in poles:
        P = lam ** 2 * (lam * M + Y) + (a * lam * M + Y) * (36.0 * lam + 180.0)
        sv = np.linalg.svd(P, compute_uv=False)
        assert sv[-1] / sv[0] < 1e-7
    # and the module's own polynomial solver agrees with the linearization
    roots = linear.mismatch_polynomial(M, Y, 180.0 * np.eye(4), 36.0 * np.eye(4), a)
    assert _match_rel(poles, roots) < 1e-6
    _, poles_wo = linear.spectral_abscissa(linear.scale_nominal_inertia(s, a), Q0, observer=False)
    # without observer the held loop is s^2 + a (Kd s + Kp) up to the small offset term: always stable
    assert poles_wo.real.max() < 0


def test_stability_boundary_search_finds_constructed_boundary():
    kp, kd, r = 100.0, 2.0, 1.0
    Y = r * reference_inertia(Q0[1])
    s = make_scenario(gains={"kp": kp, "kd": kd, "observer": Y.tolist()}, trajectory=hold_trajectory(Q0))
    # Routh boundary of s^3 + (r + a kd) s^2 + (a kp + r kd) s + r kp
    qa, qb, qc = kd * kp, r * (kp + kd ** 2), r * (r * kd - kp)
    expected = (-qb + math.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)
    found = linear.stability_boundaries(s, Q0, observer=True, low=0.1, high=10.0, points=7, rtol=1e-8)
    assert found.factors == [pytest.approx(expected, rel=1e-6)]
    assert found.boundaries[0].stable_side == "above" and not found.stable_at_low_end
    alpha_below, _ = linear.spectral_abscissa(linear.scale_nominal_inertia(s, expected * 0.98), Q0, True)
    alpha_above, _ = linear.spectral_abscissa(linear.scale_nominal_inertia(s, expected * 1.02), Q0, True)
    assert alpha_below > 0 > alpha_above
    assert linear.stability_boundaries(s, Q0, observer=False, low=0.1, high=10.0, points=7).boundaries == []


def test_equilibrium_is_accepted_on_its_residual():
    # surgical scenario (friction, tissue, 20 % inertia mismatch), nominal inertia scaled to 0.02x, no observer:
    # the root finder ends "not making good progress" on an equilibrium that is exact to rounding
    from blocks import closed_loop, load_scenario

    s = load_scenario("surgical")
    q0 = s.trajectory.evaluate(0.0)[0]
    loop = closed_loop(linear.hold_scenario(linear.scale_nominal_inertia(s, 0.02), q0), observer=False)
    x = linear.equilibrium(loop)
    assert np.max(np.abs(loop.dynamics(0.0, x, np.zeros(0)))) <= linear.EQUILIBRIUM_RTOL * (1 + np.max(np.abs(x)))
    assert np.all(np.abs(x[4:8]) < 1e-9)                      # at rest
    assert linear.spectral_abscissa(linear.scale_nominal_inertia(s, 0.02), q0, observer=False)[0] < 0


def test_bad_inputs_name_the_problem():
    s = make_scenario()
    with pytest.raises(ValueError, match="q0 must be 4 finite numbers"):
        linear.operating_point_analysis(s, [0.0, 1.0, 0.2])
    with pytest.raises(ValueError, match="inertia scale factor"):
        linear.scale_nominal_inertia(s, -1.0)
    with pytest.raises(ValueError, match="0 < low < high"):
        linear.stability_boundaries(s, Q0, True, low=2.0, high=1.0)
