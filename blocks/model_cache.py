"""Nominal-model terms remembered at their last arguments, so the controller and the observer share one evaluation.

In the Figure-2 loop the controller and the observer both evaluate the nominal
model ``M^(q)`` and ``N^(q, q') q' + G^(q)`` at the same measured ``(q, q')``,
so each right-hand-side call of the loop would compute them twice with
identical arguments.  :class:`NominalTerms` remembers the value at the last
arguments, compared byte for byte, so a hit returns exactly the numbers a new
evaluation would give; the blocks stay independent systems that can be used,
wired and tested on their own.

The remembered arrays are returned read-only: a caller cannot change what the
next caller receives by accident.  Only one-point calls (1-D float64
arguments) are remembered; a grid of columns, or other dtypes, are evaluated
directly.  A remembered value is stored as one
tuple, so threads sharing an instance see either a matching pair or recompute.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .dynamics import coriolis_vector, gravity, inertia
from .parameters import RobotParameters

__all__ = ["NominalTerms", "nominal_terms"]


_FLOAT64 = np.dtype(np.float64)      # numpy's one float64 dtype object: an identity test is enough


def _frozen(value: np.ndarray) -> np.ndarray:
    value.setflags(write=False)
    return value


class NominalTerms:
    """``(M(q), N(q, q') q' + G(q))`` of one parameter set, remembered at the last one-point ``(q, q')``.

    Parameters
    ----------
    params : RobotParameters
        The model evaluated (for the controller and observer: the nominal arm).
    """

    def __init__(self, params: RobotParameters) -> None:
        self.params = params
        self._last: tuple[tuple[bytes, bytes] | None, tuple[np.ndarray, np.ndarray] | None] = (None, None)

    def __call__(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inertia matrix (kg m^2, kg) and bias forces (N m, N) at joint positions ``q`` and velocities ``dq``.

        Parameters
        ----------
        q, dq : numpy.ndarray, shape (..., 4)
            Joint positions (rad, m) and velocities (rad/s, m/s).

        Returns
        -------
        M : numpy.ndarray, shape (..., 4, 4)
        h : numpy.ndarray, shape (..., 4)
            ``N(q, q') q' + G(q)``.
        """
        p = self.params
        if q.ndim != 1 or dq.ndim != 1 or q.dtype is not _FLOAT64 or dq.dtype is not _FLOAT64:
            return inertia(q, p), coriolis_vector(q, dq, p) + gravity(q, p)
        key = (q.tobytes(), dq.tobytes())       # equal bytes of two float64 vectors: equal arguments
        last = self._last
        if last[0] == key:
            return last[1]
        value = (_frozen(inertia(q, p)), _frozen(coriolis_vector(q, dq, p) + gravity(q, p)))
        self._last = (key, value)
        return value


@lru_cache(maxsize=64)
def nominal_terms(params: RobotParameters) -> NominalTerms:
    """The one :class:`NominalTerms` of ``params`` in this process, shared by every block built on equal parameters."""
    return NominalTerms(params)
