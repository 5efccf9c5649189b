"""Shared reference values and helpers for the tests.

Everything here is written from docs/model.md (the model facts, with the paper's
printing errors corrected) and the paper's Table 1 / Eq. 5, independently of the
package code, so that the tests compare the package against numbers it did not
produce.
"""
from __future__ import annotations

import copy
import importlib.util
import os
import shlex
import shutil
import sys
import tempfile
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

# --- markers and the private temporary folder -------------------------------------------------
NO_CC_REASON = "no C compiler (cc/gcc/CC) found"


def c_compiler_available() -> bool:
    """Whether an FMU can be built here: ``$CC`` when set (it must exist), else cc, gcc or clang on PATH."""
    spec = os.environ.get("CC")
    if spec:
        argv = shlex.split(spec)
        return bool(argv) and shutil.which(argv[0]) is not None
    return any(shutil.which(name) for name in ("cc", "gcc", "clang"))


def pytest_collection_modifyitems(config, items):
    # FMU-building tests skip, rather than fail, on a machine without a C compiler
    if c_compiler_available():
        return
    skip = pytest.mark.skip(reason=NO_CC_REASON)
    for item in items:
        if item.get_closest_marker("needs_cc") is not None:
            item.add_marker(skip)


@pytest.fixture(scope="session", autouse=True)
def session_temp_folder(tmp_path_factory):
    """The whole run's temporary files (module fixtures, child processes) go to a folder of its own.

    Other processes on the machine (another test run, an FMU loaded in a loop) use the
    machine-wide temporary folder; nothing here looks there.
    """
    folder = tmp_path_factory.mktemp("session-tmp")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tempfile, "tempdir", str(folder))
        patch.setenv("TMPDIR", str(folder))
        yield folder


@pytest.fixture(autouse=True)
def private_temp_folder(tmp_path_factory, monkeypatch):
    """Each test's temporary files (``tempfile`` and child processes) go to its own folder (not in tmp_path)."""
    folder = tmp_path_factory.mktemp("private-tmp")
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    monkeypatch.setenv("TMPDIR", str(folder))
    return folder


# --- docs/model.md, "Table 1 and the constants k1..k5" (exact) -------------------------------
PAPER_K = {"k1": 7.88827, "k2": 0.4756, "k3": 4.36971, "k4": 0.25, "k5": 1.47486}
PAPER_S1, PAPER_S2 = 0.71656, 0.29
PAPER_G = 9.8
PAPER_FR = np.array([1.43, 1.6, 1.4, 1.2])           # Eq. 4 amplitudes
PAPER_KP, PAPER_KD, PAPER_Y = 180.0, 36.0, 10.0

# Table 1 and Table 2 numbers used for kinematics (kinematic link lengths = paper's l1, l2)
L1, L2, D1, D4 = 0.5, 0.2, 0.12, 0.271
SKIN_DEFAULT = D1 - 0.24 - D4                         # tool height at Table 1's d3 = 0.24 m


def reference_inertia(theta2, k=None) -> np.ndarray:
    """M(q) of Eq. 5 written out from the constants of docs/model.md ("Inertia matrix"), shape (..., 4, 4)."""
    k = PAPER_K if k is None else k
    c2 = np.cos(np.asarray(theta2, dtype=float))
    M = np.zeros(c2.shape + (4, 4))
    M[..., 0, 0] = k["k1"] + k["k2"] * c2
    M[..., 0, 1] = M[..., 1, 0] = k["k3"] + 0.5 * k["k2"] * c2
    M[..., 1, 1] = k["k3"]
    M[..., 2, 2] = k["k4"]
    M[..., 0, 3] = M[..., 3, 0] = -k["k5"]
    M[..., 1, 3] = M[..., 3, 1] = -k["k5"]
    M[..., 3, 3] = k["k5"]
    return M


def reference_fk(q, a1=L1, a2=L2, d1=D1, d4=D4) -> np.ndarray:
    """Forward kinematics of docs/model.md ("Kinematics"): [x, y, z, phi]."""
    q = np.asarray(q, dtype=float)
    t1, t2, d3, t4 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([a1 * np.cos(t1) + a2 * np.cos(t1 + t2), a1 * np.sin(t1) + a2 * np.sin(t1 + t2),
                     d1 - d3 - d4, t1 + t2 - t4], axis=-1)


def fd_jacobian(f, q, h=1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of f: R^4 -> R^m at q, shape (m, 4)."""
    q = np.asarray(q, dtype=float)
    cols = []
    for j in range(q.size):
        dq = np.zeros_like(q)
        dq[j] = h
        cols.append((np.asarray(f(q + dq)) - np.asarray(f(q - dq))) / (2 * h))
    return np.stack(cols, axis=-1)


# --- scenarios -------------------------------------------------------------------------------
def paper_toml_dict() -> dict:
    """The built-in paper scenario file, parsed with tomllib (the raw file, not the package's data)."""
    text = (resources.files("blocks") / "scenarios" / "paper.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def make_scenario(**sections):
    """The paper scenario file with some sections changed.

    A ``trajectory`` section replaces the file's one entirely (the keys depend on
    the kind); other tables are updated key by key.
    """
    from blocks import scenario_from_dict

    data = copy.deepcopy(paper_toml_dict())
    for key, value in sections.items():
        if key == "trajectory" or not isinstance(value, dict):
            data[key] = value
        else:
            data[key] = {**data.get(key, {}), **value}
    return scenario_from_dict(data, source="<test>")


def hold_trajectory(offset=(0.3, 2.0, 0.24, 0.1)) -> dict:
    """A joint_sine section that holds the arm still at ``offset``."""
    return {"kind": "joint_sine", "amplitude": [0.0, 0.0, 0.0, 0.0], "omega": 1.0, "offset": list(offset)}


def joint_signal(response, prefix: str) -> np.ndarray:
    """The four signals ``prefix[0..3]`` of a response, shape (4, n)."""
    labels = list(response.output_labels)
    return np.array([response.outputs[labels.index(f"{prefix}[{i}]")] for i in range(4)])


@pytest.fixture(scope="session")
def paper_params():
    from blocks import RobotParameters

    return RobotParameters()


# A one-second run holding the arm near a fixed pose under the paper disturbance: end-to-end CLI and report
# tests need a real scenario file but not the 10 s path.
SHORT_SCENARIO_TOML = """
name = "short"
[trajectory]
kind = "joint_sine"
amplitude = [0.05, 0.05, 0.005, 0.05]
omega = 2.0
offset = [0.0, 2.0, 0.24, 0.0]
[disturbance]
kind = "paper"
[simulation]
t_final = 1.0
output_step = 0.01
"""


def load_benchmark(name: str):
    """A script of benchmarks/ imported as a module (its own folder on the path while it loads, for _timing)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(path.parent))
    return module


@pytest.fixture(scope="module")
def short_toml(tmp_path_factory):
    """``SHORT_SCENARIO_TOML`` written as a scenario file (1 s of a joint sine), for the commands that read one."""
    path = tmp_path_factory.mktemp("short") / "short.toml"
    path.write_text(SHORT_SCENARIO_TOML)
    return path
