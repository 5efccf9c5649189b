"""Hostile FMUs and full disks: an FMU's identifiers cannot name a library outside its archive, and an export
to a full disk says which file could not be written.

docs/hostile-inputs.md, "Round 8", lists each case with its test.  The FMUs are real: the hand-written lag FMU of
tests/fmu_lag, repackaged with one thing changed, and a shared library built with the system C compiler whose
constructor leaves a marker file when anything loads it.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from fmu import FMUModelDescriptionError, load
from fmu.description import identifier_problems
from fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"
LAG_DESCRIPTION = (LAG_DIR / "modelDescription.xml").read_text(encoding="utf-8")

pytestmark = pytest.mark.needs_cc

EVIL_C = """
#include <stdio.h>
__attribute__((constructor)) static void loaded(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("loaded", f); fclose(f); }
}
"""


def _dobkit(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "dobkit", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def lag_fmu(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lag")
    return package_fmu(folder / "lag.fmu", LAG_DESCRIPTION, {"lag.c": LAG_DIR / "lag.c"}, ["lag.c"], "lag", 2)


def _evil_library(folder: Path) -> tuple[Path, Path]:
    """A shared library ``folder/evil.so`` whose loading writes ``folder/loaded``."""
    marker = folder / "loaded"
    source = folder / "evil.c"
    source.write_text(EVIL_C % marker, encoding="utf-8")
    cc = shutil.which("cc") or shutil.which("gcc")
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(folder / "evil.so"), str(source)], check=True)
    return folder / "evil", marker


def _repackaged(lag: Path, out: Path, identifier: str) -> Path:
    """The lag FMU with ``identifier`` as its modelIdentifier and an empty binaries/linux64/ folder."""
    with zipfile.ZipFile(lag) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            if info.filename.startswith("binaries/"):
                continue
            data = src.read(info)
            if info.filename == "modelDescription.xml":
                data = data.replace(b'modelIdentifier="lag"', f'modelIdentifier="{identifier}"'.encode())
            dst.writestr(info, data)
        dst.writestr("binaries/linux64/", b"")
    return out


def _escaping_identifier(target: Path) -> str:
    # from <extraction>/binaries/linux64/ as many levels up as any temporary folder can be deep, then down to target
    return "../" * 40 + str(target).lstrip("/")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the library name is binaries/linux64/ID.so")
def test_a_model_identifier_with_a_path_is_refused_before_any_library_is_loaded(tmp_path, lag_fmu):
    # before: fmu.load and `dobkit fmu check` dlopened <dir>/evil.so (its constructor ran) and the check said
    # "validation (fmpy): passed"
    evil, marker = _evil_library(tmp_path)
    fmu = _repackaged(lag_fmu, tmp_path / "evil.fmu", _escaping_identifier(evil))
    with pytest.raises(FMUModelDescriptionError, match=r"ModelExchange modelIdentifier='(\.\./)+.*evil' is not a C "
                                                       r"identifier .* which FMI requires"):
        load(fmu)
    assert not marker.exists()
    done = _dobkit("fmu", "check", fmu)
    assert done.returncode != 0 and not marker.exists(), done.stdout + done.stderr
    assert "is not a C identifier" in done.stdout + done.stderr
    assert "validation (fmpy): passed" not in done.stdout


@pytest.mark.parametrize("identifier, good", [
    ("lag", True), ("_lag2", True), ("Lag_3x", True),
    ("2lag", False), ("la-g", False), ("lag.so", False), ("sub/lag", False), ("..", False), ("", False),
    ("lag ", False), ("läg", False), ("lag\u0661", False)])
def test_identifiers_are_checked_as_fmi_requires_c_identifiers(identifier, good):
    from types import SimpleNamespace as N
    md = N(modelExchange=N(modelIdentifier=identifier), coSimulation=N(modelIdentifier="lag"))
    assert (identifier_problems(md) == []) is good


def test_a_good_identifier_still_loads_and_a_bad_co_simulation_one_is_refused(tmp_path, lag_fmu):
    block = load(lag_fmu)
    block.fmu.close()
    text = LAG_DESCRIPTION.replace('<CoSimulation modelIdentifier="lag"', '<CoSimulation modelIdentifier="lag/x"')
    bad = package_fmu(tmp_path / "bad.fmu", text, {"lag.c": LAG_DIR / "lag.c"}, ["lag.c"], "lag", 2)
    with pytest.raises(FMUModelDescriptionError, match=r"CoSimulation modelIdentifier='lag/x' is not a C identifier"):
        load(bad)


def _can_mount() -> bool:
    if shutil.which("unshare") is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        return False
    return subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True).returncode == 0


@pytest.mark.slow                      # compiles the plant
@pytest.mark.skipif(not _can_mount(), reason="needs root and mount namespaces (unshare -m) for a real small tmpfs")
def test_an_fmu_exported_to_a_full_disk_is_named_with_the_file(tmp_path):
    # before: "dobkit fmu: error: [Errno 28] No space left on device"
    mount = tmp_path / "mnt"
    mount.mkdir()
    shell = (f"mount -t tmpfs -o size=64k tmpfs {mount} && (dd if=/dev/zero of={mount}/fill bs=1k count=100 "
             f"2>/dev/null; {sys.executable} -m dobkit fmu export --out {mount}/p.fmu; echo rc=$?; ls -A {mount})")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    run = subprocess.run(["unshare", "-m", "sh", "-c", shell], capture_output=True, text=True, env=env, timeout=600)
    assert run.stderr.strip() == (f"dobkit fmu: error: FMU file '{mount}/p.fmu' cannot be written: the disk is full "
                                  "(no space left); free space or choose another --out; nothing was written")
    assert run.stdout.split() == ["rc=2", "fill"]               # no FMU and no temporary archive left
