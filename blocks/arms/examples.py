"""Where the example arms' URDF files are: dobkit's own scope4, and the UR5 and Panda of example-robot-data.

``example-robot-data`` (installed with ``pip install "dobkit[urdf]"``) is a
cmeel package: its files sit under ``<site-packages>/cmeel.prefix/share/
example-robot-data/robots/``.  They are found through the package's
installed-file record, so no path of an environment is written here.
"""
from __future__ import annotations

from importlib import metadata
from importlib.resources import files
from pathlib import Path

__all__ = ["EXAMPLES", "example_urdf", "scope4_urdf", "example_arm"]

#: Example name -> (file under example-robot-data's ``robots/``, tool frame, locked joints).
EXAMPLES = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0", ()),
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand", ("panda_finger_joint1", "panda_finger_joint2")),
}


def scope4_urdf() -> Path:
    """The bundled 4-joint surgical arm (yaw, pitch, insertion, roll; tool frame ``tool_tip``)."""
    return Path(str(files("blocks.arms") / "data" / "scope4.urdf"))


_found: dict = {}


def example_urdf(name: str) -> Path:
    """Path of an example arm's URDF shipped by ``example-robot-data``: ``"ur5"`` or ``"panda"``.

    Raises
    ------
    ValueError
        For a name not in :data:`EXAMPLES` (the message lists them).
    ModuleNotFoundError
        When example-robot-data is not installed (the message names the extra ``dobkit[urdf]``).
    """
    if name not in EXAMPLES:
        raise ValueError(f"example arm {name!r} is unknown; choose from {sorted(EXAMPLES)} (or 'scope4')")
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        raise ModuleNotFoundError(f"the example arm {name!r} comes from example-robot-data, which is not installed: "
                                  'pip install "dobkit[urdf]"') from None
    suffix = "example-robot-data/robots/" + EXAMPLES[name][0]
    # the installed-file record is a thousand entries to parse (10 ms): read once per installed version, since every
    # scenario of an example arm (each member of a sweep) asks again
    key = (name, str(dist.locate_file("")), dist.version)
    path = _found.get(key)
    if path is not None and path.is_file():
        return path
    for f in dist.files or ():
        if str(f).replace("\\", "/").endswith(suffix):
            path = Path(str(dist.locate_file(f)))
            if path.is_file():
                _found[key] = path
                return path
    raise ModuleNotFoundError(f"example-robot-data {dist.version} is installed but has no {suffix}; "
                              'reinstall it: pip install --force-reinstall "dobkit[urdf]"')


def example_arm(name: str):
    """The :class:`~blocks.arms.ChainArm` of an example: ``"scope4"``, ``"ur5"`` or ``"panda"`` (fingers locked)."""
    from .urdf import load_urdf_arm

    if name == "scope4":
        return load_urdf_arm(scope4_urdf(), "tool_tip")
    _, tool, locked = EXAMPLES.get(name, (None, None, ()))
    return load_urdf_arm(example_urdf(name), tool, locked=locked)
