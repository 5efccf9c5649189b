"""Reproducible measurement noise on the joint positions and velocities.

White Gaussian samples are drawn once, from a seed, on a uniform grid of
period ``sample_period`` and interpolated linearly in between.  The given
standard deviations hold at the sample instants; between them the linear
interpolation lowers the spread, so the signal's RMS over time is
``sqrt(2/3) = 0.816`` times the stated value (0.707 times at mid-interval).  The noise is
therefore a fixed, continuous function of time: an adaptive ODE solver that
evaluates the right-hand side at any time, in any order and any number of
times sees the same signal, and the same seed always gives the same run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kernels.noise import sampled_noise
from .validation import read_only_array

__all__ = ["MeasurementNoise"]

_ZERO_TABLE = read_only_array(np.zeros((8, 2)))


@dataclass(frozen=True)
class MeasurementNoise:
    """Band-limited measurement noise ``(n_q(t), n_dq(t))``.

    Parameters
    ----------
    q_std : 4 floats
        Standard deviation of the position noise at the sample instants, per joint (rad, rad, m, rad).
    dq_std : 4 floats
        Standard deviation of the velocity noise at the sample instants (rad/s, rad/s, m/s, rad/s).
    seed : int
        Seed of the random generator.
    sample_period : float
        Spacing of the independent samples (s), > 0; the noise bandwidth is
        about ``1 / (2 sample_period)`` Hz.
    t_final : float
        Last time the noise is needed (s); later times hold the last sample.
    """

    q_std: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    dq_std: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    seed: int = 0
    sample_period: float = 0.001
    t_final: float = 10.0

    def __post_init__(self) -> None:
        for name in ("q_std", "dq_std"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (4,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"noise.{name} must be 4 finite numbers >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"noise.seed must be a whole number >= 0, got {self.seed!r}")
        for name in ("sample_period", "t_final"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"noise.{name} must be a finite number > 0 s, got {value!r}")
        samples = None
        if self.enabled:        # no noise, no samples: long noise-free runs must not pay for them
            n = int(math.ceil(self.t_final / self.sample_period)) + 2
            rng = np.random.default_rng(self.seed)
            # read-only for good: a scenario's noise cannot be changed through it
            samples = read_only_array((rng.standard_normal((n, 8)) * np.array(self.q_std + self.dq_std)).T)
        object.__setattr__(self, "_samples", samples)

    @property
    def enabled(self) -> bool:
        """True when any standard deviation is non-zero."""
        return any(v > 0 for v in self.q_std + self.dq_std)

    @property
    def table(self) -> np.ndarray:
        """The samples as rows ``[n_q; n_dq]``, shape (8, n_samples), read-only; zeros when disabled."""
        if self._samples is None:
            return _ZERO_TABLE
        return self._samples

    def sample(self, t):
        """Noise at time(s) ``t`` (s): ``(n_q, n_dq)``, each of shape ``(4,)`` or ``(len(t), 4)``."""
        value = sampled_noise(np.asarray(t, dtype=float), self.table, self.sample_period).T
        return value[..., :4], value[..., 4:]
