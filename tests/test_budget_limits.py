"""A budget's limits: the step budget enforced during a run (blocks.monitor counts the right-hand-side
evaluations it allows)."""
from __future__ import annotations

import pytest

import blocks

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.2, "trajectory.duration": 10.0}


def test_the_step_budget_is_enforced_during_the_run(monkeypatch):
    """The paper run is estimated at 100 steps (its PD rate 30 1/s over 10 s) and takes about 820 (4922 RK45
    evaluations): within a budget of 150 steps it starts and is stopped at 900 evaluations."""
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "150")
    with pytest.raises(blocks.SimulationError, match="more than 900 right-hand-side evaluations"):
        blocks.simulate(PAPER, engine="fast")
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "lots")
    with pytest.raises(ValueError, match="DOBKIT_MAX_STEPS"):
        blocks.simulate(PAPER.with_changes(SHORT), engine="fast")
