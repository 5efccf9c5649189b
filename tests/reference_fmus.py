"""The FMI Reference FMUs (modelica/Reference-FMUs), built from their source with cmake and cc.

Their source ships with the tests (``tests/reference_fmus_src``: the Modelica Association's BSD-2-Clause
Reference FMUs, unchanged; its ``LICENSE.txt`` and ``README.md`` say so), so a fresh machine with cmake and
a C compiler builds them.  ``$DOBKIT_REFERENCE_FMUS`` (a checkout, or a bare git directory whose HEAD is
exported) points at another revision instead.  The FMUs are built once per source content into a cache
folder under the system's temporary folder and reused by later runs; without cmake or a C compiler the
tests that need them are skipped with the reason.

Use the ``reference_fmus`` fixture: ``reference_fmus(2, "BouncingBall")`` is the path of the FMI 2 build.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

SHIPPED = Path(__file__).resolve().parent / "reference_fmus_src"
MODELS = {2: ("BouncingBall", "Stair", "Dahlquist", "Feedthrough"),
          3: ("BouncingBall", "Stair", "Dahlquist", "Feedthrough", "StateSpace", "Roberts")}
# taken before the test session points tempfile at its private folder: the cache outlives one run
CACHE_ROOT = Path(os.environ.get("DOBKIT_REFERENCE_FMU_CACHE", Path(tempfile.gettempdir()) / "dobkit-reference-fmus"))


def _source() -> tuple[Path | None, str]:
    """(folder holding the source or a git dir, why not found)."""
    given = os.environ.get("DOBKIT_REFERENCE_FMUS")
    candidate = Path(given) if given else SHIPPED
    if (candidate / "CMakeLists.txt").is_file() or (candidate / "HEAD").is_file():
        return candidate, ""
    return None, (f"no Reference-FMUs source at {candidate} (DOBKIT_REFERENCE_FMUS names a checkout of "
                  "github.com/modelica/Reference-FMUs; unset, the copy shipped in tests/ is used)")


def _revision(source: Path) -> str:
    if (source / "CMakeLists.txt").is_file():
        # a digest of the files' names and bytes, not hash() (str hashes differ per process, so every run and
        # xdist worker built again) nor the path (an edited checkout would keep its stale build)
        digest = hashlib.sha256()
        for path in sorted(p for p in source.rglob("*") if p.is_file()):
            digest.update(str(path.relative_to(source)).encode() + b"\0" + path.read_bytes())
        return "source-" + digest.hexdigest()[:16]
    out = subprocess.run(["git", f"--git-dir={source}", "rev-parse", "HEAD"], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()[:12]


def _build(source: Path, target: Path) -> None:
    work = Path(tempfile.mkdtemp(prefix="build-", dir=target.parent))
    try:
        if (source / "CMakeLists.txt").is_file():
            tree = source
        else:
            tree = work / "src"
            tree.mkdir()
            archive = subprocess.run(["git", f"--git-dir={source}", "archive", "HEAD"], capture_output=True,
                                     check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
        fmus = work / "fmus"
        for version, models in MODELS.items():
            build = work / f"build{version}"
            subprocess.run(["cmake", "-S", str(tree), "-B", str(build), f"-DFMI_VERSION={version}",
                            "-DCMAKE_BUILD_TYPE=Release"], capture_output=True, check=True)
            subprocess.run(["cmake", "--build", str(build), "--target", *models], capture_output=True, check=True)
            (fmus / str(version)).mkdir(parents=True)
            for model in models:
                shutil.copy(build / "fmus" / f"{model}.fmu", fmus / str(version) / f"{model}.fmu")
        try:
            fmus.rename(target)     # atomic: a concurrent run either sees all of them or builds its own
        except OSError:
            if not target.is_dir():
                raise
    finally:
        shutil.rmtree(work, ignore_errors=True)


@pytest.fixture(scope="session")
def reference_fmus():
    """``get(version, model) -> Path`` of a Reference FMU built from source (skips if it cannot be built)."""
    # CI's machine has both tools and the source ships: there a skip would hide that these tests never ran
    give_up = pytest.fail if os.environ.get("CI") else pytest.skip
    if shutil.which("cmake") is None or shutil.which("cc") is None:
        give_up("cmake or cc is not installed: the FMI Reference FMUs cannot be built from source")
    source, why = _source()
    if source is None:
        give_up(why)
    models = "-".join(f"{v}{''.join(m[0] for m in names)}" for v, names in MODELS.items())
    target = CACHE_ROOT / f"{_revision(source)}-{models}"
    if not target.is_dir():
        CACHE_ROOT.mkdir(parents=True, exist_ok=True)
        try:
            _build(source, target)
        except subprocess.CalledProcessError as err:
            detail = (err.stderr or b"")[-2000:].decode(errors="replace") if isinstance(err.stderr, bytes) else ""
            pytest.fail(f"building the Reference FMUs failed: {' '.join(map(str, err.cmd))}\n{detail}")

    def get(version: int, model: str) -> Path:
        return target / str(version) / f"{model}.fmu"

    return get
