"""Engine selection: "auto" falls back to numpy and says why once; "compiled" refuses with a message naming the cause.

With ``DOBKIT_HIDE_NUMBA=1`` (a second CI run) numba is made unimportable
before the package is imported, so these tests run as on a machine without
the extra ``dobkit[fast]``.  The subprocess test does the same in every run.
"""
from __future__ import annotations

import importlib.abc
import os
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest


class _NoNumba(importlib.abc.MetaPathFinder):
    """Makes ``import numba`` fail, as on a machine without it."""

    def find_spec(self, name, path=None, target=None):
        if name == "numba" or name.startswith("numba."):
            raise ImportError(f"{name} hidden for the test (DOBKIT_HIDE_NUMBA)")
        return None


HIDDEN = os.environ.get("DOBKIT_HIDE_NUMBA") == "1"
if HIDDEN:
    sys.meta_path.insert(0, _NoNumba())


import blocks  # noqa: E402
from blocks.diagram.contract import Block, BlockContract  # noqa: E402
from blocks.diagram.systems import plant_output, plant_update  # noqa: E402
from blocks.engines.compiled import CompiledUnavailable, numba_or_none  # noqa: E402
from blocks.figure2.batch import simulate_batch  # noqa: E402
from blocks.figure2.loop import EngineFallbackWarning, select_engine  # noqa: E402
from blocks.kernels import disturbance_params  # noqa: E402
from blocks.model.rrpr.dynamics_kernels import arm_constants  # noqa: E402

HAVE_NUMBA = numba_or_none() is not None
SHORT = blocks.load_scenario("paper").replace(simulation={"t_final": 0.2})


@pytest.fixture(autouse=True)
def fresh_fallback_reports(monkeypatch):
    """Each test starts as a new process would: no fallback reported yet (they are reported once per process)."""
    monkeypatch.setattr("blocks.engines.engine_choice._fallbacks_reported", set())


def test_numba_is_hidden_when_asked():
    if HIDDEN:
        assert not HAVE_NUMBA


def _users_plant(s):
    """The plant as a user's own block: the same maths and no feedthrough declared, but no kernels."""
    k, dist = arm_constants(s.robot), disturbance_params(s.disturbance, s.robot)
    states = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]
    model = s.robot.arm_kernels
    return Block(lambda t, x, u, p: plant_update(model, t, x, u, k, dist),
                 lambda t, x, u, p: plant_output(model, t, x, u, k, dist),
                 contract=BlockContract(feedthrough=frozenset()), inputs=[f"tau[{i}]" for i in range(4)],
                 states=states, outputs=states + [f"tau_dis[{i}]" for i in range(4)], name="users_plant")


def test_unknown_engine_is_refused_by_name():
    with pytest.raises(ValueError, match="'turbo'"):
        blocks.simulate(SHORT, engine="turbo")
    with pytest.raises(ValueError, match="'python-control'"):
        simulate_batch(SHORT, [{"gains.kp": 100.0}], engine="python-control")


def test_compiled_refuses_a_block_without_kernels_and_names_it():
    plant = _users_plant(SHORT)
    with pytest.raises(CompiledUnavailable, match="block 'users_plant' has no kernels" if HAVE_NUMBA else "dobkit\\[fast\\]"):
        blocks.simulate(SHORT, plant=plant, engine="compiled")


def test_auto_falls_back_to_numpy_once_and_gives_the_numpy_numbers():
    plant = _users_plant(SHORT)
    with pytest.warns(EngineFallbackWarning, match="users_plant|numba"):
        auto = blocks.simulate(SHORT.replace(name="fallback-once"), plant=plant)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EngineFallbackWarning)       # the same reason is not reported again
        again = blocks.simulate(SHORT.replace(name="fallback-once"), plant=plant)
    fast = blocks.simulate(SHORT, plant=plant, engine="fast")
    np.testing.assert_array_equal(auto.states, fast.states)
    np.testing.assert_array_equal(again.states, fast.states)


def test_compiled_refuses_a_solver_it_does_not_implement():
    s = SHORT.replace(simulation={"method": "DOP853"})
    with pytest.raises(CompiledUnavailable, match="'DOP853'" if HAVE_NUMBA else "dobkit\\[fast\\]"):
        blocks.simulate(s, engine="compiled")
    assert select_engine("fast", "any reason") == "fast"


@pytest.mark.skipif(HAVE_NUMBA, reason="numba is installed")
def test_without_numba_compiled_names_the_extra_and_auto_runs_numpy():
    with pytest.raises(CompiledUnavailable, match='pip install "dobkit\\[fast\\]"'):
        blocks.simulate(SHORT, engine="compiled")
    with pytest.raises(CompiledUnavailable, match="dobkit\\[fast\\]"):
        simulate_batch(SHORT, [{"gains.kp": 100.0}], engine="compiled")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EngineFallbackWarning)
        np.testing.assert_array_equal(blocks.simulate(SHORT).states, blocks.simulate(SHORT, engine="fast").states)


@pytest.mark.skipif(not HAVE_NUMBA, reason="needs numba")
def test_auto_is_compiled_when_it_can_be():
    with warnings.catch_warnings():
        warnings.simplefilter("error", EngineFallbackWarning)
        auto = blocks.simulate(SHORT)
    np.testing.assert_array_equal(auto.states, blocks.simulate(SHORT, engine="compiled").states)


@pytest.mark.skipif(not HAVE_NUMBA, reason="needs numba")
def test_auto_runs_a_batch_with_per_member_noise_compiled():
    s = SHORT.replace(noise={"q_std": [1e-4] * 4, "dq_std": [1e-3] * 4, "seed": 1})
    variants = [{"noise.seed": 1}, {"noise.seed": 2}, {"noise.q_std": [0.0] * 4, "noise.dq_std": [0.0] * 4}]
    with warnings.catch_warnings():
        warnings.simplefilter("error", EngineFallbackWarning)
        auto = simulate_batch(s, variants)
    compiled = simulate_batch(s, variants, engine="compiled")
    fast = simulate_batch(s, variants, engine="fast")
    np.testing.assert_array_equal(auto.metrics["rms_position_error"], compiled.metrics["rms_position_error"])
    np.testing.assert_allclose(auto.metrics["rms_position_error"], fast.metrics["rms_position_error"], rtol=1e-10)


def test_a_process_without_numba_runs_everything_on_numpy():
    script = textwrap.dedent("""
        import importlib.abc, sys, warnings
        class NoNumba(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "numba" or name.startswith("numba."):
                    raise ImportError("hidden")
        sys.meta_path.insert(0, NoNumba())
        import blocks
        from blocks.engines.compiled import CompiledUnavailable
        s = blocks.load_scenario("paper").replace(simulation={"t_final": 0.1})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            blocks.simulate(s)
            blocks.simulate(s)
        print("warnings", len(caught), caught[0].message)
        try:
            blocks.simulate(s, engine="compiled")
        except CompiledUnavailable as err:
            print("refused:", err)
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "warnings 1 engine='auto' uses the numpy engine: numba is not installed" in run.stdout
    assert 'refused: engine=\'compiled\' cannot run: numba is not installed (it comes with the optional extra: ' \
           'pip install "dobkit[fast]")' in run.stdout


def test_the_command_line_says_which_engine_in_one_note_line(tmp_path):
    short = tmp_path / "short.toml"
    short.write_text(SHORT.to_toml())
    script = textwrap.dedent(f"""
        import importlib.abc, sys
        class NoNumba(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "numba" or name.startswith("numba."):
                    raise ImportError("hidden")
        sys.meta_path.insert(0, NoNumba())
        from dobkit.cli import main
        sys.exit(main(["simulate", "--scenario", {str(short)!r}, "--out", {str(tmp_path / 'run')!r}]))
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    notes = [line for line in run.stderr.splitlines() if "numpy engine" in line]
    # once per process, one line, no echo of the Python source line that raised it
    assert notes == ["dobkit simulate: note: engine='auto' uses the numpy engine: numba is not installed "
                     "(it comes with the optional extra: pip install \"dobkit[fast]\")"]
    assert "simulate(" not in run.stderr


@pytest.mark.skipif(not HAVE_NUMBA, reason="needs numba")
def test_auto_compiles_a_loop_only_when_its_code_is_short_enough_or_already_cached(monkeypatch):
    """The rule of ``AUTO_COMPILE_SECONDS`` (the estimated compile time of the generated lines), at both sides of
    the limit, for a loop not yet compiled and a cached one."""
    import blocks.engines.compiled.engine as engine_module
    from blocks.engines.compiled.compile_estimate import COMPILE_FIXED_S, COMPILE_PER_LINE_S
    from blocks.figure2.loop import _prepared

    s = SHORT.replace(name="auto-compile-limit")
    compiled = _prepared(s, True).compiled_engine()
    lines = compiled.generated_lines
    assert lines == compiled.program.source.count("\n") + 1 > 100
    estimate = compiled.compile_estimate
    assert estimate == COMPILE_FIXED_S + COMPILE_PER_LINE_S * lines
    monkeypatch.setattr(compiled, "_announce", True)                     # as if never compiled here
    monkeypatch.setattr(engine_module, "AUTO_COMPILE_SECONDS", estimate)
    assert compiled.auto_reason() is None                                # at the limit: compiled
    monkeypatch.setattr(engine_module, "AUTO_COMPILE_SECONDS", estimate - 1e-9)
    reason = compiled.auto_reason()
    assert f"{lines} lines" in reason and f"about {estimate:.0f} s of CPU" in reason and "--engine compiled" in reason
    with pytest.warns(EngineFallbackWarning, match=f"{lines} lines"):
        auto = blocks.simulate(s)                                        # one line over: numpy, saying why
    np.testing.assert_array_equal(auto.states, blocks.simulate(s, engine="fast").states)
    monkeypatch.setattr(compiled, "_announce", False)                    # cached: compiled, whatever its length
    assert compiled.auto_reason() is None


def test_sweep_prints_the_engine_note_once_for_all_workers(tmp_path, capfd, monkeypatch):
    import warnings

    import blocks
    import blocks.engines.engine_choice
    from analysis.sweep.runner import run_sweep
    from blocks.figure2.loop import EngineFallbackWarning

    # a fallback is noted once per reason and process: start as a new process would, whatever ran before here
    monkeypatch.setattr(blocks.engines.engine_choice, "_fallbacks_reported", set())

    # RK23 is a solver the compiled engine does not have: engine='auto' falls back to numpy in every worker
    short = blocks.load_scenario("paper").replace(simulation={"t_final": 0.05, "method": "RK23"},
                                                  trajectory={"duration": 10.0})
    (tmp_path / "short.toml").write_text(short.to_toml(), encoding="utf-8")
    (tmp_path / "s.toml").write_text('scenario = "short.toml"\nengine = "fast"\n[grid]\n"gains.kp" = [100, 120, 140, '
                                     '160]\n[batch]\nsize = 1\n', encoding="utf-8")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_sweep(tmp_path / "s.toml", tmp_path / "r.jsonl", workers=2, progress=False)
    assert outcome.ran == 4
    notes = [w for w in caught if issubclass(w.category, EngineFallbackWarning)]
    # the first reason the compiled engine cannot run it: numba missing (the hidden-numba run), else the solver
    assert len(notes) == 1 and ("RK23" if HAVE_NUMBA else "numba is not installed") in str(notes[0].message)
    # and no worker printed its own copy on the shared stderr
    assert "uses the numpy engine" not in capfd.readouterr().err
