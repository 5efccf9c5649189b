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
* it has a binary for this platform (:class:`FMUPlatformError`);
* it declares the variables a caller needs (:func:`require_variables`,
  :class:`FMUMissingVariablesError`).
"""
from __future__ import annotations

import difflib
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from .build import platform_folder, shared_library_suffix
from .errors import FMUMissingVariablesError, FMUModelDescriptionError, FMUPlatformError, FMUVersionError

__all__ = ["read_description", "described", "intermediate_update_names", "offered_interfaces", "fmi_major",
           "interface", "binary_path", "require_variables",
           "INTERFACES", "real_variables", "unsupported_features", "SUPPORTED_FMI_VERSIONS"]

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
    try:
        element = ET.parse(xml).getroot()
    except ET.ParseError as err:
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is not well-formed XML: {err}") from None
    if element.tag != "fmiModelDescription":
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml has root element <{element.tag}>, "
                                       "expected <fmiModelDescription>")
    version = element.get("fmiVersion")
    if version not in SUPPORTED_FMI_VERSIONS:
        raise FMUVersionError(f"{source}: unsupported FMI version {version!r} (supported: "
                              f"{', '.join(SUPPORTED_FMI_VERSIONS)})")
    from fmpy import read_model_description
    from fmpy.model_description import ValidationError
    try:
        return read_model_description(str(root), validate=validate)
    except ValidationError as err:
        problems = [str(p) for p in err.problems]
        listed = "; ".join(problems[:5]) + (f" (and {len(problems) - 5} more)" if len(problems) > 5 else "")
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml is invalid: {listed}",
                                       problems=problems) from None
    except Exception as err:  # fmpy raises bare Exceptions for unsupported content
        raise FMUModelDescriptionError(f"{source}: modelDescription.xml cannot be read: {err}",
                                       problems=[str(err)]) from None


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
    folder = platform_folder(fmi_major(model_description))
    lib = Path(root) / "binaries" / folder / (identifier + shared_library_suffix())
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


def unsupported_features(model_description, kind: str) -> list[str]:
    """What an FMU uses that dobkit's importer does not handle (empty: supported).

    dobkit couples FMUs through scalar real signals in continuous time.  It
    does not handle, and so refuses rather than silently ignores:

    * for Model Exchange: state events (``numberOfEventIndicators`` > 0 in FMI 2,
      ``EventIndicator`` elements in FMI 3) -- time events are detected at
      initialization by :class:`~fmu.instance.FMUInstance`;
    * for both interfaces: array variables (FMI 3 ``Dimension``) among the
      inputs, outputs or continuous states; inputs or outputs of any type
      other than Real / Float64; clocks (FMI 3).

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    kind : {"ModelExchange", "CoSimulation"}

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

    if kind == "ModelExchange":
        n_events = int(getattr(md, "numberOfEventIndicators", 0) or 0)
        if n_events > 0 or getattr(md, "eventIndicators", None):
            found.append(f"state events (numberOfEventIndicators = {n_events}): event indicators are not "
                         "monitored")
    signals = [v for v in md.modelVariables if v.causality in ("input", "output")]
    states = [d.variable.derivative for d in md.derivatives if d.variable.derivative is not None]
    arrays = [v for v in signals + states if _is_array(v)]
    if arrays:
        found.append(f"array variables (FMI 3 'dimensions'): {names(arrays)}")
    clocks = [v for v in md.modelVariables if v.type == "Clock"]
    if clocks:
        found.append(f"clocks: {names(clocks)}")
    other = [v for v in signals if v.type not in _REAL_TYPES and v.type != "Clock"]
    if other:
        found.append("inputs/outputs that are not Real/Float64: "
                     + ", ".join(f"{v.name} ({v.type})" for v in other[:5])
                     + (f" and {len(other) - 5} more" if len(other) > 5 else ""))
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
