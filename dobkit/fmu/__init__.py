"""FMU export of the plant, FMU import as python-control blocks, and co-simulation.

::

    from dobkit import blocks, fmu
    path = fmu.export_plant("plant.fmu", fmi_version=2)     # C model compiled with the system compiler
    plant = fmu.load(path)                                   # Model Exchange FMU -> NonlinearIOSystem
    loop = blocks.closed_loop("paper", plant=plant)          # drop-in for the Python plant
    resp = fmu.cosimulate(path, "paper", step=1e-3)          # Co-Simulation against the Python controller side
    report = fmu.check_fmu(path)                             # fmpy validation + comparison with the Python plant

Bad FMUs raise a subclass of :class:`FMUError` (a ``ValueError``) naming what
is wrong; archives are checked before anything is extracted, into a private
temporary folder that is removed afterwards.
"""
from .archive import ExtractedFMU, ExtractionLimits, extract_fmu
from .check import check_fmu
from .cosim import controller_side, cosimulate
from .description import require_variables
from .errors import (FMUArchiveError, FMUBuildError, FMUError, FMUInstantiationError, FMUMissingVariablesError,
                     FMUModelDescriptionError, FMUPlatformError, FMUStepError, FMUVersionError)
from .export import MODEL_IDENTIFIER, export_plant
from .instance import FMUInstance
from .load import load
from .master import CoSimulationError, cosimulate_system

__all__ = [
    "export_plant", "load", "cosimulate", "cosimulate_system", "controller_side", "check_fmu", "extract_fmu",
    "require_variables", "FMUInstance", "ExtractedFMU", "ExtractionLimits", "MODEL_IDENTIFIER",
    "FMUError", "FMUArchiveError", "FMUModelDescriptionError", "FMUVersionError", "FMUPlatformError",
    "FMUMissingVariablesError", "FMUInstantiationError", "FMUStepError", "FMUBuildError", "CoSimulationError",
]
