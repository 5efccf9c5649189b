"""What a tuning reports: its objective, its budgets and its counts said alike in every place a reader meets
them (the message, the tuned scenario's description, tune.json, the report).
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
from conftest import SHORT_SCENARIO_TOML

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
