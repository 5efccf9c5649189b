"""Test FMUs written in C for dobkit's tests, independently of the plant FMU (see the .c files).

:func:`build` compiles one of them with the system C compiler and packages it
with :func:`fmu.package.package_fmu`; ``xml_edit`` lets a test package a
variant of the model description (for example one declaring event indicators).
``ball`` / ``ball3`` (state events, FMI 2 / 3) and ``stair`` (time events,
terminate) are Model Exchange only: the frames' Co-Simulation ignores events.
"""
from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).parent
FMI2_MODELS = ("mass", "spring", "gain", "oscillator", "integrator", "nanlag", "ball", "stair")
FMI3_MODELS = ("selector", "ball3")
# further sources a model includes besides its frame
INCLUDES = {"ball": ("ball_equations.inc",), "ball3": ("ball_equations.inc",)}


def build(name: str, folder: Path, xml_edit=None, filename: str | None = None) -> Path:
    """Compile test model ``name`` into ``folder/<filename or name>.fmu`` and return the path."""
    from fmu.package import package_fmu

    version = 2 if name in FMI2_MODELS else 3
    frame = f"fmi{version}_frame.inc"
    xml = (HERE / f"{name}.xml").read_text()
    if xml_edit is not None:
        xml = xml_edit(xml)
    sources = {f"{name}.c": HERE / f"{name}.c", frame: HERE / frame}
    sources |= {inc: HERE / inc for inc in INCLUDES.get(name, ())}
    return package_fmu(Path(folder) / f"{filename or name}.fmu", xml, sources, [f"{name}.c"], name, version)
