"""A context carries the numbers: one diagram, run by the simulator with the blocks' kernel parameters of a Context
(blocks.engines.context.Context.params), gives the run of a diagram built with those numbers; what the engine
cannot follow is refused by name."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.diagram.contract import contract_of
from blocks.engines.context import Context
from blocks.engines.simulator import Solver, advance, make_engine
from blocks.figure2.loop import closed_loop, initial_state

PAPER = blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.3, "trajectory.duration": 10.0})
OTHER = PAPER.with_changes({"gains.kp": 300.0, "gains.kd": 20.0, "gains.observer": 25.0})
ENGINES = ["fast", pytest.param("compiled", marks=pytest.mark.skipif(
    blocks.engines.compiled.numba_or_none() is None, reason="needs numba"))]


def _params(loop, *names) -> dict:
    return {b.name: contract_of(b).kernels.params for b in loop.syslist if b.name in names}


def _run(engine_name, loop, scenario, params=None):
    t = np.linspace(0.0, scenario.simulation.t_final, 61)
    engine = make_engine(engine_name, loop, "RK45")
    context = Context(0.0, initial_state(loop, scenario), params=params)
    states, outputs, _ = advance(engine, context, t, Solver("RK45", 1e-9, 1e-11))
    return states


@pytest.mark.parametrize("engine", ENGINES)
def test_the_contexts_numbers_give_the_run_of_a_diagram_built_with_them(engine):
    """The paper's diagram with the controller's and the observer's numbers of another scenario (Kp 300, Kd 20,
    Y 25) equals that scenario's own diagram, and differs from the paper's run (the numbers are read)."""
    loop, other = closed_loop(PAPER), closed_loop(OTHER)
    swapped = _run(engine, loop, PAPER, _params(other, "controller", "observer"))
    own = _run(engine, other, OTHER)
    np.testing.assert_allclose(swapped, own, rtol=1e-9, atol=1e-12)
    assert np.abs(_run(engine, loop, PAPER) - own).max() > 1e-6


@pytest.mark.parametrize("engine", ENGINES)
def test_the_blocks_own_numbers_in_a_context_change_nothing(engine):
    loop = closed_loop(PAPER)
    np.testing.assert_array_equal(_run(engine, loop, PAPER, _params(loop, "plant")),
                                  _run(engine, loop, PAPER))


def test_what_the_engine_cannot_follow_is_refused_by_name():
    loop = closed_loop(PAPER)
    t = np.linspace(0.0, 0.1, 5)
    x0 = initial_state(loop, PAPER)
    controller = _params(loop, "controller")["controller"]
    with pytest.raises(ValueError, match=r"names block 'ctrl', which is not a block with kernels of this diagram"):
        advance(make_engine("fast", loop, "RK45"), Context(0.0, x0, params={"ctrl": controller}), t, Solver())
    full_gain = (controller[0], np.diag(controller[1]), controller[2])          # a matrix where a diagonal was
    with pytest.raises(ValueError, match=r"Context.params\['controller'\] has another structure"):
        advance(make_engine("fast", loop, "RK45"), Context(0.0, x0, params={"controller": full_gain}), t, Solver())
    nan_gain = (controller[0], np.full_like(controller[1], np.nan), controller[2])
    with pytest.raises(ValueError, match=r"Context.params\['controller'\] holds 4 number\(s\) that are not finite"):
        advance(make_engine("fast", loop, "RK45"), Context(0.0, x0, params={"controller": nan_gain}), t, Solver())
    with pytest.raises(ValueError, match="python-control engine runs the blocks' own functions"):
        advance(make_engine("python-control", loop, "RK45"), Context(0.0, x0, params={"controller": controller}),
                t, Solver())
