"""Sweeps within bounds: sizes and step counts estimated and refused before anything runs, each run on the
step it needs, runs never held in memory all at once."""
from __future__ import annotations

import gc
import hashlib
import itertools
import json
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

import blocks
from analysis.sweep.runner import read_results, run_sweep
from analysis.sweep.spec import RunList, SweepError, load_sweep, sweep_from_dict
from blocks.engines.budget import Budget, BudgetError, estimate_batch
from blocks.figure2.batch import simulate_batch

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def short_file(tmp_path):
    """The first 0.2 s of the paper scenario (its 10 s path), as a file the sweep files refer to."""
    return write_short_scenario(tmp_path, t_final=0.2)


_write = write_sweep

_cli = run_sweep_command


def _peak(job) -> int:
    gc.collect()
    tracemalloc.start()
    try:
        job()
    except (SweepError, BudgetError):
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


def test_stiff_observer_gains_are_refused_naming_the_key_and_the_steps(tmp_path, capsys):
    """The 4-run sweep that grew to 24 GB: refused at once, run by run, before anything is simulated."""
    path = _write(tmp_path, '[grid]\n"gains.observer" = [1000, 1e5, 3e5, 1e6]\n', scenario="paper")
    with pytest.raises(BudgetError) as err:
        load_sweep(path, budget=Budget())
    assert err.value.key == "gains.observer" and err.value.limit == "steps"
    # Y = 1e5: rate Y / min eig(M) = 4e5 1/s (docs/model.md inertia), h <= 0.3 / 4e5, so at least 1.3e7 RK4 steps
    assert err.value.estimate.steps >= 2000 * 0.005 * 4e5 / 0.3
    message = str(err.value)
    assert "run 1 (gains.observer = 100000.0)" in message and "--max-steps" in message
    assert _cli(["sweep", str(path), "--check"]) == 2
    assert "gains.observer" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.jsonl"))
    # more steps allowed: the same runs are then refused for the memory their schedule takes, same key
    with pytest.raises(BudgetError) as err:
        load_sweep(path, budget=Budget(steps=10 ** 9))
    assert err.value.key == "gains.observer" and err.value.limit == "memory" and "--max-memory" in str(err.value)
    # the mild run alone passes
    ok = load_sweep(_write(tmp_path, '[grid]\n"gains.observer" = [1000]\n', name="mild", scenario="paper"))
    assert ok.plan.largest.steps < Budget().steps


@pytest.mark.parametrize("text, key", [
    ('[grid]\n"trajectory.stitches" = [2, 3, 1000000]\n', "trajectory.stitches"),
    ('[grid]\n"gains.kp" = [180]\n[batch]\nsubsteps = 1000000000\n', "batch.substeps"),
])
def test_a_run_whose_schedule_is_huge_is_refused_before_it_is_built(tmp_path, text, key, capsys):
    """Refused by the budget, or (a million stitches: phases of 5 us) by the scenario's own check first."""
    path = _write(tmp_path, text, scenario="paper")
    peak = _peak(lambda: load_sweep(path, budget=Budget()))
    with pytest.raises((BudgetError, SweepError)) as err:
        load_sweep(path, budget=Budget())
    assert key in str(err.value) and getattr(err.value, "key", key) == key
    assert peak < 100 * 2 ** 20                    # 6.4 GB before
    assert _cli(["sweep", str(path), "--check"]) == 2 and key in capsys.readouterr().err


def test_a_huge_grid_is_refused_before_any_run_is_built(tmp_path, capsys):
    values = ", ".join(str(100 + i) for i in range(1000))
    path = _write(tmp_path, f'[grid]\n"gains.kp" = [{values}]\n"gains.kd" = [{values}]\n"robot.m1" = [{values}]\n',
                  scenario="paper")
    peak = _peak(lambda: load_sweep(path, budget=Budget()))
    with pytest.raises(BudgetError) as err:
        load_sweep(path, budget=Budget())
    assert err.value.key == 'grid."gains.kp"' and "1,000,000,000 runs" in str(err.value)
    assert peak < 20 * 2 ** 20
    assert _cli(["sweep", str(path), "--check"]) == 2 and "1,000,000,000 runs" in capsys.readouterr().err


def test_many_draws_are_refused_by_a_smaller_budget_before_they_are_drawn(tmp_path):
    path = _write(tmp_path, '[monte_carlo]\nruns = 2000000\n[monte_carlo.distributions]\n'
                            '"robot.m1" = {kind = "uniform", low = 5, high = 6}\n', scenario="paper")
    peak = _peak(lambda: load_sweep(path, budget=Budget(memory="1G")))
    with pytest.raises(BudgetError) as err:
        load_sweep(path, budget=Budget(memory="1G"))
    assert err.value.key == "monte_carlo.runs" and "--max-memory" in str(err.value)
    assert peak < 20 * 2 ** 20


def test_the_budget_flags_raise_the_limit(tmp_path, capsys, monkeypatch):
    # Y = 1e4 I: h <= 0.3 / 4e4 s, 667 substeps rounded up to 1024: 2.05e6 steps over 10 s
    path = _write(tmp_path, '[grid]\n"gains.observer" = [1e4]\n', scenario="paper")
    assert _cli(["sweep", str(path), "--check"]) == 2
    assert _cli(["sweep", str(path), "--check", "--max-steps", "3e6"]) == 0
    assert "1 runs, valid" in capsys.readouterr().out
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "3e6")
    assert _cli(["sweep", str(path), "--check"]) == 0
    assert _cli(["sweep", str(path), "--check", "--max-memory", "lots"]) == 2
    assert "memory size" in capsys.readouterr().err


def test_runs_are_computed_when_asked_in_product_order_with_the_documented_ids():
    grid = {"gains.kp": list(range(1000)), "gains.kd": list(range(1000))}
    draws = {"robot.m1": [5.0, 5.5, 6.0]}
    identity = {"scenario": {"any": 1}, "observer": True, "engine": "batch", "substeps": None}
    runs = RunList(grid, draws, 3, identity)
    peak = _peak(lambda: [runs[i] for i in (0, 1234567, -1)])
    assert len(runs) == 3_000_000 and peak < 2 ** 20
    expected = [(kp, kd, d) for kp, kd in itertools.islice(itertools.product(grid["gains.kp"], grid["gains.kd"]), 3)
                for d in range(3)]
    assert [(r.values["gains.kp"], r.values["gains.kd"], r.draw) for r in runs[:9]] == expected
    r = runs[1234567]
    point, draw = divmod(1234567, 3)
    assert (r.values["gains.kp"], r.values["gains.kd"], r.values["robot.m1"], r.draw) == \
        (point // 1000, point % 1000, draws["robot.m1"][draw], draw)
    payload = json.dumps({"identity": identity, "values": r.values, "draw": r.draw}, sort_keys=True)
    assert r.run_id == hashlib.sha256(payload.encode()).hexdigest()[:16] == runs.run_id(1234567)


@pytest.mark.slow
def test_check_holds_no_list_of_runs(tmp_path):
    """Validating a sweep takes memory that hardly grows with its runs (about 700 bytes a run before)."""
    peaks = {}
    for n in (1000, 4000):
        kp = ", ".join(str(100 + i) for i in range(n // 20))
        kd = ", ".join(str(30 + 0.1 * i) for i in range(20))
        path = _write(tmp_path, f'[grid]\n"gains.kp" = [{kp}]\n"gains.kd" = [{kd}]\n', name=f"s{n}", scenario="paper")
        holder = {}
        peaks[n] = _peak(lambda: holder.setdefault("spec", load_sweep(path)))
        assert len(holder["spec"].runs) == n
    assert (peaks[4000] - peaks[1000]) / 3000 < 100


def test_a_stiff_run_does_not_impose_its_step_on_a_mild_one(tmp_path, short_file):
    """Y = 10 I needs one RK4 step per output interval, Y = 300 I 20 (h * rate <= 0.3 with rate
    Y / min eig M = 1200 1/s): each gets its own, so the mild run's numbers are those of a batch of its own."""
    spec = load_sweep(_write(tmp_path, '[grid]\n"gains.observer" = [10, 300]\n[outputs]\n'
                                       'metrics = ["rms_position_error", "rms_disturbance_error"]\n'))
    assert spec.plan.classes() == {(1, False): 1, (32, False): 1}
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    rows = {r["values"]["gains.observer"]: r for r in read_results(tmp_path / "r.jsonl")[1]}
    assert (rows[10]["substeps"], rows[300]["substeps"]) == (1, 32)
    for y, substeps in ((10, None), (300, 32)):
        alone = simulate_batch(spec.base, [{"gains.observer": y}], metrics=spec.metrics, substeps=substeps,
                               method="RK4")
        for name in spec.metrics:
            np.testing.assert_allclose(rows[y]["metrics"][name], alone.metrics[name][0], rtol=1e-12, atol=0)


def test_batches_shrink_to_fit_the_memory_budget_without_changing_any_number(tmp_path, short_file):
    text = '[grid]\n"gains.kp" = [120, 140, 160, 180, 200, 220, 240]\n[outputs]\nmetrics = ["rms_position_error"]\n'
    roomy = load_sweep(_write(tmp_path, text, name="roomy"))
    n_grid = 40
    steps = roomy.plan.largest.steps
    three = estimate_batch(3, steps=steps, grid_points=n_grid + 1, joints=4).memory
    tight = load_sweep(_write(tmp_path, text, name="tight"), budget=Budget(memory=three))
    sizes = []
    run_sweep(tight, tmp_path / "tight.jsonl", workers=1, progress=False, on_rows=lambda rows: sizes.append(len(rows)))
    run_sweep(roomy, tmp_path / "roomy.jsonl", workers=1, progress=False)
    assert max(sizes) <= 3 and sum(sizes) == 7
    a = {r["run_id"]: r for r in read_results(tmp_path / "tight.jsonl")[1]}
    b = {r["run_id"]: r for r in read_results(tmp_path / "roomy.jsonl")[1]}
    assert a.keys() == b.keys()
    for run_id, row in a.items():
        assert row["metrics"] == b[run_id]["metrics"]


def test_the_fast_engine_is_checked_for_size_but_not_for_steps(tmp_path):
    spec = sweep_from_dict({"scenario": "paper", "engine": "fast", "grid": {"gains.observer": [1e6]}})
    assert spec.plan.largest is None and len(spec.runs) == 1


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="limits the address space with RLIMIT_AS")
def test_running_out_of_memory_says_what_to_lower(tmp_path):
    """A budget raised beyond what the machine gives: the real MemoryError ends in one line that names the
    budget (not the output step, which has nothing to do with it)."""
    scenario = blocks.load_scenario("paper").replace(simulation={"t_final": 2.0}, trajectory={"duration": 10.0},
                                                     noise={"q_std": [1e-5] * 4})
    (tmp_path / "short.toml").write_text(scenario.to_toml(), encoding="utf-8")
    _write(tmp_path, '[monte_carlo]\nruns = 2000\n[monte_carlo.distributions]\n'
                     '"noise.seed" = {kind = "choice", values = [1, 2, 3, 4, 5, 6, 7]}\n[batch]\nsize = 2000\n')
    code = ("import resource, sys\nfrom dobkit.cli import main\nimport analysis.sweep.summary, analysis.sweep.runner\n"
            "vm = int([l for l in open('/proc/self/status') if l.startswith('VmSize')][0].split()[1]) * 1024\n"
            "resource.setrlimit(resource.RLIMIT_AS, (vm + 400 * 2 ** 20, resource.RLIM_INFINITY))\n"
            "sys.exit(main(['sweep', 's.toml', '--workers', '1', '--no-progress', '--max-memory', '100G']))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 1, done.stderr
    # (numba cannot load its LLVM library under the limit: engine='auto' says so, then the sweep runs on numpy)
    assert done.stderr.strip().splitlines()[-1].startswith(
        "dobkit sweep: out of memory within the memory budget of 100.0 GiB")
    assert "--max-memory" in done.stderr and "output_step" not in done.stderr and "Traceback" not in done.stderr


def test_the_wall_time_budget_stops_between_batches_keeping_the_finished_runs(tmp_path, short_file):
    path = _write(tmp_path, '[grid]\n"gains.kp" = [120, 140, 160, 180]\n[batch]\nsize = 1\n')
    results = tmp_path / "r.jsonl"
    with pytest.raises(BudgetError) as err:
        run_sweep(load_sweep(path), results, workers=1, progress=False, budget=Budget(seconds=1e-6))
    assert err.value.limit == "seconds" and "run the same command again" in str(err.value)
    assert len(read_results(results)[1]) == 1
    outcome = run_sweep(load_sweep(path), results, workers=1, progress=False)
    assert (outcome.skipped, outcome.ran) == (1, 3)


@pytest.mark.slow
def test_a_run_costs_the_sweep_less_than_its_stated_bookkeeping(tmp_path):
    """SWEEP_RUN_BYTES (the sweep-size check) bounds what each run adds to finding the pending runs and to the
    summary, measured with tracemalloc over a results file with every metric."""
    from analysis.sweep.runner import ResultsFile, read_header
    from analysis.sweep.spec import SWEEP_RUN_BYTES
    from analysis.sweep.summary import summarize
    from blocks.figure2.batch import METRICS
    rng = np.random.default_rng(0)
    peaks = {}
    for n in (1000, 4000):
        spec = sweep_from_dict({"scenario": "paper", "grid": {"gains.kp": list(range(100, 100 + n // 10))},
                                "monte_carlo": {"runs": 10, "distributions": {
                                    "nominal_scale.m1": {"kind": "uniform", "low": 0.8, "high": 1.2}}}})
        path = tmp_path / f"r{n}.jsonl"
        with path.open("w") as fh:
            fh.write(json.dumps(spec.header()) + "\n")
            for run in spec.runs:
                metrics = {m: float(rng.random()) if m.endswith("_mm") else rng.random(4).tolist() for m in METRICS}
                fh.write(json.dumps({"run_id": run.run_id, "index": run.index, "values": run.values, "status": "ok",
                                     "metrics": metrics, "engine": "batch", "seconds": 0.001}) + "\n")

        def pending():
            finished = {row["run_id"] for row in ResultsFile(path, read_header(path)).rows()}
            return [i for i in range(len(spec.runs)) if spec.runs.run_id(i) not in finished]

        plan = spec.plan.group.nbytes + spec.plan.substeps.nbytes + spec.plan.noise.nbytes     # held throughout
        peaks[n] = _peak(pending) + _peak(lambda: summarize(path, spec)) + plan
    assert (peaks[4000] - peaks[1000]) / 3000 <= SWEEP_RUN_BYTES
