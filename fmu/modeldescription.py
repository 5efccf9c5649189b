"""Write ``modelDescription.xml`` (FMI 2.0 and 3.0) from the plant's variable table.

The FMU offers Model Exchange and Co-Simulation in one binary, declares its
units, names variables with the structured convention (``q[0]``,
``der(dq[2])``) and states its dependencies in ``ModelStructure``:

* ``q[i]``, ``dq[i]`` are the states themselves;
* ``tau_dis[i]`` depends on time and the states, never on the inputs, so the
  plant has no direct feedthrough;
* ``der(q[i])`` depends on ``dq[i]``; ``der(dq[i])`` on time, the states and
  the inputs.

Co-Simulation offers what a second-order coupling needs: first derivatives
of the outputs (``maxOutputDerivativeOrder`` 1) and inputs that follow a
slope over the step -- FMI 2 ``canInterpolateInputs`` with
``fmi2SetRealInputDerivatives``; FMI 3, which has no input derivatives,
``providesIntermediateUpdate`` with the inputs marked ``intermediateUpdate``.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from .variables import UNITS, Variable

__all__ = ["model_description_xml", "build_description_xml", "LOG_CATEGORIES"]

LOG_CATEGORIES = {
    "logStatusError": "errors: invalid calls, parameters or non-finite results",
    "logStatusWarning": "warnings",
}

_FMI3_TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    return repr(float(value))


def _dependencies(variables: list[Variable]) -> dict[str, list[str]]:
    """Names each output and state derivative depends on (see the module docstring)."""
    states = [v.name for v in variables if v.name.startswith(("q[", "dq["))]
    inputs = [v.name for v in variables if v.causality == "input"]
    deps: dict[str, list[str]] = {}
    for v in variables:
        if v.causality == "output" and v.name in states:
            deps[v.name] = [v.name]
        elif v.causality == "output":
            deps[v.name] = ["time"] + states
        elif v.derivative_of is not None and v.derivative_of.startswith("q["):
            deps[v.name] = ["d" + v.derivative_of]
        elif v.derivative_of is not None:
            deps[v.name] = ["time"] + states + inputs
    return deps


def _initial_unknowns(variables: list[Variable]) -> list[Variable]:
    return [v for v in variables
            if (v.causality == "output" and v.initial == "calculated")
            or v.causality == "calculatedParameter"
            or (v.derivative_of is not None and v.initial == "calculated")]


def _root(fmi_version: int, model_identifier: str, token: str, description: str, tool: str) -> ET.Element:
    attrs = {"fmiVersion": "2.0" if fmi_version == 2 else "3.0", "modelName": model_identifier}
    attrs["guid" if fmi_version == 2 else "instantiationToken"] = token
    attrs.update(description=description, generationTool=tool, variableNamingConvention="structured")
    if fmi_version == 2:
        attrs["numberOfEventIndicators"] = "0"
    return ET.Element("fmiModelDescription", attrs)


def _interfaces(root: ET.Element, fmi_version: int, model_identifier: str, sources: list[str]) -> None:
    if fmi_version == 2:
        common = {"modelIdentifier": model_identifier, "canNotUseMemoryManagementFunctions": "true",
                  "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"}
        me = ET.SubElement(root, "ModelExchange", common)
        cs = ET.SubElement(root, "CoSimulation", dict(common, canHandleVariableCommunicationStepSize="true",
                                                      canInterpolateInputs="true", maxOutputDerivativeOrder="1"))
        for element in (me, cs):
            files = ET.SubElement(element, "SourceFiles")
            for name in sources:
                ET.SubElement(files, "File", name=name)
    else:
        common = {"modelIdentifier": model_identifier, "canGetAndSetFMUState": "true",
                  "canSerializeFMUState": "true"}
        ET.SubElement(root, "ModelExchange", common)
        ET.SubElement(root, "CoSimulation", dict(common, canHandleVariableCommunicationStepSize="true",
                                                 maxOutputDerivativeOrder="1", providesIntermediateUpdate="true"))


def _units(root: ET.Element, variables: list[Variable]) -> None:
    used = sorted({v.unit for v in variables if v.unit is not None})
    defs = ET.SubElement(root, "UnitDefinitions")
    for name in used:
        unit = ET.SubElement(defs, "Unit", name=name)
        ET.SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})


def _log_categories(root: ET.Element) -> None:
    cats = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES.items():
        ET.SubElement(cats, "Category", name=name, description=text)


def _variable_attrs(v: Variable, fmi_version: int) -> dict[str, str]:
    attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description,
             "causality": v.causality, "variability": v.variability}
    if v.initial is not None:
        attrs["initial"] = v.initial
    if fmi_version == 3 and v.causality == "input":
        attrs["intermediateUpdate"] = "true"   # set during a step through the intermediate-update callback
    return attrs


def _type_attrs(v: Variable, by_name: dict[str, Variable], fmi_version: int) -> dict[str, str]:
    attrs: dict[str, str] = {}
    if v.unit is not None:
        attrs["unit"] = v.unit
    if v.start is not None:
        attrs["start"] = _fmt(v.start)
    if v.type == "Integer" and v.name == "n_substeps":
        attrs["min"] = "1"
    if v.positive and v.type == "Real":
        attrs["min"] = "0"  # strictly > 0 is checked by the FMU itself
    if v.nonnegative:
        attrs["min"] = "0"
    if v.min is not None:
        attrs["min"] = _fmt(float(v.min))     # a joint's range: where its end stop begins
    if v.max is not None:
        attrs["max"] = _fmt(float(v.max))
    if v.derivative_of is not None:
        state = by_name[v.derivative_of]
        # FMI 2 refers to the state by its 1-based index, FMI 3 by value reference
        attrs["derivative"] = str(state.vr + 1) if fmi_version == 2 else str(state.vr)
    return attrs


def _model_variables(root: ET.Element, variables: list[Variable], fmi_version: int) -> None:
    by_name = {v.name: v for v in variables}
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:
        if fmi_version == 2:
            sv = ET.SubElement(mv, "ScalarVariable", _variable_attrs(v, 2))
            ET.SubElement(sv, v.type, _type_attrs(v, by_name, 2))
        else:
            ET.SubElement(mv, _FMI3_TYPES[v.type], {**_variable_attrs(v, 3), **_type_attrs(v, by_name, 3)})


def _model_structure(root: ET.Element, variables: list[Variable], fmi_version: int) -> None:
    by_name = {v.name: v for v in variables}
    deps = _dependencies(variables)
    outputs = [v for v in variables if v.causality == "output"]
    derivatives = [v for v in variables if v.derivative_of is not None]
    initial = _initial_unknowns(variables)
    ms = ET.SubElement(root, "ModelStructure")

    def ref(v: Variable) -> str:
        return str(v.vr + 1) if fmi_version == 2 else str(v.vr)

    def dep_list(v: Variable) -> str:
        refs = sorted(by_name[n].vr for n in deps[v.name])
        return " ".join(str(r + 1) if fmi_version == 2 else str(r) for r in refs)

    if fmi_version == 2:
        for tag, items, with_deps in (("Outputs", outputs, True), ("Derivatives", derivatives, True),
                                      ("InitialUnknowns", initial, False)):
            group = ET.SubElement(ms, tag)
            for v in items:
                attrs = {"index": ref(v)}
                if with_deps:
                    attrs["dependencies"] = dep_list(v)
                ET.SubElement(group, "Unknown", attrs)
    else:
        for tag, items, with_deps in (("Output", outputs, True), ("ContinuousStateDerivative", derivatives, True),
                                      ("InitialUnknown", initial, False)):
            for v in items:
                attrs = {"valueReference": ref(v)}
                if with_deps:
                    attrs["dependencies"] = dep_list(v)
                ET.SubElement(ms, tag, attrs)


def model_description_xml(variables: list[Variable], fmi_version: int, model_identifier: str, token: str,
                          sources: list[str], description: str, tool: str,
                          default_stop_time: float = 1.0, default_step: float = 1e-3) -> str:
    """The complete ``modelDescription.xml`` text.

    Parameters
    ----------
    variables : list of Variable
        The plant's variable table, ordered by value reference.
    fmi_version : {2, 3}
    model_identifier : str
        Name of the shared library (without extension).
    token : str
        The GUID (FMI 2) or instantiationToken (FMI 3).
    sources : list of str
        C files under ``sources/`` (listed in FMI 2's ``SourceFiles``).
    description, tool : str
        Free text for the ``description`` and ``generationTool`` attributes.
    default_stop_time, default_step : float
        ``DefaultExperiment`` stop time and step size (s).
    """
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    root = _root(fmi_version, model_identifier, token, description, tool)
    _interfaces(root, fmi_version, model_identifier, sources)
    _units(root, variables)
    _log_categories(root)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime=_fmt(default_stop_time),
                  stepSize=_fmt(default_step))
    _model_variables(root, variables, fmi_version)
    _model_structure(root, variables, fmi_version)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def build_description_xml(model_identifier: str, sources: list[str]) -> str:
    """FMI 3 ``sources/buildDescription.xml``: one C99 build configuration of all sources."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    config = ET.SubElement(root, "BuildConfiguration", modelIdentifier=model_identifier)
    file_set = ET.SubElement(config, "SourceFileSet", language="C99")
    for name in sources:
        ET.SubElement(file_set, "SourceFile", name=name)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
