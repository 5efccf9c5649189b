"""A numpy sampled run's wall time, estimated before it starts (per-tick cost x ticks): refused or warned.

Both sides of the wall-time budget and of the warning, on a URDF arm (scope4-digital), in a process where
numba cannot be imported (as ``DOBKIT_HIDE_NUMBA`` does for the CI run): there ``engine="auto"`` runs the
numpy engine, which is what the estimate is for.
"""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import warnings

import pytest

import blocks
from blocks.engines.budget import Budget, BudgetError
from blocks.engines.sampled_cost import SlowSampledRunWarning, check_sampled_time, estimate_sampled_time
from blocks.figure2.digital_loop import simulate_sampled
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop

SCOPE4 = {"simulation.t_final": 2.0}


def test_without_numba_a_urdf_run_over_the_wall_time_budget_is_refused_before_it_starts_naming_the_key():
    script = textwrap.dedent(f"""
        import importlib.abc, json, os, sys
        class NoNumba(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "numba" or name.startswith("numba."):
                    raise ImportError("hidden")
        sys.meta_path.insert(0, NoNumba())
        import warnings
        import blocks
        from blocks.engines.budget import BudgetError
        from blocks.figure2.digital_loop import simulate_sampled
        from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop
        from blocks.engines.sampled_cost import estimate_sampled_time
        s = blocks.load_scenario("scope4-digital").with_changes({SCOPE4!r})
        loop = sampled_loop(s)
        estimate = estimate_sampled_time(loop, sampled_initial_state(loop, s), s)
        out = {{"estimate": estimate.seconds, "ticks": estimate.ticks}}
        warnings.simplefilter("ignore")              # the engine fallback's note
        progress = []
        os.environ["DOBKIT_MAX_SECONDS"] = repr(estimate.seconds / 100)
        try:
            simulate_sampled(s, progress=progress.append)
            out["low"] = "ran"
        except BudgetError as err:
            out["low"] = str(err)
            out["low_key"], out["low_limit"] = err.key, err.limit
        out["progress_before_refusal"] = len(progress)
        os.environ["DOBKIT_MAX_SECONDS"] = repr(estimate.seconds * 100 + 5.0)
        r = simulate_sampled(s, progress=progress.append)
        out["high"] = "ran" if r.outputs.shape[1] == s.simulation.time_grid.size else "short"
        print(json.dumps(out))
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["ticks"] == 2000 and out["estimate"] > 0
    text = out["low"]
    assert text.startswith("scenario 'scope4-digital' (sampled at 1000 Hz) needs about ")
    assert "of wall time with the numpy sampled engine" in text and "x 2,000 ticks: 2 s at 1000 Hz" in text
    assert "set by 'controller.sample_rate' and 'simulation.t_final'" in text
    assert "numba is not installed" in text and "--max-seconds or DOBKIT_MAX_SECONDS" in text
    assert (out["low_key"], out["low_limit"]) == ("controller.sample_rate", "seconds")
    assert out["progress_before_refusal"] == 0              # refused before the run started
    assert out["high"] == "ran"


def test_a_long_run_without_a_budget_is_warned_about_and_a_short_one_is_not(monkeypatch):
    s = blocks.load_scenario("scope4-digital").with_changes(SCOPE4)
    loop = sampled_loop(s)
    x0 = sampled_initial_state(loop, s)
    estimate = estimate_sampled_time(loop, x0, s)
    what = "scope4"
    monkeypatch.setattr("blocks.engines.sampled_cost.WARN_SECONDS", estimate.seconds / 100)
    with pytest.warns(SlowSampledRunWarning, match=r"scope4 will take about .* with the numpy sampled engine"):
        check_sampled_time(loop, x0, s, Budget(), what)
    monkeypatch.setattr("blocks.engines.sampled_cost.WARN_SECONDS", estimate.seconds * 100 + 5.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_sampled_time(loop, x0, s, Budget(), what)
    # with a budget it is the budget that judges: no warning under it
    monkeypatch.setattr("blocks.engines.sampled_cost.WARN_SECONDS", estimate.seconds / 100)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_sampled_time(loop, x0, s, Budget(seconds=estimate.seconds * 100 + 5.0), what)
    with pytest.raises(BudgetError, match="wall-time budget"):
        check_sampled_time(loop, x0, s, Budget(seconds=estimate.seconds / 100), what)


def test_the_estimate_is_the_ticks_times_the_cost_of_one_and_near_the_run():
    s = blocks.load_scenario("scope4-digital").with_changes(SCOPE4)
    loop = sampled_loop(s)
    estimate = estimate_sampled_time(loop, sampled_initial_state(loop, s), s)
    assert estimate.ticks == 2000
    assert estimate.seconds == pytest.approx(estimate.per_tick * 2000, rel=1e-12)
    import time
    start = time.perf_counter()
    simulate_sampled(s, engine="fast")
    took = time.perf_counter() - start
    # the run adds its set-up and the response to the ticks; the load of a shared machine varies: a factor of 20
    assert estimate.seconds / 20 < took < estimate.seconds * 20 + 2.0
    # a run shorter than a few calibrations is not estimated
    short = s.with_changes({"simulation.t_final": 0.02})
    loop = sampled_loop(short)
    assert estimate_sampled_time(loop, sampled_initial_state(loop, short), short) is None
