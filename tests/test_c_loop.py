"""The fast engine's right-hand side of a chain arm's loop in C (blocks.engines.compiled.c_loop).

The C is written from the loop's generated Python text; the references here are that text run by Python on floats
(the fast engine's right-hand side before C), the numpy plan (the chain kernels on arrays) and the run with the C
switched off (pinocchio's algorithms bound to the text's calls).
"""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from blocks import initial_state, load_scenario, simulate
from blocks.engines.compiled import c_loop
from blocks.engines.compiled.codegen import program_for
from blocks.engines.compiled.rows import loop_rows_of
from blocks.engines.compiled.scalar import ScalarFunctions
from blocks.engines.fastsim import CompiledLoop
from blocks.figure2.loop import closed_loop
from blocks.figure2.metrics import signal

pytestmark = pytest.mark.needs_cc


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty compiled-code cache folder, and no library loaded in this process."""
    monkeypatch.setenv("DOBKIT_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(c_loop, "_libraries", {})
    monkeypatch.setattr(c_loop, "_failures", set())
    return tmp_path / "compiled"


def _loop(name: str):
    s = load_scenario(name)
    loop = closed_loop(s)
    compiled = CompiledLoop(loop)
    program, kernels = program_for(compiled.plan, loop, loop_rows_of(loop))
    return s, loop, compiled, program, kernels


@pytest.mark.parametrize("name", ["scope4", "ur5", "panda"])
def test_the_c_right_hand_side_is_the_generated_text_bit_for_bit(name):
    """At states and times around the run's start (and far from it), the library's derivative equals the loop's
    generated Python run by Python on floats, to the last bit."""
    pytest.importorskip("pinocchio")
    s, loop, compiled, program, kernels = _loop(name)
    theta, ext = program.numbers(kernels)
    c = c_loop.CLoop(program, theta, compiled.nstates)
    fns = ScalarFunctions.of(program)
    theta_floats = tuple(theta.tolist())
    work = np.zeros(program.n_work)
    rng = np.random.default_rng(5)
    x0 = initial_state(loop, s)
    for scale in (0.05, 0.05, 0.05, 2.0, 2.0):
        x = x0 + scale * rng.standard_normal(x0.size)
        t = float(rng.uniform(0.0, 10.0))
        src, dx = [0.0] * program.n_src, [0.0] * compiled.nstates
        fns.sources(t, theta_floats, ext, work, src)
        fns.rhs(t, x.tolist(), theta_floats, src, ext, work, dx)
        np.testing.assert_array_equal(c.rhs(t, x), np.array(dx))
        y = [0.0] * program.n_out
        fns.outputs(t, x.tolist(), theta_floats, src, ext, work, y)
        np.testing.assert_array_equal(c.outputs(t, x), np.array(y))


def test_the_fast_engine_runs_a_chain_arm_in_c_and_equals_its_run_without_c(monkeypatch):
    """``engine="fast"`` on the UR5: the right-hand side is the library's, the numpy plan's derivative to rounding,
    and the run equals the run with the C switched off (pinocchio bound to the text's calls) to 1e-9 rad."""
    pytest.importorskip("pinocchio")
    s = load_scenario("ur5").replace(simulation={"t_final": 1.0})
    loop = closed_loop(s)
    compiled = CompiledLoop(loop)
    assert isinstance(getattr(compiled.point_rhs, "__self__", None), c_loop.CLoop)
    x0 = initial_state(loop, s)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = x0 + 0.1 * rng.standard_normal(x0.size)
        np.testing.assert_allclose(compiled.point_rhs(0.7, x), compiled.rhs(0.7, x), rtol=1e-11, atol=1e-11)
    with_c = signal(simulate(s, engine="fast"), "q")
    monkeypatch.setenv("DOBKIT_FAST_C", "0")
    assert not isinstance(getattr(CompiledLoop(closed_loop(s)).point_rhs, "__self__", None), c_loop.CLoop)
    without_c = signal(simulate(s, engine="fast"), "q")
    np.testing.assert_allclose(with_c, without_c, rtol=0, atol=1e-9)
    assert np.ptp(with_c) > 0.01                        # the arm moved


def test_a_loop_with_a_called_kernel_stays_in_python():
    """The paper's loop calls its laceration path (not traced): no C text, and the fast engine keeps the text."""
    s, loop, compiled, program, _ = _loop("paper")
    with pytest.raises(c_loop.CUnavailable, match="'trajectory'"):
        c_loop.loop_c_source(program)
    assert c_loop.c_rhs(compiled.plan, loop) is None


def test_without_a_compiler_or_with_the_switch_off_the_text_runs(monkeypatch):
    pytest.importorskip("pinocchio")
    monkeypatch.setenv("CC", "/nonexistent/dobkit-cc")
    assert c_loop.c_compiler() is None
    s, loop, compiled, _, _ = _loop("scope4")
    assert not isinstance(getattr(compiled.point_rhs, "__self__", None), c_loop.CLoop)
    monkeypatch.delenv("CC")
    assert c_loop.c_compiler() is not None
    monkeypatch.setenv("DOBKIT_FAST_C", "0")
    assert c_loop.c_compiler() is None


def test_a_failing_compiler_is_said_once_and_the_run_goes_on(fresh_cache, monkeypatch):
    """A compiler that fails: one warning saying so, then the Python text, with the same derivative."""
    pytest.importorskip("pinocchio")
    monkeypatch.setenv("CC", "false")
    s, loop, _, _, _ = _loop("scope4")
    with pytest.warns(RuntimeWarning, match="compiling the loop's C failed"):
        compiled = CompiledLoop(loop)
        rhs = compiled.point_rhs
    assert not isinstance(getattr(rhs, "__self__", None), c_loop.CLoop)
    x = initial_state(loop, s)
    np.testing.assert_allclose(rhs(0.2, x), compiled.rhs(0.2, x), rtol=1e-11, atol=1e-11)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert CompiledLoop(loop).point_rhs is not None               # said once per process
    assert not any(fresh_cache.glob("dobkit_cloop_*.so"))


def test_a_library_changed_on_disk_is_compiled_again(fresh_cache, monkeypatch):
    """The library's bytes are checked against the digest written beside it: a library replaced by another file (or
    whose digest is gone) is compiled again, not loaded; nothing else is left in the folder.  (The engine never
    writes over a library in place -- a loaded one is mapped into memory -- it renames a new file into place.)"""
    pytest.importorskip("pinocchio")
    s, loop, compiled, program, kernels = _loop("scope4")
    theta = program.numbers(kernels)[0]
    x = initial_state(loop, s)
    want = c_loop.CLoop(program, theta, compiled.nstates).rhs(0.1, x)
    (library,) = fresh_cache.glob("dobkit_cloop_*.so")
    digest = library.with_name(library.name + ".sha256")
    assert digest.is_file() and sorted(p.name for p in fresh_cache.iterdir()) == [library.name, digest.name]
    built = library.read_bytes()
    for damage in ("overwrite", "no digest"):
        monkeypatch.setattr(c_loop, "_libraries", {})
        if damage == "overwrite":          # another file put in its place (never written over: it is mapped)
            stranger = library.with_name("stranger")
            stranger.write_bytes(b"\x7fELF not a library")
            os.replace(stranger, library)
        else:
            digest.unlink()
        assert not c_loop._checked(library)
        np.testing.assert_array_equal(c_loop.CLoop(program, theta, compiled.nstates).rhs(0.1, x), want)
        assert c_loop._checked(library) and len(library.read_bytes()) == len(built)


def test_the_compile_limit_on_both_sides(fresh_cache):
    """A library not in the cache is compiled only when its estimated compile time is within the limit; the
    refusal names the estimate.  Once built, it is loaded whatever the limit."""
    pytest.importorskip("pinocchio")
    _, _, _, program, _ = _loop("scope4")
    lines = c_loop.loop_c_source(program).count("\n")
    estimate = c_loop.estimate_c_compile_seconds(lines)
    assert 0.0 < estimate < c_loop.C_COMPILE_LIMIT
    with pytest.raises(c_loop.CTooLong, match=f"about {estimate:.3g} s to compile"):
        c_loop.loop_library(program, max_compile_seconds=0.99 * estimate)
    assert not any(fresh_cache.glob("dobkit_cloop_*.so"))
    c_loop.loop_library(program, max_compile_seconds=1.01 * estimate)
    c_loop._libraries.clear()
    c_loop.loop_library(program, max_compile_seconds=0.0)             # from the cache: no compile
    # the estimate grows with the text: a big arm's over the limit is not compiled
    assert c_loop.estimate_c_compile_seconds(10 * lines) > estimate
    assert c_loop.estimate_c_compile_seconds(200_000) > c_loop.C_COMPILE_LIMIT


def test_non_finite_states_give_the_numpy_plans_numbers():
    """Where Python's float arithmetic would raise (the text falls back to the numpy plan), C computes as numpy
    does: inf and nan where the plan has them."""
    pytest.importorskip("pinocchio")
    s, loop, compiled, program, kernels = _loop("scope4")
    c = c_loop.CLoop(program, program.numbers(kernels)[0], compiled.nstates)
    x = initial_state(loop, s).copy()
    x[0] = np.inf
    with np.errstate(all="ignore"):
        got, want = c.rhs(0.3, x), compiled.rhs(0.3, x)
    assert not np.isfinite(want).all()
    np.testing.assert_array_equal(got, want)


def test_the_grid_pass_gives_the_outputs_and_the_lumped_disturbance():
    """One C call over the output grid: the outputs equal the numpy plan's on the grid, the row group ``d`` equals
    the lumped disturbance computed from them by the numpy kernels (Eq. 2-3), to rounding; a row group that reads
    the reference's tool pose (``aux``) is not offered, and asking for it is refused by name."""
    pytest.importorskip("pinocchio")
    from blocks.figure2.derived import lumped_disturbance_of

    s, loop, compiled, program, kernels = _loop("ur5")
    c = c_loop.CLoop(program, program.numbers(kernels)[0], compiled.nstates)
    assert "d" in c.row_groups and "tool_distance" in program.row_groups and "tool_distance" not in c.row_groups
    rng = np.random.default_rng(9)
    t_grid = np.linspace(0.0, 2.0, 41)
    x0 = initial_state(loop, s)
    X = x0[:, None] + 0.1 * rng.standard_normal((x0.size, t_grid.size))
    outputs, rows = c.outputs_on_grid(t_grid, X, ("d",))
    np.testing.assert_allclose(outputs, compiled.outputs_on_grid(t_grid, X), rtol=1e-12, atol=1e-12)
    want = lumped_disturbance_of(outputs, list(loop.output_labels), s)
    np.testing.assert_allclose(rows["d"], want, rtol=1e-11, atol=1e-11)
    assert np.ptp(want) > 0.1
    with pytest.raises(ValueError, match="tool_distance"):
        c.outputs_on_grid(t_grid, X, ("tool_distance",))


def test_a_fast_run_takes_d_from_the_grid_pass_and_it_is_the_lumped_disturbance():
    pytest.importorskip("pinocchio")
    from blocks.figure2.derived import lumped_disturbance_of

    s = load_scenario("scope4").replace(simulation={"t_final": 1.0})
    response = simulate(s, engine="fast")
    labels = list(response.output_labels)
    n = s.robot.n
    want = lumped_disturbance_of(response.outputs[:-n], labels[:-n], s)
    np.testing.assert_allclose(signal(response, "d"), want, rtol=1e-11, atol=1e-12)
