"""An arm's row kernels as one value, passed to the laws (as pinocchio passes ``model, data``).

The laws (:mod:`blocks.kernels.laws`, :mod:`blocks.kernels.disturbance`),
the block kernels (:mod:`blocks.diagram.systems`, :mod:`blocks.diagram.digital`) and the
compiled engine's row groups (:mod:`blocks.engines.compiled.rows`) are written once
and take the arm's kernels as their first argument ``model``, an
:class:`ArmKernels`: ``model.mass_times(k, q, v)``,
``model.tool_position(kin, q)``, ...  One law serves every arm; which arm it
computes is the value it is called with, never the module it lives in.

How each engine gets the value
------------------------------
* The numpy engines call the block kernel :func:`with_arm` made: the law
  with the arm's value as its first argument (a :class:`functools.partial`).
* The compiled engine's trace runs that same callable on symbols: the arm's
  value passes through untouched (it is no parameter, so no number of it
  becomes a symbol) and the generated code is the kernels' straight-line
  statements, as before.  The callable's qualified name carries the arm's
  :attr:`ArmKernels.name`, so the structure and cache keys of two arms differ.
* A kernel numba compiles as it stands (:func:`blocks.engines.compiled.jit.jit_kernel`,
  where a trace fails) gets the value as an argument of a numba type keyed
  by the arm's :attr:`ArmKernels.name` (:mod:`blocks.engines.compiled.arm_type`):
  ``model.mass_times(...)`` resolves, when numba types the law, to the
  compiled copy of that arm's kernel.  The type is a name, so numba's
  on-disk cache keeps working, and two arms are two specialisations.
"""
from __future__ import annotations

import functools
import importlib
import types

__all__ = ["MODEL_NAMES", "TOOL_NAMES", "ArmKernels", "ArmLaw", "arm_kernels", "with_arm", "by_name"]

#: Names of the dynamics row kernels a law may call (see :mod:`blocks.model.arm`).
MODEL_NAMES = ("inertia_matrix", "mass_times", "mass_solve", "bias_forces", "gravity_forces", "plant_acceleration")
#: Names of the tool-point row kernels.
TOOL_NAMES = ("tool_position", "tool_jacobian", "tool_acceleration_bias")

_by_modules: dict = {}          # (id(kernels), id(tool_kernels)) -> ArmKernels (which keeps both alive)
_by_name: dict = {}             # ArmKernels.name -> ArmKernels


class ArmKernels:
    """An arm's row kernels: the functions of :data:`MODEL_NAMES` and :data:`TOOL_NAMES` as attributes.

    Parameters
    ----------
    kernels : module or object
        The dynamics row kernels (``arm.kernels``).
    tool_kernels : module or object
        The tool-point row kernels (``arm.tool_kernels``).

    Attributes
    ----------
    name : str
        ``"<kernels module>+<tool kernels module>"`` (``#2``, ... added for other modules of the same names):
        what the compiled code is specialised on (the structure keys, the cache keys and numba's type of the
        value carry it); one value per name in a process.
    kernels, tool_kernels
        The two modules it was made from.

    A kernel the modules lack is absent: a law that calls it fails by name.
    Make one with :func:`arm_kernels` (one value per pair of modules).
    """

    def __init__(self, kernels, tool_kernels) -> None:
        self.kernels, self.tool_kernels = kernels, tool_kernels
        self.name = f"{_module_name(kernels)}+{_module_name(tool_kernels)}"
        for names, source in ((MODEL_NAMES, kernels), (TOOL_NAMES, tool_kernels)):
            for key in names:
                if hasattr(source, key):
                    setattr(self, key, getattr(source, key))

    def functions(self) -> list:
        """The kernels it holds that are plain Python functions, in the order of the names."""
        return [f for f in (getattr(self, n, None) for n in MODEL_NAMES + TOOL_NAMES)
                if isinstance(f, types.FunctionType)]

    def __repr__(self) -> str:
        return f"ArmKernels({self.name})"

    def __reduce__(self):
        # another process rebuilds the value from its modules' names (same name, same functions)
        if not all(isinstance(m, types.ModuleType) for m in (self.kernels, self.tool_kernels)):
            raise TypeError(f"{self!r} is made of objects that are not modules and cannot be sent to another process")
        return _from_modules, (self.kernels.__name__, self.tool_kernels.__name__)


def _module_name(source) -> str:
    return getattr(source, "__name__", None) or type(source).__qualname__


def _from_modules(kernels: str, tool_kernels: str) -> ArmKernels:
    return arm_kernels((importlib.import_module(kernels), importlib.import_module(tool_kernels)))


def arm_kernels(arm) -> ArmKernels:
    """The :class:`ArmKernels` of an arm (an :class:`~blocks.model.arm.ArmModel`) or of its two kernel modules
    ``(kernels, tool_kernels)``; the same object for the same modules."""
    kernels, tool_kernels = arm if isinstance(arm, tuple) else (arm.kernels, arm.tool_kernels)
    key = (id(kernels), id(tool_kernels))
    found = _by_modules.get(key)
    if found is None:
        found = ArmKernels(kernels, tool_kernels)
        # the compiled code is keyed by the name: other modules of the same names (a module made again in a
        # notebook) get a name of their own
        base, i = found.name, 1
        while found.name in _by_name:
            i += 1
            found.name = f"{base}#{i}"
        _by_modules[key] = _by_name[found.name] = found
    return found


def by_name(name: str) -> ArmKernels:
    """The :class:`ArmKernels` made in this process under ``name`` (numba's type of the value carries the name)."""
    found = _by_name.get(name)
    if found is None:
        raise KeyError(f"no arm kernels named {name!r} in this process")
    return found


class ArmLaw(functools.partial):
    """A law or block kernel with an arm's :class:`ArmKernels` as its first argument: ``law(model, *args)``.

    ``__module__`` and ``__name__`` are the law's; ``__qualname__`` adds the arm's name (``law[name]``), so the
    compiled engine's structure keys, which name a kernel by module and qualified name, differ between arms.
    Make one with :func:`with_arm`.
    """

    @property
    def law(self):
        """The law itself (a plain function of ``model`` first)."""
        return self.func

    @property
    def model(self) -> ArmKernels:
        """The arm's kernels it passes."""
        return self.args[0]


_laws: dict = {}


def with_arm(fn, arm) -> ArmLaw:
    """``fn`` with the arm's kernels as its first argument (memoised: the same object for the same law and arm).

    Parameters
    ----------
    fn : function
        A law, block kernel or row function taking ``model`` first.
    arm : blocks.model.arm.ArmModel, ArmKernels or (kernels, tool_kernels)
    """
    model = arm if isinstance(arm, ArmKernels) else arm_kernels(arm)
    key = (fn, model.name)
    found = _laws.get(key)
    if found is None:
        found = ArmLaw(fn, model)
        found.__module__, found.__name__, found.__doc__ = fn.__module__, fn.__name__, fn.__doc__
        found.__qualname__ = f"{fn.__qualname__}[{model.name}]"
        _laws[key] = found
    return found


