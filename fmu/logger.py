"""Deliver each FMU log message to the instance that logged it.

FMI 2 hands the FMU one ``logger`` function pointer plus an opaque
``componentEnvironment`` that the FMU passes back with every message.
fmpy's native proxy (:func:`fmpy.logging.addLoggerProxy`) formats the
printf-style message, but it forwards to a *single process-wide* Python
callback: registering one callback per instance means the last instance
loaded receives everybody's messages, and once that instance's callback is
garbage collected the next message from any FMU calls freed memory and
crashes the process.

So there is exactly one Python logger, :data:`_PY_LOGGER`, created at import
and never freed.  Every FMI 2 instance gets a callbacks structure with the
proxy in front of that logger and its own integer key as
``componentEnvironment``.  The logger looks the key up in a registry of weak
references to :class:`MessageLog` objects, so the registry never keeps an
instance alive, and a message for an instance already gone is dropped rather
than delivered to freed memory.  FMUs that do not pass the environment back
are matched by instance name when that name is unique; messages that match
nothing (for example from fmpy's own default callbacks) are printed as fmpy
would.

FMI 3 needs none of this: its ``logMessage`` callback is per instance and
fmpy keeps it alive on the FMU object.

Other code that calls ``addLoggerProxy`` with a short-lived logger of its own
(e.g. ``fmpy.simulate_fmu(..., logger=f)``) replaces the proxy's target for
the whole process; dobkit re-asserts its own (permanent) logger at every FMI 2
instantiation, which is idempotent.
"""
from __future__ import annotations

import ctypes
import itertools
import threading
import weakref

__all__ = ["MessageLog", "register", "unregister", "fmi2_callbacks", "fmi3_log_function", "status_name",
           "STATUS_NAMES"]

STATUS_NAMES = ("ok", "warning", "discard", "error", "fatal", "pending")


def status_name(status: int) -> str:
    """``"ok"``, ``"warning"``, ... for an FMI status code."""
    return STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else f"illegal status {status}"


def _text(value) -> str:
    if value is None:
        return ""
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


class MessageLog:
    """The log messages of one FMU instance: the most recent ``limit`` of them and a running count.

    Attributes
    ----------
    entries : list of str
        ``"[status] message"``, most recent last (the oldest are dropped beyond ``limit``).
    count : int
        Number of messages received so far (dropped ones included).
    """

    __slots__ = ("entries", "count", "limit", "__weakref__")

    def __init__(self, limit: int = 200):
        self.entries: list[str] = []
        self.count = 0
        self.limit = limit

    def add(self, status: int, message) -> None:
        """Record one message."""
        self.entries.append(f"[{status_name(status)}] {_text(message)}")
        del self.entries[:-self.limit]
        self.count += 1

    def since(self, mark: int) -> list[str]:
        """The messages received after ``count`` was ``mark`` (those still kept)."""
        new = self.count - mark
        return self.entries[len(self.entries) - min(new, len(self.entries)):] if new > 0 else []


_LOCK = threading.Lock()
_KEYS = itertools.count(1)
_REGISTRY: dict[int, tuple[weakref.ref, str]] = {}


def register(log: MessageLog, instance_name: str) -> int:
    """Register a log; returns the key to pass as ``componentEnvironment``."""
    with _LOCK:
        key = next(_KEYS)
        _REGISTRY[key] = (weakref.ref(log), instance_name)
    return key


def unregister(key: int) -> None:
    """Forget a key (idempotent); later messages with it are printed instead."""
    with _LOCK:
        _REGISTRY.pop(key, None)


def _find(env, instance_name) -> MessageLog | None:
    entry = _REGISTRY.get(env) if env is not None else None
    if entry is None:
        # an FMU that does not hand the environment back: match a unique instance name
        name = _text(instance_name)
        matches = [ref for ref, n in list(_REGISTRY.values()) if n == name]
        entry = (matches[0], name) if len(matches) == 1 else None
    return entry[0]() if entry is not None else None


def _route(env, instance_name, status, category, message) -> None:
    try:
        log = _find(env, instance_name)
        if log is not None:
            log.add(status, message)
        else:
            from fmpy.fmi2 import printLogMessage
            printLogMessage(env, instance_name, status, category, message)
    except Exception:  # noqa: BLE001 - an exception cannot cross back into C
        pass


def _make_logger():
    from fmpy.fmi2 import fmi2CallbackLoggerTYPE
    return fmi2CallbackLoggerTYPE(_route)


# Created once, referenced from this module for the life of the process: never freed under an FMU.
_PY_LOGGER = _make_logger()


def _proxied(callbacks) -> bool:
    """Put fmpy's formatting proxy in front of :data:`_PY_LOGGER` (False if fmpy has no proxy here)."""
    try:
        from fmpy.logging import addLoggerProxy
    except Exception:  # noqa: BLE001 - the native helper is missing on some platforms
        return False
    addLoggerProxy(ctypes.byref(callbacks))
    return True


def fmi2_callbacks(key: int):
    """An ``fmi2CallbackFunctions`` for one instance: the shared logger, fmpy's memory functions, ``key``.

    The structure must be kept alive as long as the instance (fmpy's FMU object stores it).
    Messages with printf arguments are formatted when fmpy's native proxy is
    available, else delivered with the format unexpanded.
    """
    from fmpy.fmi2 import defaultCallbacks, fmi2CallbackFunctions
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _PY_LOGGER
    callbacks.allocateMemory = defaultCallbacks.allocateMemory
    callbacks.freeMemory = defaultCallbacks.freeMemory
    callbacks.componentEnvironment = key
    _proxied(callbacks)  # sets the proxy's one target to _PY_LOGGER again: idempotent
    return callbacks


def fmi3_log_function(log: MessageLog):
    """The Python ``logMessage`` for an FMI 3 instance (fmpy wraps and keeps it per instance)."""

    def log_message(env, status, category, message) -> None:
        try:
            log.add(status, message)
        except Exception:  # noqa: BLE001
            pass

    return log_message
