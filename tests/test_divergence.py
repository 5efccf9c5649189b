"""The divergence rule (blocks.divergence): a state beyond its bound, or running away, stops the run naming the
signal and the bound; a stiff but stable loop is not called diverged (docs/hostile-inputs.md, "Single
runs")."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
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
