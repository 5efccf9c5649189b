"""numba, when installed, and compiled copies of the kernels.

:func:`jit_kernel` compiles a kernel of :mod:`blocks.kernels` (or a block
kernel of :mod:`blocks.systems`, a path kernel of :mod:`blocks.trajectory`)
as it is: a copy of the same function object whose global names for other
kernels point at their compiled copies, handed to :func:`numba.njit`.  The
numpy function itself is untouched, so the numpy engines keep calling it.
"""
from __future__ import annotations

import importlib
import inspect
import os
import sys
import types

__all__ = ["numba_or_none", "jit_kernel", "kernel_sources"]

_UNSET = object()
_numba = _UNSET
_jitted: dict = {}


def numba_or_none():
    """The numba module, or None when it cannot be imported (it is the optional extra ``dobkit[fast]``)."""
    global _numba
    if _numba is _UNSET:
        try:
            _numba = importlib.import_module("numba")
        except (ImportError, OSError):      # not installed, or its LLVM library cannot load (a memory limit)
            _numba = None
        else:
            # The batch runs members on numba's threads, and sweeps and studies fork worker processes
            # afterwards: GNU OpenMP's threads do not survive a fork, numba's own work queue does.
            if "NUMBA_THREADING_LAYER" not in os.environ:
                _numba.config.THREADING_LAYER = "workqueue"
    return _numba


def _is_kernel(value) -> bool:
    """A plain Python function of this package (a kernel or a helper of one), not numpy's, math's or a class."""
    return isinstance(value, types.FunctionType) and (value.__module__ or "").startswith("blocks.")


def _callees(fn) -> list:
    """The package functions ``fn`` names as globals."""
    return [fn.__globals__[name] for name in fn.__code__.co_names
            if name in fn.__globals__ and _is_kernel(fn.__globals__[name])]


def _copy_module(name: str) -> types.ModuleType:
    """The importable twin of module ``name`` whose kernel names point at compiled copies.

    numba's on-disk cache finds a compiled function's globals by importing its
    module by name, so the copies live in a real module (``dobkit_jit_...``).
    """
    twin_name = "dobkit_jit_" + name.replace(".", "_")
    twin = sys.modules.get(twin_name)
    if twin is None:
        twin = types.ModuleType(twin_name)
        twin.__dict__.update({k: v for k, v in vars(sys.modules[name]).items() if k not in ("__name__", "__spec__")})
        sys.modules[twin_name] = twin
    return twin


def jit_kernel(fn):
    """The numba-compiled copy of kernel ``fn`` (memoised; its kernel callees compiled the same way); a kernel
    that carries its own compiled form (``numba_kernel``: a user's function compiled as it stands) gives that."""
    own = getattr(fn, "numba_kernel", None)
    if own is not None:
        return own
    found = _jitted.get(fn)
    if found is not None:
        return found
    numba = numba_or_none()
    twin = _copy_module(fn.__module__)
    for callee in _callees(fn):
        twin.__dict__[callee.__name__] = jit_kernel(callee)
    copy = types.FunctionType(fn.__code__, twin.__dict__, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__, copy.__module__, copy.__doc__ = fn.__qualname__, twin.__name__, fn.__doc__
    compiled = numba.njit(error_model="numpy")(copy)
    _jitted[fn] = compiled
    return compiled


def kernel_sources(functions) -> str:
    """The source text of ``functions`` and every kernel they call, in a fixed order (for cache keys)."""
    seen, stack = {}, list(functions)
    while stack:
        fn = stack.pop()
        key = f"{fn.__module__}.{fn.__qualname__}"
        if key in seen:
            continue
        seen[key] = inspect.getsource(fn)
        stack.extend(_callees(fn))
    return "\n".join(seen[k] for k in sorted(seen))
