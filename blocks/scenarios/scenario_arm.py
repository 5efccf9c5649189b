"""A scenario's arm: the ``[arm]`` section (a URDF arm) and what follows from the arm for the other sections.

Without ``[arm]`` a scenario is the paper's RRPR (``[robot]``,
``[nominal_scale]``) exactly as before.  With it::

    [arm]
    urdf = "scope4.urdf"          # path, relative to the scenario file's folder
    tool_frame = "tool_tip"       # frame of the tool point (tool-tip errors, task-space paths)
    locked = ["finger_joint1"]    # optional: joints held fixed
    locked_values = [0.02]        # optional: their positions (rad, m), one per locked joint; default 0
    gravity = 9.81                # optional: m/s^2 along -z, or a vector [gx, gy, gz]; default the URDF world's
    nominal_mass_scale = 1.1      # optional: the controller's and observer's model has every link's mass and
                                  # inertia times this (Eq. 3's internal disturbance); default 1

``[nominal_scale]`` then names URDF links, ``shaft_link = 1.2``: the nominal
model is the URDF with each named link's mass and inertia times its factor
(:func:`link_scaled_nominal`; a link on a fixed joint is merged into its
parent's body as in the true arm), and ``nominal_mass_scale`` multiplies every
link on top.  Everything per joint in the other sections then has the arm's ``n`` entries
(``gains.kp``, ``trajectory.amplitude``, ``disturbance.f_r``, ``initial.q``,
...), and the messages name the key, ``n`` and the arm.  The tissue contact
(``disturbance.kind = "tissue"``) works for any arm; its plane
``disturbance.skin_height`` defaults to the RRPR's, so for another arm a
scenario that does not set it puts the skin through the tool point at the
reference's start (:func:`skin_height_default`); a laceration path
(:class:`~blocks.scenarios.tool_path.ToolLaceration`) sets it.  This module holds
the pieces that need the arm; :mod:`blocks.scenarios.scenario` calls them.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from blocks.model.arm import ArmModel
from blocks.model.rrpr import dynamics_kernels as _rrpr_dynamics
from blocks.model.rrpr import tool_kernels as _rrpr_tool

__all__ = ["ARM_KEYS", "arm_name", "is_rrpr", "load_arm", "scaled_nominal", "link_masses", "link_scaled_nominal",
           "joint_sine_defaults", "observer_gain_from_bandwidth", "skin_height_default"]

#: The keys of ``[arm]`` and what each takes.
ARM_KEYS = {"urdf": "a path (text), relative to the scenario file", "tool_frame": "a frame name (text)",
            "locked": "a list of joint names", "locked_values": "a list of numbers (rad, m), one per locked joint",
            "gravity": "a number (m/s^2, along -z) or 3 numbers", "nominal_mass_scale": "a number > 0"}


def is_rrpr(arm: ArmModel) -> bool:
    """Whether ``arm`` is the paper's RRPR in closed form (its own sections and paths apply)."""
    return arm.kernels is _rrpr_dynamics and arm.tool_kernels in (None, _rrpr_tool)


def arm_name(arm: ArmModel, urdf: str | None = None) -> str:
    """How messages name an arm: the URDF file's stem, the arm's ``name``, or its class."""
    if urdf:
        return urdf.split(":", 1)[1] if urdf.startswith("example:") else Path(urdf).stem
    return str(getattr(arm, "name", None) or ("rrpr" if is_rrpr(arm) else type(arm).__name__))


def _gravity(value) -> tuple[float, float, float]:
    g = np.asarray(value, dtype=float)
    return (0.0, 0.0, -float(g)) if g.ndim == 0 else tuple(float(v) for v in g)


def load_arm(given: dict, base: Path | None, error):
    """The true arm of an ``[arm]`` section (checked values ``given``), its name and the URDF file's full path.

    Parameters
    ----------
    given : dict
        The section's checked values.
    base : pathlib.Path or None
        The folder ``urdf`` is relative to (the scenario file's); None: the working folder.
    error : type
        The exception to raise (the scenario's error), with a message naming the key.
    """
    for key in ("urdf", "tool_frame"):
        if key not in given:
            raise error(f"'arm.{key}' is required in an [arm] section ({ARM_KEYS[key]})")
    locked = list(given.get("locked", []))
    values = list(given.get("locked_values", []))
    if values and len(values) != len(locked):
        raise error(f"'arm.locked_values' has {len(values)} values for {len(locked)} locked joint(s) {locked}: "
                    "give one position per locked joint")
    path = Path(given["urdf"])
    if not path.is_absolute() and base is not None:
        path = base / path
    if not path.is_file():              # refused before pinocchio is imported (seconds on a busy machine)
        raise error(f"[arm] urdf = {given['urdf']!r}: URDF file '{path}' does not exist (or is not a file)")
    try:
        from blocks.model.urdf.urdf import load_urdf_arm
    except ImportError as err:          # pinocchio is the extra dobkit[urdf]
        raise error(f"'arm.urdf' needs pinocchio, the optional extra: pip install \"dobkit[urdf]\" ({err})") from None
    gravity = _gravity(given["gravity"]) if "gravity" in given else None
    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, given["tool_frame"], tuple(locked), tuple(values),
               gravity)
    except OSError:
        key = None
    arm = _loaded.get(key) if key is not None else None
    if arm is None:
        try:
            arm = load_urdf_arm(path, given["tool_frame"], locked=locked, locked_values=dict(zip(locked, values)),
                                gravity=gravity)
        except (ValueError, OSError) as err:
            raise error(f"[arm] urdf = {given['urdf']!r}: {err}") from None
        if key is not None:
            _loaded[key] = arm
            while len(_loaded) > _KEPT:
                _loaded.pop(next(iter(_loaded)))
    return arm, arm_name(arm, given["urdf"]), str(path.resolve())


# Arms read from unchanged files are read once: a scenario varied many times (a sweep) shares its arm, and two
# loads of one scenario are equal (an arm compares by identity).
_KEPT = 16
_loaded: dict = {}
_scaled: dict = {}


def scaled_nominal(arm: ArmModel, scale: float, error) -> ArmModel:
    """The nominal model of ``arm`` with every body's mass and inertia times ``scale`` (centres of mass kept).

    The dynamics are linear in those parameters, so the nominal ``M``, ``N q'``
    and ``G`` are ``scale`` times the true ones: the internal disturbance of
    Eq. 3 is ``(scale - 1) (M q'' + h)``.
    """
    if scale == 1.0:
        return arm
    found = _scaled.get((id(arm), scale))
    if found is not None and found[0] is arm:
        return found[1]
    chain = getattr(arm, "chain", None)
    # the body parameters that scale with the mass: masses, inertias, first moments (centres of mass do not)
    fields = [f for f in ("masses", "first_moments", "inertias", "com_inertias") if hasattr(chain, f)]
    if chain is None or "masses" not in fields or len(fields) < 2:
        raise error(f"'arm.nominal_mass_scale' needs an arm given by its bodies (a URDF arm), not {arm!r:.80}")

    def times(value):
        return tuple(times(v) for v in value) if isinstance(value, tuple) else float(value) * scale

    scaled = dataclasses.replace(chain, **{f: times(getattr(chain, f)) for f in fields})
    nominal = type(arm)(scaled, arm.joints, arm.tool_frame, continuous=arm.continuous, source=arm.source)
    nominal.pin_model = None            # the reference model is the true arm's
    nominal.source_path = getattr(arm, "source_path", None)
    _scaled[(id(arm), scale)] = (arm, nominal)
    while len(_scaled) > _KEPT:
        _scaled.pop(next(iter(_scaled)))
    return nominal


def link_masses(arm: ArmModel) -> dict[str, float]:
    """The URDF links of ``arm`` whose mass enters its dynamics, with their masses (kg): those with an
    ``<inertial>`` of positive mass that a joint of the model moves (a link fixed to the base, or to it through
    locked joints only, moves with nothing).  Empty for an arm not read from a URDF."""
    model, source = getattr(arm, "pin_model", None), getattr(arm, "source_path", None)
    if model is None or not source:
        return {}
    moved = {f.name for f in model.frames if f.parentJoint > 0 and str(f.type).endswith("BODY")}
    out = {}
    for link in _urdf_root(source).findall("link"):
        mass = link.find("inertial/mass")
        value = float(mass.get("value", "0")) if mass is not None else 0.0
        if link.get("name") in moved and value > 0:
            out[link.get("name")] = value
    return out


def _urdf_root(source: str):
    import xml.etree.ElementTree as ET
    return ET.parse(source).getroot()


def link_scaled_nominal(arm: ArmModel, given: dict, base: Path | None, scales: dict, error) -> ArmModel:
    """The nominal model of a URDF arm with each named link's mass and inertia times its factor (``[nominal_scale]``,
    link name -> factor > 0; centres of mass kept): the URDF so changed, read as the true arm was (``given``: the
    ``[arm]`` values it was loaded with, the file relative to ``base``).

    The merged bodies (a link on a fixed joint joins its parent's body) are pinocchio's, as for the true arm.
    """
    allowed = link_masses(arm)
    bad = sorted(set(scales) - set(allowed))
    if bad:
        raise error(f"[nominal_scale] names {', '.join(repr(b) for b in bad)}, not a link of the arm whose mass moves "
                    f"with a joint; its links: {', '.join(allowed)} (a factor > 0 scales that link's mass and inertia "
                    "in the controller's and observer's model)")
    key = (id(arm), tuple(sorted(scales.items())))
    found = _scaled.get(key)
    if found is not None and found[0] is arm:
        return found[1]
    import os
    import tempfile
    import xml.etree.ElementTree as ET
    root = _urdf_root(arm.source_path)
    for link in root.findall("link"):
        factor = scales.get(link.get("name"))
        if factor is None:
            continue
        mass, inertia = link.find("inertial/mass"), link.find("inertial/inertia")
        mass.set("value", repr(float(mass.get("value")) * factor))
        if inertia is not None:
            for name in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                if inertia.get(name) is not None:
                    inertia.set(name, repr(float(inertia.get(name)) * factor))
    handle, path = tempfile.mkstemp(suffix=".urdf", prefix="dobkit-nominal-")
    try:
        with os.fdopen(handle, "wb") as f:
            ET.ElementTree(root).write(f, encoding="utf-8", xml_declaration=True)
        values = dict(given, urdf=path)
        values.pop("nominal_mass_scale", None)
        from blocks.model.urdf.urdf import load_urdf_arm
        locked = list(values.get("locked", []))
        nominal = load_urdf_arm(path, values["tool_frame"], locked=locked,
                                locked_values=dict(zip(locked, values.get("locked_values", []))),
                                gravity=_gravity(values["gravity"]) if "gravity" in values else None)
    except (ValueError, OSError) as err:
        # the copy's temporary name means nothing to the user, and the reader's advice is for a file's author
        reason = str(err).replace(f"'{path}'", "the arm's URDF with these factors").replace(path, "the copy")
        raise error(f"[nominal_scale] {scales} leaves no usable nominal model (the factors multiply the links' "
                    f"masses and inertias; choose factors nearer 1): {reason}") from None
    finally:
        os.unlink(path)
    nominal.source, nominal.pin_model = arm.source, None        # the reference model is the true arm's
    nominal.source_path = arm.source_path
    _scaled[key] = (arm, nominal)
    while len(_scaled) > _KEPT:
        _scaled.pop(next(iter(_scaled)))
    return nominal


def joint_sine_defaults(arm: ArmModel) -> dict:
    """A joint sine that suits ``arm``: 0.1 rad (revolute) or 0.01 m (prismatic) about the middle of each
    joint's range (0 where a joint turns without end), 1 rad/s."""
    amplitude, offset = [], []
    for kind, (lo, hi) in zip(arm.joints.kinds, arm.joints.limits):
        amplitude.append(0.1 if kind == "revolute" else 0.01)
        offset.append(0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else 0.0)
    return {"amplitude": tuple(amplitude), "omega": 1.0, "offset": tuple(offset)}


def observer_gain_from_bandwidth(nominal: ArmModel, omega: float, q0) -> np.ndarray:
    """``Y = omega M^(q0)`` (kg m^2/s, kg/s): the observer gain whose error dynamics ``e_d' = -Y M^-1 e_d`` are
    ``-omega e_d`` at ``q0`` on the nominal model (a first-order filter of bandwidth ``omega`` rad/s per joint)."""
    M = np.asarray(nominal.inertia(np.asarray(q0, dtype=float)), dtype=float)
    return omega * 0.5 * (M + M.T)


def skin_height_default(arm: ArmModel, q0) -> float:
    """The skin plane of the tissue contact for an arm that does not set ``disturbance.skin_height``: the tool
    point's height (m, base frame) at the reference's start ``q0``.

    The tool then starts on the skin, and the tissue resists wherever the motion takes it lower.  The start of the
    reference (not ``initial.q``) is used because the members of a batch share it, as they share the plane.
    """
    return float(np.asarray(arm.tool_position(np.asarray(q0, dtype=float)), dtype=float)[2])
