"""Any serial arm from a URDF file: pinocchio reads it, dobkit's kernels do the maths.

:func:`load_urdf_arm` parses the file with pinocchio (``pip install
"dobkit[urdf]"``), removes the joints the user locks, and copies what the
dynamics need into a :class:`~blocks.kernels.chain.ChainParams`: each
moving joint's parent, placement and axis, and the inertia of the body it
moves (pinocchio merges links on fixed joints into their parent's body).
Joint names, kinds and limits come from the URDF.

Supported joints: ``revolute``, ``continuous`` (one angle to the user;
pinocchio's ``(cos, sin)`` pair is converted), ``prismatic`` (axes in any
direction, negative or unaligned) and ``fixed``.  ``floating``,
``planar`` and ``spherical`` joints are refused by name, and so is a
``<mimic>`` joint that is not locked (unless ``mimic="independent"``).  A
tree is kept as it is: joints on branches off the tool's chain are joints of
the model unless locked.  The file's own XML is checked first (one tree of
uniquely named links, every number dobkit reads present, finite and written
as urdfdom reads it, axes non-zero, ``lower <= upper``, a ``lower`` or
``upper`` not given read as 0 as URDF says): urdfdom drops an ``<inertial>``
it cannot read without failing and says so only on stderr, so what it says
there is a refusal too.  A file is read only when it is a regular file of at
most :data:`MAX_URDF_BYTES` bytes, :data:`MAX_URDF_LINKS` links and
:data:`MAX_URDF_DEPTH` links deep (pinocchio walks the tree recursively: 5000
deep overflowed its stack, a segmentation fault).
"""
from __future__ import annotations

import collections
import contextlib
import math
import os
import re
import stat
import sys
import tempfile
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from blocks.kernels.chain import ChainParams
from blocks.model.joints import JointSpace
from blocks.model.urdf.chain_model import ChainArm

__all__ = ["UrdfError", "UrdfFileError", "UrdfParseError", "UnknownFrameError", "UnknownJointError",
           "UnsupportedJointError", "InertiaError", "load_urdf_arm", "chain_from_pinocchio"]


#: The most moving joints an arm may have (serial arms have 4 to 9; beyond a few dozen the dynamics' cost per
#: evaluation, which grows as n^2, and the length of the traced code make a run impractical).
MAX_JOINTS = 32

#: The largest URDF file read, in bytes (example-robot-data's largest, TIAGo dual, is 0.2 MB).
MAX_URDF_BYTES = 4 * 2 ** 20
#: The most links a URDF may have (TIAGo dual has 130): pinocchio's reading and dobkit's checks grow with them.
MAX_URDF_LINKS = 2000
#: The deepest chain of links from the base, the base counted (pinocchio walks the tree recursively, each level a
#: few frames of C stack: 5000 deep ended the process with a segmentation fault; arms are tens deep).
MAX_URDF_DEPTH = 256


class UrdfError(ValueError):
    """A URDF arm cannot be built; the message names the file, joint, frame or value and what is allowed."""


class UrdfFileError(UrdfError):
    """The URDF file does not exist or cannot be read."""


class UrdfParseError(UrdfError):
    """The file is not a URDF robot description pinocchio can read."""


class UnknownFrameError(UrdfError):
    """The tool frame is not a frame of the model (the message lists the frames)."""


class UnknownJointError(UrdfError):
    """A locked joint is not a moving joint of the model (the message lists them), or its value is out of range."""


class UnsupportedJointError(UrdfError):
    """The URDF has a joint of a type dobkit does not model (floating, planar, spherical, ...)."""


class InertiaError(UrdfError):
    """A body has a negative mass or an inertia that is not positive semi-definite, or ``M(q)`` is singular."""


# pinocchio joint models of one degree of freedom, by short name: revolute (R*), continuous (RUB*), prismatic (P*)
_REVOLUTE = {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned"}
_CONTINUOUS = {"JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned"}
_PRISMATIC = {"JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned"}
_URDF_TYPES = {"revolute", "continuous", "prismatic", "fixed"}

#: Entries of rotations and axes this close to 0 or +-1 are taken as exact, so a trace skips them
#: (``rpy = pi/2`` gives cos = 6e-17 in floating point); so are inertia entries this small relative to the largest.
SNAP = 1e-14


def _pinocchio():
    try:
        import pinocchio
    except ImportError as exc:          # pragma: no cover - the extra is installed where tests run
        raise ImportError('URDF arms need pinocchio: pip install "dobkit[urdf]"') from exc
    return pinocchio


def _snap(x: float) -> float:
    x = float(x)
    if abs(x) < SNAP:
        return 0.0
    if abs(abs(x) - 1.0) < SNAP:
        return math.copysign(1.0, x)
    return x


def _vec(v, snap: bool = False, snap_below: float = 0.0) -> tuple:
    return tuple(_snap(x) if snap else (0.0 if abs(x) < snap_below else float(x))
                 for x in np.asarray(v, dtype=float).ravel())


def _mat(m, snap: bool = False, snap_below: float = 0.0) -> tuple:
    """Rows as tuples; ``snap`` takes entries near 0 and +-1 as exact, ``snap_below`` zeroes smaller entries."""
    return tuple(_vec(row, snap, snap_below) for row in np.asarray(m, dtype=float))


# what urdfdom's strToDouble reads (a C++ stream in the classic locale that must reach the end of the text): C
# white space before, ASCII digits, an optional sign, point and exponent, nothing after; Python's float() also takes
# "0_35", " 0.35 ", other scripts' digits, "nan" and "inf", which urdfdom refuses (and drops the element)
_C_SPACE = " \t\n\v\f\r"
_URDFDOM_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def _urdfdom_number(text: str) -> float | None:
    """The number urdfdom reads from ``text``, or None where it reads none (or one beyond a double)."""
    text = text.lstrip(_C_SPACE)
    if not _URDFDOM_NUMBER.fullmatch(text):
        return None
    value = float(text)
    return value if math.isfinite(value) else None


def _numbers(element, attribute: str, count: int, where: str, path: Path) -> tuple | None:
    """The ``count`` finite numbers of ``element``'s ``attribute`` (None when absent), read as urdfdom reads them
    (one number; or ``count`` of them separated by spaces); refused by name otherwise.

    urdfdom drops an ``<inertial>`` whose numbers it cannot read, silently: the link would lose its mass.
    """
    if element is None or element.get(attribute) is None:
        return None
    text = element.get(attribute)
    pieces = [text] if count == 1 else [p for p in text.split(" ") if p]
    values = tuple(_urdfdom_number(p) for p in pieces)
    if len(values) != count or None in values:
        raise UrdfParseError(f"URDF file {str(path)!r}: {where} {attribute}={text!r}; it must be {count} finite "
                             f"number{'s' if count > 1 else ''} (SI units, separated by spaces) as URDF readers "
                             "take them: ASCII digits with an optional sign, point and exponent, nothing after the "
                             "last (urdfdom drops an element it cannot read)")
    return values


def _check_numbers(root, path: Path) -> None:
    """Every number dobkit's dynamics read (inertials, origins, axes, limits) is present and finite."""
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        where = f"link {link.get('name')!r} <inertial>"
        _numbers(inertial.find("origin"), "xyz", 3, f"{where} <origin>", path)
        _numbers(inertial.find("origin"), "rpy", 3, f"{where} <origin>", path)
        for tag, names in (("mass", ("value",)), ("inertia", ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))):
            element = inertial.find(tag)
            for name in names:
                if element is None or element.get(name) is None:
                    raise UrdfParseError(f"URDF file {str(path)!r}: {where} has no <{tag} {name}=...>; an "
                                         f"<inertial> needs <mass value> and <inertia ixx ixy ixz iyy iyz izz>")
                _numbers(element, name, 1, f"{where} <{tag}>", path)
    for joint in root.findall("joint"):
        where = f"joint {joint.get('name')!r}"
        _numbers(joint.find("origin"), "xyz", 3, f"{where} <origin>", path)
        _numbers(joint.find("origin"), "rpy", 3, f"{where} <origin>", path)
        axis = _numbers(joint.find("axis"), "xyz", 3, f"{where} <axis>", path)
        if axis is not None and joint.get("type") != "fixed" and not any(axis):
            raise UrdfParseError(f"URDF file {str(path)!r}: {where} <axis> xyz={joint.find('axis').get('xyz')!r} "
                                 "has no direction; an axis must be a non-zero vector")
        squared = math.fsum(v * v for v in axis) if axis is not None else 1.0
        if joint.get("type") != "fixed" and not sys.float_info.min <= squared < math.inf:
            # pinocchio divides by the length: 0 1e-200 0 squares to 0 (then 'yaw moves no mass' was said)
            raise UrdfParseError(f"URDF file {str(path)!r}: {where} <axis> xyz={joint.find('axis').get('xyz')!r} "
                                 f"cannot be normalised in double precision (its squared length is {squared:.3g}); "
                                 "write the axis as a unit vector, e.g. '0 1 0'")
        limit = joint.find("limit")
        if limit is None and joint.get("type") in ("revolute", "prismatic"):
            raise UrdfParseError(f"URDF file {str(path)!r}: {where} is {joint.get('type')} without <limit lower upper "
                                 "effort velocity>, which URDF requires (a revolute joint without end is 'continuous')")
        bounds = [_numbers(limit, name, 1, f"{where} <limit>", path) for name in ("lower", "upper")]
        if limit is not None and joint.get("type") in ("revolute", "prismatic"):
            lower, upper = (0.0 if b is None else b[0] for b in bounds)      # URDF: an attribute not given is 0
            if lower > upper:
                unsaid = " and ".join(f"{n} is not given, which URDF reads as 0" for n, b in
                                      zip(("lower", "upper"), bounds) if b is None)
                raise UrdfParseError(f"URDF file {str(path)!r}: {where} <limit> lower={lower:g} is above "
                                     f"upper={upper:g}{' (' + unsaid + ')' if unsaid else ''}; give lower <= upper")


def _check_tree(root, path: Path) -> None:
    """One tree of links: names unique, every joint between two links, each link the child of one joint at most."""
    links = [link.get("name") for link in root.findall("link")]
    if len(links) > MAX_URDF_LINKS:
        raise UrdfParseError(f"URDF file {str(path)!r} has {len(links)} links; dobkit reads at most {MAX_URDF_LINKS} "
                             "(MAX_URDF_LINKS; robots have tens to a few hundred)")
    joints = root.findall("joint")
    for kind, names in (("link", links), ("joint", [j.get("name") for j in joints])):
        counts = collections.Counter(names)
        twice = sorted((n for n, c in counts.items() if c > 1), key=str)
        if twice:
            raise UrdfParseError(f"URDF file {str(path)!r}: {kind} name(s) {twice} given more than once; each "
                                 f"{kind} needs its own name")
    parent_of: dict = {}
    known = set(links)
    for joint in joints:
        ends = [(tag, None if joint.find(tag) is None else joint.find(tag).get("link")) for tag in ("parent", "child")]
        for tag, link in ends:
            if link not in known:
                raise UrdfParseError(f"URDF file {str(path)!r}: joint {joint.get('name')!r} has <{tag} link="
                                     f"{link!r}>, which is not a link of the file")
        child = ends[1][1]
        if child in parent_of:
            raise UrdfParseError(f"URDF file {str(path)!r}: link {child!r} is the child of joints "
                                 f"{parent_of[child][0]!r} and {joint.get('name')!r}; a URDF is a tree (no closed "
                                 "loops): each link hangs from one joint")
        parent_of[child] = (joint.get("name"), ends[0][1])
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise UrdfParseError(f"URDF file {str(path)!r}: the links form {len(roots)} trees (root links {roots}); a "
                             "URDF arm is one tree from one base link")
    _check_depth(parent_of, links, path)


def _check_depth(parent_of: dict, links: list, path: Path) -> None:
    """No link deeper than :data:`MAX_URDF_DEPTH` below the base, and no loop apart from the tree; without
    recursion (the walk that must not overflow the stack is pinocchio's)."""
    depth: dict = {}
    for start in links:
        chain = []
        link = start
        while link not in depth and link in parent_of:
            chain.append(link)
            if len(chain) > len(links):
                raise UrdfParseError(f"URDF file {str(path)!r}: link {start!r} hangs from a closed loop of joints, "
                                     "not from the base; a URDF is a tree (no closed loops)")
            link = parent_of[link][1]
        level = depth.get(link, 1)
        depth[link] = level
        for name in reversed(chain):
            level += 1
            depth[name] = level
            if level > MAX_URDF_DEPTH:
                raise UrdfParseError(f"URDF file {str(path)!r}: link {name!r} is {level} links deep from the base "
                                     f"(and the file has {len(links)}); dobkit reads trees at most {MAX_URDF_DEPTH} "
                                     "deep (MAX_URDF_DEPTH: pinocchio walks the tree recursively, and a deep one "
                                     "overflows its stack)")


def _read_urdf(path: Path) -> tuple[dict, dict]:
    """Joint name -> (URDF type, lower, upper) from the file's XML, and mimic joint -> the joint it mimics,
    checking it is a robot description whose numbers and tree pinocchio will read as written."""
    data = _read_bounded(path)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise UrdfParseError(f"URDF file {str(path)!r} is not well-formed XML: {exc}") from exc
    if root.tag != "robot":
        raise UrdfParseError(f"URDF file {str(path)!r} has root element <{root.tag}>; a URDF's root is <robot>")
    joints, mimics = {}, {}
    for j in root.iter("joint"):
        if j.get("name") is None or j.get("type") is None:
            continue                     # a transmission's <joint> reference, not a joint
        kind = j.get("type")
        if kind not in _URDF_TYPES:
            raise UnsupportedJointError(
                f"URDF file {str(path)!r}: joint {j.get('name')!r} is of type {kind!r}; dobkit models "
                f"{sorted(_URDF_TYPES)} joints (lock or remove the others)")
    _check_tree(root, path)
    _check_numbers(root, path)
    for j in root.findall("joint"):
        kind = j.get("type")
        limit = j.find("limit")
        # URDF (urdfdom, pinocchio): a lower or upper not given is 0
        lower = _urdfdom_number(limit.get("lower", "0")) if limit is not None and kind != "continuous" else -math.inf
        upper = _urdfdom_number(limit.get("upper", "0")) if limit is not None and kind != "continuous" else math.inf
        if not lower < upper:            # a URDF without a real range (lower = upper = 0): no limits
            lower, upper = -math.inf, math.inf
        joints[j.get("name")] = (kind, lower, upper)
        if j.find("mimic") is not None and kind != "fixed":
            mimics[j.get("name")] = j.find("mimic").get("joint")
    return joints, mimics


def _read_bounded(path: Path) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_URDF_BYTES`, opened without blocking and checked on the
    open file (a FIFO would wait for a writer, ``/dev/zero`` has no end)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as err:
        raise UrdfFileError(f"URDF file {str(path)!r} cannot be read ({err.strerror or err})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UrdfFileError(f"URDF file {str(path)!r} is not a regular file (a folder, device, pipe or socket); "
                                "give the path of a .urdf file")
        data = f.read(MAX_URDF_BYTES + 1)
    if len(data) > MAX_URDF_BYTES:
        raise UrdfParseError(f"URDF file {str(path)!r} has more than {MAX_URDF_BYTES:,} bytes; dobkit reads URDF "
                             f"files of at most {MAX_URDF_BYTES:,} (MAX_URDF_BYTES; a robot's is well under 1 MB: "
                             "meshes are separate files)")
    return data


def _check_inertia(name: str, mass: float, inertia: np.ndarray) -> None:
    if not (math.isfinite(mass) and mass >= 0.0) or not np.all(np.isfinite(inertia)):
        raise InertiaError(f"the body moved by joint {name!r} has mass {mass!r} kg; it must be finite and >= 0")
    eig = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    scale = max(float(np.max(np.abs(eig))), 1e-300)
    if eig[0] < -1e-12 * scale:
        raise InertiaError(f"the body moved by joint {name!r} has a rotational inertia with eigenvalues "
                           f"{eig.tolist()} kg m^2; it must be positive semi-definite")


def tool_frame_id(model, name: str) -> int:
    """The index of the frame ``name`` in a pinocchio model; where a link and a joint share the name, the link's.

    URDF places a link's frame at the joint that carries it, so the link (pinocchio ``BODY``) frame and the frame
    of its parent joint of the same name are one place: the link's is taken, and the choice changes no number.
    Any other ambiguity (two links of one name, or a name two joints share) raises :class:`UnknownFrameError`.
    """
    pin = _pinocchio()
    matches = [k for k, f in enumerate(model.frames) if f.name == name]
    if len(matches) == 1:
        return matches[0]
    links = [k for k in matches if model.frames[k].type == pin.FrameType.BODY]
    if len(links) == 1:
        return links[0]
    kinds = ", ".join(str(model.frames[k].type).rsplit(".", 1)[-1].lower() for k in matches)
    raise UnknownFrameError(f"tool frame {name!r} names {len(matches)} frames of the model ({kinds}) and not exactly "
                            "one link: rename one in the URDF")


def chain_from_pinocchio(model, tool_frame: str, gravity=None) -> tuple[ChainParams, tuple, tuple]:
    """The :class:`ChainParams` of a pinocchio model (fixed base, 1-DOF joints) with the tool at ``tool_frame``.

    Returns
    -------
    chain : ChainParams
    kinds : tuple of str
        ``"revolute"`` or ``"prismatic"`` per joint.
    continuous : tuple of bool
        Whether each joint is continuous (pinocchio's ``(cos, sin)``).
    """
    pin = _pinocchio()
    if not model.existFrame(tool_frame):
        frames = [f.name for f in model.frames if f.name != "universe"]
        raise UnknownFrameError(f"tool frame {tool_frame!r} is not a frame of the model; its frames are {frames}")
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    names, kinds, continuous, parents = [], [], [], []
    rotations, translations, axes, masses, coms, inertias = [], [], [], [], [], []
    for j in range(1, model.njoints):
        name, short = model.names[j], model.joints[j].shortname()
        if short in _REVOLUTE or short in _CONTINUOUS:
            kind = "revolute"
        elif short in _PRISMATIC:
            kind = "prismatic"
        else:
            raise UnsupportedJointError(f"joint {name!r} is a pinocchio {short}; dobkit models revolute, continuous, "
                                        "prismatic and fixed joints (lock it or remove it)")
        S = np.asarray(data.joints[j].S).ravel()           # (v, w) in the joint's frame, constant for these joints
        axis = S[3:] if kind == "revolute" else S[:3]
        placement = model.jointPlacements[j]
        inertia = model.inertias[j]
        m, c, Ic = float(inertia.mass), np.asarray(inertia.lever, float), np.asarray(inertia.inertia, float)
        _check_inertia(name, m, Ic)
        names.append(name)
        kinds.append(kind)
        continuous.append(short in _CONTINUOUS)
        parents.append(int(model.parents[j]) - 1)
        rotations.append(_mat(placement.rotation, snap=True))
        translations.append(_vec(placement.translation))
        axes.append(_vec(axis / np.linalg.norm(axis), snap=True))
        masses.append(m)
        coms.append(_vec(c))
        inertias.append(_mat(Ic, snap_below=SNAP * float(np.max(np.abs(Ic)))))
    if gravity is None:
        g = _vec(model.gravity.linear)
    else:
        g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise UrdfError(f"gravity {gravity!r} must be a finite 3-vector in m/s^2 in the base frame "
                            "(default (0, 0, -9.81))")
        g = _vec(g)
    frame = model.frames[tool_frame_id(model, tool_frame)]
    chain = ChainParams(names=tuple(names), kinds=tuple(kinds), parents=tuple(parents), rotations=tuple(rotations),
                        translations=tuple(translations), axes=tuple(axes), masses=tuple(masses),
                        coms=tuple(coms), com_inertias=tuple(inertias), gravity=g,
                        tool_joint=int(frame.parentJoint) - 1, tool_rotation=_mat(frame.placement.rotation, snap=True),
                        tool_translation=_vec(frame.placement.translation))
    return chain, tuple(kinds), tuple(continuous)


def load_urdf_arm(path, tool_frame: str, locked=(), locked_values=None, gravity=None, *,
                  mimic: str = "refuse") -> ChainArm:
    """An arm model read from a URDF file.

    Parameters
    ----------
    path : str or pathlib.Path
        The URDF file (meshes are not read).
    tool_frame : str
        A link or joint name of the URDF: the tool point is its origin.
    locked : sequence of str, optional
        Joints held fixed (removed from the model): a gripper's fingers, say.
    locked_values : dict of str to float, optional
        Position of locked joints (rad, m; an angle for a continuous joint);
        a locked joint not given here is held at 0.
    gravity : sequence of 3 floats, optional
        Gravitational acceleration in the base frame (m/s^2); default the
        URDF world's ``(0, 0, -9.81)``.
    mimic : {"refuse", "independent"}
        A joint with ``<mimic>`` that is not locked: refused (default), or
        read as a joint of its own, as pinocchio reads it (a gripper's second
        finger driven on its own).

    Returns
    -------
    ChainArm
        With ``pin_model`` set to the reduced pinocchio model.

    Raises
    ------
    UrdfError
        (a ``ValueError``) or one of its subclasses, naming what is wrong: a
        missing file, a file that is no URDF, an unknown tool frame or
        locked joint, an unsupported joint type, a locked value out of
        range, a body of negative mass or inertia, an arm whose ``M(q)`` is
        singular (a joint that moves no mass).

    Examples
    --------
    >>> from blocks.model.urdf import load_urdf_arm, scope4_urdf
    >>> arm = load_urdf_arm(scope4_urdf(), "tool_tip")
    >>> arm.joints.names
    ('yaw', 'pitch', 'insertion', 'roll')
    """
    pin = _pinocchio()
    path = Path(path)
    if not path.exists():
        raise UrdfFileError(f"URDF file {str(path)!r} does not exist (or is not a file)")
    xml_joints, mimics = _read_urdf(path)
    with _stderr_kept() as said:       # urdfdom writes its reasons to the process's stderr, not to the exception
        try:
            model = pin.buildModelFromUrdf(str(path))
        except (RuntimeError, ValueError) as exc:
            reasons = "; ".join(said())
            raise UrdfParseError(f"pinocchio cannot read URDF file {str(path)!r}: {reasons or exc}") from exc
        dropped = said()
    if dropped:     # read, but without what urdfdom could not read (a link's <inertial>, say): refused, not dropped
        raise UrdfParseError(f"URDF file {str(path)!r}: urdfdom (pinocchio's URDF reader) could not read all of it "
                             f"and would go on without it: {'; '.join(dropped)}; write it as URDF requires")

    locked = [locked] if isinstance(locked, str) else list(locked)
    moving = [model.names[j] for j in range(1, model.njoints)]
    locked_values = dict(locked_values or {})
    for name in locked:
        if name not in moving:
            raise UnknownJointError(f"locked joint {name!r} is not a moving joint of {str(path)!r}; "
                                    f"its moving joints are {moving}")
    twice = sorted({name for name in locked if locked.count(name) > 1})
    if twice:
        raise UnknownJointError(f"locked joint(s) {twice} named more than once in locked {locked}")
    if moving and set(moving) <= set(locked):
        raise UnknownJointError(f"locked {locked} holds every moving joint of {str(path)!r}: nothing is left to "
                                "move; lock fewer joints")
    if mimic not in ("refuse", "independent"):
        raise UrdfError(f"mimic must be 'refuse' or 'independent', got {mimic!r}")
    free_mimics = {name: of for name, of in mimics.items() if name not in locked}
    if free_mimics and mimic == "refuse":
        name, of = next(iter(free_mimics.items()))
        raise UnsupportedJointError(f"joint {name!r} of {str(path)!r} mimics joint {of!r} (<mimic>): dobkit drives "
                                    "every joint on its own and would move it freely; lock it with 'locked' (held at "
                                    "its locked value) or remove the <mimic>")
    extra = sorted(set(locked_values) - set(locked))
    if extra:
        raise UnknownJointError(f"locked_values names {extra}, which are not in locked {locked}")
    q_ref = pin.neutral(model)
    for name in locked:
        j = model.getJointId(name)
        value = float(locked_values.get(name, 0.0))
        _, lo, hi = xml_joints.get(name, (None, -math.inf, math.inf))
        if not (math.isfinite(value) and lo <= value <= hi):
            given = "" if name in locked_values else (" (the default; give its position: arm.locked_values, or "
                                                      "--locked NAME=VALUE on the command line)")
            raise UnknownJointError(f"locked joint {name!r} at {value!r}{given} is outside its range {lo:g} to "
                                    f"{hi:g}")
        iq = model.joints[j].idx_q
        if model.joints[j].nq == 2:
            q_ref[iq:iq + 2] = (math.cos(value), math.sin(value))
        else:
            q_ref[iq] = value
    if locked:
        model = pin.buildReducedModel(model, [model.getJointId(name) for name in locked], q_ref)
    moving = [model.names[j] for j in range(1, model.njoints)]
    if len(moving) > MAX_JOINTS:
        raise UnsupportedJointError(
            f"URDF file {str(path)!r} has {len(moving)} moving joints after locking {len(locked)}; dobkit takes at "
            f"most {MAX_JOINTS} (a serial arm's dynamics grow as n^2 per evaluation, and the traced code with them): "
            f"lock the joints the study does not move with 'locked'")

    chain, kinds, continuous = chain_from_pinocchio(model, tool_frame, gravity)
    limits = tuple(xml_joints.get(name, (None, -math.inf, math.inf))[1:] for name in chain.names)
    joints = JointSpace(names=chain.names, kinds=kinds, limits=limits)
    arm = ChainArm(chain, joints, tool_frame, continuous=continuous, source=str(path))
    arm.pin_model = model
    # the file itself, wherever the working folder goes later (source is the name as given, for messages)
    arm.source_path = str(Path(path).resolve())
    _check_positive_definite(arm)
    return arm


@contextlib.contextmanager
def _stderr_kept():
    """Capture what native code writes to file descriptor 2 while the body runs; yields a function giving its
    ``Error:`` lines (urdfdom's reasons for refusing a file), without the source locations."""
    def said() -> list[str]:
        kept.seek(0)
        lines = kept.read().decode("utf-8", "replace").splitlines()
        return [line.split("Error:", 1)[1].strip() for line in lines if line.lstrip().startswith("Error:")]

    # descriptor 2 is the process's: one redirection at a time, and always restored (an interrupt included)
    with _STDERR_LOCK, tempfile.TemporaryFile() as kept:
        saved = None
        try:
            try:
                if sys.stderr is not None:
                    sys.stderr.flush()
                saved = os.dup(2)
                os.dup2(kept.fileno(), 2)
            except (OSError, ValueError, AttributeError):   # no usable descriptor 2 (an embedded interpreter)
                pass
            yield said
        finally:
            if saved is not None:
                os.dup2(saved, 2)
                os.close(saved)


_STDERR_LOCK = threading.Lock()


def _check_positive_definite(arm: ChainArm) -> None:
    """``M(q)`` must be positive definite: every joint moves some mass or inertia about its axis."""
    q = np.array([0.0 if math.isinf(lo) or math.isinf(hi) else 0.5 * (lo + hi) for lo, hi in arm.joints.limits])
    M = arm.inertia(q)
    scale = max(float(np.max(np.abs(np.diag(M)))), 1e-300)
    for i in range(arm.n):                # the leading minors: the first that fails names the joint
        smallest = float(np.linalg.eigvalsh(M[:i + 1, :i + 1])[0])
        if smallest > 1e-12 * scale:
            continue
        if M[i, i] > 1e-12 * scale or smallest <= 0.0 or not math.isfinite(scale):
            raise InertiaError(f"joint {arm.joints.names[i]!r} of {arm.source!r} moves no mass or inertia "
                               f"(M(q) is singular at q = {q.tolist()}); give its links <inertial> elements")
        # it moves something, but so little next to the heaviest joint that M cannot be inverted in doubles
        unit = "kg" if arm.joints.kinds[i] == "prismatic" else "kg m^2"
        raise InertiaError(f"joint {arm.joints.names[i]!r} of {arm.source!r} moves {M[i, i]:.3g} {unit} at q = "
                           f"{q.tolist()}, while M's largest diagonal entry is {scale:.3g}: the arm's inertias "
                           "differ by more than 1e12, which double precision cannot invert; is a mass or an inertia "
                           "in the wrong unit?")
