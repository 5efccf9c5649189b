"""Start values checked against the type of the FMU variable they go to, before any reaches native code.

A C setter converts silently: ``fmi3SetInt8`` with 1000 stores -24, ``fmi3SetUInt8`` with -1 stores 255,
``fmi3SetFloat32`` with 1e39 stores infinity.  :func:`checked_start_value` refuses such values with a message
naming the variable, the value and the range of its type.
"""
from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from .errors import FMUStartValueError

__all__ = ["INTEGER_RANGES", "FLOAT32_MAX", "checked_start_value"]

# inclusive ranges of the FMI integer types (FMI 2 Integer and enumerations are C int, FMI 3 enumerations Int64)
INTEGER_RANGES = {
    "Int8": (-2**7, 2**7 - 1), "UInt8": (0, 2**8 - 1), "Int16": (-2**15, 2**15 - 1), "UInt16": (0, 2**16 - 1),
    "Int32": (-2**31, 2**31 - 1), "UInt32": (0, 2**32 - 1), "Int64": (-2**63, 2**63 - 1), "UInt64": (0, 2**64 - 1),
}
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _integer_range(type_name: str, fmi_version: int) -> tuple[int, int]:
    if type_name in ("Integer", "Enumeration") and fmi_version == 2:
        return INTEGER_RANGES["Int32"]
    if type_name == "Enumeration":
        return INTEGER_RANGES["Int64"]
    return INTEGER_RANGES[type_name]


def _elements(value, count: int, what: str) -> list:
    """``value`` as a flat list of ``count`` elements (a scalar for a scalar variable)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (Iterable, np.ndarray)):
        items = [value]
    else:
        items = list(np.asarray(value, dtype=object).ravel())
    if len(items) != count:
        raise FMUStartValueError(f"{what}: {len(items)} value(s) given, the variable has {count} element(s)")
    return items


def _one(item, variable, fmi_version: int, what: str):
    t = variable.type
    if t in ("Real", "Float64", "Float32"):
        if isinstance(item, (bool, np.bool_, str, bytes)):
            raise FMUStartValueError(f"{what}: {item!r} is not a number ({t})")
        try:
            number = float(item)
        except (TypeError, ValueError):
            raise FMUStartValueError(f"{what}: {item!r} is not a number ({t})") from None
        if t == "Float32" and math.isfinite(number) and abs(number) > FLOAT32_MAX:
            raise FMUStartValueError(f"{what}: {number!r} is outside the Float32 range (|value| <= {FLOAT32_MAX:.7g})")
        return number
    if t == "Boolean":
        if isinstance(item, (bool, np.bool_)) or (isinstance(item, (int, np.integer)) and item in (0, 1)):
            return bool(item)
        raise FMUStartValueError(f"{what}: {item!r} is not a Boolean (True, False, 1 or 0)")
    if t == "String":
        if not isinstance(item, str):
            raise FMUStartValueError(f"{what}: {item!r} is not a string (String)")
        if "\x00" in item:
            raise FMUStartValueError(f"{what}: the string holds a NUL character, which C cannot pass")
        return item
    if t in INTEGER_RANGES or t in ("Integer", "Enumeration"):
        low, high = _integer_range(t, fmi_version)
        allowed = f"a whole number in [{low}, {high}] ({'FMI 2 ' if fmi_version == 2 else ''}{t})"
        if isinstance(item, (bool, np.bool_)) or isinstance(item, (str, bytes)):
            raise FMUStartValueError(f"{what}: {item!r} is not {allowed}")
        if isinstance(item, (int, np.integer)):
            number = int(item)
        else:
            try:
                f = float(item)
            except (TypeError, ValueError):
                raise FMUStartValueError(f"{what}: {item!r} is not {allowed}") from None
            if not (math.isfinite(f) and f == int(f)):
                raise FMUStartValueError(f"{what}: {item!r} is not {allowed}")
            number = int(f)
        if not low <= number <= high:
            raise FMUStartValueError(f"{what}: {number} is outside the range of its type: {allowed}; the FMU would "
                                     "store a wrapped value")
        return number
    raise FMUStartValueError(f"{what}: variables of type {t} cannot be given a start value")


def checked_start_value(variable, value, fmi_version: int, count: int = 1, source: str = "FMU") -> list:
    """The start value(s) for ``variable`` as a list ready for the FMI setter of its type.

    Parameters
    ----------
    variable : fmpy.model_description.ModelVariable
        The variable (its ``type`` and ``name`` are used).
    value : scalar or array_like
        The value; for an FMI 3 array, ``count`` values (any shape, row-major).
    fmi_version : int
        2 or 3 (FMI 2 ``Integer`` is a C int).
    count : int
        Number of elements of the variable.
    source : str
        Name of the FMU, for the message.

    Raises
    ------
    FMUStartValueError
        Naming the variable, the value and what its type allows.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> checked_start_value(SimpleNamespace(name="k", type="UInt8"), 200, 3)
    [200]
    >>> checked_start_value(SimpleNamespace(name="k", type="Int8"), 1000, 3)
    Traceback (most recent call last):
    ...
    fmu.errors.FMUStartValueError: FMU: start value of k: 1000 is outside the range of its type: a whole number \
in [-128, 127] (Int8); the FMU would store a wrapped value
    """
    what = f"{source}: start value of {variable.name}"
    return [_one(item, variable, fmi_version, what) for item in _elements(value, count, what)]
