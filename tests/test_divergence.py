"""The divergence rule (blocks.divergence): a state beyond its bound, or running away, stops the run naming the
signal and the bound; a stiff but stable loop is not called diverged (docs/hostile-inputs.md, "Single
runs")."""
from __future__ import annotations

import re

import numpy as np
import pytest

import blocks
from blocks.divergence import StateBounds
from blocks.metrics import signal

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.2, "trajectory.duration": 10.0}


def test_a_stiff_but_stable_loop_runs_with_an_implicit_method_and_is_not_called_diverged():
    """Y = 1e6: d_hat = Y dq + z, with z of the order of Y |dq|; the loop is stable and the estimate converges
    within milliseconds (time constant k4 / Y = 0.25 us on the prismatic joint, 0.1 s / 1e5 on the slowest)."""
    s = PAPER.with_changes({"gains.observer": 1e6, "simulation.method": "Radau"} | SHORT)
    run = blocks.simulate(s, engine="fast")
    error = np.abs(signal(run, "d") - signal(run, "d_hat"))[:, run.time >= 0.01]
    assert error.max() < 1e-3


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_divergence_is_judged_on_physical_signals_and_named(engine):
    if engine == "compiled":
        pytest.importorskip("numba")
    s = PAPER.with_changes({"noise.q_std": [1e3] * 4, "noise.dq_std": [0.0] * 4} | SHORT)
    with pytest.raises(blocks.SimulationError,
                       match=r"diverged (at|by) t = .*plant dq\[\d\] reached .* beyond its bound .*reference's "
                             r"largest speed plus"):
        blocks.simulate(s, engine=engine)


def test_a_value_beyond_its_bound_prints_beyond_it():
    rng = np.random.default_rng(3)
    for bound in list(rng.uniform(1.0, 1e4, 200)) + [100.2, 1000.0, 1e-3]:
        for excess in (1e-15, 1e-12, 1e-9, 3e-5, 1e-3, 0.5):
            value = bound * (1 + excess)
            if value <= bound:
                continue
            bounds = StateBounds(np.array([bound]), ["plant dq[2]"], ["m/s"], ["a reason"])
            text = bounds.describe(np.array([-value]))
            shown, limit = re.fullmatch(r"plant dq\[2\] reached (-?\S+) m/s, beyond its bound (\S+) m/s "
                                        r"\(a reason\)", text).groups()
            assert abs(float(shown)) > float(limit), text
    text = StateBounds(np.array([100.2]), ["plant dq[2]"], ["m/s"], ["r"]).describe(np.array([100.23]))
    assert "reached 100.23 m/s, beyond its bound 100.2 m/s" in text
