"""The plant FMU's maths, generated from the plant block's kernels (:mod:`blocks.engines.compiled.c_backend`).

:func:`plant_c` traces the plant block of :func:`blocks.diagram.systems.plant` --
the arm's ``plant_acceleration`` and the external disturbance models -- and
writes ``plant_generated.h``: the state derivative and ``tau_dis`` as C, the
same operations as the numpy kernels and the compiled engine's numba code.
``plant_model.c`` includes it and keeps only what is not maths (RK4 stepping,
the input hold, the status codes).

The disturbance switches (``disturbance_paper`` ...) are structure to the
trace, yet the FMU lets the user flip them before initialization: ``tau_dis``
is generated for each combination and the C picks one by the switches' bit
mask; the dynamics, which the disturbance reaches only through the force
``u + tau_dis``, are generated once.  The numbers the trace lifts (``theta``) are computed from
the FMU's tunable parameters by ``plant_theta`` (for the paper's arm the Table-1
parameters through the traced ``k1..k5`` of Eq. 5-7), so changing a parameter
at simulation time needs no new code; structure that is frozen in an arm
(a URDF arm's geometry) would stay a constant in the text.

Generated (all ``static``, one header per export)::

    N_JOINTS, N_THETA, N_CALCULATED, N_MODEL_COMBOS
    plant_theta(const double *p, double *theta)               theta from the real parameters p[P_*]
    plant_calculated(const double *p, double *out)            calculated parameters (k1..k5)
    plant_dynamics(t, x, f, theta, dx)                         [dq; q''] of Eq. 1 under the force f
    plant_update(mask, t, x, u, theta, dx)                     the same with f = u + tau_dis
    PLANT_TAU_DIS[mask](t, x, u, theta, tau_dis)               the acting disturbance
    plant_arm_valid(p, sw, msg, size)                        the arm's own parameter check
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from blocks.diagram.contract import Kernels, contract_of
from blocks.diagram.systems import plant as plant_block
from blocks.diagram.systems import plant_output, plant_update
from blocks.engines.compiled.c_backend import C_PRELUDE, CodegenError, emit_c_function, trace_block
from blocks.kernels.disturbance import DisturbanceParams
from blocks.kernels.model import with_arm
from blocks.kernels.trace import Graph, Sym, param_values
from blocks.model.disturbances import DISTURBANCE_KINDS, DisturbanceSpec

__all__ = ["GeneratedPlant", "plant_c", "plant_kernels", "arm_disturbance", "GENERATED_HEADER"]

#: The file name of the generated maths inside the FMU's ``sources/``.
GENERATED_HEADER = "plant_generated.h"

_KERNEL_ARGS = "double t, const double *x, const double *u, const double *theta, double *out"


@dataclass(frozen=True)
class GeneratedPlant:
    """The generated C of one plant export and what it is made of.

    Attributes
    ----------
    text : str
        The header ``plant_generated.h``.
    n_joints, n_theta, n_calculated : int
        Joints of the arm, numbers the code reads, calculated parameters.
    calculated : tuple of (name, unit, description)
        The calculated parameters ``plant_calculated`` gives (k1..k5 for the paper's arm).
    functions : int
        C functions in the text.
    theta_names : tuple of str
        What each entry of ``theta`` is.
    """

    text: str
    n_joints: int
    n_theta: int
    n_calculated: int
    calculated: tuple
    functions: int
    theta_names: tuple


# --------------------------------------------------------------------------------------------------------------
# The plant's kernels for any arm
# --------------------------------------------------------------------------------------------------------------
def arm_disturbance(arm, disturbance: DisturbanceSpec | None, q0=None):
    """The disturbance settings of a plant export, per joint of ``arm``.

    For the paper's arm: the :class:`~blocks.model.disturbances.DisturbanceSpec`
    itself (default: Eq. 4).  For another arm: its per-joint vectors must have
    one entry per joint; without one, every model is off and the amplitudes
    are zero (start values the user sets on the FMU), and the skin plane of
    the tissue contact goes through the tool point at the start pose ``q0``
    (default: the export's start pose), as a scenario of that arm places it.

    Raises
    ------
    ValueError
        On vectors of the wrong length or a model of the paper's arm only (none today) on another arm.
    """
    if arm.paper is not None:                 # the paper's arm: its Eq. 4 by default
        return DisturbanceSpec() if disturbance is None else disturbance
    n = arm.joints.count
    base = DisturbanceSpec()
    if disturbance is None:
        start = np.zeros(n) if q0 is None else np.asarray(q0, dtype=float)
        skin = float(arm.tool_position(start)[2])
        return SimpleNamespace(kinds=(), f_r=(0.0,) * n, coulomb=(0.0,) * n, viscous=(0.0,) * n,
                               friction_velocity=base.friction_velocity, skin_height=skin,
                               tissue_stiffness=base.tissue_stiffness, tissue_damping=base.tissue_damping,
                               tissue_drag=base.tissue_drag)
    for name in ("f_r", "coulomb", "viscous"):
        if len(getattr(disturbance, name)) != n:
            raise ValueError(f"disturbance.{name} has {len(getattr(disturbance, name))} entries; the arm has {n} "
                             "joints")
    return disturbance


def _disturbance_params(d, tissue_kin) -> DisturbanceParams:
    return DisturbanceParams(
        paper="paper" in d.kinds, friction="friction" in d.kinds, tissue="tissue" in d.kinds,
        f_r=np.array(d.f_r, dtype=float), coulomb=np.array(d.coulomb, dtype=float),
        viscous=np.array(d.viscous, dtype=float), friction_velocity=float(d.friction_velocity),
        skin_height=float(d.skin_height), tissue_stiffness=float(d.tissue_stiffness),
        tissue_damping=float(d.tissue_damping), tissue_drag=float(d.tissue_drag), kin=tissue_kin)


def plant_kernels(arm, d) -> Kernels:
    """The plant's kernels: ``update`` gives ``[dq; q'']`` of Eq. 1, ``output`` ``[q; dq; tau_dis]``.

    The paper's arm uses the plant block's own kernels (:func:`blocks.diagram.systems.plant`); another arm the same
    block kernels called with its row kernels (``arm.arm_kernels``: its ``plant_acceleration`` and the tool
    point of the tissue contact), its geometry a frozen parameter (constants in the generated code).
    """
    if arm.stacks_constants:                  # its numbers are the FMU's parameters: the plant block's own kernels
        return contract_of(plant_block(arm, d)).kernels
    # the tool parameters are frozen (structure, like the dynamics'): the trace reads no number from them
    return Kernels((arm.kernel_params(), _disturbance_params(d, arm.tool_params())), with_arm(plant_output, arm),
                   with_arm(plant_update, arm))


# --------------------------------------------------------------------------------------------------------------
# The arm's parameter map: theta (what the trace lifted) as expressions of the FMU's real parameters
# --------------------------------------------------------------------------------------------------------------
#: SI units of calculated constants as the FMU's unit definitions write them
_FMU_UNITS = {"kg m^2": "kg.m2", "kg": "kg"}

#: plant_arm_valid of an arm whose numbers are fixed (nothing to check)
_NOTHING_TO_CHECK = """    (void)p;
    (void)sw;
    (void)msg;
    (void)msg_size;
    return 1;
"""


def _c_text(text: str) -> str:
    return text.replace("\\", "\\\\").replace('"', '\\"')


def _validity_check(margins: list) -> str:
    """The body of ``plant_arm_valid`` for the arm's validity margins (``plant_margins``: each > 0 on a valid arm)."""
    texts = ", ".join(f'"{_c_text(text)}"' for _, text in margins)
    return f"""    static const char *const CONDITION[{len(margins)}] = {{{texts}}};
    double margin[{len(margins)}];
    int i;
    (void)sw;
    plant_margins(p, margin);
    for (i = 0; i < {len(margins)}; i++) {{
        if (!(margin[i] > 0.0)) {{
            snprintf(msg, msg_size, "parameters break the arm's condition %s (its margin is %g, must be > 0)",
                     CONDITION[i], margin[i]);
            return 0;
        }}
    }}
    return 1;
"""


def _theta_expressions(arm, spec: DisturbanceSpec, params, p: dict, graph: Graph) -> tuple[list, list, list]:
    """theta as expressions of ``p`` in the order the plant block's trace reads them; the calculated constants; the
    arm's validity margins (:meth:`blocks.model.arm.ArmModel.exported_parameter_map`)."""
    mapped = arm.exported_parameter_map({name: p[name] for name in arm.parameter_names()})
    if mapped is not None:
        arm_theta, kin, calculated, margins = mapped
        calculated = [(name, _FMU_UNITS.get(unit, unit), text, expr) for name, unit, text, expr in calculated]
    else:
        # geometry, inertias and the tool point are frozen (literals in the code): only the disturbance numbers
        # are tunable
        arm_theta, kin, calculated, margins = [], [], [], []
    theta = list(arm_theta)
    dist = params[1]
    for name in DisturbanceParams._fields:
        value = getattr(dist, name)
        if isinstance(value, (bool, np.bool_)):
            continue
        if name == "kin":
            theta += kin                # the tissue model's lengths (none for an arm whose tool point is frozen)
        elif isinstance(value, np.ndarray):
            theta += [p[f"{name}[{i}]"] for i in range(value.size)]
        else:
            theta.append(p[name])
    return theta, calculated, margins


def _evaluate(expr, values: dict) -> float:
    """A traced expression of the parameters on numbers, with Python floats (for the export's self-check)."""
    if not isinstance(expr, Sym):
        return float(expr)
    if expr.op == "const":
        return float(expr.args[0])
    if expr.op == "leaf":
        return values[expr.args[1]]
    if expr.op == "bin" and expr.args[0] in "+-*/":
        a, b = (_evaluate(v, values) for v in expr.args[1:])
        return {"+": a + b, "-": a - b, "*": a * b, "/": a / b}[expr.args[0]]
    if expr.op == "call" and expr.args[0] == "negative":
        return -_evaluate(expr.args[1], values)
    raise CodegenError(f"a parameter expression uses {expr.op} {expr.args[0]!r}, which the export cannot check")


# --------------------------------------------------------------------------------------------------------------
# The header
# --------------------------------------------------------------------------------------------------------------
def plant_c(arm, spec: DisturbanceSpec, param_order: list[str], start: dict) -> GeneratedPlant:
    """Generate ``plant_generated.h`` for an arm and its disturbance models.

    Parameters
    ----------
    arm : blocks.model.arm.ArmModel
        The true arm (its joint count sizes everything).
    spec : DisturbanceSpec
        Disturbance parameters; every combination of the models is generated.
    param_order : list of str
        The FMU's real parameters in ``PlantData.p`` order (their variable names).
    start : dict
        Their start values, to check that ``plant_theta`` gives the trace's numbers.

    Raises
    ------
    CodegenError
        If the arm has no parameter map, a kernel cannot be traced, or the
        generated parameter map disagrees with the block's own numbers.
    """
    n = arm.joints.count
    nx, nu = 2 * n, n
    graph = Graph()
    p = {name: graph.leaf("p", j) for j, name in enumerate(param_order)}
    base = plant_kernels(arm, spec)
    theta_exprs, calculated, margins = _theta_expressions(arm, spec, base.params, p, graph)
    expected = param_values(base.params, [])
    if len(theta_exprs) != len(expected):
        raise CodegenError(f"the parameter map gives {len(theta_exprs)} numbers, the plant's trace reads "
                           f"{len(expected)}")
    got = [_evaluate(e, {j: float(start[name]) for j, name in enumerate(param_order)}) for e in theta_exprs]
    bad = [j for j, (a, b) in enumerate(zip(got, expected)) if not abs(a - b) <= 1e-15 * max(abs(b), 1.0)]
    if bad:
        raise CodegenError(f"the parameter map disagrees with the plant's numbers at theta{bad}")

    parts = [f"/* {GENERATED_HEADER}: the plant's maths for one export, generated by fmu.generated from the "
             "kernels of blocks; do not edit. */",
             "#ifndef DOBKIT_PLANT_GENERATED_H", "#define DOBKIT_PLANT_GENERATED_H", "", "#include <stdio.h>",
             C_PRELUDE, f"#define N_JOINTS {n}", f"#define N_THETA {len(theta_exprs)}",
             f"#define N_CALCULATED {len(calculated)}", f"#define N_MODEL_COMBOS {2 ** len(DISTURBANCE_KINDS)}",
             "#if NX != 2 * N_JOINTS || NU != N_JOINTS", "#error plant_config.h and plant_generated.h disagree",
             "#endif", ""]
    leaves = {"p": "p[{i}]"}
    parts.append(emit_c_function("plant_theta", theta_exprs, leaves, "const double *p, double *out", static=True))
    parts.append(emit_c_function("plant_calculated", [c[3] for c in calculated] or [], leaves,
                                 "const double *p, double *out", static=True) if calculated else
                 "static void plant_calculated(const double *p, double *out)\n{\n    (void)p;\n    (void)out;\n}\n")
    if margins:
        parts.append(emit_c_function("plant_margins", [m for m, _ in margins], leaves, "const double *p, double *out",
                                     static=True))
    functions = 2
    # the dynamics once: the disturbance enters only through the force u + tau_dis (Eq. 1), so the plant with
    # models on is this function of u + tau_dis, operation for operation
    dynamics = trace_block(plant_kernels(arm, _with_kinds(spec, ())), nx, nu, ("update",), ("k", "disturbance"))
    if list(dynamics.theta) != expected:
        raise CodegenError("the plant without disturbance models reads other numbers than the export's")
    theta_names = tuple(dynamics.theta_names)
    parts.append("/* Eq. 1 under the total force u (N m, N): [dq; M(q)^-1 (u - h(q, dq))] */")
    parts.append(emit_c_function("plant_dynamics", dynamics.rows["update"], args=_KERNEL_ARGS, static=True))
    functions += 1
    for mask, kinds in enumerate(_combinations()):
        trace = trace_block(plant_kernels(arm, _with_kinds(spec, kinds)), nx, nu, ("output",),
                            ("k", "disturbance"))
        if list(trace.theta) != expected:
            raise CodegenError(f"the plant with disturbance models {kinds} reads other numbers than the export's")
        parts.append(f"/* tau_dis of the disturbance models: {', '.join(kinds) or 'none'} */")
        parts.append(emit_c_function(f"plant_tau_dis_{mask}", trace.rows["output"][nx:], args=_KERNEL_ARGS,
                                     static=True))
        functions += 1
    combos = list(range(2 ** len(DISTURBANCE_KINDS)))
    parts += ["typedef void (*PlantKernel)(double, const double *, const double *, const double *, double *);",
              "static const PlantKernel PLANT_TAU_DIS[N_MODEL_COMBOS] = {"
              + ", ".join(f"plant_tau_dis_{m}" for m in combos) + "};", "",
              "/* [dq; q''] with the disturbance models of bit mask `mask` (bit j: switch j) acting */",
              "static void plant_update(int mask, double t, const double *x, const double *u, const double *theta, "
              "double *dx)\n{\n"
              "    double tau_dis[N_JOINTS], force[N_JOINTS];\n    int i;\n"
              "    if (mask == 0) {\n        plant_dynamics(t, x, u, theta, dx);\n        return;\n    }\n"
              "    PLANT_TAU_DIS[mask](t, x, u, theta, tau_dis);\n"
              "    for (i = 0; i < N_JOINTS; i++) force[i] = u[i] + tau_dis[i];\n"
              "    plant_dynamics(t, x, force, theta, dx);\n}\n",
              "/* the arm's own check of its parameters (beyond the ranges of each one) */",
              "static int plant_arm_valid(const double *p, const int *sw, char *msg, unsigned long msg_size)\n{\n"
              + (_validity_check(margins) if margins else _NOTHING_TO_CHECK) + "}\n",
              "#endif", ""]
    functions += 1
    functions += 1
    return GeneratedPlant(text="\n".join(parts), n_joints=n, n_theta=len(theta_exprs), n_calculated=len(calculated),
                          calculated=tuple(c[:3] for c in calculated), functions=functions,
                          theta_names=theta_names)


def _with_kinds(spec, kinds: tuple):
    if isinstance(spec, DisturbanceSpec):
        return replace(spec, kinds=kinds)
    return SimpleNamespace(**(vars(spec) | {"kinds": kinds}))


def _combinations() -> list[tuple]:
    """Every subset of the disturbance models, the subset of bit mask m at index m (bit j: DISTURBANCE_KINDS[j])."""
    kinds = tuple(DISTURBANCE_KINDS)
    out = []
    for mask in range(2 ** len(kinds)):
        out.append(tuple(k for j, k in enumerate(kinds) if mask >> j & 1))
    return out
