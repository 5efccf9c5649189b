"""Checks of the arguments of the public array functions, written once.

The model functions (:func:`blocks.inertia`, :func:`blocks.forward_kinematics`,
...) take joint arrays of shape ``(..., n)`` and an arm's parameters.  Each
checks its arguments here, once, at its entry: a wrong type raises
:class:`TypeError`, a wrong shape or a non-finite entry :class:`ValueError`,
and the message names the argument, what it got and what is expected.  The
kernels underneath trust what they are given.

Examples
--------
>>> from blocks.model.joints import JointSpace
>>> from blocks.model.validation import joint_array
>>> slider = JointSpace(names=("theta", "s"), kinds=("revolute", "prismatic"))
>>> joint_array([0.0, 0.2], "q", slider).shape
(2,)
>>> joint_array([0.0, 1.0, 0.2], "q", slider)
Traceback (most recent call last):
    ...
ValueError: q must have shape (..., 2), a last axis of length 2 (joints theta, s), got shape (3,)
"""
from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from blocks.model.joints import JointSpace

__all__ = ["joint_array", "joint_arrays", "real_array", "callable_or_none", "read_only_array",
           "number_text"]


def number_text(value) -> str:
    """A value for a message: whole numbers too long to read (``10**400``) in short scientific form,
    also inside lists; anything else as its ``repr``."""
    if isinstance(value, (list, tuple)):
        inner = ", ".join(number_text(v) for v in value)
        return f"[{inner}]" if isinstance(value, list) else f"({inner}{',' if len(value) == 1 else ''})"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10 ** 15:
        digits = str(abs(value))
        return f"{'-' if value < 0 else ''}{digits[0]}.{digits[1:4]}e+{len(digits) - 1}"
    return repr(value)


def _kind(value) -> str:
    return type(value).__name__


def real_array(value, name: str) -> np.ndarray:
    """``value`` as a float array of finite real numbers (any shape).

    Raises
    ------
    TypeError
        On nothing, text, true/false, a mapping, complex numbers or other non-numbers.
    ValueError
        On ragged nesting or a non-finite entry (an integer too large for a float is not finite).
    """
    if type(value) is np.ndarray and value.dtype == np.float64:        # the common case, checked at once
        if not np.isfinite(value).all():
            _not_finite(value, name)
        return value
    if value is None or isinstance(value, (str, bytes, bool, np.bool_, Mapping)):
        raise TypeError(f"{name} must be an array of real numbers, got {_kind(value)} {value!r:.80}")
    try:
        raw = np.asarray(value)
    except ValueError:
        raise ValueError(f"{name} must be a regular array of real numbers (all rows of one length), "
                         f"got {value!r:.80}") from None
    if raw.dtype.kind not in "iufO":
        raise TypeError(f"{name} must be an array of real numbers, got an array of {raw.dtype} "
                        f"(shape {raw.shape})")
    try:
        arr = np.asarray(raw, dtype=float)
    except OverflowError:
        raise ValueError(f"{name} must be finite, got a non-finite value: a number too large for a float "
                         f"(shape {raw.shape})") from None
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of real numbers, got {value!r:.80}") from None
    if not np.isfinite(arr).all():
        _not_finite(arr, name)
    return arr


def _not_finite(arr: np.ndarray, name: str):
    where = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
    raise ValueError(f"{name} must be finite, got a non-finite value {arr[where] if where else float(arr)} "
                     f"{f'at index {where} ' if where else ''}(shape {arr.shape})")


def joint_array(value, name: str, joints: JointSpace) -> np.ndarray:
    """``value`` as a float array of shape ``(..., n)``: one entry per joint on the last axis.

    Parameters
    ----------
    value : array_like
        Joint positions, velocities, accelerations or forces (rad, m; rad/s, m/s; ...).
    name : str
        The argument's name, for the message (``"q"``, ``"dq"``).
    joints : JointSpace
        The arm's joints.

    Raises
    ------
    TypeError, ValueError
        See :func:`real_array`; ValueError also when the last axis is not one entry per joint.
    """
    arr = real_array(value, name)
    n = joints.count
    if arr.shape[-1:] != (n,):
        raise ValueError(f"{name} must have shape (..., {n}), a last axis of length {n} (joints "
                         f"{', '.join(joints.names)}), got shape {arr.shape}")
    return arr


def joint_arrays(names_values: Mapping[str, object], joints: JointSpace) -> list[np.ndarray]:
    """Several joint arrays (``{"q": q, "dq": dq}``), checked and broadcast against each other.

    Raises
    ------
    ValueError
        Also when their leading shapes do not broadcast, naming each argument's shape.
    """
    arrays = [joint_array(v, k, joints) for k, v in names_values.items()]
    try:
        return list(np.broadcast_arrays(*arrays))
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in zip(names_values, arrays))
        raise ValueError(f"{', '.join(names_values)} must have shapes that broadcast together, got {shapes}") \
            from None


def arm_model(value, name: str = "arm"):
    """``value`` when it is an arm model (:class:`~blocks.model.arm.ArmModel`: the paper's arm or a URDF arm).

    Raises
    ------
    TypeError
        Naming the argument and what it got.
    """
    from blocks.model.arm import ArmModel
    if not isinstance(value, ArmModel):
        raise TypeError(f"{name} must be an arm model (blocks.model.arm.ArmModel: blocks.model.default.default_arm() is "
                        f"the default scenario's, scenario.robot a scenario's), got {_kind(value)} {value!r:.80}")
    return value


def callable_or_none(value, name: str) -> Callable | None:
    """``value`` when it is None or can be called (a progress or callback argument).

    Raises
    ------
    TypeError
        Naming the argument and what it got.
    """
    if value is not None and not callable(value):
        raise TypeError(f"{name} must be a function (or None), got {_kind(value)} {value!r:.80}")
    return value


def read_only_array(value) -> np.ndarray:
    """A float copy of ``value`` that cannot be made writable again.

    Its memory is an immutable ``bytes`` object, so ``arr.setflags(write=True)``
    raises :class:`ValueError` (so does the same on its ``base``): a value held
    by a scenario stays what it was validated as.
    """
    arr = np.ascontiguousarray(value, dtype=float)     # no copy when it already is one; tobytes copies
    return np.frombuffer(arr.tobytes(), dtype=float).reshape(arr.shape)
