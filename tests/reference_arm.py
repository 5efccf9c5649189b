"""An independent reference for the loop's maths, derived from the arm's geometry (not from the package).

The arm is described as bodies (docs/model.md, "The arm as bodies"): link 1 of
mass m1 with its centre of mass at l1 from joint 1; link 2 of mass m2, attached
at the end of link 1 (2 l1 from joint 1), centre of mass at l2 along it; the
prismatic stage m3 + m4 at the end of link 2 (2 l2 along it), moving down by
d3; rotational inertias I1 (turning with theta1), I2 and I3 (theta1 + theta2)
and I4 (the tool, theta1 + theta2 - theta4).  From these alone:

* the kinetic energy T(q, q') from body velocities, themselves complex-step
  derivatives of body positions along q' (exact to rounding: no subtraction);
* M(q) by polarisation of the quadratic form T (exact up to the differences);
* the Coriolis vector from Christoffel symbols of numerically differentiated M;
* gravity from the potential energy -(m3 + m4) g d3 (d3 positive downwards);
* the tool pose of Eq. 8 and its Jacobian by central differences;

and the control laws written directly with ``numpy.linalg.solve``.
"""
from __future__ import annotations

import numpy as np

STEP = 1e-30     # complex step: Im f(q + i h dq) / h = f'(q) dq to rounding


def _bodies(q, p):
    """Positions (x, y, z) of the point masses and angles of the rotating inertias at joint positions q."""
    t1, t2, d3, t4 = q
    e1 = np.array([np.cos(t1), np.sin(t1)])
    e12 = np.array([np.cos(t1 + t2), np.sin(t1 + t2)])
    masses = [
        (p.m1, np.append(p.l1 * e1, 0.0)),
        (p.m2, np.append(2 * p.l1 * e1 + p.l2 * e12, 0.0)),
        (p.m3 + p.m4, np.append(2 * p.l1 * e1 + 2 * p.l2 * e12, -d3)),
    ]
    spins = [(p.I1, t1), (p.I2, t1 + t2), (p.I3, t1 + t2), (p.I4, t1 + t2 - t4)]
    return masses, spins


def kinetic_energy(q, dq, p) -> float:
    """T = sum 1/2 m |v|^2 + 1/2 I w^2, with velocities the complex-step derivatives of positions along dq."""
    masses, spins = _bodies(np.asarray(q, dtype=complex) + 1j * STEP * np.asarray(dq, dtype=float), p)
    T = 0.0
    for m, position in masses:
        v = position.imag / STEP
        T += 0.5 * m * v @ v
    for inertia, angle in spins:
        w = angle.imag / STEP
        T += 0.5 * inertia * w * w
    return T


def mass_matrix(q, p) -> np.ndarray:
    """M(q) from T by polarisation: M_ij = T(e_i + e_j) - T(e_i) - T(e_j) (T quadratic in q')."""
    q = np.asarray(q, dtype=float)
    n = q.size
    E = np.eye(n)
    t_single = [kinetic_energy(q, E[i], p) for i in range(n)]
    M = np.empty((n, n))
    for i in range(n):
        M[i, i] = 2 * t_single[i]
        for j in range(i + 1, n):
            M[i, j] = M[j, i] = kinetic_energy(q, E[i] + E[j], p) - t_single[i] - t_single[j]
    return M


def coriolis(q, dq, p, h=1e-4) -> np.ndarray:
    """c_i = sum_jk (dM_ij/dq_k - 1/2 dM_jk/dq_i) dq_j dq_k, with dM/dq by central differences."""
    q = np.asarray(q, dtype=float)
    n = q.size
    dM = np.empty((n, n, n))        # dM[:, :, k] = dM/dq_k
    for k in range(n):
        step = np.zeros(n)
        step[k] = h
        dM[:, :, k] = (mass_matrix(q + step, p) - mass_matrix(q - step, p)) / (2 * h)
    return np.array([sum((dM[i, j, k] - 0.5 * dM[j, k, i]) * dq[j] * dq[k] for j in range(n) for k in range(n))
                     for i in range(n)])


def gravity(q, p) -> np.ndarray:
    """G = dV/dq with V = -(m3 + m4) g d3 (the stage moves down by d3; the links stay in a horizontal plane)."""
    return np.array([0.0, 0.0, -(p.m3 + p.m4) * p.g, 0.0])


def tool_pose(q, p) -> np.ndarray:
    """Eq. 8 with the kinematic lengths: [x, y, z, phi]."""
    t1, t2, d3, t4 = q
    return np.array([p.a1 * np.cos(t1) + p.a2 * np.cos(t1 + t2), p.a1 * np.sin(t1) + p.a2 * np.sin(t1 + t2),
                     p.d1 - d3 - p.d4, t1 + t2 - t4])


def tool_jacobian(q, p, h=1e-6) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return np.column_stack([(tool_pose(q + h * e, p) - tool_pose(q - h * e, p)) / (2 * h) for e in np.eye(q.size)])


def disturbance(t, q, dq, spec, p) -> np.ndarray:
    """The external disturbance models written from their definitions (docs/model.md)."""
    out = np.zeros(4)
    if "paper" in spec.kinds:
        out += np.array(spec.f_r) * (1.0 if 2 * t + 1 > 0 else -1.0)
    if "friction" in spec.kinds:
        out -= np.array(spec.coulomb) * np.tanh(np.asarray(dq) / spec.friction_velocity) \
            + np.array(spec.viscous) * np.asarray(dq)
    if "tissue" in spec.kinds:
        J = tool_jacobian(q, p)
        depth = spec.skin_height - tool_pose(q, p)[2]
        if depth > 0:
            v = J @ dq
            F = np.array([-spec.tissue_drag * v[0], -spec.tissue_drag * v[1],
                          max(0.0, spec.tissue_stiffness * depth - spec.tissue_damping * v[2]), 0.0])
            out += J.T @ F
    return out


def plant_acceleration(q, dq, force, p) -> np.ndarray:
    return np.linalg.solve(mass_matrix(q, p), force - coriolis(q, dq, p) - gravity(q, p))


def computed_torque(q, dq, q_ref, dq_ref, ddq_ref, d_hat, kp, kd, nominal) -> np.ndarray:
    """Eq. 11 with diagonal gains given as 4-vectors."""
    v = ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)
    return mass_matrix(q, nominal) @ v + coriolis(q, dq, nominal) + gravity(q, nominal) - d_hat


def observer_rate(q, dq, tau, z, Y, nominal) -> np.ndarray:
    """z' = -Y M^-1 (tau + Y q' + z - N q' - G), the correct law (Chen 2000 / Mohammadi 2013)."""
    d_hat = Y @ dq + z
    return -Y @ np.linalg.solve(mass_matrix(q, nominal), tau + d_hat - coriolis(q, dq, nominal) - gravity(q, nominal))
