"""``dobkit analyze`` and ``dobkit report`` end to end: typed results, strict JSON, self-contained HTML, same numbers
again.

The checks are on numbers: attributes of the typed results, values read back
from ``analysis.json`` and ``metrics.json``, and the numbers the page shows next
to their labels (table cells by row label) -- compared with the results or
with independent derivations (docs/model.md, ``conftest.reference_inertia``).
Also: every built-in scenario goes through every analysis; interpretive
statements are made only where the numbers support them; the page escapes all
text (a scenario name with ``<script>`` in it stays text) and the JSON is strict.
"""
from __future__ import annotations

import html
import json
import math
import re
from dataclasses import replace
from html.parser import HTMLParser

import control as ct
import numpy as np
import pytest
from conftest import PAPER_FR, reference_inertia
from conftest import SHORT_SCENARIO_TOML as SHORT

from analysis.linear import gain_design
from analysis.linear.bandwidth import workspace_grid
from analysis.report.build import (
    AnalysisResult,
    AnalysisSettings,
    experiment_metrics,
    json_text,
    render_html,
    run_analysis,
    write_report,
)
from analysis.report.view import worse_with_observer
from analysis.simulation.experiment import run_experiment
from blocks import builtin_scenarios, load_scenario
from dobkit import analysis_commands as analysis_cli
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

# The short scenario's arm is held near q0 with Kp = 180, Kd = 36: its PD roots are the roots of s^2 + 36 s + 180.
Q0 = [0.0, 2.0, 0.24, 0.0]
PD_SLOWEST = 6.0


def _strict(text):
    def bad(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=bad)


class _Page(HTMLParser):
    """Tags, text and tables of a page; HTMLParser reports a stray '<' (e.g. an unescaped '<=') as text."""

    def __init__(self, page: str):
        super().__init__(convert_charrefs=True)
        self.stack, self.text, self.bad = [], [], []
        self.tables, self.paragraphs = [], []
        self._cell = self._para = None
        self.feed(page)
        self.close()

    def handle_starttag(self, tag, attrs):
        if tag in ("meta", "img", "br"):
            return
        self.stack.append(tag)
        if tag == "table":
            self.tables.append({"caption": "", "header": [], "rows": []})
        elif tag == "tr":
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th", "caption"):
            self._cell = []
        elif tag == "p":
            self._para = []

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.bad.append(tag)
        if tag in ("td", "th", "caption"):
            text = "".join(self._cell).strip()
            table = self.tables[-1]
            if tag == "caption":
                table["caption"] = text
            elif tag == "th":
                table["header"].append(text)
            else:
                table["rows"][-1].append(text)
            self._cell = None
        elif tag == "p":
            self.paragraphs.append("".join(self._para))
            self._para = None

    def handle_data(self, data):
        if self.stack and self.stack[-1] != "style":
            self.text.append(data)
        for part in (self._cell, self._para):
            if part is not None:
                part.append(data)

    def rows(self, caption: str | None = None, header: list | None = None) -> list[list[str]]:
        """The body rows of the one table with this caption (start) or this header."""
        found = [t for t in self.tables if (caption is None or t["caption"].startswith(caption))
                 and (header is None or t["header"] == header)]
        assert len(found) == 1, f"{len(found)} tables captioned {caption!r} with header {header!r}"
        return [row for row in found[0]["rows"] if row]

    def table(self, caption: str | None = None, header: list | None = None) -> dict:
        """The same rows by their first cell (the first row of each label)."""
        out = {}
        for row in self.rows(caption, header):
            out.setdefault(row[0], row[1:])
        return out


def _summary(page: str) -> list[str]:
    """The statements of the page's summary for the surgical team (plain text)."""
    block = re.search(r"<div class='summary'>(.*?)</div>", page, flags=re.S).group(1)
    return [html.unescape(li) for li in re.findall(r"<li>(.*?)</li>", block, flags=re.S)]


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)]


def _shown(value, digits: int):
    """What a cell showing ``value`` to ``digits`` significant digits must equal."""
    return pytest.approx(value, rel=0.51 * 10.0 ** (1 - digits))


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
    calls = []
    path = write_report(load_scenario(scenario_file), out, TINY, progress=lambda stage, f: calls.append((stage, f)))
    return path, out, calls


@pytest.fixture(scope="module")
def report_data(reported):
    path, out, _ = reported
    return (_Page(path.read_text(encoding="utf-8")), AnalysisResult.from_json((out / "analysis.json").read_text()),
            _strict((out / "metrics.json").read_text()))


def test_analyze_writes_json_and_figures(analyzed):
    status, out = analyzed
    assert status == 0
    text = (out / "analysis.json").read_text()
    _strict(text)
    result = AnalysisResult.from_json(text)
    op = result.operating_points[0]
    assert op.q0 == pytest.approx(Q0)
    assert len(op.poles_with_dob) == 12 and len(op.poles_without_dob) == 8
    assert all(p.real < 0 for p in op.poles_with_dob + op.poles_without_dob)
    # the PD roots of s^2 + 36 s + 180 are -6 and -30 (twice per joint)
    assert sorted(m.analytic_pole.real for m in op.modes_without_dob) == pytest.approx([-30.0] * 4 + [-6.0] * 4)
    bw = result.observer_bandwidth
    assert len(bw.theta2) == len(bw.eigenvalues) and all(len(row) == 4 for row in bw.eigenvalues)
    assert bw.slowest_rad_s.min == pytest.approx(0.848, abs=0.001)        # docs/model.md, at theta2 = 0
    assert bw.slowest_rad_s.min <= bw.slowest_rad_s.max == pytest.approx(0.930, abs=0.001)
    names = {p.name for p in out.iterdir()}
    for stem in FIGURES:
        assert {f"{stem}.png", f"{stem}.svg"} <= names
        assert (out / f"{stem}.png").stat().st_size > 10_000
    assert sorted(result.figures) == sorted(n for n in names if n != "analysis.json")
    assert "workers" not in _strict(text)["settings"]             # it does not change results


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


def test_report_and_analyze_default_to_their_own_folders(capsys, monkeypatch):
    assert (analysis_cli.ANALYSIS_PREFIX, analysis_cli.REPORT_PREFIX) == ("dobkit-analysis", "dobkit-report")
    # argparse wraps the help to the terminal's width and may break the name at a hyphen ("dobkit-analysis-" /
    # "YYYYmmdd-HHMMSS"): it failed in a terminal of 70 or 100-120 columns. One width, wide enough for the name
    monkeypatch.setenv("COLUMNS", "200")
    for command, prefix in (("analyze", "dobkit-analysis"), ("report", "dobkit-report")):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert f"{prefix}-YYYYmmdd-HHMMSS" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("name", builtin_scenarios())
def test_every_builtin_scenario_goes_through_every_analysis(name, monkeypatch):
    s = load_scenario(name)
    if s.robot.n > 4:
        # the analyses, not the compile (tests/test_compile_estimate.py): a 6- or 7-joint loop's few short runs
        # cost less on the numpy engine than compiling its structures on a cold cache
        import blocks.engines.compiled.engine
        monkeypatch.setattr(blocks.engines.compiled.engine, "AUTO_COMPILE_SECONDS", 0.0)
    n = s.robot.n
    # one value per joint but five along the second: the same small grid for any joint count
    result = run_analysis(s, replace(MINIMAL, workspace_points=(1, 5) + (1,) * (n - 2)))
    _strict(result.to_json())
    for op in result.operating_points:          # an equilibrium was found and linearized at every point
        assert len(op.poles_with_dob) == 3 * n and len(op.poles_without_dob) == 2 * n
    studies = result.studies
    runs = [studies.gains_with_dob.runs[0][0], studies.gains_without_dob.runs[0][0]]
    assert all(r.ok for r in runs + studies.observer.runs)
    assert set(result.observer_design.simulation) == {"scenario gain", "designed"}


def test_report_is_one_self_contained_file(reported):
    path, out, _ = reported
    page = path.read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>")
    # nothing fetched from anywhere: no scripts, stylesheets or remote images; all images inline
    assert not re.search(r"<script|<link|<iframe|src=\"(?!data:)", page)
    assert "http://" not in page and "https://" not in page
    images = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,', page)
    pngs = list((out / "figures").glob("*.png"))
    assert len(images) == len(pngs) >= len(FIGURES) + 5                   # ours and Figures 4-8
    headings = re.findall(r"<h2[^>]*>([^<]*)</h2>", page)
    assert [h.split(".")[0] for h in headings] == ["Summary for the surgical team", "1", "2", "3", "4", "5", "6", "7"]


def test_report_tables_show_the_computed_numbers(report_data):
    page, result, metrics = report_data
    tracking = page.table("Tracking metrics per joint")
    for label, run, key in (("RMS position error, with observer", "with_dob", "rms_position_error"),
                            ("RMS position error, without observer", "without_dob", "rms_position_error"),
                            ("largest position error, with observer", "with_dob", "max_abs_position_error")):
        assert [float(c) for c in tracking[label]] == [_shown(v, 4) for v in metrics[run][key]]
    # the short scenario sags without the observer by M^-1 d / Kp on the prismatic joint (docs/model.md: 31.1 mm)
    assert float(tracking["largest position error, without observer"][2]) == pytest.approx(1.4 / 0.25 / 180, rel=0.05)

    modes = page.table("Eigenvalues of Y M^-1(q) over the workspace")
    for k, (lo, hi) in enumerate(result.observer_bandwidth.ranges_rad_s):
        assert [float(c) for c in modes[f"mode {k + 1}"][:2]] == [_shown(lo, 4), _shown(hi, 4)]
    assert float(modes["mode 4"][0]) == pytest.approx(40.0)                     # 10 / 0.25 (docs/model.md)

    design = result.observer_design
    cert = page.table("Convergence certificate")
    assert [float(c) for c in cert["certificate beta_min (rad/s)"]] == [
        _shown(design.certificate_scenario_gain.beta_min_rad_s, 5),
        _shown(design.certificate_designed.beta_min_rad_s, 5)]
    # the scenario gain Y = 10 I keeps beta > 0 for |theta2'| < 2 Y / ||dM/dtheta2|| = 34.8 rad/s (docs/model.md)
    assert float(cert["largest |theta2'| keeping beta > 0 (rad/s)"][0]) == pytest.approx(34.8, abs=0.05)

    mismatch = page.rows("Poles against inertia mismatch")
    for observer, label in ((True, "with observer"), (False, "without observer")):
        sweep = result.mismatch.loop(observer).sweep
        shown = [row[1:3] for row in mismatch if row[0] == label]
        assert [[float(a), float(alpha)] for a, alpha in shown] == [
            [_shown(a, 4), _shown(alpha, 5)] for a, alpha in zip(sweep.factors, sweep.spectral_abscissa)]

    responses = {tuple(row[:2]): row[2:] for row in page.rows("Per-joint disturbance responses")}
    # 1 N on the prismatic joint without the observer: -1 / (k4 Kp) = -1 / 45 m/N (DC gain column)
    assert float(responses["e, without observer", "Joint 3 (d3)"][1]) == pytest.approx(-1 / 45, rel=1e-3)
    assert float(responses["e, with observer", "Joint 3 (d3)"][1]) == 0.0                    # the observer: zero
    # a high-pass band open at the top reads "above 40" (not "40 to inf")
    band = responses["d - d_hat, with observer", "Joint 3 (d3)"][5]
    assert band.startswith("above ") and float(band.split()[1]) == pytest.approx(40.0)


def test_report_statements_carry_the_computed_numbers(report_data):
    page, result, _ = report_data
    # the stability boundary the search found is quoted in the mismatch reading, to 6 significant digits
    found = result.mismatch.with_dob.boundaries.factors
    assert found
    stability = [p for p in page.paragraphs if p.startswith("Stability with observer:")][0]
    assert [x for x in _numbers(stability) if x not in result.mismatch.with_dob.boundaries.range][-len(found):] == [
        _shown(a, 6) for a in found]
    # the slowest observer mode over the workspace and where it is, in the bandwidth section
    slow = result.observer_bandwidth.slowest_rad_s
    line = [p for p in page.paragraphs if p.startswith("Slowest mode:")][0]
    assert _numbers(line)[:5] == [_shown(slow.min, 4)] + [_shown(v, 4) if v else 0.0 for v in slow.q_at_min]


def test_summary_quotes_the_tool_tip_error_and_the_observer_speed(reported, report_data):
    path, _, _ = reported
    _, result, metrics = report_data
    summary = _summary(path.read_text(encoding="utf-8"))
    w, wo = metrics["with_dob"], metrics["without_dob"]
    assert _numbers(summary[0]) == [_shown(run[key], 3) for key in ("max_tool_position_error_mm",
                                                                    "rms_tool_position_error_mm") for run in (w, wo)]
    slow = result.observer_bandwidth.slowest_rad_s
    speed = [s for s in summary if f"{slow.min:.3g} to {slow.max:.3g} per second" in s][0]
    # slower than the slowest PD root by PD_SLOWEST / slowest mode (the observer limits the rejection speed)
    ratios = [PD_SLOWEST / slow.max, PD_SLOWEST / slow.min]
    assert [x for x in _numbers(speed) if x in (_shown(r, 3) for r in ratios)] == [_shown(r, 3) for r in ratios]


def test_the_summary_for_the_surgical_team_is_in_plain_words(reported):
    path, _, _ = reported
    summary = _summary(path.read_text(encoding="utf-8"))
    notation = (r"s\^2", r"M\^-1", r"d_hat", r"\bpoles?\b", r"DC gain", r"\bmodes?\b", r"Kd s", r"1/s\^2", r"eigen",
                r"\d rad/s\b")
    for line in summary:
        # old: "slowest pole of the PD error dynamics s^2 + Kd s + Kp: 6 rad/s", "(it is M^-1 d / Kp)"
        assert not [w for w in notation if re.search(w, line)], line


def test_an_analysis_not_made_for_the_arm_is_one_line_and_the_rest_is_written(report_data, scenario_file):
    from analysis.report.html import render_html
    _, result, metrics = report_data
    why = "frequency responses at the reference at t = 0: without the observer: no equilibrium found (a test)"
    page = render_html(replace(result, frequency=None, not_done=[why]), metrics, load_scenario(scenario_file), {},
                       ())
    text = html.unescape(re.sub(r"<[^>]+>", " ", page))
    assert text.count(f"Not computed for this arm: {why}") == 2        # the summary and section 6
    assert "Per-joint disturbance responses" not in page and "Gain and noise studies" in page


def test_a_mismatch_factor_without_a_rest_is_a_row_that_says_so(report_data, scenario_file):
    # an arm that sags away from q0 without the observer at some factor has no poles there (old: min() of an
    # empty sequence in the mismatch table, the report lost after minutes of work)
    from analysis.report.html import render_html
    _, result, metrics = report_data
    loop = result.mismatch.without_dob
    sweep = replace(loop.sweep, poles=[[]] + loop.sweep.poles[1:],
                    spectral_abscissa=[1e6] + loop.sweep.spectral_abscissa[1:])
    mismatch = replace(result.mismatch, without_dob=replace(loop, sweep=sweep))
    page = render_html(replace(result, mismatch=mismatch), metrics, load_scenario(scenario_file), {}, ())
    assert "no rest near q0" in page


def test_report_progress_reports_every_stage_done(reported):
    _, _, calls = reported
    stages = list(dict.fromkeys(stage for stage, _ in calls))
    assert {"simulating with observer", "observer bandwidth", "inertia mismatch", "frequency responses",
            "observer gain and noise study", "writing figures and report"} <= set(stages)
    for stage in stages:
        fractions = [f for s, f in calls if s == stage]
        assert fractions == sorted(fractions) and fractions[-1] == 1.0 and 0.0 <= fractions[0]


def test_same_scenario_gives_the_same_numbers(reported, scenario_file):
    _, out, _ = reported
    written = (out / "analysis.json").read_text()
    again = run_analysis(load_scenario(scenario_file), TINY)
    assert replace(AnalysisResult.from_json(written), figures=[]).to_json() == again.to_json()
    # and the file reads back to exactly what was written
    assert AnalysisResult.from_json(written).to_json() == written


def test_report_text_is_escaped_and_well_formed(reported):
    path, _, _ = reported
    page = path.read_text(encoding="utf-8")
    parser = _Page(page)
    assert parser.bad == [] and parser.stack == []
    assert "<=" in "".join(parser.text) and "&lt;=" in page
    # every '<' or '>' of the page source belongs to a tag: removing the tags leaves none
    body = page.split("</style>", 1)[1]
    assert not re.search(r"[<>]", re.sub(r"</?[a-z][a-z0-9]*(\s[^<>]*)?>", "", body))


def test_a_script_in_the_scenario_name_stays_text(fast_observer):
    s, result, metrics = fast_observer
    name = "held <script>alert('x')</script> & co"
    hostile = s.replace(name=name, description='"quoted" <b>bold</b>')
    page = render_html(replace(result, scenario=replace(result.scenario, name=name, toml=hostile.to_toml())),
                       metrics, hostile, {})
    assert "<script" not in page and "<b>bold" not in page
    assert "&lt;script&gt;" in page
    parsed = _Page(page)
    assert parsed.bad == [] and parsed.stack == []
    settings = parsed.table(header=["setting", "value"])
    assert settings["name"] == [name] and settings["description"] == ['"quoted" <b>bold</b>']
    assert f"dobkit analysis report: scenario '{name}'" in "".join(parsed.text)


def test_json_has_no_nonstandard_numbers():
    text = json_text({"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": {"d": float("nan")}})
    assert _strict(text) == {"a": None, "b": [None, None, 1.5], "c": {"d": None}}
    with pytest.raises(TypeError, match="control.*StateSpace.*no JSON form"):
        json_text({"loop": ct.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]])})


def test_an_unlimited_critical_speed_is_null_in_json_and_infinite_when_read_back():
    # M(q) does not depend on theta1: moving joint 1 alone never breaks the condition
    grid, _ = workspace_grid((1, 13, 1, 1))
    crit = gain_design.critical_speed(load_scenario("paper").nominal, 10.0 * np.eye(4), grid, [1.0, 0.0, 0.0, 0.0])
    assert crit.unlimited and crit.speed_factor == math.inf
    data = _strict(crit.to_json())
    assert data["speed_factor"] is None and data["speed_bound"] == [None, 0.0, 0.0, 0.0]
    back = gain_design.CriticalSpeed.from_json(crit.to_json())
    assert back.speed_factor == math.inf and back.speed_bound == [math.inf, 0.0, 0.0, 0.0]


@pytest.fixture(scope="module")
def fast_observer(scenario_file):
    """The short scenario with Y = 50 I: no stability boundary in the searched inertia range."""
    s = load_scenario(scenario_file).replace(gains={"observer": 50.0})
    # the default inertia range of the boundary search, a finer scan, everything else minimal
    result = run_analysis(s, replace(MINIMAL, boundary_points=5))
    return s, result, experiment_metrics(run_experiment(s, None, figures=False))


def test_report_claims_no_instability_that_was_not_found(fast_observer):
    s, result, metrics = fast_observer
    search = result.mismatch.with_dob.boundaries
    assert search.boundaries == [] and max(search.scan.spectral_abscissa) < 0
    page = _Page(render_html(result, metrics, s, {}))
    assert "unstable" not in " ".join(page.paragraphs + page.text)
    stability = [p for p in page.paragraphs if p.startswith("Stability with observer:")][0]
    assert _numbers(stability) == pytest.approx(search.range)          # only the ends of the range searched
    # held at q0 the arm rests on its target with the observer: every DC gain of the tracking error is zero
    assert all(abs(m.dc_gain) <= 1e-6 * m.peak_gain for m in result.frequency.tracking_with_dob.metrics)
    dc = [row[3] for row in page.rows("Per-joint disturbance responses")
          if row[0] == "e, with observer" and row[1].startswith("Joint")]
    assert dc == ["0"] * 4
    # Y = 50 I: the slowest observer mode (50 / the largest inertia seen) is still slower than the PD root at 6 rad/s
    largest = max(np.linalg.eigvalsh(reference_inertia(t)).max() for t in np.linspace(-np.pi, np.pi, 73))
    slow = result.observer_bandwidth.slowest_rad_s
    assert slow.max < PD_SLOWEST and slow.min == pytest.approx(50.0 / largest, rel=1e-9)


def test_report_discloses_joints_made_worse_by_the_observer(reported, report_data, scenario_file):
    _, result, metrics = report_data
    w, wo = metrics["with_dob"]["rms_position_error"], metrics["without_dob"]["rms_position_error"]
    worse = [j for j in range(4) if w[j] > wo[j]]
    assert worse == [0]          # this scenario, like the paper's: joint 1 is worse with the observer
    lines = worse_with_observer(result, metrics, load_scenario(scenario_file))
    assert len(lines) == len(worse)
    numbers = _numbers(lines[0].split(")", 1)[1])          # past "On joint 1 (theta1)"
    assert numbers[:2] == [_shown(w[0], 3), _shown(wo[0], 3)]
    # why, from independent numbers: held at q0 without the observer joint 1 rests M^-1 f / Kp off, which is
    # far smaller than what its own disturbance alone would give, (M^-1)_11 f_1 / Kp
    q0 = np.array(Q0)
    q = q0.copy()
    for _ in range(50):
        q = q0 + np.linalg.solve(reference_inertia(q[1]), PAPER_FR) / 180.0
    own = np.linalg.inv(reference_inertia(q0[1]))[0, 0] * PAPER_FR[0] / 180.0
    assert abs(q - q0)[0] < 0.5 * own
    assert _shown(abs(q - q0)[0], 3) in numbers and _shown(own, 3) in numbers
    # the error with the observer is called a start-up transient only when it is one: largest in the first half
    # of the run and less than half as large at its end
    peak, final = metrics["with_dob"]["max_abs_position_error"][0], metrics["with_dob"]["final_abs_position_error"][0]
    early = metrics["with_dob"]["time_of_max_abs_position_error"][0] <= 0.5 * metrics["duration_s"]
    assert ("start-up transient" in lines[0]) == (early and final < 0.5 * peak)
    assert _shown(peak, 3) in numbers and _shown(final, 3) in numbers


# --- what a reader sees -----------------------------------------------------------------------------------------


def test_a_quick_preview_says_so_and_what_it_leaves_out(reported, report_data, scenario_file):
    _, out, _ = reported
    _, result, metrics = report_data
    s = load_scenario(scenario_file)
    pngs = {p.stem: p for p in (out / "figures").glob("*.png")}
    full = _Page(render_html(result, metrics, s, pngs))
    preview = _Page(render_html(replace(result, settings=replace(result.settings, quick=True)), metrics, s, pngs))
    full_text, preview_text = " ".join(full.text), " ".join(preview.text)
    assert "quick preview" not in full_text and "--quick" not in full_text
    assert f"dobkit analysis report, quick preview: scenario '{s.name}'" in preview_text
    assert f"dobkit report --scenario {s.source} --quick" in preview_text           # the regenerate line
    # what it leaves out, from the settings: the study runs of TINY are 0.5 s where the full report runs 10 s
    assert "length of the study runs: 0.5 s (full: 10 s)" in preview_text
    assert "Kp of the gain study: 180 1/s^2 (full: 45, 90, 180, 360 1/s^2)" in preview_text


def test_every_section_is_in_the_table_of_contents(reported):
    path, _, _ = reported
    page = path.read_text(encoding="utf-8")
    ids = re.findall(r"<h2 id='([a-z]+)'", page)
    links = re.findall(r"<li><a href='#([a-z]+)'>", page)
    assert ids == links and len(ids) == 8


def test_the_summary_repeats_no_paragraph_of_the_page(reported):
    path, _, _ = reported
    page = path.read_text(encoding="utf-8")
    summary = _summary(page)
    paragraphs = [html.unescape(re.sub(r"<[^>]+>", "", p)) for p in re.findall(r"<p>(.*?)</p>", page, flags=re.S)]
    for line in summary:
        assert not any(line in p for p in paragraphs), line


def test_the_scenario_table_is_written_for_people(report_data):
    page, result, _ = report_data
    settings = page.table(header=["setting", "value"])
    values = " ".join(v[0] for v in settings.values())
    assert "[[" not in values and "['" not in values and "array(" not in values
    Y = np.array(AnalysisResult.from_json(result.to_json()).observer_design.base)
    assert settings["Kp (1/s^2)"] == ["180 (every joint)"]
    assert np.allclose(Y, 10 * np.eye(4))                                      # the short scenario: Y = 10 I
    assert settings["observer gain Y (kg m^2/s; kg/s on joint 3)"] == ["10 I"]
    assert settings["disturbance"][0].startswith("paper: the constant step f_r = 1.43, 1.6, 1.4, 1.2")


def test_the_observer_reading_compares_every_gain_tried(report_data):
    page, result, _ = report_data
    obs = result.studies.observer
    ok = [k for k, r in enumerate(obs.runs) if r.ok and obs.labels[k] != "none"]
    peaks = {obs.labels[k]: obs.runs[k].tool_mm.peak_error for k in ok}
    reading = [p for p in page.paragraphs if p.startswith("Reading. Over the")][0]
    largest, smallest = max(peaks, key=peaks.get), min(peaks, key=peaks.get)
    assert f"from {peaks[largest]:.3g} mm ({largest}) down to {peaks[smallest]:.3g} mm ({smallest})" in reading
    assert f"Over the {len(ok)} observer gains tried" in reading


def test_settling_time_has_one_wording_in_the_readme_and_the_report(report_data):
    from test_readme import README

    from analysis.simulation.studies import settling_definition
    page, _, _ = report_data
    definition = settling_definition()
    assert definition in " ".join(README.read_text(encoding="utf-8").split())      # line breaks aside
    assert definition.capitalize() in " ".join(page.paragraphs)


def test_run_analysis_and_analysis_json_have_the_same_keys(analyzed, scenario_file):
    _, out = analyzed
    written = _strict((out / "analysis.json").read_text())
    computed = _strict(run_analysis(load_scenario(scenario_file), MINIMAL).to_json())
    assert set(written) == set(computed) and computed["figures"] == [] and written["figures"]


def test_no_estimation_error_metric_that_only_measures_the_jump_at_t0(report_data):
    # with d_hat(0) = 0 the largest |d - d_hat| of a run is f_r at t = 0 whatever the gain: not reported
    _, _, metrics = report_data
    assert "max_abs_disturbance_error" not in metrics["with_dob"]
    assert "rms_disturbance_error" in metrics["with_dob"]


def test_long_steps_report_how_far_they_have_got(reported):
    # the steps that take longest on the full settings say how far they are, not only that they started and ended
    _, _, calls = reported
    # (TINY's Kp x Kd grid is a single run, so the gain studies have nothing in between)
    for stage in ("inertia mismatch", "observer gain design", "observer gain and noise study",
                  "writing figures and report"):
        inside = [f for s, f in calls if s == stage and 0.0 < f < 1.0]
        assert inside, f"{stage!r} reports nothing between its start and its end"


def test_figures_name_the_joints_as_a_person_reads_them(tmp_path):
    from analysis.simulation.figures import convergence_figure
    from blocks.model.rrpr.joints import RRPR_JOINTS
    h = [0.004, 0.002, 0.001]
    study = {"steps": h, "errors": {f"q[{i}]": [(i + 1) * x for x in h] for i in range(4)},
             "units": {"q[0]": "rad", "q[1]": "rad", "q[2]": "m", "q[3]": "rad"}, "order": 1.0, "scenario": "s",
             "fmi_version": 2, "t_final": 1.0}
    svg = next(p for p in convergence_figure(study, tmp_path, RRPR_JOINTS) if p.suffix == ".svg").read_text()
    for label in RRPR_JOINTS.labels:
        assert label in svg
    assert "q[0] (rad)" not in svg
