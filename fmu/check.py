"""Check an FMU: does it validate, load, run -- and, for the dobkit plant, match the Python plant?

:func:`check_fmu` answers what a user needs to know before using an FMU
with dobkit, in a JSON-ready report:

* ``validation``: fmpy's static checks (:func:`fmpy.validation.validate_fmu`:
  schema, names, model structure, start values, units).  Findings of the
  variable-naming convention (``der(der(x))`` is outside the grammar of the
  structured convention, yet common and harmless) are *warnings*; the rest
  are errors.
* ``model_exchange``: whether the FMU loads as a block with :func:`fmu.load`
  -- and if not, the named reason ``load`` gives (state events, arrays,
  non-real signals, ...) -- and a short run with the inputs held at their
  start values (SciPy LSODA): every output must stay finite.
* ``co_simulation``: whether its Co-Simulation part runs a short simulation
  (the inputs at their start values, 100 recorded points) with finite
  outputs, and whether the co-simulation master can couple it (the same
  named reasons).
* ``me_vs_cs``: where it offers both, the two runs compared output by output.
* ``plant_comparison``: for the dobkit plant FMU only, Model Exchange and
  Co-Simulation against the native Python plant (:mod:`fmu.plant_check`).

``passed`` is true when the validation has no error, the FMU offers Model
Exchange or Co-Simulation (else ``unusable`` says what it offers), and every
part that it offers works with dobkit.  A NaN anywhere fails the part it is in.  A
model description that fails the schema validation is reported (its
problems listed, nothing run) rather than raised; a missing or malformed one,
or an unsupported FMI version, raises.  Sizes are checked against a
:class:`~fmu.budget.Budget` before anything runs.  The archive is extracted
once.  Checking runs the FMU's native code in this process: check an
untrusted FMU in a sandbox.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from blocks.control_compat import fast_dynamics, fast_output

from .archive import ExtractionLimits, extract_fmu
from .block import load
from .budget import DEFAULT_BUDGET, Budget, Deadline, counted
from .description import described, offered_interfaces, read_description, real_variables, unsupported_features
from .errors import BudgetError, FMUError, FMUModelDescriptionError
from .instance import FMUInstance
from .plant_check import (
    CHECK_INITIAL_STATE,
    check_torque,
    compare_co_simulation,
    compare_model_exchange,
    plant_from_description,
    worst,
)

__all__ = ["check_fmu", "check_torque", "plant_from_description", "CHECK_INITIAL_STATE", "NAMING_FINDING"]

# how fmpy words a finding of the variable-naming convention check
NAMING_FINDING = "is not a legal variable name for naming convention"
_POINTS = 100       # recorded intervals of the short runs


def _validation(extracted) -> dict:
    from fmpy.validation import validate_fmu
    problems = [str(p) for p in validate_fmu(str(extracted.root))]
    warnings = [p for p in problems if NAMING_FINDING in p]
    errors = [p for p in problems if NAMING_FINDING not in p]
    return {"problems": problems, "errors": errors, "warnings": warnings, "passed": not errors}


def _start_inputs(md, names: list[str]) -> np.ndarray:
    starts = {v.name: v.start for v in md.modelVariables}
    values = []
    for name in names:
        try:
            values.append(float(starts.get(name)) if starts.get(name) is not None else 0.0)
        except (TypeError, ValueError):
            values.append(0.0)
    return np.array(values)


def _grid(t_final: float, step: float) -> tuple[int, int, float]:
    """(steps, record_every, step): a whole number of steps, recorded at ``_POINTS + 1`` instants."""
    every = max(1, math.ceil(t_final / (_POINTS * step)))
    return _POINTS * every, every, t_final / (_POINTS * every)


def _model_exchange(extracted, md, t_final: float, budget: Budget, deadline: Deadline) -> tuple[dict, dict | None]:
    """The Model Exchange part and, when it ran, its outputs by name on the check's grid."""
    if md.modelExchange is None:
        return {"offered": False, "skipped": "the FMU does not offer Model Exchange (it offers: "
                f"{', '.join(offered_interfaces(md)) or 'no interface'})", "passed": True}, None
    try:
        block = load(extracted, name="checked")
    except FMUError as err:
        return {"offered": True, "loads": False, "refused": str(err), "passed": False}, None
    part = {"offered": True, "loads": True, "states": block.nstates, "inputs": list(block.input_labels),
            "outputs": list(block.output_labels), "feedthrough": sorted(block.contract.feedthrough)}
    with block:
        u = _start_inputs(md, list(block.input_labels))
        times = np.linspace(0.0, t_final, _POINTS + 1)
        out = fast_output(block)
        try:
            if block.nstates:
                f = fast_dynamics(block)
                rhs = counted(lambda t, x: f(t, x, u), budget, deadline, "the Model Exchange run")
                sol = solve_ivp(rhs, (0.0, t_final), block.initial_state, method="LSODA", t_eval=times, rtol=1e-8,
                                atol=1e-10)
                if not sol.success:
                    part["run"] = {"passed": False, "error": f"the integration failed: {sol.message}"}
                    part["passed"] = False
                    return part, None
                states = sol.y
            else:
                states = np.zeros((0, times.size))
            y = np.column_stack([out(t, states[:, k], u) for k, t in enumerate(times)])
        except BudgetError:
            raise
        except FMUError as err:
            part["run"] = {"passed": False, "error": str(err)}
            part["passed"] = False
            return part, None
    largest = worst(y)
    method = "SciPy LSODA, rtol 1e-8, atol 1e-10" if block.nstates else "outputs evaluated (no states)"
    part["run"] = {"t_final": t_final, "inputs": "held at their start values", "method": method,
                   "max_abs_output": largest, "finite": bool(np.isfinite(largest)),
                   "passed": bool(np.isfinite(largest))}
    part["passed"] = part["run"]["passed"]
    return part, dict(zip(block.output_labels, y))


def _co_simulation(extracted, md, t_final: float, step: float, deadline: Deadline) -> tuple[dict, dict | None]:
    """The Co-Simulation part and, when it ran, its real outputs by name on the check's grid."""
    if md.coSimulation is None:
        return {"offered": False, "skipped": "the FMU does not offer Co-Simulation (it offers: "
                f"{', '.join(offered_interfaces(md)) or 'no interface'})", "passed": True}, None
    refused = unsupported_features(md, "CoSimulation")
    part = {"offered": True, "couples": not refused}
    if refused:
        part["refused"] = "the co-simulation master does not couple: " + "; ".join(refused)
    n, every, h = _grid(t_final, step)
    names = [v.name for v in real_variables(md, "output")]
    try:
        with FMUInstance(extracted, kind="CoSimulation", check_interface=False, name="checked") as fmu:
            vr = fmu.value_references(names)
            rows = [fmu.get_real(vr).copy()]
            for k in range(n):
                fmu.do_step(k * h, h)
                if (k + 1) % every == 0:
                    rows.append(fmu.get_real(vr).copy())
                    deadline.check(f"Co-Simulation run at t = {(k + 1) * h:.6g} s")
    except BudgetError:
        raise
    except FMUError as err:
        part.update(runs=False, error=str(err), passed=False)
        return part, None
    y = np.array(rows).T if names else np.zeros((0, _POINTS + 1))
    largest = worst(y)
    part.update(runs=True, run={"t_final": t_final, "step": h, "steps": n, "inputs": "held at their start values",
                                "max_abs_output": largest, "finite": bool(np.isfinite(largest))})
    part["passed"] = bool(np.isfinite(largest)) and not refused
    return part, dict(zip(names, y))


def _me_vs_cs(me: dict | None, cs: dict | None, tolerance: float) -> dict:
    if me is None or cs is None:
        return {"skipped": "needs both interfaces to run"}
    common = [n for n in me if n in cs]
    if not common:
        return {"skipped": "no common real outputs"}
    gaps = {n: worst(me[n] - cs[n]) for n in common}
    scale = max(1.0, worst(*[me[n] for n in common]))
    largest = worst(np.array(list(gaps.values())))
    return {"max_abs_difference": largest, "per_output": gaps, "tolerance": tolerance * scale,
            "definition": f"max over the grid of |y_ME - y_CS|; tolerance {tolerance:g} x max(1, max |y_ME|)",
            "passed": bool(largest <= tolerance * scale)}


def check_fmu(path, t_final: float = 1.0, tolerance: float = 1e-6, cs_step: float = 0.01,
              cs_tolerance: float = 1e-6, me_cs_tolerance: float = 1e-4, budget: Budget | None = None,
              limits: ExtractionLimits | None = None) -> dict:
    """Validate an FMU, load and run what it offers, and compare the plant FMU with the Python plant.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file.
    t_final : float
        Length of the runs (s).
    tolerance : float
        Largest allowed Model Exchange difference to the Python plant (rad, m, rad/s, m/s, N m, N).
    cs_step : float
        Communication step (s) of the Co-Simulation runs.
    cs_tolerance : float
        Largest allowed Co-Simulation difference of the plant's states after ``t_final``.
    me_cs_tolerance : float
        Largest allowed Model Exchange / Co-Simulation difference, relative to ``max(1, max |y|)``.
    budget : Budget, optional
        Limits on steps, right-hand-side evaluations and wall time
        (:data:`fmu.budget.DEFAULT_BUDGET`); the step counts are estimated first.
    limits : ExtractionLimits, optional
        Archive size limits.

    Returns
    -------
    dict
        ``path``, ``fmi_version``, ``model``, ``interfaces``, ``validation``
        (``problems``, ``errors``, ``warnings``, ``passed``), ``model_exchange``,
        ``co_simulation``, ``me_vs_cs``, ``plant_comparison`` and ``passed``
        (see the module docstring).

    Raises
    ------
    FMUError
        (a subclass) for an unsafe archive, a missing or malformed model
        description or an unsupported FMI version; :class:`~fmu.errors.BudgetError`
        when the runs would exceed the budget.
    ValueError
        For a ``t_final`` or ``cs_step`` that is not a finite number > 0.
    """
    for name, value in (("t_final", t_final), ("cs_step", cs_step)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0 s, got {value!r}")
    budget = DEFAULT_BUDGET if budget is None else budget
    report: dict = {"path": str(path)}
    with extract_fmu(path, limits=limits) as extracted:
        try:
            md = described(extracted)
        except FMUModelDescriptionError as err:
            if not err.problems:  # missing, malformed, unsupported version: nothing to validate
                raise
            return _invalid_report(report, extracted, err.problems)
        report.update(fmi_version=md.fmiVersion, model=md.modelName, interfaces=offered_interfaces(md))
        try:
            robot, spec = plant_from_description(md)
        except (KeyError, ValueError, TypeError) as err:
            plant, plant_reason = None, f"not a dobkit plant FMU (no usable parameter {err})"
        else:
            plant, plant_reason = (robot, spec), None
        if md.coSimulation is not None:     # estimates first: refuse before running anything
            budget.check_steps(_grid(t_final, cs_step)[0], "the Co-Simulation run of the check",
                               f"t_final = {t_final:g} s (--t-final) / step {cs_step:g} s")
            if plant is not None:
                budget.check_steps(t_final / cs_step, "the plant's Co-Simulation comparison",
                                   f"t_final = {t_final:g} s (--t-final) / step {cs_step:g} s")
        deadline = budget.deadline(f"check of {extracted.source}")
        report["validation"] = _validation(extracted)
        report["model_exchange"], me_out = _model_exchange(extracted, md, t_final, budget, deadline)
        report["co_simulation"], cs_out = _co_simulation(extracted, md, t_final, cs_step, deadline)
        report["me_vs_cs"] = _me_vs_cs(me_out, cs_out, me_cs_tolerance)
        if plant is None:
            report["plant_comparison"] = {"skipped": plant_reason}
        else:
            comparison = {}
            if md.modelExchange is not None and report["model_exchange"].get("loads"):
                comparison["model_exchange"] = compare_model_exchange(extracted, *plant, t_final, tolerance, budget,
                                                                      deadline)
            if md.coSimulation is not None and report["co_simulation"].get("runs"):
                comparison["co_simulation"] = compare_co_simulation(extracted, *plant, t_final, cs_step,
                                                                    cs_tolerance, deadline)
            comparison["passed"] = all(c["passed"] for c in comparison.values())
            report["plant_comparison"] = comparison
    usable = md.modelExchange is not None or md.coSimulation is not None
    if not usable:
        report["unusable"] = ("dobkit uses Model Exchange or Co-Simulation; the FMU offers "
                              f"{', '.join(report['interfaces']) or 'no interface'}")
    parts = [report["validation"], report["model_exchange"], report["co_simulation"]]
    parts += [p for p in (report["me_vs_cs"], report["plant_comparison"]) if "skipped" not in p]
    report["passed"] = usable and all(p["passed"] for p in parts)
    return report


def _invalid_report(report: dict, extracted, problems: list[str]) -> dict:
    """The report for a model description that fails the schema validation: its problems, nothing run."""
    try:
        md = read_description(extracted.root, extracted.source, validate=False, limits=extracted.limits)
        report["fmi_version"], report["model"] = md.fmiVersion, md.modelName
        report["interfaces"] = offered_interfaces(md)
    except FMUError:
        report["fmi_version"] = report["model"] = None
        report["interfaces"] = []
    errors = [p for p in problems if NAMING_FINDING not in p]
    report["validation"] = {"problems": problems, "errors": errors,
                            "warnings": [p for p in problems if NAMING_FINDING in p], "passed": False}
    skipped = {"skipped": "the model description is invalid (see validation); the FMU was not loaded"}
    for key in ("model_exchange", "co_simulation", "me_vs_cs", "plant_comparison"):
        report[key] = dict(skipped)
    report["passed"] = False
    return report
