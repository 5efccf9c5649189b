"""Compile C sources and zip them with a model description into an FMU archive.

:func:`package_fmu` is the generic step behind :func:`fmu.export_plant`;
it also packages any other hand-written C model (the tests use it for an
independent first-order-lag FMU).  The archive holds ``modelDescription.xml``,
``binaries/<platform>/<modelIdentifier>.<so|dylib|dll>`` and ``sources/``
(the C files and headers, the standard FMI headers with their BSD notice, and
any extra files such as ``BUILD.txt`` or ``buildDescription.xml``).  Zip
entries carry a fixed timestamp, so the same inputs give the same archive.
"""
from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path

from blocks.plumbing.outputs import DISK_ERRORS, file_error

from .build import FMI_HEADERS, compile_shared_library, fmi_header_dir, platform_folder, shared_library_suffix

__all__ = ["package_fmu"]

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _write_zip(path: Path, files: dict[str, bytes], replace: bool = True) -> None:
    """Write atomically: a half-written FMU never appears under the final name.

    Without ``replace`` the archive is put in place by a hard link, which the
    system refuses if ``path`` exists: of two exports to one path started at
    once, the second is refused, not silently the one that stays.
    """
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        try:
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
                for name, data in files.items():
                    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                    info.compress_type = zipfile.ZIP_DEFLATED
                    info.external_attr = (0o755 if name.startswith("binaries/") else 0o644) << 16
                    zf.writestr(info, data)
        except OSError as err:
            if err.errno not in DISK_ERRORS:
                raise
            # a full disk or a read-only one: named with the FMU's path, not "[Errno 28] No space left on device"
            raise file_error(err, path, "FMU file", "free space or choose another --out; nothing was written") \
                from None
        if replace:
            os.replace(tmp, path)
        else:
            _put_new(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _put_new(tmp: Path, path: Path) -> None:
    """Move ``tmp`` to ``path``, which must not exist (checked by the system where it has hard links)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(f"path {str(path)!r} was written by another export while this one compiled; "
                              "refusing to overwrite it (pass force=True to replace it)") from None
    except OSError:                  # a file system without hard links: checked, then replaced
        if path.exists():
            raise FileExistsError(f"path {str(path)!r} exists; refusing to overwrite it (pass force=True to "
                                  "replace it)") from None
        os.replace(tmp, path)


def _as_bytes(content) -> bytes:
    if isinstance(content, Path):
        return content.read_bytes()
    return content.encode("utf-8") if isinstance(content, str) else bytes(content)


def package_fmu(path, model_description: str, sources: dict, compile_files: list[str], model_identifier: str,
                fmi_version: int, extra_files: dict | None = None, cc: str | None = None,
                replace: bool = True) -> Path:
    """Build the shared library and write the FMU archive.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file to write (its folder must exist).
    model_description : str
        Text of ``modelDescription.xml``.
    sources : dict
        File name -> content (str, bytes or a Path to read) of every C file and
        header, all placed side by side in ``sources/``.
    compile_files : list of str
        Names among ``sources`` to compile and link.
    model_identifier : str
        Base name of the shared library.
    fmi_version : {2, 3}
        Selects the standard headers and the ``binaries/`` platform folder.
    extra_files : dict, optional
        Archive name -> content of further files (e.g. ``sources/BUILD.txt``).
    cc : str, optional
        C compiler command (default ``$CC``, else ``cc``/``gcc``/``clang``).
    replace : bool
        Replace a file at ``path`` (default); if false, a file that appeared there
        meanwhile (another export) is kept and :class:`FileExistsError` raised.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FMUBuildError
        If no compiler is found or compilation fails.
    FileExistsError
        If ``replace`` is false and ``path`` exists when the archive is written.
    """
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"folder {path.parent} for the FMU does not exist")
    unknown = [n for n in compile_files if n not in sources]
    if unknown:
        raise ValueError(f"compile_files {unknown} are not among the sources {sorted(sources)}")
    headers = fmi_header_dir()
    library = model_identifier + shared_library_suffix()
    with tempfile.TemporaryDirectory(prefix="dobkit-build-") as tmp:
        build = Path(tmp)
        for name, content in sources.items():
            (build / name).write_bytes(_as_bytes(content))
        compile_shared_library([build / n for n in compile_files], [build, headers], build / library, cc=cc)
        files = {"modelDescription.xml": model_description.encode("utf-8"),
                 f"binaries/{platform_folder(fmi_version)}/{library}": (build / library).read_bytes()}
        for name in sorted(sources):
            files[f"sources/{name}"] = (build / name).read_bytes()
        for name in FMI_HEADERS[fmi_version]:
            files.setdefault(f"sources/{name}", (headers / name).read_bytes())
        for name, content in (extra_files or {}).items():
            files[name] = _as_bytes(content)
        _write_zip(path, files, replace)
    return path
