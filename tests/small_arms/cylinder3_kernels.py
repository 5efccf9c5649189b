"""Row kernels of the 3-joint cylindrical arm (joint-first rows; k = [J, m2, m3, g])."""
import numpy as np


def _last(rows):
    return np.moveaxis(np.asarray(rows, dtype=float), 0, -1)


def _rows(x):
    return np.moveaxis(x, -1, 0)


def inertia_matrix(k, q):
    J, m2, m3, _ = k
    r = np.asarray(q[2], dtype=float)
    zero = 0.0 * r
    return np.stack([np.stack([J + m3 * r ** 2, zero, zero], -1), np.stack([zero, m2 + m3 + zero, zero], -1),
                     np.stack([zero, zero, m3 + zero], -1)], -2)


def mass_times(k, q, v):
    return _rows(np.einsum("...ij,...j->...i", inertia_matrix(k, q), _last(v)))


def mass_solve(k, q, r):
    return _rows(np.linalg.solve(inertia_matrix(k, q), _last(r)[..., None])[..., 0])


def gravity_forces(k, q):
    J, m2, m3, g = k
    zero = 0.0 * np.asarray(q[0], dtype=float)
    return np.stack([zero, (m2 + m3) * g + zero, zero])


def bias_forces(k, q, dq):
    m3 = k[2]
    r = q[2]
    return np.stack([2 * m3 * r * dq[2] * dq[0], 0.0 * r, -m3 * r * dq[0] ** 2]) + gravity_forces(k, q)


def plant_acceleration(k, q, dq, f):
    return mass_solve(k, q, f - bias_forces(k, q, dq))


def tool_position(kin, q):
    return np.stack([q[2] * np.cos(q[0]), q[2] * np.sin(q[0]), q[1] + 0.0 * q[0]])


def tool_jacobian(kin, q):
    c, s = np.cos(q[0]), np.sin(q[0])
    zero, one = 0.0 * c, 1.0 + 0.0 * c
    return np.stack([np.stack([-q[2] * s, zero, c]), np.stack([q[2] * c, zero, s]), np.stack([zero, one, zero])])


def tool_acceleration_bias(kin, q, dq):
    c, s = np.cos(q[0]), np.sin(q[0])
    return np.stack([-2 * s * dq[0] * dq[2] - q[2] * c * dq[0] ** 2, 2 * c * dq[0] * dq[2] - q[2] * s * dq[0] ** 2,
                     0.0 * c])
