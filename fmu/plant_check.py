"""The dobkit plant FMU against the native Python plant of its arm (part of :func:`fmu.check_fmu`).

The arm is the paper's RRPR (built from the FMU's own Table-1 start values)
or any other arm model (a URDF arm: given by the caller, or rebuilt from the
record the export wrote into the FMU, :mod:`fmu.arm_record`).  Joint count,
names and units come from the arm; an FMU of another joint count, joint
kinds or joint ranges is refused by name before anything runs.

* Model Exchange: the FMU loaded with :func:`fmu.load` and the Python plant
  integrated side by side with SciPy (DOP853, tight tolerances) under the
  same torque from the same initial state; the largest differences of states
  and ``tau_dis``.  The reference is the plant block :func:`blocks.diagram.systems.plant`
  for the paper's arm and, for another arm, its own ``forward_dynamics``
  under ``tau + tau_dis`` (the disturbance models of
  :func:`blocks.kernels.disturbance.external_disturbance`).
* Co-Simulation: the FMU's own fixed-step integration against the Python
  plant integrated exactly under the same piecewise-constant torque.
* End stops (Model Exchange): the FMU's state derivative at states beyond each
  bounded joint's range against the reference with the stop force of
  :mod:`fmu.end_stops` written here from its definition.

The two runs compare the arm's dynamics: the Python plant has no end stops,
so they run with the FMU's stops off (``stop_stiffness[i] = stop_damping[i]
= 0``; inside the ranges that changes no number), and the stops are
checked on their own.  The torque: for the paper's arm the fixed test
input :func:`check_torque`; for another arm a PD law with gravity
compensation around the middle of the joint ranges (:func:`arm_torque`),
which keeps every joint inside its range.

Every difference is a NaN-propagating maximum: a NaN anywhere fails the
comparison (Python's ``max(x, nan)`` is ``x``; numpy's is ``nan``).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from blocks.diagram.control_compat import fast_dynamics, fast_output
from blocks.diagram.systems import plant as python_plant
from blocks.engines.budget import Budget
from blocks.engines.monitor import Monitor
from blocks.kernels.disturbance import DisturbanceParams, external_disturbance
from blocks.model.arm import ArmModel
from blocks.model.disturbances import DISTURBANCE_KINDS, DisturbanceSpec
from blocks.scenarios.scenario import default_arm

from .arm_match import arm_name, check_arm_matches, check_scenario_arm
from .block import load
from .errors import FMUError
from .instance import FMUInstance

__all__ = ["check_torque", "arm_torque", "plant_from_description", "plant_reference", "PlantReference",
           "check_arm_matches", "check_scenario_arm", "arm_name", "compare_model_exchange", "compare_co_simulation",
           "compare_end_stops", "substeps_for",
           "CHECK_INITIAL_STATE", "worst", "stop_parameters"]

# The paper's arm: a generic configuration away from the singular theta2 = 0, pi, already moving (rad, m; rad/s, m/s).
CHECK_INITIAL_STATE = np.array([0.3, 1.2, 0.05, 0.2, 0.4, -0.3, 0.0, 0.2])

# Another arm: the PD law of arm_torque -- natural frequency (rad/s), amplitude of the commanded sine (a fraction
# of the range, at most 0.2 rad or m) and its frequency (rad/s)
_PD_FREQUENCY = 10.0
_SINE_SHARE, _SINE_MAX, _SINE_FREQUENCY = 0.1, 0.2, 3.0


def worst(*arrays) -> float:
    """The largest absolute value over all arrays; NaN if any entry is NaN (so that ``worst <= tol`` fails)."""
    values = np.concatenate([np.abs(np.ravel(np.asarray(a, dtype=float))) for a in arrays])
    return float(np.max(values)) if values.size else 0.0


def check_torque(t, params: ArmModel) -> np.ndarray:
    """The paper arm's test input (N m, N m, N, N m): sines plus gravity compensation on joint 3 (its masses
    ``m3 + m4`` times ``g``)."""
    return np.array([2.0 * np.sin(3.0 * t), 1.5 * np.cos(2.0 * t),
                     -(params.m3 + params.m4) * params.g + 0.5 * np.sin(5.0 * t), 0.3 * np.sin(t)])


def _middle(arm) -> np.ndarray:
    """The middle of each joint's range (0 for an open range, the finite end plus 0.5 for a half-open one)."""
    def mid(lo: float, hi: float) -> float:
        if math.isfinite(lo) and math.isfinite(hi):
            return 0.5 * (lo + hi)
        if math.isfinite(lo) or math.isfinite(hi):
            return lo + 0.5 if math.isfinite(lo) else hi - 0.5
        return 0.0
    return np.array([mid(lo, hi) for lo, hi in arm.joints.limits])


def arm_torque(arm) -> tuple[np.ndarray, Callable]:
    """The initial state and the torque law ``tau(t, x)`` (N m, N) of another arm's comparison.

    ``tau = G(q) + M(q_m) (w^2 (q_c(t) - q) + 2 w (q_c'(t) - q'))`` with
    ``q_c(t) = q_m + a sin(3 t + i)`` around the middle ``q_m`` of the ranges,
    ``a`` a tenth of each range (at most 0.2 rad or m), ``w = 10 rad/s``: with
    the whole inertia matrix (not its diagonal) every joint, light or heavy,
    follows critically damped at about 10 rad/s -- slow against a 0.01 s
    held step -- so every joint moves and none leaves its range.  The arm
    starts on ``q_c(0)`` with its velocity.
    """
    q_m = _middle(arm)
    span = np.array([hi - lo if math.isfinite(hi - lo) else 2.0 * _SINE_MAX for lo, hi in arm.joints.limits])
    amp = np.minimum(_SINE_SHARE * span, _SINE_MAX)
    phase = np.arange(arm.n, dtype=float)
    m = arm.inertia(q_m)
    kp, kd = _PD_FREQUENCY ** 2, 2.0 * _PD_FREQUENCY
    w = _SINE_FREQUENCY

    def torque(t, x):
        q, dq = x[:arm.n], x[arm.n:]
        q_c = q_m + amp * np.sin(w * t + phase)
        dq_c = amp * w * np.cos(w * t + phase)
        return arm.gravity_forces(q) + m @ (kp * (q_c - q) + kd * (dq_c - dq))

    x0 = np.concatenate((q_m + amp * np.sin(phase), amp * w * np.cos(phase)))
    return x0, torque


@dataclass
class PlantReference:
    """What the comparison needs of the Python side.

    Attributes
    ----------
    arm : blocks.model.arm.ArmModel
    spec : DisturbanceSpec or namespace
        The disturbance models and their parameters (the FMU's start values).
    name : str
        How the report names the arm.
    x0 : numpy.ndarray
        Initial state ``[q; q']``.
    torque : callable
        ``torque(t, x)`` -> the input (N m, N).
    derivatives : callable
        ``derivatives(t, x, u)`` -> ``[q'; q'']`` of the plant without end stops.
    disturbance : callable
        ``disturbance(t, x, u)`` -> ``tau_dis`` (N m, N).
    """

    arm: object
    spec: object
    name: str
    x0: np.ndarray
    torque: Callable
    derivatives: Callable
    disturbance: Callable

    @property
    def states(self) -> list[str]:
        n = self.arm.n
        return [f"q[{i}]" for i in range(n)] + [f"dq[{i}]" for i in range(n)]


def _start_values(model_description) -> dict:
    return {v.name: v.start for v in model_description.modelVariables}




def _spec_from(start: dict, n: int) -> DisturbanceSpec:
    def num(name):
        return float(start[name])

    kinds = tuple(k for k in DISTURBANCE_KINDS if str(start[f"disturbance_{k}"]).lower() in ("true", "1"))
    return DisturbanceSpec(kinds=kinds,
                           **{b: tuple(num(f"{b}[{i}]") for i in range(n)) for b in ("f_r", "coulomb", "viscous")},
                           **{name: num(name) for name in ("friction_velocity", "skin_height", "tissue_stiffness",
                                                           "tissue_damping", "tissue_drag")})


def plant_from_description(model_description) -> tuple[ArmModel, DisturbanceSpec]:
    """The default scenario's arm (the paper's) with the FMU's parameter start values, and its disturbance.

    Raises
    ------
    KeyError
        If the FMU lacks one of the plant's parameters.
    """
    start = _start_values(model_description)
    arm = default_arm()
    robot = arm.with_parameters(**{name: float(start[name]) for name in arm.parameter_names()})
    return robot, _spec_from(start, robot.joints.count)


def plant_reference(model_description, arm=None) -> PlantReference:
    """The Python side of the comparison for a dobkit plant FMU.

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    arm : blocks.model.arm.ArmModel, optional
        The arm to hold the FMU against.  Default: the default scenario's arm
        (the paper's) with the FMU's start values of its parameters (an FMU
        without them: KeyError).  The paper's arm given here is compared with
        its own values, not the FMU's.

    Raises
    ------
    KeyError
        If the FMU lacks a parameter of the plant (not a dobkit plant FMU).
    """
    start = _start_values(model_description)
    from_fmu = arm is None
    if arm is None:
        arm, spec = plant_from_description(model_description)
    else:
        spec = _spec_from(start, arm.n)
    if arm.paper is not None:            # the paper's arm: its own test input and start (its FMU has no record)
        py = python_plant(arm, spec)
        rhs, out, n = fast_dynamics(py), fast_output(py), arm.n
        return PlantReference(arm=arm, spec=spec, name=arm_name(arm) + (" (Table 1 values of the FMU)" if from_fmu
                                                                        else ""), x0=CHECK_INITIAL_STATE.copy(),
                              torque=lambda t, x: check_torque(t, arm), derivatives=rhs,
                              disturbance=lambda t, x, u: np.asarray(out(t, x, u))[2 * n:3 * n])
    if "tissue" in spec.kinds:
        raise ValueError("the FMU has disturbance_tissue switched on; the tissue model needs the paper's arm")
    params = DisturbanceParams(
        paper="paper" in spec.kinds, friction="friction" in spec.kinds, tissue=False,
        f_r=np.array(spec.f_r), coulomb=np.array(spec.coulomb), viscous=np.array(spec.viscous),
        friction_velocity=spec.friction_velocity, skin_height=spec.skin_height,
        tissue_stiffness=spec.tissue_stiffness, tissue_damping=spec.tissue_damping, tissue_drag=spec.tissue_drag,
        kin=np.zeros(0))
    n = arm.n

    def disturbance(t, x, u=None):
        return external_disturbance(arm.arm_kernels, t, x[:n], x[n:], params)

    def derivatives(t, x, u):
        return np.concatenate((x[n:], arm.forward_dynamics(x[:n], x[n:], np.asarray(u) + disturbance(t, x))))

    x0, torque = arm_torque(arm)
    return PlantReference(arm=arm, spec=spec, name=arm_name(arm), x0=x0, torque=torque, derivatives=derivatives,
                          disturbance=disturbance)


def stop_parameters(model_description) -> dict:
    """``stop_stiffness[i]`` and ``stop_damping[i]`` of the FMU -> their start values (empty without end stops)."""
    return {v.name: float(v.start) for v in model_description.modelVariables
            if v.name.startswith(("stop_stiffness[", "stop_damping["))}


def _stops_off(model_description) -> dict:
    return {name: 0.0 for name in stop_parameters(model_description)}


def compare_model_exchange(extracted, ref: PlantReference, t_final: float, tolerance: float, budget: Budget,
                           deadline: Monitor, model_description=None) -> dict:
    """Model Exchange FMU against the Python plant (see the module docstring)."""
    x0, states, n = ref.x0, ref.states, ref.arm.n
    off = _stops_off(model_description) if model_description is not None else {}
    fmu = load(extracted, name="fmu_plant", start_values=dict(zip(states, x0)) | off)
    try:
        t_eval = np.linspace(0.0, t_final, 101)
        labels = list(fmu.output_labels)
        dis = [labels.index(f"tau_dis[{i}]") for i in range(n)]
        sides = {"fmu": (fast_dynamics(fmu), lambda t, x, u, out=fast_output(fmu): np.asarray(out(t, x, u))[dis]),
                 "python": (ref.derivatives, ref.disturbance)}
        runs = {}
        for key, (f, tau_dis) in sides.items():
            rhs = deadline.counted(lambda t, x, f=f: f(t, x, ref.torque(t, x)),
                                   f"the Model Exchange comparison ({key} plant)")
            sol = solve_ivp(rhs, (0.0, t_final), x0, method="DOP853", t_eval=t_eval, rtol=1e-11, atol=1e-12)
            if not sol.success:
                raise FMUError(f"{key} plant: the reference integration failed: {sol.message}")
            outs = np.column_stack([tau_dis(t, sol.y[:, k], ref.torque(t, sol.y[:, k]))
                                    for k, t in enumerate(t_eval)])
            runs[key] = (sol.y, outs)
        state_err = np.abs(runs["fmu"][0] - runs["python"][0]).max(axis=1)
        dis_err = np.abs(runs["fmu"][1] - runs["python"][1]).max(axis=1)
    finally:
        fmu.close()
    largest = worst(state_err, dis_err)
    part = {"t_final": t_final, "max_abs_error": largest, "tolerance": tolerance,
            "passed": bool(largest <= tolerance),
            "max_abs_error_per_state": dict(zip(states, state_err.tolist())),
            "max_abs_error_tau_dis": dis_err.tolist(),
            "method": "SciPy DOP853, rtol 1e-11, atol 1e-12, on both; same torque law and initial state"
                      + ("; the FMU's end stops off" if off else "")}
    if not part["passed"]:
        part["why"] = (f"Model Exchange differs from {ref.name} by {largest:.3g} (tolerance {tolerance:g}): the FMU "
                       "is not this arm's plant, or its parameters differ")
    return part


def _rk4_twin(derivatives, t: float, x: np.ndarray, u: np.ndarray, h: float, substeps: int) -> np.ndarray:
    """One communication step of the FMU's own integrator written again here: classical RK4, ``substeps`` equal
    steps of ``h / substeps``, the input held (``fmu/c/plant_model.c``, ``plant_rk4``)."""
    dt = h / substeps
    for k in range(substeps):
        tk = t + k * dt
        k1 = derivatives(tk, x, u)
        k2 = derivatives(tk + 0.5 * dt, x + 0.5 * dt * k1, u)
        k3 = derivatives(tk + 0.5 * dt, x + 0.5 * dt * k2, u)
        k4 = derivatives(tk + dt, x + dt * k3, u)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def substeps_for(error: float, tolerance: float, substeps: int) -> int:
    """The RK4 sub-steps that bring an integration error ``error`` at ``substeps`` down to ``tolerance``.

    RK4's global error falls as the fourth power of its step, so the step must shrink by
    ``(error / tolerance)^(1/4)``; the answer is at least ``substeps``.

    Examples
    --------
    >>> substeps_for(1.6e-2, 1e-6, 4)
    45
    """
    if not (math.isfinite(error) and error > tolerance > 0):
        return int(substeps)
    return int(math.ceil(substeps * (error / tolerance) ** 0.25))


def compare_co_simulation(extracted, ref: PlantReference, t_final: float, step: float, tolerance: float,
                          deadline: Monitor, model_description=None) -> dict:
    """Co-Simulation FMU against its own integrator run here in Python, and both against the exact solution.

    Each communication step holds the same torque (computed from the exact
    solution's state) for three runs from the same start: the FMU, the same
    classical RK4 with the FMU's ``n_substeps`` written here (:func:`_rk4_twin`),
    and the Python plant integrated exactly (SciPy DOP853, rtol 1e-12).

    * The verdict is the FMU against the RK4 twin (``max_abs_error``): both make
      the same arithmetic, so a difference above ``tolerance`` is an error in
      the FMU's model or its stepping.
    * The exact solution measures the integrator's own error at the chosen
      step (``exact_zoh_error``), which is a property of the step, not of the
      FMU: a stiff arm (light links, joint damping: a fast mode of hundreds of
      1/s) needs more sub-steps.  Above ``tolerance`` it is a finding with the
      sub-steps that would meet it (RK4's error falls as the step^4,
      :func:`substeps_for`), not a failure.
    """
    x0, states, n = ref.x0, ref.states, ref.arm.n
    off = _stops_off(model_description) if model_description is not None else {}
    steps = max(1, int(round(t_final / step)))
    x_ref = x0.copy()
    x_twin = x0.copy()
    with FMUInstance(extracted, kind="CoSimulation", start_values=dict(zip(states, x0)) | off) as fmu:
        in_vr = fmu.value_references([f"tau[{i}]" for i in range(n)])
        out_vr = fmu.value_references(states)
        substeps = fmu.get_integer("n_substeps")
        twin_err = 0.0
        for k in range(steps):
            t = k * step
            u = np.asarray(ref.torque(t, x_ref), dtype=float)
            fmu.set_real(in_vr, u)
            fmu.do_step(t, step)
            x_twin = _rk4_twin(ref.derivatives, t, x_twin, u, step, substeps)
            twin_err = max(twin_err, worst(fmu.get_real(out_vr) - x_twin)) if np.isfinite(twin_err) else twin_err
            sol = solve_ivp(lambda tt, x: ref.derivatives(tt, x, u), (t, t + step), x_ref, method="DOP853",
                            rtol=1e-12, atol=1e-13)
            x_ref = sol.y[:, -1]
            if k % 100 == 0:
                deadline.check_time(where=f"Co-Simulation comparison at t = {t:.6g} s")
        x_fmu = fmu.get_real(out_vr)
    exact = worst(x_fmu - x_ref)
    twin_err = max(twin_err, worst(x_fmu - x_twin)) if np.isfinite(twin_err) else twin_err
    part = {"t_final": steps * step, "step": step, "n_substeps": substeps, "max_abs_error": twin_err,
            "tolerance": tolerance, "passed": bool(twin_err <= tolerance), "exact_zoh_error": exact,
            "exact_zoh_within_tolerance": bool(exact <= tolerance),
            "method": "torque held over each step; verdict: the FMU against the same classical RK4 "
                      f"({substeps} sub-steps) run in Python; its integration error: against SciPy DOP853 rtol "
                      "1e-12 per step" + ("; the FMU's end stops off" if off else "")}
    if not part["passed"]:
        part["why"] = (f"Co-Simulation differs from the same RK4 on {ref.name} by {twin_err:.3g} (tolerance "
                       f"{tolerance:g}): the FMU's model or stepping is not the Python plant's")
    elif not part["exact_zoh_within_tolerance"]:
        need = substeps_for(exact, tolerance, substeps)
        part["finding"] = (f"its RK4 ({substeps} sub-steps of {step / substeps:.3g} s) is {exact:.3g} off the exact "
                           f"solution (tolerance {tolerance:g}), the integrator's error at this step, not the model's: "
                           f"the arm has modes too fast for it; export with --substeps {need} (the error falls as the "
                           "sub-step^4) or check with a smaller --cs-step")
    return part


def _stop_force(q: float, dq: float, lo: float, hi: float, k: float, c: float) -> float:
    """The end-stop law of :mod:`fmu.end_stops`, written again from its definition."""
    if q > hi:
        return min(0.0, -k * (q - hi) - c * dq)
    if q < lo:
        return max(0.0, k * (lo - q) - c * dq)
    return 0.0


def compare_end_stops(extracted, ref: PlantReference, model_description, tolerance: float = 1e-9) -> dict:
    """The FMU's state derivative beyond each bounded joint's range against the reference plus the stop force.

    At each finite end of each bounded joint: 2 % of the range (or 0.01 rad, m) beyond it, moving outwards
    (the stop pushes back) and inwards at twice ``k depth / c`` (the damper outpulls the spring: the stop
    lets go), with the other joints at the comparison's
    initial state and the torque of its law.  ``max_rel_error`` is relative to ``max(1, max |q''|)``.
    """
    stops = stop_parameters(model_description)
    arm, n = ref.arm, ref.arm.n
    joints = [i for i in range(n) if f"stop_stiffness[{i}]" in stops]
    if not joints:
        return {"skipped": "the FMU has no end stops"}
    rows, largest = [], 0.0
    with FMUInstance(extracted, kind="ModelExchange") as fmu:
        taus = fmu.value_references([f"tau[{i}]" for i in range(n)])
        for i in joints:
            lo, hi = arm.joints.limits[i]
            k, c = stops[f"stop_stiffness[{i}]"], stops[f"stop_damping[{i}]"]
            depth = 0.02 * (hi - lo) if math.isfinite(hi - lo) else 0.01
            for end, sign in ((hi, 1.0), (lo, -1.0)):
                if not math.isfinite(end):
                    continue
                # outwards: pushed back; inwards twice as fast as the damper takes to outpull the spring: let go
                for speed in (0.5, -2.0 * k * depth / c if c > 0 else -2.0):
                    x = ref.x0.copy()
                    x[i], x[n + i] = end + sign * depth, sign * speed
                    u = ref.torque(0.0, x)
                    fmu.set_time(0.0)
                    fmu.set_states(x)
                    fmu.set_real(taus, u)
                    got = fmu.derivatives()
                    push = np.zeros(n)
                    push[i] = _stop_force(x[i], x[n + i], lo, hi, k, c)
                    want = ref.derivatives(0.0, x, u + push)
                    scale = max(1.0, float(np.max(np.abs(want[n:]))))
                    err = worst(got - want) / scale
                    largest = max(largest, err) if not math.isnan(err) else math.nan
                    rows.append({"joint": arm.joints.names[i], "q": float(x[i]), "dq": float(x[n + i]),
                                 "stop_force": float(push[i]), "max_rel_error": err})
    passed = bool(largest <= tolerance)
    part = {"max_rel_error": largest, "tolerance": tolerance, "passed": passed, "states": rows,
            "method": "Model Exchange derivatives beyond the ranges vs the reference under tau + the stop force "
                      "min(0, -k (q - upper) - c q') / max(0, k (lower - q) - c q')"}
    if not passed:
        part["why"] = f"the end stops differ from their definition by {largest:.3g} (relative; tolerance {tolerance:g})"
    return part
