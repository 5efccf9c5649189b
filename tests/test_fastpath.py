"""The numpy engine (CompiledLoop over the loop's plan) gives the numbers of control.input_output_response."""
from __future__ import annotations

import control as ct
import numpy as np
import pytest

import blocks
from blocks.diagram.contract import Block, BlockContract, ContractError, contract_of
from blocks.engines.fastsim import AlgebraicLoopError, CompiledLoop

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


def test_a_declared_feedthrough_cycle_is_reported():
    through = BlockContract(feedthrough={"u"})
    a = Block(None, lambda t, x, u, p: u, inputs=["u"], outputs=["y"], name="a", contract=through)
    b = Block(None, lambda t, x, u, p: u, inputs=["y"], outputs=["u"], name="b",
              contract=BlockContract(feedthrough={"y"}))
    with pytest.raises(AlgebraicLoopError, match="a -> b -> a|b -> a -> b"):
        CompiledLoop(ct.interconnect([a, b], inplist=[], outlist=["y"], check_unused=False))


def test_blocks_without_declared_feedthrough_are_evaluated_to_a_fixed_point_as_python_control_does():
    """No contract: feedthrough unknown.  A cycle that is not a real algebraic loop (the integrator's output is its
    state) is then iterated to a fixed point, giving python-control's numbers; one that does not settle is refused."""
    gain = ct.nlsys(None, lambda t, x, u, p: -2.0 * u, inputs=["e"], outputs=["v"], name="gain")
    integ = ct.nlsys(lambda t, x, u, p: u, lambda t, x, u, p: x, inputs=["v"], outputs=["e"], states=1, name="integ")
    loop = ct.interconnect([gain, integ], inplist=[], outlist=["e", "v"])
    compiled = CompiledLoop(loop)
    assert compiled.plan.fixed_point
    x = np.array([0.7])
    np.testing.assert_array_equal(compiled.rhs(0.0, x), loop.dynamics(0.0, x, []))
    np.testing.assert_array_equal(compiled.output(0.0, x), loop.output(0.0, x, []))
    grows = ct.nlsys(None, lambda t, x, u, p: u + 1.0, inputs=["u"], outputs=["y"], name="a")
    back = ct.nlsys(None, lambda t, x, u, p: u, inputs=["y"], outputs=["u"], name="b")
    never = CompiledLoop(ct.interconnect([grows, back], inplist=[], outlist=["y"], check_unused=False))
    with pytest.raises(AlgebraicLoopError, match="did not settle"):
        never.output(0.0, np.zeros(0))


def test_outputs_on_grid_equal_the_point_by_point_outputs():
    """One pass per block over a grid gives each point's outputs (every built-in block, every variant)."""
    rng = np.random.default_rng(5)
    for scenario, observer in _scenarios().values():
        loop = blocks.closed_loop(scenario, observer=observer)
        compiled = CompiledLoop(loop)
        assert all(compiled.plan.takes_columns)
        x0 = blocks.initial_state(loop, scenario)
        t = np.array([0.0, 0.013, 0.05, 0.1])
        X = x0[:, None] + 0.01 * rng.standard_normal((x0.size, t.size))
        want = np.column_stack([loop.output(tk, X[:, k], []) for k, tk in enumerate(t)])
        np.testing.assert_allclose(compiled.outputs_on_grid(t, X), want, rtol=1e-12, atol=1e-12)


def test_outputs_on_grid_falls_back_to_points_for_a_block_without_columns():
    s = blocks.load_scenario("paper")
    pcl = blocks.closed_loop(s)
    # the same observer without kernels: its python-control functions take one point at a time
    parts = [Block(b.updfcn, b.outfcn, inputs=b.input_labels, outputs=b.output_labels, states=b.state_labels,
                   name=b.name, contract=BlockContract(feedthrough=contract_of(b).feedthrough))
             if b.name == "observer" else b for b in pcl.syslist]
    loop = ct.interconnect(parts, inplist=[], outlist=list(pcl.output_labels))
    compiled = CompiledLoop(loop)
    assert compiled.plan.takes_columns == [name != "observer" for name in compiled.order]
    x0 = blocks.initial_state(loop, s)
    t = np.array([0.0, 0.2])
    X = np.column_stack([x0, x0 + 0.01])
    want = np.column_stack([loop.output(tk, X[:, k], []) for k, tk in enumerate(t)])
    np.testing.assert_allclose(compiled.outputs_on_grid(t, X), want, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="shape"):
        compiled.outputs_on_grid(t, X[:, :1])


def test_right_hand_side_reads_the_plant_states_instead_of_calling_its_output():
    """The plant's q, dq are declared copies of its states, so a right-hand side never calls its output."""
    s = blocks.load_scenario("paper").replace(disturbance={"kind": ["paper", "friction", "tissue"]})
    pcl = blocks.closed_loop(s)
    plant = next(b for b in pcl.syslist if b.name == "plant")
    kernels, calls = contract_of(plant).kernels, []
    counted = type(kernels)(kernels.params, lambda *args: calls.append(args) or kernels.output(*args), kernels.update)
    plant = Block(plant.updfcn, lambda t, x, u, p: counted.output(t, x, u, *counted.params), name="plant",
                  inputs=plant.input_labels, outputs=plant.output_labels, states=plant.state_labels,
                  contract=BlockContract(feedthrough=frozenset(), kernels=counted,
                                         state_outputs=contract_of(pcl.syslist[2]).state_outputs))
    loop = ct.interconnect([plant if b.name == "plant" else b for b in pcl.syslist], inplist=[],
                           outlist=list(pcl.output_labels))
    compiled = CompiledLoop(loop)
    assert "plant" not in compiled.rhs_order and "plant" in compiled.order
    calls.clear()                                   # the declaration was checked once at construction
    rng = np.random.default_rng(8)
    x0 = blocks.initial_state(loop, s)
    xs = [x0 + 0.01 * rng.standard_normal(x0.size) for _ in range(2)]
    fast = [compiled.rhs(t, x) for t, x in zip((0.0, 1.7), xs)]
    assert not calls
    for t, x, got in zip((0.0, 1.7), xs, fast):
        np.testing.assert_allclose(got, loop.dynamics(t, x, []), rtol=1e-12, atol=1e-12)
    assert calls, "python-control evaluates the plant output"


def test_a_wrong_state_output_declaration_is_refused():
    s = blocks.load_scenario("paper")
    pcl = blocks.closed_loop(s)
    plant = next(b for b in pcl.syslist if b.name == "plant")
    k = contract_of(plant).kernels

    def remade(pairs):
        return Block(plant.updfcn, plant.outfcn, name="plant", inputs=plant.input_labels, outputs=plant.output_labels,
                     states=plant.state_labels, contract=BlockContract(feedthrough=frozenset(), kernels=k,
                                                                       state_outputs=pairs))
    wrong = remade({"q[0]": "q[1]"})          # names real signals, but q[0] is not the state q[1]
    loop = ct.interconnect([wrong if b.name == "plant" else b for b in pcl.syslist], inplist=[],
                           outlist=list(pcl.output_labels))
    with pytest.raises(ValueError, match="plant.*does not return the states"):
        CompiledLoop(loop)
    with pytest.raises(ContractError, match="plant.*'theta'.*does not have"):
        remade({"q[0]": "theta"})
    with pytest.raises(ContractError, match="feedthrough names \\['v'\\]"):
        Block(None, lambda t, x, u, p: u, inputs=["u"], outputs=["y"], name="g",
              contract=BlockContract(feedthrough={"v"}))


def test_call_time_params_are_honoured_as_python_control_honours_them():
    gain = ct.nlsys(None, lambda t, x, u, p: -p["a"] * u, inputs="e", outputs="v", name="gain", params={"a": 1.0})
    integ = Block(lambda t, x, u, p: u, lambda t, x, u, p: x, inputs="v", outputs="e", states="x", name="integ",
                  contract=BlockContract(feedthrough=frozenset(), state_outputs={"e": "x"}))
    loop = ct.interconnect([gain, integ], inplist=[], outlist=["e"])
    x = np.array([1.0])
    for params in (None, {"a": 5.0}, {"a": -2.0}, None):
        want = loop.dynamics(0.0, x, [], params)
        assert CompiledLoop(loop).rhs(0.0, x, params=params) == pytest.approx(want)
        assert CompiledLoop(loop, params=params).rhs(0.0, x) == pytest.approx(want)
    assert CompiledLoop(loop).rhs(0.0, x, params={"a": 5.0})[0] == -5.0


def test_every_built_in_block_declares_a_contract_and_kernels():
    s = blocks.load_scenario("paper").replace(noise={"q_std": [1e-4] * 4, "seed": 1})
    for block in blocks.closed_loop(s).syslist:
        contract = contract_of(block)
        assert contract is block.contract and isinstance(block, Block)
        assert contract.takes_columns
        if block.name != "trajectory":
            assert contract.kernels is not None, block.name


def test_a_block_update_returning_a_column_is_accepted_like_python_control_does():
    lag = ct.nlsys(lambda t, x, u, p: (u - x).reshape(-1, 1), lambda t, x, u, p: x, inputs=["u"], outputs=["y"],
                   states=["x"], name="lag")
    src = ct.nlsys(None, lambda t, x, u, p: np.array([np.sin(t)]), inputs=0, outputs=["u"], name="src")
    loop = ct.interconnect([src, lag], inplist=[], outlist=["y"])
    compiled = CompiledLoop(loop)
    np.testing.assert_array_equal(compiled.rhs(0.7, np.array([0.2])), loop.dynamics(0.7, np.array([0.2]), []))


def test_rhs_order_names_each_block_even_when_blocks_share_a_function():
    def same(t, x, u, p):
        return u
    a = ct.nlsys(None, same, inputs=["x"], outputs=["y"], name="a")
    b = ct.nlsys(None, same, inputs=["y"], outputs=["w"], name="b")
    integ = Block(lambda t, x, u, p: u, lambda t, x, u, p: x, inputs=["w"], outputs=["x"], states=1, name="integ",
                  contract=BlockContract(feedthrough=frozenset()))       # its output is its state
    compiled = CompiledLoop(ct.interconnect([a, b, integ], inplist=[], outlist=["x"]))
    assert compiled.rhs_order == ["integ", "a", "b"]


def test_a_trajectory_without_stacked_evaluation_is_simulated_point_by_point():
    """A user trajectory that only knows scalar times: the grid pass falls back to one point at a time."""
    class Hold:
        def __init__(self, q):
            self.q = np.asarray(q, dtype=float)

        def evaluate(self, t):
            if np.ndim(t):
                raise TypeError("one time at a time")
            return self.q.copy(), np.zeros(4), np.zeros(4)
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 0.2})
    start = s.trajectory.evaluate(0.0)[0]
    block = blocks.trajectory_block(Hold(start))
    assert not contract_of(block).takes_columns
    pcl = blocks.closed_loop(s)
    parts = [block if b.name == "trajectory" else b for b in pcl.syslist]
    loop = ct.interconnect(parts, inplist=[], outlist=list(pcl.output_labels))
    compiled = CompiledLoop(loop)
    assert compiled.plan.takes_columns == [name != "trajectory" for name in compiled.order]
    t = np.array([0.0, 0.1])
    X = np.column_stack([blocks.initial_state(pcl, s)] * 2)
    want = np.column_stack([loop.output(tk, X[:, k], []) for k, tk in enumerate(t)])
    np.testing.assert_array_equal(compiled.outputs_on_grid(t, X), want)


def test_a_block_output_returning_a_column_is_accepted_like_python_control_does():
    src = ct.nlsys(None, lambda t, x, u, p: np.array([[np.sin(t)], [np.cos(t)]]), inputs=0, outputs=["a", "b"],
                   name="src")
    integ = Block(lambda t, x, u, p: u - x, lambda t, x, u, p: x.reshape(-1, 1), inputs=["a", "b"],
                  outputs=["ya", "yb"], states=2, name="integ", contract=BlockContract(feedthrough=frozenset()))
    loop = ct.interconnect([src, integ], inplist=[], outlist=["ya", "yb", "a"])
    compiled = CompiledLoop(loop)
    x = np.array([0.2, 0.3])
    np.testing.assert_array_equal(compiled.rhs(0.4, x), loop.dynamics(0.4, x, []))
    np.testing.assert_array_equal(compiled.output(0.4, x), loop.output(0.4, x, []))


def _float_rhs_cases():
    cases = dict(_scenarios())
    cases["full observer gain"] = (cases["paper"][0].replace(
        gains={"observer": [[12.0, 1.0, 0, 0], [1.0, 9.0, 0, 0], [0, 0, 10.0, 0], [0, 0, 0, 10.0]]}), True)
    cases["joint sine"] = (blocks.load_scenario("joint-sine"), True)
    return cases


@pytest.mark.parametrize("name", list(_float_rhs_cases()))
def test_the_generated_float_right_hand_side_equals_the_numpy_plan_bit_for_bit(name):
    """What the fast engine integrates (the plan traced into statements on floats) is the kernels' arithmetic."""
    scenario, observer = _float_rhs_cases()[name]
    loop = blocks.closed_loop(scenario, observer=observer)
    compiled = CompiledLoop(loop)
    assert compiled.generated
    rng = np.random.default_rng(7)
    x0 = blocks.initial_state(loop, scenario)
    for _ in range(50):
        t, x = float(rng.uniform(0.0, 1.0)), x0 + 0.05 * rng.standard_normal(x0.size)
        np.testing.assert_array_equal(compiled.point_rhs(t, x), compiled.rhs(t, x))


def test_the_float_right_hand_side_gives_numpy_results_where_float_arithmetic_raises():
    """cos(inf) raises in Python and is nan in numpy; the call is then made by the numpy plan, nan and all."""
    s = blocks.load_scenario("paper")
    loop = blocks.closed_loop(s)
    compiled = CompiledLoop(loop)
    x = blocks.initial_state(loop, s).copy()
    x[1] = np.inf
    with np.errstate(all="ignore"):
        got, want = compiled.point_rhs(0.3, x), compiled.rhs(0.3, x)
    assert np.isnan(want).any()
    np.testing.assert_array_equal(got, want)


def test_a_loop_with_a_block_without_kernels_runs_the_numpy_plan():
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 0.1})
    plant = blocks.plant(s.robot, s.disturbance)
    users = Block(plant.updfcn, plant.outfcn, inputs=list(plant.input_labels), outputs=list(plant.output_labels),
                  states=list(plant.state_labels), name="plant", contract=BlockContract(feedthrough=frozenset()))
    compiled = CompiledLoop(blocks.closed_loop(s, plant=users))
    assert not compiled.generated
    x = blocks.initial_state(blocks.closed_loop(s), s)
    np.testing.assert_array_equal(compiled.point_rhs(0.05, x), compiled.rhs(0.05, x))
