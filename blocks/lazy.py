"""Public names of a package imported on first use (PEP 562), written once for ``blocks``, ``analysis`` and ``fmu``.

A package lists each public name under the module that defines it; importing the package then loads none of
them, so that ``dobkit --version`` and a scenario error come before python-control, scipy or fmpy are imported.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module
from importlib.util import find_spec

__all__ = ["lazy_exports"]


def lazy_exports(package: str, where: Mapping[str, tuple], namespace: dict) -> tuple[Callable, Callable]:
    """``__getattr__`` and ``__dir__`` for the package ``package`` whose public names are listed in ``where``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    where : mapping of str to tuple of str
        Module (relative to the package) -> the public names it defines.
    namespace : dict
        The package's ``globals()``: a name imported once is stored there, so later look-ups are plain reads.
    """
    module_of = {name: module for module, names in where.items() for name in names}

    def __getattr__(name: str):
        module = module_of.get(name)
        if module is None:
            if not name.startswith("_") and find_spec(f"{package}.{name}") is not None:
                return import_module(f".{name}", package)          # a submodule, as ``blocks.figure2.metrics``
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f".{module}", package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(module_of))

    return __getattr__, __dir__
