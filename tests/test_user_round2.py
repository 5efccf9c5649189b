"""What a user sees (issue 21, round 2): the path a user asked for, one skin plane, the simulate flags,
a command line that starts without the heavy imports, pandas, and an FMU export that keeps existing files."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import D1, D4
from conftest import SHORT_SCENARIO_TOML as SHORT

import blocks
from blocks import ScenarioError, load_scenario
from blocks.metrics import tracking_metrics
from dobkit.cli import SIMULATE_ENGINES, main

# paper.toml's laceration (read from the file, not from the code): start, end and hover above the skin (m)
PAPER_START, PAPER_END, PAPER_HOVER = (0.36, -0.05), (0.46, 0.05), 0.003


def _rows(resp, name: str) -> np.ndarray:
    labels = list(resp.output_labels)
    return np.array([resp.outputs[labels.index(f"{name}[{i}]")] for i in range(4)])


def _tool_tip(q) -> np.ndarray:
    """Tool tip ``x, y, z`` of Eq. 8 by hand (link lengths l1 = 0.5 m, l2 = 0.2 m; z = d1 - d3 - d4)."""
    t1, t2, d3 = q[0], q[1], q[2]
    return np.array([0.5 * np.cos(t1) + 0.2 * np.cos(t1 + t2), 0.5 * np.sin(t1) + 0.2 * np.sin(t1 + t2),
                     D1 - d3 - D4])


# --- simulation.t_final never rescales the path ---------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_runs():
    paper = load_scenario("paper")
    short = paper.with_changes({"simulation.t_final": 2.0})
    return (blocks.simulate(paper, engine="fast"), blocks.simulate(short, engine="fast"), paper, short)


def test_a_short_window_is_the_start_of_the_same_path(paper_runs):
    full, short, paper, two = paper_runs
    assert two.trajectory.duration == paper.trajectory.duration == 10.0
    n = len(short.time)
    assert n == 401 and short.time[-1] == pytest.approx(2.0)
    np.testing.assert_array_equal(short.time, full.time[:n])
    # the reference is the same function of time: identical numbers on the shared grid
    for name in ("q_ref", "dq_ref", "ddq_ref"):
        np.testing.assert_array_equal(_rows(short, name), _rows(full, name)[:, :n])
    # and the run follows it as the 10 s run does (same solver, same tolerances)
    np.testing.assert_allclose(_rows(short, "q"), _rows(full, "q")[:, :n], rtol=0, atol=1e-7)
    tau_short, tau_full = _rows(short, "tau"), _rows(full, "tau")
    np.testing.assert_allclose(tau_short, tau_full[:, :n], rtol=1e-5, atol=1e-5)
    # peak |tau|: about 30 N m, as in the whole paper run (a path squeezed into 2 s needed 718 N m)
    peak = np.abs(tau_short).max()
    assert peak <= np.abs(tau_full).max() * (1 + 1e-9)
    assert 20.0 < peak < 40.0


def test_the_path_starts_where_the_file_says(paper_runs):
    _, short, _, _ = paper_runs
    tip = _tool_tip(_rows(short, "q_ref")[:, 0])
    skin = load_scenario("paper").disturbance.skin_height
    np.testing.assert_allclose(tip, [*PAPER_START, skin + PAPER_HOVER], atol=1e-12)


def test_a_longer_window_holds_the_end_of_the_path():
    long = load_scenario("paper").with_changes({"simulation.t_final": 12.0})
    assert long.trajectory.duration == 10.0
    q, dq, ddq = long.trajectory.evaluate(np.array([10.0, 11.0, 12.0]))
    skin = long.disturbance.skin_height
    for k in range(3):
        np.testing.assert_allclose(_tool_tip(q[k]), [*PAPER_END, skin + PAPER_HOVER], atol=1e-12)
    np.testing.assert_array_equal(dq, 0.0)
    np.testing.assert_array_equal(ddq, 0.0)


def test_a_path_duration_of_its_own_is_kept():
    s = load_scenario("paper").with_changes({"trajectory.duration": 6.0, "simulation.t_final": 3.0})
    assert s.trajectory.duration == 6.0 and s.simulation.t_final == 3.0
    # the stitch phases are 6 / 9 s long: at t = 6 s the path is at its end, at 3 s it is not
    tip_end = _tool_tip(s.trajectory.evaluate(6.0)[0])
    np.testing.assert_allclose(tip_end[:2], PAPER_END, atol=1e-12)
    assert not np.allclose(_tool_tip(s.trajectory.evaluate(3.0)[0])[:2], PAPER_END, atol=1e-3)


# --- one skin plane ---------------------------------------------------------------------------------------------
def test_the_skin_plane_is_the_disturbance_key():
    s = load_scenario("paper").with_changes({"disturbance.skin_height": -0.35})
    assert s.trajectory.skin_height == -0.35
    q0 = s.trajectory.evaluate(0.0)[0]
    assert _tool_tip(q0)[2] == pytest.approx(-0.35 + PAPER_HOVER, abs=1e-12)
    assert "skin_height" not in s.data["trajectory"] and s.data["disturbance"]["skin_height"] == -0.35
    # the written scenario has the plane once and reads back the same
    assert load_scenario("paper").with_changes({"disturbance.skin_height": -0.35}).to_toml().count("skin_height") == 1


def test_an_agreeing_second_skin_height_is_accepted():
    s = load_scenario("paper").with_changes({"disturbance.skin_height": -0.36, "trajectory.skin_height": -0.36})
    assert s.trajectory.skin_height == s.disturbance.skin_height == -0.36


@pytest.mark.parametrize("changes", [{"trajectory.skin_height": -0.35},
                                     {"disturbance.skin_height": -0.36, "trajectory.skin_height": -0.35}])
def test_a_disagreeing_second_skin_height_is_refused(changes):
    with pytest.raises(ScenarioError) as err:
        load_scenario("paper").with_changes(changes)
    text = str(err.value)
    assert "'trajectory.skin_height' (-0.35 m)" in text and "'disturbance.skin_height'" in text
    expected = changes.get("disturbance.skin_height", load_scenario("paper").disturbance.skin_height)
    assert repr(expected) in text and math.isfinite(expected)


# --- dobkit simulate --no-figures, --svg and --engine -----------------------------------------------------------
FIGURE_STEMS = ("fig4_joint_tracking", "fig5_tracking_error", "fig6_disturbance_estimate", "fig7_estimation_error",
                "fig8_task_space")


@pytest.fixture(scope="module")
def short_toml(tmp_path_factory):
    path = tmp_path_factory.mktemp("round2") / "short.toml"
    path.write_text(SHORT)
    return path


def _simulate(short_toml, out, *flags) -> tuple[int, dict]:
    status = main(["simulate", "--scenario", str(short_toml), "--out", str(out), *flags])
    return status, (json.loads((out / "metrics.json").read_text()) if status == 0 else {})


def test_no_figures_writes_the_numbers_only(short_toml, tmp_path, capsys):
    status, metrics = _simulate(short_toml, tmp_path / "out", "--no-figures", "--engine", "fast")
    assert status == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["metrics.json", "scenario.toml", "timeseries.csv"]
    assert metrics["engine"] == "fast"
    assert "no figures (--no-figures)" in capsys.readouterr().out


def test_figures_are_png_by_default_and_svg_on_request(short_toml, tmp_path):
    assert _simulate(short_toml, tmp_path / "png", "--engine", "fast")[0] == 0
    names = {p.name for p in (tmp_path / "png").iterdir()}
    assert {f"{s}.png" for s in FIGURE_STEMS} <= names and not any(n.endswith(".svg") for n in names)
    assert _simulate(short_toml, tmp_path / "both", "--engine", "fast", "--svg")[0] == 0
    for stem in FIGURE_STEMS:
        svg = (tmp_path / "both" / f"{stem}.svg").read_text()
        assert svg.lstrip().startswith("<?xml") and "time (s)" in svg          # every figure keeps its axes' labels
        assert (tmp_path / "both" / f"{stem}.png").stat().st_size > 10_000


def test_no_figures_and_svg_exclude_each_other(short_toml, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["simulate", "--scenario", str(short_toml), "--no-figures", "--svg"])
    assert stop.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_the_engine_flag_picks_the_engine(short_toml, tmp_path):
    scenario = load_scenario(short_toml)
    for engine in ("fast", "python-control"):
        status, metrics = _simulate(short_toml, tmp_path / engine, "--no-figures", "--engine", engine)
        assert status == 0 and metrics["engine"] == engine
        # the command's numbers are those of a run with that engine from Python
        same = tracking_metrics(blocks.simulate(scenario, engine=engine))
        assert metrics["with_dob"]["rms_position_error"] == same["rms_position_error"]
    # the PD error dynamics without observer: the prismatic joint sags by M^-1 d / Kp = 1.4 / 0.25 / 180 m
    assert metrics["without_dob"]["max_abs_position_error"][2] == pytest.approx(1.4 / 0.25 / 180, rel=0.05)


def test_the_engine_choices_are_the_simulators(capsys):
    from blocks.loop import ENGINES

    assert SIMULATE_ENGINES == ENGINES
    with pytest.raises(SystemExit):
        main(["simulate", "--engine", "warp"])
    assert "invalid choice: 'warp'" in capsys.readouterr().err


# --- commands start without the heavy libraries -----------------------------------------------------------------
HEAVY = ("control", "scipy", "matplotlib", "numba", "fmpy", "dask", "pandas")


def _fresh_python(code: str, cwd) -> subprocess.CompletedProcess:
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def test_the_command_line_imports_no_heavy_library(tmp_path):
    run = _fresh_python("import sys, dobkit.cli, blocks, analysis, fmu, blocks.scenario\n"
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


# --- pandas comes with the package ------------------------------------------------------------------------------
def test_to_pandas_gives_every_signal_by_name(short_toml):
    resp = blocks.simulate(load_scenario(short_toml), engine="fast")
    frame = resp.to_pandas()
    assert list(frame.columns[:1 + len(resp.output_labels)]) == ["time", *resp.output_labels]   # then the states
    assert len(frame) == 101 and frame["time"].iloc[-1] == pytest.approx(1.0)
    # the joint-sine reference of the short scenario: q_ref[1] = 2 + 0.05 sin(2 t) (rad)
    t = frame["time"].to_numpy()
    np.testing.assert_allclose(frame["q_ref[1]"].to_numpy(), 2.0 + 0.05 * np.sin(2.0 * t), atol=1e-12)


def test_pandas_is_a_dependency_of_the_package():
    import tomllib

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    assert any(r.replace(" ", "").startswith("pandas>=") for r in project["dependencies"])     # not an extra


# --- fmu.export_plant keeps an existing file and starts in a regular pose ---------------------------------------
def test_export_refuses_an_existing_file_before_compiling(tmp_path):
    from fmu import export_plant

    target = tmp_path / "plant.fmu"
    target.write_bytes(b"someone's file")
    with pytest.raises(FileExistsError, match="plant.fmu.*exists; refusing to overwrite it.*force=True"):
        export_plant(target)
    assert target.read_bytes() == b"someone's file"
    with pytest.raises(IsADirectoryError, match="is a folder"):
        export_plant(tmp_path)


@pytest.mark.parametrize("force", [False, True])
def test_a_file_another_export_wrote_while_this_one_compiled_is_kept_unless_forced(tmp_path, force):
    """Two exports to one path at once: the check before compiling passes for both; without force the second to
    finish is refused when it puts its archive in place (a real compiler, run by a script that first writes the
    other export's file)."""
    import zipfile

    from fmu import export_plant
    from fmu.build import find_compiler

    target = tmp_path / "plant.fmu"
    compiler = tmp_path / "cc-after-another-export"
    compiler.write_text(f"#!/bin/sh\nprintf 'the other export' > '{target}'\nexec {find_compiler()[0]} \"$@\"\n")
    compiler.chmod(0o755)
    if force:
        export_plant(target, cc=str(compiler), force=True)
        assert zipfile.is_zipfile(target)                   # replaced, as asked
    else:
        with pytest.raises(FileExistsError, match="plant.fmu.*written by another export.*force=True"):
            export_plant(target, cc=str(compiler))
        assert target.read_bytes() == b"the other export"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []    # no archive left half-named


@pytest.mark.needs_cc
def test_export_replaces_with_force_and_starts_in_a_regular_pose(tmp_path):
    import fmpy

    from fmu import export_plant

    target = tmp_path / "plant.fmu"
    target.write_bytes(b"old")
    assert export_plant(target, force=True) == target and target.stat().st_size > 1000
    start = {v.name: v.start for v in fmpy.read_model_description(str(target)).modelVariables}
    q0 = [float(start[f"q[{i}]"]) for i in range(4)]
    # theta2 = pi/2: |sin(theta2)| = 1, the largest planar Jacobian determinant a1 a2 sin(theta2); d3 = 0.24 m
    assert q0 == pytest.approx([0.0, math.pi / 2, 0.24, 0.0], abs=1e-12)
    assert [float(start[f"dq[{i}]"]) for i in range(4)] == [0.0] * 4
    # a start given by the caller is kept
    again = export_plant(tmp_path / "mine.fmu", q0=[0.1, 1.0, 0.2, 0.0])
    start = {v.name: v.start for v in fmpy.read_model_description(str(again)).modelVariables}
    assert float(start["q[1]"]) == pytest.approx(1.0)


def test_figure_formats_are_checked(short_toml, tmp_path):
    from analysis.simulation.figures import paper_figures

    resp = blocks.simulate(load_scenario(short_toml), engine="fast")
    with pytest.raises(ValueError, match=r"figure formats must be one or more of \['png', 'svg'\], got \('jpg',\)"):
        paper_figures(resp, resp, tmp_path, formats=("jpg",))
    assert not any(tmp_path.iterdir())
