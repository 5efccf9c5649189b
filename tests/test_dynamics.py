"""Parameters, rigid-body dynamics, energy and the disturbance models, against independent values."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    PAPER_FR,
    PAPER_G,
    PAPER_K,
    PAPER_S1,
    PAPER_S2,
    SKIN_DEFAULT,
    fd_jacobian,
    reference_fk,
    reference_inertia,
)
from scipy.integrate import solve_ivp

from blocks import DisturbanceSpec, ParameterError, RobotParameters, plant
from blocks.model.disturbances import external_disturbance, friction_disturbance, tissue_disturbance
from blocks.model.rrpr.dynamics import (
    coriolis_matrix,
    coriolis_vector,
    forward_dynamics,
    gravity,
    inertia,
    inverse_dynamics,
    kinetic_energy,
    potential_energy,
)

THETA2 = np.linspace(0.0, 2 * np.pi, 73)


# ---------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------
def test_inertia_constants_match_table1(paper_params):
    """docs/model.md, "Table 1 and the constants k1..k5"."""
    k = paper_params.constants
    for name, value in PAPER_K.items():
        assert getattr(k, name) == pytest.approx(value, rel=1e-12, abs=1e-12), name
    assert k.g == PAPER_G
    p = paper_params
    # S1 and S2 of the paper's k1 (Table 1), from the Table 1 numbers
    assert p.m2 * (p.l2 ** 2 + 4 * p.l1 ** 2) == pytest.approx(PAPER_S1, rel=1e-12)
    assert (p.m3 + p.m4) * (4 * p.l1 ** 2 + 4 * p.l2 ** 2) == pytest.approx(PAPER_S2, rel=1e-12)
    # k1 = I1+I2+I3+I4 + m1 l1^2 + S1 + S2 with the paper's numbers
    assert 1.18456 + 1.36439 + 1.4629 + 1.47486 + 5.58 * 0.25 + PAPER_S1 + PAPER_S2 == pytest.approx(k.k1, rel=1e-12)


def test_paper_defaults_keep_table1_and_separate_kinematic_lengths(paper_params):
    p = paper_params
    assert (p.m1, p.m2, p.m3, p.m4) == (5.58, 0.689, 0.17, 0.08)
    assert (p.l1, p.l2, p.a1, p.a2, p.d1, p.d4) == (0.5, 0.2, 0.5, 0.2, 0.12, 0.271)
    # The kinematic lengths are their own parameters: changing them leaves the inertia alone.
    moved = RobotParameters(a1=0.6, a2=0.3)
    np.testing.assert_array_equal(inertia([0, 1.0, 0, 0], moved), inertia([0, 1.0, 0, 0], paper_params))


@pytest.mark.parametrize("name, value, fragment", [
    ("m1", -1.0, "> 0"),
    ("m3", 0.0, "> 0"),
    ("I2", -0.5, "> 0"),
    ("l1", float("nan"), "finite"),
    ("I4", float("inf"), "finite"),
    ("g", float("nan"), "finite"),
    ("a2", "0.2", "number"),
])
def test_bad_parameter_raises_parameter_error_naming_it(name, value, fragment):
    with pytest.raises(ParameterError) as info:
        RobotParameters(**{name: value})
    message = str(info.value)
    assert f"'{name}'" in message and fragment in message


# Links without mass or inertia carrying a point mass at the tip: M is singular at theta2 = 0
# (a stretched two-link arm cannot move a point mass radially through the planar joints).
DEGENERATE = {"m1": 1e-20, "m2": 1e-20, "I1": 1e-20, "I2": 1e-20, "I3": 1e-20, "I4": 1e-20,
              "m3": 0.5, "m4": 0.5, "l1": 1.0, "l2": 1.0}


def test_parameters_giving_singular_inertia_are_rejected():
    with pytest.raises(ParameterError) as info:
        RobotParameters(**DEGENERATE)
    message = str(info.value)
    assert "positive definite" in message
    for name in ("k1", "k2", "k3", "k5"):
        assert name in message


def test_degenerate_parameters_really_give_singular_inertia():
    """The rejected set is really one where M(theta2 = 0) is singular (the check is not over-strict)."""
    p, m34 = DEGENERATE, DEGENERATE["m3"] + DEGENERATE["m4"]
    k = {"k1": 8 * m34, "k2": 8 * m34, "k3": 4 * m34, "k4": m34, "k5": p["I4"]}   # Table 1 formulas, l1 = l2 = 1
    eig = np.linalg.eigvalsh(reference_inertia(0.0, k))
    assert eig.min() <= 1e-12 * eig.max()


def test_positive_parameters_always_give_positive_definite_inertia():
    """For strictly positive masses, lengths and inertias M(q) is positive definite for every theta2.

    Algebraically: k3 - k5 >= l2^2 (m2 + 4 m34), k1 - k3 >= 4 l1^2 (m2 + m34) and
    (m2 + m34)(m2 + 4 m34) - (m2 + 2 m34)^2 = m2 m34 > 0, so det M > 0.  Check on random sets.
    """
    rng = np.random.default_rng(3)
    names = ("m1", "m2", "m3", "m4", "l1", "l2", "I1", "I2", "I3", "I4")
    for _ in range(200):
        values = dict(zip(names, 10 ** rng.uniform(-3, 1, size=len(names))))
        params = RobotParameters(**values)            # must not raise
        q = np.zeros((THETA2.size, 4))
        q[:, 1] = THETA2
        assert np.linalg.eigvalsh(inertia(q, params)).min() > 0


def test_scaled_rejects_unknown_and_bad_factors(paper_params):
    with pytest.raises(ParameterError, match="mass"):
        paper_params.scaled(mass=2.0)
    with pytest.raises(ParameterError, match="'m1'"):
        paper_params.scaled(m1=-1.0)
    assert paper_params.scaled(m1=2.0).m1 == pytest.approx(11.16)


# ---------------------------------------------------------------------------------------------
# Inertia matrix
# ---------------------------------------------------------------------------------------------
def test_inertia_equals_eq5_with_paper_constants(paper_params):
    q = np.column_stack([np.full_like(THETA2, 0.3), THETA2, np.full_like(THETA2, 0.2), np.full_like(THETA2, -1.0)])
    np.testing.assert_allclose(inertia(q, paper_params), reference_inertia(THETA2), rtol=1e-12, atol=1e-12)


def test_inertia_is_spd_with_paper_eigenvalue_range(paper_params):
    q = np.zeros((THETA2.size, 4))
    q[:, 1] = THETA2
    M = inertia(q, paper_params)
    np.testing.assert_array_equal(M, np.swapaxes(M, -1, -2))
    eig = np.linalg.eigvalsh(M)
    assert eig.min() > 0
    # lambda_min = 0.25 (the prismatic joint) for every theta2
    np.testing.assert_allclose(eig[:, 0], 0.25, rtol=1e-12)
    lam_max = eig[:, -1]
    # lambda_max from 10.75 at theta2 = pi to 11.79 at theta2 = 0 (docs/model.md, "Inertia matrix", two decimals)
    assert lam_max.min() == pytest.approx(10.75, abs=0.006)
    assert lam_max.max() == pytest.approx(11.79, abs=0.006)
    assert lam_max[np.argmin(np.abs(THETA2 - np.pi))] == pytest.approx(lam_max.min())
    assert lam_max[0] == pytest.approx(lam_max.max())


def test_inertia_determinant_formula(paper_params):
    k = PAPER_K
    q = np.zeros((THETA2.size, 4))
    q[:, 1] = THETA2
    det = np.linalg.det(inertia(q, paper_params))
    expected = k["k4"] * k["k5"] * ((k["k1"] - k["k3"]) * (k["k3"] - k["k5"]) - k["k2"] ** 2 * np.cos(THETA2) ** 2 / 4)
    np.testing.assert_allclose(det, expected, rtol=1e-10)
    assert expected.min() > 0


def test_inertia_is_batched(paper_params):
    rng = np.random.default_rng(1)
    q = rng.uniform(-3, 3, size=(3, 5, 4))
    M = inertia(q, paper_params)
    assert M.shape == (3, 5, 4, 4)
    np.testing.assert_allclose(M[2, 4], inertia(q[2, 4], paper_params))


def test_observer_error_eigenvalues_match_the_model_facts(paper_params):
    """Eigenvalues of 10 M^-1(q) over theta2: 40, 12.09-12.99, 5.95-6.08, 0.848-0.930.

    docs/model.md, "Observer eigenvalues".
    """
    q = np.zeros((THETA2.size, 4))
    q[:, 1] = THETA2
    eig = np.sort(np.linalg.eigvals(10 * np.linalg.inv(inertia(q, paper_params))).real, axis=-1)
    np.testing.assert_allclose(eig[:, 3], 40.0, rtol=1e-12)
    for col, (lo, hi) in zip((0, 1, 2), ((0.848, 0.930), (5.95, 6.08), (12.09, 12.99))):
        assert eig[:, col].min() == pytest.approx(lo, abs=0.006)
        assert eig[:, col].max() == pytest.approx(hi, abs=0.006)


# ---------------------------------------------------------------------------------------------
# Coriolis / centrifugal terms
# ---------------------------------------------------------------------------------------------
def _christoffel_vector(q, dq, h=1e-6):
    """sum_jk Gamma_ijk dq_j dq_k with Gamma from central differences of the reference M."""
    def M_of(qq):
        return reference_inertia(qq[1])
    dM = np.stack([(M_of(q + h * e) - M_of(q - h * e)) / (2 * h) for e in np.eye(4)])   # dM[k, i, j]
    gamma = 0.5 * (np.einsum("kij->ijk", dM) + np.einsum("jik->ijk", dM) - np.einsum("ijk->ijk", dM))
    # gamma[i, j, k] = 0.5 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i)
    return np.einsum("ijk,j,k->i", gamma, dq, dq)


RNG_STATES = np.random.default_rng(7).uniform(-2.5, 2.5, size=(12, 8))


@pytest.mark.parametrize("state", RNG_STATES)
def test_coriolis_vector_equals_christoffel_vector(state, paper_params):
    q, dq = state[:4], state[4:]
    np.testing.assert_allclose(coriolis_vector(q, dq, paper_params), _christoffel_vector(q, dq), atol=1e-8)


@pytest.mark.parametrize("state", RNG_STATES[:6])
def test_coriolis_matrix_times_dq_equals_vector(state, paper_params):
    q, dq = state[:4], state[4:]
    np.testing.assert_allclose(coriolis_matrix(q, dq, paper_params) @ dq, _christoffel_vector(q, dq), atol=1e-8)
    np.testing.assert_allclose(coriolis_matrix(q, dq, paper_params) @ dq, coriolis_vector(q, dq, paper_params),
                               atol=1e-14)


def test_mdot_minus_2c_is_skew_along_a_trajectory(paper_params):
    """M' (finite differences in time along q(t)) - 2 C(q, q') is skew-symmetric."""
    def q_of(t):
        return np.array([0.3 + np.sin(1.3 * t), 1.0 + 0.8 * np.sin(2.1 * t + 0.4), 0.2 + 0.05 * t, np.cos(t)])

    def dq_of(t):
        return np.array([1.3 * np.cos(1.3 * t), 0.8 * 2.1 * np.cos(2.1 * t + 0.4), 0.05, -np.sin(t)])

    h = 1e-6
    for t in np.linspace(0.0, 3.0, 11):
        Mdot = (inertia(q_of(t + h), paper_params) - inertia(q_of(t - h), paper_params)) / (2 * h)
        S = Mdot - 2 * coriolis_matrix(q_of(t), dq_of(t), paper_params)
        np.testing.assert_allclose(S + S.T, 0.0, atol=1e-8)
        # and M' is not identically zero on this path (the check is not vacuous)
    assert np.abs(Mdot).max() > 0.1


def test_printed_paper_n_matrix_is_not_the_skew_factorisation(paper_params):
    """Eq. 6 as a matrix gives the right vector but not the skew property.

    docs/model.md, "Coriolis and centrifugal terms".
    """
    q, dq = np.array([0.1, 1.1, 0.2, 0.0]), np.array([0.7, -1.2, 0.0, 0.3])
    k2, s2 = PAPER_K["k2"], np.sin(q[1])
    N = np.zeros((4, 4))
    N[0, 0] = -k2 * s2 * dq[1]
    N[0, 1] = -0.5 * k2 * s2 * dq[1]
    N[1, 0] = 0.5 * k2 * s2 * dq[0]
    np.testing.assert_allclose(N @ dq, coriolis_vector(q, dq, paper_params), atol=1e-14)
    Mdot = -k2 * s2 * dq[1] * np.array([[1, 0.5, 0, 0], [0.5, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    S = Mdot - 2 * N
    assert np.abs(S + S.T).max() > 1e-3
    S = Mdot - 2 * coriolis_matrix(q, dq, paper_params)
    np.testing.assert_allclose(S + S.T, 0.0, atol=1e-14)


def test_gravity_is_gradient_of_potential(paper_params):
    q = np.array([0.4, -1.0, 0.23, 2.0])
    np.testing.assert_allclose(gravity(q, paper_params), [0.0, 0.0, -PAPER_K["k4"] * PAPER_G, 0.0], rtol=1e-12)
    grad = fd_jacobian(lambda x: np.atleast_1d(potential_energy(x, paper_params)), q)[0]
    np.testing.assert_allclose(gravity(q, paper_params), grad, atol=1e-7)


def test_potential_energy_lowers_when_tool_goes_down(paper_params):
    """d3 is positive downwards: V = m g z(tool) + const, with z = d1 - d3 - d4."""
    q = np.array([0.0, 1.0, 0.2, 0.0])
    for d3 in (0.0, 0.1, 0.3):
        qq = q.copy()
        qq[2] = d3
        z = reference_fk(qq)[2]
        assert potential_energy(qq, paper_params) - potential_energy(q, paper_params) == pytest.approx(
            PAPER_K["k4"] * PAPER_G * (z - reference_fk(q)[2]), abs=1e-12)


@pytest.mark.parametrize("state", RNG_STATES[:4])
def test_forward_dynamics_solves_equation_of_motion(state, paper_params):
    q, dq = state[:4], state[4:]
    tau = np.array([1.0, -2.0, 3.0, 0.5])
    ddq = forward_dynamics(q, dq, tau, paper_params)
    # independent: M (docs/model.md) q'' + Christoffel + G = tau
    lhs = reference_inertia(q[1]) @ ddq + _christoffel_vector(q, dq) + np.array([0, 0, -0.25 * 9.8, 0])
    np.testing.assert_allclose(lhs, tau, atol=1e-8)
    np.testing.assert_allclose(inverse_dynamics(q, dq, ddq, paper_params), tau, atol=1e-10)


# ---------------------------------------------------------------------------------------------
# Energy: integrate the plant block itself
# ---------------------------------------------------------------------------------------------
Q0 = np.array([0.3, 1.0, 0.2, -0.4])
DQ0 = np.array([1.5, -2.0, 0.3, 3.0])


def _integrate_plant(params, spec, t_final, extra=None):
    """Integrate the plant block's own dynamics with zero torque; optional extra integrand."""
    sys = plant(params, spec)
    u = np.zeros(4)

    def rhs(t, x):
        dx = sys.dynamics(t, x[:8], u)
        if extra is None:
            return dx
        return np.concatenate([dx, [extra(t, x[:4], x[4:8])]])

    x0 = np.concatenate([Q0, DQ0] + ([[0.0]] if extra is not None else []))
    sol = solve_ivp(rhs, (0.0, t_final), x0, method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True,
                    t_eval=np.linspace(0.0, t_final, 201))
    assert sol.success, sol.message
    return sol


def _kinetic(q, dq):
    M = reference_inertia(q[1])
    return 0.5 * dq @ M @ dq


def test_kinetic_energy_conserved_without_gravity_or_torque():
    params = RobotParameters(g=0.0)
    sol = _integrate_plant(params, DisturbanceSpec(kinds=()), 3.0)
    T = np.array([_kinetic(sol.y[:4, k], sol.y[4:8, k]) for k in range(sol.t.size)])
    np.testing.assert_allclose(T, T[0], rtol=1e-8)
    # the motion is not trivial: theta2 sweeps and the velocities change
    assert np.ptp(sol.y[1]) > 1.0 and np.ptp(sol.y[4:8], axis=1).max() > 0.1, np.ptp(sol.y[4:8], axis=1)
    # the package's kinetic_energy agrees with the reference along the run
    np.testing.assert_allclose(kinetic_energy(sol.y[:4].T, sol.y[4:8].T, params), T, rtol=1e-12)


def test_total_energy_conserved_with_gravity(paper_params):
    sol = _integrate_plant(paper_params, DisturbanceSpec(kinds=()), 1.0)
    q, dq = sol.y[:4].T, sol.y[4:8].T
    E = kinetic_energy(q, dq, paper_params) + potential_energy(q, paper_params)
    # independent potential: m g z of the lumped stage, z from reference FK
    E_ref = np.array([_kinetic(q[k], dq[k]) for k in range(len(q))]) + 0.25 * 9.8 * reference_fk(q)[:, 2]
    np.testing.assert_allclose(E - E[0], 0.0, atol=1e-8 * abs(E).max())
    np.testing.assert_allclose(E_ref - E_ref[0], 0.0, atol=1e-8 * abs(E_ref).max())
    # the stage fell freely: d3 = d3_0 + v t + g t^2 / 2
    assert q[-1, 2] == pytest.approx(Q0[2] + DQ0[2] * 1.0 + 0.5 * 9.8, rel=1e-8)


def test_friction_power_balance(paper_params):
    spec = DisturbanceSpec(kinds=("friction",))
    Fc, Fv, vs = np.array(spec.coulomb), np.array(spec.viscous), spec.friction_velocity

    def power(t, q, dq):        # dq . tau_friction with the documented formula
        return float(dq @ (-(Fc * np.tanh(dq / vs) + Fv * dq)))

    sol = _integrate_plant(paper_params, spec, 1.0, extra=power)
    q, dq, work = sol.y[:4].T, sol.y[4:8].T, sol.y[8]
    E = np.array([_kinetic(q[k], dq[k]) for k in range(len(q))]) + 0.25 * 9.8 * reference_fk(q)[:, 2]
    np.testing.assert_allclose(E - E[0], work, atol=1e-7)
    assert work[-1] < -1.0                            # friction removed energy
    assert np.all(np.diff(E) <= 1e-9)                 # and never adds any


# ---------------------------------------------------------------------------------------------
# Disturbance models
# ---------------------------------------------------------------------------------------------
def test_paper_eq4_is_a_constant_step(paper_params):
    spec = DisturbanceSpec(kinds=("paper",))
    assert spec.f_r == tuple(PAPER_FR)
    t = np.array([0.0, 1e-9, 0.25, 3.0, 10.0, 100.0])
    rng = np.random.default_rng(0)
    q, dq = rng.normal(size=(t.size, 4)), rng.normal(size=(t.size, 4))
    tau = external_disturbance(t, q, dq, spec, paper_params)
    np.testing.assert_array_equal(tau, np.tile(PAPER_FR, (t.size, 1)))
    for tk in t:
        np.testing.assert_array_equal(external_disturbance(float(tk), q[0], dq[0], spec, paper_params), PAPER_FR)


def test_no_disturbance_is_zero(paper_params):
    tau = external_disturbance(1.0, Q0, DQ0, DisturbanceSpec(kinds=()), paper_params)
    np.testing.assert_array_equal(tau, 0.0)


def test_friction_formula_and_sign():
    spec = DisturbanceSpec(kinds=("friction",))
    dq = np.array([[0.5, -0.2, 0.03, -2.0], [-1e-4, 1e-3, -0.5, 0.0]])
    Fc, Fv, vs = np.array([0.8, 0.6, 0.5, 0.1]), np.array([0.4, 0.3, 2.0, 0.05]), 0.01
    tau = friction_disturbance(dq, spec.coulomb, spec.viscous, spec.friction_velocity)
    np.testing.assert_allclose(tau, -(Fc * np.tanh(dq / vs) + Fv * dq), rtol=1e-14)
    moving = dq != 0
    assert np.all(np.sign(tau[moving]) == -np.sign(dq[moving]))
    assert np.all(tau[~moving] == 0)
    # well above v_s: Coulomb level plus viscous
    np.testing.assert_allclose(tau[0, 0], -(0.8 + 0.4 * 0.5), rtol=1e-12)


def _skin_state(d3, dq):
    return np.array([0.2, 1.3, d3, 0.4]), np.asarray(dq, dtype=float)


def test_tissue_zero_above_skin(paper_params):
    spec = DisturbanceSpec(kinds=("tissue",))
    assert spec.skin_height == pytest.approx(SKIN_DEFAULT)
    for d3 in (0.0, 0.2, 0.2399):
        q, dq = _skin_state(d3, [0.3, -0.2, 0.5, 1.0])
        np.testing.assert_array_equal(tissue_disturbance(q, dq, spec, paper_params), 0.0)


@pytest.mark.parametrize("d3, dq", [
    (0.245, [0.0, 0.0, 0.0, 0.0]),
    (0.245, [0.3, -0.2, 0.05, 1.0]),
    (0.250, [-0.1, 0.4, -0.02, 0.0]),
])
def test_tissue_force_below_skin_by_virtual_work(d3, dq, paper_params):
    spec = DisturbanceSpec(kinds=("tissue",))
    q, dq = _skin_state(d3, dq)
    J = fd_jacobian(reference_fk, q)                   # independent Jacobian
    v = J @ dq
    depth = spec.skin_height - reference_fk(q)[2]
    assert depth > 0
    F = np.array([-spec.tissue_drag * v[0], -spec.tissue_drag * v[1],
                  max(0.0, spec.tissue_stiffness * depth - spec.tissue_damping * v[2]), 0.0])
    tau = tissue_disturbance(q, dq, spec, paper_params)
    np.testing.assert_allclose(tau, J.T @ F, atol=1e-7)
    assert tau @ dq == pytest.approx(F @ v, abs=1e-7)
    # in all three cases the spring outweighs the damping: the normal force pushes the prismatic stage up
    # (negative along d3, which points down)
    assert F[2] > 0 and tau[2] < 0


def test_tissue_cannot_pull(paper_params):
    spec = DisturbanceSpec(kinds=("tissue",))
    q, dq = _skin_state(0.241, [0.0, 0.0, -5.0, 0.0])   # leaving the skin fast (z' = +5 m/s)
    tau = tissue_disturbance(q, dq, spec, paper_params)
    np.testing.assert_allclose(tau, 0.0, atol=1e-12)


@pytest.mark.parametrize("kwargs, name", [
    ({"kinds": ("wind",)}, "wind"),
    ({"f_r": (1.0, 2.0, 3.0)}, "f_r"),
    ({"viscous": (0.1, -0.1, 0.0, 0.0)}, "viscous"),
    ({"friction_velocity": 0.0}, "friction_velocity"),
    ({"tissue_stiffness": float("nan")}, "tissue_stiffness"),
])
def test_disturbance_spec_rejects_bad_values(kwargs, name):
    with pytest.raises(ValueError, match=name):
        DisturbanceSpec(**kwargs)
