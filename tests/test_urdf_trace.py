"""A chain arm's kernels traced into straight-line code: geometry frozen as constants, numba equals numpy."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")



from blocks.engines.compiled.arm_trace import trace_rows  # noqa: E402
from blocks.kernels import chain  # noqa: E402
from blocks.kernels.trace import Frozen, Graph, param_structure, param_values, symbolic_params  # noqa: E402
from blocks.model.urdf import example_arm  # noqa: E402


@pytest.fixture(scope="module")
def scope4():
    return example_arm("scope4")


def test_frozen_parameters_are_structure(scope4):
    k = scope4.kernel_params()
    assert isinstance(k, Frozen)
    graph, values = Graph(), []
    params = (k, np.array([2.0, 3.0]))
    sym = symbolic_params(graph, params, values)
    assert sym[0] is k and values == [2.0, 3.0]               # no symbol read from the geometry
    assert param_values(params, []) == [2.0, 3.0]
    # the code is specialised on the geometry: a different mass gives a different structure, an equal one the same
    import dataclasses
    heavier = dataclasses.replace(k, masses=(k.masses[0] * 2,) + k.masses[1:])
    same = dataclasses.replace(k)
    assert param_structure(heavier) != param_structure(k)
    assert param_structure(same) == param_structure(k)
    assert param_structure(k).startswith("ChainParams#")


def test_traced_geometry_is_constants(scope4):
    """Only the 12 inputs are leaves; the arm's numbers appear as literals, and no product with a zero is left."""
    traced = trace_rows(chain.plant_acceleration, scope4.kernel_params(), 4, 4, 4)
    assert "theta" not in traced.source
    for line in (s for s in traced.source.splitlines() if " = " in s):
        operands = line.split(" = ", 1)[1].split(" * ")
        if len(operands) == 2:
            for literal in operands:
                assert literal.strip("()") not in ("0.0", "-0.0", "1.0", "-1.0"), line
    assert traced.n_inputs == 12 and traced.n_outputs == 4


def _states(arm, count, seed):
    rng = np.random.default_rng(seed)
    lo, hi = np.array(arm.joints.limits).T
    return [np.concatenate([rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3)), rng.uniform(-2, 2, arm.n),
                            rng.uniform(-5, 5, arm.n)]) for _ in range(count)]


@pytest.mark.slow
def test_numba_compiled_trace_equals_the_numpy_kernel(scope4):
    pytest.importorskip("numba")
    n = scope4.n
    fn = trace_rows(chain.plant_acceleration, scope4.kernel_params(), n, n, n).numba()
    out = np.empty(n)
    for x in _states(scope4, 20, 1):
        fn(x, out)
        ref = scope4.forward_dynamics(x[:n], x[n:2 * n], x[2 * n:])
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name,kernel,rows", [("panda", chain.plant_acceleration, 3), ("panda", chain.inertia_matrix, 1),
                                              ("ur5", chain.bias_forces, 2), ("scope4", chain.tool_acceleration_bias, 2)])
def test_traced_code_equals_the_numpy_kernel(name, kernel, rows):
    arm = example_arm(name)
    n, k = arm.n, arm.kernel_params()
    fn = trace_rows(kernel, k, *([n] * rows)).python()
    for x in _states(arm, 5, 2):
        args = [x[i * n:(i + 1) * n] for i in range(rows)]
        ref = np.asarray(kernel(k, *args)).ravel()
        out = np.empty(ref.size)
        fn(x, out)
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_constant_folding_in_a_trace_is_the_arithmetic():
    """tr-fold-minus.  Two constants combine into the constant the arithmetic gives: 5 - 2 = 3, 2 - 5 = -3,
    5 / 2 = 2.5, 5 + 2 = 7, 5 * 2 = 10 (a traced kernel with a literal expression relies on it)."""
    from blocks.kernels.trace import Graph

    g = Graph()
    five, two = g.const(5.0), g.const(2.0)
    for expr, value in ((five - two, 3.0), (two - five, -3.0), (five / two, 2.5), (five + two, 7.0),
                        (five * two, 10.0), (7.0 - two, 5.0), (two - 7.0, -5.0)):
        assert expr.op == "const" and expr.args[0] == value
