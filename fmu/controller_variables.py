"""The variables of the controller FMU and its ``modelDescription.xml`` (FMI 2.0 and 3.0, Co-Simulation only).

Value references, in blocks (n joints, from the scenario's arm)::

    0 .. n-1        q[i]        inputs: the plant's joint positions at the tick (rad, m)
    n .. 2n-1       dq[i]       inputs: the plant's joint velocities (rad/s, m/s)
    2n .. 3n-1      tau[i]      outputs: applied joint torques and forces (N m, N)
    3n .. 4n-1      d_hat[i]    outputs: the observer's disturbance estimate (N m, N)
    4n ..           kp[i], kd[i], Y[i] (or Y[i,j] for a full matrix)   tunable parameters
    then            sample_period, reference_end                       constants (s)
    last            time                                               the independent variable (s)

The names of the inputs and outputs are those of the plant FMU's outputs and
inputs (:mod:`fmu.variables`), so the two FMUs connect by name.  Every output
depends on every input: with a velocity difference the estimate reads the
positions too, and the torque is available as soon as the inputs of the tick
are set.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from .modeldescription import LOG_CATEGORIES
from .variables import UNITS, Variable

__all__ = ["controller_variables", "controller_description_xml", "position_units"]

_UNIT = {"revolute": {"q": "rad", "dq": "rad/s", "tau": "N.m"}, "prismatic": {"q": "m", "dq": "m/s", "tau": "N"}}


def position_units(kinds) -> dict[str, list[str]]:
    """FMI unit names per joint of ``q``, ``dq`` and ``tau`` for the joint kinds (``"revolute"``/``"prismatic"``)."""
    return {sig: [_UNIT[k][sig] for k in kinds] for sig in ("q", "dq", "tau")}


def controller_variables(kinds, kp, kd, y, y_full: bool, period: float, reference_end: float) -> list[Variable]:
    """The controller FMU's variable table, ordered by value reference.

    Parameters
    ----------
    kinds : sequence of str
        Joint kinds, from the scenario's arm (``arm.joints.kinds``).
    kp, kd : sequence of float
        Start values of the diagonal gains (1/s^2, 1/s).
    y : sequence of float
        Start values of the observer gain: its diagonal, or its entries row by row when ``y_full``.
    y_full : bool
        Whether ``Y`` is a full matrix.
    period : float
        Sample period ``Ts`` (s).
    reference_end : float
        Time of the reference table's last row (s).
    """
    n = len(kinds)
    units = position_units(kinds)
    out: list[Variable] = []

    def add(name, causality, variability, description, start=None, unit=None, initial=None):
        out.append(Variable(name=name, vr=len(out), type="Real", causality=causality, variability=variability,
                            description=description, start=start, unit=unit, initial=initial))
    for sig, text in (("q", "joint position of the plant at the tick"),
                      ("dq", "joint velocity of the plant at the tick")):
        for i in range(n):
            add(f"{sig}[{i}]", "input", "continuous", text, start=0.0, unit=units[sig][i])
    for sig, text in (("tau", "applied joint torque (held until the next tick)"),
                      ("d_hat", "the observer's disturbance estimate at the tick")):
        for i in range(n):
            add(f"{sig}[{i}]", "output", "discrete", text, unit=units["tau"][i], initial="calculated")
    for i in range(n):
        add(f"kp[{i}]", "parameter", "tunable", "proportional gain of Eq. 11 (1/s^2)", start=float(kp[i]),
            initial="exact")
    for i in range(n):
        add(f"kd[{i}]", "parameter", "tunable", "derivative gain of Eq. 11 (1/s)", start=float(kd[i]),
            initial="exact")
    if y_full:
        for i in range(n):
            for j in range(n):
                add(f"Y[{i},{j}]", "parameter", "tunable", "observer gain Y (d_hat = Y dq + z)",
                    start=float(y[i * n + j]), initial="exact")
    else:
        for i in range(n):
            add(f"Y[{i}]", "parameter", "tunable", "observer gain Y, diagonal (d_hat = Y dq + z)",
                start=float(y[i]), initial="exact")
    add("sample_period", "local", "constant", "the controller's sample period Ts: the only communication step",
        start=float(period), unit="s", initial="exact")
    add("reference_end", "local", "constant", "time of the reference table's last row (the scenario's t_final)",
        start=float(reference_end), unit="s", initial="exact")
    add("time", "independent", "continuous", "simulation time", unit="s")
    return out


def _fmt(value: float) -> str:
    return repr(float(value))


def controller_description_xml(variables: list[Variable], model_identifier: str, token: str, sources: list[str],
                               description: str, tool: str, stop_time: float, step: float,
                               fmi_version: int = 2) -> str:
    """The ``modelDescription.xml`` of the controller FMU (Co-Simulation only), FMI 2.0 or 3.0.

    The communication step is fixed (``canHandleVariableCommunicationStepSize``
    false) and the ``DefaultExperiment`` step is the sample period.  Every
    output is declared as depending on every input.
    """
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": f"{fmi_version}.0", "modelName": model_identifier,
        "guid" if fmi_version == 2 else "instantiationToken": token, "description": description,
        "generationTool": tool, "variableNamingConvention": "structured"})
    if fmi_version == 2:
        root.set("numberOfEventIndicators", "0")
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": model_identifier, "canHandleVariableCommunicationStepSize": "false"})
    if fmi_version == 2:
        cs.attrib.update(canNotUseMemoryManagementFunctions="true", canGetAndSetFMUstate="false",
                         canSerializeFMUstate="false")
        files = ET.SubElement(cs, "SourceFiles")
        for name in sources:
            ET.SubElement(files, "File", name=name)
    else:
        cs.attrib.update(canGetAndSetFMUState="false", canSerializeFMUState="false")
    defs = ET.SubElement(root, "UnitDefinitions")
    for name in sorted({v.unit for v in variables if v.unit is not None}):
        unit = ET.SubElement(defs, "Unit", name=name)
        ET.SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
    cats = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES.items():
        ET.SubElement(cats, "Category", name=name, description=text)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime=_fmt(stop_time), stepSize=_fmt(step))
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:
        attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.initial is not None:
            attrs["initial"] = v.initial
        real = {}
        if v.unit is not None:
            real["unit"] = v.unit
        if v.start is not None:
            real["start"] = _fmt(v.start)
        if fmi_version == 2:
            ET.SubElement(ET.SubElement(mv, "ScalarVariable", attrs), "Real", real)
        else:
            ET.SubElement(mv, "Float64", {**attrs, **real})

    def ref(v: Variable) -> str:          # FMI 2: 1-based index in ModelVariables; FMI 3: value reference
        return str(v.vr + 1) if fmi_version == 2 else str(v.vr)
    inputs = " ".join(ref(v) for v in variables if v.causality == "input")
    outputs = [v for v in variables if v.causality == "output"]
    ms = ET.SubElement(root, "ModelStructure")
    if fmi_version == 2:
        for tag in ("Outputs", "InitialUnknowns"):
            group = ET.SubElement(ms, tag)
            for v in outputs:
                ET.SubElement(group, "Unknown", index=ref(v), dependencies=inputs)
    else:
        for tag in ("Output", "InitialUnknown"):
            for v in outputs:
                ET.SubElement(ms, tag, valueReference=ref(v), dependencies=inputs)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
