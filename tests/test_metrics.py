"""Every metric the project reports, against values computed here without the package.

* The tracking metrics (blocks/figure2/metrics.py) on hand-made signals: per-joint
  errors with a known RMS, maximum and final value; tool-tip errors whose
  distance is known in closed form (a d3 error moves the tip by itself; a roll
  error does not move it; a theta1 error moves it along a chord of the circle
  of radius ``|p_xy|``; a theta2 error along a chord of radius ``l2``); a
  disturbance-estimate error of known RMS.  The same through the accumulator
  in chunks over a member axis, as the numpy batch uses it.
* The batch engines' metrics (numpy and compiled) against the same formulas
  applied by hand to the signals each run kept.
* A sweep summary's statistics, worst runs and influence (Spearman) on rows
  with hand-picked values.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from conftest import L1, L2

import blocks
from analysis.sweep.summary import summarize
from blocks.figure2.batch import simulate_batch
from blocks.figure2.metrics import METRICS, TrackingAccumulator, tracking_metrics
from blocks.model.rrpr import tool_kernels as RRPR_TOOL

# --------------------------------------------------------------------------------------------------------------
# Hand-made signals: five grid points, one kind of error at each
# --------------------------------------------------------------------------------------------------------------
Q_REF = np.array([0.4, 1.1, 0.2, 0.3])              # a pose held by the reference (rad, rad, m, rad)
# q_ref - q at each of the five points: none; d3 by 4 mm; roll by 0.3 rad; theta1 by 0.1 rad; theta2 by 0.2 rad
ERRORS = np.array([[0.0, 0.0, 0.0, 0.1, 0.0],
                   [0.0, 0.0, 0.0, 0.0, 0.2],
                   [0.0, 0.004, 0.0, 0.0, 0.0],
                   [0.0, 0.0, 0.3, 0.0, 0.0]])
RADIUS = math.sqrt(L1 ** 2 + L2 ** 2 + 2 * L1 * L2 * math.cos(Q_REF[1]))      # |p_xy|, law of cosines
TIP_MM = np.array([0.0, 4.0, 0.0, 2e3 * RADIUS * math.sin(0.05), 2e3 * L2 * math.sin(0.1)])
D_ERROR = np.array([[2.0, -2.0, 2.0, -2.0, 2.0],    # d - d_hat: |.| constant per joint, so RMS = that value
                    [0.5, 0.5, -0.5, 0.5, 0.5],
                    [0.0, 0.0, 0.0, 0.0, 3.0],       # RMS sqrt(9 / 5)
                    [1.0, 2.0, 2.0, 4.0, 0.0]])      # RMS sqrt(25 / 5) = sqrt(5)
D_RMS = [2.0, 0.5, math.sqrt(9 / 5), math.sqrt(5.0)]


def hand_response(errors=ERRORS, d_error=D_ERROR, scenario=True) -> ct.TimeResponseData:
    """A response with the five points above: q_ref held, q = q_ref - errors, d = 1 + d_error, d_hat = 1."""
    n = errors.shape[1]
    q_ref = np.tile(Q_REF[:, None], (1, n))
    rows = {"q_ref": q_ref, "q": q_ref - errors, "d": 1.0 + d_error, "d_hat": np.ones((4, n))}
    labels = [f"{name}[{i}]" for name in rows for i in range(4)]
    resp = ct.TimeResponseData(np.linspace(0.0, 0.4, n), np.vstack(list(rows.values())), output_labels=labels,
                               issiso=False)
    if scenario:
        resp.scenario = blocks.load_scenario("paper")
    return resp


def test_the_tip_distances_are_those_of_the_paper_kinematics():
    """The closed forms above against the kinematics written out (x = l1 c1 + l2 c12, y = l1 s1 + l2 s12,
    z = d1 - d3 - d4), so that the tests below rest on two independent derivations."""
    from conftest import reference_fk
    p = reference_fk(np.tile(Q_REF, (5, 1)))[:, :3] - reference_fk((Q_REF[:, None] - ERRORS).T)[:, :3]
    np.testing.assert_allclose(1e3 * np.linalg.norm(p, axis=1), TIP_MM, rtol=1e-12, atol=1e-12)


def test_tracking_metrics_of_hand_made_signals():
    m = tracking_metrics(hand_response())
    assert set(m) == set(METRICS)
    np.testing.assert_allclose(m["rms_position_error"], [math.sqrt(0.01 / 5), math.sqrt(0.04 / 5),
                                                         0.004 / math.sqrt(5), math.sqrt(0.09 / 5)], rtol=1e-12)
    np.testing.assert_allclose(m["max_abs_position_error"], [0.1, 0.2, 0.004, 0.3], rtol=1e-12)
    np.testing.assert_allclose(m["final_abs_position_error"], [0.0, 0.2, 0.0, 0.0], rtol=0, atol=1e-15)
    assert m["max_tool_position_error_mm"] == pytest.approx(TIP_MM.max(), rel=1e-12)
    assert m["rms_tool_position_error_mm"] == pytest.approx(math.sqrt(np.sum(TIP_MM ** 2) / 5), rel=1e-12)
    np.testing.assert_allclose(m["rms_disturbance_error"], D_RMS, rtol=1e-12)


def test_the_final_error_is_the_last_points_and_signs_do_not_matter():
    errors = -ERRORS[:, ::-1]                  # reversed in time and negated: the final error is the first above
    m = tracking_metrics(hand_response(errors, -D_ERROR))
    np.testing.assert_allclose(m["final_abs_position_error"], [0.0, 0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(m["max_abs_position_error"], [0.1, 0.2, 0.004, 0.3], rtol=1e-12)
    np.testing.assert_allclose(m["rms_disturbance_error"], D_RMS, rtol=1e-12)
    m = tracking_metrics(hand_response(ERRORS[:, :4], D_ERROR[:, :4]))    # ends on the theta1 error
    np.testing.assert_allclose(m["final_abs_position_error"], [0.1, 0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(m["rms_position_error"][0], 0.1 / 2, rtol=1e-12)


def test_without_a_scenario_or_observer_those_metrics_are_not_reported():
    resp = hand_response(scenario=False)
    assert "max_tool_position_error_mm" not in tracking_metrics(resp)
    n = ERRORS.shape[1]
    no_observer = ct.TimeResponseData(np.linspace(0, 0.4, n), np.vstack([np.tile(Q_REF[:, None], (1, n))] * 2),
                                      output_labels=[f"{s}[{i}]" for s in ("q_ref", "q") for i in range(4)],
                                      issiso=False)
    m = tracking_metrics(no_observer)
    assert "rms_disturbance_error" not in m and m["rms_position_error"] == [0.0] * 4


def test_the_accumulator_over_chunks_and_members_gives_the_hand_values():
    """Two members (the hand signals, and no error at all), the grid given in chunks of 2, 2 and 1 points."""
    q_ref = np.tile(Q_REF[:, None, None], (1, 5, 2))
    q = q_ref.copy()
    q[:, :, 0] -= ERRORS
    d = np.ones((4, 5, 2))
    d[:, :, 0] += D_ERROR
    kin = [L1, L2, 0.12, 0.271]
    acc = TrackingAccumulator(kin, 5, METRICS, members=(2,), n_joints=4, tool_position=RRPR_TOOL.tool_position)
    for a, b in ((0, 2), (2, 4), (4, 5)):
        acc.add(q_ref[:, a:b], q[:, a:b], d[:, a:b], np.ones((4, b - a, 2)), last=b == 5)
    r = acc.result()
    assert r["rms_position_error"].shape == (4, 2) and r["max_tool_position_error_mm"].shape == (2,)
    np.testing.assert_allclose(r["rms_position_error"][:, 0], [math.sqrt(0.01 / 5), math.sqrt(0.04 / 5),
                                                               0.004 / math.sqrt(5), math.sqrt(0.09 / 5)], rtol=1e-12)
    np.testing.assert_allclose(r["max_abs_position_error"][:, 0], [0.1, 0.2, 0.004, 0.3], rtol=1e-12)
    np.testing.assert_allclose(r["final_abs_position_error"][:, 0], [0.0, 0.2, 0.0, 0.0], atol=1e-15)
    assert r["max_tool_position_error_mm"][0] == pytest.approx(TIP_MM.max(), rel=1e-12)
    assert r["rms_tool_position_error_mm"][0] == pytest.approx(math.sqrt(np.sum(TIP_MM ** 2) / 5), rel=1e-12)
    np.testing.assert_allclose(r["rms_disturbance_error"][:, 0], D_RMS, rtol=1e-12)
    for name in METRICS:
        np.testing.assert_array_equal(r[name][..., 1], 0.0)


# --------------------------------------------------------------------------------------------------------------
# The batch engines: their metrics against the formulas applied to the signals they kept
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("observer", [True, False])
@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_batch_metrics_are_the_formulas_applied_to_the_kept_signals(engine, observer):
    s = blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.3, "simulation.output_step": 0.01})
    kept = ("q_ref", "q") + (("d", "d_hat") if observer else ())
    result = simulate_batch(s, [{}, {"gains.kp": 90.0, "disturbance.f_r": [3.0, -2.0, 2.8, 1.0]}], observer=observer,
                            signals=kept, engine=engine)
    assert set(result.metrics) == {m for m in METRICS if observer or m != "rms_disturbance_error"}
    for i in range(2):
        e = result.signals["q_ref"][i] - result.signals["q"][i]            # (points, 4)
        m = result.member_metrics(i)
        np.testing.assert_allclose(m["rms_position_error"], np.sqrt(np.sum(e ** 2, axis=0) / e.shape[0]), rtol=1e-12)
        np.testing.assert_allclose(m["max_abs_position_error"], np.max(np.abs(e), axis=0), rtol=1e-12)
        np.testing.assert_allclose(m["final_abs_position_error"], np.abs(e[-1]), rtol=1e-12)
        if observer:        # most errors peak before the end: the maximum and the final error differ
            assert np.sum(np.argmax(np.abs(e), axis=0) < e.shape[0] - 1) >= 3
            ed = result.signals["d"][i] - result.signals["d_hat"][i]
            np.testing.assert_allclose(m["rms_disturbance_error"], np.sqrt(np.mean(ed ** 2, axis=0)), rtol=1e-12)


# --------------------------------------------------------------------------------------------------------------
# A sweep's summary
# --------------------------------------------------------------------------------------------------------------
def _rows():
    """Six runs: five ok with rms_position_error[0] = 1..5 (one joint given), one diverged, and one NaN metric."""
    firsts = [3.0, 1.0, 5.0, 2.0, 4.0]
    rows = []
    for k, v in enumerate(firsts):
        rows.append({"run_id": f"r{k}", "index": k, "status": "ok",
                     "values": {"gains.kp": 100.0 * v, "observer.gain": 10.0 * [1, 3, 2, 5, 4][int(v) - 1],
                                "noise.seed": 7},
                     "metrics": {"rms_position_error": [v, 0.5, 0.25, 0.125],
                                 "max_tool_position_error_mm": 2.0 * v if k != 4 else None}})
    rows.append({"run_id": "r5", "index": 5, "status": "diverged", "values": {"gains.kp": 1.0, "observer.gain": 1.0,
                                                                              "noise.seed": 7},
                 "metrics": {}, "failed_at": 0.25, "message": "q[2] = 1e9"})
    return rows


def test_the_sweep_statistics_are_those_of_the_hand_values():
    header = {"name": "s", "worst_metric": "rms_position_error[0]", "worst_count": 2, "runs": 6}
    summary = summarize((header, _rows()))
    assert (summary.counts.runs, summary.counts.finished, summary.counts.ok, summary.counts.diverged) == (6, 6, 5, 1)
    st = summary.statistics["rms_position_error[0]"]
    # 1, 2, 3, 4, 5: mean 3, sample std sqrt(10 / 4), quantiles by linear interpolation at 0.05 * 4 = 0.2 and 3.8
    assert (st.count, st.min, st.max, st.not_finite) == (5, 1.0, 5.0, 0)
    assert st.mean == pytest.approx(3.0, rel=1e-15) and st.median == pytest.approx(3.0, rel=1e-15)
    assert st.std == pytest.approx(math.sqrt(2.5), rel=1e-14)
    assert st.p5 == pytest.approx(1.2, rel=1e-14) and st.p95 == pytest.approx(4.8, rel=1e-14)
    const = summary.statistics["rms_position_error[3]"]
    assert (const.mean, const.std, const.min, const.max) == (0.125, 0.0, 0.125, 0.125)
    tool = summary.statistics["max_tool_position_error_mm"]    # the run with 4.0 has no value: 2, 6, 10, 4
    assert (tool.count, tool.not_finite, tool.max) == (4, 1, 10.0)
    assert tool.mean == pytest.approx(5.5, rel=1e-15) and tool.median == pytest.approx(5.0, rel=1e-15)
    assert [(w.run_id, w.value) for w in summary.worst] == [("r2", 5.0), ("r4", 4.0)]
    assert summary.failed[0].run_id == "r5" and summary.failed[0].failed_at == 0.25


def test_the_influence_is_spearmans_rank_correlation_by_hand():
    summary = summarize(({"worst_metric": "rms_position_error[0]", "worst_count": 2, "runs": 6}, _rows()))
    # kp = 100 x metric: ranks equal, rho = 1; the observer gain's ranks 1 3 2 5 4 against 1 2 3 4 5:
    # sum d^2 = 4, rho = 1 - 6 * 4 / (5 (25 - 1)) = 0.8; the seed does not vary: no value
    assert summary.influence["gains.kp"] == pytest.approx(1.0, rel=1e-14)
    assert summary.influence["observer.gain"] == pytest.approx(0.8, rel=1e-14)
    assert "noise.seed" not in summary.influence


Q = np.array([0.4, 1.1, 0.2, 0.3])            # a pose away from every singularity (rad, rad, m, rad)


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_disturbance_error_is_against_the_lumped_disturbance_when_the_run_has_it():
    """me-d-source (killed before only because the hand-made signals had no tau_dis to read): with model mismatch
    the observer estimates the lumped d (Eq. 2-3), not tau_dis alone; the RMS of d - d_hat over five hand-made
    points is that of the constant errors chosen here."""
    import control as ct

    from blocks.figure2.metrics import tracking_metrics
    n = 5
    q = np.tile(Q[:, None], (1, n))
    d_error = np.array([1.0, 2.0, 0.5, 3.0])[:, None] * np.array([1.0, -1.0, 1.0, -1.0, 1.0])   # |.| constant
    rows = {"q_ref": q, "q": q, "d": 4.0 + d_error, "d_hat": np.full((4, n), 4.0),
            "tau_dis": np.full((4, n), 1.5)}                   # the mismatch makes d differ from tau_dis
    labels = [f"{name}[{i}]" for name in rows for i in range(4)]
    resp = ct.TimeResponseData(np.linspace(0.0, 0.4, n), np.vstack(list(rows.values())), output_labels=labels,
                               issiso=False)
    got = tracking_metrics(resp)["rms_disturbance_error"]
    np.testing.assert_allclose(got, [1.0, 2.0, 0.5, 3.0], rtol=1e-14)
