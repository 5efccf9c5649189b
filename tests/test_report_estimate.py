"""The report's time: estimated from the scenario's own run before the studies start, refused past a budget."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from analysis.report.estimate import check_report_time, estimate_report, study_runs
from analysis.report.settings import QUICK_SETTINGS, AnalysisSettings
from blocks import load_scenario
from blocks.engines.budget import BudgetError
from dobkit.cli import main


def test_the_estimate_adds_the_stages_at_the_measured_pace():
    s = load_scenario("scope4")                       # t_final 10 s, output step 5 ms
    settings = replace(QUICK_SETTINGS, workers=2)
    stages = {st.stage: st for st in study_runs(s, settings)}
    # quick: Kp x Kd = 2 x 2 runs of 6 s with and without the observer; design check 2 runs of 2 s;
    # observer study: none, v = 3, 30, the scenario's 10, designed = 5 runs of 6 s, and 10 noise runs of 0.3 s
    assert (stages["gain study with observer"].runs, stages["gain study with observer"].seconds_each) == (4, 6.0)
    assert (stages["observer gain design: simulation"].runs,
            stages["observer gain design: simulation"].seconds_each) == (2, 2.0)
    assert stages["observer gain and noise study"].runs == 5
    noise = stages["observer gain and noise study (torque noise)"]
    assert noise.runs == 10 and math.isclose(noise.seconds_each, 0.3)
    est = estimate_report(s, settings, measured_wall_s=2.0, measured_sim_s=20.0)     # 0.1 s per simulated s
    by_hand = 0.1 * (1 * 2.0 + 2 * 6.0 + 2 * 6.0 + 3 * 6.0 + 5 * 0.3)       # ceil(runs / 2 workers) x length
    assert math.isclose(est.seconds, by_hand) and est.runs == 25
    assert math.isclose(est.simulated_s, 2 * 2.0 + 4 * 6.0 * 2 + 5 * 6.0 + 10 * 0.3)
    full = estimate_report(s, replace(AnalysisSettings(), workers=2), 2.0, 20.0)
    assert full.seconds > est.seconds


def test_the_budget_is_held_at_both_sides():
    s = load_scenario("scope4")
    est = estimate_report(s, replace(QUICK_SETTINGS, workers=1), 1.0, 10.0)
    check_report_time(est, None, 5.0, "report")                       # no budget: no limit
    check_report_time(est, 5.0 + est.seconds, 5.0, "report")           # exactly the budget: allowed
    with pytest.raises(BudgetError, match=r"over the wall-time budget of .* --max-seconds or DOBKIT_MAX_SECONDS"):
        check_report_time(est, 5.0 + est.seconds - 0.01, 5.0, "report")


def test_a_report_past_its_budget_is_refused_before_the_studies(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--quick", "--scenario", "scope4", "--out", str(out), "--max-seconds", "0.001"]) == 2
    err = capsys.readouterr().err
    assert "estimated time of the studies: about" in err
    assert "error: report of scenario 'scope4': the studies need about" in err and "simulation.t_final" in err
    assert not out.exists() or not any(out.iterdir())


def test_no_progress_prints_no_stage_lines(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--quick", "--scenario", "scope4", "--out", str(out), "--max-seconds", "0.001",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # old: "simulating with observer: done, took ..." (report had no --no-progress; tune printed stage lines)
    assert len(err) == 1 and err[0].startswith("dobkit report: error: report of scenario 'scope4'"), err
