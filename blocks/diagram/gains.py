"""Controller and observer gains: the one check of a gain, wherever it is given.

A scenario file, a batch variant and a block factory all give a gain the same
way -- a number, one number per joint, or (the observer only) a full matrix --
and all of them turn it into a matrix here, so that a gain one of them accepts
none of the others refuses.

Examples
--------
>>> from blocks.diagram.gains import validated_gain
>>> from blocks.model.joints import JointSpace
>>> arm = JointSpace(names=("theta", "s"), kinds=("revolute", "prismatic"))
>>> float(validated_gain(180, "kp", arm)[1, 1])
180.0
>>> validated_gain(-1, "kd", arm)
Traceback (most recent call last):
    ...
blocks.diagram.gains.GainError: 'gains.kd' must be > 0 on every joint, got -1
"""
from __future__ import annotations

import numpy as np

from blocks.model.joints import JointSpace
from blocks.model.validation import number_text, read_only_array

__all__ = ["GainError", "GAIN_KEYS", "OBSERVER_VARIANTS", "validated_gain"]

#: The gains a scenario gives, with their units: proportional (1/s^2), derivative (1/s), observer ``Y``.
GAIN_KEYS = {"kp": "1/s^2", "kd": "1/s", "observer": "kg m^2/s (kg/s on the prismatic joint)"}

#: The observer laws: the correct one and the paper's Eq. 16 as printed (an extra ``- Y q'`` term).
OBSERVER_VARIANTS = ("correct", "paper-eq16")


class GainError(ValueError):
    """A gain is invalid; the message names ``gains.<key>``, the value and what is allowed."""


def validated_gain(value, key: str, joints: JointSpace, arm_name: str | None = None) -> np.ndarray:
    """A gain as the loop uses it: an n x n matrix (n joints), checked and read-only.

    Parameters
    ----------
    value : float, sequence of n floats, or n x n nested sequence / array
        A number (the same gain on every joint), one number per joint (a
        diagonal matrix) or a full matrix.  ``kp`` and ``kd`` must be diagonal;
        ``observer`` may be any matrix ``Y``.
    key : {"kp", "kd", "observer"}
        Which gain: ``kp`` (1/s^2) and ``kd`` (1/s) of the computed-torque law,
        ``observer`` the observer gain ``Y`` (kg m^2/s, kg/s on a prismatic joint).
    joints : JointSpace
        The arm's joints.
    arm_name : str, optional
        The arm's name, for the message on a gain of the wrong size.

    Returns
    -------
    numpy.ndarray
        A new (n, n) float array that is read-only and cannot be made writable again.

    Raises
    ------
    GainError
        On text or true/false, a non-finite entry (a whole number too large
        for a float is not finite), a wrong shape, a
        non-diagonal ``kp`` or ``kd``, a ``kp`` or ``kd`` entry <= 0, or an
        observer gain whose symmetric part ``Y + Y^T`` is not positive
        definite (then the estimate need not converge).
    """
    if key not in GAIN_KEYS:
        raise GainError(f"'gains.{key}' is not a gain; gains are {list(GAIN_KEYS)}")
    n = joints.count
    full = key == "observer"
    allowed = f"a number, {n} numbers or {'a' if full else 'a diagonal'} {n}x{n} matrix"
    try:
        matrix = _as_matrix(value, key, joints, allowed, arm_name)
    except RecursionError:
        raise GainError(f"'gains.{key}' must be {allowed}, got lists nested too deeply") from None
    if full:
        # d_hat' = Y M^-1 (d - d_hat): with M > 0 the error decays when Y + Y^T > 0; the symmetric part is
        # scaled to at most 1 first, so that entries near 1e308 do not overflow
        symmetric = 0.5 * matrix + 0.5 * matrix.T
        scale = np.abs(symmetric).max()
        if scale == 0 or np.linalg.eigvalsh(symmetric / scale).min() <= 0:
            raise GainError(f"'gains.{key}' must have a positive definite symmetric part (Y + Y^T > 0) "
                            f"for the observer to converge, got {_shown(value)}")
    else:
        if np.count_nonzero(matrix - np.diag(np.diag(matrix))):
            raise GainError(f"'gains.{key}' must be {allowed} (one gain per joint, no coupling), "
                            f"got {_shown(value)}")
        if np.any(np.diag(matrix) <= 0):
            raise GainError(f"'gains.{key}' must be > 0 on every joint, got {_shown(value)}")
    return read_only_array(matrix)


def _as_matrix(value, key: str, joints: JointSpace, allowed: str, arm_name: str | None) -> np.ndarray:
    """A number, an n-vector or an n x n array of finite numbers as a new n x n float array."""
    n = joints.count
    if _holds_non_numbers(value):
        raise GainError(f"'gains.{key}' must be {allowed}, got {_shown(value)}")
    try:
        arr = np.array(value, dtype=float)      # a copy: the caller's array stays the caller's
    except OverflowError:                       # a whole number beyond any float (10**400)
        raise GainError(f"'gains.{key}' must be a finite number, got {_shown(value)}") from None
    except (TypeError, ValueError):
        raise GainError(f"'gains.{key}' must be {allowed}, got {_shown(value)}") from None
    if not np.all(np.isfinite(arr)):
        raise GainError(f"'gains.{key}' must be a finite number, got {_shown(value)}")
    if arr.ndim == 0:
        return float(arr) * np.eye(n)
    if arr.shape == (n,):
        return np.diag(arr)
    if arr.shape == (n, n):
        return arr
    if arr.ndim in (1, 2) and arr.shape[0] != n:
        arm = f"the arm {arm_name!r}" if arm_name else "the arm"
        given = f"{arr.shape[0]} values" if arr.ndim == 1 else f"{arr.shape[0]}x{arr.shape[1]} entries"
        raise GainError(f"'gains.{key}' has {given}; {arm} has {n} joints ({', '.join(joints.names)}): give "
                        f"{allowed}, got {_shown(value)} (shape {arr.shape})")
    raise GainError(f"'gains.{key}' must be {allowed}, got {_shown(value)} (shape {arr.shape})")


def _holds_non_numbers(value) -> bool:
    """Text, true/false or nothing anywhere in a (nested) value: numpy would read them as numbers (or nan)."""
    if value is None or isinstance(value, (bool, np.bool_, str, bytes)):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "bUSO" and (value.dtype.kind != "O" or any(map(_holds_non_numbers, value.flat)))
    if isinstance(value, (list, tuple)):
        return any(_holds_non_numbers(v) for v in value)
    return False


def _shown(value) -> str:
    """The value as the user wrote it (arrays as lists, huge whole numbers short) for messages."""
    return number_text(value.tolist() if isinstance(value, np.ndarray) else value)
