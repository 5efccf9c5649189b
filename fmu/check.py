"""Check an FMU: fmpy's static validation, and the plant FMU against the native Python plant.

:func:`check_fmu` returns a JSON-ready report:

* ``validation``: the problems :func:`fmpy.validation.validate_fmu` finds
  (schema, names, model structure, start values, units);
* ``model_exchange``: the FMU loaded with :func:`fmu.load` and the
  Python plant :func:`blocks.systems.plant` -- built from the FMU's own
  parameter start values -- integrated side by side with SciPy (DOP853, tight
  tolerances) under the same torque input from the same initial state; the
  largest differences of states and ``tau_dis``;
* ``co_simulation``: the FMU's own fixed-step integration against the Python
  plant integrated exactly under the same piecewise-constant torque.

The comparisons need the plant's variable names (``m1``, ``f_r[0]``, ...);
for another FMU they are reported as skipped.  A model description that
fails the schema validation is reported (its problems listed, comparisons
skipped) rather than raised; a missing or malformed one, or an unsupported
FMI version, raises.  The archive is checked and extracted once.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from blocks.control_compat import fast_dynamics, fast_output
from blocks.disturbances import DISTURBANCE_KINDS, DisturbanceSpec
from blocks.parameters import RobotParameters
from blocks.systems import plant as python_plant
from .archive import ExtractionLimits, extract_fmu
from .description import described, read_description
from .errors import FMUError, FMUModelDescriptionError
from .instance import FMUInstance
from .block import load
from blocks.joints import RRPR_JOINTS

__all__ = ["check_fmu", "check_torque", "plant_from_description", "CHECK_INITIAL_STATE"]

JOINTS = RRPR_JOINTS.count
# A generic configuration away from the singular theta2 = 0, pi, already moving (rad, m; rad/s, m/s).
CHECK_INITIAL_STATE = np.array([0.3, 1.2, 0.05, 0.2, 0.4, -0.3, 0.0, 0.2])
_STATES = [f"q[{i}]" for i in range(JOINTS)] + [f"dq[{i}]" for i in range(JOINTS)]


def check_torque(t, params: RobotParameters) -> np.ndarray:
    """The deterministic test input (N m, N m, N, N m): sines plus gravity compensation on joint 3."""
    return np.array([2.0 * np.sin(3.0 * t), 1.5 * np.cos(2.0 * t),
                     -(params.m3 + params.m4) * params.g + 0.5 * np.sin(5.0 * t), 0.3 * np.sin(t)])


def plant_from_description(model_description) -> tuple[RobotParameters, DisturbanceSpec]:
    """The Python parameter objects matching the FMU's parameter start values.

    Raises
    ------
    KeyError
        If the FMU lacks one of the plant's parameters.
    """
    start = {v.name: v.start for v in model_description.modelVariables}

    def num(name):
        return float(start[name])

    robot = RobotParameters(**{name: num(name) for name in RobotParameters.names()})
    kinds = tuple(k for k in DISTURBANCE_KINDS if str(start[f"disturbance_{k}"]).lower() in ("true", "1"))
    spec = DisturbanceSpec(
        kinds=kinds,
        **{base: tuple(num(f"{base}[{i}]") for i in range(JOINTS)) for base in ("f_r", "coulomb", "viscous")},
        **{name: num(name)
           for name in ("friction_velocity", "skin_height", "tissue_stiffness", "tissue_damping", "tissue_drag")})
    return robot, spec


def _compare_model_exchange(extracted, robot, spec, t_final, tolerance) -> dict:
    x0 = CHECK_INITIAL_STATE
    fmu = load(extracted, name="fmu_plant", start_values=dict(zip(_STATES, x0)))
    try:
        py = python_plant(robot, spec)
        t_eval = np.linspace(0.0, t_final, 101)
        runs = {}
        for key, sys in (("fmu", fmu), ("python", py)):
            sol = solve_ivp(lambda t, x, f=fast_dynamics(sys): f(t, x, check_torque(t, robot)), (0.0, t_final), x0,
                            method="DOP853", t_eval=t_eval, rtol=1e-11, atol=1e-12)
            if not sol.success:
                raise FMUError(f"{key} plant: the reference integration failed: {sol.message}")
            out = fast_output(sys)
            outs = np.column_stack([out(t, sol.y[:, k], check_torque(t, robot)) for k, t in enumerate(t_eval)])
            runs[key] = (sol.y, outs)
        labels = list(fmu.output_labels)
        dis = [labels.index(f"tau_dis[{i}]") for i in range(JOINTS)]
        state_err = np.abs(runs["fmu"][0] - runs["python"][0]).max(axis=1)
        dis_err = np.abs(runs["fmu"][1][dis] - runs["python"][1][8:12]).max(axis=1)
    finally:
        fmu.fmu.close()
    worst = float(max(state_err.max(), dis_err.max()))
    return {"t_final": t_final, "max_abs_error": worst, "tolerance": tolerance, "passed": worst <= tolerance,
            "max_abs_error_per_state": dict(zip(_STATES, state_err.tolist())),
            "max_abs_error_tau_dis": dis_err.tolist(),
            "method": "SciPy DOP853, rtol 1e-11, atol 1e-12, on both; same torque input and initial state"}


def _compare_co_simulation(extracted, robot, spec, t_final, step, tolerance) -> dict:
    x0 = CHECK_INITIAL_STATE
    py = python_plant(robot, spec)
    n = int(round(t_final / step))
    x_ref = x0.copy()
    with FMUInstance(extracted, kind="CoSimulation", start_values=dict(zip(_STATES, x0))) as fmu:
        in_vr = fmu.value_references([f"tau[{i}]" for i in range(JOINTS)])
        out_vr = fmu.value_references(_STATES)
        substeps = fmu.get_integer("n_substeps")
        for k in range(n):
            t, u = k * step, check_torque(k * step, robot)
            fmu.set_real(in_vr, u)
            fmu.do_step(t, step)
            sol = solve_ivp(lambda tt, x: fast_dynamics(py)(tt, x, u), (t, t + step), x_ref, method="DOP853",
                            rtol=1e-12, atol=1e-13)
            x_ref = sol.y[:, -1]
        x_fmu = fmu.get_real(out_vr)
    err = float(np.abs(x_fmu - x_ref).max())
    return {"t_final": n * step, "step": step, "n_substeps": substeps, "max_abs_error": err, "tolerance": tolerance,
            "passed": err <= tolerance,
            "method": "torque held over each step; reference SciPy DOP853 rtol 1e-12 per step"}


def check_fmu(path, t_final: float = 1.0, tolerance: float = 1e-6, cs_step: float = 0.01,
              cs_tolerance: float = 1e-6, limits: ExtractionLimits | None = None) -> dict:
    """Validate an FMU and compare the plant FMU with the Python plant.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file.
    t_final : float
        Length of the comparison runs (s).
    tolerance : float
        Largest allowed Model Exchange difference (rad, m, rad/s, m/s, N m, N).
    cs_step : float
        Communication step (s) of the Co-Simulation comparison.
    cs_tolerance : float
        Largest allowed Co-Simulation difference of the states after ``t_final``.
    limits : ExtractionLimits, optional
        Archive size limits.

    Returns
    -------
    dict
        ``path``, ``fmi_version``, ``model``, ``validation`` (``problems``,
        ``passed``), ``model_exchange`` and ``co_simulation`` (errors,
        tolerances, ``passed``, or ``skipped`` with the reason), and ``passed``.

    Raises
    ------
    FMUError
        (a subclass) for an unsafe archive, a missing or malformed model
        description, an unsupported FMI version, or a failure while comparing.
    """
    from fmpy.validation import validate_fmu

    report: dict = {"path": str(path)}
    with extract_fmu(path, limits=limits) as extracted:
        try:
            md = described(extracted)
        except FMUModelDescriptionError as err:
            if not err.problems:  # missing, malformed, unsupported version: nothing to validate
                raise
            return _invalid_report(report, extracted, err.problems)
        report["fmi_version"] = md.fmiVersion
        report["model"] = md.modelName
        problems = validate_fmu(str(extracted.root))
        report["validation"] = {"problems": problems, "passed": not problems}
        try:
            robot, spec = plant_from_description(md)
        except (KeyError, ValueError, TypeError) as err:
            reason = f"not a dobkit plant FMU (no usable parameter {err})"
            report["model_exchange"] = report["co_simulation"] = {"skipped": reason}
        else:
            for key, kind, run in (
                    ("model_exchange", md.modelExchange,
                     lambda: _compare_model_exchange(extracted, robot, spec, t_final, tolerance)),
                    ("co_simulation", md.coSimulation,
                     lambda: _compare_co_simulation(extracted, robot, spec, t_final, cs_step, cs_tolerance))):
                report[key] = run() if kind is not None else {"skipped": "the FMU does not offer this interface"}
    parts = [report["validation"]] + [report[k] for k in ("model_exchange", "co_simulation")
                                      if "skipped" not in report[k]]
    report["passed"] = all(p["passed"] for p in parts)
    return report


def _invalid_report(report: dict, extracted, problems: list[str]) -> dict:
    """The report for a model description that fails the schema validation: its problems, nothing compared."""
    try:
        md = read_description(extracted.root, extracted.source, validate=False)
        report["fmi_version"], report["model"] = md.fmiVersion, md.modelName
    except FMUError:
        report["fmi_version"] = report["model"] = None
    report["validation"] = {"problems": problems, "passed": False}
    report["model_exchange"] = report["co_simulation"] = {
        "skipped": "the model description is invalid (see validation); the FMU was not loaded"}
    report["passed"] = False
    return report
