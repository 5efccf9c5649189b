"""The dobkit plant FMU against the native Python plant (part of :func:`fmu.check_fmu`).

* Model Exchange: the FMU loaded with :func:`fmu.load` and the Python plant
  :func:`blocks.systems.plant` -- built from the FMU's own parameter start
  values -- integrated side by side with SciPy (DOP853, tight tolerances)
  under the same torque input from the same initial state; the largest
  differences of states and ``tau_dis``.
* Co-Simulation: the FMU's own fixed-step integration against the Python
  plant integrated exactly under the same piecewise-constant torque.

Every difference is a NaN-propagating maximum: a NaN anywhere fails the
comparison (Python's ``max(x, nan)`` is ``x``; numpy's is ``nan``).
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from blocks.budget import Budget
from blocks.control_compat import fast_dynamics, fast_output
from blocks.disturbances import DISTURBANCE_KINDS, DisturbanceSpec
from blocks.joints import RRPR_JOINTS
from blocks.monitor import Monitor
from blocks.parameters import RobotParameters
from blocks.systems import plant as python_plant

from .block import load
from .errors import FMUError
from .instance import FMUInstance

__all__ = ["check_torque", "plant_from_description", "compare_model_exchange", "compare_co_simulation",
           "CHECK_INITIAL_STATE", "worst"]

JOINTS = RRPR_JOINTS.count
# A generic configuration away from the singular theta2 = 0, pi, already moving (rad, m; rad/s, m/s).
CHECK_INITIAL_STATE = np.array([0.3, 1.2, 0.05, 0.2, 0.4, -0.3, 0.0, 0.2])
STATES = [f"q[{i}]" for i in range(JOINTS)] + [f"dq[{i}]" for i in range(JOINTS)]


def worst(*arrays) -> float:
    """The largest absolute value over all arrays; NaN if any entry is NaN (so that ``worst <= tol`` fails)."""
    values = np.concatenate([np.abs(np.ravel(np.asarray(a, dtype=float))) for a in arrays])
    return float(np.max(values)) if values.size else 0.0


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


def compare_model_exchange(extracted, robot, spec, t_final: float, tolerance: float, budget: Budget,
                           deadline: Monitor) -> dict:
    """Model Exchange FMU against the Python plant under :func:`check_torque` (see the module docstring)."""
    x0 = CHECK_INITIAL_STATE
    fmu = load(extracted, name="fmu_plant", start_values=dict(zip(STATES, x0)))
    try:
        py = python_plant(robot, spec)
        t_eval = np.linspace(0.0, t_final, 101)
        runs = {}
        for key, sys in (("fmu", fmu), ("python", py)):
            rhs = deadline.counted(lambda t, x, f=fast_dynamics(sys): f(t, x, check_torque(t, robot)),
                                   f"the Model Exchange comparison ({key} plant)")
            sol = solve_ivp(rhs, (0.0, t_final), x0, method="DOP853", t_eval=t_eval, rtol=1e-11, atol=1e-12)
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
        fmu.close()
    largest = worst(state_err, dis_err)
    return {"t_final": t_final, "max_abs_error": largest, "tolerance": tolerance,
            "passed": bool(largest <= tolerance),
            "max_abs_error_per_state": dict(zip(STATES, state_err.tolist())),
            "max_abs_error_tau_dis": dis_err.tolist(),
            "method": "SciPy DOP853, rtol 1e-11, atol 1e-12, on both; same torque input and initial state"}


def compare_co_simulation(extracted, robot, spec, t_final: float, step: float, tolerance: float,
                          deadline: Monitor) -> dict:
    """Co-Simulation FMU against the Python plant integrated exactly under the same held torque."""
    x0 = CHECK_INITIAL_STATE
    py = python_plant(robot, spec)
    n = max(1, int(round(t_final / step)))
    x_ref = x0.copy()
    with FMUInstance(extracted, kind="CoSimulation", start_values=dict(zip(STATES, x0))) as fmu:
        in_vr = fmu.value_references([f"tau[{i}]" for i in range(JOINTS)])
        out_vr = fmu.value_references(STATES)
        substeps = fmu.get_integer("n_substeps")
        for k in range(n):
            t, u = k * step, check_torque(k * step, robot)
            fmu.set_real(in_vr, u)
            fmu.do_step(t, step)
            sol = solve_ivp(lambda tt, x: fast_dynamics(py)(tt, x, u), (t, t + step), x_ref, method="DOP853",
                            rtol=1e-12, atol=1e-13)
            x_ref = sol.y[:, -1]
            if k % 100 == 0:
                deadline.check_time(where=f"Co-Simulation comparison at t = {t:.6g} s")
        x_fmu = fmu.get_real(out_vr)
    err = worst(x_fmu - x_ref)
    return {"t_final": n * step, "step": step, "n_substeps": substeps, "max_abs_error": err, "tolerance": tolerance,
            "passed": bool(err <= tolerance),
            "method": "torque held over each step; reference SciPy DOP853 rtol 1e-12 per step"}
