"""Constraints engineers use on tuned gains: the error dynamics' damping ratio (default 0.7) or overshoot, the
observer bandwidth against the tracking bandwidth, each reported with its margin, and what the damping costs."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.signal
from test_tune import KP_EDGE, NOISE, _budget_at, load_scenario_text, write_problem

from analysis.tune.evaluate import Evaluator
from analysis.tune.report import html_section
from analysis.tune.runner import RESULT_NAME, run_tune
from analysis.tune.spec import DEFAULT_MIN_DAMPING, TuneError, damping_for_overshoot, damping_ratios, load_tuning, overshoots
from blocks import inertia, load_scenario
from blocks.figure2.batch import simulate_batch
from dobkit.cli import main

KP_KD = {'"gains.kp"': [20, 2000], '"gains.kd"': [2, 80], "seed": 3, "population": 6, "max_evaluations": 60,
         "polish_evaluations": 24}


def _constraints(**extra) -> dict:
    """The small problem's [constraints] table with more keys."""
    return {"torque_noise_rms": _budget_at(KP_EDGE), "stability_margin": 0.5,
            "sensor_noise": f"{{q_std = {NOISE['q_std']}, dq_std = {NOISE['dq_std']}, sample_period = 0.001}}"} | extra


# --------------------------------------------------------------------------------------------
# The formulas, against textbook values and a simulated step
# --------------------------------------------------------------------------------------------
def test_damping_ratio_of_the_paper_gains_is_the_papers():
    # paper-notes: s^2 + 36 s + 180 = (s + 6)(s + 30), zeta = 1.342; the tuned Kp 736, Kd 20.6: 0.38
    assert damping_ratios(180.0, 36.0) == pytest.approx([36 / (2 * math.sqrt(180))] * 4, rel=1e-12)
    assert damping_ratios(180.0, 36.0)[0] == pytest.approx(1.342, abs=5e-4)
    assert damping_ratios(736.0, 20.6)[0] == pytest.approx(0.3797, abs=5e-4)
    assert damping_ratios([100.0, 400.0, 100.0, 400.0], [14.0, 28.0, 20.0, 8.0]).tolist() == \
        pytest.approx([0.7, 0.7, 1.0, 0.2])


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7, 0.9])
def test_overshoot_equals_that_of_a_simulated_step_of_the_error_dynamics(zeta):
    wn = 20.0
    t, y = scipy.signal.step(([wn ** 2], [1.0, 2 * zeta * wn, wn ** 2]), T=np.linspace(0, 3, 60001))
    assert overshoots([zeta])[0] == pytest.approx(y.max() - 1.0, abs=1e-5)
    assert damping_for_overshoot(float(y.max() - 1.0)) == pytest.approx(zeta, abs=1e-4)
    assert overshoots([1.0, 1.5]).tolist() == [0.0, 0.0]
    assert overshoots([DEFAULT_MIN_DAMPING])[0] == pytest.approx(0.0460, abs=1e-4)      # the textbook 4.6 %


# --------------------------------------------------------------------------------------------
# The tuning file
# --------------------------------------------------------------------------------------------
def test_the_damping_constraint_is_on_by_default_and_can_be_stated_as_overshoot_or_switched_off(tmp_path):
    spec = load_tuning(write_problem(tmp_path / "a", search=KP_KD))
    assert (spec.limits.min_damping_ratio, spec.limits.damping_from) == (0.7, "default")
    spec = load_tuning(write_problem(tmp_path / "b", search=KP_KD, constraints=_constraints(max_overshoot=0.1)))
    assert (spec.limits.min_damping_ratio, spec.limits.max_overshoot, spec.limits.damping_from) == \
        (None, 0.1, "overshoot")
    spec = load_tuning(write_problem(tmp_path / "c", search=KP_KD, constraints=_constraints(min_damping_ratio=0)))
    assert (spec.limits.min_damping_ratio, spec.limits.damping_from) == (None, "off")


@pytest.mark.parametrize("extra, words", [
    ({"min_damping_ratio": -0.5}, ["'constraints.min_damping_ratio'", "-0.5", "from 0"]),
    ({"max_overshoot": 5}, ["'constraints.max_overshoot'", "5", "between 0 and 1"]),
    ({"min_damping_ratio": 0.8, "max_overshoot": 0.05}, ["min_damping_ratio", "max_overshoot", "one of them"]),
    ({"min_observer_bandwidth_ratio": 0}, ["'constraints.min_observer_bandwidth_ratio'", "a number > 0"]),
])
def test_bad_constraint_values_are_refused_naming_the_key(tmp_path, extra, words):
    with pytest.raises(TuneError) as err:
        load_tuning(write_problem(tmp_path, search=KP_KD, constraints=_constraints(**extra)))
    assert all(w in str(err.value) for w in words), str(err.value)


def test_unreachable_damping_is_refused_before_anything_is_simulated(tmp_path):
    # kd at most 10 and kp at least 100: zeta <= 10 / (2 * 10) = 0.5 < 0.7 everywhere in the bounds
    search = dict(KP_KD, **{'"gains.kp"': [100, 2000], '"gains.kd"': [2, 10]})
    with pytest.raises(TuneError, match=r"cannot be met.*min_damping_ratio.*damping ratios .* not all >= 0.7"):
        run_tune(load_tuning(write_problem(tmp_path, search=search)), tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out").exists()


def test_observer_bandwidth_ratio_uses_the_slowest_observer_mode(tmp_path):
    """paper-notes: for Y = 10 I the slowest mode of Y M^-1(q) is 0.848-0.930 rad/s over theta2; the tracking
    bandwidth of Kp = 180 is sqrt(180) rad/s."""
    spec = load_tuning(write_problem(tmp_path, search=KP_KD, scenario='"paper"'))
    zeta, ratio, _ = Evaluator(spec).design({"gains.kp": 180.0, "gains.kd": 36.0})
    assert zeta.tolist() == pytest.approx([1.3416] * 4, abs=1e-4)
    slowest = ratio * math.sqrt(180.0)
    assert 0.848 - 1e-3 <= slowest <= 0.930 + 1e-3
    # and from the nominal inertia along the path, computed here
    M = inertia(spec.configurations, load_scenario("paper").nominal)
    assert slowest == pytest.approx(min(np.linalg.eigvalsh(10.0 * np.linalg.inv(m)).min() for m in M), rel=1e-9)


# --------------------------------------------------------------------------------------------
# A tuning with the default constraint: damped gains, margins and the cost
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    """Kp and Kd of the small problem tuned with the default damping constraint and without it."""
    folder = tmp_path_factory.mktemp("damped")
    damped = run_tune(load_tuning(write_problem(folder / "a", search=KP_KD)), folder / "a" / "out", workers=1,
                      progress=False)
    free = run_tune(load_tuning(write_problem(folder / "b", search=KP_KD, constraints=_constraints(min_damping_ratio=0))),
                    folder / "b" / "out", workers=1, progress=False, figures=False)
    return folder, damped, free


def test_compare_unconstrained_runs_the_same_search_without_the_damping_constraint(tuned, tmp_path):
    folder, damped, free = tuned
    compared = run_tune(load_tuning(write_problem(tmp_path, search=KP_KD)), tmp_path / "out", workers=1,
                        progress=False, figures=False, compare_unconstrained=True)
    assert compared.tuned.gains == damped.tuned.gains                      # the constrained answer is unchanged
    # the search without the constraint, run apart with min_damping_ratio = 0, gave the same answer
    assert compared.unconstrained_from == "search"
    assert compared.unconstrained.gains == free.tuned.gains
    assert compared.unconstrained.objective == pytest.approx(free.tuned.objective, rel=1e-9)
    assert compared.damping_cost == pytest.approx(damped.tuned.objective - free.tuned.objective, rel=1e-9)
    assert compared.damping_cost >= damped.damping_cost                    # the log's estimate is a lower bound
    assert compared.unconstrained.violations["min_damping_ratio"] > 0
    assert compared.evaluations["unconstrained_simulated"] > 0


def test_tuned_gains_meet_the_default_damping_and_report_it(tuned):
    folder, damped, free = tuned
    kp, kd = damped.tuned.gains["gains.kp"], damped.tuned.gains["gains.kd"]
    zeta = kd / (2 * math.sqrt(kp))
    assert damped.feasible and zeta >= 0.7
    assert damped.tuned.damping_ratio == pytest.approx([zeta] * 4, rel=1e-12)
    assert damped.tuned.margins["min_damping_ratio"] == pytest.approx(zeta - 0.7, rel=1e-9)
    budget = np.array(damped.limits["torque_noise_rms"])
    assert damped.tuned.margins["torque_noise_rms"] == pytest.approx(
        float(np.min(1 - np.array(damped.tuned.torque_noise_rms) / budget)), rel=1e-9)
    assert damped.tuned.margins["stability_margin"] == pytest.approx(-damped.tuned.spectral_abscissa - 0.5)
    # without the constraint the same search settles on less damped gains, with a smaller error
    free_zeta = free.tuned.gains["gains.kd"] / (2 * math.sqrt(free.tuned.gains["gains.kp"]))
    assert free.feasible and free_zeta < 0.7 and free.tuned.objective < damped.tuned.objective
    assert free.unconstrained is None and free.damping_cost is None


def test_the_damping_cost_is_measured_against_the_best_evaluation_without_it(tuned):
    folder, damped, free = tuned
    other = damped.unconstrained
    assert other is not None and min(other.damping_ratio) < 0.7 and damped.unconstrained_from == "evaluations"
    assert damped.damping_cost == pytest.approx(damped.tuned.objective - other.objective, rel=1e-12)
    assert damped.damping_cost > 0
    # the unconstrained point's objective, simulated here without the tuner
    spec = load_tuning(folder / "a" / "tune.toml")
    base = load_scenario_text((folder / "a" / "base.toml").read_text())
    result = simulate_batch(base, [r | other.gains for r in spec.records], metrics=[spec.metric])
    assert float(result.metrics[spec.metric].max()) == pytest.approx(other.objective, rel=1e-6)
    saved = json.loads((folder / "a" / "out" / RESULT_NAME).read_text())
    assert saved["damping_cost"] == pytest.approx(damped.damping_cost)
    assert saved["tuned"]["margins"]["min_damping_ratio"] == pytest.approx(damped.tuned.margins["min_damping_ratio"])
    page = html_section(folder / "a" / "out")
    assert "damping ratio of the error dynamics" in page and "margin of the tuned gains" in page
    assert "the constraint costs" in page and f"{damped.tuned.damping_ratio[0]:.3g}" in page


# --------------------------------------------------------------------------------------------
# The built-in paper-tune on a small budget, through the command line
# --------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_paper_tune_with_default_constraints_returns_damped_gains(tmp_path, capsys):
    out = tmp_path / "paper-tune"
    code = main(["tune", "paper-tune", "--out", str(out), "--max-evaluations", "84", "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0, text
    result = json.loads((out / RESULT_NAME).read_text())
    gains = result["tuned"]["gains"]
    zeta = gains.get("gains.kd", 36.0) / (2 * math.sqrt(gains.get("gains.kp", 180.0)))
    assert zeta >= 0.7 and min(result["tuned"]["damping_ratio"]) >= 0.7
    assert "damping ratio of the error dynamics: tuned" in text and "at least 0.7 (the default)" in text
    assert "margins of the tuned gains:" in text


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_damping_margin_is_that_of_the_least_damped_joint(tmp_path):
    """ev-damping-max.  The error dynamics of joint i are s^2 + kd_i s + kp_i: zeta_i = kd_i / (2 sqrt(kp_i)).
    The constraint is on every joint, so its margin is min zeta_i - zeta_min (here the stiffest joint's)."""
    from test_tune import write_problem

    from analysis.tune.evaluate import Evaluation, Evaluator
    from analysis.tune.spec import load_tuning

    search = {'"gains.kp"': [20, 2000], '"gains.kd"': [2, 80], "seed": 3, "population": 6, "max_evaluations": 60}
    spec = load_tuning(write_problem(tmp_path, search=search))
    limit = spec.limits.min_damping_ratio
    assert limit is not None                                   # the default constraint
    kp, kd = np.array([100.0, 150.0, 200.0, 250.0]), np.full(4, 20.0)
    zeta = kd / (2.0 * np.sqrt(kp))                            # 1.0, 0.816, 0.707, 0.632
    ev = Evaluation(gains={"gains.kp": kp, "gains.kd": kd}, torque_noise_rms=np.zeros(4), spectral_abscissa=-1.0,
                    damping_ratio=zeta)
    assert Evaluator(spec).margins(ev)["min_damping_ratio"] == pytest.approx(1.0 / np.sqrt(10.0) * 2 - limit,
                                                                             rel=1e-12)


def test_the_tune_score_of_an_infeasible_candidate_is_worse_than_every_feasible_one(tmp_path):
    """ev-energy-total.  The module's rule: an infeasible candidate scores INFEASIBLE (1 + total violation), above
    every feasible objective however small its violation.  A simulated candidate with errors of 1-2 mm that
    misses the damping constraint by a relative 1e-9 must still score above 1e9."""
    from test_tune import write_problem

    from analysis.tune.evaluate import INFEASIBLE, Evaluation, Evaluator
    from analysis.tune.spec import load_tuning

    search = {'"gains.kp"': [20, 2000], '"gains.kd"': [2, 80], "seed": 3, "population": 6, "max_evaluations": 60}
    spec = load_tuning(write_problem(tmp_path, search=search))
    zeta = np.full(4, spec.limits.min_damping_ratio * (1.0 - 1e-9))
    ev = Evaluation(gains={"gains.kp": 100.0, "gains.kd": 20.0}, torque_noise_rms=np.zeros(4), spectral_abscissa=-1.0,
                    damping_ratio=zeta, bandwidth_ratio=10.0, simulated=True, values=np.array([1.0, 2.0]),
                    peak_torque=np.zeros(4))
    judged = Evaluator(spec).judged(ev)
    assert not judged.feasible and 0 < judged.violations["min_damping_ratio"] < 1e-8
    assert judged.energy >= INFEASIBLE > 2.0
