"""Two derived signals pinned in every engine: the measurement noise and the tool-tip error.

* The noise is the scenario's table of samples, interpolated linearly
  (blocks/model/noise.py): at ``t = k * period`` it is sample ``k`` itself, at a
  quarter of the way to the next one ``3/4`` of sample ``k`` plus ``1/4`` of
  sample ``k + 1``.  Read from each engine's recorded ``q_meas - q`` (and the
  sampled controller's encoder readings), never from another engine.
* The tool-tip error is the distance between the tool positions of ``q_ref``
  and ``q``, with ``x = l1 c1 + l2 c12``, ``y = l1 s1 + l2 s12``,
  ``z = d1 - d3 - d4`` (paper-notes; written out in tests/conftest.py), from
  the run's own recorded positions.  The run is without the observer: the
  prismatic joint then rests 31 mm off (paper-notes), so the z part dominates.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import reference_fk

import blocks
from analysis.simulation.studies import run_metrics
from blocks.figure2.batch import simulate_batch
from blocks.figure2.metrics import signal, tracking_metrics

PERIOD = 0.01            # s between noise samples
NOISE = {"noise.q_std": [1e-3, 2e-3, 1e-4, 3e-3], "noise.dq_std": [1e-2, 2e-2, 1e-3, 3e-2], "noise.seed": 7,
         "noise.sample_period": PERIOD}
SHORT = {"simulation.t_final": 0.2, "simulation.output_step": PERIOD / 4}


@pytest.fixture(scope="module")
def noisy():
    return blocks.load_scenario("paper").with_changes(NOISE | SHORT)


def expected_noise(table: np.ndarray, n_points: int) -> np.ndarray:
    """The noise at ``t_j = j period / 4``, by hand: sample k at t = k period, 3/4 of k + 1/4 of k + 1 a quarter on..."""
    out = np.empty((table.shape[0], n_points))
    for j in range(n_points):
        k, quarter = divmod(j, 4)
        w = quarter / 4
        out[:, j] = table[:, k] if quarter == 0 else (1 - w) * table[:, k] + w * table[:, k + 1]
    return out


def _check_noise(q_noise, dq_noise, table) -> None:
    """Rows (4, n) of recorded noise against the table (rounding: q_meas - q cancels digits of q ~ 1, dq ~ 1)."""
    want = expected_noise(table, q_noise.shape[1])
    np.testing.assert_allclose(q_noise, want[:4], rtol=0, atol=1e-13)
    np.testing.assert_allclose(dq_noise, want[4:], rtol=0, atol=1e-13)


def test_the_table_holds_independent_samples_of_the_stated_spread(noisy):
    table = noisy.noise.table
    assert table.shape[0] == 8 and table.shape[1] >= 0.2 / PERIOD + 1
    assert len({float(v) for v in table.ravel()}) == table.size         # no sample repeats another
    # a bigger table of the same definition: the spread at the sample instants is the stated one (within 3 %)
    big = blocks.MeasurementNoise(q_std=(1e-3,) * 4, dq_std=(2e-2,) * 4, seed=7, sample_period=PERIOD, t_final=100.0,
                                  joints=blocks.RRPR_JOINTS)
    std = big.table.std(axis=1)
    np.testing.assert_allclose(std, [1e-3] * 4 + [2e-2] * 4, rtol=0.03)


@pytest.mark.parametrize("engine", ["python-control", "fast", "compiled"])
def test_a_single_run_reads_sample_k_at_k_periods(noisy, engine):
    r = blocks.simulate(noisy, engine=engine)
    np.testing.assert_allclose(np.asarray(r.time), np.arange(81) * PERIOD / 4, rtol=0, atol=1e-15)
    _check_noise(signal(r, "q_meas") - signal(r, "q"), signal(r, "dq_meas") - signal(r, "dq"), noisy.noise.table)


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_each_batch_member_reads_its_own_table(noisy, engine):
    result = simulate_batch(noisy, [{}, {"noise.seed": 11}], signals=("q", "q_meas", "dq", "dq_meas"),
                            engine=engine, metrics=("rms_position_error",))
    seeds = [7, 11]
    for i, seed in enumerate(seeds):
        table = blocks.MeasurementNoise(q_std=tuple(NOISE["noise.q_std"]), dq_std=tuple(NOISE["noise.dq_std"]),
                                        seed=seed, sample_period=PERIOD, t_final=0.2,
                                        joints=blocks.RRPR_JOINTS).table
        q_noise = (result.signals["q_meas"][i] - result.signals["q"][i]).T
        dq_noise = (result.signals["dq_meas"][i] - result.signals["dq"][i]).T
        _check_noise(q_noise, dq_noise, table)


def test_the_sampled_controller_reads_sample_k_at_its_tick(noisy):
    """Encoders without quantization, velocity measured: q_s(t_k) = q(t_k) + n_q(t_k) at every 500 Hz tick."""
    s = noisy.with_changes({"controller.sample_rate": 500.0, "simulation.output_step": 0.002})
    r = blocks.simulate(s)
    t = np.asarray(r.time)
    want = np.array([[s.noise.table[i, int(round(tk / PERIOD))] if abs(tk / PERIOD - round(tk / PERIOD)) < 1e-9
                      else np.nan for tk in t] for i in range(8)])
    at_samples = ~np.isnan(want[0])
    assert at_samples.sum() == 21
    # between samples: linear interpolation by hand
    for j in np.flatnonzero(~at_samples):
        k, w = int(t[j] // PERIOD), (t[j] % PERIOD) / PERIOD
        want[:, j] = (1 - w) * s.noise.table[:, k] + w * s.noise.table[:, k + 1]
    np.testing.assert_allclose(signal(r, "q_s") - signal(r, "q"), want[:4], rtol=0, atol=1e-12)
    np.testing.assert_allclose(signal(r, "dq_s") - signal(r, "dq"), want[4:], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------------------------
# The tool-tip error, by hand, in every engine that reports it
# --------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def held_off():
    """0.3 s without the observer, reference moving: the prismatic joint sags towards 31 mm below its reference."""
    return blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.3, "simulation.output_step": 0.01})


def hand_tip_distance_mm(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """|p(q_ref) - p(q)| (mm) per grid point, rows (4, n) in, from the paper's kinematics."""
    d = reference_fk(q_ref.T)[:, :3] - reference_fk(q.T)[:, :3]
    return 1e3 * np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2)


def _assert_tool_metrics(metrics: dict, dist: np.ndarray) -> None:
    assert metrics["max_tool_position_error_mm"] == pytest.approx(dist.max(), rel=1e-12)
    assert metrics["rms_tool_position_error_mm"] == pytest.approx(math.sqrt(np.mean(dist ** 2)), rel=1e-12)


def _z_dominates(q_ref: np.ndarray, q: np.ndarray, dist: np.ndarray) -> None:
    """The height error is most of the distance at the end: an x, y-only distance would be far off."""
    dz = 1e3 * np.abs(q[2, -1] - q_ref[2, -1])
    assert dz > 5.0 and dz > 0.9 * dist[-1]


@pytest.mark.parametrize("engine", ["python-control", "fast", "compiled"])
def test_a_single_runs_tool_tip_error_is_the_hand_distance(held_off, engine):
    r = blocks.simulate(held_off, observer=False, engine=engine)
    q_ref, q = signal(r, "q_ref"), signal(r, "q")
    dist = hand_tip_distance_mm(q_ref, q)
    _z_dominates(q_ref, q, dist)
    _assert_tool_metrics(tracking_metrics(r), dist)
    tool = run_metrics(r).tool_mm                     # the studies' view of the same run
    assert tool.peak_error == pytest.approx(dist.max(), rel=1e-12)
    assert tool.rms_error == pytest.approx(math.sqrt(np.mean(dist ** 2)), rel=1e-12)


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_a_batchs_tool_tip_error_is_the_hand_distance_of_its_own_positions(held_off, engine):
    result = simulate_batch(held_off, [{}, {"disturbance.f_r": [1.43, 1.6, 2.8, 1.2]}], observer=False,
                            signals=("q_ref", "q"), engine=engine,
                            metrics=("max_tool_position_error_mm", "rms_tool_position_error_mm"))
    for i in range(2):
        q_ref, q = result.signals["q_ref"][i].T, result.signals["q"][i].T
        dist = hand_tip_distance_mm(q_ref, q)
        _z_dominates(q_ref, q, dist)
        _assert_tool_metrics(result.member_metrics(i), dist)
