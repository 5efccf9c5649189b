"""The arm model of Eq. 5-7 over a member axis: N arms' inertia, bias forces and accelerations at once."""
from __future__ import annotations

import dataclasses
from typing import Iterable, Sequence

import numpy as np

from ..parameters import InertiaConstants, RobotParameters
from ..systems import JOINTS

__all__ = ["BatchArm", "batched_constants"]


def batched_constants(params: Sequence[RobotParameters]) -> InertiaConstants:
    """The inertia constants k1..k5 and g of each member, as arrays of shape (N,).

    Each member's constants come from :attr:`RobotParameters.constants`, so
    the batch uses exactly the single run's numbers.
    """
    per_member = [p.constants for p in params]
    return InertiaConstants(**{f.name: np.array([getattr(c, f.name) for c in per_member], dtype=float)
                               for f in dataclasses.fields(InertiaConstants)})


class BatchArm:
    """Eq. 5-7 of N arms at once, in signal-major layout: joint vectors are (4, N).

    ``M(q)`` of Eq. 5 depends on ``theta2`` only and has one prismatic joint
    decoupled, so ``M v`` and ``M^-1 r`` have short closed forms over the
    member axis; a batched ``numpy.linalg.solve`` of 1000 4x4 systems costs
    about ten times as much.  These formulas restate
    :mod:`blocks.dynamics` for speed; the tests check them member by
    member against it, and :meth:`check_against` does so at run time.

    Parameters
    ----------
    constants : InertiaConstants
        k1..k5 (kg m^2; k4 in kg) and g (m/s^2), each of shape (N,) or scalar.
    """

    def __init__(self, constants: InertiaConstants) -> None:
        c = constants
        self.constants = c
        self.k2 = np.asarray(c.k2, dtype=float)
        self.half_k2 = 0.5 * self.k2
        self.k3, self.k4, self.k5 = (np.asarray(v, dtype=float) for v in (c.k3, c.k4, c.k5))
        self.k1_minus_k5 = np.asarray(c.k1, dtype=float) - self.k5
        self.k3_minus_k5 = self.k3 - self.k5
        self.inv_k4, self.inv_k5 = 1.0 / self.k4, 1.0 / self.k5
        self.gravity_force = -self.k4 * np.asarray(c.g, dtype=float)      # G[2], N

    def mass_times(self, c2: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``M(q) v`` for ``c2 = cos(theta2)``, shape (N,), and ``v``, shape (4, N) (the result's shape)."""
        k2c2 = self.k2 * c2
        m00 = self.k1_minus_k5 + self.k5 + k2c2
        m01 = self.k3 + 0.5 * k2c2
        k5v3 = self.k5 * v[3]
        out = np.empty((JOINTS,) + np.shape(c2))
        out[0] = m00 * v[0] + m01 * v[1] - k5v3
        out[1] = m01 * v[0] + self.k3 * v[1] - k5v3
        out[2] = self.k4 * v[2]
        out[3] = k5v3 - self.k5 * (v[0] + v[1])
        return out

    def mass_solve(self, c2: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``M(q)^-1 r`` for ``c2 = cos(theta2)``, shape (N,), and ``r``, shape (4, N) (the result's shape).

        Row 3 of ``M x = r`` gives ``x3 = x0 + x1 + r3 / k5``; substituting it
        leaves a 2x2 system in ``x0, x1`` whose determinant
        ``(k1 - k3)(k3 - k5) - k2^2 c2^2 / 4`` is positive for every valid arm.
        """
        k2c2 = self.k2 * c2
        a = self.k1_minus_k5 + k2c2
        b = self.k3_minus_k5 + 0.5 * k2c2
        c = self.k3_minus_k5
        r03 = r[0] + r[3]
        r13 = r[1] + r[3]
        inv_det = 1.0 / (a * c - b * b)
        out = np.empty((JOINTS,) + np.shape(c2))
        out[0] = (c * r03 - b * r13) * inv_det
        out[1] = (a * r13 - b * r03) * inv_det
        out[2] = r[2] * self.inv_k4
        out[3] = out[0] + out[1] + r[3] * self.inv_k5
        return out

    def bias(self, s2: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """``N(q, q') q' + G(q)`` (Eq. 6-7) for ``s2 = sin(theta2)``, shape (N,), and ``dq``, shape (4, N)."""
        k2s2 = self.k2 * s2
        out = np.empty((JOINTS,) + np.shape(s2))
        out[0] = -k2s2 * dq[1] * (dq[0] + 0.5 * dq[1])
        out[1] = 0.5 * k2s2 * dq[0] * dq[0]
        out[2] = self.gravity_force
        out[3] = 0.0
        return out

    def check_against(self, params: Sequence[RobotParameters], members: Iterable[int] | None = None,
                      samples: int = 3, seed: int = 0) -> None:
        """Raise ``AssertionError`` unless these formulas reproduce :mod:`blocks.dynamics`.

        Parameters
        ----------
        params : sequence of RobotParameters
            The N members' parameters this arm was built from.
        members : iterable of int, optional
            Which members to compare (default all), each at ``samples`` random
            states: ``M v``, ``M^-1 r`` and ``N q' + G`` to 1e-9 relative.
        """
        from ..dynamics import coriolis_vector, gravity, inertia
        rng = np.random.default_rng(seed)
        members = range(len(params)) if members is None else members
        for _ in range(samples):
            q, dq, v = rng.uniform(-3, 3, (3, JOINTS, len(params)))
            c2, s2 = np.cos(q[1]), np.sin(q[1])
            got_all = (self.mass_times(c2, v), self.mass_solve(c2, v), self.bias(s2, dq))
            for i in members:
                M = inertia(q[:, i], params[i])
                want = (M @ v[:, i], np.linalg.solve(M, v[:, i]),
                        coriolis_vector(q[:, i], dq[:, i], params[i]) + gravity(q[:, i], params[i]))
                for name, w, g in zip(("M v", "M^-1 r", "N q' + G"), want, got_all):
                    if not np.allclose(g[:, i], w, rtol=1e-9, atol=1e-12):
                        raise AssertionError(f"batched {name} of member {i} disagrees with blocks.dynamics: "
                                             f"{g[:, i]} vs {w}")
