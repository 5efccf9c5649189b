"""The JSON-lines logs of the resumable jobs (a sweep's results file, a tuning's evaluation log).

Both kinds of job keep one log: a header line that records the job and its
*definition* (the hash of everything that decides its rows), then one row a
line, appended as the work finishes.  This module is the one place for what
such a log needs:

One writer at a time
    :func:`exclusive_lock` holds ``<log>.lock`` (``flock``) for the job; a
    second process is refused with the first one's process id, host and start.
Whole lines only
    :func:`cut_partial_last_line` drops the part of a line that a killed
    writer left; a reader never takes a last line without its newline.
Rewrites that leave the old or the new file
    :func:`write_lines_atomically` (a temporary sibling and a rename).
One log, one definition (:meth:`JobLog.prepare`)
    A log of another definition is refused naming what differs
    (:func:`differences`), or moved aside (:func:`move_aside`) with
    ``restart``; when only presentation (name, description, budget) changed,
    the header is rewritten in place.
A checksum per row (:func:`row_checksum`)
    Every row carries ``"checksum"``: the first 16 hex digits of the SHA-256 of
    the row without it, as canonical JSON (keys sorted, no spaces).  A row whose
    checksum does not match its contents was changed after it was written: it
    is not used (its work is done again) and is named among the log's problems.
    A log written before rows had checksums (no ``"row_checksum"`` in its
    header line) may hold rows without one; in a log whose header line says
    ``"row_checksum": "sha256-16"`` a row without one is not used.
Repeats
    Two rows of one piece of work (one run, one candidate) that agree in
    everything but the time they took count once; two that disagree are
    refused (:meth:`JobLog.rows`), naming both line numbers and the fields
    that differ: a log cannot say which of them is the job's answer.
Bytes that are not UTF-8
    are refused naming the file, the line and the remedy (``--restart`` moves
    the log aside and starts a new one).
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import itertools
import json
import os
import socket
import stat
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

__all__ = ["read_job_file", "check_regular", "MAX_JOB_FILE_BYTES",
           "exclusive_lock", "cut_partial_last_line", "write_lines_atomically", "move_aside", "json_default",
           "row_checksum", "row_line", "differences", "LogKind", "JobLog", "LogWriter", "ROW_CHECKSUM"]

#: How rows are checksummed (recorded in the header line of every log written with checksums).
ROW_CHECKSUM = "sha256-16"
_CHECKSUM_KEY = "checksum"


def json_default(value):
    """``json.dumps`` helper: numpy scalars and arrays as plain values."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {value!r} as JSON")


def _canonical(value) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=json_default)


def row_checksum(row: Mapping) -> str:
    """The checksum of a row: SHA-256 of its canonical JSON without ``"checksum"``, first 16 hex digits."""
    body = {k: v for k, v in row.items() if k != _CHECKSUM_KEY}
    return hashlib.sha256(_canonical(body).encode("utf-8")).hexdigest()[:16]


def row_line(row: Mapping) -> str:
    """A row as its log line: strict JSON with its checksum, ending in a newline."""
    body = {k: v for k, v in row.items() if k != _CHECKSUM_KEY}
    return json.dumps(body | {_CHECKSUM_KEY: row_checksum(body)}, default=json_default, allow_nan=False) + "\n"


def differences(old: Mapping, new: Mapping, parts: Mapping[str, str]) -> list[str]:
    """The words of the header entries (``parts``: key -> words) whose values differ between two headers."""
    return [words for key, words in parts.items()
            if json.dumps(old.get(key), sort_keys=True, default=json_default)
            != json.dumps(new.get(key), sort_keys=True, default=json_default)]


# --------------------------------------------------------------------------------------------
# Files: lock, torn lines, atomic rewrites, moving aside
# --------------------------------------------------------------------------------------------
#: The largest sweep or tuning file read (a job's definition is a short text file; scenario files stop at 1 MB).
MAX_JOB_FILE_BYTES = 2 ** 20


def check_regular(path: Path, error: type[Exception], what: str) -> None:
    """Refuse ``path`` when it exists and is not a regular file (a folder, device, FIFO or socket); a missing
    path passes (a job's log is made by the job).  Checked without opening it: a FIFO would wait for a writer,
    and ``/dev/zero`` read line by line has no end (it filled memory)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as err:
        raise error(f"{what} '{path}' cannot be read ({err.strerror or err})") from None
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a device, pipe or socket"
        raise error(f"{what} '{path}' is not a regular file ({kind}); give the path of a file")


def read_job_file(path: Path, error: type[Exception], what: str, limit: int = MAX_JOB_FILE_BYTES) -> str:
    """The UTF-8 text (a byte-order mark dropped) of a regular file of at most ``limit`` bytes.

    Opened without blocking and checked on the open file, so that a FIFO or a device is refused, not read.

    Raises
    ------
    error
        Naming the file (``what`` is its role: ``"sweep file"``) and what is wrong: missing, not a regular file,
        larger than ``limit``, not UTF-8.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise error(f"{what} '{path}' does not exist") from None
    except OSError as err:
        raise error(f"{what} '{path}' cannot be read ({err.strerror or err})") from None
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = "a folder" if stat.S_ISDIR(mode) else "a device, pipe or socket"
            raise error(f"{what} '{path}' is not a regular file ({kind}); give the path of a .toml file")
        raw = f.read(limit + 1)
    if len(raw) > limit:
        raise error(f"{what} '{path}' has more than {limit:,} bytes; a {what} is a short text file (at most "
                    f"{limit:,} bytes)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise error(f"{path}: not UTF-8 text: {err}") from None


@contextlib.contextmanager
def exclusive_lock(path: Path, error: type[Exception], what: str, job: str, elsewhere: str):
    """Hold ``<path>.lock`` (an exclusive ``flock``) while the block runs.

    The lock ends with its holder's process, even on ``kill -9``; the lock file
    names the holder (process id, host, since when) for the message of a second
    process.

    Parameters
    ----------
    path : pathlib.Path
        The job's file.
    error : type of Exception
        Raised when another process holds the lock.
    what, job, elsewhere : str
        The message's words: ``"results file"``, ``"sweep"``, ``"another --results file"``.

    Raises
    ------
    error
        When another process holds the lock: "{what} '{path}' is in use by another {job} ({holder}); wait for it
        to end, or give this one {elsewhere}".
    """
    lock = path.with_name(path.name + ".lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise _unwritable(err, path, error, what, elsewhere, "nothing was run") from None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as err:
            raise _unwritable(err, path, error, what, elsewhere, "nothing was run") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 500).decode("utf-8", "replace").strip() or "a process that did not say who it is"
            os.close(fd)
            raise error(f"{what} '{path}' is in use by another {job} ({holder}); wait for it to end, or give this "
                        f"one {elsewhere}") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)             # the previous holder removed the file between our open and our lock: again
    try:
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {datetime.now():%Y-%m-%d %H:%M:%S}\n"
                     .encode())
        except OSError as err:      # a full disk: said now, naming the job's file, not as "[Errno 28]"
            raise _unwritable(err, path, error, what, elsewhere, "nothing was run") from None
        yield lock
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _unwritable(err: OSError, path: Path, error: type[Exception], what: str, elsewhere: str, kept: str) -> Exception:
    """``error`` saying that the job's file cannot be written, and why in words (``blocks.plumbing.outputs.file_error``)."""
    from blocks.plumbing.outputs import file_error
    return error(f"{file_error(err, path, what, f'free space, or give this one {elsewhere}')}; {kept}")


def cut_partial_last_line(path: Path) -> None:
    """Cut a partial last line left by a writer that was killed or interrupted mid-line."""
    if not path.exists() or path.stat().st_size == 0:
        return
    with path.open("rb+") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        fh.seek(max(0, size - 1))
        if fh.read(1) == b"\n":
            return
        # find the last newline, reading backwards in blocks
        end = size
        while end > 0:
            start = max(0, end - 65536)
            fh.seek(start)
            block = fh.read(end - start)
            cut = block.rfind(b"\n")
            if cut >= 0:
                fh.truncate(start + cut + 1)
                return
            end = start
        fh.truncate(0)


def write_lines_atomically(path: Path, lines: Iterable[str]) -> None:
    """Write a file through a temporary sibling and a rename, so that a crash leaves the old or the new file."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with tmp.open("w", encoding="utf-8") as fh:
            for line in lines:
                fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def move_aside(path: Path, definition: str) -> Path:
    """Rename ``path`` to ``<stem>.old-<definition>[-k]<suffix>`` beside it (never over another file); the new path."""
    target = path.with_name(f"{path.stem}.old-{definition[:16]}{path.suffix}")
    k = 1
    while target.exists():
        target = path.with_name(f"{path.stem}.old-{definition[:16]}-{k}{path.suffix}")
        k += 1
    os.replace(path, target)
    return target


# --------------------------------------------------------------------------------------------
# A job's log
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LogKind:
    """What tells one kind of job's log from another's.

    Attributes
    ----------
    header_key : str
        The header line is ``{header_key: {...}}`` (``"sweep"``, ``"tune"``).
    id_key : str
        The row entry that names the piece of work (``"run_id"``, ``"key"``).
    error : type of Exception
        Raised on a log that cannot be used.
    what, job, elsewhere : str
        Words of the messages: ``"results file"``, ``"sweep"``, ``"another --results file"``.
    parts : dict of str to str
        Header entries that decide the rows, with their words (for :func:`differences`).
    volatile : tuple of str
        Row entries in which two rows of one piece of work may differ (the time it took).
    """

    header_key: str
    id_key: str
    error: type[Exception]
    what: str
    job: str
    elsewhere: str
    parts: Mapping[str, str]
    volatile: tuple[str, ...] = ("seconds",)


class _Undecodable(Exception):
    pass


class _Conflict(Exception):
    pass


@dataclass
class JobLog:
    """One job's log file read line by line: its header, its usable rows, and the lines it could not use.

    Attributes
    ----------
    path : pathlib.Path
    kind : LogKind
    problems : list of str
        One entry per line that is not a usable row (``"line 7: missing values"``), filled by :meth:`rows`.
    repeated : int
        Rows that repeat an earlier row of the same work with the same values (counted once), by :meth:`rows`.
    """

    path: Path
    kind: LogKind
    problems: list = field(default_factory=list)
    repeated: int = 0

    def __post_init__(self) -> None:
        check_regular(self.path, self.kind.error, self.kind.what)     # before its lock is made beside it

    # -- reading ----------------------------------------------------------------------------------
    def _lines(self) -> Iterator[tuple[int, str]]:
        """(number, text) of every whole line; stops before a last line cut off by a kill."""
        if not self.path.exists():
            return
        with self.path.open("rb") as fh:
            for number, raw in enumerate(fh, start=1):
                if not raw.endswith(b"\n"):
                    return
                try:
                    yield number, raw.decode("utf-8")
                except UnicodeDecodeError as err:
                    raise _Undecodable(f"{self.kind.what} '{self.path}' line {number} is not UTF-8 text (byte "
                                       f"0x{raw[err.start]:02x} at column {err.start + 1}): it was damaged or not "
                                       f"written by dobkit; --restart moves it aside and starts a new one") from None

    def header_line(self) -> dict | None:
        """The whole first line (``{header_key: {...}, "row_checksum": ...}``), or None when it is not a header.

        Raises
        ------
        kind.error
            When the first line is not UTF-8 text.
        """
        try:
            for _, text in self._lines():
                try:
                    record = json.loads(text)
                except json.JSONDecodeError:
                    return None
                ok = isinstance(record, dict) and isinstance(record.get(self.kind.header_key), dict)
                return record if ok else None
        except _Undecodable as err:
            raise self.kind.error(str(err)) from None
        return None

    def header(self) -> dict | None:
        """The job's header (the first line's ``header_key`` entry), or None."""
        line = self.header_line()
        return None if line is None else line[self.kind.header_key]

    def rows(self, problem: Callable[[dict], str] = lambda row: "") -> Iterator[dict]:
        """The usable rows in file order, each piece of work once.

        Parameters
        ----------
        problem : callable
            Why a parsed row is not usable (``""`` when it is): the job's own checks of a row.

        Raises
        ------
        kind.error
            On bytes that are not UTF-8, and on two rows of one piece of work that differ in more than
            :attr:`LogKind.volatile` (naming both lines and the fields).
        """
        try:
            yield from self._rows(problem)
        except (_Undecodable, _Conflict) as err:
            raise self.kind.error(str(err)) from None

    def _usable(self, number: int, text: str, problem, required: bool | None) -> tuple[dict | None, str, str]:
        """A parsed row, its checksum and ``""``; or None, ``""`` and why it is not usable."""
        try:
            record = json.loads(text)
        except json.JSONDecodeError as err:
            return None, "", f"not JSON ({err.msg})"
        if not isinstance(record, dict):
            return None, "", "not a JSON object"
        given, digest = record.get(_CHECKSUM_KEY), row_checksum(record)
        if given is None and required:
            return None, "", "no checksum (the log's header says its rows have one)"
        if given is not None and given != digest:
            return None, "", "its checksum does not match its contents (the line was changed after it was written)"
        why = problem(record)
        if not why and not isinstance(record.get(self.kind.id_key), str):
            why = f"missing {self.kind.id_key}" if self.kind.id_key not in record else \
                f"{self.kind.id_key} {record[self.kind.id_key]!r} is not text"
        return (None, "", why) if why else (record, digest, "")

    def _rows(self, problem: Callable[[dict], str]) -> Iterator[dict]:
        self.problems, self.repeated = [], 0
        required = None
        seen: dict[str, int] = {}                 # id -> its first row's checksum (as a number: less memory)
        suspects: dict[int, str] = {}             # line -> id of repeats whose checksum differs from the first row's
        for number, text in self._lines():
            if not text.strip():
                continue
            if number == 1:
                line = _record(text)
                if isinstance(line, dict) and isinstance(line.get(self.kind.header_key), dict):
                    required = line.get("row_checksum") == ROW_CHECKSUM
                    continue
            record, digest, why = self._usable(number, text, problem, required)
            if record is None:
                self.problems.append(f"line {number}: {why}")
                continue
            work, key = record[self.kind.id_key], int(digest, 16)
            if work in seen:
                if seen[work] == key:
                    self.repeated += 1          # the same row again, to the letter
                else:
                    suspects[number] = work     # may differ in the time it took only: compared below
                continue
            seen[work] = key
            record.pop(_CHECKSUM_KEY, None)
            yield record
        if suspects:
            self._compare(suspects, problem, required)

    def _compare(self, suspects: dict[int, str], problem, required: bool | None) -> None:
        """Count the suspect repeats that agree with their work's first row but for :attr:`LogKind.volatile`;
        raise on the first that does not (one more pass over the file, keeping the first rows of those ids)."""
        ids, first, strip, last = set(suspects.values()), {}, (_CHECKSUM_KEY,) + self.kind.volatile, max(suspects)
        for number, text in self._lines():
            if number > last:
                break
            if not text.strip() or _record_id(text, self.kind.id_key) not in ids:
                continue
            record, _, _ = self._usable(number, text, problem, required)
            if record is None:
                continue
            work = record[self.kind.id_key]
            if number not in suspects:
                first.setdefault(work, (number, record))
                continue
            first_number, earlier = first[work]
            if _differing(earlier, record, strip):
                raise _Conflict(self._conflict(work, first_number, earlier, number, record))
            self.repeated += 1

    def _conflict(self, work: str, first_number: int, first: dict, number: int, record: dict) -> str:
        """The message on two rows of one piece of work that differ."""
        fields = [f"{name} {_short(a)} against {_short(b)}" for name, a, b in
                  _differing(first, record, (_CHECKSUM_KEY,) + self.kind.volatile)]
        k = self.kind
        return (f"{k.what} '{self.path}' holds two rows of one {k.id_key.replace('_', ' ')} ({work}) that differ: "
                f"line {first_number} and line {number} ({'; '.join(fields)}). The {k.job} cannot tell which is its "
                f"answer; delete the wrong line, or --restart to move the file aside and start anew")

    def check_whole(self) -> str:
        """Why the log cannot be used at all (bytes that are not UTF-8, conflicting rows), or ``""``."""
        try:
            for _ in self._rows(lambda row: ""):
                pass
        except (_Undecodable, _Conflict) as err:
            return str(err)
        return ""

    # -- making it the job's own -----------------------------------------------------------------
    def prepare(self, header: dict, name: str, restart: bool) -> Path | None:
        """Make the log the job's own before it runs; returns where an old log was moved (``restart``), if it was.

        A log of another definition, one without a header of this kind of job, or (with ``restart``) one that
        cannot be used at all (:meth:`check_whole`) is moved aside with ``restart`` and refused without it; when
        only presentation entries changed, the header line is rewritten in place.

        Parameters
        ----------
        header : dict
            The job's header (without the ``header_key`` wrapping); its ``"definition"`` decides.
        name : str
            The job's name, for the message.
        restart : bool
        """
        k, path = self.kind, self.path
        line = self.header_line()
        if line is None:
            if path.exists() and path.stat().st_size > 0:
                if not restart:
                    raise k.error(f"{k.what} '{path}' does not start with a {k.job} header, so it is not a {k.what} "
                                  f"of this {k.job}; choose {k.elsewhere}, or --restart to move it aside and start "
                                  "anew")
                return move_aside(path, "unknown")
            return None
        old = line[k.header_key]
        if old.get("definition") != header.get("definition"):
            if restart:
                return move_aside(path, str(old.get("definition") or "undefined"))
            what = ", ".join(differences(old, header, k.parts)) or f"the {k.job} definition"
            written = "written without a definition (an older dobkit)" if "definition" not in old else \
                f"of definition {old['definition']}"
            raise k.error(f"{k.what} '{path}' belongs to {k.job} '{old.get('name')}' {written}, not to this "
                          f"definition of {k.job} '{name}' ({header.get('definition')}): {what} differ(s). Its rows "
                          f"would mix with this {k.job}'s. Give this {k.job} {k.elsewhere}, or --restart to move the "
                          "old file aside and start anew")
        if restart and self.check_whole():
            return move_aside(path, str(old.get("definition") or "undefined"))
        if old != header:                 # the same work; only how it is named or presented changed
            unusable = self.check_whole()
            if unusable:
                raise k.error(unusable)
            cut_partial_last_line(path)
            new_line = {k.header_key: header} | ({"row_checksum": line["row_checksum"]} if "row_checksum" in line
                                                 else {})
            with path.open("rb") as fh:
                fh.readline()
                write_lines_atomically(path, itertools.chain([json.dumps(new_line, default=json_default) + "\n"],
                                                             (raw.decode("utf-8") for raw in fh)))
        return None

    def lock(self):
        """:func:`exclusive_lock` on the log, with this kind's words."""
        return exclusive_lock(self.path, self.kind.error, self.kind.what, self.kind.job, self.kind.elsewhere)

    def writer(self, header: dict) -> LogWriter:
        """A :class:`LogWriter` that starts a new log with ``header`` (checksummed rows) or appends to this one."""
        return LogWriter(self.path, {self.kind.header_key: header, "row_checksum": ROW_CHECKSUM}, self.kind)


class LogWriter:
    """Appends rows to a log, creating it (header line first) with the first rows: a job that fails before any
    work finishes leaves no file.  Every batch is written whole (checksummed lines), flushed and synced."""

    def __init__(self, path: Path, header_line: dict, kind: LogKind | None = None) -> None:
        self.path, self.header_line, self.fh, self.kind = path, header_line, None, kind

    def write(self, rows: Iterable[Mapping]) -> None:
        text = "".join(row_line(r) for r in rows)
        try:
            if self.fh is None:
                cut_partial_last_line(self.path)
                new = not self.path.exists() or self.path.stat().st_size == 0
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.fh = self.path.open("a", encoding="utf-8")
                if new:
                    text = json.dumps(self.header_line, default=json_default) + "\n" + text
            self.fh.write(text)
            self.fh.flush()
            os.fsync(self.fh.fileno())
        except OSError as err:
            if self.kind is None:
                raise
            self.close()              # the part of a line written is cut: the file holds whole rows only
            k = self.kind
            kept = "the rows written before are kept whole, and the same command goes on from them"
            with contextlib.suppress(OSError):
                if self.path.stat().st_size == 0:       # made now and nothing of it kept
                    self.path.unlink()
                    kept = "nothing was written"
            raise _unwritable(err, self.path, k.error, k.what, k.elsewhere, kept) from None

    def close(self) -> None:
        if self.fh is not None:
            with contextlib.suppress(OSError):      # a full disk: what was flushed stays, the rest is cut below
                self.fh.close()
            self.fh = None
            cut_partial_last_line(self.path)          # an interrupted write may have left part of a line


def _record_id(text: str, id_key: str):
    record = _record(text)
    return record.get(id_key) if isinstance(record, dict) else None


def _record(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return None


def _differing(a: Mapping, b: Mapping, ignore: tuple, prefix: str = "") -> list[tuple[str, object, object]]:
    """(dotted name, value in a, value in b) of every entry that differs, nested objects entered."""
    out = []
    for key in sorted(set(a) | set(b)):
        if not prefix and key in ignore:
            continue
        x, y = a.get(key, _MISSING), b.get(key, _MISSING)
        if isinstance(x, dict) and isinstance(y, dict):
            out += _differing(x, y, ignore, f"{prefix}{key}.")
        elif x is _MISSING or y is _MISSING or _canonical(x) != _canonical(y):
            out.append((f"{prefix}{key}", x, y))
    return out


_MISSING = object()


def _short(value) -> str:
    text = "missing" if value is _MISSING else json.dumps(value, default=json_default)
    return text if len(text) <= 60 else text[:57] + "..."
