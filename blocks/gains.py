"""Controller and observer gains, validated by one function wherever they are given."""
from __future__ import annotations

import numpy as np

from .joints import RRPR_JOINTS

__all__ = ["GainError", "validated_gain", "OBSERVER_VARIANTS"]

OBSERVER_VARIANTS = ("correct", "paper-eq16")


class GainError(ValueError):
    """A gain has the wrong shape, a non-finite entry, or a value that makes the loop unusable."""


def validated_gain(value, key: str) -> np.ndarray:
    """The 4x4 gain ``gains.<key>`` from a scalar, 4 numbers or (observer only) a 4x4 matrix; read-only."""
    n = RRPR_JOINTS.count
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise GainError(f"'gains.{key}' must be a number or a list of numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise GainError(f"'gains.{key}' must be finite, got {value!r}")
    if arr.ndim == 0:
        mat = float(arr) * np.eye(n)
    elif arr.shape == (n,):
        mat = np.diag(arr)
    elif arr.shape == (n, n) and (key == "observer" or np.count_nonzero(arr - np.diag(np.diag(arr))) == 0):
        mat = arr.copy()
    else:
        allowed = "a scalar, 4 numbers" + (" or a 4x4 matrix" if key == "observer" else " or a diagonal 4x4 matrix")
        raise GainError(f"'gains.{key}' must be {allowed}, got shape {arr.shape}")
    if key != "observer" and np.any(np.diag(mat) <= 0):
        raise GainError(f"'gains.{key}' must be > 0 on every joint, got {value!r}")
    if key == "observer" and np.any(np.linalg.eigvalsh(mat + mat.T) <= 0):
        raise GainError(f"'gains.observer' must have a positive definite symmetric part (Y + Y^T > 0) for the "
                        f"observer to converge, got {value!r}")
    mat.setflags(write=False)
    return mat
