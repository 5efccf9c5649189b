"""Observer bandwidth over the workspace, gain design and the Mohammadi convergence certificate.

References: docs/model.md ("Observer eigenvalues" and "Convergence condition": eigenvalues of 10 M^-1(q) are
40, 12.09-12.99, 5.95-6.08 and 0.848-0.930 rad/s; ||M'|| <= 0.574 |theta2'| so the
condition holds for |theta2'| < 34.8 rad/s), ``conftest.reference_inertia`` (Eq. 5)
and the Lyapunov bound V(t) <= V(0) exp(-2 beta t).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER_K, make_scenario, reference_inertia

import blocks
from analysis.linear import bandwidth, gain_design


@pytest.fixture(scope="module")
def paper():
    return make_scenario()


@pytest.fixture(scope="module")
def grid():
    q, _ = bandwidth.workspace_grid((3, 73, 2, 3))
    return q


def test_observer_eigenvalues_match_the_model_facts(paper):
    survey = bandwidth.bandwidth_survey(paper, points=(3, 181, 2, 3))
    ranges = survey.ranges_rad_s
    assert ranges[3] == pytest.approx([40.0, 40.0], rel=1e-12)               # prismatic: 10 / 0.25
    for (lo, hi), (lo_ref, hi_ref) in zip(ranges[:3], [(0.848, 0.930), (5.95, 6.08), (12.09, 12.99)]):
        assert lo == pytest.approx(lo_ref, abs=0.0051) and hi == pytest.approx(hi_ref, abs=0.0051)
    assert survey.slowest_rad_s.min < 1.0                               # the slow whole-arm mode
    # the slice equals eig(10 M^-1) of Eq. 5 written out independently
    theta2 = np.array(survey.theta2)
    expected = np.sort(np.linalg.eigvals(10.0 * np.linalg.inv(reference_inertia(theta2))).real, axis=1)
    assert np.allclose(survey.eigenvalues, expected, rtol=1e-10)
    assert len(survey.eigenvalues[0]) == 4


def test_slowest_mode_location_direction_and_joint_dependence(paper):
    survey = bandwidth.bandwidth_survey(paper, points=(3, 73, 2, 3))
    assert survey.slowest_rad_s.q_at_min[1] == pytest.approx(0.0, abs=1e-12)        # arm stretched
    assert abs(survey.slowest_rad_s.q_at_max[1]) == pytest.approx(math.pi)           # arm folded
    # measured, not assumed: the modes do not change along theta1, d3, theta4 but do along theta2
    sens = survey.sensitivity_rad_s
    assert max(sens["theta1"], sens["d3"], sens["theta4"]) < 1e-12 and sens["theta2"] > 0.5
    # the slow mode is a whole-arm mode: joints 1, 2 and 4 together, nothing on the prismatic joint
    k = int(np.argmin(np.abs(np.array(survey.theta2))))
    v = np.array(survey.slowest_direction[k])
    M = reference_inertia(survey.theta2[k])
    w, V = np.linalg.eig(10.0 * np.linalg.inv(M))
    ref = V[:, np.argmin(w.real)].real
    assert abs(abs(v @ ref) / np.linalg.norm(ref) - 1.0) < 1e-10
    assert abs(v[2]) < 1e-12 and min(abs(v[0]), abs(v[1]), abs(v[3])) > 0.1


@pytest.mark.parametrize("base", [None, "scenario"])
def test_designed_gain_meets_target_on_a_finer_grid(paper, grid, base):
    target = 10.0
    design = gain_design.design_observer_gain(paper.nominal, target, grid,
                                              base=None if base is None else 10.0 * np.eye(4))
    Y = design.Y
    assert np.allclose(Y, Y.T) and np.linalg.eigvalsh(Y).min() > 0
    theta2 = np.linspace(-math.pi, math.pi, 2001)             # independent of the design grid
    rates = np.linalg.eigvals(Y @ np.linalg.inv(reference_inertia(theta2))).real
    assert rates.min() >= target * (1 - 1e-8)
    assert rates.min() <= target * (1 + 1e-6)                 # the smallest gain that does it
    if base is not None:
        # lifting never slows a mode down (Weyl): sorted eigenvalues dominate those of 10 I
        old = np.sort(np.linalg.eigvals(10.0 * np.linalg.inv(reference_inertia(theta2))).real, axis=1)
        assert np.all(np.sort(rates, axis=1) >= old - 1e-9)


def test_certificate_for_paper_gain_matches_the_model_facts(paper, grid):
    Y = 10.0 * np.eye(4)
    critical = gain_design.critical_speed(paper.nominal, Y, grid, [0.0, 1.0, 0.0, 0.0])
    norm_dM = PAPER_K["k2"] * (1 + math.sqrt(2)) / 2            # largest |eig| of dM/dtheta2 at sin(theta2) = 1
    assert norm_dM == pytest.approx(0.574, abs=5e-4)
    assert critical.speed_factor == pytest.approx(2 * 10.0 / norm_dM, rel=1e-6)   # 34.8 rad/s
    assert critical.speed_factor == pytest.approx(34.8, abs=0.05) and not critical.unlimited
    at_rest = gain_design.convergence_certificate(paper.nominal, Y, grid, [0.0] * 4)
    assert at_rest.beta_min_rad_s == pytest.approx(
        np.linalg.eigvals(10.0 * np.linalg.inv(reference_inertia(0.0))).real.min(), rel=1e-10)
    below = gain_design.convergence_certificate(paper.nominal, Y, grid, [0.0, 0.99 * critical.speed_factor, 0, 0])
    above = gain_design.convergence_certificate(paper.nominal, Y, grid, [0.0, 1.01 * critical.speed_factor, 0, 0])
    assert below.holds and not above.holds
    assert abs(above.q_at[1]) == pytest.approx(math.pi / 2, abs=0.1)       # worst where |sin(theta2)| = 1
    with pytest.raises(ValueError, match="speed_bound"):
        gain_design.convergence_certificate(paper.nominal, Y, grid, [1.0, 1.0, -1.0, 1.0])


def test_inertia_partials_equal_hand_derivative(paper):
    q = np.array([[0.3, 2.0, 0.24, 0.1], [-1.0, -0.7, 0.15, 2.0], [0.0, math.pi / 2, 0.3, 0.0]])
    parts = gain_design.inertia_partials(paper.nominal, q)
    assert parts.shape == (3, 4, 4, 4)
    for n, qn in enumerate(q):
        s2 = math.sin(qn[1])
        dM = np.zeros((4, 4))                       # d/dtheta2 of Eq. 5: only the k2 cos(theta2) entries move
        dM[0, 0], dM[0, 1], dM[1, 0] = -PAPER_K["k2"] * s2, -0.5 * PAPER_K["k2"] * s2, -0.5 * PAPER_K["k2"] * s2
        assert np.allclose(parts[n, 1], dM, rtol=0, atol=1e-15)
        for j in (0, 2, 3):                         # M does not depend on theta1, d3, theta4
            assert np.all(parts[n, j] == 0.0)


def test_simulation_confirms_faster_estimate(paper, grid):
    design = gain_design.design_observer_gain(paper.nominal, 10.0, grid, base=10.0 * np.eye(4))
    runs = gain_design.confirm_by_simulation(paper, [("paper", 10.0 * np.eye(4)), ("designed", design.Y)],
                                             t_final=1.5)
    paper_run, designed = runs["paper"], runs["designed"]
    # the Lyapunov function decays at least as fast as the certificate over the visited states says
    assert paper_run.bound_holds and designed.bound_holds
    assert designed.beta_run_rad_s >= 10.0 * (1 - 1e-6)
    # 2 % of the initial error: exp(-10 t) reaches it by ln(50)/10 = 0.39 s up to the conditioning of M
    assert designed.convergence_time_s is not None and designed.convergence_time_s < 0.6
    assert paper_run.convergence_time_s is None                  # the 0.85 rad/s mode needs ~4.6 s
    assert np.all(np.array(designed.rms_disturbance_error) < np.array(paper_run.rms_disturbance_error))


def test_design_rejects_bad_target(paper, grid):
    with pytest.raises(ValueError, match="target observer bandwidth"):
        gain_design.design_observer_gain(paper.nominal, 0.0, grid)
    with pytest.raises(ValueError, match="symmetric positive semidefinite"):
        gain_design.design_observer_gain(paper.nominal, 5.0, grid, base=np.triu(np.ones((4, 4))))


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_designed_gain_meets_its_target_on_its_own_grid():
    """gd-return-lo.  The design's promise is "at least target_rad_s on every configuration of the grid": the
    slowest eigenvalue of Y M^-1(q), computed here with numpy on the design grid, is not below the target (to
    the rounding of the eigenvalue, 1e-13, far inside the bisection's rtol of 1e-10)."""
    from analysis.linear import gain_design

    paper = blocks.load_scenario("paper")
    grid = np.array([[0.0, t2, 0.24, 0.0] for t2 in np.linspace(0.3, 3.0, 13)])
    for base in (None, 10.0 * np.eye(4)):
        design = gain_design.design_observer_gain(paper.nominal, 10.0, grid, base=base)
        rates = np.linalg.eigvals(design.Y @ np.linalg.inv(paper.nominal.inertia(grid))).real
        assert rates.min() >= 10.0 * (1.0 - 1e-13), rates.min() / 10.0 - 1.0
