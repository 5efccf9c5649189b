"""numba's type of an arm's kernels (:class:`~blocks.kernels.model.ArmKernels`): a name, resolved when typing.

A law that numba compiles as it stands takes the arm's kernels as its first
argument and calls ``model.mass_times(k, q, v)``.  numba cannot take a
Python object as an argument; it can take a value of a type it is told of.
:class:`ArmKernelsType` is such a type, keyed by the arm's
:attr:`~blocks.kernels.model.ArmKernels.name` and carrying no data: each
kernel name is a method of it (:func:`numba.extending.overload_method`)
whose implementation, chosen when numba types the call, is the compiled copy
of that arm's kernel (:func:`blocks.engines.compiled.jit.jit_kernel`).  So the arm
is a compile-time constant of the law's specialisation: no call through a
pointer, two arms are two specialisations, and numba's on-disk cache, which
keys a compiled function by its argument types, finds it again in another
process (the type pickles as its name; numba's first-class function types do
not: a dispatcher's identity is part of them, numba issues #6264, #2956).

Imported by :func:`blocks.engines.compiled.jit.numba_or_none` once numba is loaded.
"""
from __future__ import annotations

from numba import types
from numba.core.imputils import lower_constant
from numba.extending import (
    NativeValue,
    models,
    overload_method,
    register_model,
    typeof_impl,
    unbox,
)

from blocks.kernels.model import MODEL_NAMES, TOOL_NAMES, ArmKernels, by_name

__all__ = ["ArmKernelsType"]


class ArmKernelsType(types.Dummy):
    """The numba type of one arm's kernels: its name, nothing at run time."""

    def __init__(self, arm_name: str) -> None:
        self.arm_name = arm_name
        super().__init__(name=f"ArmKernels({arm_name})")

    @property
    def key(self):
        return self.arm_name

    def __reduce__(self):
        return ArmKernelsType, (self.arm_name,)


register_model(ArmKernelsType)(models.OpaqueModel)


@typeof_impl.register(ArmKernels)
def _typeof(value, context):
    return ArmKernelsType(value.name)


@unbox(ArmKernelsType)
def _unbox(typ, obj, c):
    return NativeValue(c.context.get_dummy_value())


@lower_constant(ArmKernelsType)
def _constant(context, builder, typ, value):
    return context.get_dummy_value()


#: How a kernel becomes its compiled copy: set by :mod:`blocks.engines.compiled.jit` when it loads this module
#: (``jit_kernel``), so that this module needs nothing of it.
compile_kernel = None


def _kernel_method(name: str) -> None:
    @overload_method(ArmKernelsType, name)
    def _method(model, *args):
        kernel = getattr(by_name(model.arm_name), name, None)
        if kernel is None:
            return None
        compiled = compile_kernel(kernel)

        def impl(model, *args):
            return compiled(*args)
        return impl


for _name in MODEL_NAMES + TOOL_NAMES:
    _kernel_method(_name)
