"""Check an FMU: does it validate, load, run -- and, for the dobkit plant, match the Python plant?

:func:`check_fmu` answers what a user needs to know before using an FMU
with dobkit, in a JSON-ready report that is always written: every stage
(``archive``, ``model_description``, ``validation``, ``model_exchange``,
``simulate_fmu``, ``co_simulation``, ``me_vs_cs``, ``plant_comparison``)
has a ``status`` -- ``"passed"``, ``"failed"`` or ``"not applicable"`` --
and a ``why``, listed in order under ``stages``.  An FMU that cannot be
opened, described, loaded or run fails its stage and the report goes on;
only bad arguments and the budget (a run the caller's limits refuse) raise.

* ``validation``: fmpy's static checks (:func:`fmpy.validation.validate_fmu`:
  schema, names, model structure, start values, units).  Findings of the
  variable-naming convention (``der(der(x))`` is outside the grammar of the
  structured convention, yet common and harmless) are *warnings*; the rest
  are errors.
* ``model_exchange``: whether the FMU loads as a block with :func:`fmu.load`
  -- and if not, the named reason ``load`` gives (arrays, non-real signals,
  ...); a block with events is left to the ``simulate_fmu`` stage -- and a short run with the inputs held at their
  start values (SciPy LSODA): every output must stay finite.
* ``co_simulation``: whether its Co-Simulation part runs a short simulation
  (the inputs at their start values, 100 recorded points) with finite
  outputs, and whether the co-simulation master can couple it (the same
  named reasons).
* ``simulate_fmu``: the Model Exchange interface run by :func:`fmu.simulate_fmu`
  (events, arrays), which also gives the fine reference (DOP853, rtol 1e-12);
* ``me_vs_cs``: where it offers both, each run compared with the fine
  reference, saying which side is off: a crude co-simulation solver inside
  the FMU is a finding, not a failure (dobkit integrates Model Exchange
  itself); a comparison of outputs that do not move (zero against zero) is
  flagged as trivial and not applicable.
* ``plant_comparison``: for the dobkit plant FMU only, Model Exchange and
  Co-Simulation against the native Python plant of its arm, and its end stops
  against their definition (:mod:`fmu.plant_check`).  The arm is the
  paper's (from the FMU's Table-1 parameters), the one recorded in the FMU
  by its export (``resources/dobkit_arm.json``, any other arm), or the one
  the caller gives (``arm=``; ``dobkit fmu check --arm``); an FMU whose
  joints are not the arm's fails by name.

``passed`` is true when the validation has no error, the FMU offers Model
Exchange or Co-Simulation (else ``unusable`` says what it offers), and every
part that it offers works with dobkit.  A NaN anywhere fails the part it is in.  A
model description that fails the schema validation is reported (its
problems listed, nothing run); so is a missing or malformed one, or an
unsupported FMI version.  Sizes are checked against a
:class:`~blocks.engines.budget.Budget` before anything runs.  The archive is extracted
once.  Checking runs the FMU's native code in this process: check an
untrusted FMU in a sandbox.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from blocks.diagram.control_compat import fast_dynamics, fast_output
from blocks.engines.budget import Budget
from blocks.engines.monitor import Monitor

from .archive import ExtractionLimits, extract_fmu
from .block import load
from .description import (
    array_shape,
    described,
    element_names,
    offered_interfaces,
    read_description,
    real_variables,
    unsupported_features,
)
from .errors import BudgetError, FMUError, FMUModelDescriptionError, FMUUnsupportedError
from .instance import FMUInstance
from .plant_check import (
    CHECK_INITIAL_STATE,
    arm_name,
    check_arm_matches,
    check_torque,
    compare_co_simulation,
    compare_end_stops,
    compare_model_exchange,
    plant_from_description,
    plant_reference,
    worst,
)

__all__ = ["check_fmu", "stage", "STAGES", "check_torque", "plant_from_description", "CHECK_INITIAL_STATE", "NAMING_FINDING"]

# how fmpy words a finding of the variable-naming convention check
NAMING_FINDING = "is not a legal variable name for naming convention"
_POINTS = 100       # recorded intervals of the short runs


def _validation(extracted) -> dict:
    # the schema was validated when the description was read: the rest of fmpy's checks on the parsed description
    # (validate_fmu would parse the XML a second time, the bulk of the cost for a large description)
    from fmpy.validation import validate_model_description
    problems = [str(p) for p in validate_model_description(described(extracted), validate_variable_names=True,
                                                           validate_model_structure=True)]
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


def _model_exchange(extracted, md, t_final: float, budget: Budget, deadline: Monitor) -> tuple[dict, dict | None]:
    """The Model Exchange part and, when it ran, its outputs by name on the check's grid."""
    if md.modelExchange is None:
        return {"offered": False, "skipped": "the FMU does not offer Model Exchange (it offers: "
                f"{', '.join(offered_interfaces(md)) or 'no interface'})", "passed": True}, None
    try:
        block = load(extracted, name="checked")
    except FMUUnsupportedError as err:
        if "simulate_fmu" not in str(err):
            return {"offered": True, "loads": False, "refused": str(err), "passed": False}, None
        # events or arrays: not a block, but a Model Exchange FMU all the same, run by the simulate_fmu stage
        return {"offered": True, "loads": False, "refused": str(err), "passed": True,
                "skipped": f"not a block: {err}; the simulate_fmu stage runs it"}, None
    except FMUError as err:
        return {"offered": True, "loads": False, "refused": str(err), "passed": False}, None
    part = {"offered": True, "loads": True, "states": block.nstates, "inputs": list(block.input_labels),
            "outputs": list(block.output_labels), "feedthrough": sorted(block.contract.feedthrough)}
    if block.event_source is not None:   # a hybrid block: its run alone is simulate_fmu's, with the same events
        block.close()
        return part | {"events": True, "passed": True, "skipped": "loads as a block with events (the numpy engine "
                       "stops at them: fmu.simulate_loop, blocks.simulate with engine='fast'); the simulate_fmu "
                       "stage runs it"}, None
    with block:
        u = _start_inputs(md, list(block.input_labels))
        times = np.linspace(0.0, t_final, _POINTS + 1)
        out = fast_output(block)
        try:
            if block.nstates:
                f = fast_dynamics(block)
                rhs = deadline.counted(lambda t, x: f(t, x, u), "the Model Exchange run")
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


def _co_simulation(extracted, md, t_final: float, step: float, deadline: Monitor) -> tuple[dict, dict | None]:
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
    labels = names
    try:
        with FMUInstance(extracted, kind="CoSimulation", check_interface=False, name="checked") as fmu:
            vr = fmu.value_references(names)
            labels = [e for name in names for e in element_names(fmu.variables[name],
                                                                 array_shape(fmu.variables[name], fmu.source))]
            rows = [fmu.get_real(vr).copy()]
            for k in range(n):
                fmu.do_step(k * h, h)
                if (k + 1) % every == 0:
                    rows.append(fmu.get_real(vr).copy())
                    deadline.check_time(where=f"Co-Simulation run at t = {(k + 1) * h:.6g} s")
    except BudgetError:
        raise
    except FMUError as err:
        part.update(runs=False, error=str(err), passed=False)
        return part, None
    y = np.array(rows).T if labels else np.zeros((0, _POINTS + 1))
    largest = worst(y)
    part.update(runs=True, run={"t_final": t_final, "step": h, "steps": n, "inputs": "held at their start values",
                                "max_abs_output": largest, "finite": bool(np.isfinite(largest))})
    part["passed"] = bool(np.isfinite(largest)) and not refused
    return part, dict(zip(labels, y))


_REFERENCE = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-14}


def _me_vs_cs(me: dict | None, cs: dict | None, ref: dict | None, tolerance: float, cs_step: float) -> dict:
    """Both interfaces against the fine reference: which side is off, if any."""
    if me is None or cs is None:
        return {"skipped": "needs both interfaces to run"}
    common = [n for n in me if n in cs]
    if not common:
        return {"skipped": "no common real outputs"}
    gaps = {n: worst(me[n] - cs[n]) for n in common}
    scale = max(1.0, worst(*[me[n] for n in common]))
    largest = worst(np.array(list(gaps.values())))
    part = {"max_abs_difference": largest, "per_output": gaps, "tolerance": tolerance * scale,
            "definition": f"max over the grid of |y_ME - y_CS|; tolerance {tolerance:g} x max(1, max |y_ME|)"}
    if ref is not None and all(n in ref for n in common):
        if all(np.ptp(np.asarray(ref[n])) == 0 and np.ptp(np.asarray(me[n])) == 0 and np.ptp(np.asarray(cs[n])) == 0
               for n in common):
            part.update(trivial=True, passed=True,
                        skipped=("trivially equal: every compared output is constant in both runs with the inputs at "
                                 "their start values (" + ", ".join(f"{n} = {float(me[n][0]):g}" for n in common[:3])
                                 + "); the comparison shows nothing"))
            return part
        me_off = 0.0 if me is ref else worst(*[me[n] - ref[n] for n in common])
        cs_off = worst(*[cs[n] - ref[n] for n in common])
        ref_scale = max(1e-300, worst(*[ref[n] for n in common]))
        part.update(reference=f"fmu.simulate_fmu, SciPy {_REFERENCE['method']}, rtol {_REFERENCE['rtol']:g}",
                    me_vs_reference=me_off, cs_vs_reference=cs_off, trivial=False)
        me_ok, cs_ok = bool(me_off <= tolerance * scale), bool(cs_off <= tolerance * scale)
        if me_ok and cs_ok:
            part["finding"] = "both interfaces agree with the fine reference"
        elif me_ok:
            me_side = ("Model Exchange, run by fmu.simulate_fmu, is the reference" if me is ref
                       else f"Model Exchange is within {me_off:.3g}")
            part["finding"] = (f"the FMU's own co-simulation solver is {100 * cs_off / ref_scale:.3g} % off its Model "
                               f"Exchange answer at the step {cs_step:g} s (max |y_CS - y_ref| = {cs_off:.3g}; "
                               f"{me_side}); dobkit uses Model Exchange (fmu.load, fmu.simulate_fmu), a co-simulation "
                               "with this FMU inherits the error")
        elif cs_ok:
            part["finding"] = (f"the Model Exchange run is off the fine reference by {me_off:.3g} while Co-Simulation "
                               f"is within {cs_off:.3g}: dobkit's Model Exchange integration of this FMU is not accurate")
        else:
            part["finding"] = (f"both interfaces are off the fine reference (Model Exchange by {me_off:.3g}, "
                               f"Co-Simulation by {cs_off:.3g})")
        part["passed"] = me_ok
        part["within_tolerance"] = bool(largest <= tolerance * scale)
        return part
    part["passed"] = bool(largest <= tolerance * scale)
    return part


def _simulated(extracted, md, t_final: float, budget: Budget) -> tuple[dict, dict | None]:
    """The Model Exchange interface run by :func:`fmu.simulate_fmu` (events, arrays): the fine reference."""
    if md.modelExchange is None:
        return {"skipped": "the FMU does not offer Model Exchange", "passed": True}, None
    from .simulate import simulate_fmu
    try:
        resp = simulate_fmu(extracted, t_final, t_final / _POINTS, method=_REFERENCE["method"], rtol=_REFERENCE["rtol"],
                            atol=_REFERENCE["atol"], budget=budget)
    except BudgetError:
        raise
    except Exception as err:  # noqa: BLE001 - the FMU's problem goes into the report, whatever it is
        return {"runs": False, "error": _why(err), "passed": False}, None
    y = np.asarray(resp.outputs).reshape(len(resp.output_labels), -1)
    largest = worst(y)
    events = resp.simulation["events"]
    part = {"runs": True, "t_final": t_final, "method": resp.simulation["method"], "events": len(events),
            "state_events": sum(e["kind"] == "state" for e in events),
            "time_events": sum(e["kind"] == "time" for e in events), "terminated": resp.simulation["terminated"],
            "max_abs_output": largest, "finite": bool(np.isfinite(largest)), "passed": bool(np.isfinite(largest))}
    if resp.simulation["terminated"] is not None or y.shape[1] != _POINTS + 1:
        return part, None     # the FMU stopped early: no full grid to compare on
    return part, dict(zip(resp.output_labels, y))


def _why(err: BaseException) -> str:
    """An exception as one line for the report: FMU errors by their message, others with their type."""
    if isinstance(err, FMUError):
        return str(err)
    return f"{type(err).__name__}: {err}"


def _raw_identity(extracted) -> tuple[str, str]:
    """fmiVersion and modelName read straight from the XML when it cannot be parsed as a model description."""
    import re
    try:
        head = (extracted.root / "modelDescription.xml").read_bytes()[:65536].decode("utf-8", "replace")
    except OSError:
        return "unknown (no readable modelDescription.xml)", "unknown"
    version = re.search(r'fmiVersion\s*=\s*["\']([^"\']*)["\']', head)
    model = re.search(r'modelName\s*=\s*["\']([^"\']*)["\']', head)
    return (version.group(1) if version else "unknown (no fmiVersion attribute)",
            model.group(1) if model else "unknown (no modelName attribute)")


STAGES = ("archive", "model_description", "validation", "model_exchange", "simulate_fmu", "co_simulation", "me_vs_cs",
          "plant_comparison")


_PASSED = {"validation": "no schema or consistency errors (fmpy)",
           "model_exchange": "loads as a block and runs with finite outputs (inputs at their start values)",
           "simulate_fmu": "runs with its events, outputs finite",
           "co_simulation": "runs with finite outputs and the master can couple it",
           "plant_comparison": "matches the Python plant within the tolerances"}


def _status(name: str, part: dict) -> tuple[str, str]:
    """(status, why) of one stage from its findings."""
    if "skipped" in part:
        return "not applicable", part["skipped"]
    if part.get("passed"):
        return "passed", part.get("finding") or part.get("why") or _PASSED.get(name, "ok")
    for key in ("error", "refused", "why"):
        if part.get(key):
            return "failed", part[key]
    run = part.get("run") or {}
    if run.get("error"):
        return "failed", run["error"]
    if run.get("finite") is False or part.get("finite") is False:
        return "failed", "an output is not finite"
    if part.get("finding"):
        return "failed", part["finding"]
    if "errors" in part and part["errors"]:
        return "failed", f"{len(part['errors'])} error(s), the first: {part['errors'][0].splitlines()[0]}"
    return "failed", "see the details"


def _finish(report: dict) -> dict:
    """The ordered list of stages, each with its status and why."""
    report["stages"] = []
    for name in STAGES:
        status, why = _status(name, report.setdefault(name, {"skipped": "not reached"}))
        report["stages"].append({"stage": name, "status": status, "why": why})
    return report


def stage(report: dict, name: str) -> dict:
    """The ``{"stage", "status", "why"}`` entry of one stage of a :func:`check_fmu` report."""
    return next(s for s in report["stages"] if s["stage"] == name)


def _not_applicable(report: dict, after: str, why: str) -> None:
    for name in STAGES[STAGES.index(after) + 1:]:
        report[name] = {"skipped": why}


def _reference(extracted, md, arm):
    """(PlantReference, None, None) for a dobkit plant FMU, (None, why not, None) for another FMU, or
    (None, None, why it fails) for a plant FMU that is not the given arm's."""
    from .arm_record import ARM_RECORD, arm_from_record

    names = {v.name for v in md.modelVariables}
    if arm is not None and "disturbance_paper" in names:
        try:
            check_arm_matches(md, arm, arm_name(arm))
        except FMUError as err:
            return None, None, str(err)
    if arm is None and "m1" not in names:
        record = extracted.root / ARM_RECORD
        if record.is_file():
            arm = arm_from_record(record.read_text(encoding="utf-8"))
        elif "disturbance_paper" in names and "tau[0]" in names:
            return None, ("a dobkit plant FMU of an arm that is not recorded in it (no " + ARM_RECORD + "): give "
                          "the arm (check_fmu(arm=...), dobkit fmu check --arm) to compare it"), None
    try:
        return plant_reference(md, arm), None, None
    except (KeyError, TypeError) as err:
        return None, f"not a dobkit plant FMU (no usable parameter {err})", None
    except ValueError as err:           # a plant FMU whose settings the arm's Python plant cannot take
        return None, f"no Python plant to compare with: {err}", None


def _run_settings(md, t_final: float | None, cs_step: float | None) -> tuple[float, float]:
    """The run length and Co-Simulation step not given: 1 s and 0.01 s; for an FMU that cannot vary its
    communication step (a sampled controller, which refuses any other step and steps past its reference table),
    its ``DefaultExperiment`` stepSize and, when earlier than 1 s, its stopTime."""
    def declared(text) -> float | None:
        try:
            value = float(text)
        except (TypeError, ValueError):
            return None
        return value if math.isfinite(value) and value > 0 else None
    experiment = md.defaultExperiment
    fixed = (experiment is not None and md.coSimulation is not None
             and not md.coSimulation.canHandleVariableCommunicationStepSize)
    stop = declared(experiment.stopTime) if fixed else None
    size = declared(experiment.stepSize) if fixed else None
    if t_final is None:
        t_final = min(1.0, stop) if stop is not None else 1.0
    if cs_step is None:
        cs_step = size if size is not None else 0.01
    return t_final, cs_step


def check_fmu(path, t_final: float | None = None, tolerance: float = 1e-6, cs_step: float | None = None,
              cs_tolerance: float = 1e-6, me_cs_tolerance: float = 1e-4, budget: Budget | None = None,
              limits: ExtractionLimits | None = None, arm=None) -> dict:
    """Validate an FMU, load and run what it offers, and compare the plant FMU with the Python plant.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file.
    t_final : float, optional
        Length of the runs (s); default 1 s, or for an FMU that cannot vary
        its communication step its ``DefaultExperiment`` stopTime when earlier.
    tolerance : float
        Largest allowed Model Exchange difference to the Python plant (rad, m, rad/s, m/s, N m, N).
    cs_step : float, optional
        Communication step (s) of the Co-Simulation runs; default 0.01 s, or
        the FMU's ``DefaultExperiment`` stepSize when it cannot vary its
        communication step (``canHandleVariableCommunicationStepSize="false"``,
        a sampled controller).
    cs_tolerance : float
        Largest allowed Co-Simulation difference of the plant's states after ``t_final``.
    me_cs_tolerance : float
        Largest allowed difference of either interface to the fine reference, relative to ``max(1, max |y|)``.
    budget : Budget, optional
        Limits on steps, right-hand-side evaluations and wall time
        (:meth:`blocks.engines.budget.Budget.from_env`); the step counts are estimated first.
    limits : ExtractionLimits, optional
        Archive size limits.
    arm : blocks.model.arm.ArmModel, optional
        The arm to hold a dobkit plant FMU against (its joint count, names,
        units, ranges and dynamics).  Default: the paper's arm with the FMU's
        Table-1 values, or the arm the export recorded in the FMU.

    Returns
    -------
    dict
        ``path``, ``fmi_version``, ``model``, ``interfaces``, one entry per
        stage (``archive``, ``model_description``, ``validation``,
        ``model_exchange``, ``simulate_fmu``, ``co_simulation``, ``me_vs_cs``,
        ``plant_comparison``: the findings of each), ``stages``
        (each stage's ``status`` and ``why``, in order; :func:`stage` picks one)
        and ``passed`` (see the module docstring).

    Raises
    ------
    BudgetError
        When the runs would exceed the budget, or exceed it while running.
    ValueError
        For a ``t_final`` or ``cs_step`` that is not a finite number > 0.
    """
    for name, value in (("t_final", t_final), ("cs_step", cs_step)):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0 s, got {value!r}")
    budget = Budget.from_env() if budget is None else budget
    report: dict = {"path": str(path), "fmi_version": "unknown", "model": "unknown", "interfaces": []}
    try:
        extracted = extract_fmu(path, limits=limits)
    except (FMUError, OSError) as err:
        report["archive"] = {"passed": False, "error": _why(err)}
        _not_applicable(report, "archive", "the archive could not be opened (see archive)")
        report["passed"] = False
        return _finish(report)
    report["archive"] = {"passed": True, "why": f"extracted safely ({extracted.source})"}
    with extracted:
        try:
            md = described(extracted)
        except FMUModelDescriptionError as err:
            if err.problems:
                report = _invalid_report(report, extracted, err.problems)
                report["model_description"] = {"passed": False, "error": _why(err)}
                return _finish(report)
            report["fmi_version"], report["model"] = _raw_identity(extracted)
            report["model_description"] = {"passed": False, "error": _why(err)}
            _not_applicable(report, "model_description", "the model description could not be read (see "
                                                         "model_description)")
            report["passed"] = False
            return _finish(report)
        report["model_description"] = {"passed": True, "why": f"FMI {md.fmiVersion}, {len(md.modelVariables)} "
                                                               "variables"}
        report.update(fmi_version=md.fmiVersion, model=md.modelName, interfaces=offered_interfaces(md))
        t_final, cs_step = _run_settings(md, t_final, cs_step)
        plant, plant_reason, mismatch = _reference(extracted, md, arm)
        if md.coSimulation is not None:     # estimates first: refuse before running anything
            budget.check_steps(_grid(t_final, cs_step)[0], "the Co-Simulation run of the check",
                               f"t_final = {t_final:g} s (--t-final) / step {cs_step:g} s")
            if plant is not None:
                budget.check_steps(t_final / cs_step, "the plant's Co-Simulation comparison",
                                   f"t_final = {t_final:g} s (--t-final) / step {cs_step:g} s")
        deadline = Monitor.for_job(f"check of {extracted.source}", budget)
        report["validation"] = _guarded(lambda: _validation(extracted))
        me_out = cs_out = ref_out = None

        def model_exchange():
            nonlocal me_out
            part, me_out = _model_exchange(extracted, md, t_final, budget, deadline)
            return part

        def simulated():
            nonlocal ref_out
            part, ref_out = _simulated(extracted, md, t_final, budget)
            return part

        def co_simulation():
            nonlocal cs_out
            part, cs_out = _co_simulation(extracted, md, t_final, cs_step, deadline)
            return part

        report["model_exchange"] = _guarded(model_exchange)
        report["simulate_fmu"] = _guarded(simulated)
        if me_out is None and ref_out is not None:     # not a block (events, arrays): simulate_fmu's run is its ME
            me_out = ref_out
        report["co_simulation"] = _guarded(co_simulation)
        report["me_vs_cs"] = _guarded(lambda: _me_vs_cs(me_out, cs_out, ref_out, me_cs_tolerance, cs_step))
        if mismatch is not None:
            report["plant_comparison"] = {"passed": False, "error": mismatch}
        elif plant is None:
            report["plant_comparison"] = {"skipped": plant_reason}
        else:
            def compare():
                comparison = {"arm": plant.name, "joints": list(plant.arm.joints.names)}
                check_arm_matches(md, plant.arm, plant.name)
                if md.modelExchange is not None and report["model_exchange"].get("loads"):
                    comparison["model_exchange"] = compare_model_exchange(extracted, plant, t_final, tolerance,
                                                                          budget, deadline, md)
                    stops = compare_end_stops(extracted, plant, md)
                    if "skipped" not in stops:
                        comparison["end_stops"] = stops
                if md.coSimulation is not None and report["co_simulation"].get("runs"):
                    comparison["co_simulation"] = compare_co_simulation(extracted, plant, t_final, cs_step,
                                                                        cs_tolerance, deadline, md)
                parts = [c for c in comparison.values() if isinstance(c, dict)]
                comparison["passed"] = all(c["passed"] for c in parts)
                failed = [c["why"] for c in parts if not c["passed"] and c.get("why")]
                if failed:
                    comparison["why"] = "; ".join(failed)
                return comparison
            report["plant_comparison"] = _guarded(compare)
    usable = md.modelExchange is not None or md.coSimulation is not None
    if not usable:
        report["unusable"] = ("dobkit uses Model Exchange or Co-Simulation; the FMU offers "
                              f"{', '.join(report['interfaces']) or 'no interface'}")
    parts = [report["validation"], report["model_exchange"], report["co_simulation"]]
    parts += [p for p in (report["me_vs_cs"], report["plant_comparison"]) if "skipped" not in p]
    report["passed"] = usable and all(p["passed"] for p in parts)
    return _finish(report)


def _guarded(stage) -> dict:
    """Run one stage; an exception from the FMU (or from reading it) fails the stage instead of the check."""
    try:
        return stage()
    except BudgetError:
        raise
    except Exception as err:  # noqa: BLE001 - whatever the FMU does, the report goes on
        return {"passed": False, "error": _why(err)}


def _invalid_report(report: dict, extracted, problems: list[str]) -> dict:
    """The report for a model description that fails the schema validation: its problems, nothing run."""
    try:
        md = read_description(extracted.root, extracted.source, validate=False, limits=extracted.limits)
        report["fmi_version"], report["model"] = md.fmiVersion, md.modelName
        report["interfaces"] = offered_interfaces(md)
    except FMUError:
        report["fmi_version"], report["model"] = _raw_identity(extracted)
        report["interfaces"] = []
    errors = [p for p in problems if NAMING_FINDING not in p]
    report["validation"] = {"problems": problems, "errors": errors,
                            "warnings": [p for p in problems if NAMING_FINDING in p], "passed": False}
    skipped = {"skipped": "the model description is invalid (see validation); the FMU was not loaded"}
    for key in ("model_exchange", "simulate_fmu", "co_simulation", "me_vs_cs", "plant_comparison"):
        report[key] = dict(skipped)
    report["passed"] = False
    return report
