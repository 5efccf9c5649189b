"""Output folders: default names, and reserved staging so that a failed or concurrent run leaves nothing mixed."""
from __future__ import annotations

import atexit
import contextlib
import errno
import json
import math
import os
import shutil
import signal
import tempfile
import threading
import weakref
from datetime import datetime
from pathlib import Path

__all__ = ["default_out_dir", "staged_output", "file_error", "interrupts_held", "DISK_ERRORS", "metrics_json",
           "NON_FINITE_MEANING"]

#: Why a write fails for reasons of the file system rather than of the file, in words.
DISK_ERRORS = {errno.EROFS: "the file system is read-only", errno.ENOSPC: "the disk is full (no space left)",
               errno.EDQUOT: "the disk quota is used up", errno.EFBIG: "the file is larger than this system allows",
               errno.EACCES: "permission denied", errno.EPERM: "the operation is not permitted"}


def file_error(err: OSError, path, role: str, advice: str = "choose another --out") -> OSError:
    """``err`` said in words that name the file's role and path, as an exception of the same type.

    Parameters
    ----------
    err : OSError
        What the system said (``[Errno 28] No space left on device``).
    path : path-like
        The file or folder the user gave or dobkit made.
    role : str
        What it is to the user: ``"output folder"``, ``"results file"``, ``"cache folder"``.
    advice : str
        What to do about it.

    Examples
    --------
    >>> import errno
    >>> str(file_error(OSError(errno.EROFS, "Read-only file system"), "/mnt/o", "output folder"))
    "output folder '/mnt/o' cannot be written: the file system is read-only; choose another --out"
    """
    what = DISK_ERRORS.get(err.errno, err.strerror or str(err))
    new = type(err)(f"{role} '{path}' cannot be written: {what}" + (f"; {advice}" if advice else ""))
    new.errno = err.errno           # kept for callers that test it; without strerror and filename str() is the text
    return new


#: What ``null`` means in the JSON files dobkit writes (``metrics.json``, ``convergence.json``, ...).
NON_FINITE_MEANING = ("null marks a value that was not a finite number (NaN or infinite); each place is listed "
                      "as a path of keys and list indices")


def metrics_json(data) -> tuple[str, list[str]]:
    """``data`` as strict JSON text, and the paths of its values that were not finite numbers.

    Every JSON file of results is written by this one function: a NaN or an
    infinity (numpy's as well) becomes ``null`` and its place is listed under
    ``non_finite_values`` (JSON has no such numbers: ``Infinity`` is a token
    other readers refuse); numpy arrays and scalars become lists and numbers.

    Returns
    -------
    text : str
        Indented (2 spaces), ending in a newline.
    paths : list of str
        ``key/index/...`` of each non-finite value (empty when all are finite).

    Examples
    --------
    >>> text, paths = metrics_json({"a": [1.0, float("inf")]})
    >>> paths, json.loads(text)["a"]
    (['a/1'], [1.0, None])
    """
    paths: list[str] = []

    def clean(value, path: str):
        if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):      # numpy arrays and scalars
            value = value.tolist()
        if isinstance(value, float) and not math.isfinite(value):
            paths.append(path or "/")
            return None
        if isinstance(value, dict):
            return {k: clean(v, f"{path}/{k}" if path else str(k)) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v, f"{path}/{i}" if path else str(i)) for i, v in enumerate(value)]
        return value

    cleaned = clean(data, "")
    if paths:
        cleaned = dict(cleaned) if isinstance(cleaned, dict) else {"value": cleaned}
        cleaned["non_finite_values"] = {"meaning": NON_FINITE_MEANING, "paths": paths}
    return json.dumps(cleaned, indent=2, allow_nan=False) + "\n", paths


_unused_defaults: set[Path] = set()
_unused_lock = threading.Lock()


def default_out_dir(prefix: str = "dobkit-run") -> Path:
    """A new folder under the current one, ``prefix-YYYYmmdd-HHMMSS`` (suffixed ``-1``, ``-2``, ... if taken).

    The folder is made here, so that two runs started in the same second get
    two folders (a name only checked would be the same for both, and the
    second run would be refused for a folder it never asked for).  Output
    staged into it (:class:`staged_output`) removes it if the run fails; one
    never used is removed, if still empty, when the process exits.  Where it
    cannot be made (a folder this user cannot write) the name is returned as
    it is, for the writer to report.
    """
    base = Path.cwd() / f"{prefix}-{datetime.now():%Y%m%d-%H%M%S}"
    path, k = base, 1
    while True:
        try:
            path.mkdir()
        except FileExistsError:
            path, k = Path(f"{base}-{k}"), k + 1
            continue
        except OSError:
            return path
        with _unused_lock:
            _unused_defaults.add(path)
        return path


def _adopt_default(target: Path) -> bool:
    """Whether ``target`` is a folder :func:`default_out_dir` made in this process and no writer has taken yet."""
    with _unused_lock:
        if target in _unused_defaults:
            _unused_defaults.discard(target)
            return True
    return False


@atexit.register
def _remove_unused_defaults() -> None:
    with _unused_lock:
        for path in _unused_defaults:
            try:
                path.rmdir()                # only if empty: a user may have put something there
            except OSError:
                pass
        _unused_defaults.clear()


_LOCK = ".dobkit-writing"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:         # alive, owned by someone else
        return True
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _discard_stages(target: Path) -> None:
    """Remove every staging folder in ``target``: the caller holds its reservation, so they are its own."""
    for stage in target.glob(".partial-*"):
        shutil.rmtree(stage, ignore_errors=True)


def _release(lock: Path, created: Path | None) -> None:
    """Undo a reservation that was not used: the lock file, and the folder if this run made it (and it is empty).

    Staging folders go first: a Ctrl-C or SIGTERM may have come after one was
    made and before its name was kept (inside ``mkdtemp``).
    """
    _discard_stages(lock.parent)
    lock.unlink(missing_ok=True)
    if created is not None:
        try:
            created.rmdir()
        except OSError:
            pass


class staged_output:
    """An output folder reserved before the work and filled only on success.

    Made before the work starts, it checks that ``target`` can be used and
    reserves it: ``target`` may not exist (it is created) or be an empty
    folder (a mount point or a symbolic link to one are fine); anything else
    -- a file, a non-empty folder, a dangling link, a folder this user cannot
    write, a folder another run is writing into -- is refused now, not after
    the work.  Entered (``with staging as stage``), it gives a hidden staging
    folder inside ``target``; on success its files are moved into ``target``,
    on failure (an exception, Ctrl-C) they are removed and so is the
    reservation.  Folders are created with the user's umask.  If the final
    move fails the results stay in a visible folder inside ``target``, and the
    error says where.

    Raises
    ------
    FileExistsError, FileNotFoundError, PermissionError
        When ``target`` cannot be used, naming it and why.
    """

    def __init__(self, target: Path) -> None:
        self.target = target = Path(target)
        if target.is_symlink() and not target.exists():
            raise FileNotFoundError(f"output folder '{target}' is a symbolic link to '{os.readlink(target)}', "
                                    "which does not exist; choose another --out")
        if target.exists() and not target.is_dir():
            raise FileExistsError(f"output folder '{target}' is an existing file, not a folder; choose a new --out")
        lock = target / _LOCK
        if lock.exists():
            pid = _lock_pid(lock)
            if pid is not None and _pid_alive(pid):
                raise FileExistsError(f"output folder '{target}' is being written by another dobkit run (process "
                                      f"{pid}); choose another --out")
            _discard_stages(target)             # left by a run that was killed
            lock.unlink(missing_ok=True)
        if target.exists() and any(target.iterdir()):
            raise FileExistsError(f"output folder '{target}' exists and is not empty; choose a new --out")
        # a Ctrl-C or SIGTERM between making the folder or the lock and registering their removal would leave them
        # behind: it waits until the reservation can be undone, then ends the run as it would have
        with interrupts_held():
            created = target if _adopt_default(target) else None      # made empty by default_out_dir: this run's
            if not target.exists():
                try:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    target.mkdir()
                except FileExistsError:
                    raise FileExistsError(f"output folder '{target}' was just created by another run; choose another "
                                          "--out") from None
                except OSError as err:
                    raise file_error(err, target, "output folder") from None
                created = target
            try:
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
            except FileExistsError:
                raise FileExistsError(f"output folder '{target}' is being written by another dobkit run; choose another "
                                      "--out") from None
            except OSError as err:
                _release(lock, created)
                raise file_error(err, target, "output folder") from None
            try:
                with os.fdopen(fd, "w") as f:
                    f.write(str(os.getpid()))
            except OSError as err:
                _release(lock, created)
                raise file_error(err, target, "output folder") from None
            self._lock, self._created = lock, created
            self._release = weakref.finalize(self, _release, lock, created)     # work that fails before `with`

    def __enter__(self) -> Path:
        try:
            self.stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=self.target))
            self.stage.chmod(0o777 & ~_umask())
        except BaseException as err:        # also Ctrl-C or SIGTERM: `__exit__` runs only once this returns
            self._release()
            if isinstance(err, OSError):
                raise file_error(err, self.target, "output folder") from None
            raise
        return self.stage

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self._release()
            if isinstance(exc, OSError) and exc.errno in DISK_ERRORS and _inside(exc.filename, self.stage):
                # a full disk or a file system turned read-only while the results were written
                raise file_error(exc, self.target, "output folder", "free space or choose another --out; nothing "
                                 "was kept") from None
            return
        # a Ctrl-C or SIGTERM now waits for the last file: the folder then holds all results, not some
        with interrupts_held():
            try:
                for entry in sorted(self.stage.iterdir()):
                    os.replace(entry, self.target / entry.name)
                self.stage.rmdir()
            except OSError as err:
                kept = self.target / f"results-not-moved-{datetime.now():%Y%m%d-%H%M%S}"
                self.stage.rename(kept)
                raise OSError(f"the results could not be moved into '{self.target}' ({err}); they are complete "
                              f"in '{kept}'") from None
            finally:
                self._lock.unlink(missing_ok=True)
                self._release.detach()


@contextlib.contextmanager
def interrupts_held():
    """Hold SIGINT and SIGTERM back while the body runs, then deliver the first that came.

    For writers that move whole results into place (an output folder, a tuning's files).

    The handlers are swapped for one that only records the signal; at the end
    the previous handlers come back and a recorded signal is raised again, so
    it ends the command as it would have, once the body is whole.  Outside the
    main thread (where Python does not handle signals) the body runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    names = (signal.SIGINT, signal.SIGTERM)
    previous = {signum: signal.signal(signum, lambda signum, frame: received.append(signum)) for signum in names}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if received:
            signal.raise_signal(received[0])


def _inside(filename, folder: Path) -> bool:
    """Whether an error's file is in ``folder`` (an error without a file name is taken as the writer's)."""
    if filename is None or isinstance(filename, int):
        return True
    try:
        return Path(os.fsdecode(filename)).resolve().is_relative_to(folder.resolve())
    except (OSError, ValueError, TypeError):
        return False


def _lock_pid(lock: Path) -> int | None:
    try:
        return int(lock.read_text().strip())
    except (OSError, ValueError):
        return None
