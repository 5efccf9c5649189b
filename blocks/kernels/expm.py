"""The exponential of a small square matrix, in the numpy subset numba compiles.

:func:`expm_small` is the scaling-and-squaring method with the degree-13
Pade approximant of Higham (2005), "The scaling and squaring method for the
matrix exponential revisited", SIAM J. Matrix Anal. Appl. 26(4): the matrix
is scaled by ``2^-s`` until its 1-norm is at most ``theta_13 = 5.37``, where
the [13/13] approximant is exact to double precision, and the result is
squared ``s`` times.  It serves the sampled observer's zero-order-hold update
(:func:`blocks.diagram.digital.observer_zoh_update`), a 5x5 matrix per sample, in
the numpy blocks and in the compiled sampled engine alike.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["expm_small"]

# Coefficients b_0 .. b_13 of the [13/13] Pade approximant of exp (Higham 2005, Table 2.3 and eq. 2.5).
_B = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
               129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0,
               960960.0, 16380.0, 182.0, 1.0])
# The largest 1-norm for which the [13/13] approximant's backward error is below the unit roundoff.
_THETA_13 = 5.371920351148152


def expm_small(a):
    """``exp(a)`` of a square matrix ``a`` (n, n), float.

    Parameters
    ----------
    a : numpy.ndarray
        A finite square matrix (dimensionless: a rate matrix times a time).

    Returns
    -------
    numpy.ndarray
        ``exp(a)``, shape (n, n); NaN where ``a`` is not finite.
    """
    n = a.shape[0]
    norm = 0.0                      # the 1-norm: largest column sum of magnitudes
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(a[i, j])
        if col > norm or col != col:
            norm = col
    if not norm < np.inf:           # not finite: no scaling count exists
        return np.full((n, n), np.nan)
    squarings = 0
    if norm > _THETA_13:
        squarings = int(math.ceil(math.log2(norm / _THETA_13)))
    x = np.ascontiguousarray(a) * (0.5 ** squarings)
    eye = np.eye(n)
    x2 = x @ x
    x4 = x2 @ x2
    x6 = x4 @ x2
    b = _B
    inner_u = x6 @ (b[13] * x6 + b[11] * x4 + b[9] * x2) + b[7] * x6 + b[5] * x4 + b[3] * x2 + b[1] * eye
    u = x @ inner_u
    v = x6 @ (b[12] * x6 + b[10] * x4 + b[8] * x2) + b[6] * x6 + b[4] * x4 + b[2] * x2 + b[0] * eye
    r = np.ascontiguousarray(np.linalg.solve(v - u, v + u))
    for _ in range(squarings):
        r = r @ r
    return r
