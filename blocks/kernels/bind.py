"""The loop's kernels for any arm: copies of the laws and block kernels whose model terms are the arm's.

The laws (:mod:`blocks.kernels.laws`), the block kernels (:mod:`blocks.systems`)
and the compiled engine's row groups (:mod:`blocks.compiled.rows`) are written
once, against the names of the model's row kernels (``mass_times``,
``mass_solve``, ``bias_forces``, ``plant_acceleration``, ...; and
``tool_position``, ... for the tool point).  In their own modules those names
are the paper's RRPR kernels (:mod:`blocks.model.rrpr.dynamics_kernels`,
:mod:`blocks.model.rrpr.tool_kernels`).

:func:`bound` gives, for another arm, a copy of such a function (same code
object) whose globals are those of its module with the model names pointing
at the arm's kernel modules; every package function it calls is bound the
same way.  So one source serves every arm, no kernel branches on the type of
its parameters (numba could not compile that), and the compiled engine traces
or compiles the copy as it would the original.  The copies live in real,
importable modules (``blocks.kernels.bound_<arm>__<module>``, registered in
:data:`sys.modules`) because numba's cache and :mod:`blocks.compiled.jit`
find a function's globals through its module's name; those names are unique
per arm, so the compiled engine's structure key and cache key (which name a
kernel by module and qualified name, and hash the source of every callee)
differ between arms.  For the RRPR the originals are returned: the paper's
numbers and generated code do not change.
"""
from __future__ import annotations

import sys
import types

from ..model.rrpr import dynamics_kernels as _rrpr
from ..model.rrpr import tool_kernels as _rrpr_tool

__all__ = ["MODEL_NAMES", "TOOL_NAMES", "bound", "closed_form", "is_rrpr_kernels"]

#: Names of the dynamics row kernels a law may call (see :mod:`blocks.arm`).
MODEL_NAMES = ("inertia_matrix", "mass_times", "mass_solve", "bias_forces", "gravity_forces", "plant_acceleration")
#: Names of the tool-point row kernels.
TOOL_NAMES = ("tool_position", "tool_jacobian", "tool_acceleration_bias")

_bound: dict = {}
# the RRPR's dynamics helpers beyond the interface (inertia_entries, coriolis_forces, arm_constants)
_RRPR_ONLY = {id(v) for k, v in vars(_rrpr).items() if isinstance(v, types.FunctionType) and k not in MODEL_NAMES}


def closed_form(kernels: types.ModuleType, tool_kernels: types.ModuleType | None = None) -> bool:
    """Whether the kernel modules are the paper's RRPR ones (then :func:`bound` returns originals)."""
    return kernels is _rrpr and tool_kernels in (None, _rrpr_tool)


def is_rrpr_kernels(arm) -> bool:
    """Whether ``arm`` computes with the paper's RRPR closed-form kernels (its constants stack per member)."""
    return closed_form(arm.kernels, arm.tool_kernels)


def _modules_of(arm) -> tuple[types.ModuleType, types.ModuleType]:
    if isinstance(arm, tuple):
        return arm
    return arm.kernels, arm.tool_kernels


def _is_package_function(value) -> bool:
    return isinstance(value, types.FunctionType) and (value.__module__ or "").startswith("blocks.")


def _twin(module_name: str, kernels: types.ModuleType, tool_kernels: types.ModuleType) -> types.ModuleType:
    """The importable copy of module ``module_name`` whose model names are the arm's kernels."""
    tag = f"{kernels.__name__}__{tool_kernels.__name__}".replace(".", "_")
    name = f"blocks.kernels.bound_{tag}__{module_name.replace('.', '_')}"
    twin = sys.modules.get(name)
    if twin is not None:
        return twin
    twin = types.ModuleType(name)
    source = vars(sys.modules[module_name])
    twin.__dict__.update({k: v for k, v in source.items() if k not in ("__name__", "__spec__", "__loader__")})
    for key, value in source.items():
        # an RRPR-only dynamics helper is left out of the arm's copy: a law that reached for it would fail by name
        # instead of computing the RRPR's numbers
        if isinstance(value, types.FunctionType) and id(value) in _RRPR_ONLY:
            del twin.__dict__[key]
    for names, mod in ((MODEL_NAMES, kernels), (TOOL_NAMES, tool_kernels)):
        for key in names:
            if hasattr(mod, key):
                twin.__dict__[key] = getattr(mod, key)
    sys.modules[name] = twin
    return twin


def bound(fn, arm):
    """``fn`` for the arm ``arm``: the original for the paper's RRPR, else a copy calling the arm's row kernels.

    Parameters
    ----------
    fn : function
        A law, block kernel or row function of this package written against :data:`MODEL_NAMES` and
        :data:`TOOL_NAMES`.
    arm : blocks.arm.ArmModel or (kernels, tool_kernels)
        The arm, or its two kernel modules.

    Returns
    -------
    function
        Same code, same name and qualified name; module ``blocks.kernels.bound_...`` for another arm.
    """
    kernels, tool_kernels = _modules_of(arm)
    if closed_form(kernels, tool_kernels):
        return fn
    key = (fn, kernels.__name__, tool_kernels.__name__)
    found = _bound.get(key)
    if found is not None:
        return found
    twin = _twin(fn.__module__, kernels, tool_kernels)
    for name in fn.__code__.co_names:
        value = twin.__dict__.get(name)
        arm_own = value is not None and getattr(value, "__module__", None) in (kernels.__name__, tool_kernels.__name__)
        if _is_package_function(value) and not arm_own and not value.__module__.startswith("blocks.kernels.bound_"):
            twin.__dict__[name] = bound(value, (kernels, tool_kernels))
    copy = types.FunctionType(fn.__code__, twin.__dict__, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__, copy.__module__, copy.__doc__ = fn.__qualname__, twin.__name__, fn.__doc__
    copy.__kwdefaults__ = fn.__kwdefaults__
    _bound[key] = copy
    return copy
