"""The examples/ gallery: every script runs as a user runs it and writes its figure.

Each script runs in its own process (``sys.executable``) from an empty folder,
with ``DOBKIT_EXAMPLES_OUT`` pointing at a fresh output folder; it must exit 0
and write exactly its own PNG there.  Where a script prints a number with a
closed form (the linearized loop's poles, the DC gain of the computed-torque
loop), the number is checked against the paper's constants (docs/model.md),
not against the package.
"""
from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import PAPER_K, PAPER_KD, PAPER_KP, PAPER_Y

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SCRIPTS = ["wire_blocks_by_hand", "linearize_and_bode", "small_sweep", "fmu_cosimulation", "digital_controller",
           "urdf_arm"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_example(name: str, tmp_path: Path) -> tuple[subprocess.CompletedProcess, Path]:
    """Run ``examples/NAME.py`` from an empty folder; the output folder is made by the script."""
    work, out = tmp_path / "work", tmp_path / "figures"
    work.mkdir()
    env = dict(os.environ, DOBKIT_EXAMPLES_OUT=str(out), MPLBACKEND="Agg")
    # this checkout's packages, not whichever copy is installed
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    proc = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py")], cwd=work, env=env,
                          capture_output=True, text=True, timeout=300)
    return proc, out


def test_gallery_lists_every_script():
    on_disk = sorted(p.stem for p in EXAMPLES.glob("*.py"))
    assert on_disk == sorted(SCRIPTS), "a script in examples/ is not run by this test (or one listed is missing)"
    readme = (EXAMPLES / "README.md").read_text(encoding="utf-8")
    missing = [name for name in SCRIPTS if f"{name}.py" not in readme]
    assert not missing, f"examples/README.md does not describe {missing}"
    assert "examples/README.md" in (ROOT / "README.md").read_text(encoding="utf-8")


@pytest.mark.parametrize("name", [
    pytest.param(name, marks=[pytest.mark.needs_cc] if name == "fmu_cosimulation" else [])
    for name in SCRIPTS])
def test_example_runs_and_writes_its_figure(name, tmp_path):
    proc, out = run_example(name, tmp_path)
    assert proc.returncode == 0, f"examples/{name}.py exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    assert sorted(p.name for p in out.iterdir()) == [f"{name}.png"]
    data = (out / f"{name}.png").read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 10_000, "not a PNG with a drawn figure in it"
    assert not any(Path(tmp_path / "work").iterdir()), "the script wrote into the current folder"
    _check_numbers(name, proc.stdout)


def _floats(pattern: str, text: str) -> list[float]:
    match = re.search(pattern, text)
    assert match, f"no line matching {pattern!r} in:\n{text}"
    return [float(v) for v in match.groups()]


def _check_numbers(name: str, stdout: str) -> None:
    """What a script prints, against values derived by hand from the paper's constants."""
    if name == "urdf_arm":
        _check_urdf_arm(stdout)
    if name == "linearize_and_bode":
        line = re.search(r"poles with the observer:\s*\[([^\]]*)\]", stdout, re.S)
        assert line, stdout
        poles = sorted(float(v) for v in line.group(1).split())
        # PD roots of s^2 + Kd s + Kp (four joints each) and the prismatic joint's observer pole -Y / k4
        pd = sorted(r.real for r in np.roots([1.0, PAPER_KD, PAPER_KP]))
        for root in pd:
            assert sum(abs(p - root) < 1e-3 for p in poles) == 4, (root, poles)
        assert any(abs(p + PAPER_Y / PAPER_K["k4"]) < 1e-3 for p in poles), poles
        # without the observer the prismatic joint sags by w / (Kp k4): DC gain 1 / (180 * 0.25) m/N
        (dc_ctc, _, dc_dob) = _floats(r"without observer ([-\d.e+]+) m/N \(1/\(Kp M33\) = ([-\d.e+]+)\), "
                                      r"with observer ([-\d.e+]+) m/N", stdout)
        assert dc_ctc == pytest.approx(1.0 / (PAPER_KP * PAPER_K["k4"]), rel=1e-2)
        assert abs(dc_dob) < 1e-9
    elif name == "wire_blocks_by_hand":
        dq, dd = _floats(r"q\[2\] ([-\d.e+]+) m, d_hat\[2\] ([-\d.e+]+) N", stdout)
        # two engines on one interconnection, both at rtol 1e-6: the paths agree to solver tolerance
        assert dq < 1e-5 and dd < 1e-3, stdout
        # the diagram with the user's own blocks: compiled when numba is installed, python-control's numbers
        engine, diff, moved = re.search(r"with the actuator lag: engine (\w[\w-]*); largest difference from "
                                        r"ct.input_output_response ([-\d.e+]+); the lag moves q\[2\] by up to "
                                        r"([-\d.e+]+) mm", stdout).groups()
        assert engine == ("compiled" if importlib.util.find_spec("numba") else "fast"), stdout
        assert float(diff) < 1e-6 and 0.0 < float(moved) < 10.0, stdout
    elif name == "small_sweep":
        errors = [float(v) for v in re.findall(r"RMS tool-tip error ([\d.]+) mm", stdout)]
        assert len(errors) == 6 and all(a > b for a, b in zip(errors, errors[1:])), errors


def _check_urdf_arm(stdout: str) -> None:
    """scope4's observer gain against pinocchio's own inertia of the URDF (Y = 10 rad/s x 1.05 M(q0)), and the
    observer removing the constant disturbance's offset on every joint."""
    pin = pytest.importorskip("pinocchio")
    from blocks.model.urdf import scope4_urdf

    model = pin.buildModelFromUrdf(str(scope4_urdf()))
    q0 = np.array(_floats(r"q0: \[\s*([-\d.e+]+)\s+([-\d.e+]+)\s+([-\d.e+]+)\s+([-\d.e+]+)\s*\]", stdout))
    M = pin.crba(model, model.createData(), q0)
    expected = 10.0 * 1.05 * np.diag(M)            # observer_bandwidth 10 rad/s, nominal_mass_scale 1.05
    got = _floats(r"observer gain diagonal: \[\s*([-\d.e+]+)\s+([-\d.e+]+)\s+([-\d.e+]+)\s+([-\d.e+]+)\s*\]",
                  stdout)
    np.testing.assert_allclose(got, expected, rtol=1e-8)
    late = re.findall(r"(\w+) ([-\d.e+]+) / ([-\d.e+]+)", stdout.split("late RMS error")[1])
    assert [name for name, _, _ in late] == ["yaw", "pitch", "insertion", "roll"]
    for name, with_dob, without in late:
        assert float(with_dob) < float(without) / 50, (name, with_dob, without)
