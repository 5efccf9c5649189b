"""The one key checker of the job files (sweep and tuning definitions): which keys a table allows, what each
value must be, and its default.

::

    KEYS = {None: {"seed": Key(whole(0), "a whole number >= 0", 1)}}
    top = read_table(data, KEYS, None, fail)          # unknown keys and bad values refused, defaults filled in

Messages name the key as the file spells it (``'search.seed'``), the value given and what is allowed; ``fail``
raises the job's own error (:class:`analysis.sweep.spec.SweepError`, :class:`analysis.tune.spec.TuneError`).

A job key that holds a scenario value (a tuning's ``constraints.sensor_noise.q_std`` is a ``noise.q_std``) is
checked by the scenario's own validator (:func:`scenario_value`, through :func:`blocks.scenarios.scenario.check_value`), so
that the two files cannot disagree on what the value may be.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["Key", "read_table", "read_top", "failing", "whole", "number", "numbers", "text", "a_table",
           "scenario_value"]


@dataclass(frozen=True)
class Key:
    """One key of a job file: whether a value is allowed, what is (for the message), and its default."""

    allows: Callable[[Any], bool]
    expected: str
    default: Any = None


def whole(minimum: int) -> Callable[[Any], bool]:
    """A whole number (not true/false) >= ``minimum``."""
    return lambda v: not isinstance(v, bool) and isinstance(v, int) and v >= minimum


def number(v) -> bool:
    """A finite number (not true/false)."""
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def numbers(v, n: int) -> bool:
    """A list of ``n`` finite numbers."""
    return isinstance(v, list) and len(v) == n and all(map(number, v))


def text(v) -> bool:
    return isinstance(v, str)


def a_table(v) -> bool:
    return isinstance(v, dict)


def read_table(table: Mapping, keys: Mapping[str | None, Mapping[str, Key]], section: str | None, fail,
               skip: Callable[[str], bool] = lambda k: False, also: str = "") -> dict:
    """The keys of one table checked against ``keys[section]``, defaults filled in.

    Parameters
    ----------
    table : mapping
        The table as read (``[section]``, or the top level when ``section`` is None).
    keys : dict
        The allowed keys by section.
    fail : callable
        Called with the message; raises.
    skip : callable
        Keys this check leaves to another (a tuning's gain bounds in ``[search]``).
    also : str
        Words appended to the list of allowed keys (what ``skip`` leaves to another).
    """
    allowed = keys[section]
    unknown = sorted(k for k in set(table) - set(allowed) if not skip(k))
    if unknown:
        where = "at the top level" if section is None else f"in [{section}]"
        fail(f"unknown key(s) {[k if section is None else f'{section}.{k}' for k in unknown]}; allowed {where}: "
             f"{', '.join(allowed)}{also}")
    out = {}
    for key, spec in allowed.items():
        value = table.get(key, copy.deepcopy(spec.default))
        if key in table and not spec.allows(value):
            fail(f"'{key if section is None else f'{section}.{key}'}' must be {spec.expected}, got {value!r}")
        out[key] = value
    return out


def scenario_value(scenario_key: str, value, label: str, fail):
    """``value`` checked as a scenario file checks ``scenario_key`` (:func:`blocks.scenarios.scenario.check_value`), the
    message naming the job file's ``label`` for it; returns the value as the model takes it.

    Examples
    --------
    ``scenario_value("noise.q_std", [2e-4] * 4, "constraints.sensor_noise.q_std", fail)``
    """
    from blocks.scenarios.scenario import ScenarioError, check_value
    try:
        return check_value(scenario_key, value)
    except ScenarioError as err:
        message = str(err).replace(f"'{scenario_key}", f"'{label}")
        fail(message + ("" if label in message else f" ('{label}', a scenario's '{scenario_key}')"))


def failing(error: type[Exception], source: str):
    """The ``fail`` of one file: raises ``error`` with the message after the file's name."""
    def fail(message: str):
        raise error(f"{source}: {message}")
    return fail


def read_top(data, keys: Mapping[str | None, Mapping[str, Key]], what: str, fail) -> dict:
    """The top level of a job file (``data``, the parsed TOML) checked as :func:`read_table` checks a table."""
    if not isinstance(data, dict):
        fail(f"a {what} must be a table, got {type(data).__name__}")
    return read_table(data, keys, None, fail)
