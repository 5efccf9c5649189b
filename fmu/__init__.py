"""FMU export of the plant, FMU import as python-control blocks, and co-simulation.

::

    import blocks
    import fmu

    path = fmu.export_plant("plant.fmu", fmi_version=2)     # C model compiled with the system compiler
    ctrl = fmu.export_controller("ctrl.fmu", "paper-digital")  # the sampled controller as a Co-Simulation FMU
    plant = fmu.load(path)                                   # Model Exchange FMU -> NonlinearIOSystem
    loop = blocks.closed_loop("paper", plant=plant)          # drop-in for the Python plant
    resp = fmu.cosimulate(path, "paper", step=1e-3)          # Co-Simulation against the Python controller side
    report = fmu.check_fmu(path)                             # validate, load, run; plant vs Python plant
    study = fmu.cosim_convergence(path, "paper")             # co-simulation error vs h, fitted order
    resp = fmu.simulate_fmu("BouncingBall.fmu", 2.0, 0.01)   # any ME FMU alone: state/time events, FMI 3 arrays
    resp = fmu.simulate_loop(loop_with_event_fmus, t_grid)   # FMU blocks with events in a loop (numpy engine)

Bad FMUs raise a subclass of :class:`FMUError` (a ``ValueError``) naming what
is wrong; archives are checked before anything is extracted, into a private
temporary folder that is removed afterwards (and, should the process die
inside FMU code, at the next start).  Loading or checking an FMU runs its
native code in this process (a shared library's constructor runs on load):
check an untrusted FMU in a sandbox.

Modules, one job each: ``archive`` (safe extraction), ``description`` (model
description checks, supported subset), ``logger`` (FMU log messages to the
right instance), ``instance`` (one native instance), ``block`` (``load``: ME FMU as a
block), ``coupling`` (what crosses between the sides within a step),
``master`` (fixed-step co-simulation), ``simulate`` (a Model Exchange FMU
on its own, with events and arrays), ``events`` (the event iteration; FMU blocks
with events in a loop of the numpy engine, ``simulate_loop``), ``start_values`` (start values checked by type),
``scenario_values`` (scenario -> FMU start values), ``cosim`` (a
scenario against a plant FMU), ``convergence`` (co-simulation error versus
step size), ``check`` and ``plant_check``,
``export`` / ``variables`` / ``modeldescription`` / ``build`` / ``package``
(the plant FMU), ``end_stops`` (its joint ranges' stops), ``arm_record`` (the arm recorded in it),
``controller_export`` / ``controller_variables`` / ``controller_tick`` (the controller FMU),
``c/`` (the FMI layers and the C the kernels' trace does not write).
The command line (``dobkit fmu ...``) lives in :mod:`dobkit.fmu_commands`.
"""
from blocks.lazy import lazy_exports

# Each public name and its module, imported on first use (PEP 562): ``import fmu.errors`` or the command
# line's parser do not load fmpy, python-control or scipy.
_WHERE = {
    "archive": ("ExtractedFMU", "ExtractionLimits", "extract_fmu"),
    "block": ("FMUBlock", "load"),
    "check": ("check_fmu",),
    "convergence": ("cosim_convergence",),
    "controller_export": ("export_controller",),
    "cosim": ("controller_side", "cosimulate"),
    "description": ("require_variables",),
    "errors": ("Budget", "BudgetError", "CoSimulationError", "FMUArchiveError", "FMUBuildError", "FMUError",
               "FMUInstantiationError", "FMUMissingVariablesError", "FMUModelDescriptionError", "FMUPlatformError",
               "FMUStartValueError", "FMUStepError", "FMUUnsupportedError", "FMUVersionError"),
    "export": ("MODEL_IDENTIFIER", "export_plant"),
    "instance": ("FMUInstance",),
    "master": ("cosimulate_system",),
    "simulate": ("simulate_fmu",),
    "events": ("simulate_loop",),
}
__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals())


__all__ = [
    "export_plant", "load", "FMUBlock", "cosimulate", "cosimulate_system", "controller_side", "check_fmu",
    "extract_fmu", "cosim_convergence", "require_variables", "FMUInstance", "ExtractedFMU", "ExtractionLimits",
    "MODEL_IDENTIFIER", "FMUError", "FMUArchiveError", "FMUModelDescriptionError", "FMUVersionError",
    "FMUUnsupportedError", "FMUPlatformError", "FMUMissingVariablesError", "FMUInstantiationError", "FMUStepError",
    "FMUBuildError", "CoSimulationError", "Budget", "BudgetError", "simulate_fmu", "FMUStartValueError",
    "simulate_loop",
]
