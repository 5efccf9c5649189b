"""Typed analysis results and their strict JSON form.

Every analysis returns a frozen dataclass that derives from :class:`JsonResult`;
readers use its attributes, files hold its :meth:`~JsonResult.to_json` text.
The JSON keys are the field names, in field order, so a file reads the same as
the dictionaries the analyses returned before they were typed.

Strict JSON
    ``to_json`` never writes ``NaN`` or ``Infinity``: a value that is not a
    finite number is written as ``null``.  Read back with
    :meth:`~JsonResult.from_json`, ``null`` becomes ``None`` where the field
    may be ``None`` (its docstring says what ``None`` means there, for example
    "not settled") and ``nan`` in a plain float field (a number that could not
    be computed).  Where infinity has a meaning (an unlimited critical speed)
    the result carries a flag saying so and restores it.

Only plain data goes in: numbers, strings, lists, dicts, numpy arrays and
scalars (written as lists and numbers), complex numbers (written as
``[re, im]``) and other results.  Anything else -- a python-control system, a
response object -- is refused by name rather than written as something a
reader cannot use.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import math
import types
import typing

import numpy as np

__all__ = ["JsonResult", "plain", "from_plain", "omitted_if_none", "strict_json"]

# Field metadata: leave the key out of the JSON when the value is None (keys that a result has only sometimes).
_OMIT = "omit_if_none"


def omitted_if_none(**kwargs):
    """A dataclass field, default None, whose key is left out of the JSON while it is None."""
    return dataclasses.field(default=None, metadata={_OMIT: True}, **kwargs)


def plain(value):
    """``value`` as JSON-ready Python data; every non-finite float becomes None.

    Raises
    ------
    TypeError
        For a value that has no JSON form (for example a python-control object).
    """
    if isinstance(value, JsonResult):
        return value.as_dict()
    if dataclasses.is_dataclass(value) and hasattr(value, "as_dict"):
        return plain(value.as_dict())
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (complex, np.complexfloating)):
        return [plain(float(value.real)), plain(float(value.imag))]
    raise TypeError(f"{type(value).__module__}.{type(value).__name__} has no JSON form; results hold plain "
                    "numbers, strings, lists, dicts and other results")


def strict_json(data, indent: int = 1) -> str:
    """Strict JSON text of plain data (NaN and infinities written as null), ending in a newline."""
    return json.dumps(plain(data), indent=indent, allow_nan=False) + "\n"


@functools.cache
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _arms(tp) -> tuple:
    return typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,)


def _fits(tp, data) -> bool:
    """Whether JSON data has the shape of type ``tp`` (used to choose a union arm)."""
    origin = typing.get_origin(tp) or tp
    if dataclasses.is_dataclass(origin) or origin is dict:
        return isinstance(data, dict)
    if origin in (list, tuple, np.ndarray, complex):
        return isinstance(data, list)
    if origin is bool:
        return isinstance(data, bool)
    if origin in (int, float):
        return isinstance(data, (int, float)) and not isinstance(data, bool)
    if origin is str:
        return isinstance(data, str)
    return True


def from_plain(tp, data, where: str = "result"):
    """JSON data read back as type ``tp`` (a result class, list/dict/tuple of them, numbers, strings).

    ``where`` names the place in the result for error messages.
    """
    arms = _arms(tp)
    if data is None:
        if type(None) in arms or tp is typing.Any:
            return None
        if float in arms:
            return math.nan                  # a float written as null: not a finite number
        raise ValueError(f"{where}: null where a value of type {tp} is needed")
    candidates = [a for a in arms if a is not type(None)]
    if len(candidates) > 1:
        tp = next((a for a in candidates if _fits(a, data)), candidates[0])
    else:
        tp = candidates[0]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is typing.Any:
        return data
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp.from_dict(data, where) if issubclass(tp, JsonResult) else _dataclass(tp, data, where)
    if origin is list or tp is list:
        if not isinstance(data, list):
            raise ValueError(f"{where}: expected a list, got {data!r}")
        return [from_plain(args[0], v, f"{where}[{i}]") for i, v in enumerate(data)] if args else list(data)
    if origin is tuple or tp is tuple:
        if not args:
            return tuple(data)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(from_plain(args[0], v, f"{where}[{i}]") for i, v in enumerate(data))
        return tuple(from_plain(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, data)))
    if origin is dict or tp is dict:
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected an object, got {data!r}")
        return {k: from_plain(args[1], v, f"{where}[{k!r}]") for k, v in data.items()} if args else dict(data)
    if tp is complex:
        return complex(*(math.nan if v is None else v for v in data))
    if tp is np.ndarray:
        return np.asarray(data, dtype=float)            # numpy reads null (None) as nan
    if tp is float:
        return float(data)
    if tp in (int, str, bool) and not isinstance(data, tp):
        raise ValueError(f"{where}: expected {tp.__name__}, got {data!r}")
    return data


def _dataclass(cls, data: dict, where: str):
    """A dataclass instance from its JSON object: every key a field, every required field given."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected an object for {cls.__name__}, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown} for {cls.__name__}; allowed: {sorted(fields)}")
    hints = _hints(cls)
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = from_plain(hints[name], data[name], f"{where}.{name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"{where}: missing key '{name}' of {cls.__name__}")
    return cls(**kwargs)


class JsonResult:
    """Base of the typed results: ``as_dict``, ``to_json``, ``from_dict`` and ``from_json``.

    Subclasses are dataclasses; their fields are the JSON keys, in order.
    """

    def as_dict(self) -> dict:
        """JSON-ready dict: fields in order, plain values, non-finite floats as None."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.metadata.get(_OMIT):
                continue
            out[f.name] = plain(value)
        return out

    def to_json(self, indent: int = 1) -> str:
        """Strict JSON text (no NaN or Infinity tokens: see the module docstring), ending in a newline."""
        return json.dumps(self.as_dict(), indent=indent, allow_nan=False) + "\n"

    @classmethod
    def from_dict(cls, data: dict, where: str | None = None):
        """The result from its JSON object (as written by :meth:`as_dict`)."""
        return _dataclass(cls, data, where or cls.__name__)

    @classmethod
    def from_json(cls, text: str):
        """The result from its JSON text (as written by :meth:`to_json`)."""
        return cls.from_dict(json.loads(text))
