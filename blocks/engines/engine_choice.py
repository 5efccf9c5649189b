"""Which engine runs a loop: the request (``"auto"``, ``"compiled"``, ``"fast"``, ``"python-control"``) and why.

Written once for the continuous loop (:func:`blocks.figure2.loop.simulate`), the sampled loop
(:func:`blocks.figure2.digital_loop.simulate_sampled`) and the batch (:func:`blocks.figure2.batch.simulate_batch`); it imports
none of them, so that the engines can ask for it without importing each other.
"""
from __future__ import annotations

import warnings

__all__ = ["ENGINES", "EngineFallbackWarning", "select_engine"]

#: Engines of :func:`blocks.figure2.loop.simulate`.
ENGINES = ("auto", "compiled", "fast", "python-control")


class EngineFallbackWarning(UserWarning):
    """``engine="auto"`` runs the numpy engine because the compiled one cannot run this loop (the message says why)."""


_fallbacks_reported: set[str] = set()


def select_engine(engine: str, reason: str | None) -> str:
    """The engine to run for a requested ``engine``, given why the compiled one cannot run (None: it can).

    ``"auto"`` becomes ``"compiled"`` or ``"fast"``; a fallback is reported
    once per reason and process (:class:`EngineFallbackWarning`).

    Raises
    ------
    ValueError
        If ``engine`` is not one of :data:`ENGINES`.
    blocks.engines.compiled.CompiledUnavailable
        If ``engine="compiled"`` and ``reason`` is not None; the message is the reason.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    if engine == "compiled" and reason is not None:
        from blocks.engines.compiled import CompiledUnavailable
        raise CompiledUnavailable(f"engine='compiled' cannot run: {reason}")
    if engine != "auto":
        return engine
    if reason is None:
        return "compiled"
    if reason not in _fallbacks_reported:
        _fallbacks_reported.add(reason)
        warnings.warn(f"engine='auto' uses the numpy engine: {reason}", EngineFallbackWarning, stacklevel=3)
    return "fast"
