"""The variables of the exported plant FMU: one table for the XML and the C code.

The table fixes each variable's value reference, type, causality, unit and
start value.  :func:`config_header` writes the matching ``plant_config.h``
for the C sources, and :mod:`fmu.modeldescription` writes
``modelDescription.xml`` from the same table, so the two cannot disagree.

Value references are unique across types (required by FMI 3, allowed by
FMI 2) and laid out in blocks::

    0        time
    1..      q[0..n-1], dq[0..n-1]      continuous states, outputs (n joints of the arm; below n = 4);
                                        q[i] carries the joint's range as min/max
    9..16    der(q[i]), der(dq[i])      state derivatives
    17..20   tau[0..3]                  inputs
    21..24   tau_dis[0..3]              outputs
    25..29   k1..k5                     calculated parameters (Eq. 5-7)
    30..61   Table-1 and disturbance parameters
    62..63   stop_stiffness[2], stop_damping[2]   end stop of each bounded joint (:mod:`fmu.end_stops`)
    64       n_substeps                 Co-Simulation RK4 sub-steps per step
    65..67   disturbance_paper, disturbance_friction, disturbance_tissue
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from blocks.model.arm import ArmModel
from blocks.model.disturbances import DisturbanceSpec

__all__ = ["Variable", "UNITS", "plant_variables", "plant_parameter_values", "config_header", "JOINT_UNITS"]

# FMI unit name -> exponents of the SI base units (and rad)
UNITS: dict[str, dict[str, int]] = {
    "s": {"s": 1},
    "m": {"m": 1},
    "rad": {"rad": 1},
    "m/s": {"m": 1, "s": -1},
    "rad/s": {"rad": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s2": {"rad": 1, "s": -2},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
}

# Units per joint for each per-joint quantity (revolute, revolute, prismatic, revolute)
JOINT_UNITS = {
    "q": ("rad", "m"), "dq": ("rad/s", "m/s"), "ddq": ("rad/s2", "m/s2"),
    "force": ("N.m", "N"), "viscous": ("N.m.s/rad", "N.s/m"), "stiffness": ("N.m/rad", "N/m"),
}

#: FMI unit names of an arm parameter's SI unit
_ROBOT_UNITS = {"kg": "kg", "m": "m", "kg m^2": "kg.m2", "m/s^2": "m/s2"}

@dataclass(frozen=True)
class Variable:
    """One scalar FMU variable.

    Attributes
    ----------
    name : str
        Structured name, identical to the Python signal or parameter name.
    vr : int
        Value reference (unique across types).
    type : {"Real", "Integer", "Boolean"}
        FMI 2 type name (FMI 3: Float64, Int32, Boolean).
    causality, variability : str
        FMI causality and variability.
    initial : str or None
        FMI ``initial`` attribute (None: not written).
    start : float, int, bool or None
        Start value (None: no start value).
    unit : str or None
        Unit name, one of :data:`UNITS`.
    description : str
    derivative_of : str or None
        For a state derivative, the name of its state.
    c_name : str or None
        Index name in the C code (``P_<c_name>``) for real parameters.
    positive, nonnegative : bool
        Range the FMU checks when it leaves initialization mode.
    min, max : float or None
        FMI ``min`` / ``max`` attributes (None: not written): a joint position's range.
    """

    name: str
    vr: int
    type: str
    causality: str
    variability: str
    initial: str | None
    start: float | int | bool | None
    unit: str | None
    description: str
    derivative_of: str | None = None
    c_name: str | None = None
    positive: bool = False
    nonnegative: bool = False
    min: float | None = None
    max: float | None = None


def _joint_unit(kind: str, i: int, joints) -> str:
    """The unit of a per-joint quantity on joint ``i``, by the joint's kind (revolute or prismatic)."""
    revolute, prismatic = JOINT_UNITS[kind]
    return prismatic if joints.kinds[i] == "prismatic" else revolute


def plant_variables(params: ArmModel, disturbance: DisturbanceSpec, substeps: int,
                    q0=None, dq0=None, stops=()) -> list[Variable]:
    """The variable table of the plant FMU, ordered by value reference.

    Parameters
    ----------
    params : blocks.model.arm.ArmModel
        The true arm.  Its named parameters (:meth:`~blocks.model.arm.ArmModel.parameter_names`, the paper's
        Table 1) become tunable parameters, with the constants it calculates from them
        (:meth:`~blocks.model.arm.ArmModel.calculated_parameters`, the paper's k1..k5); an arm without named
        parameters has its geometry frozen in the generated C, and only its joint count and kinds shape
        the table.
    disturbance : DisturbanceSpec or namespace
        Selected disturbance models and their parameters (start values), one
        entry per joint (see :func:`fmu.generated.arm_disturbance`).
    substeps : int
        Start value of ``n_substeps`` (RK4 steps per Co-Simulation step), >= 1.
    q0, dq0 : n floats, optional
        Start values of the states (rad, m; rad/s, m/s); zero by default.
    stops : sequence of fmu.end_stops.EndStop
        End stops: each adds ``stop_stiffness[i]`` and ``stop_damping[i]`` with its values as start values.
        The joint ranges (``min`` / ``max`` of ``q[i]``) come from ``params.joints`` with or without them.
    """
    joints = params.joints
    n = joints.count
    q0 = [0.0] * n if q0 is None else [float(v) for v in q0]
    dq0 = [0.0] * n if dq0 is None else [float(v) for v in dq0]
    rows: list[Variable] = []

    def add(**kw) -> None:
        rows.append(Variable(vr=len(rows), **kw))

    add(name="time", type="Real", causality="independent", variability="continuous", initial=None, start=None,
        unit="s", description="simulation time")
    for sig, x0, kind, text in (("q", q0, "q", "joint position"), ("dq", dq0, "dq", "joint velocity")):
        for i in range(n):
            lo, hi = joints.limits[i] if sig == "q" else (-math.inf, math.inf)
            rng = f", range {lo:g} to {hi:g} {joints.position_units[i]}" if sig == "q" and (
                math.isfinite(lo) or math.isfinite(hi)) else ""
            add(name=f"{sig}[{i}]", type="Real", causality="output", variability="continuous", initial="exact",
                start=x0[i], unit=_joint_unit(kind, i, joints),
                description=f"{text} {i + 1}, {joints.names[i]} (state{rng})",
                min=lo if math.isfinite(lo) else None, max=hi if math.isfinite(hi) else None)
    for sig, kind in (("q", "dq"), ("dq", "ddq")):
        for i in range(n):
            add(name=f"der({sig}[{i}])", type="Real", causality="local", variability="continuous",
                initial="calculated", start=None, unit=_joint_unit(kind, i, joints),
                description=f"time derivative of {sig}[{i}]", derivative_of=f"{sig}[{i}]")
    for i in range(n):
        add(name=f"tau[{i}]", type="Real", causality="input", variability="continuous", initial=None, start=0.0,
            unit=_joint_unit("force", i, joints), description=f"actuator force of joint {i + 1}")
    for i in range(n):
        add(name=f"tau_dis[{i}]", type="Real", causality="output", variability="continuous",
            initial="calculated", start=None, unit=_joint_unit("force", i, joints),
            description=f"external disturbance on joint {i + 1} (sum of the selected models)")
    for name, unit, text in params.calculated_parameters():
        add(name=name, type="Real", causality="calculatedParameter", variability="fixed", initial="calculated",
            start=None, unit=_ROBOT_UNITS[unit], description=text)

    for name, value in params.parameter_values().items():
        add(name=name, type="Real", causality="parameter", variability="fixed", initial="exact",
            start=value, unit=_ROBOT_UNITS[params.parameter_unit(name)],
            description=params.parameter_description(name), c_name=name, positive=params.parameter_positive(name))
    d = disturbance
    for base, values, kind, text, nonneg in (
            ("f_r", d.f_r, "force", "Eq. 4 step amplitude", False),
            ("coulomb", d.coulomb, "force", "Coulomb friction level", True),
            ("viscous", d.viscous, "viscous", "viscous friction coefficient", True)):
        for i in range(n):
            add(name=f"{base}[{i}]", type="Real", causality="parameter", variability="fixed", initial="exact",
                start=float(values[i]), unit=_joint_unit(kind, i, joints), description=f"{text}, joint {i + 1}",
                c_name=f"{base}_{i}", nonnegative=nonneg)
    # friction_velocity scales rad/s on revolute joints and m/s on the prismatic one: no single unit
    add(name="friction_velocity", type="Real", causality="parameter", variability="fixed", initial="exact",
        start=d.friction_velocity, unit=None, c_name="friction_velocity", positive=True,
        description="smoothing velocity v_s of the Coulomb term tanh(dq/v_s): rad/s on revolute joints, "
                    "m/s on the prismatic joint")
    for name, unit, text, nonneg in (
            ("skin_height", "m", "height of the skin plane in the base frame", False),
            ("tissue_stiffness", "N/m", "normal stiffness of the tissue", True),
            ("tissue_damping", "N.s/m", "normal damping of the tissue", True),
            ("tissue_drag", "N.s/m", "in-plane viscous drag below the skin", True)):
        add(name=name, type="Real", causality="parameter", variability="fixed", initial="exact",
            start=float(getattr(d, name)), unit=unit, description=text, c_name=name, nonnegative=nonneg)
    for stop in stops:
        i = stop.joint
        add(name=f"stop_stiffness[{i}]", type="Real", causality="parameter", variability="fixed", initial="exact",
            start=float(stop.stiffness), unit=_joint_unit("stiffness", i, joints), c_name=f"stop_stiffness_{i}",
            nonnegative=True, description=f"end-stop stiffness of {joints.names[i]} beyond its range")
        add(name=f"stop_damping[{i}]", type="Real", causality="parameter", variability="fixed", initial="exact",
            start=float(stop.damping), unit=_joint_unit("viscous", i, joints), c_name=f"stop_damping_{i}",
            nonnegative=True, description=f"end-stop damping of {joints.names[i]} beyond its range")
    add(name="n_substeps", type="Integer", causality="parameter", variability="fixed", initial="exact",
        start=int(substeps), unit=None,
        description="Co-Simulation: classical RK4 steps per communication step")
    for kind in ("paper", "friction", "tissue"):
        add(name=f"disturbance_{kind}", type="Boolean", causality="parameter", variability="fixed",
            initial="exact", start=kind in d.kinds, unit=None,
            description=f"switch on the '{kind}' disturbance model")
    return rows


def plant_parameter_values(params: ArmModel, disturbance: DisturbanceSpec) -> dict:
    """FMU parameter name -> value for a Python parameter set (the plant FMU's naming).

    Examples
    --------
    >>> from blocks import load_scenario
    >>> values = plant_parameter_values(load_scenario("paper").robot, DisturbanceSpec(kinds=("friction",)))
    >>> values["m1"], values["coulomb[2]"], values["disturbance_friction"], values["disturbance_paper"]
    (5.58, 0.5, True, False)
    """
    # an arm without named parameters has its geometry as constants in the C
    values: dict = params.parameter_values()
    for base in ("f_r", "coulomb", "viscous"):
        for i, v in enumerate(getattr(disturbance, base)):
            values[f"{base}[{i}]"] = float(v)
    for name in ("friction_velocity", "skin_height", "tissue_stiffness", "tissue_damping", "tissue_drag"):
        values[name] = float(getattr(disturbance, name))
    for kind in ("paper", "friction", "tissue"):
        values[f"disturbance_{kind}"] = kind in disturbance.kinds
    return values


def _c_double(value: float) -> str:
    return repr(float(value))


def _stop_lines(variables: list[Variable], n: int) -> list[str]:
    """``plant_config.h`` lines of the end stops: the bounded joints, their ranges and parameter indices.

    A stop acts on the joint ``q[i]`` whose ``stop_stiffness[i]`` is in the table, between the ``min`` and
    ``max`` of ``q[i]`` (an open side: no stop there).
    """
    by_name = {v.name: v for v in variables}
    joints = [i for i in range(n) if f"stop_stiffness[{i}]" in by_name]
    lines = ["", "/* end stops (fmu.end_stops): joint, range (an open side has HAS_* 0), parameter indices */",
             f"#define N_STOPS {len(joints)}"]
    if not joints:
        return lines
    q = [by_name[f"q[{i}]"] for i in joints]

    def row(values) -> str:
        return "{" + ", ".join(values) + "}"

    lines += [f"#define STOP_JOINT {row(str(i) for i in joints)}",
              f"#define STOP_HAS_LOWER {row(str(int(v.min is not None)) for v in q)}",
              f"#define STOP_HAS_UPPER {row(str(int(v.max is not None)) for v in q)}",
              f"#define STOP_LOWER {row(_c_double(v.min if v.min is not None else 0.0) for v in q)}",
              f"#define STOP_UPPER {row(_c_double(v.max if v.max is not None else 0.0) for v in q)}",
              f"#define STOP_STIFFNESS {row(f'P_stop_stiffness_{i}' for i in joints)}",
              f"#define STOP_DAMPING {row(f'P_stop_damping_{i}' for i in joints)}"]
    return lines


def config_header(variables: list[Variable], token: str) -> str:
    """The text of ``plant_config.h``: value references, parameter indices and start values.

    Parameters
    ----------
    variables : list of Variable
        The table from :func:`plant_variables`.
    token : str
        The GUID / instantiationToken compiled into the binary.
    """
    by_name = {v.name: v for v in variables}
    params = [v for v in variables if v.c_name is not None]
    first_param = params[0].vr
    if [v.vr for v in params] != list(range(first_param, first_param + len(params))):
        raise AssertionError("real parameters must have consecutive value references")

    def vr(name: str) -> int:
        return by_name[name].vr

    n = sum(1 for v in variables if v.causality == "input")     # one torque per joint
    calculated = [v for v in variables if v.causality == "calculatedParameter"]
    if [v.vr for v in calculated] != list(range(calculated[0].vr, calculated[0].vr + len(calculated))) \
            if calculated else False:
        raise AssertionError("calculated parameters must have consecutive value references")

    lines = [
        "/* plant_config.h: written by fmu.export for one export; do not edit. */",
        "#ifndef DOBKIT_PLANT_CONFIG_H", "#define DOBKIT_PLANT_CONFIG_H", "",
        f'#define PLANT_TOKEN "{token}"', "",
        f"#define NX {2 * n}", f"#define NU {n}", f"#define N_VARIABLES {len(variables)}",
        f"#define VR_TIME {vr('time')}", f"#define VR_Q {vr('q[0]')}", f"#define VR_DQ {vr('dq[0]')}",
        f"#define VR_DER_Q {vr('der(q[0])')}", f"#define VR_TAU {vr('tau[0]')}",
        f"#define VR_TAU_DIS {vr('tau_dis[0]')}", f"#define VR_K {calculated[0].vr if calculated else 0}",
        f"#define N_CALCULATED_PARAMS {len(calculated)}",
        f"#define VR_PARAM {first_param}", f"#define N_PARAMS {len(params)}",
        f"#define VR_N_SUBSTEPS {vr('n_substeps')}", f"#define VR_SWITCH {vr('disturbance_paper')}",
        "#define N_SWITCHES 3", "#define SW_PAPER 0", "#define SW_FRICTION 1", "#define SW_TISSUE 2", "",
        "/* index of each real parameter in PlantData.p; arrays f_r, coulomb, viscous by their first element */",
    ]
    for k, v in enumerate(params):
        lines.append(f"#define P_{v.c_name} {k}")
    for base in ("f_r", "coulomb", "viscous"):
        lines.append(f"#define P_{base} P_{base}_0")
    lines += _stop_lines(variables, n)
    lines += [
        "",
        "#define PARAM_NAMES {" + ", ".join(f'"{v.name}"' for v in params) + "}",
        "#define PARAM_POSITIVE {" + ", ".join(str(int(v.positive)) for v in params) + "}",
        "#define PARAM_NONNEGATIVE {" + ", ".join(str(int(v.nonnegative)) for v in params) + "}",
        "#define START_PARAMS {" + ", ".join(_c_double(v.start) for v in params) + "}",
        "#define START_X {" + ", ".join(_c_double(by_name[f"{s}[{i}]"].start)
                                        for s in ("q", "dq") for i in range(n)) + "}",
        f"#define START_N_SUBSTEPS {int(by_name['n_substeps'].start)}",
        "#define START_SWITCHES {" + ", ".join(str(int(bool(by_name[f"disturbance_{k}"].start)))
                                               for k in ("paper", "friction", "tissue")) + "}",
        "#define VAR_NAMES {" + ", ".join(f'"{v.name}"' for v in variables) + "}",
        "", "#endif", "",
    ]
    # the C code relies on this block layout
    expected = {"VR_DQ": vr("q[0]") + n, "VR_DER_Q": vr("q[0]") + 2 * n, "VR_N_SUBSTEPS": first_param + len(params),
                "VR_SWITCH": first_param + len(params) + 1}
    actual = {"VR_DQ": vr("dq[0]"), "VR_DER_Q": vr("der(q[0])"), "VR_N_SUBSTEPS": vr("n_substeps"),
              "VR_SWITCH": vr("disturbance_paper")}
    if expected != actual:
        raise AssertionError(f"variable layout changed: {actual} != {expected}")
    return "\n".join(lines)
