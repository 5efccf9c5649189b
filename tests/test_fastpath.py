"""The fast simulation path gives the numbers of control.input_output_response on the same interconnected system."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import control as ct
import numpy as np
import pytest

from dobkit import blocks
from dobkit.blocks.fastsim import AlgebraicLoopError, CompiledLoop

SHORT = {"t_final": 1.0}


def _scenarios():
    paper = blocks.load_scenario("paper").replace(simulation=SHORT, trajectory={"duration": 10.0})
    return {
        "paper": (paper, True),
        "paper without observer": (paper, False),
        "model mismatch, Eq. 16 as printed": (paper.replace(nominal_scale={"m1": 0.8, "I2": 1.3},
                                                            observer={"variant": "paper-eq16"}), True),
        "friction and tissue": (paper.replace(disturbance={"kind": ["paper", "friction", "tissue"]}), True),
        "measurement noise": (paper.replace(simulation={"t_final": 0.1},
                                            noise={"q_std": [1e-4] * 4, "dq_std": [1e-3] * 4, "seed": 4}), True),
    }


@pytest.mark.parametrize("name", list(_scenarios()))
def test_fast_path_equals_input_output_response(name):
    scenario, observer = _scenarios()[name]
    fast = blocks.simulate(scenario, observer=observer, engine="fast")
    ref = blocks.simulate(scenario, observer=observer, engine="python-control")
    sim = scenario.simulation
    assert list(fast.output_labels) == list(ref.output_labels)
    np.testing.assert_array_equal(fast.time, ref.time)
    # to the solver tolerance: the solver's own error bound on states, scaled to each signal's size for outputs
    np.testing.assert_allclose(fast.states, ref.states, rtol=sim.rtol, atol=sim.atol)
    scale = np.max(np.abs(ref.outputs), axis=1, keepdims=True) + 1.0
    np.testing.assert_allclose(fast.outputs / scale, ref.outputs / scale, rtol=0, atol=sim.rtol)


def test_compiled_loop_outputs_equal_the_interconnection_outputs():
    s = blocks.load_scenario("paper")
    loop = blocks.closed_loop(s)
    compiled = CompiledLoop(loop)
    rng = np.random.default_rng(3)
    x0 = blocks.initial_state(loop, s)
    for t in (0.0, 0.37, 4.2):
        x = x0 + 0.01 * rng.standard_normal(x0.size)
        np.testing.assert_allclose(compiled.output(t, x), loop.output(t, x, []), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(compiled.rhs(t, x), loop.dynamics(t, x, []), rtol=1e-12, atol=1e-12)


def test_block_order_follows_the_signal_flow():
    loop = blocks.closed_loop(blocks.load_scenario("paper"))
    order = CompiledLoop(loop).order
    # the controller needs the reference, the measured state and d_hat, which needs the plant's dq
    assert order.index("controller") > max(order.index("trajectory"), order.index("plant"), order.index("observer"))
    assert order.index("observer") > order.index("plant")


def test_a_feedthrough_cycle_is_reported():
    a = ct.nlsys(None, lambda t, x, u, p: u, inputs=["u"], outputs=["y"], name="a")
    b = ct.nlsys(None, lambda t, x, u, p: u, inputs=["y"], outputs=["u"], name="b")
    with pytest.raises(AlgebraicLoopError, match="a -> b -> a|b -> a -> b"):
        CompiledLoop(ct.interconnect([a, b], inplist=[], outlist=["y"], check_unused=False))


def test_fast_path_equals_a_hand_fused_loop():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_fastpath.py"
    spec = importlib.util.spec_from_file_location("bench_fastpath", path)
    module = importlib.util.module_from_spec(spec)
    import sys
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(path.parent))
    s = blocks.load_scenario("paper").replace(simulation=SHORT, trajectory={"duration": 10.0})
    fused = module.hand_fused(s)
    fast = blocks.simulate(s)
    labels = list(fast.output_labels)
    for name in ("q", "dq", "tau", "d_hat", "tau_dis", "d"):
        got = np.asarray(fast.outputs)[[labels.index(f"{name}[{i}]") for i in range(4)]].T
        np.testing.assert_allclose(got, fused[name], rtol=1e-9, atol=1e-9, err_msg=name)


def test_proposed_loop_plan_and_grid_outputs_reproduce_the_fast_path():
    """benchmarks/proposed/ (a candidate CompiledLoop) gives the current class's numbers."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from proposed.fastsim import PlannedLoop
        from proposed.grid_outputs import GridLoop, attach_column_outputs
    finally:
        sys.path.pop(0)
    for scenario, observer in _scenarios().values():
        loop = blocks.closed_loop(scenario, observer=observer)
        x0 = blocks.initial_state(loop, scenario)
        current, planned = CompiledLoop(loop), PlannedLoop(loop)
        attach_column_outputs(loop)
        grid = GridLoop(loop)
        rng = np.random.default_rng(5)
        t = np.array([0.0, 0.05, 0.1])
        X = x0[:, None] + 0.01 * rng.standard_normal((x0.size, t.size))
        for k, tk in enumerate(t):
            np.testing.assert_array_equal(planned.rhs(tk, X[:, k]), current.rhs(tk, X[:, k]))
            np.testing.assert_array_equal(planned.output(tk, X[:, k]), current.output(tk, X[:, k]))
        want = np.column_stack([current.output(tk, X[:, k]) for k, tk in enumerate(t)])
        np.testing.assert_allclose(grid.outputs_on_grid(t, X), want, rtol=1e-12, atol=1e-12)
