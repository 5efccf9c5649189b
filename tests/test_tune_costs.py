"""What each constraint of a tuning costs (analysis.tune.costs, ``dobkit tune --constraint-costs``).

The small problem of ``test_tune`` (one gain, Kp on every joint, Kd 36, three runs): the worst RMS tool-tip error
falls as Kp rises, and the torque-noise budget is the noise of Kp = 400, so the tuned Kp sits at the budget's edge.
Three constraints are costed:

- the torque-noise budget binds: without it the search goes past Kp = 400, to a lower error, until the default
  damping ratio 0.7 stops it (kd / (2 sqrt(kp)) = 0.7 at Kp = (36 / 1.4)^2 = 661);
- the damping ratio does not bind: every Kp that breaks it (above 661) breaks the noise budget too;
- an observer bandwidth ratio of at least 0.01 does not bind, and no Kp within the bounds breaks it, so the search
  without it asks for exactly the same candidates (none simulated again).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_tune import KP_EDGE, NOISE, _budget_at, load_scenario_text, write_problem

from analysis.tune.costs import COSTED, costed_constraints, search_count, without
from analysis.tune.evaluate import Evaluator, time_estimate
from analysis.tune.report import html_section
from analysis.tune.runner import RESULT_NAME, run_tune
from analysis.tune.spec import load_tuning
from blocks import inertia
from blocks.figure2.batch import simulate_batch
from dobkit.cli import main
from dobkit.tune_commands import cost_lines

RATIO = 0.01
CONSTRAINTS = {"torque_noise_rms": _budget_at(KP_EDGE), "stability_margin": 0.5, "min_observer_bandwidth_ratio": RATIO,
               "sensor_noise": f"{{q_std = {NOISE['q_std']}, dq_std = {NOISE['dq_std']}, sample_period = 0.001}}"}
KP_DAMPED = (36.0 / (2 * 0.7)) ** 2          # the largest Kp with kd = 36 that keeps the damping ratio >= 0.7


@pytest.fixture(scope="module")
def costed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("costs")
    path = write_problem(folder, constraints=CONSTRAINTS)
    result = run_tune(load_tuning(path), folder / "out", workers=1, progress=False, constraint_costs=True)
    return path, folder / "out", result


def _by_key(result) -> dict:
    return {c.constraint: c for c in result.constraint_costs}


def test_each_active_constraint_is_searched_without_in_turn(costed):
    path, _, result = costed
    assert [c.constraint for c in result.constraint_costs] == \
        ["min_damping_ratio", "min_observer_bandwidth_ratio", "torque_noise_rms"]
    assert costed_constraints(load_tuning(path).limits) == [c.constraint for c in result.constraint_costs]
    assert result.feasible and KP_EDGE * 0.97 <= result.tuned.gains["gains.kp"] <= KP_EDGE
    # every cost is measured against the best evaluation that meets every constraint: the tuned gains
    assert {c.reference for c in result.constraint_costs} == {result.tuned.objective}


def test_a_constraint_no_candidate_breaks_costs_exactly_nothing_and_the_search_repeats_itself(costed):
    path, _, result = costed
    ratio = _by_key(result)["min_observer_bandwidth_ratio"]
    assert ratio.cost == 0.0 and not ratio.binds
    assert ratio.simulated == 0                          # the same candidates: all of them already in the log
    assert ratio.objective == result.tuned.objective
    # independently: the slowest mode of Y M^-1 along the path over sqrt(Kp) stays above 0.01 for every Kp
    spec = load_tuning(path)
    M = inertia(spec.configurations, spec.base.nominal)
    slowest = min(float(np.linalg.eigvals(10.0 * np.linalg.inv(m)).real.min()) for m in M)
    assert slowest / math.sqrt(2000.0) > RATIO
    assert ratio.margin == pytest.approx(slowest / math.sqrt(result.tuned.gains["gains.kp"]) - RATIO, rel=1e-9)


def test_a_constraint_that_does_not_bind_at_the_optimum_costs_nothing(costed):
    _, _, result = costed
    damping = _by_key(result)["min_damping_ratio"]
    kp = result.tuned.gains["gains.kp"]
    assert damping.margin == pytest.approx(36.0 / (2 * math.sqrt(kp)) - 0.7, rel=1e-9) and damping.margin > 0
    assert damping.cost == 0.0 and not damping.binds


def test_the_binding_noise_budget_costs_the_error_the_search_reaches_without_it(costed):
    path, _, result = costed
    noise = _by_key(result)["torque_noise_rms"]
    assert noise.binds and noise.cost > 0
    assert noise.cost == pytest.approx(result.tuned.objective - noise.objective, rel=1e-12)
    assert abs(noise.margin) < 0.05                   # the tuned gains sit at the budget's edge
    kp = noise.gains["gains.kp"]
    # past the budget's edge, up to the damping's: the only constraint it breaks is the one dropped
    assert KP_EDGE < kp <= KP_DAMPED * (1 + 1e-9) and noise.margin_there < 0
    # its objective, simulated here without the tuner, and its torque noise from the linear model
    spec = load_tuning(path)
    base = load_scenario_text((path.parent / "base.toml").read_text())
    worst = float(simulate_batch(base, [r | noise.gains for r in spec.records], metrics=[spec.metric])
                  .metrics[spec.metric].max())
    assert worst == pytest.approx(noise.objective, rel=1e-6) and worst < result.tuned.objective
    assert noise.margin_there == pytest.approx(float(np.min(1 - np.array(_budget_at(kp)) / _budget_at(KP_EDGE))),
                                               rel=1e-6)


def test_the_costs_are_in_tune_json_the_summary_and_the_report(costed):
    _, out, result = costed
    saved = json.loads((out / RESULT_NAME).read_text())
    assert [c["constraint"] for c in saved["constraint_costs"]] == [c.constraint for c in result.constraint_costs]
    assert saved["constraint_costs"][2]["cost"] == pytest.approx(result.constraint_costs[2].cost)
    text = "\n".join(cost_lines(result))
    assert "torque noise: margin" in text and "binds: without it" in text
    assert "damping ratio: margin" in text and "does not bind: costs 0 mm" in text
    page = html_section(out)
    assert "What each constraint costs" in page and "torque-noise budget" in page and "best without it" in page


def test_running_it_again_replays_every_search_from_the_log(costed):
    path, out, result = costed
    again = run_tune(load_tuning(path), out, workers=1, progress=False, figures=False, constraint_costs=True)
    assert again.evaluations["simulated"] == 0 and all(c.simulated == 0 for c in again.constraint_costs)
    assert [(c.constraint, c.cost, c.objective) for c in again.constraint_costs] == \
        [(c.constraint, c.cost, c.objective) for c in result.constraint_costs]


def test_the_time_estimate_counts_one_search_more_per_constraint(costed, tmp_path, capsys):
    path, _, _ = costed
    spec = load_tuning(path)
    measured = Evaluator(spec).evaluate([spec.gains_of_base()], "base", force=True)[0]
    assert search_count(spec) == 1 and search_count(spec, compare_unconstrained=True) == 2
    assert search_count(spec, constraint_costs=True) == 1 + 3
    assert time_estimate(spec, measured, search_count(spec, constraint_costs=True)) == \
        pytest.approx(4 * spec.max_evaluations * measured.seconds, rel=1e-12)
    code = main(["tune", str(path), "--out", str(tmp_path / "check"), "--check", "--constraint-costs"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert f"for 4 searches of at most {spec.max_evaluations} evaluations each" in text
    assert "then 3 more searches, one without each of: damping ratio, observer bandwidth ratio, torque noise" in text


def test_dropping_a_constraint_that_has_no_cost_is_refused_by_name(costed):
    path, _, _ = costed
    with pytest.raises(ValueError, match=r"'stability_margin' has no cost to measure; allowed: min_damping_ratio"):
        without(load_tuning(path).limits, "stability_margin")
    assert set(COSTED) >= set(costed_constraints(load_tuning(path).limits))


def test_the_sampled_margin_of_a_controller_binds_where_a_larger_observer_gain_would_lower_the_error(tmp_path):
    """test_tune_sampled's problem: Y alone, 100 Hz Euler controller, the margin 0.2 allows Y <= 40 (closed form
    Ts lambda_max(Y M^-1) = 0.01 Y / 0.25 against the limit 2).  The search without the margin simulates the
    larger gains its own search refused, and the margin there is the closed form's."""
    from test_tune_sampled import EDGE, _spec
    spec = _spec(tmp_path)
    result = run_tune(spec, tmp_path / "out", workers=1, progress=False, figures=False, constraint_costs=True)
    costs = _by_key(result)
    assert list(costs) == ["min_damping_ratio", "sampled_margin"]
    sampled = costs["sampled_margin"]
    assert result.feasible and 0.95 * EDGE <= result.tuned.gains["gains.observer"] <= EDGE
    assert sampled.binds and sampled.cost > 0 and sampled.simulated > 0
    y = sampled.gains["gains.observer"]
    assert y > EDGE and sampled.margin_there == pytest.approx(1 - 0.01 * y / 0.25 / 2 - 0.2, abs=1e-6)
    assert sampled.cost == pytest.approx(result.tuned.objective - sampled.objective, rel=1e-12)
    # Kp and Kd are not searched: the damping ratio is the paper's 1.342 for every candidate, never broken
    damping = costs["min_damping_ratio"]
    assert damping.cost == 0.0 and not damping.binds and damping.simulated == 0
    assert damping.margin == pytest.approx(36 / (2 * math.sqrt(180)) - 0.7, rel=1e-9)


def test_the_time_bound_scales_the_estimate_by_the_high_bounds_substeps_and_never_falls_below_it():
    """An evaluation's cost grows with its RK4 steps: the bound is the estimate times corner / measured substeps."""
    from types import SimpleNamespace

    from analysis.tune.evaluate import time_bound, time_estimate

    spec = SimpleNamespace(max_evaluations=48)
    measured = SimpleNamespace(seconds=0.5, substeps=2)
    assert time_estimate(spec, measured, 3) == 3 * 48 * 0.5
    assert time_bound(spec, measured, 3, 16) == 3 * 48 * 0.5 * 8        # gains at the high bounds: 8x the steps
    assert time_bound(spec, measured, 3, 2) == time_estimate(spec, measured, 3)
    assert time_bound(spec, measured, 3, 1) == time_estimate(spec, measured, 3)   # never below the estimate
