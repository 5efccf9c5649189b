"""The divergence rule (blocks.engines.divergence): a state beyond its bound, or running away, stops the run naming the
signal, the value it reached and the bound; a stiff but stable loop is not called diverged.

The bounds are the rule's numbers worked by hand; a bound holds the magnitude inclusively on both sides; the
printed value is always beyond the printed bound (docs/hostile-inputs.md, "Single runs" and "Round 3")."""
from __future__ import annotations

import re

import numpy as np
import pytest

import blocks
from blocks.engines.divergence import RUNAWAY_FACTOR, RUNAWAY_STEPS, Runaway, StateBounds
from blocks.engines.monitor import Monitor
from blocks.figure2.metrics import signal

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


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_a_bound_holds_the_magnitude_inclusive_on_both_sides():
    """div-violated-lt, div-violated-abs: divergence is a magnitude *beyond* the bound; at the bound, or at minus
    it, the run goes on; a hair beyond either side, or a value far below minus the bound, has diverged."""
    b = StateBounds(np.array([2.0, 5.0]), ["a", "b"], ["m", "m/s"], ["given", "given"])
    assert b.violated([2.0, -5.0]).tolist() == [False, False]
    assert b.violated([np.nextafter(2.0, 3.0), -np.nextafter(5.0, 6.0)]).tolist() == [True, True]
    assert b.violated([-1e9, 0.0]).tolist() == [True, False]
    monitor = Monitor("run", b, np.zeros(2))
    with pytest.raises(blocks.SimulationError, match="b reached -7 m/s, beyond its bound 5 m/s"):
        monitor.check(0.5, [0.0, -7.0])


def test_runaway_is_growth_beyond_the_factor_in_consecutive_steps():
    """div-runaway-factor, div-runaway-reset: a signal runs away when it grows more than RUNAWAY_FACTOR-fold in
    each of RUNAWAY_STEPS consecutive steps; slower growth, or growth interrupted by one step, does not count."""
    assert (RUNAWAY_FACTOR, RUNAWAY_STEPS) == (10.0, 3)
    fast = Runaway(1)
    values = [1.0, 11.0, 121.0, 1331.0]
    verdicts = [fast.update([a], [b]) for a, b in zip(values, values[1:])]
    assert verdicts == [None, None, 0]
    slow = Runaway(1)                                           # 9-fold each step: an unstable but slow mode
    y = 1.0
    for _ in range(6):
        assert slow.update([y], [9.0 * y]) is None
        y *= 9.0
    broken = Runaway(1)                                         # two fast steps, a pause, two fast steps
    values = [1.0, 11.0, 121.0, 100.0, 1100.0, 12100.0]
    assert [broken.update([a], [b]) for a, b in zip(values, values[1:])] == [None] * 5


def test_the_bounds_of_a_held_arm_are_the_rules_numbers_by_hand():
    """div-pos-abs, div-force-no-external: holding q_ref = (-0.5, -1, 0.2, -0.3) under f_r = (0, 0, 300, 0) N:

    * positions: |q_ref| + 100 rad (revolute) or + 10 m (the slide) -- a negative reference counts by magnitude;
    * velocities: 0 + 1000 rad/s or 100 m/s;
    * d_hat on the slide: 1000 x (|300| external + |G3| + |M q'' + h|_3 at rest (= |G3|) + 1), G3 = k4 g = 2.45 N,
      one bound for every joint's estimate, the largest; z[i] adds Y_ii times joint i's velocity bound.
    """
    from conftest import hold_trajectory, make_scenario

    from blocks.figure2.loop import closed_loop
    from blocks.figure2.physical_bounds import state_bounds
    offset = (-0.5, -1.0, 0.2, -0.3)
    s = make_scenario(trajectory=hold_trajectory(offset), disturbance={"kind": "paper", "f_r": [0.0, 0.0, 300.0, 0.0]},
                      simulation={"t_final": 0.1})
    b = state_bounds(closed_loop(s), s)
    bound = dict(zip(b.names, b.bounds))
    for i, margin in enumerate((100.0, 100.0, 10.0, 100.0)):
        assert bound[f"plant q[{i}]"] == pytest.approx(abs(offset[i]) + margin, rel=1e-12)
        assert bound[f"plant dq[{i}]"] == pytest.approx(1000.0 if i != 2 else 100.0, rel=1e-12)
    g3 = 0.25 * 9.8
    force = 1000.0 * (300.0 + 2 * g3 + 1.0)                     # the largest start force: the slide's
    assert bound["observer z[2] (= d_hat - Y dq)"] == pytest.approx(force + 10.0 * 100.0, rel=1e-9)
    assert bound["observer z[0] (= d_hat - Y dq)"] == pytest.approx(force + 10.0 * 1000.0, rel=1e-9)


def _renamed(block, name, meanings):
    """The same block under another name, its contract declaring ``meanings`` (or nothing)."""
    from dataclasses import replace

    from blocks.diagram.contract import Block
    return Block(block.updfcn, block.outfcn, inputs=list(block.input_labels), outputs=list(block.output_labels),
                 states=list(block.state_labels), name=name,
                 contract=replace(block.contract, state_meanings=meanings))


def test_a_state_is_bounded_by_what_its_block_declares_it_to_be_not_by_the_blocks_name():
    """The paper's plant under another name keeps its physical bounds (its contract says what q and dq are); the
    same block named "plant" but declaring nothing is judged by growth only; a user's block that declares its
    state a velocity of joint 1 gets joint 1's velocity bound (a held reference: 0 + 1000 rad/s)."""
    from conftest import hold_trajectory, make_scenario

    from blocks.engines.divergence import state_meanings
    from blocks.figure2.loop import build_blocks
    from blocks.figure2.physical_bounds import state_bounds
    offset = (-0.5, -1.0, 0.2, -0.3)
    s = make_scenario(trajectory=hold_trajectory(offset), simulation={"t_final": 0.1})
    plant = build_blocks(s)["plant"]
    assert state_meanings([plant])[:2] == [("plant q[0]", ("position", 0)), ("plant q[1]", ("position", 1))]

    reference = state_bounds([plant], s)
    actuator = _renamed(plant, "my_arm", plant.contract.state_meanings)
    renamed = state_bounds([actuator], s)
    np.testing.assert_array_equal(renamed.bounds, reference.bounds)
    assert renamed.names[0] == "my_arm q[0]"
    np.testing.assert_allclose(renamed.bounds, [100.5, 101.0, 10.2, 100.3, 1e3, 1e3, 1e2, 1e3], rtol=1e-12)

    silent = state_bounds([_renamed(plant, "plant", ())], s)
    assert np.isinf(silent.bounds).all()

    import control as ct

    from blocks.diagram.contract import Block, BlockContract
    lag = Block(lambda t, x, u, p: -x + u, lambda t, x, u, p: x, inputs=["u"], outputs=["y"], states=["w"],
                name="filter", contract=BlockContract(state_meanings=[("w", "velocity", 1)]))
    assert isinstance(lag, ct.NonlinearIOSystem)
    (w_bound,) = state_bounds([lag], s).bounds
    assert w_bound == 1e3


def test_a_contract_that_declares_an_unknown_state_or_quantity_is_refused():
    from blocks.diagram.contract import Block, BlockContract, ContractError
    with pytest.raises(ContractError, match=r"'v' a velocity, which is not one of its states \['w'\]"):
        Block(lambda t, x, u, p: -x, None, inputs=[], outputs=[], states=["w"], name="f",
              contract=BlockContract(state_meanings=[("v", "velocity", 0)]))
    with pytest.raises(ContractError, match=r"'w' is declared 'torque' of joint 0"):
        BlockContract(state_meanings=[("w", "torque", 0)])
