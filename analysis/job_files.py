"""The JSON-lines files of the resumable jobs (a sweep's results file, a tuning's evaluation log).

One writer at a time (:func:`exclusive_lock`), whole lines only (:func:`cut_partial_last_line`
after a kill), rewrites that leave the old or the new file and never a mix
(:func:`write_lines_atomically`), and a file of another definition moved aside
rather than overwritten (:func:`move_aside`).
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import socket
from collections.abc import Iterable
from datetime import datetime
from pathlib import Path

__all__ = ["exclusive_lock", "cut_partial_last_line", "write_lines_atomically", "move_aside"]


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
    lock.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
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
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {datetime.now():%Y-%m-%d %H:%M:%S}\n"
                 .encode())
        yield lock
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


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
