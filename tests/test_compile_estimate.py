"""Big arms compile in seconds: a chain arm's M and h are functions of the generated module (called, not inlined),
``engine="auto"`` compiles a loop whose estimated compile time is within its budget -- every built-in scenario and
the Panda, not the Panda inlined -- and the paper's RRPR code is the same either way."""
from __future__ import annotations

import pytest

from blocks import load_scenario
from blocks.diagram.plan import make_plan
from blocks.engines.compiled import codegen
from blocks.engines.compiled.compile_estimate import (
    AUTO_COMPILE_SECONDS,
    COMPILE_FIXED_S,
    COMPILE_PER_LINE_S,
    estimate_compile_seconds,
)
from blocks.engines.compiled.rows import loop_rows_of
from blocks.figure2.loop import closed_loop


def _source(name: str, calls: bool, monkeypatch) -> str:
    monkeypatch.setattr(codegen, "ARM_CALLS", calls)
    loop = closed_loop(load_scenario(name))
    return codegen.program_for(make_plan(loop), loop, loop_rows_of(loop))[0].source


def test_the_estimate_is_linear_in_the_lines():
    assert estimate_compile_seconds(0) == COMPILE_FIXED_S
    assert estimate_compile_seconds(1000) - estimate_compile_seconds(0) == pytest.approx(1000 * COMPILE_PER_LINE_S)


def test_the_paper_loop_is_the_same_code_with_calls_on_or_off(monkeypatch):
    """The RRPR's kernels are closed form (no chain arm): calling M and h changes nothing in its generated text, and
    its structure key is what it was before calls were the default (no marker)."""
    on = _source("paper", True, monkeypatch)
    off = _source("paper", False, monkeypatch)
    assert on == off and "def arm_" not in on
    monkeypatch.setattr(codegen, "ARM_CALLS", True)
    loop = closed_loop(load_scenario("paper"))
    plan = make_plan(loop)
    structure = codegen.structure_of(plan, codegen.block_kernels(plan, loop), list(loop.output_labels),
                                     loop_rows_of(loop))
    assert "inlined" not in structure and "called" not in structure


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_auto_compiles_the_big_arms_called_and_not_inlined(name, monkeypatch):
    """The budget at both sides with real loops: the arm's loop with M and h called is within it, the same loop
    inlined (what 'auto' refused before, 6,000+ lines) over it for the Panda; calls at most 2/3 of the lines."""
    called = _source(name, True, monkeypatch)
    inlined = _source(name, False, monkeypatch)
    lines_called, lines_inlined = called.count("\n") + 1, inlined.count("\n") + 1
    assert called.count("def arm_inertia_") == 2 and "def arm_" not in inlined
    assert lines_called < 2 / 3 * lines_inlined
    assert estimate_compile_seconds(lines_called) <= AUTO_COMPILE_SECONDS
    if name == "panda":
        assert estimate_compile_seconds(lines_inlined) > AUTO_COMPILE_SECONDS


@pytest.mark.parametrize("name", ["scope4", "scope4-path", "surgical", "ur5", "panda", "paper"])
def test_every_built_in_scenario_is_within_the_budget(name, monkeypatch):
    source = _source(name, codegen.ARM_CALLS, monkeypatch)
    assert estimate_compile_seconds(source.count("\n") + 1) <= AUTO_COMPILE_SECONDS


def test_every_example_arm_is_within_the_budget():
    """`dobkit arms`' arms in their default scenario: 'auto' compiles each (the 7-joint arms are the longest)."""
    pytest.importorskip("pinocchio")
    from blocks.model.urdf.examples import example_names
    from blocks.scenarios.scenario import scenario_from_dict

    longest = 0
    for name in example_names():
        loop = closed_loop(scenario_from_dict({"arm": {"urdf": f"example:{name}"}}))
        source = codegen.program_for(make_plan(loop), loop, loop_rows_of(loop))[0].source
        longest = max(longest, source.count("\n") + 1)
    assert 3000 < longest and estimate_compile_seconds(longest) <= AUTO_COMPILE_SECONDS


@pytest.mark.slow
def test_the_compiled_panda_with_called_dynamics_equals_the_numpy_engine():
    """The one compile of a big arm here (about 13 s of CPU with a fresh cache): the Panda's loop, its M and h
    generated once and called, run by numba, against the numpy engine (pinocchio's ABA, RNEA and CRBA for the same
    kernels, itself checked against an independent pinocchio + scipy loop in tests/test_arm_loop.py)."""
    pytest.importorskip("numba")
    pytest.importorskip("pinocchio")
    import numpy as np

    import blocks
    from blocks.figure2.metrics import signal

    s = load_scenario("panda").with_changes({"simulation.t_final": 1.0, "simulation.rtol": 1e-10,
                                             "simulation.atol": 1e-12})
    compiled = blocks.simulate(s, engine="compiled")
    fast = blocks.simulate(s, engine="fast")
    assert compiled.engine == "compiled" and fast.engine == "fast"
    np.testing.assert_allclose(signal(compiled, "q"), signal(fast, "q"), rtol=0, atol=1e-8)
    assert np.ptp(signal(compiled, "q")) > 0.1                     # the arm moves


def test_a_called_function_whose_outputs_are_all_constants_is_valid_code():
    """A one-joint arm's gravity about a vertical axis is exactly zero: its generated function returns nothing (an
    empty tuple; the caller reads the constant), and the module's text compiles (it was ``return (,)``)."""
    import types

    from blocks.kernels.trace import Callee, Graph

    graph = Graph(calls=True)
    out = graph.call(Callee("arm_gravity_zero", 1, lambda x: [0.0 * 1.0]), [graph.leaf("x", 0)])
    assert out == [0.0]
    text = codegen._callee_functions(types.SimpleNamespace(graph=graph))
    namespace = {}
    exec(compile(text, "<callees>", "exec"), namespace)
    assert namespace["arm_gravity_zero"]((0.3,)) == ()


@pytest.mark.parametrize("name, inlined", [("paper", True), ("ur5", False)])
def test_a_small_programs_sources_and_outputs_are_inlined_into_the_drivers_a_big_ones_are_called(name, inlined):
    """``SMALL_PROGRAM_LINES`` on both sides: the paper's loop (1,132 lines) has its sources and outputs inlined into
    the integrators' drivers (its short run pays for the calls); the UR5's (5,114) calls them (inlined they cost its
    compile in proportion to their size); the integrators' own helpers are inlined in both."""
    pytest.importorskip("numba")
    if name == "ur5":
        pytest.importorskip("pinocchio")
    loop = closed_loop(load_scenario(name))
    program = codegen.program_for(make_plan(loop), loop, loop_rows_of(loop))[0]
    lines = program.source.count("\n")
    assert (lines <= codegen.SMALL_PROGRAM_LINES) == inlined
    module, _ = codegen.load_module(program)
    for fn in module.INLINE_WHEN_SMALL:
        assert (getattr(module, fn).targetoptions.get("inline") == "always") == inlined, fn
    assert module.dp_step.targetoptions.get("inline") == "always"
