"""The compiled engine (blocks.engines.compiled) gives the numpy engine's numbers: states to solver tolerance, metrics to
1e-6."""
from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import hold_trajectory, make_scenario

import blocks
from blocks.engines.fastsim import CompiledLoop
from blocks.figure2.batch import STATE_ATOL, Variants, simulate_batch
from blocks.figure2.metrics import METRICS, OBSERVER_METRICS, tracking_metrics

numba = pytest.importorskip("numba", reason="the compiled engine needs the extra dobkit[fast]")

from blocks.engines.compiled import CompiledLoopEngine  # noqa: E402

METRIC_RTOL = 1e-6


def _scenarios():
    paper = blocks.load_scenario("paper")
    short = paper.replace(simulation={"t_final": 2.0})
    return {
        "paper, 10 s": (paper, True),
        "paper without observer, 10 s": (paper, False),
        "surgical": (blocks.load_scenario("surgical").replace(simulation={"t_final": 2.0}), True),
        "joint-sine": (blocks.load_scenario("joint-sine").replace(simulation={"t_final": 2.0}), True),
        "friction, tissue, Eq. 16 as printed, mismatch": (
            short.replace(disturbance={"kind": ["paper", "friction", "tissue"]}, observer={"variant": "paper-eq16"},
                          nominal_scale={"m1": 0.8, "I2": 1.3}), True),
        "full observer gain, noise": (
            short.replace(simulation={"t_final": 0.5}, gains={"observer": [[12.0, 1.0, 0, 0], [1.0, 9.0, 0, 0],
                                                                            [0, 0, 10.0, 0], [0, 0, 0, 10.0]]},
                          noise={"q_std": [1e-4] * 4, "dq_std": [1e-3] * 4, "seed": 3}), True),
    }


def _assert_same_run(compiled, fast, sim, metric_rtol=None):
    assert list(compiled.output_labels) == list(fast.output_labels)
    np.testing.assert_array_equal(compiled.time, fast.time)
    # to solver tolerance: each joint position within 10 x (rtol x its largest magnitude + atol) of the numpy
    # run's.  (The two pick their own steps once a rounding difference flips a step decision; velocities and
    # observer states then differ by the solver's local error, which noise and contact kinks make larger.)
    q = slice(0, 4)
    scale = np.max(np.abs(fast.states[q]), axis=1, keepdims=True)
    assert np.all(np.abs(compiled.states[q] - fast.states[q]) <= 10 * (sim.rtol * scale + sim.atol))
    mc, mf = tracking_metrics(compiled), tracking_metrics(fast)
    position_tol = float(np.max(10 * (sim.rtol * scale + sim.atol)))
    for name, value in mf.items():
        if metric_rtol is not None and name.startswith("rms"):
            np.testing.assert_allclose(mc[name], value, rtol=metric_rtol, atol=0, err_msg=name)
        elif name in ("rms_position_error", "max_abs_position_error", "final_abs_position_error"):
            # a position metric moves by at most the largest position difference
            np.testing.assert_allclose(mc[name], value, rtol=0, atol=position_tol, err_msg=name)


@pytest.mark.parametrize("name", list(_scenarios()))
def test_compiled_equals_numpy_engine(name):
    scenario, observer = _scenarios()[name]
    compiled = blocks.simulate(scenario, observer=observer, engine="compiled")
    fast = blocks.simulate(scenario, observer=observer, engine="fast")
    # the paper's 10 s runs (Table 3): every RMS metric to 1e-6 relative
    _assert_same_run(compiled, fast, scenario.simulation, METRIC_RTOL if name.startswith("paper") else None)


def test_compiled_equals_numpy_engine_on_random_variants():
    rng = np.random.default_rng(11)
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 1.0})
    for _ in range(3):
        s = base.replace(gains={"kp": float(rng.uniform(100, 250)), "kd": float(rng.uniform(25, 45)),
                                "observer": list(rng.uniform(5, 30, 4))},
                         nominal_scale={k: float(rng.uniform(0.8, 1.2)) for k in ("m1", "m2", "I1", "I4")},
                         disturbance={"f_r": list(rng.uniform(0.5, 3.0, 4))})
        _assert_same_run(blocks.simulate(s, engine="compiled"), blocks.simulate(s, engine="fast"), s.simulation)


def test_generated_right_hand_side_and_outputs_equal_the_plan_executed_with_numpy():
    """The traced and called kernels give each block's numbers at arbitrary states (rounding only)."""
    rng = np.random.default_rng(5)
    for scenario, observer in _scenarios().values():
        loop = blocks.closed_loop(scenario, observer=observer)
        engine, numpy_loop = CompiledLoopEngine(loop), CompiledLoop(loop)
        x0 = blocks.initial_state(loop, scenario)
        t = np.array([0.0, 0.013, 0.37, 1.9])
        X = x0[:, None] + 0.01 * rng.standard_normal((x0.size, t.size))
        for k, tk in enumerate(t):
            want = numpy_loop.rhs(tk, X[:, k])
            np.testing.assert_allclose(engine.rhs(tk, X[:, k]), want, rtol=1e-11, atol=1e-11 * np.abs(want).max())
        want = numpy_loop.outputs_on_grid(t, X)
        scale = np.abs(want).max(axis=1, keepdims=True) + 1.0
        np.testing.assert_allclose(engine.outputs_on_grid(t, X) / scale, want / scale, rtol=0, atol=1e-12)


def test_blocks_are_traced_or_called_as_their_kernels_allow():
    s = blocks.load_scenario("paper").replace(noise={"q_std": [1e-4] * 4, "dq_std": [1e-3] * 4})
    program = CompiledLoopEngine(blocks.closed_loop(s)).program
    # the sensor's noise table is read by the generated code at a traced index; its length at run time
    assert sorted(program.traced) == ["controller", "observer", "plant", "sensor"]
    assert len(program.tables) == 1 and "ext[" in program.source and ".shape[1]" in program.source
    # the laceration path branches on the phase: called as a compiled kernel (returning a tuple, no array)
    assert program.called == ["trajectory"]
    sine = CompiledLoopEngine(blocks.closed_loop(blocks.load_scenario("joint-sine"))).program
    assert "trajectory" in sine.traced and sine.sources == ["trajectory"]


def test_divergence_is_reported_with_the_crossing_time():
    s = make_scenario(trajectory=hold_trajectory(), disturbance={"f_r": [0.0, 0.0, 1e9, 0.0]},
                      simulation={"t_final": 1.0, "output_step": 0.01})
    errors = {}
    for engine in ("compiled", "fast"):
        with pytest.raises(blocks.SimulationError, match="diverged at t = ") as info:
            blocks.simulate(s, observer=False, engine=engine)
        errors[engine] = float(str(info.value).split("t = ")[1].split(" s")[0])
    assert errors["compiled"] == pytest.approx(errors["fast"], rel=1e-3)


def _paper_variants(n, seed=3):
    rng = np.random.default_rng(seed)
    return {"gains.kp": rng.uniform(120.0, 250.0, n), "gains.kd": rng.uniform(30.0, 45.0, n),
            "nominal_scale.m2": rng.uniform(0.9, 1.1, n), "disturbance.f_r": 1.43 * rng.uniform(0.5, 2.0, (n, 4))}


def test_compiled_batch_equals_numpy_batch_and_single_compiled_runs():
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 2.0})
    v = Variants(base, _paper_variants(5))
    compiled = simulate_batch(base, v, engine="compiled", signals=("q", "d_hat", "d"), workers=2,
                              method="RK4")
    numpy_batch = simulate_batch(base, v, engine="fast", signals=("q", "d_hat", "d"))
    # the same RK4 schedule (method='RK4'): equal to rounding
    for name, value in numpy_batch.signals.items():
        np.testing.assert_allclose(compiled.signals[name], value, rtol=1e-9, atol=1e-10, err_msg=name)
    # and each member equals its own single compiled run within the batch's stated tolerance
    for i in range(len(v)):
        single = blocks.simulate(v.scenario(i), engine="compiled")
        q = np.stack([single.outputs[list(single.output_labels).index(f"q[{j}]")] for j in range(4)], axis=1)
        assert np.abs(compiled.signals["q"][i] - q).max() < STATE_ATOL


def _assert_same_metrics(compiled, numpy_batch, rtol=1e-10):
    assert set(compiled.metrics) == set(numpy_batch.metrics)
    for name, value in numpy_batch.metrics.items():
        assert np.all(np.isfinite(value)), name
        np.testing.assert_allclose(compiled.metrics[name], value, rtol=rtol, atol=1e-14, err_msg=name)


_FULL_GAIN = [[12.0, 1.0, 0, 0], [1.0, 9.0, 0, 0], [0, 0, 10.0, 0], [0, 0, 0, 10.0]]


@pytest.mark.parametrize("case", ["paper variants", "without observer", "matrix observer gains and Eq. 16"])
def test_metrics_accumulated_in_the_compiled_driver_equal_the_numpy_batch(case):
    """All seven metrics -- position, tool tip (traced tool pose) and disturbance error (traced lumped
    disturbance) -- summed inside the compiled driver, against the numpy batch's TrackingAccumulator."""
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 2.0})
    records, observer = {
        "paper variants": (_paper_variants(4, seed=8), True),
        "without observer": (_paper_variants(3, seed=9), False),
        "matrix observer gains and Eq. 16": ([{"gains.observer": _FULL_GAIN}, {"observer.variant": "paper-eq16"},
                                              {"nominal_scale.I2": 1.3, "gains.observer": [5.0, 10.0, 20.0, 8.0]}],
                                             True),
    }[case]
    v = Variants(base, records)
    compiled = simulate_batch(base, v, observer=observer, engine="compiled", workers=2, method="RK4")
    numpy_batch = simulate_batch(base, v, observer=observer, engine="fast")
    assert len(compiled.metrics) == len([m for m in METRICS if observer or m not in OBSERVER_METRICS])
    _assert_same_metrics(compiled, numpy_batch)
    # a subset is the same subset
    only = simulate_batch(base, v, observer=observer, engine="compiled", metrics=("max_tool_position_error_mm",),
                          method="RK4")
    assert list(only.metrics) == ["max_tool_position_error_mm"]
    np.testing.assert_array_equal(only.metrics["max_tool_position_error_mm"],
                                  compiled.metrics["max_tool_position_error_mm"])


def test_per_member_noise_compiled_equals_numpy():
    """Members with their own noise read their own table in the compiled driver; a member without noise none."""
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 0.5})
    records = [{"noise.q_std": [1e-4] * 4, "noise.dq_std": [1e-3] * 4, "noise.seed": 3},
               {"noise.q_std": [2e-4, 0, 0, 1e-4], "noise.seed": 5, "gains.kp": 150.0}, {}]
    compiled = simulate_batch(base, records, engine="compiled", signals=("q", "q_meas"), workers=2, method="RK4")
    numpy_batch = simulate_batch(base, records, engine="fast", signals=("q", "q_meas"))
    _assert_same_metrics(compiled, numpy_batch)
    for name in ("q", "q_meas"):
        np.testing.assert_allclose(compiled.signals[name], numpy_batch.signals[name], rtol=0, atol=1e-12)
    # the noise is there: member 0 measures what it does not have, member 2 measures itself
    assert np.abs(compiled.signals["q_meas"][0] - compiled.signals["q"][0]).max() > 1e-5
    np.testing.assert_array_equal(compiled.signals["q_meas"][2], compiled.signals["q"][2])


def test_repeated_runs_reuse_the_prepared_loop_and_another_scenario_does_not():
    from blocks.figure2.loop import _prepared
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 0.5})
    first = blocks.simulate(s, engine="compiled")
    run = _prepared(s, True)
    engine = run.compiled_engine()
    again = blocks.simulate(s, engine="compiled")
    assert _prepared(s, True) is run and run.compiled_engine() is engine
    np.testing.assert_array_equal(again.outputs, first.outputs)
    # an equal scenario made again shares the prepared run; the observer flag and other values do not
    equal = blocks.load_scenario("paper").replace(simulation={"t_final": 0.5})
    assert equal is not s and _prepared(equal, True) is run
    assert _prepared(s, False) is not run
    other = s.with_changes({"gains.kp": 150.0})
    assert _prepared(other, True) is not run
    changed = blocks.simulate(other, engine="compiled")
    assert not np.allclose(changed.outputs, first.outputs, rtol=0, atol=1e-9)
    # the other scenario's run is its own: as the numpy engine on a loop built for it
    _assert_same_run(changed, blocks.simulate(other, engine="fast"), other.simulation)


def test_compiled_lumped_disturbance_is_the_kernels_on_the_outputs():
    """The response's d, computed in the compiled grid pass, equals blocks.lumped_disturbance of its signals."""
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 1.0}, nominal_scale={"m1": 0.8, "I4": 1.2})
    r = blocks.simulate(s, engine="compiled")
    labels = list(r.output_labels)
    rows = lambda name: r.outputs[[labels.index(f"{name}[{i}]") for i in range(4)]].T     # noqa: E731
    want = blocks.lumped_disturbance(rows("q"), rows("dq"), rows("tau"), rows("tau_dis"), s)
    np.testing.assert_allclose(rows("d"), want, rtol=1e-12, atol=1e-12)
    assert np.abs(rows("d") - rows("tau_dis")).max() > 1e-3          # the mismatch is in d


def test_compiled_progress_reports_fractions_of_simulated_time(monkeypatch):
    import blocks.engines.compiled.engine as engine_module
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 1.0})
    blocks.simulate(s, engine="compiled")
    seen = []
    import blocks.engines.monitor as monitor_module
    monkeypatch.setattr(monitor_module, "PROGRESS_PERIOD", 0.0)     # report after every call of the compiled loop
    monkeypatch.setattr(monitor_module, "CHUNK_SECONDS", 0.0)       # and return to the Monitor after few steps
    monkeypatch.setattr(engine_module, "_FIRST_STEPS", 4)
    with_progress = blocks.simulate(s, engine="compiled", progress=seen.append)
    assert len(seen) > 5 and seen == sorted(seen) and 0 < seen[0] < 0.5 and seen[-1] == 1.0
    np.testing.assert_array_equal(with_progress.states, blocks.simulate(s, engine="compiled").states)
    seen.clear()
    monkeypatch.setattr(monitor_module, "PROGRESS_PERIOD", 1e9)     # a run shorter than the period: only its end
    blocks.simulate(s, engine="compiled", progress=seen.append)
    assert seen == [1.0]


def test_a_repeated_run_takes_the_compiled_driver_in_one_call(monkeypatch):
    """The monitored run returns to Python every ``CHUNK_SECONDS``: its first call is sized from the engine's
    previous pace, so a run much shorter than that is one call of ``dopri_run`` (the first run starts with a few
    steps and measures the pace), with the states of the run in many calls."""
    from blocks.figure2.loop import _prepared
    s = blocks.load_scenario("paper").replace(simulation={"t_final": 1.0})
    first = blocks.simulate(s, engine="compiled")
    module = _prepared(s, True).compiled_engine().module
    calls = []
    driver = module.dopri_run
    monkeypatch.setattr(module, "dopri_run", lambda *args: calls.append(args[7]) or driver(*args))
    again = blocks.simulate(s, engine="compiled")
    assert len(calls) == 1 and calls[0] > 100          # about 90 accepted steps in this run
    np.testing.assert_array_equal(again.states, first.states)
    np.testing.assert_array_equal(again.outputs, first.outputs)


def test_no_allocation_per_step_in_the_compiled_right_hand_side(tmp_path):
    """numba's allocation count of a run does not grow with the number of steps (paper loop, with and without
    measurement noise; the batch)."""
    script = textwrap.dedent("""
        import numpy as np
        import blocks
        from blocks.figure2.batch import simulate_batch
        from blocks.figure2.loop import _prepared
        from numba.core.runtime import rtsys
        s = blocks.load_scenario("paper")
        counts = []
        for loop_scenario in (s, s.replace(noise={"q_std": [1e-4] * 4, "dq_std": [1e-3] * 4})):
            engine = _prepared(loop_scenario, True).compiled_engine()
            engine.warm()
            for t_final in (0.2, 2.0):
                grid = s.replace(simulation={"t_final": t_final}).simulation.time_grid
                before = rtsys.get_allocation_stats().alloc
                states, nfev = engine.integrate(_prepared(loop_scenario, True).x0, grid, 1e-6, 1e-8, np.inf, 1e6)
                counts.append((nfev, rtsys.get_allocation_stats().alloc - before))
        short = s.replace(simulation={"t_final": 0.2}, trajectory={"duration": 10.0})
        simulate_batch(short, [{"gains.kp": 150.0}, {}], engine="compiled")
        for t_final in (0.2, 2.0):
            member = s.replace(simulation={"t_final": t_final}, trajectory={"duration": 10.0})
            before = rtsys.get_allocation_stats().alloc
            simulate_batch(member, [{"gains.kp": 150.0}, {}], engine="compiled")
            counts.append((t_final, rtsys.get_allocation_stats().alloc - before))
        print(counts)
    """)
    env = dict(os.environ, NUMBA_NRT_STATS="1")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    (calls_short, single_short), (calls_long, single_long), (noisy_short_calls, noisy_short), \
        (noisy_long_calls, noisy_long), (_, batch_short), (_, batch_long) = \
        ast.literal_eval(run.stdout.strip().splitlines()[-1])
    assert calls_long > 5 * calls_short and noisy_long_calls > 5 * noisy_short_calls
    assert single_long == single_short
    assert noisy_long == noisy_short                    # measurement noise read from its table in place
    assert batch_long == batch_short


def test_compiled_batch_marks_diverging_members():
    base = make_scenario(trajectory=hold_trajectory(), simulation={"t_final": 1.0, "output_step": 0.01})
    v = Variants(base, {"disturbance.f_r": [[1.43, 1.6, 1.4, 1.2], [0.0, 0.0, 1e9, 0.0]]})
    compiled = simulate_batch(base, v, observer=False, engine="compiled")
    numpy_batch = simulate_batch(base, v, observer=False, engine="fast")
    np.testing.assert_array_equal(np.isnan(compiled.failed_at), np.isnan(numpy_batch.failed_at))
    assert not compiled.ok[1] and compiled.ok[0]
    assert np.isnan(compiled.metrics["rms_position_error"][1]).all()


def test_a_second_process_loads_the_compiled_code_from_the_cache(tmp_path):
    """Two processes on one cache folder: the first compiles, the second only loads (numba's cache hits)."""
    script = textwrap.dedent("""
        import blocks
        from blocks.engines.compiled import CompiledLoopEngine
        s = blocks.load_scenario("paper").replace(simulation={"t_final": 0.2})
        engine = CompiledLoopEngine(blocks.closed_loop(s))
        r = blocks.simulate(s, engine="compiled")
        stats = engine.module.dopri_run.stats
        print("hits", sum(stats.cache_hits.values()), "misses", sum(stats.cache_misses.values()))
    """)
    env = dict(os.environ, DOBKIT_CACHE_DIR=str(tmp_path))
    runs = [subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
            for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr
    assert "compiling the loop with numba" in runs[0].stderr
    assert "compiling" not in runs[1].stderr
    assert "misses 1" in runs[0].stdout and "hits 0" in runs[0].stdout
    assert "hits 1" in runs[1].stdout and "misses 0" in runs[1].stdout
