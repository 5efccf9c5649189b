"""The exceptions of :mod:`fmu`: one hierarchy under :class:`FMUError` (and the one budget error of the project,
:class:`blocks.engines.budget.BudgetError`, re-exported here).

Every message names what is wrong (the archive entry, the variable, the
platform, the simulation time and status) so that it can be acted on without
a debugger.
"""
from __future__ import annotations

# the project's one budget and its error (blocks.engines.budget), re-exported as fmu.Budget and fmu.BudgetError
from blocks.engines.budget import Budget, BudgetError  # noqa: F401

__all__ = [
    "FMUError", "FMUArchiveError", "FMUModelDescriptionError", "FMUVersionError", "FMUUnsupportedError",
    "FMUPlatformError", "FMUMissingVariablesError", "FMUInstantiationError", "FMUStepError", "FMUBuildError",
    "BudgetError", "CoSimulationError", "FMUStartValueError",
]


class FMUError(ValueError):
    """Something is wrong with an FMU or with a call into one."""


class FMUArchiveError(FMUError):
    """The file is not a zip archive, or an entry is unsafe or too large to extract."""


class FMUModelDescriptionError(FMUError):
    """``modelDescription.xml`` is missing, malformed or lacks what is needed.

    Attributes
    ----------
    problems : list of str
        The individual findings of the schema validation (empty for other errors).
    """

    def __init__(self, message: str, problems=()):
        super().__init__(message)
        self.problems = list(problems)


class FMUVersionError(FMUModelDescriptionError):
    """The FMI version (or the interface type) is not supported."""


class FMUUnsupportedError(FMUModelDescriptionError):
    """The FMU uses an FMI feature that dobkit does not handle (events, arrays, non-real signals, clocks)."""


class FMUStartValueError(FMUError):
    """A start value does not fit the type of its variable (out of range, not whole, not a string, wrong size)."""


class FMUPlatformError(FMUError):
    """The FMU has no binary for this platform."""


class FMUMissingVariablesError(FMUModelDescriptionError):
    """Variables that the caller needs are not in the model description.

    Attributes
    ----------
    missing : list of str
        Names of the missing variables.
    """

    def __init__(self, message: str, missing=()):
        super().__init__(message)
        self.missing = list(missing)


class FMUInstantiationError(FMUError):
    """The FMU refused to instantiate (for example a GUID / instantiationToken mismatch)."""


class FMUStepError(FMUError):
    """The FMU returned an error status while simulating.

    Attributes
    ----------
    time : float
        Simulation time (s) at which the failing call was made.
    status : str
        The FMI status returned (``"error"``, ``"fatal"``, ...).
    function : str
        The FMI function that failed.
    messages : list of str
        The FMU's own log lines from the failing call (``"[status] text"``).
    """

    def __init__(self, message: str, time: float, status: str, function: str, messages=()):
        super().__init__(message)
        self.time = time
        self.status = status
        self.function = function
        self.messages = list(messages)


class FMUBuildError(FMUError):
    """Exporting an FMU failed: no C compiler, or the compiler rejected the sources."""


class CoSimulationError(FMUError):
    """The co-simulation could not run: bad step, diverging signals, sides whose signals do not match."""
