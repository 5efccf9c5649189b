"""Folding single-use temporaries of generated straight-line code (blocks.engines.compiled.fold): the same floats to the last
bit, fewer statements; calls, subscripts, names read twice and code with blocks are left where they are."""
from __future__ import annotations

import ast
import math
import struct

import numpy as np
import pytest

from blocks.engines.compiled.fold import MAX_DEPTH, fold_single_use

# generated-style code whose grouping matters in floating point: subtraction and division are not associative,
# a unary minus binds tighter than ** on its right, and a temporary is read by a later call's tuple
SOURCE = '''def loop_rhs(t, x, theta, src, ext, work, dx):
    v0 = x[0]
    v1 = x[1]
    v2 = theta[0]
    v3 = v0 - v1
    v4 = v2 - v3
    v5 = v0 / v1
    v6 = v2 / v5
    v7 = -v6
    v8 = v7 ** 2.0
    v9 = v1 ** -v2
    v10 = v4 * v8
    v11 = v10 + v9
    v12 = -2.5 * v11
    v13 = v0 * v1
    v14 = v13 + v13
    v15 = np.sin(v12)
    v16 = v14 - v15
    v17 = f((v0, v16, v3 * 1.0,))
    v18 = v17[0]
    v19 = v18 + v16
    dx[0] = v19
    work[0] = v12


def other(x):
    return x
'''


def _bits(values) -> list:
    return [struct.pack("<d", float(v)) for v in values]


def _run(source: str, x, theta):
    namespace = {"np": math, "f": lambda a: [a[0] * a[1] - a[2]]}
    exec(compile(source, "<test>", "exec"), namespace)
    dx, work = [0.0], [0.0]
    namespace["loop_rhs"](0.0, x, theta, [], (), work, dx)
    return dx + work


def _statements(source: str, name: str) -> int:
    (fn,) = [n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == name]
    return len(fn.body)


def test_a_folded_function_computes_the_same_floats_to_the_last_bit():
    folded = fold_single_use(SOURCE, ["loop_rhs"])
    assert _statements(folded, "loop_rhs") < _statements(SOURCE, "loop_rhs") - 8
    assert "def other(x):\n    return x" in folded                       # the rest as it was
    rng = np.random.default_rng(7)
    for _ in range(300):
        x = (rng.uniform(0.5, 2.0) * 10.0 ** rng.integers(-3, 4), rng.uniform(0.5, 2.0) * 10.0 ** rng.integers(-3, 4))
        theta = (float(rng.uniform(-3.0, 3.0)),)
        assert _bits(_run(folded, list(x), theta)) == _bits(_run(SOURCE, list(x), theta))


def test_names_read_twice_calls_and_subscripts_stay_statements():
    folded = fold_single_use(SOURCE, ["loop_rhs"])
    text = folded.split("def other")[0]
    assert "v13 = v0 * v1" in text                  # read twice
    assert "v0 = x[0]" in text and "v18 = v17[0]" in text    # subscripts
    assert "v15 = np.sin(" in text and "v17 = f((" in text   # calls, in their order
    assert text.index("np.sin(") < text.index("f((")
    assert "v3 =" in text                           # read twice (in v4 and in the call's tuple)


def test_code_with_blocks_or_a_name_assigned_twice_is_left_as_it_is():
    branching = "def loop_rhs(x, dx):\n    v0 = x[0]\n    v1 = v0 * 2.0\n    if v1 > 0:\n        dx[0] = v1\n"
    assert fold_single_use(branching, ["loop_rhs"]) == branching
    twice = "def loop_rhs(x, dx):\n    v0 = x[0] * 2.0\n    v1 = v0 + 1.0\n    v0 = v1 * 3.0\n    dx[0] = v0\n"
    assert fold_single_use(twice, ["loop_rhs"]) == twice
    into_local = "def loop_rhs(x, dx):\n    v0 = [1.0]\n    v0[0] = x[0]\n    v1 = v0[0] * 2.0\n    dx[0] = v1\n"
    assert fold_single_use(into_local, ["loop_rhs"]) == into_local
    assert fold_single_use(SOURCE, ["absent"]) == SOURCE


def test_folded_expressions_are_at_most_max_depth_deep():
    """A chain of 500 additions (as a long sum of products is traced) folds into expressions CPython compiles."""
    lines = ["def loop_rhs(x, dx):", "    v0 = x[0]"]
    lines += [f"    v{i + 1} = v{i} + {0.1 * (i + 1)!r}" for i in range(500)]
    lines += ["    dx[0] = v500"]
    source = "\n".join(lines) + "\n"
    folded = fold_single_use(source, ["loop_rhs"])
    (fn,) = ast.parse(folded).body
    depths = [_depth(s.value) for s in fn.body if isinstance(s, ast.Assign)]
    assert max(depths) <= MAX_DEPTH and len(fn.body) < 30
    results = []
    for text in (source, folded):
        namespace = {}
        exec(compile(text, "<test>", "exec"), namespace)
        dx = [0.0]
        namespace["loop_rhs"]([0.3], dx)
        results.append(dx[0])
    assert results[0] == results[1] == pytest.approx(0.3 + 0.1 * 500 * 501 / 2, rel=1e-12)


def _depth(node) -> int:
    if isinstance(node, ast.BinOp):
        return 1 + max(_depth(node.left), _depth(node.right))
    if isinstance(node, ast.UnaryOp):
        return 1 + _depth(node.operand)
    return 0


@pytest.mark.parametrize("name", ["paper", "ur5"])
def test_the_fast_engines_folded_functions_equal_the_generated_ones_bit_for_bit(name):
    """The fast engine runs the folded loop functions (a third fewer statements or more); the program's own text,
    executed with the same bindings, gives the same derivative to the last bit (with pinocchio's algorithms on the
    URDF arm too)."""
    if name == "ur5":
        pytest.importorskip("pinocchio")
    from blocks import initial_state, load_scenario
    from blocks.engines.compiled import scalar
    from blocks.engines.compiled.codegen import program_for
    from blocks.engines.compiled.rows import loop_rows_of
    from blocks.engines.fastsim import CompiledLoop
    from blocks.figure2.loop import closed_loop

    s = load_scenario(name)
    loop = closed_loop(s)
    plan = CompiledLoop(loop).plan
    program, kernels = program_for(plan, loop, loop_rows_of(loop), scalar._calls_for(plan, loop))
    fns = scalar.ScalarFunctions.of(program)
    plain = dict(fns.rhs.__globals__)
    exec(compile(program.source, "<unfolded>", "exec"), plain)
    plain.update({callee: fns.rhs.__globals__[callee] for callee in fns.pinocchio_calls})   # pinocchio's again
    folded = fold_single_use(program.source, ["loop_rhs"])
    assert _statements(folded, "loop_rhs") < 0.75 * _statements(program.source, "loop_rhs")
    assert fns.rhs.__code__.co_code != plain["loop_rhs"].__code__.co_code
    theta = tuple(program.numbers(kernels)[0].tolist())
    ext = program.numbers(kernels)[1]
    rng = np.random.default_rng(3)
    x0 = initial_state(loop, s)
    for _ in range(5):
        x = (x0 + 0.05 * rng.standard_normal(x0.size)).tolist()
        t = float(rng.uniform(0.0, 2.0))
        out = []
        for sources, rhs in ((fns.sources, fns.rhs), (plain["loop_sources"], plain["loop_rhs"])):
            work, src, dx = np.zeros(program.n_work), [0.0] * program.n_src, [0.0] * len(x)
            sources(t, theta, ext, work, src)
            rhs(t, x, theta, src, ext, work, dx)
            out.append(dx)
        assert _bits(out[0]) == _bits(out[1])
