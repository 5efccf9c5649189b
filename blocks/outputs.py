"""Output folders: default names, and staging so that a failed run leaves nothing behind."""
from __future__ import annotations

import shutil
import tempfile
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


class staged_output:
    """Context manager: a staging folder that replaces ``target``'s files only on success.

    ``target`` may not exist or be an empty folder; a non-empty folder is refused
    so that earlier results are never mixed with new ones.
    """

    def __init__(self, target: Path) -> None:
        self.target = Path(target)
        if self.target.exists() and not self.target.is_dir():
            raise FileExistsError(f"output folder '{self.target}' is an existing file, not a folder; choose a new --out")
        if self.target.exists() and any(self.target.iterdir()):
            raise FileExistsError(f"output folder '{self.target}' exists and is not empty; choose a new --out")

    def __enter__(self) -> Path:
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.stage = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.partial-", dir=self.target.parent))
        return self.stage

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            return
        if self.target.exists():
            self.target.rmdir()
        self.stage.rename(self.target)
