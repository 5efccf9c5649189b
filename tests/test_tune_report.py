"""What a tuning reports: its objective, its budgets and its counts said alike in every place a reader meets
them (the message, the tuned scenario's description, tune.json, the report).
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
from conftest import SHORT_SCENARIO_TOML

from analysis.tune.report import evaluations_text, html_section, write_figures
from analysis.tune.results import PointResult, TuneFigure, TuneHistory, TuneResult
from dobkit.tune_commands import _summary, constraint_lines

NUMBER = r"([0-9.]+(?:e[+-]?\d+)?)"


TUNE_BASE = SHORT_SCENARIO_TOML.replace('name = "short"', 'name = "short-base"')


def _tuning(folder: Path, constraints: str, search: str = "population = 5\nmax_evaluations = 20\n"
            "polish_evaluations = 5\n") -> Path:
    (folder / "base.toml").write_text(TUNE_BASE)
    path = folder / "tune.toml"
    path.write_text('name = "round3"\nscenario = "base.toml"\nobjective = "worst"\n[search]\n"gains.kp" = [20, 2000]\n'
                    f"seed = 3\n{search}[constraints]\n{constraints}\n[monte_carlo]\nruns = 2\nseed = 1\n"
                    '[monte_carlo.distributions]\n"nominal_scale.m1" = {kind = "choice", values = [0.9, 1.1]}\n')
    return path


def test_an_infeasible_tunings_file_stdout_and_result_give_the_same_objective(tmp_path):
    from analysis.tune.results import objective_text
    from analysis.tune.runner import run_tune
    from analysis.tune.spec import load_tuning
    result = run_tune(load_tuning(_tuning(tmp_path, "torque_limit = 1.0")), tmp_path / "out", workers=1,
                      progress=False)
    assert not result.feasible and result.tuned.diverged == 0
    # tune.json keeps the objective; the message (stdout) and the tuned file's description say it alike
    text = objective_text(result.tuned.objective)
    assert text == f"{result.tuned.objective:.4g} mm"
    assert result.tuned.objective == pytest.approx(max(result.tuned.values))
    description = tomllib.loads((tmp_path / "out" / result.scenario_file).read_text())["description"]
    assert description.startswith("INFEASIBLE") and description.endswith(text)
    assert f"is {text} (base gains" in result.message and "not finite" not in description


def test_a_tiny_torque_noise_budget_is_printed_with_significant_digits(tmp_path):
    from analysis.tune.runner import run_tune
    from analysis.tune.spec import TuneError, load_tuning
    with pytest.raises(TuneError) as err:
        run_tune(load_tuning(_tuning(tmp_path, "torque_noise_rms = 1e-9")), tmp_path / "out", workers=1,
                 progress=False)
    text = str(err.value)
    noise = [float(v) for v in re.search(r"torque noise \[([^\]]+)\]", text).group(1).split(", ")]
    budget = re.search(r"against the budget \[([^\]]+)\] N m", text).group(1)
    assert budget == "1e-09, 1e-09, 1e-09, 1e-09"
    joint, factor = re.search(rf"\(joint (\d) {NUMBER} times its budget\)", text).groups()
    # four significant digits each: the printed factor and the printed noise agree to 1e-3
    assert min(noise) > 0 and float(factor) == pytest.approx(noise[int(joint) - 1] / 1e-9, rel=2e-3)
    assert float(factor) == pytest.approx(max(noise) / 1e-9, rel=2e-3)


def _point(objective: float) -> PointResult:
    return PointResult(gains={"gains.kp": 100.0}, objective=objective, worst=objective, mean=objective,
                       values=[objective] * 3, nominal=objective, torque_noise_rms=[1.0, 1.0, 0.01, 0.5],
                       peak_torque=[30.0, 30.0, 5.0, 28.0], spectral_abscissa=-2.0, violations={},
                       feasible=True, diverged=0)


def _tune_result() -> TuneResult:
    """A history counted by hand: 1 base, 6 search, 4 polish, 1 final = 12 evaluations; 5 refused (not
    simulated); of the 7 with a simulation, 4 simulated now, 1 from the log, so 2 repeats."""
    phase = ["base"] + ["search"] * 6 + ["polish"] * 4 + ["final"]
    simulated = [True, True, False, True, False, True, False, True, False, False, True, True]
    objective = [2.0 if s else None for s in simulated]
    history = TuneHistory(phase=phase, objective=objective, feasible=list(simulated), simulated=simulated)
    return TuneResult(name="t", source="t.toml", description="", definition="abc", scenario="paper",
                      objective="worst", metric="rms_tool_error_mm", runs=3, parameters=["gains.kp"],
                      units=["1/s^2"], bounds=[[50.0, 500.0]], limits={"torque_noise_rms": [2.0, 2.0, 0.02, 1.0]},
                      base=_point(2.0), tuned=_point(1.5), feasible=True, message="Tuned gains", history=history,
                      evaluations={"search": 6, "polish": 4, "simulated": 4, "from_log": 1, "linear_only": 5},
                      seconds=1.0, scenario_file="t-tuned.toml")


COUNTS = ("12 evaluations (1 with the base gains, 6 search, 4 polish, 1 final): 5 refused by the linear "
          "constraints without simulating, 7 with a simulation of the set (4 simulated in this run, 1 taken "
          "from the evaluation log of an earlier, stopped run, 2 repeats of gains already simulated)")


def test_evaluation_counts_are_one_sentence_everywhere(tmp_path):
    result = _tune_result()
    assert evaluations_text(result) == COUNTS
    made = write_figures(result, tmp_path / "figures")
    caption = dict(made)["tune_history.png"]
    assert COUNTS in caption
    assert COUNTS in _summary(result, tmp_path)
    # a folder written before the counts had one source: its stored caption is made again from the history
    folder = tmp_path
    stale = TuneFigure(file="tune_history.png", caption="(38 simulated; 59 more refused)")
    result = TuneResult(**{**result.__dict__, "figures": [stale]})
    (folder / "tune.json").write_text(result.to_json(), encoding="utf-8")
    section = re.sub(r"\s+", " ", html_section(folder))
    assert section.count(COUNTS) == 3                   # the paragraph, the caption and the image's alt text
    assert "38 simulated" not in section
    # no second count in other words (the old "36 + 60 evaluations", "simulated now")
    assert "simulated now" not in section and "6 + 4" not in section


def test_tune_output_gives_the_prismatic_joint_newtons():
    lines = "\n".join(constraint_lines(_tune_result()))
    assert "torque noise RMS [N m, N m, N, N m]" in lines
    assert "[N m]:" not in lines
