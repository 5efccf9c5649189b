"""FMU export of the plant, FMU import as python-control blocks, and co-simulation.

::

    import blocks
    import fmu
    path = fmu.export_plant("plant.fmu", fmi_version=2)     # C model compiled with the system compiler
    plant = fmu.load(path)                                   # Model Exchange FMU -> NonlinearIOSystem
    loop = blocks.closed_loop("paper", plant=plant)          # drop-in for the Python plant
    resp = fmu.cosimulate(path, "paper", step=1e-3)          # Co-Simulation against the Python controller side
    report = fmu.check_fmu(path)                             # fmpy validation + comparison with the Python plant
    study = fmu.cosim_convergence(path, "paper")             # co-simulation error vs h, fitted order

Bad FMUs raise a subclass of :class:`FMUError` (a ``ValueError``) naming what
is wrong; archives are checked before anything is extracted, into a private
temporary folder that is removed afterwards.

Modules, one job each: ``archive`` (safe extraction), ``description`` (model
description checks, supported subset), ``logger`` (FMU log messages to the
right instance), ``instance`` (one native instance), ``block`` (``load``: ME FMU as a
block), ``master`` (fixed-step co-simulation), ``scenario_values`` (scenario
-> FMU start values), ``cosim`` (a scenario against a plant FMU),
``convergence`` (co-simulation error versus step size), ``check``,
``export`` / ``variables`` / ``modeldescription`` / ``build`` / ``package``
(the plant FMU), ``cli`` (``dobkit fmu ...``), ``c/`` (the plant's C code).
"""
from __future__ import annotations

import importlib

# Public name -> defining module.  Imported on first use (PEP 562), so that
# ``import fmu`` stays cheap: the heavy parts (python-control, SciPy)
# load only when a function that needs them is used.
_EXPORTS = {
    "ExtractedFMU": "archive", "ExtractionLimits": "archive", "extract_fmu": "archive",
    "check_fmu": "check",
    "controller_side": "cosim", "cosimulate": "cosim",
    "cosim_convergence": "convergence",
    "require_variables": "description",
    "FMUArchiveError": "errors", "FMUBuildError": "errors", "FMUError": "errors",
    "FMUInstantiationError": "errors", "FMUMissingVariablesError": "errors", "FMUModelDescriptionError": "errors",
    "FMUPlatformError": "errors", "FMUStepError": "errors", "FMUUnsupportedError": "errors",
    "FMUVersionError": "errors",
    "MODEL_IDENTIFIER": "export", "export_plant": "export",
    "FMUInstance": "instance",
    "load": "block",
    "CoSimulationError": "master", "cosimulate_system": "master",
}

__all__ = [
    "export_plant", "load", "cosimulate", "cosimulate_system", "controller_side", "check_fmu", "extract_fmu",
    "cosim_convergence", "require_variables", "FMUInstance", "ExtractedFMU", "ExtractionLimits", "MODEL_IDENTIFIER",
    "FMUError", "FMUArchiveError", "FMUModelDescriptionError", "FMUVersionError", "FMUUnsupportedError",
    "FMUPlatformError", "FMUMissingVariablesError", "FMUInstantiationError", "FMUStepError", "FMUBuildError",
    "CoSimulationError",
]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
