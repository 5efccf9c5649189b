"""numba, when installed, and compiled copies of the kernels.

:func:`jit_kernel` compiles a kernel of :mod:`blocks.kernels` (or a block
kernel of :mod:`blocks.diagram.systems`, a path kernel of :mod:`blocks.diagram.trajectory`)
as it is: a copy of the same function object whose global names for other
kernels point at their compiled copies, handed to :func:`numba.njit`.  The
numpy function itself is untouched, so the numpy engines keep calling it.

A law bound to an arm (:class:`~blocks.kernels.model.ArmLaw`: the law with
the arm's kernels as its first argument) compiles as the law, called with
the arm's value, which numba types by the arm's name
(:mod:`blocks.engines.compiled.arm_type`): the arm is a constant of that
specialisation, and its kernels are compiled copies resolved when numba types
``model.mass_times(...)``.
"""
from __future__ import annotations

import importlib
import inspect
import os
import sys
import types

from blocks.kernels.model import ArmLaw

__all__ = ["numba_or_none", "jit_kernel", "compiled_arm", "kernel_sources"]

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
            # numba's type of an arm's kernels, before anything is compiled (a law takes them as a value)
            importlib.import_module("blocks.engines.compiled.arm_type").compile_kernel = jit_kernel
    return _numba


def _is_kernel(value) -> bool:
    """A plain Python function of this package (a kernel or a helper of one), not numpy's, math's or a class."""
    return isinstance(value, types.FunctionType) and (value.__module__ or "").startswith("blocks.")


def _is_arm_law(fn) -> bool:
    return isinstance(fn, ArmLaw)


def _callees(fn) -> list:
    """The package functions ``fn`` names as globals; for a law bound to an arm, the law and the arm's kernels."""
    if _is_arm_law(fn):
        return [fn.law] + fn.model.functions()
    return [fn.__globals__[name] for name in fn.__code__.co_names
            if name in fn.__globals__ and _is_kernel(fn.__globals__[name])]


def _copy_module(name: str, suffix: str = "") -> types.ModuleType:
    """The importable twin of module ``name`` whose kernel names point at compiled copies.

    numba's on-disk cache finds a compiled function's globals by importing its
    module by name, so the copies live in a real module (``dobkit_jit_...``).
    """
    twin_name = "dobkit_jit_" + name.replace(".", "_") + suffix
    twin = sys.modules.get(twin_name)
    if twin is None:
        twin = types.ModuleType(twin_name)
        twin.__dict__.update({k: v for k, v in vars(sys.modules[name]).items() if k not in ("__name__", "__spec__")})
        sys.modules[twin_name] = twin
    return twin


#: Names whose use in a helper means it branches on its arguments' types (``isinstance``, ``x.ndim``): numba's
#: inlining of untyped code cannot prune such a branch, so those helpers stay calls.
_TYPE_BRANCHES = frozenset({"isinstance", "ndim", "shape", "size", "dtype", "len", "type"})


def _inlinable(fn) -> bool:
    """Whether helper ``fn`` and everything it calls can be inlined into a caller (no branch on types)."""
    return not (set(fn.__code__.co_names) & _TYPE_BRANCHES) and all(_inlinable(c) for c in _callees(fn))


def jit_kernel(fn, inline_callees: bool = False):
    """The numba-compiled copy of kernel ``fn`` (memoised; its kernel callees compiled the same way); a kernel
    that carries its own compiled form (``numba_kernel``: a user's function compiled as it stands) gives that.

    With ``inline_callees`` the helpers ``fn`` calls are inlined into it where they branch on no type
    (:func:`_inlinable`): a call between compiled functions passes every argument (a path's 20 numbers) and
    is not inlined by LLVM; the loop's reference kernel is called at every right-hand side and grid point.
    """
    own = getattr(fn, "numba_kernel", None)
    if own is not None:
        return own
    found = _jitted.get((fn, inline_callees))
    if found is not None:
        return found
    numba = numba_or_none()
    if _is_arm_law(fn):
        _jitted[(fn, inline_callees)] = compiled = _jit_arm_law(numba, fn)
        return compiled
    twin = _copy_module(fn.__module__, "_inlined" if inline_callees else "")
    for callee in _callees(fn):
        twin.__dict__[callee.__name__] = _inlined_copy(callee) if inline_callees and _inlinable(callee) else \
            jit_kernel(callee)
    compiled = numba.njit(error_model="numpy")(_copy(fn, twin))
    _jitted[(fn, inline_callees)] = compiled
    return compiled


def _inlined_copy(fn):
    """Helper ``fn`` compiled to be inlined into its callers, with its own helpers inlined (memoised)."""
    found = _jitted.get((fn, "inline"))
    if found is not None:
        return found
    twin = _copy_module(fn.__module__, "_inlined")
    for callee in _callees(fn):
        twin.__dict__[callee.__name__] = _inlined_copy(callee)
    compiled = numba_or_none().njit(error_model="numpy", inline="always")(_copy(fn, twin))
    _jitted[(fn, "inline")] = compiled
    return compiled


def _copy(fn, twin: types.ModuleType):
    """``fn`` as a function of the twin module (its globals the twin's compiled copies)."""
    copy = types.FunctionType(fn.__code__, twin.__dict__, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__, copy.__module__, copy.__doc__ = fn.__qualname__, twin.__name__, fn.__doc__
    return copy


def compiled_arm(model) -> list:
    """The compiled copies of an arm's kernels (:class:`~blocks.kernels.model.ArmKernels`), made now.

    numba resolves ``model.mass_times(...)`` to them when it types a law; a law loaded from numba's cache is not
    typed again, yet its code refers to their module (``dobkit_jit_...``), which must exist before it loads.
    """
    return [jit_kernel(f) for f in model.functions()]


def _jit_arm_law(numba, fn):
    """The compiled law of ``fn`` called with its arm's kernels: ``kernel(*args) = law(model, *args)``, the arm a
    constant of numba's type (:mod:`blocks.engines.compiled.arm_type`)."""
    law, model = jit_kernel(fn.law), fn.model
    compiled_arm(model)

    def kernel(*args):
        return law(model, *args)
    kernel.__qualname__ = fn.__qualname__
    return numba.njit(error_model="numpy")(kernel)


def kernel_sources(functions) -> str:
    """The source text of ``functions`` and every kernel they call, in a fixed order (for cache keys)."""
    seen, stack = {}, list(functions)
    while stack:
        fn = stack.pop()
        key = f"{fn.__module__}.{fn.__qualname__}"
        if key in seen:
            continue
        # a law bound to an arm: the arm's name (in its qualified name) and the sources of the law and kernels
        seen[key] = key if _is_arm_law(fn) else inspect.getsource(fn)
        stack.extend(_callees(fn))
    return "\n".join(seen[k] for k in sorted(seen))
