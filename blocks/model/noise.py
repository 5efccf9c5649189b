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
from dataclasses import dataclass, field

import numpy as np

from blocks.kernels.noise import sampled_noise
from blocks.model.joints import JointSpace
from blocks.model.validation import read_only_array

__all__ = ["MeasurementNoise"]


@dataclass(frozen=True)
class MeasurementNoise:
    """Band-limited measurement noise ``(n_q(t), n_dq(t))``.

    Parameters
    ----------
    q_std : float or n floats
        Standard deviation of the position noise at the sample instants (rad; m on a prismatic joint):
        one number for every joint or one per joint.
    dq_std : float or n floats
        Standard deviation of the velocity noise at the sample instants (rad/s; m/s on a prismatic joint).
    seed : int
        Seed of the random generator.
    sample_period : float
        Spacing of the independent samples (s), > 0; the noise bandwidth is
        about ``1 / (2 sample_period)`` Hz.
    t_final : float
        Last time the noise is needed (s); later times hold the last sample.
    joints : JointSpace
        The measured arm's joints (n, units), a keyword.  Take it from the arm:
        ``MeasurementNoise(q_std=1e-4, joints=arm.joints)``.
    """

    q_std: tuple[float, ...] | float = 0.0
    dq_std: tuple[float, ...] | float = 0.0
    seed: int = 0
    sample_period: float = 0.001
    t_final: float = 10.0
    joints: JointSpace = field(repr=False, kw_only=True)

    def __post_init__(self) -> None:
        if not isinstance(self.joints, JointSpace):
            raise TypeError(f"'joints' must be a blocks.model.joints.JointSpace (an arm's .joints), got {self.joints!r:.80}")
        n = self.joints.count
        for name, units in (("q_std", self.joints.position_units), ("dq_std", self.joints.velocity_units)):
            given = getattr(self, name)
            try:
                value = np.asarray(given, dtype=float)
            except (TypeError, ValueError):
                value = np.array([np.nan])
            if value.ndim == 0 and not isinstance(given, bool):
                value = np.full(n, float(value))
            if value.shape != (n,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"noise.{name} must be a number or {n} finite numbers >= 0 ({', '.join(units)}), "
                                 f"one per joint of {list(self.joints.names)}, got {given!r}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"noise.seed must be a whole number >= 0, got {self.seed!r}")
        for name in ("sample_period", "t_final"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"noise.{name} must be a finite number > 0 s, got {value!r}")
        samples = None
        if self.enabled:        # no noise, no samples: long noise-free runs must not pay for them
            count = int(math.ceil(self.t_final / self.sample_period)) + 2
            rng = np.random.default_rng(self.seed)
            # read-only for good: a scenario's noise cannot be changed through it
            samples = read_only_array((rng.standard_normal((count, 2 * n)) * np.array(self.q_std + self.dq_std)).T)
        object.__setattr__(self, "_samples", samples)
        object.__setattr__(self, "_zeros", None if samples is not None else read_only_array(np.zeros((2 * n, 2))))

    @property
    def enabled(self) -> bool:
        """True when any standard deviation is non-zero."""
        return any(v > 0 for v in self.q_std + self.dq_std)

    @property
    def table(self) -> np.ndarray:
        """The samples as rows ``[n_q; n_dq]``, shape (2 n, n_samples), read-only; zeros when disabled."""
        if self._samples is None:
            return self._zeros
        return self._samples

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.joints.count

    def sample(self, t):
        """Noise at time(s) ``t`` (s): ``(n_q, n_dq)``, each of shape ``(n,)`` or ``(len(t), n)``."""
        n = self.joints.count
        value = sampled_noise(np.asarray(t, dtype=float), self.table, self.sample_period).T
        return value[..., :n], value[..., n:]
