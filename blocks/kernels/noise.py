"""Measurement noise: seeded white samples on a uniform grid, interpolated linearly (see :mod:`blocks.model.noise`)."""
from __future__ import annotations

import numpy as np

__all__ = ["sampled_noise"]


def sampled_noise(t, table, period):
    """Noise rows at time(s) ``t`` (s) from samples ``table`` taken every ``period`` s.

    Parameters
    ----------
    t : float or numpy.ndarray
        One time or a row of ``K`` times; before 0 the first sample holds,
        after the last sample time the last one.
    table : numpy.ndarray
        Samples, shape ``(n_signals, n_samples)``, or ``(n_signals,
        n_samples, N)`` with one column of samples per batch member.
    period : float
        Sample spacing (s).

    Returns
    -------
    numpy.ndarray
        ``(n_signals,)`` for one time, ``(n_signals, K)`` for ``K`` times, or
        ``(n_signals, N)`` for a batch table at one time.
    """
    last = table.shape[1] - 1
    position = np.minimum(np.maximum(t / period, 0.0), last * 1.0)
    index = _sample_index(position, last)
    weight = position - index
    return (1.0 - weight) * table[:, index] + weight * table[:, index + 1]


def _sample_index(position, last):
    """The sample at or before ``position`` (>= 0), at most ``last - 1``: an int, or int64 array for arrays.

    (The compiled engine traces the array form on one time: the index stays a
    whole-valued expression until it reads the table.)
    """
    if isinstance(position, float):        # one time (numba compiles this branch only; it has no astype on floats)
        return min(int(position), last - 1)
    return np.minimum(np.floor(position), last - 1.0).astype(np.int64)
