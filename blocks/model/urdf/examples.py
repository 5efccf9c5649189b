"""The example arms by name: dobkit's own scope4, and every serial arm example-robot-data ships.

``example-robot-data`` (installed with ``pip install "dobkit[urdf]"``) is a
cmeel package: its files sit under ``<site-packages>/cmeel.prefix/share/
example-robot-data/robots/``.  They are found through the package's
installed-file record, so no path of an environment is written here.

Which of its robots are arms is read from the URDF files themselves, lightly
(XML only, no pinocchio: :func:`serial_chain`): a robot is an example arm when
its moving joints, from the root link on, form one chain -- every link on the
way has one child branch that moves something -- that may end in a gripper
(branches of one moving joint each past the chain's last link: a hand's
fingers, which are locked).  Legged robots, humanoids, hands and mobile
manipulators branch earlier and are not listed.  An arm is named by its file's
stem, lower case (``z1``, ``so101``, ``kinova``, ``double_pendulum``; a
``_robot`` suffix dropped where no other file takes the name: ``ur5``,
``ur10``); its tool frame defaults to the chain's last frame (the last moving
joint's link, or the link that fixed joints carry on to from there while they
do not branch).  The UR5 and the Panda keep the tool frames dobkit always gave
them (``tool0``, ``panda_hand``).

The listing is read once per process and installed version (about 70 files of
XML; a tenth of a second).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import metadata
from importlib.resources import files
from pathlib import Path

__all__ = ["EXAMPLES", "ExampleArm", "example_arms", "example_names", "example_urdf", "scope4_urdf", "example_arm",
           "serial_chain", "UnknownExampleError"]

#: Tool frames and locked joints dobkit gave these examples before every arm was listed (kept: scenarios use them).
#: Example name -> (file under example-robot-data's ``robots/``, tool frame, locked joints).
EXAMPLES = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0", ()),
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand", ("panda_finger_joint1", "panda_finger_joint2")),
}

_ROBOTS = "example-robot-data/robots/"
_MOVING = ("revolute", "continuous", "prismatic")


class UnknownExampleError(ValueError):
    """``example:NAME`` names no example arm; the message lists the names there are."""


@dataclass(frozen=True)
class ExampleArm:
    """One example arm as its URDF file describes it (read without pinocchio).

    Attributes
    ----------
    name : str
        Its name in ``example:NAME``.
    file : str
        The file under example-robot-data's ``robots/`` (``scope4``: dobkit's own).
    tool_frame : str
        The default tool frame.
    locked : tuple of str
        Joints held fixed by default (a gripper's fingers).
    joints : tuple of str
        The moving joints, base first (locked ones left out).
    kinds : tuple of str
        Their URDF types: ``revolute``, ``continuous`` or ``prismatic``.
    limits : tuple of (float, float)
        Their ranges (rad, m); ``(-inf, inf)`` where the file gives none.
    """

    name: str
    file: str
    tool_frame: str
    locked: tuple
    joints: tuple
    kinds: tuple
    limits: tuple


def scope4_urdf() -> Path:
    """The bundled 4-joint surgical arm (yaw, pitch, insertion, roll; tool frame ``tool_tip``)."""
    return Path(str(files("blocks.model.urdf") / "data" / "scope4.urdf"))


# --------------------------------------------------------------------------------------------------------------
# Reading a URDF's tree lightly
# --------------------------------------------------------------------------------------------------------------
def _limits(joint) -> tuple:
    limit = joint.find("limit")
    if joint.get("type") == "continuous" or limit is None:
        return (-math.inf, math.inf)
    try:
        lower, upper = float(limit.get("lower", "-inf")), float(limit.get("upper", "inf"))
    except ValueError:
        return (-math.inf, math.inf)
    return (lower, upper) if lower < upper else (-math.inf, math.inf)


def serial_chain(root) -> tuple | None:
    """The serial chain of a URDF's XML tree ``root``: ``(joints, tool_frame, locked)``, or None when it has none.

    ``joints`` are the chain's moving joint elements, base first; ``locked``
    names the gripper joints past its end.  None when a link branches into two
    moving branches before the chain ends (a legged robot, a hand, two arms),
    when the file has a joint of another type (floating, planar) or no moving
    joint, or when its links do not form one tree.
    """
    joints = [j for j in root.findall("joint") if j.get("name") and j.get("type")]
    if any(j.get("type") not in _MOVING + ("fixed",) for j in joints):
        return None
    children: dict[str, list] = {}
    child_links = set()
    for j in joints:
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            return None
        children.setdefault(parent.get("link"), []).append(j)
        child_links.add(child.get("link"))
    roots = {link.get("name") for link in root.findall("link")} - child_links
    if len(roots) != 1:
        return None

    moving_below: dict[str, int] = {}

    def count(link: str) -> int:            # moving joints in the subtree of a link (iteratively: deep files)
        order, stack = [], [link]
        while stack:
            node = stack.pop()
            order.append(node)
            stack.extend(j.find("child").get("link") for j in children.get(node, ()))
        for node in reversed(order):
            moving_below[node] = sum(moving_below[j.find("child").get("link")] + (j.get("type") in _MOVING)
                                     for j in children.get(node, ()))
        return moving_below[link]

    count(next(iter(roots)))

    def moves(j) -> int:
        return moving_below[j.find("child").get("link")] + (j.get("type") in _MOVING)

    chain, link, last_link, locked = [], next(iter(roots)), None, ()
    while True:
        branches = [j for j in children.get(link, ()) if moves(j)]
        if len(branches) > 1:
            # a gripper: every branch one moving joint, past at least one joint of the chain
            if not chain or any(moves(j) != 1 for j in branches):
                return None
            locked = tuple(sub.get("name") for j in branches for sub in _subtree_joints(j, children)
                           if sub.get("type") in _MOVING)
            return chain, link, locked          # the tool frame: the gripper's palm, where its fingers branch
        if not branches:
            break
        j = branches[0]
        if j.get("type") in _MOVING:
            chain.append(j)
            last_link = j.find("child").get("link")
        link = j.find("child").get("link")
    if not chain:
        return None
    # the tool frame: the last moving joint's link, carried on along fixed joints while they do not branch
    tool = last_link
    while True:
        fixed = [j for j in children.get(tool, ()) if j.get("type") == "fixed"]
        if len(fixed) != 1 or moving_below[tool]:
            break
        tool = fixed[0].find("child").get("link")
    return chain, tool, locked


def _subtree_joints(joint, children: dict) -> list:
    out, stack = [], [joint]
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(children.get(j.find("child").get("link"), ()))
    return out


def _describe(name: str, file: str, path: Path) -> ExampleArm | None:
    """The example arm of one URDF file, or None when it is not a serial arm (or cannot be read as XML)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return None
    if root.tag != "robot":
        return None
    found = serial_chain(root)
    if found is None:
        return None
    chain, tool, locked = found
    if name in EXAMPLES:
        _, tool, locked = EXAMPLES[name]
    return ExampleArm(name=name, file=file, tool_frame=tool, locked=tuple(locked),
                      joints=tuple(j.get("name") for j in chain if j.get("name") not in locked),
                      kinds=tuple(j.get("type") for j in chain if j.get("name") not in locked),
                      limits=tuple(_limits(j) for j in chain if j.get("name") not in locked))


# --------------------------------------------------------------------------------------------------------------
# The listing
# --------------------------------------------------------------------------------------------------------------
def _distribution():
    try:
        return metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        return None


def _urdf_files(dist) -> dict:
    """File under ``robots/`` -> its path, for every URDF the installed example-robot-data records."""
    out = {}
    for f in dist.files or ():
        text = str(f).replace("\\", "/")
        if text.endswith(".urdf") and _ROBOTS in text:
            out[text.split(_ROBOTS, 1)[1]] = Path(str(dist.locate_file(f)))
    return out


def _stems(files_: list) -> dict:
    """Stem in lower case -> file (the first file of a stem, in sorted order)."""
    stems = {}
    for file in sorted(files_):
        stems.setdefault(Path(file).stem.lower().replace("-", "_"), file)
    return stems


def _short(stem: str, taken) -> str:
    """The example name of an arm's stem: ``_robot`` dropped where no other arm takes the shorter name."""
    short = stem[:-len("_robot")] if stem.endswith("_robot") else stem
    return short if short == stem or short not in taken else stem


_listing: dict = {}


def example_arms() -> dict:
    """Every example arm by name (scope4 first, then example-robot-data's serial arms when it is installed).

    Read once per process and installed version of example-robot-data.
    """
    dist = _distribution()
    key = None if dist is None else (str(dist.locate_file("")), dist.version)
    found = _listing.get(key)
    if found is not None:
        return found
    out = {"scope4": _describe("scope4", "scope4", scope4_urdf())}
    if dist is not None:
        paths = _urdf_files(dist)
        stems = _stems(list(paths))
        arms = {stem: _describe(_short(stem, ()), file, paths[file]) for stem, file in stems.items()}
        arms = {stem: arm for stem, arm in arms.items() if arm is not None}
        for stem in sorted(arms):
            name = _short(stem, arms)
            file = stems[stem]
            out[name] = _describe(name, file, paths[file]) if name != arms[stem].name else arms[stem]
            _paths[(key, name)] = paths[file]
    _listing[key] = out
    return out


_paths: dict = {}


def example_names() -> list:
    """The names ``example:NAME`` takes, sorted (scope4 among them)."""
    return sorted(example_arms())


def _unknown(name: str) -> UnknownExampleError:
    names = example_names()
    more = "" if _distribution() is not None else ' (more with example-robot-data: pip install "dobkit[urdf]")'
    shown = repr(name) if len(name) <= 80 else f"{name[:60]!r}... ({len(name):,} characters)"
    near = [n for n in names if n.casefold() == name.strip().casefold()]
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    return UnknownExampleError(f"example arm {shown} is unknown{hint}; the example arms are {', '.join(names)}{more} "
                               "(`dobkit arms` lists them with their joints)")


def example_urdf(name: str) -> Path:
    """Path of an example arm's URDF file (``scope4`` is dobkit's own; the others are example-robot-data's).

    Raises
    ------
    UnknownExampleError
        (a ``ValueError``) for a name that is no example arm (the message lists them).
    ModuleNotFoundError
        When the name is one of dobkit's known examples of example-robot-data (``ur5``, ``panda``) and the
        package is not installed (the message names the extra ``dobkit[urdf]``).
    """
    if name == "scope4":
        return scope4_urdf()
    dist = _distribution()
    if dist is None:
        if name in EXAMPLES:
            raise ModuleNotFoundError(f"the example arm {name!r} comes from example-robot-data, which is not "
                                      'installed: pip install "dobkit[urdf]"')
        raise _unknown(name)
    arms = example_arms()
    if name not in arms:
        raise _unknown(name)
    path = _paths.get(((str(dist.locate_file("")), dist.version), name))
    if path is None or not path.is_file():
        raise ModuleNotFoundError(f"example-robot-data {dist.version} is installed but has no {arms[name].file}; "
                                  'reinstall it: pip install --force-reinstall "dobkit[urdf]"')
    return path


def example_defaults(name: str) -> ExampleArm:
    """The example arm ``name`` as listed (its default tool frame and locked joints).

    Raises
    ------
    UnknownExampleError
        For a name that is no example arm.
    ModuleNotFoundError
        For ``ur5`` or ``panda`` when example-robot-data is not installed.
    """
    arms = example_arms()
    if name not in arms:
        if name in EXAMPLES and _distribution() is None:
            example_urdf(name)                  # raises: the package is missing (the message names the extra)
        raise _unknown(name)
    return arms[name]


def example_arm(name: str, tool_frame: str | None = None):
    """The :class:`~blocks.model.urdf.ChainArm` of an example arm (its gripper's fingers locked), tool frame
    ``tool_frame`` or the example's default."""
    from blocks.model.urdf.urdf import load_urdf_arm

    info = example_defaults(name)
    return load_urdf_arm(example_urdf(name), tool_frame or info.tool_frame, locked=info.locked)
