"""Compile FMU sources into a shared library with the system C compiler.

The compiler is ``$CC`` when set (it may carry flags, e.g. ``"ccache gcc"``),
otherwise the first of ``cc``, ``gcc``, ``clang`` found on ``PATH``.  The
standard FMI headers come from fmpy's package folder ``c-code/`` (2-clause
BSD, Modelica Association).
"""
from __future__ import annotations

import hashlib
import os
import shlex
import sys
import uuid
from pathlib import Path

from blocks.plumbing.compiler import CANDIDATES, CompilerTimeout, compiler_command, run_compiler

from .errors import FMUBuildError

__all__ = ["instantiation_token", "rebuild_command", "shared_layer_files",
           "find_compiler", "fmi_header_dir", "compile_shared_library", "platform_folder", "FMI_HEADERS",
           "COMPILE_FLAGS"]

FMI_HEADERS = {
    2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}

# -fvisibility=hidden keeps internal symbols private; the FMI headers mark the API visible.
# -ffp-contract=off: no fused multiply-adds, so the generated maths rounds as the numpy kernels do.
COMPILE_FLAGS = ("-shared", "-fPIC", "-O2", "-std=c99", "-ffp-contract=off", "-D_POSIX_C_SOURCE=200809L",
                 "-fvisibility=hidden", "-Wall", "-Wextra")

# C files under fmu/c shared by the plant and the controller FMU layers of each FMI version: (sources, headers).
_SHARED_LAYER_FILES = {
    2: (("fmi_log.c", "fmi2_common.c"), ("fmi_log.h", "fmi2_common.h")),
    3: (("fmi3_common.c",), ("fmi3_common.h",)),
}


def shared_layer_files(fmi_version: int) -> tuple[list[str], list[str]]:
    """The C sources and headers (names under ``fmu/c``) that the plant and the controller FMU of
    ``fmi_version`` (2 or 3) both compile: the FMI entry points and log helpers they have in common."""
    if fmi_version not in _SHARED_LAYER_FILES:
        raise ValueError(f"fmi_version {fmi_version!r} is not supported; use 2 or 3")
    sources, headers = _SHARED_LAYER_FILES[fmi_version]
    return list(sources), list(headers)


def instantiation_token(kind: str, fmi_version: int, texts: list[str]) -> str:
    """The GUID / instantiationToken of an export: a hash of ``kind`` (``"plant"``, ``"controller"``), the FMI
    version and ``texts`` (its sources and variable table), so the same export gives the same token."""
    digest = hashlib.sha256(f"dobkit-{kind}-fmi{fmi_version}".encode())
    for text in texts:
        digest.update(b"\0" + text.encode("utf-8"))
    return "{" + str(uuid.UUID(hex=digest.hexdigest()[:32])) + "}"


def rebuild_command(identifier: str, sources: list[str]) -> tuple[str, str]:
    """The shared library's file name and the compile command (as one shell line) that rebuilds it from an
    FMU's ``sources/`` folder, for its ``BUILD.txt``."""
    lib = identifier + shared_library_suffix()
    return lib, shlex.join(["cc"] + list(COMPILE_FLAGS) + ["-I."] + sources + ["-o", lib, "-lm"])


def find_compiler(cc: str | None = None) -> list[str]:
    """The compiler command as an argument list.

    Parameters
    ----------
    cc : str, optional
        Compiler command; default ``$CC``, else ``cc``, ``gcc`` or ``clang``.

    Raises
    ------
    FMUBuildError
        If no compiler is found; the message says what was tried.
    """
    spec = cc if cc is not None else os.environ.get("CC")
    argv = compiler_command(spec)
    if argv is not None:
        return argv
    if spec:
        source = "cc argument" if cc is not None else "CC environment variable"
        raise FMUBuildError(f"C compiler {spec!r} (from the {source}) was not found on PATH; "
                            "install a C compiler or point CC at one")
    raise FMUBuildError(f"no C compiler found (tried the CC environment variable and {', '.join(CANDIDATES)} on "
                        "PATH); exporting an FMU compiles its C sources: install gcc or clang, or set CC")


def fmi_header_dir() -> Path:
    """Folder holding the standard FMI 2.0 and 3.0 headers shipped with fmpy."""
    import fmpy
    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise FMUBuildError(f"the FMI headers were not found in {folder} (fmpy installation incomplete?)")
    return folder


def platform_folder(fmi_version: int) -> str:
    """The ``binaries/`` sub-folder for this machine: ``linux64`` (FMI 2), ``x86_64-linux`` (FMI 3), ..."""
    import fmpy
    return fmpy.platform if fmi_version == 2 else fmpy.platform_tuple


def shared_library_suffix() -> str:
    return {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")


def compile_shared_library(sources: list[Path], include_dirs: list[Path], output: Path,
                           cc: str | None = None, timeout: float = 120.0) -> list[str]:
    """Compile and link C sources into ``output``.

    Returns
    -------
    list of str
        The command that was run (recorded in the FMU's ``sources/``).

    Raises
    ------
    FMUBuildError
        If the compiler is missing, fails or times out; the message holds its output.
    """
    argv = find_compiler(cc)
    cmd = argv + list(COMPILE_FLAGS) + [f"-I{d}" for d in include_dirs] + [str(s) for s in sources] \
        + ["-o", str(output), "-lm"]
    # Its temporaries (cc*.s, cc*.o) go to the build folder, which is removed with them; its own process group
    # lets an interrupt end the whole compiler (cc1, as, ld), not only its driver.
    try:
        returncode, said = run_compiler(cmd, timeout, str(Path(output).parent))
    except OSError as err:
        raise FMUBuildError(f"could not run the C compiler {argv[0]!r}: {err}") from None
    except CompilerTimeout:
        raise FMUBuildError(f"the C compiler did not finish within {timeout:g} s: {shlex.join(cmd)}") from None
    if returncode != 0 or not output.is_file():
        raise FMUBuildError(f"compiling the FMU failed (exit code {returncode}):\n$ {shlex.join(cmd)}\n"
                            f"{said.strip()}")
    return cmd
