"""Output folders: default names, and reserved staging so that a failed or concurrent run leaves nothing mixed."""
from __future__ import annotations

import os
import shutil
import tempfile
import weakref
from datetime import datetime
from pathlib import Path

__all__ = ["default_out_dir", "staged_output"]


def default_out_dir(prefix: str = "dobkit-run") -> Path:
    """A new folder name under the current one, ``prefix-YYYYmmdd-HHMMSS`` (suffixed if taken)."""
    base = Path.cwd() / f"{prefix}-{datetime.now():%Y%m%d-%H%M%S}"
    path, k = base, 1
    while path.exists():
        path, k = Path(f"{base}-{k}"), k + 1
    return path


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


def _release(lock: Path, created: Path | None) -> None:
    """Undo a reservation that was not used: the lock file, and the folder if this run made it (and it is empty)."""
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
            lock.unlink(missing_ok=True)        # left by a run that was killed
            for stale in target.glob(".partial-*"):
                shutil.rmtree(stale, ignore_errors=True)
        if target.exists() and any(target.iterdir()):
            raise FileExistsError(f"output folder '{target}' exists and is not empty; choose a new --out")
        created = None
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                target.mkdir()
            except FileExistsError:
                raise FileExistsError(f"output folder '{target}' was just created by another run; choose another "
                                      "--out") from None
            created = target
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            raise FileExistsError(f"output folder '{target}' is being written by another dobkit run; choose another "
                                  "--out") from None
        except PermissionError:
            _release(lock, created)
            raise PermissionError(f"output folder '{target}' cannot be written (permission denied); choose another "
                                  "--out") from None
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        self._lock, self._created = lock, created
        self._release = weakref.finalize(self, _release, lock, created)     # work that fails before `with`

    def __enter__(self) -> Path:
        self.stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=self.target))
        self.stage.chmod(0o777 & ~_umask())
        return self.stage

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self._release()
            return
        try:
            for entry in sorted(self.stage.iterdir()):
                os.replace(entry, self.target / entry.name)
            self.stage.rmdir()
        except OSError as err:
            kept = self.target / f"results-not-moved-{datetime.now():%Y%m%d-%H%M%S}"
            self.stage.rename(kept)
            self._lock.unlink(missing_ok=True)
            self._release.detach()
            raise OSError(f"the results could not be moved into '{self.target}' ({err}); they are complete in "
                          f"'{kept}'") from None
        self._lock.unlink(missing_ok=True)
        self._release.detach()


def _lock_pid(lock: Path) -> int | None:
    try:
        return int(lock.read_text().strip())
    except (OSError, ValueError):
        return None
