"""``dobkit analyze`` and ``dobkit report`` end to end: files, JSON schema, self-contained HTML, same numbers again.

Also: every built-in scenario goes through every analysis; the report's
interpretive statements follow the computed numbers (no instability claimed
when none was found, joints made worse by the observer disclosed); the HTML
has all text escaped and the JSON is strict.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from html.parser import HTMLParser

import numpy as np
import pytest

from conftest import PAPER_FR, SHORT_SCENARIO_TOML as SHORT, reference_inertia
from dobkit import analysis_commands as analysis_cli
from analysis.experiment import run_experiment
from analysis.report import (AnalysisSettings, experiment_metrics, json_text, render_html, run_analysis,
                                    write_report)
from blocks import builtin_scenarios, load_scenario
from dobkit.cli import main


# Small grids and short runs: every analysis, in seconds.
TINY = AnalysisSettings(mismatch_factors=(0.5, 2.0), boundary_points=5, workspace_points=(2, 13, 1, 2),
                        kp_values=(180.0,), kd_values=(36.0,), observer_values=(30.0,), study_t_final=0.5,
                        design_t_final=0.5, noise_t_final=0.1)

# Every stage, on the smallest grids and runs that still exercise it (for the every-scenario check).
# (The boundary scan keeps its default ends, 0.02x and 50x: the surgical loop without the observer at 0.02x is where
# the root finder stops "without good progress" on an exact equilibrium.)
MINIMAL = AnalysisSettings(mismatch_factors=(1.0,), boundary_points=2, workspace_points=(1, 5, 1, 1),
                           kp_values=(180.0,), kd_values=(36.0,), observer_values=(), study_t_final=0.2,
                           design_t_final=0.2, noise_t_final=0.05)

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


@pytest.mark.parametrize("value", ["-1", "0", "inf", "nan", "fast"])
def test_bad_observer_target_is_refused_while_parsing(tmp_path, value, capsys):
    # refused by the argument parser (exit status 2) before any stage runs or any folder is made
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exc:
        main(["report", "--scenario", "no-such-scenario", "--out", str(out), "--observer-target", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--observer-target" in err and "no built-in scenario" not in err
    assert not out.exists()


def test_report_and_analyze_default_to_their_own_folders(capsys):
    assert (analysis_cli.ANALYSIS_PREFIX, analysis_cli.REPORT_PREFIX) == ("dobkit-analysis", "dobkit-report")
    for command, prefix in (("analyze", "dobkit-analysis"), ("report", "dobkit-report")):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert f"{prefix}-YYYYmmdd-HHMMSS" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("name", builtin_scenarios())
def test_every_builtin_scenario_goes_through_every_analysis(name):
    result = run_analysis(name, MINIMAL)
    _strict(json_text(result))
    for op in result["operating_points"]:          # an equilibrium was found and linearized at every point
        assert len(op["poles_with_dob"]) == 12 and len(op["poles_without_dob"]) == 8
    studies = result["studies"]
    runs = [studies["gains_with_dob"]["runs"][0][0], studies["gains_without_dob"]["runs"][0][0]]
    assert all(r["ok"] for r in runs + studies["observer"]["runs"])
    assert set(result["observer_design"]["simulation"]) == {"scenario gain", "designed"}


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
    assert _strict(json_text(run_analysis(load_scenario(scenario_file), TINY))) == written


class _Structure(HTMLParser):
    """Collects tags and text; HTMLParser reports a stray '<' (e.g. an unescaped '<=') as text."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack, self.text, self.bad = [], [], []

    def handle_starttag(self, tag, attrs):
        if tag not in ("meta", "img", "br"):
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.bad.append(tag)

    def handle_data(self, data):
        if self.stack and self.stack[-1] != "style":
            self.text.append(data)


def test_report_text_is_escaped_and_well_formed(reported):
    path, _ = reported
    page = path.read_text(encoding="utf-8")
    parser = _Structure()
    parser.feed(page)
    parser.close()
    assert parser.bad == [] and parser.stack == []
    text = "".join(parser.text)
    assert "V(t) <= V(0) exp(-2 beta t)" in text and "&lt;=" in page
    # every '<' or '>' of the page source belongs to a tag: removing the tags leaves none
    body = page.split("</style>", 1)[1]
    assert not re.search(r"[<>]", re.sub(r"</?[a-z][a-z0-9]*(\s[^<>]*)?>", "", body))


def test_json_has_no_nonstandard_numbers():
    text = json_text({"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": {"d": float("nan")}})
    assert _strict(text) == {"a": None, "b": [None, None, 1.5], "c": {"d": None}}


@pytest.fixture(scope="module")
def fast_observer(scenario_file):
    """The short scenario with Y = 50 I: no stability boundary in the searched inertia range."""
    s = load_scenario(scenario_file).replace(gains={"observer": 50.0})
    # the default inertia range of the boundary search, a finer scan, everything else minimal
    result = run_analysis(s, replace(MINIMAL, boundary_points=5))
    return s, result, experiment_metrics(run_experiment(s, None, figures=False))


def test_report_claims_no_instability_that_was_not_found(fast_observer):
    s, result, metrics = fast_observer
    with_dob = result["mismatch"]["with_dob"]["boundaries"]
    assert with_dob["boundaries"] == [] and max(with_dob["scan"]["spectral_abscissa"]) < 0
    page = render_html(result, metrics, s, {})
    assert "unstable" not in page and "goes unstable" not in page
    assert "with the observer the held loop stays stable for every nominal inertia from 0.02 to 50" in page
    # and the statements that depend on the scenario are made only where the numbers support them
    assert "zero DC gain" in page                      # stable, and DC gain computed ~0
    slow = result["observer_bandwidth"]["slowest_rad_s"]["min"]
    assert slow < 6.0 and "limits how fast a disturbance is rejected" in page


def test_report_discloses_joints_made_worse_by_the_observer(reported):
    path, out = reported
    page = path.read_text(encoding="utf-8")
    summary = page.split("Summary for the surgical team", 1)[1].split("1. Scenario", 1)[0]
    metrics = _strict((out / "metrics.json").read_text())
    w, wo = metrics["with_dob"]["rms_position_error"], metrics["without_dob"]["rms_position_error"]
    worse = [j for j in range(4) if w[j] > wo[j]]
    assert worse == [0]          # this scenario, like the paper's: joint 1 is worse with the observer
    for j in range(4):
        assert (f"On joint {j + 1} " in summary) == (j in worse)
    assert f"RMS {w[0]:.3g} rad with it against {wo[0]:.3g} rad without" in summary
    # why, from independent numbers: held at q0 without the observer joint 1 rests M^-1 f / Kp off, which is
    # far smaller than what its own disturbance alone would give, (M^-1)_11 f_1 / Kp
    q0 = np.array([0.0, 2.0, 0.24, 0.0])
    q = q0.copy()
    for _ in range(50):
        q = q0 + np.linalg.solve(reference_inertia(q[1]), PAPER_FR) / 180.0
    own = np.linalg.inv(reference_inertia(q0[1]))[0, 0] * PAPER_FR[0] / 180.0
    assert abs(q - q0)[0] < 0.5 * own
    assert f"only {abs(q - q0)[0]:.3g} rad off without the observer" in summary
    assert f"which alone would leave {own:.3g} rad" in summary
    # the error with the observer is called a start-up transient only when it is one: largest in the first half
    # of the run and less than half as large at its end
    peak, final = metrics["with_dob"]["max_abs_position_error"][0], metrics["with_dob"]["final_abs_position_error"][0]
    early = metrics["with_dob"]["time_of_max_abs_position_error"][0] <= 0.5 * metrics["duration_s"]
    assert ("start-up transient" in summary) == (early and final < 0.5 * peak)
