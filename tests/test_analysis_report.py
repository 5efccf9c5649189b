"""``dobkit analyze`` and ``dobkit report`` end to end: files, JSON schema, self-contained HTML, same numbers again."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from dobkit.analysis.report import AnalysisSettings, run_analysis, write_report
from dobkit.blocks import load_scenario
from dobkit.cli import main

SHORT = """
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

# Small grids and short runs: every analysis, in seconds.
TINY = AnalysisSettings(mismatch_factors=(0.5, 2.0), boundary_points=5, workspace_points=(2, 13, 1, 2),
                        kp_values=(180.0,), kd_values=(36.0,), observer_values=(30.0,), study_t_final=0.5,
                        design_t_final=0.5, noise_t_final=0.1)

FIGURES = ("linear_poles", "linear_mismatch", "observer_bandwidth", "observer_design", "frequency_tracking",
           "frequency_estimation", "study_gains", "study_observer")


def _strict(text):
    def bad(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=bad)


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scen") / "short.toml"
    path.write_text(SHORT)
    return path


@pytest.fixture(scope="module")
def analyzed(tmp_path_factory, scenario_file):
    out = tmp_path_factory.mktemp("analyze") / "out"
    status = main(["analyze", "--scenario", str(scenario_file), "--out", str(out), "--quick", "--jobs", "2"])
    return status, out


@pytest.fixture(scope="module")
def reported(tmp_path_factory, scenario_file):
    out = tmp_path_factory.mktemp("report") / "out"
    path = write_report(load_scenario(scenario_file), out, TINY)
    return path, out


def test_analyze_writes_json_and_figures(analyzed):
    status, out = analyzed
    assert status == 0
    data = _strict((out / "analysis.json").read_text())
    op = data["operating_points"][0]
    assert op["q0"] == pytest.approx([0.0, 2.0, 0.24, 0.0])
    assert len(op["poles_with_dob"]) == 12 and len(op["poles_without_dob"]) == 8
    assert all(len(p) == 2 and p[0] < 0 for p in op["poles_with_dob"] + op["poles_without_dob"])
    bw = data["observer_bandwidth"]
    assert len(bw["theta2"]) == len(bw["eigenvalues"]) and all(len(row) == 4 for row in bw["eigenvalues"])
    assert bw["slowest_rad_s"]["min"] == pytest.approx(0.848, abs=0.001)        # paper-notes, at theta2 = 0
    assert bw["slowest_rad_s"]["min"] <= bw["slowest_rad_s"]["max"] == pytest.approx(0.930, abs=0.001)
    for section in ("mismatch", "observer_design", "frequency", "studies"):
        assert section in data
    names = {p.name for p in out.iterdir()}
    for stem in FIGURES:
        assert {f"{stem}.png", f"{stem}.svg"} <= names
        assert (out / f"{stem}.png").stat().st_size > 10_000
    assert sorted(data["figures"]) == sorted(n for n in names if n != "analysis.json")


def test_cli_errors_are_one_clear_line(analyzed, scenario_file, capsys):
    _, out = analyzed
    assert main(["analyze", "--scenario", "no-such-scenario", "--out", str(out.parent / "x")]) == 2
    assert "no built-in scenario named 'no-such-scenario'" in capsys.readouterr().err
    assert main(["analyze", "--scenario", str(scenario_file), "--out", str(out)]) == 2     # not empty
    assert "not empty" in capsys.readouterr().err
    assert main(["report", "--scenario", str(scenario_file), "--out", str(out.parent / "y"),
                 "--observer-target", "-1"]) == 2
    assert "--observer-target" in capsys.readouterr().err


def test_report_is_one_self_contained_file(reported):
    path, out = reported
    html = path.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>")
    # nothing fetched from anywhere: no scripts, stylesheets or remote images; all images inline
    assert not re.search(r"<script|<link|<iframe|src=\"(?!data:)", html)
    assert "http://" not in html and "https://" not in html
    images = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,', html)
    pngs = list((out / "figures").glob("*.png"))
    assert len(images) == len(pngs) >= len(FIGURES) + 5                   # ours and Figures 4-8
    for heading in ("Summary for the surgical team", "1. Scenario", "2. Simulation", "3. Linearized closed loop",
                    "4. Observer bandwidth", "5. Observer gain design", "6. Disturbance rejection in frequency",
                    "7. Gain and noise studies", "Figure 5"):
        assert heading in html


def test_report_numbers_come_from_the_computation(reported):
    path, out = reported
    html = path.read_text(encoding="utf-8")
    metrics = _strict((out / "metrics.json").read_text())
    data = _strict((out / "analysis.json").read_text())
    worst = metrics["with_dob"]["max_tool_position_error_mm"]
    assert f"strays at most {worst:.3g} mm" in html
    assert f"{data['observer_bandwidth']['slowest_rad_s']['min']:.4g} rad/s at q" in html
    boundary = data["mismatch"]["with_dob"]["boundaries"]["boundaries"]
    assert boundary and f"a = {boundary[0]['factor']:.6g}" in html


def test_same_scenario_gives_the_same_numbers(reported, scenario_file):
    _, out = reported
    written = _strict((out / "analysis.json").read_text())
    written.pop("figures")
    again = json.loads(json.dumps(run_analysis(load_scenario(scenario_file), TINY), default=np.ndarray.tolist))
    assert again == written
