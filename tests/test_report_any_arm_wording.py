"""Report wording and early refusals of ``dobkit analyze`` / ``report`` (issue "Any arm, every command", item 10).

* A -3 dB band open at the top reads "above 2.639", not "2.639 to inf".
* A Table-3 table is in one notation throughout (not 1.611e-04 beside 0.000233).
* A histogram of picometre lengths is labelled in pm, not "[1e-12 m]".
* A used ``--out`` or a missing URDF is refused before pinocchio and python-control are imported.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.report.view.frequency import _band
from analysis.report.view.simulation import _joint_rows, _table_3_layout
from analysis.sweep.summary import _display_scale
from blocks.model.rrpr.joints import RRPR_JOINTS

ROOT = Path(__file__).resolve().parents[1]


def test_an_open_band_reads_in_words():
    assert _band(2.639, None) == "above 2.639"
    assert _band(0.0, 3.2) == "below 3.2"
    assert _band(2.1, 7.5) == "2.1 to 7.5"
    assert "inf" not in _band(0.0, None)


def _cells(table) -> list[str]:
    return [cell.text for row in table.rows for cell in row[1:] if cell.numeric]


def test_table_3_is_in_one_notation():
    # the numbers: joint 1 needs scientific notation (6.3e-05), joint 4 alone would not (0.000233)
    numbers = [("RMS position error, with observer", [1.611e-4, 2.0e-3, 1.2e-4, 2.33e-4]),
               ("RMS position error, without observer", [6.32e-5, 3.1e-2, 2.5e-3, 4.1e-3]),
               ("largest position error, with observer", [4.0e-4, 5.0e-3, 3.0e-4, 6.0e-4]),
               ("largest position error, without observer", [2.0e-3, 6.0e-2, 3.1e-2, 8.0e-3])]
    for table in (_table_3_layout(numbers, RRPR_JOINTS), _joint_rows(numbers, RRPR_JOINTS)):
        cells = _cells(table)
        assert len(cells) == 16
        assert all("e" in c for c in cells), cells          # old: '1.611e-04' beside '0.000233'
        back = sorted(float(c) for c in cells)
        np.testing.assert_allclose(back, sorted(v for _, values in numbers for v in values), rtol=1e-3)


def test_tiny_lengths_are_labelled_in_a_unit_not_a_power_of_ten():
    # old: "[1e-12 m]" on the axis; now mm, as the tables give lengths, and the ticks carry their own digits
    for unit, values in (("m", np.array([2.0e-12, 7.5e-12])), ("m", np.array([3e-9])), ("mm", np.array([4e-10]))):
        factor, shown = _display_scale(unit, values)
        assert shown == "mm" and "e" not in shown
        np.testing.assert_allclose(values / factor, values * (1e3 if unit == "m" else 1.0))
    assert _display_scale("m", np.array([0.02]))[1] == "mm"
    assert _display_scale("m", np.array([2e-6]))[1] == "µm"
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from analysis.sweep.summary import _histogram
    fig, ax = plt.subplots()
    _histogram(ax, np.array([2.0e-12, 3.0e-12, 7.5e-12, 5e-12]), "m", "final error")
    fig.canvas.draw()
    assert ax.get_xlabel().endswith("[mm]"), ax.get_xlabel()
    ticks = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert ticks and all(float(t.replace("\u2212", "-")) < 1e-8 for t in ticks if t != "0"), ticks
    plt.close(fig)


def _run(args: list[str]) -> dict:
    """``dobkit ARGS`` in a fresh interpreter: its exit status, error line and whether heavy modules came in."""
    code = ("import sys, json\nfrom dobkit.cli import main\nrc = main(sys.argv[1:])\n"
            "print(json.dumps({'rc': rc, 'heavy': [m for m in ('pinocchio', 'control', 'matplotlib') "
            "if m in sys.modules]}))")
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, timeout=120)
    out = json.loads(done.stdout.strip().splitlines()[-1])
    out["stderr"] = done.stderr.strip()
    return out


def test_a_used_out_folder_is_refused_before_the_arm_is_read(tmp_path):
    used = tmp_path / "used"
    used.mkdir()
    (used / "keep.txt").write_text("x")
    for command in ("analyze", "report"):
        got = _run([command, "--quick", "--scenario", "scope4", "--out", str(used)])
        assert got["rc"] == 2 and got["stderr"].endswith("exists and is not empty; choose a new --out"), got
        assert got["heavy"] == [], got            # old: refused after pinocchio and python-control were imported
    assert [p.name for p in used.iterdir()] == ["keep.txt"]


def test_a_missing_urdf_is_refused_before_pinocchio(tmp_path):
    text = (ROOT / "blocks" / "scenarios" / "scope4.toml").read_text().replace('"example:scope4"', '"nothere.urdf"')
    path = tmp_path / "missing.toml"
    path.write_text(text)
    got = _run(["analyze", "--quick", "--scenario", str(path), "--out", str(tmp_path / "out")])
    assert got["rc"] == 2 and "nothere.urdf' does not exist (or is not a file)" in got["stderr"], got
    assert "pinocchio" not in got["heavy"], got
    assert not (tmp_path / "out").exists()


def test_tool_path_keys_are_documented_and_explained_by_the_key_checker(tmp_path):
    import dataclasses
    import re

    import pytest

    from blocks import load_scenario
    from blocks.scenarios.scenario import _SECTIONS, ScenarioError
    from blocks.scenarios.tool_path import ToolPath

    allowed = [k for k in _SECTIONS["trajectory"].checks_for("tool_path") if k != "kind"]
    doc = (ROOT / "docs" / "tool-path.md").read_text()
    rows = dict(re.findall(r"^\| `(\w+)` \|.*\| ([^|]+) \|$", doc, flags=re.M))
    assert set(rows) - {"kind"} == set(allowed)
    defaults = {f.name: f.default for f in dataclasses.fields(ToolPath)}
    for key in allowed:
        if rows[key].strip() != "required":
            assert float(rows[key]) == defaults[key], key
    text = (ROOT / "blocks" / "scenarios" / "scope4-path.toml").read_text().replace(
        "sample_period = 0.05 ", "sample_periodd = 0.05 ").replace('"example:scope4"',
                                                                   f'"{ROOT}/blocks/model/urdf/data/scope4.urdf"')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    message = str(err.value)
    assert "trajectory.sample_periodd" in message
    for key in allowed:                       # old: only the names ("waypoints, duration, sample_period")
        assert re.search(rf"\b{key} \(.+?\)", message), key
    assert "(m, in the arm's base frame)" in message and "(s, > 0" in message


def test_a_scenario_called_the_paper_scenario_has_its_path():
    from blocks import load_scenario
    from blocks.scenarios.scenario import builtin_scenarios

    paper = load_scenario("paper")
    for name in builtin_scenarios():
        s = load_scenario(name)
        if "paper scenario" in s.data.get("description", "").lower() and name != "paper":
            assert s.data["trajectory"] == paper.data["trajectory"], name
    digital = load_scenario("paper-digital")
    assert digital.data["trajectory"] != paper.data["trajectory"]
    # its description says which path it takes, and that path is the one it has: straight, at x = 0.42 m
    assert "default laceration path (straight, 8 cm at x = 0.42 m)" in digital.data["description"]
    start, end = digital.data["trajectory"]["start"], digital.data["trajectory"]["end"]
    assert start[0] == end[0] == 0.42 and abs(end[1] - start[1]) == pytest.approx(0.08)
    assert digital.data["trajectory"]["bulge"] == 0


def test_the_sampled_check_says_it_is_conservative_on_a_path():
    from blocks import load_scenario
    from blocks.figure2.digital_loop import check_observer_rate
    from blocks.scenarios.scenario import ScenarioError

    s = load_scenario("scope4-digital").replace(gains={"observer_bandwidth": 2500.0})   # Euler at 1 kHz: < 2000
    with pytest.raises(ScenarioError) as err:
        check_observer_rate(s)
    message = str(err.value)
    assert "takes the worst one" in message and "conservative" in message and "\n" not in message
