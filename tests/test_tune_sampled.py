"""The sampled loop's stability margin as a tuning constraint (scenarios with a [controller]).

The closed form it is checked against (blocks.figure2.digital_stability): with forward Euler and a measured velocity the
observer's estimate error obeys ``e+ = (I - Ts Y M^-1) e``, so the sampled loop is stable exactly while
``Ts lambda_max(Y M^-1) < 2``.  With ``Y = y I`` and the paper's arm, ``lambda_max(M^-1) = 1 / 0.25`` (the
prismatic joint's mass, exact at every pose), so at 100 Hz the limit is ``y = 50`` and a margin of 0.2 allows
``y <= 40``.  Tests on both sides of that edge.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_tune import BASE_TOML

from analysis.tune.evaluate import Evaluation, Evaluator
from analysis.tune.runner import run_tune
from analysis.tune.spec import DEFAULT_SAMPLED_MARGIN, TuneError, load_tuning

CONTROLLER = "[controller]\nsample_rate = 100.0\n"
TUNING = """
name = "sampled-tune"
scenario = "base.toml"
[search]
"gains.observer" = [{low}, {high}]
seed = 2
population = 6
max_evaluations = 30
polish_evaluations = 10
[constraints]
{constraints}
"""
EDGE = 40.0        # y at Ts lambda_max = (1 - 0.2) x 2 at 100 Hz


def _spec(tmp_path, controller: str = CONTROLLER, constraints: str = "sampled_margin = 0.2", low=1, high=100):
    (tmp_path / "base.toml").write_text(BASE_TOML + controller)
    path = tmp_path / "tune.toml"
    path.write_text(TUNING.format(low=low, high=high, constraints=constraints))
    return load_tuning(path)


def _margin(evaluator: Evaluator, y: float) -> float:
    ev = Evaluation(gains={"gains.observer": y}, torque_noise_rms=np.zeros(4), spectral_abscissa=-1.0)
    return evaluator.margins(ev)["sampled_margin"]


@pytest.mark.parametrize("y, met", [(0.999 * EDGE, True), (1.001 * EDGE, False)])
def test_the_sampled_margin_holds_up_to_the_euler_closed_form_and_not_beyond(tmp_path, y, met):
    spec = _spec(tmp_path)
    evaluator = Evaluator(spec)
    gains = {"gains.observer": y}
    violations = evaluator.linear_violations(*evaluator.linear(gains), *evaluator.design(gains))
    assert (violations["sampled_margin"] == 0) is met
    loop = evaluator.sampled_loop(gains)
    np.testing.assert_allclose(loop["ts_lambda_max"], 0.01 * y / 0.25, rtol=1e-9)
    np.testing.assert_allclose(loop["ts_lambda_limit"], 2.0, rtol=1e-6)
    # reported like the other margins: the share of the limit left beyond the required 20 %
    np.testing.assert_allclose(_margin(evaluator, y), 1 - 0.01 * y / 0.25 / 2 - 0.2, atol=1e-6)
    assert (_margin(evaluator, y) >= 0) is met


def test_zoh_and_a_delay_lower_the_limit_the_margin_is_taken_from(tmp_path):
    def limit(extra: str) -> dict:
        return Evaluator(_spec(tmp_path, CONTROLLER + extra)).sampled_loop({"gains.observer": 10.0})
    euler, zoh = limit(""), limit('observer_discretization = "zoh"\n')
    zoh_delayed = limit('observer_discretization = "zoh"\ndelay = 1\n')
    assert euler["ts_lambda_max"] == zoh["ts_lambda_max"] == zoh_delayed["ts_lambda_max"]
    # Euler's 2 holds with a delay too; the exact (zoh) observer couples to the tracking and lowers it
    assert limit("delay = 1\n")["ts_lambda_limit"] == pytest.approx(2.0, rel=1e-6)
    assert 0 < zoh_delayed["ts_lambda_limit"] < zoh["ts_lambda_limit"] < euler["ts_lambda_limit"]
    # docs/model.md, "Digital observer": Kp = 180, Kd = 36, zoh, measured velocity, 100 Hz
    assert zoh["ts_lambda_limit"] == pytest.approx(1.7899, abs=1e-4)


def test_bounds_that_all_break_the_margin_are_refused_before_anything_runs(tmp_path):
    spec = _spec(tmp_path, low=45, high=100)
    with pytest.raises(TuneError, match=r"sampled_margin.*Ts lambda_max\(Y M\^-1\) = 1\.8 against the sampled "
                                        r"loop's limit 2, more than 0\.8 of it"):
        run_tune(spec, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_the_margin_is_on_by_default_with_a_controller_and_refused_without_one(tmp_path):
    spec = _spec(tmp_path, constraints="")
    assert spec.limits.sampled_margin == DEFAULT_SAMPLED_MARGIN and spec.limits.sampled_from == "default"
    assert _spec(tmp_path, constraints="sampled_margin = 0").limits.sampled_margin is None
    with pytest.raises(TuneError, match=r"'constraints.sampled_margin' \(0.2\) needs a scenario with a \[controller\]"):
        _spec(tmp_path, controller="")
    with pytest.raises(TuneError, match=r"'constraints.sampled_margin' must be a fraction from 0.*got 1.5"):
        _spec(tmp_path, constraints="sampled_margin = 1.5")
    # a tuning without a controller keeps the constraints of its definition as they were
    assert "sampled_margin" not in _spec(tmp_path, controller="", constraints="").limits.as_dict()


def test_a_tuning_with_a_controller_stops_at_the_margin_and_reports_it(tmp_path):
    spec = _spec(tmp_path)
    result = run_tune(spec, tmp_path / "out", workers=1, progress=False, figures=False)
    y = result.tuned.gains["gains.observer"]
    # a larger observer gain lowers the error here, so the best design sits at the edge the margin allows
    assert result.feasible and 0.95 * EDGE <= y <= EDGE
    assert 0 <= result.tuned.margins["sampled_margin"] < 0.01
    assert result.base.margins["sampled_margin"] == pytest.approx(1 - 0.01 * 10 / 0.25 / 2 - 0.2, abs=1e-6)
    saved = json.loads((tmp_path / "out" / "tune.json").read_text())
    assert saved["tuned"]["sampled_loop"]["ts_lambda_limit"] == pytest.approx(2.0, rel=1e-6)
    assert "[controller]" in (tmp_path / "out" / result.scenario_file).read_text()
