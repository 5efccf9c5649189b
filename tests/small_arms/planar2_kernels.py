"""Row kernels of the 2-link planar arm (joint-first rows; k = [m1, m2, l1, lc1, lc2, I1, I2, g])."""
import numpy as np


def _last(rows):
    return np.moveaxis(np.asarray(rows, dtype=float), 0, -1)


def _rows(x):
    return np.moveaxis(x, -1, 0)


def inertia_matrix(k, q):
    m1, m2, l1, lc1, lc2, I1, I2, _ = k
    c2 = np.cos(q[1])
    m11 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * c2) + I1 + I2
    m12 = m2 * (lc2 ** 2 + l1 * lc2 * c2) + I2
    m22 = m2 * lc2 ** 2 + I2 + 0.0 * c2
    return np.stack([np.stack([m11, m12], -1), np.stack([m12, m22], -1)], -2)


def mass_times(k, q, v):
    return _rows(np.einsum("...ij,...j->...i", inertia_matrix(k, q), _last(v)))


def mass_solve(k, q, r):
    return _rows(np.linalg.solve(inertia_matrix(k, q), _last(r)[..., None])[..., 0])


def gravity_forces(k, q):
    m1, m2, l1, lc1, lc2, _, _, g = k
    g2 = m2 * lc2 * g * np.cos(q[0] + q[1])
    return np.stack([(m1 * lc1 + m2 * l1) * g * np.cos(q[0]) + g2, g2])


def bias_forces(k, q, dq):
    m2, l1, lc2 = k[1], k[2], k[4]
    hs = m2 * l1 * lc2 * np.sin(q[1])
    coriolis = np.stack([-hs * (2 * dq[0] * dq[1] + dq[1] ** 2), hs * dq[0] ** 2])
    return coriolis + gravity_forces(k, q)


def plant_acceleration(k, q, dq, f):
    return mass_solve(k, q, f - bias_forces(k, q, dq))


def tool_position(kin, q):
    l1, l2 = kin
    return np.stack([l1 * np.cos(q[0]) + l2 * np.cos(q[0] + q[1]),
                     l1 * np.sin(q[0]) + l2 * np.sin(q[0] + q[1]), 0.0 * q[0]])


def tool_jacobian(kin, q):
    l1, l2 = kin
    s1, c1, s12, c12 = np.sin(q[0]), np.cos(q[0]), np.sin(q[0] + q[1]), np.cos(q[0] + q[1])
    zero = 0.0 * s1
    return np.stack([np.stack([-l1 * s1 - l2 * s12, -l2 * s12]), np.stack([l1 * c1 + l2 * c12, l2 * c12]),
                     np.stack([zero, zero])])


def tool_acceleration_bias(kin, q, dq):
    l1, l2 = kin
    w1, w12 = dq[0], dq[0] + dq[1]
    return np.stack([-l1 * np.cos(q[0]) * w1 ** 2 - l2 * np.cos(q[0] + q[1]) * w12 ** 2,
                     -l1 * np.sin(q[0]) * w1 ** 2 - l2 * np.sin(q[0] + q[1]) * w12 ** 2, 0.0 * w1])
