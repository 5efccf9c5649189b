"""An arm's M(q) and h(q, q') as functions of a loop's generated module, called where needed (not inlined).

A trace whose graph asks for calls (``Graph(calls=True)``, as the compiled engine's does) records one call of the
arm's ``inertia`` or ``bias`` function per arm and state, however many kernels use it; the generated functions and
the code around them compute the numpy kernels' numbers (the same operations), for a chain and for a tree whose
inertia matrix has exact zeros (those stay constants in the caller).
"""
from __future__ import annotations

import types

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from blocks.engines.compiled.codegen import _callee_functions, _Function  # noqa: E402
from blocks.kernels import chain  # noqa: E402
from blocks.kernels.trace import Graph  # noqa: E402
from blocks.model.urdf import example_arm, example_urdf, load_urdf_arm  # noqa: E402


def _rows(graph, n, count):
    out = []
    for r in range(count):
        row = np.empty(n, dtype=object)
        for i in range(n):
            row[i] = graph.leaf("x", r * n + i)
        out.append(row)
    return out


def _generated(arm, kernel, count: int, calls: bool = True):
    """``kernel(k, *rows)`` traced (calls or inlined) and emitted as Python: ``f(x) -> list`` and the graph."""
    graph = Graph(calls=calls)
    result = np.asarray(kernel(arm.kernel_params(), *_rows(graph, arm.n, count)), dtype=object).ravel()
    fn = _Function(None, "traced", "x, out")
    for i, v in enumerate(result):
        fn.assign(f"out[{i}]", v)
    text = _callee_functions(types.SimpleNamespace(graph=graph)) + fn.text()
    namespace = {"np": np}
    exec(compile(text, "<test>", "exec"), namespace)

    def f(x):
        out = [0.0] * result.size
        namespace["traced"](list(x), out)
        return np.array(out)
    return f, graph, text


def _tree_panda():
    """The Panda with its two fingers kept: a tree (the fingers' rows of M are zero against each other)."""
    return load_urdf_arm(example_urdf("panda"), "panda_hand", mimic="independent")


@pytest.fixture(scope="module", params=["scope4", "panda", "panda with fingers"])
def arm(request):
    return _tree_panda() if request.param == "panda with fingers" else example_arm(request.param)


def test_one_call_per_arm_term_and_state(arm):
    graph = Graph(calls=True)
    k, n = arm.kernel_params(), arm.n
    q, dq, v, r = _rows(graph, n, 4)
    chain.mass_times(k, q, v)
    chain.bias_forces(k, q, dq)
    chain.mass_solve(k, q, r)
    chain.plant_acceleration(k, q, dq, r)
    calls = [node for node in graph.nodes.values() if node.op == "fcall"]
    assert sorted(c.args[0].rpartition("_")[0] for c in calls) == ["arm_bias", "arm_inertia"]
    assert set(graph.callees) == {c.args[0] for c in calls}
    # an inlined trace has no call, and the arm's CRBA and RNEA statements instead
    inline = Graph()
    chain.plant_acceleration(k, *_rows(inline, n, 3))
    assert not any(node.op == "fcall" for node in inline.nodes.values()) and not inline.callees


@pytest.mark.parametrize("kernel, count", [(chain.plant_acceleration, 3), (chain.mass_times, 2),
                                           (chain.mass_solve, 2), (chain.bias_forces, 2),
                                           (chain.gravity_forces, 1), (chain.inertia_matrix, 1)])
def test_called_dynamics_equal_the_numpy_kernels(arm, kernel, count):
    called, _, text = _generated(arm, kernel, count)
    inlined, _, _ = _generated(arm, kernel, count, calls=False)
    assert "def arm_" in text
    rng = np.random.default_rng(11)
    k, n = arm.kernel_params(), arm.n
    for _ in range(5):
        rows = [rng.uniform(-1.5, 1.5, n) for _ in range(count)]
        want = np.asarray(kernel(k, *rows), dtype=float).ravel()
        x = np.concatenate(rows)
        np.testing.assert_allclose(called(x), want, rtol=1e-13, atol=1e-13 * np.abs(want).max())
        np.testing.assert_array_equal(called(x), inlined(x))         # the same operations in the same order


def test_exact_zeros_of_a_tree_stay_constants():
    arm = _tree_panda()
    graph = Graph(calls=True)
    n = arm.n
    M = chain.inertia_matrix(arm.kernel_params(), *_rows(graph, n, 1))
    constants = [(i, j) for i in range(n) for j in range(i + 1) if isinstance(M[i, j], float)]
    assert any(M[i, j] == 0.0 for i, j in constants), "the two fingers' entries of M are exact zeros"
    (callee,) = graph.callees.values()
    text = _callee_functions(types.SimpleNamespace(graph=graph))
    returned = text.split("return (", 1)[1].split(")", 1)[0].rstrip(",").split(", ")
    assert len(returned) == n * (n + 1) // 2 - len(constants)
    assert callee.n_in == 2 * n - sum(1 for kind in arm.joints.kinds if kind == "prismatic")


@pytest.mark.parametrize("name", ["scope4", "panda"])
def test_a_loop_with_called_dynamics_computes_the_same_derivative(name, monkeypatch):
    """The whole generated loop with ``ARM_CALLS`` (its M and h functions in the module, called by the loop's
    functions), run by Python on floats (the ``fast`` engine's right-hand side): the derivative of the inlined loop,
    bit for bit, at random states; and half the generated lines or less."""
    from blocks import load_scenario
    from blocks.diagram.plan import make_plan
    from blocks.engines.compiled import codegen
    from blocks.engines.compiled.rows import loop_rows_of
    from blocks.engines.compiled.scalar import scalar_rhs
    from blocks.figure2.loop import closed_loop

    s = load_scenario(name)
    loop = closed_loop(s)
    plan = make_plan(loop)

    def unused(t, x):
        raise AssertionError("float arithmetic raised")

    monkeypatch.setenv("DOBKIT_FAST_C", "0")                           # the Python text, not its C
    monkeypatch.setattr(codegen, "ARM_CALLS", False)                     # the default is True: inlined first
    inlined = scalar_rhs(plan, loop, unused)
    lines_inlined = codegen.program_for(plan, loop, loop_rows_of(loop))[0].source.count("\n")
    monkeypatch.setattr(codegen, "ARM_CALLS", True)
    called = scalar_rhs(plan, loop, unused)
    program = codegen.program_for(plan, loop, loop_rows_of(loop))[0]
    assert program.source.count("def arm_inertia_") == 2 and program.source.count("def arm_bias_") == 2
    assert program.source.count("\n") < 0.7 * lines_inlined
    rng = np.random.default_rng(5)
    for _ in range(5):
        x = rng.uniform(-1.0, 1.0, plan.nstates)
        t = float(rng.uniform(0.0, 10.0))
        np.testing.assert_array_equal(called(t, x), inlined(t, x))
