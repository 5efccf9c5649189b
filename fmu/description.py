"""Read and check the model description of an extracted FMU.

Checks, each with its own error naming what is wrong:

* ``modelDescription.xml`` exists at the top of the archive, is not too large
  and has no huge comment, attribute or text (checked before parsing: the
  parser is quadratic in such a token), and is well-formed XML whose root is
  ``fmiModelDescription`` (:class:`FMUModelDescriptionError`);
* the FMI version is 2.0 or 3.0 and the FMU offers the interface asked for
  (:class:`FMUVersionError`);
* it passes fmpy's schema validation (:class:`FMUModelDescriptionError`,
  with fmpy's list of problems as ``problems``);
* it stays within the subset of FMI that dobkit's importer handles
  (:func:`unsupported_features`);
* every interface's ``modelIdentifier`` is a C identifier, as FMI requires
  (it names the shared library: ``../x`` would load one from outside the
  archive), checked before anything is loaded (:class:`FMUModelDescriptionError`);
* it has a binary for this platform, inside the extracted archive
  (:class:`FMUPlatformError`);
* it declares the variables a caller needs (:func:`require_variables`,
  :class:`FMUMissingVariablesError`).
"""
from __future__ import annotations

import difflib
import math
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from .build import platform_folder, shared_library_suffix
from .errors import FMUMissingVariablesError, FMUModelDescriptionError, FMUPlatformError, FMUVersionError

__all__ = ["read_description", "described", "intermediate_update_names", "offered_interfaces", "fmi_major",
           "interface", "binary_path", "require_variables", "identifier_problems",
           "INTERFACES", "real_variables", "unsupported_features", "SUPPORTED_FMI_VERSIONS", "array_shape",
           "element_names", "state_count", "event_indicator_count", "state_variables"]

INTERFACES = ("ModelExchange", "CoSimulation")
_REAL_TYPES = ("Real", "Float64")
SUPPORTED_FMI_VERSIONS = ("2.0", "3.0")


def fmi_major(model_description) -> int:
    """2 or 3, from the ``fmiVersion`` attribute."""
    return 2 if model_description.fmiVersion == "2.0" else 3


def _line(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


# one attribute value (either quote) or text run between tags
_LONG_TOKEN = r"""(?:"[^"]{%d,}")|(?:'[^']{%d,}')|(?:>[^<]{%d,})"""


def _check_size(xml: Path, source: str, limits) -> None:
    """Refuse a description too large, or with one comment, attribute or text too long, before parsing it."""
    from .archive import ExtractionLimits
    limits = ExtractionLimits() if limits is None else limits
    size = xml.stat().st_size
    if size > limits.max_description_size:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml has {size} bytes, more than the limit of "
                                       f"{limits.max_description_size} (ExtractionLimits.max_description_size)")
    data = xml.read_bytes()
    n = limits.max_description_token
    start = data.find(b"<!--")
    while start >= 0:
        end = data.find(b"-->", start + 4)
        stop = len(data) if end < 0 else end
        if stop - start > n:
            raise FMUModelDescriptionError(f"{source}: modelDescription.xml has a comment of {stop - start} bytes "
                                           f"(line {_line(data, start)}), more than the limit of {n} "
                                           "(ExtractionLimits.max_description_token); refusing to parse it")
        start = data.find(b"<!--", stop)
    long_token = re.search((_LONG_TOKEN % (n, n, n)).encode(), data)
    if long_token:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml has an attribute value or text of more "
                                       f"than {n} bytes (line {_line(data, long_token.start())}; "
                                       "ExtractionLimits.max_description_token); refusing to parse it")


def _root_element(xml: Path, source: str) -> tuple[str, dict]:
    """The root element's tag and attributes, the whole document checked for well-formedness without a tree.

    expat without handlers for the rest runs in C: a 24 MB description in a fraction of a second, where
    building an ElementTree costs as much as fmpy's own parse.
    """
    from xml.parsers import expat
    parser = expat.ParserCreate()
    found: list = []

    def start(name, attributes):
        if not found:
            found.append((name, attributes))
            parser.StartElementHandler = None

    parser.StartElementHandler = start
    try:
        with open(xml, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as err:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is not well-formed XML: {err}") from None
    return found[0]


#: FMI 2.0.4 section 2.2.1 and FMI 3.0 section 2.4.1: a modelIdentifier is a C identifier (it names the library
#: binaries/<platform>/<modelIdentifier>.so and prefixes the functions of a source FMU).
_C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def identifier_problems(model_description) -> list[str]:
    """One phrase per interface whose ``modelIdentifier`` is not a C identifier (empty: all are).

    Examples
    --------
    >>> from types import SimpleNamespace as N
    >>> [p[:50] for p in identifier_problems(N(modelExchange=N(modelIdentifier="../x"), coSimulation=None))]
    ["ModelExchange modelIdentifier='../x' is not a C id"]
    """
    problems = []
    for kind in INTERFACES + ("ScheduledExecution",):
        attribute = {"ModelExchange": "modelExchange", "CoSimulation": "coSimulation"}.get(kind, "scheduledExecution")
        element = getattr(model_description, attribute, None)
        if element is None:
            continue
        name = getattr(element, "modelIdentifier", None)
        if not isinstance(name, str) or not name.isascii() or not _C_IDENTIFIER.fullmatch(name):
            problems.append(f"{kind} modelIdentifier={name!r} is not a C identifier (letters, digits and '_', not "
                            "starting with a digit), which FMI requires: it names the library "
                            "binaries/<platform>/<modelIdentifier>.so")
    return problems


def read_description(root: Path, source: str, validate: bool = True, limits=None):
    """Parse and validate ``modelDescription.xml`` of an extracted FMU.

    Parameters
    ----------
    root : pathlib.Path
        The extraction folder.
    source : str
        Name of the archive, for messages.
    validate : bool
        Check against the FMI schema (fmpy); a failure raises with the list of problems.
    limits : ExtractionLimits, optional
        Size limits of the description (checked before parsing).

    Returns
    -------
    fmpy.model_description.ModelDescription

    Raises
    ------
    FMUModelDescriptionError
        Missing, malformed or schema-invalid (attribute ``problems``: fmpy's findings).
    FMUVersionError
        An FMI version other than 2.0 or 3.0.
    """
    xml = Path(root) / "modelDescription.xml"
    if xml.is_dir():
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is a directory, not a file")
    if not xml.is_file():
        found = sorted(p.name for p in Path(root).iterdir())[:10]
        raise FMUModelDescriptionError(f"{source}: no modelDescription.xml at the top of the archive "
                                       f"(found: {found or 'nothing'})")
    _check_size(xml, source, limits)
    tag, attributes = _root_element(xml, source)
    if tag != "fmiModelDescription":
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml has root element <{tag}>, "
                                       "expected <fmiModelDescription>")
    version = attributes.get("fmiVersion")
    if version not in SUPPORTED_FMI_VERSIONS:
        raise FMUVersionError(f"{source}: unsupported FMI version {version!r} (supported: "
                              f"{', '.join(SUPPORTED_FMI_VERSIONS)})")
    from fmpy import read_model_description
    from fmpy.model_description import ValidationError
    try:
        md = read_model_description(str(root), validate=validate)
    except ValidationError as err:
        problems = [str(p) for p in err.problems]
        listed = "; ".join(problems[:5]) + (f" (and {len(problems) - 5} more)" if len(problems) > 5 else "")
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is invalid: {listed}",
                                       problems=problems) from None
    except Exception as err:  # fmpy raises bare Exceptions for unsupported content
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml cannot be read: {err}",
                                       problems=[str(err)]) from None
    bad = identifier_problems(md)       # before anything can load a library named by it
    if bad:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is invalid: {'; '.join(bad)}; nothing was "
                                       "loaded", problems=bad)
    return md


def intermediate_update_names(root: Path) -> frozenset[str]:
    """FMI 3 variables marked ``intermediateUpdate="true"`` (fmpy does not read the attribute)."""
    variables = ET.parse(Path(root) / "modelDescription.xml").getroot().find("ModelVariables")
    return frozenset(e.get("name") for e in (variables if variables is not None else [])
                     if e.get("intermediateUpdate") == "true")


def described(extracted):
    """The (validated) model description of an :class:`~fmu.archive.ExtractedFMU`, parsed once.

    The result is cached on the object, so that one extraction serves every
    step of a command without parsing the XML again.
    """
    md = getattr(extracted, "model_description", None)
    if md is None:
        md = read_description(extracted.root, extracted.source, limits=getattr(extracted, "limits", None))
        extracted.model_description = md
    return md


def interface(model_description, kind: str, source: str):
    """The ``ModelExchange`` or ``CoSimulation`` element, or an error saying which interfaces exist."""
    if kind not in INTERFACES:
        raise ValueError(f"kind must be one of {INTERFACES}, got {kind!r}")
    element = model_description.modelExchange if kind == "ModelExchange" else model_description.coSimulation
    if element is None:
        offered = offered_interfaces(model_description)
        raise FMUVersionError(f"{source}: the FMU does not offer {kind} (it offers: "
                              f"{', '.join(offered) if offered else 'no interface'})")
    return element


def offered_interfaces(model_description) -> list[str]:
    """The interfaces an FMU declares: ``ModelExchange``, ``CoSimulation``, ``ScheduledExecution`` (FMI 3)."""
    elements = (("ModelExchange", model_description.modelExchange), ("CoSimulation", model_description.coSimulation),
                ("ScheduledExecution", getattr(model_description, "scheduledExecution", None)))
    return [name for name, element in elements if element is not None]


def binary_path(root: Path, model_description, kind: str, source: str) -> Path:
    """Path of the shared library for this platform; raises if the FMU has none."""
    identifier = interface(model_description, kind, source).modelIdentifier
    bad = identifier_problems(model_description)
    if bad:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is invalid: {'; '.join(bad)}; nothing was "
                                       "loaded", problems=bad)
    folder = platform_folder(fmi_major(model_description))
    lib = Path(root) / "binaries" / folder / (identifier + shared_library_suffix())
    # only a regular file inside the extraction is ever loaded (the archive checks refuse links; this holds even so)
    inside = str(Path(root).resolve() / "binaries") + os.sep
    if lib.is_file() and not os.path.realpath(lib).startswith(inside):
        raise FMUPlatformError(f"{source}: the binary {lib} resolves to {os.path.realpath(lib)}, outside the "
                               "extracted archive; refusing to load it")
    if not lib.is_file():
        bins = Path(root) / "binaries"
        present = sorted(p.name for p in bins.iterdir() if p.is_dir()) if bins.is_dir() else []
        has_sources = (Path(root) / "sources").is_dir()
        raise FMUPlatformError(
            f"{source}: no binary for this platform: expected binaries/{folder}/{lib.name}; the FMU has binaries "
            f"for {present or 'no platform'}" + (" (it ships sources/, so it could be rebuilt)" if has_sources else ""))
    return lib


def _is_array(variable) -> bool:
    return bool(getattr(variable, "dimensions", None))


def array_shape(variable, source: str = "FMU") -> tuple[int, ...]:
    """The shape of an FMI 3 array variable (``()`` for a scalar), structural parameters at their start values.

    Each ``Dimension`` has a fixed ``start`` or names a structural parameter
    (``valueReference``) whose start value is the size.  dobkit does not
    change structural parameters, so the sizes are those of the model description.

    Raises
    ------
    FMUModelDescriptionError
        For a size that is not a whole number >= 0, naming the variable and the dimension.
    """
    shape = []
    for k, dim in enumerate(getattr(variable, "dimensions", None) or []):
        ref = getattr(dim, "variable", None)
        text = dim.start if getattr(dim, "start", None) is not None else (ref.start if ref is not None else None)
        try:
            size = int(str(text).strip())
        except (TypeError, ValueError):
            size = -1
        if size < 0:
            by = f"structural parameter {ref.name!r}" if ref is not None else f"value reference {dim.valueReference}"
            raise FMUModelDescriptionError(f"{source}: dimension {k} of array variable {variable.name!r} (from "
                                           f"{by}) has size {text!r}; a whole number >= 0 is needed")
        shape.append(size)
    return tuple(shape)


def element_names(variable, shape: tuple[int, ...]) -> list[str]:
    """Signal names of a variable's elements: ``[name]`` for a scalar, ``y[0]``, ``y[1]``, ... (row-major).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> element_names(SimpleNamespace(name="y"), (3,)), element_names(SimpleNamespace(name="A"), (2, 2))
    (['y[0]', 'y[1]', 'y[2]'], ['A[0,0]', 'A[0,1]', 'A[1,0]', 'A[1,1]'])
    """
    if not shape:
        return [variable.name]
    import itertools
    return [f"{variable.name}[{','.join(map(str, idx))}]" for idx in itertools.product(*(range(n) for n in shape))]


def state_variables(model_description, source: str = "FMU") -> list:
    """The continuous state variables, in the order of ``ModelStructure/Derivatives`` (FMI 3: ``ContinuousStateDerivative``).

    Raises
    ------
    FMUModelDescriptionError
        If an entry points at a variable that is not the derivative of another (a malformed model structure,
        for example indices shifted by extra variables), naming the entry and the variable.
    """
    states = []
    for k, unknown in enumerate(model_description.derivatives):
        variable = unknown.variable
        state = getattr(variable, "derivative", None)
        if state is None:
            where = "Derivatives" if fmi_major(model_description) == 2 else "ContinuousStateDerivative"
            raise FMUModelDescriptionError(
                f"{source}: ModelStructure/{where} entry {k + 1} points at {getattr(variable, 'name', variable)!r}, "
                "which is not the derivative of a state (it has no 'derivative' attribute): the model structure is "
                "malformed")
        states.append(state)
    return states


def state_count(model_description, source: str = "FMU") -> int:
    """The number of continuous states: one per scalar state, the size of each array state."""
    return sum(math.prod(array_shape(v, source)) for v in state_variables(model_description, source))


def event_indicator_count(model_description, source: str = "FMU") -> int:
    """The number of event indicators (FMI 2 attribute; FMI 3 ``EventIndicator`` elements, arrays by size)."""
    if fmi_major(model_description) == 2:
        return int(getattr(model_description, "numberOfEventIndicators", 0) or 0)
    return sum(math.prod(array_shape(u.variable, source)) for u in (model_description.eventIndicators or []))


def unsupported_features(model_description, kind: str, events: bool = False,
                         state_events: bool = False) -> list[str]:
    """What an FMU uses that dobkit's importer does not handle (empty: supported).

    With ``events=False`` (the default: the co-simulation master; :func:`fmu.load`
    blocks with ``state_events=True``) dobkit couples FMUs through scalar real
    signals in continuous time.  It does not handle, and so refuses rather than
    silently ignores:

    * for Model Exchange: state events (``numberOfEventIndicators`` > 0 in
      FMI 2, ``EventIndicator`` elements in FMI 3) -- time events are
      detected at initialization by :class:`~fmu.instance.FMUInstance`;
      array variables (FMI 3 ``Dimension``) among the inputs, outputs or
      continuous states; inputs or outputs of a type other than Real /
      Float64 -- :func:`fmu.simulate_fmu` handles all three;
    * for Co-Simulation: array variables and inputs or outputs that are not
      Real / Float64 (the master couples scalar real signals);
    * for Model Exchange: inputs of ``discrete`` variability (settable only
      at events, while dobkit sets inputs in continuous time);
    * for both: clocks (FMI 3).

    With ``events=True`` (:func:`fmu.simulate_fmu`) only the last two remain.

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    kind : {"ModelExchange", "CoSimulation"}
    events : bool
        True for the event-handling simulation of :func:`fmu.simulate_fmu`.
    state_events : bool
        True for a block of the numpy engine (:func:`fmu.load`): state events
        accepted, the rest as with ``events=False``.

    Returns
    -------
    list of str
        One phrase per unsupported feature, naming the variables concerned.
    """
    md = model_description
    found: list[str] = []

    def names(variables, limit: int = 5) -> str:
        listed = [v.name for v in variables]
        return ", ".join(listed[:limit]) + (f" and {len(listed) - limit} more" if len(listed) > limit else "")

    use = "use fmu.simulate_fmu, which handles them"
    if kind == "ModelExchange" and not events and not state_events:
        n_events = int(getattr(md, "numberOfEventIndicators", 0) or 0)
        if n_events > 0 or getattr(md, "eventIndicators", None):
            found.append(f"state events (numberOfEventIndicators = {n_events}): event indicators are not "
                         f"monitored by a block ({use})")
    signals = [v for v in md.modelVariables if v.causality in ("input", "output")]
    if not events:
        states = [d.variable.derivative for d in md.derivatives if getattr(d.variable, "derivative", None) is not None]
        arrays = [v for v in signals + states if _is_array(v)]
        if arrays:
            found.append(f"array variables (FMI 3 'dimensions'): {names(arrays)}: the "
                         + ("master couples scalar signals" if kind == "CoSimulation" else f"block has scalar signals "
                            f"({use})"))
    discrete = [v for v in signals if v.causality == "input" and v.variability == "discrete" and v.type != "Clock"]
    if discrete and kind == "ModelExchange":    # Co-Simulation sets every input between steps
        found.append(f"inputs of discrete variability, which may be set only at events: {names(discrete)} (dobkit "
                     "sets inputs in continuous time, so it cannot use them as inputs)")
    clocks = [v for v in md.modelVariables if v.type == "Clock"]
    if clocks:
        found.append(f"clocks (FMI 3 Clock variables, not supported): {names(clocks)}")
    other = [v for v in signals if v.type not in _REAL_TYPES and v.type != "Clock"]
    if other and not events:
        found.append("inputs/outputs that are not Real/Float64: "
                     + ", ".join(f"{v.name} ({v.type})" for v in other[:5])
                     + (f" and {len(other) - 5} more" if len(other) > 5 else "")
                     + ("" if kind == "CoSimulation" else f" ({use})"))
    elif events:
        other_inputs = [v for v in signals if v.causality == "input" and v.type not in _REAL_TYPES
                        and v.type != "Clock"]
        if other_inputs:
            found.append("inputs that are not Real/Float64 (fmu.simulate_fmu drives real inputs): "
                         + names(other_inputs))
    return found


def real_variables(model_description, causality: str) -> list:
    """The real (Real / Float64) scalar variables of a causality, in model-description order."""
    return [v for v in model_description.modelVariables if v.causality == causality and v.type in _REAL_TYPES]


def require_variables(model_description, names, causality: str | None = None, source: str = "FMU") -> None:
    """Raise if any of ``names`` is missing (or has another causality).

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    names : iterable of str
        Variable names the caller needs, e.g. ``["q[0]", "tau[0]"]``.
    causality : str, optional
        Required causality (``"input"``, ``"output"``, ``"parameter"``...).
    source : str
        Name of the FMU, for the message.

    Raises
    ------
    FMUMissingVariablesError
        Listing every missing name, with close matches where there are any.
    """
    by_name = {v.name: v for v in model_description.modelVariables}
    missing, wrong = [], []
    for name in names:
        v = by_name.get(name)
        if v is None:
            missing.append(name)
        elif causality is not None and v.causality != causality:
            wrong.append(f"{name} (causality {v.causality!r})")
    if not missing and not wrong:
        return
    parts = []
    if missing:
        hints = {n: difflib.get_close_matches(n, list(by_name), n=2) for n in missing}
        listed = ", ".join(n + (f" (did you mean {' or '.join(hints[n])}?)" if hints[n] else "") for n in missing)
        parts.append(f"missing variable(s): {listed}")
    if wrong:
        parts.append(f"variable(s) not of causality {causality!r}: {', '.join(wrong)}")
    raise FMUMissingVariablesError(f"{source}: " + "; ".join(parts), missing=missing)
