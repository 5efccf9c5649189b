"""Safe extraction of an FMU archive into a private temporary folder.

An FMU is a zip file from somewhere else.  Before anything is written,
every entry is checked:

* the file must be a zip archive;
* no entry may leave the extraction folder: absolute paths, ``..``
  components, backslashes, drive letters or other colons, NUL characters,
  symbolic links and other special files are refused;
* no duplicate (after normalisation) file entries or encrypted entries
  (a directory entry zipped twice, a common packaging artefact, is harmless
  and accepted);
* size limits: the number of entries, the total uncompressed size, the
  compression ratio of each large entry and the ratio of the whole archive
  (total uncompressed / total compressed size), so that a bomb made of many
  small entries is refused as well as one made of a single large entry; the
  byte count is enforced again while extracting, so a lying header does not
  help.

Extraction goes into a fresh folder from :func:`tempfile.mkdtemp` that the
returned :class:`ExtractedFMU` owns and removes (``cleanup``, ``with``, or
at garbage collection).  Nothing is written outside it; on any error it is
removed before the exception propagates.  The folder's name carries the
process id (``dobkit-fmu-<pid>-...``): when FMU code crashes or hangs the
process, nothing runs to remove it, so the first extraction of a later
process removes the folders, in the same parent folder, of processes that
no longer exist.
"""
from __future__ import annotations

import os
import re
import shutil
import stat
import tempfile
import weakref
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

from .errors import FMUArchiveError

__all__ = ["ExtractionLimits", "ExtractedFMU", "extract_fmu", "check_entries", "open_extracted",
           "remove_stale_extractions"]

_CHUNK = 1 << 16
_PREFIX = "dobkit-fmu-"
_SWEPT: set[str] = set()        # parent folders already cleaned of dead processes' extractions


@dataclass(frozen=True)
class ExtractionLimits:
    """Limits applied before and during extraction.

    Parameters
    ----------
    max_total_size : int
        Largest total uncompressed size in bytes (default 512 MiB).
    max_ratio : float
        Largest uncompressed / compressed size of one entry, checked for
        entries larger than ``ratio_min_size`` (default 200).
    ratio_min_size : int
        Entries up to this many bytes are exempt from the per-entry ratio
        check, and archives up to this many uncompressed bytes from the
        aggregate one (small text files compress well and cannot hurt);
        default 1 MiB.
    max_total_ratio : float
        Largest total uncompressed size / total compressed size of the
        archive (default 100; a typical FMU is below 10).
    max_entries : int
        Largest number of entries (default 10000).
    max_description_size : int
        Largest ``modelDescription.xml`` in bytes (default 64 MiB; large
        generated models stay well below), checked before it is extracted or parsed.
    max_description_token : int
        Largest single comment, attribute value or text run in
        ``modelDescription.xml`` in bytes (default 1 MiB): the XML parser
        takes time quadratic in the length of one such token (80 MB of
        comment: 45 s), so longer ones are refused before parsing.
    """

    max_total_size: int = 512 * 2 ** 20
    max_ratio: float = 200.0
    ratio_min_size: int = 2 ** 20
    max_entries: int = 10_000
    max_total_ratio: float = 100.0
    max_description_size: int = 64 * 2 ** 20
    max_description_token: int = 2 ** 20

    def __post_init__(self) -> None:
        for name in ("max_total_size", "max_ratio", "max_entries", "max_total_ratio", "max_description_size",
                     "max_description_token"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise ValueError(f"ExtractionLimits.{name} must be a number > 0, got {value!r}")
        if isinstance(self.ratio_min_size, bool) or not isinstance(self.ratio_min_size, int) \
                or self.ratio_min_size < 0:
            raise ValueError(f"ExtractionLimits.ratio_min_size must be an integer >= 0, got {self.ratio_min_size!r}")


_DRIVE = re.compile(r"^[A-Za-z]:")


def _entry_problem(info: zipfile.ZipInfo) -> str | None:
    """Why an entry is unsafe, or None."""
    name = info.orig_filename
    if "\x00" in name:
        return "contains a NUL character"
    if "\\" in name:
        return "contains a backslash (a Windows path separator)"
    if _DRIVE.match(name):
        return "starts with a drive letter"
    if ":" in name:
        return "contains a colon"
    if name.startswith("/"):
        return "is an absolute path"
    if any(part == ".." for part in name.split("/")):
        return "refers to a parent folder ('..')"
    mode = info.external_attr >> 16
    kind = stat.S_IFMT(mode)
    if kind == stat.S_IFLNK:
        return "is a symbolic link"
    if kind not in (0, stat.S_IFREG, stat.S_IFDIR):
        return "is a special file (device, FIFO or socket)"
    if info.flag_bits & 0x1:
        return "is encrypted"
    return None


def _normalised(name: str) -> str:
    return "/".join(p for p in name.split("/") if p not in ("", "."))


def check_entries(zf: zipfile.ZipFile, source: str, limits: ExtractionLimits) -> list[zipfile.ZipInfo]:
    """Check every entry of an open archive; return the entries to extract.

    Raises
    ------
    FMUArchiveError
        On the first problem, naming the entry and the rule it breaks.
    """
    infos = zf.infolist()
    if len(infos) > limits.max_entries:
        raise FMUArchiveError(f"{source}: {len(infos)} entries, more than the limit of {limits.max_entries}")
    seen: dict[str, str] = {}
    total = compressed = 0
    for info in infos:
        problem = _entry_problem(info)
        if problem:
            raise FMUArchiveError(f"{source}: entry {info.orig_filename!r} {problem}; refusing to extract")
        key = _normalised(info.filename)
        if not key:
            continue
        if key in seen:
            if info.is_dir() and seen[key].endswith("/"):
                continue            # the same directory twice: nothing to overwrite
            raise FMUArchiveError(f"{source}: entries {seen[key]!r} and {info.orig_filename!r} name the same file")
        seen[key] = info.orig_filename
        if key == "modelDescription.xml" and info.file_size > limits.max_description_size:
            raise FMUArchiveError(f"{source}: modelDescription.xml has {info.file_size} bytes, more than the limit of "
                                  f"{limits.max_description_size} (ExtractionLimits.max_description_size); refusing "
                                  "to extract")
        total += info.file_size
        compressed += info.compress_size
        if total > limits.max_total_size:
            raise FMUArchiveError(f"{source}: uncompressed size exceeds the limit of {limits.max_total_size} bytes "
                                  f"(reached at entry {info.orig_filename!r})")
        if info.file_size > limits.ratio_min_size:
            ratio = info.file_size / max(info.compress_size, 1)
            if ratio > limits.max_ratio:
                raise FMUArchiveError(f"{source}: entry {info.orig_filename!r} expands {ratio:.0f}-fold "
                                      f"({info.compress_size} -> {info.file_size} bytes), more than the limit of "
                                      f"{limits.max_ratio:g} (a zip bomb?)")
    # many small entries, each exempt above, can still add up to a bomb
    total_ratio = total / max(compressed, 1)
    if total > limits.ratio_min_size and total_ratio > limits.max_total_ratio:
        raise FMUArchiveError(f"{source}: the archive expands {total_ratio:.0f}-fold as a whole ({compressed} -> "
                              f"{total} bytes in {len(infos)} entries), more than the limit of "
                              f"{limits.max_total_ratio:g} (a zip bomb?); refusing to extract")
    return infos


class ExtractedFMU:
    """An FMU extracted into a private temporary folder that this object owns.

    Attributes
    ----------
    root : pathlib.Path
        The extraction folder.
    source : str
        The archive it came from.
    """

    def __init__(self, root: Path, source: str, limits: ExtractionLimits | None = None):
        self.root = root
        self.source = source
        self.limits = ExtractionLimits() if limits is None else limits
        self.model_description = None  # filled once by fmu.description.described
        self._finalizer = weakref.finalize(self, shutil.rmtree, str(root), True)

    def cleanup(self) -> None:
        """Remove the extraction folder (idempotent)."""
        self._finalizer()

    @property
    def removed(self) -> bool:
        """True once the folder has been removed."""
        return not self._finalizer.alive

    def __enter__(self) -> ExtractedFMU:
        return self

    def __exit__(self, *exc) -> None:
        self.cleanup()

    def __repr__(self) -> str:
        return f"ExtractedFMU({self.source!r} -> {str(self.root)!r})"


def _extract_one(zf: zipfile.ZipFile, info: zipfile.ZipInfo, root: Path, root_real: str, budget: list[int],
                 source: str) -> None:
    key = _normalised(info.filename)
    target = root.joinpath(*key.split("/"))
    parent = target if info.is_dir() else target.parent
    os.makedirs(parent, exist_ok=True)
    # belt and braces: the entry checks already exclude every way out of root
    if not (os.path.realpath(parent) + os.sep).startswith(root_real):
        raise FMUArchiveError(f"{source}: entry {info.orig_filename!r} resolves outside the extraction folder")
    if info.is_dir():
        return
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    written = 0
    with zf.open(info) as src, os.fdopen(os.open(target, flags, 0o600), "wb") as dst:
        while chunk := src.read(_CHUNK):
            written += len(chunk)
            budget[0] -= len(chunk)
            if written > info.file_size or budget[0] < 0:
                raise FMUArchiveError(f"{source}: entry {info.orig_filename!r} expands beyond its declared size "
                                      "or the total size limit; refusing to extract")
            dst.write(chunk)
    # executables must stay loadable; nothing else needs more than read/write for the owner
    os.chmod(target, 0o700 if key.startswith("binaries/") else 0o600)


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # another user's process: alive
        return True
    return True


def remove_stale_extractions(parent=None) -> list[str]:
    """Remove extraction folders left in ``parent`` by processes that no longer exist (crashed in FMU code).

    Only folders named ``dobkit-fmu-<pid>-...``, owned by this user, whose
    process is gone, are removed.  Returns their paths.
    """
    folder = Path(tempfile.gettempdir() if parent is None else parent)
    removed = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for entry in entries:
        name = entry.name
        if not name.startswith(_PREFIX):
            continue
        pid_text = name[len(_PREFIX):].split("-", 1)[0]
        if not pid_text.isdigit() or int(pid_text) == os.getpid() or _process_alive(int(pid_text)):
            continue
        try:
            info = entry.lstat()
        except OSError:
            continue
        if stat.S_ISDIR(info.st_mode) and (not hasattr(os, "getuid") or info.st_uid == os.getuid()):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(str(entry))
    return removed


def extract_fmu(path, limits: ExtractionLimits | None = None, parent=None) -> ExtractedFMU:
    """Check and extract an FMU into a new private temporary folder.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file.
    limits : ExtractionLimits, optional
        Size limits (defaults: 512 MiB total, ratio 200, 10000 entries).
    parent : str or pathlib.Path, optional
        Folder in which to create the extraction folder (default: the system temporary folder).

    Returns
    -------
    ExtractedFMU
        Owner of the extraction folder; call ``cleanup()`` (or use ``with``) when done.

    Raises
    ------
    FMUArchiveError
        If the file is missing, not a zip archive, or any entry is unsafe or too large.
    """
    limits = ExtractionLimits() if limits is None else limits
    source = str(path)
    if Path(path).is_dir():
        raise FMUArchiveError(f"{source}: is a directory, not an FMU file (an FMU is a zip archive)")
    if not Path(path).is_file():
        raise FMUArchiveError(f"{source}: no such file")
    if not zipfile.is_zipfile(path):
        raise FMUArchiveError(f"{source}: not a zip archive (an FMU is a zip file)")
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as err:
        raise FMUArchiveError(f"{source}: cannot be read as a zip archive: {err}") from None
    with zf:
        infos = check_entries(zf, source, limits)
        sweep_key = str(Path(tempfile.gettempdir() if parent is None else parent).resolve())
        if sweep_key not in _SWEPT:         # once per parent folder and process
            _SWEPT.add(sweep_key)
            remove_stale_extractions(parent)
        root = Path(tempfile.mkdtemp(prefix=f"{_PREFIX}{os.getpid()}-", dir=parent))
        extracted = ExtractedFMU(root, source, limits)
        root_real = os.path.realpath(root) + os.sep
        budget = [limits.max_total_size]
        try:
            for info in infos:
                if _normalised(info.filename):
                    _extract_one(zf, info, root, root_real, budget, source)
        except FMUArchiveError:
            extracted.cleanup()
            raise
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, RuntimeError) as err:
            extracted.cleanup()
            raise FMUArchiveError(f"{source}: extraction failed: {err}") from None
    return extracted


def open_extracted(fmu, limits: ExtractionLimits | None = None, parent=None) -> tuple[ExtractedFMU, bool]:
    """An extracted FMU for a path or an existing extraction, and whether the caller owns it.

    Parameters
    ----------
    fmu : str, pathlib.Path or ExtractedFMU
        A ``.fmu`` file (checked and extracted now) or an extraction to reuse.
    limits, parent :
        As for :func:`extract_fmu` (ignored when ``fmu`` is already extracted).

    Returns
    -------
    (ExtractedFMU, bool)
        The extraction, and True if it was made here (the caller must clean it up).
    """
    if isinstance(fmu, ExtractedFMU):
        if fmu.removed:
            raise FMUArchiveError(f"{fmu.source}: its extraction folder was already removed")
        return fmu, False
    return extract_fmu(fmu, limits=limits, parent=parent), True
