"""The FMI Reference FMUs (modelica/Reference-FMUs), built from their public source with cmake and cc.

The source is looked for at ``$DOBKIT_REFERENCE_FMUS`` (a checkout, or a bare git directory whose HEAD is
exported), else at the mirror this machine keeps of ``github:modelica/Reference-FMUs``.  The FMUs are built
once per source commit into a cache folder under the system's temporary folder and reused by later runs;
without cmake, a C compiler or the source the tests that need them are skipped with the reason.

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

MIRROR = Path("/work/.mirror/modelica+Reference-FMUs/repo")
MODELS = {2: ("BouncingBall", "Stair", "Dahlquist", "Feedthrough"),
          3: ("BouncingBall", "Stair", "Dahlquist", "Feedthrough", "StateSpace", "Roberts")}
# taken before the test session points tempfile at its private folder: the cache outlives one run
CACHE_ROOT = Path(os.environ.get("DOBKIT_REFERENCE_FMU_CACHE", Path(tempfile.gettempdir()) / "dobkit-reference-fmus"))


def _source() -> tuple[Path | None, str]:
    """(folder holding the source or a git dir, why not found)."""
    given = os.environ.get("DOBKIT_REFERENCE_FMUS")
    candidate = Path(given) if given else MIRROR
    if (candidate / "CMakeLists.txt").is_file() or (candidate / "HEAD").is_file():
        return candidate, ""
    return None, (f"no Reference-FMUs source at {candidate} (set DOBKIT_REFERENCE_FMUS to a checkout of "
                  "github.com/modelica/Reference-FMUs)")


def _revision(source: Path) -> str:
    if (source / "CMakeLists.txt").is_file():
        # a digest, not hash(): str hashes differ per process (PYTHONHASHSEED), so every run and xdist worker
        # missed the cache and built again
        return "checkout-" + hashlib.sha256(str(source.resolve()).encode()).hexdigest()[:16]
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
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed: the FMI Reference FMUs cannot be built from source")
    source, why = _source()
    if source is None:
        pytest.skip(why)
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
