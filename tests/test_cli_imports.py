"""The command line starts without the heavy libraries: importing ``dobkit.cli`` and the packages loads none of
them, and errors and ``--version`` come before any is imported.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

# --- commands start without the heavy libraries -----------------------------------------------------------------
HEAVY = ("control", "scipy", "matplotlib", "numba", "fmpy", "dask", "pandas")


def _fresh_python(code: str, cwd) -> subprocess.CompletedProcess:
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def test_the_command_line_imports_no_heavy_library(tmp_path):
    run = _fresh_python("import sys, dobkit.cli, blocks, analysis, fmu, blocks.scenarios.scenario\n"
                        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))", tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"


@pytest.mark.parametrize("argv, words", [
    (["--version"], "dobkit "),
    (["simulate", "--scenario", "BAD"], "'simulation.t_final' must be > 0.0, got -1"),
    (["analyze", "--scenario", "BAD"], "'simulation.t_final' must be > 0.0, got -1"),
    (["simulate", "--engine", "warp"], "invalid choice: 'warp'"),
    (["fmu", "export", "--scenario", "BAD", "--out", "p.fmu"], "'simulation.t_final' must be > 0.0, got -1"),
])
def test_errors_and_version_come_before_the_heavy_imports(tmp_path, argv, words):
    bad = tmp_path / "bad.toml"
    bad.write_text("[simulation]\nt_final = -1\n")
    argv = [str(bad) if a == "BAD" else a for a in argv]
    code = ("import contextlib, io, sys\nfrom dobkit.cli import main\nerr, out = io.StringIO(), io.StringIO()\n"
            "with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):\n"
            f"    try:\n        status = main({argv!r})\n    except SystemExit as stop:\n        status = stop.code\n"
            f"print(status, sorted(m for m in {HEAVY!r} if m in sys.modules), repr(err.getvalue() + out.getvalue()))")
    run = _fresh_python(code, tmp_path)
    assert run.returncode == 0, run.stderr
    status, loaded, text = run.stdout.strip().split(" ", 2)
    assert status in ("0", "2") and loaded == "[]", run.stdout
    assert words in text
    assert not (tmp_path / "p.fmu").exists()
