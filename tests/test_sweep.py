"""Sweeps: validation before any run, resumable results, agreement of batch, single-run and Dask execution."""
from __future__ import annotations

import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import PAPER_FR

import blocks
from analysis.sweep import spec as sweep
from analysis.sweep.runner import read_results, run_sweep
from analysis.sweep.spec import SweepError, load_sweep, sweep_from_dict
from analysis.sweep.summary import html_section, summarize, write_summary
from blocks.figure2.batch import METRIC_ATOL, METRIC_RTOL, simulate_batch
from blocks.plumbing.progress import CountProgress
from dobkit.sweep_commands import add_sweep_subcommand

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def scenario_file(tmp_path):
    """The first 0.5 s of the paper scenario (its 10 s path), as a file the sweep files refer to."""
    path = tmp_path / "short.toml"
    short = blocks.load_scenario("paper").replace(simulation={"t_final": 0.5}, trajectory={"duration": 10.0})
    path.write_text(short.to_toml(), encoding="utf-8")
    return path


def _sweep(tmp_path, text: str, name: str = "s") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text('scenario = "short.toml"\n' + text, encoding="utf-8")
    return path


GRID_MC = """
[grid]
"gains.kp" = [120, 200]
[monte_carlo]
runs = 3
seed = 7
[monte_carlo.distributions]
"nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
"disturbance.f_r[2]" = {kind = "normal", mean = 1.4, std = 0.2}
[outputs]
metrics = ["rms_position_error", "max_tool_position_error_mm", "rms_disturbance_error"]
"""


def test_runs_are_the_grid_times_the_draws(tmp_path, scenario_file):
    spec = load_sweep(_sweep(tmp_path, GRID_MC))
    assert len(spec.runs) == 6
    assert [r.values["gains.kp"] for r in spec.runs] == [120] * 3 + [200] * 3
    # the same draws at every grid point, reproducible from the seed
    assert [r.values["nominal_scale.m1"] for r in spec.runs[:3]] == [r.values["nominal_scale.m1"] for r in spec.runs[3:]]
    assert [r.run_id for r in load_sweep(_sweep(tmp_path, GRID_MC)).runs] == [r.run_id for r in spec.runs]
    assert len({r.run_id for r in spec.runs}) == 6


def test_rows_equal_a_direct_batch_and_the_single_runs(tmp_path, scenario_file):
    spec = load_sweep(_sweep(tmp_path, GRID_MC))
    outcome = run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    assert (outcome.total, outcome.skipped, outcome.ran, outcome.diverged) == (6, 0, 6, 0)
    _, rows = read_results(tmp_path / "r.jsonl")
    rows = sorted(rows, key=lambda r: r["index"])
    # the element key written out by hand: the whole Eq. 4 vector with its third entry drawn
    records = [{"gains.kp": r.values["gains.kp"], "nominal_scale.m1": r.values["nominal_scale.m1"],
                "disturbance.f_r": [*PAPER_FR[:2], r.values["disturbance.f_r[2]"], PAPER_FR[3]]} for r in spec.runs]
    direct = simulate_batch(spec.base, records, metrics=spec.metrics, method="RK4")   # the sweep's RK4
    for i, row in enumerate(rows):
        assert row["status"] == "ok" and set(row["metrics"]) == set(spec.metrics)
        for name, value in row["metrics"].items():
            np.testing.assert_allclose(value, direct.metrics[name][i], rtol=1e-12)
    # the same sweep run one blocks.simulate at a time agrees to the batch's stated tolerance
    single = load_sweep(_sweep(tmp_path, 'engine = "fast"\n' + GRID_MC, name="single"))
    run_sweep(single, tmp_path / "single.jsonl", workers=1, progress=False)
    _, single_rows = read_results(tmp_path / "single.jsonl")
    for a, b in zip(rows, sorted(single_rows, key=lambda r: r["index"])):
        assert a["values"] == b["values"]
        for name in a["metrics"]:
            np.testing.assert_allclose(a["metrics"][name], b["metrics"][name], rtol=METRIC_RTOL, atol=METRIC_ATOL)


def test_local_processes_give_the_in_process_rows(tmp_path, scenario_file):
    spec = load_sweep(_sweep(tmp_path, GRID_MC))
    run_sweep(spec, tmp_path / "one.jsonl", workers=1, progress=False)
    run_sweep(spec, tmp_path / "two.jsonl", workers=2, progress=False)
    _assert_same_rows(tmp_path / "one.jsonl", tmp_path / "two.jsonl")


def _assert_same_rows(a: Path, b: Path) -> None:
    rows_a = {r["run_id"]: r for r in read_results(a)[1]}
    rows_b = {r["run_id"]: r for r in read_results(b)[1]}
    assert rows_a.keys() == rows_b.keys()
    for run_id, row in rows_a.items():
        assert row["values"] == rows_b[run_id]["values"] and row["status"] == rows_b[run_id]["status"]
        for name, value in row["metrics"].items():
            np.testing.assert_allclose(value, rows_b[run_id]["metrics"][name], rtol=1e-12, atol=0)


def test_a_killed_sweep_resumes_without_redoing_or_losing_runs(tmp_path, scenario_file):
    path = _sweep(tmp_path, """
[grid]
"gains.kp" = [100, 130, 160, 190, 220, 250, 280, 310]
[batch]
size = 1
""")
    results, marker = tmp_path / "r.jsonl", tmp_path / "three-rows-written"
    # the sweep holds after its third row (it says so in the marker) until it is killed: the kill lands half way
    # however loaded the machine (watching the file raced the last five runs, ~17 ms each)
    code = ("import time; from pathlib import Path; from analysis.sweep.runner import run_sweep; seen = []\n"
            "def held(rows):\n"
            "    seen.extend(rows)\n"
            "    if len(seen) >= 3:\n"
            f"        Path({str(marker)!r}).write_text(str(len(seen))); time.sleep(3600)\n"
            f"run_sweep({str(path)!r}, {str(results)!r}, workers=1, progress=False, on_rows=held)")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", code], env=env)
    try:
        deadline = time.monotonic() + 1800                # guards a hung run only (a cold numba cache compiles)
        while not marker.exists():
            assert proc.poll() is None, "the sweep ended before it could be killed"
            assert time.monotonic() < deadline, "the sweep wrote no third row"
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    before = read_results(results)[1]
    assert 3 <= len(before) < 8, "the sweep should have been killed half way"
    with results.open("a", encoding="utf-8") as fh:       # as if killed in the middle of writing a row
        fh.write('{"run_id": "half a li')
    outcome = run_sweep(load_sweep(path), results, workers=1, progress=False)
    assert outcome.skipped == len(before) and outcome.ran == 8 - len(before)
    header, after = read_results(results)
    assert header["runs"] == 8
    assert sorted(r["run_id"] for r in after) == sorted(r.run_id for r in load_sweep(path).runs)
    assert after[:len(before)] == before                    # finished rows kept as they were
    again = run_sweep(load_sweep(path), results, workers=1, progress=False)
    assert (again.skipped, again.ran) == (8, 0)


def test_keys_outside_the_batch_split_the_sweep(tmp_path, scenario_file):
    spec = load_sweep(_sweep(tmp_path, """
[grid]
"trajectory.stitches" = [3, 5]
"gains.kp" = [150, 250]
[outputs]
metrics = ["rms_position_error"]
"""))
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    rows = {r["index"]: r for r in read_results(tmp_path / "r.jsonl")[1]}
    three = spec.base.replace(trajectory={"stitches": 3})
    direct = simulate_batch(three, [{"gains.kp": 150}, {"gains.kp": 250}], metrics=("rms_position_error",),
                            method="RK4")
    np.testing.assert_allclose(rows[0]["metrics"]["rms_position_error"], direct.metrics["rms_position_error"][0],
                               rtol=1e-12)
    np.testing.assert_allclose(rows[1]["metrics"]["rms_position_error"], direct.metrics["rms_position_error"][1],
                               rtol=1e-12)


BAD = {
    "unknown top-level key": ('[grids]\n"gains.kp" = [1]\n', ["grids"]),
    "unknown scenario key": ('[grid]\n"gains.kq" = [1, 2]\n', ["gains.kq"]),
    "unknown section": ('[grid]\n"gain.kp" = [1, 2]\n', ["gain.kp"]),
    "empty grid": ('[grid]\n"gains.kp" = []\n', ["gains.kp", "empty"]),
    "repeated grid value": ('[grid]\n"gains.kp" = [1, 1]\n', ["gains.kp", "repeats"]),
    "nothing varied": ("", ["varies nothing"]),
    "bad element index": ('[grid]\n"disturbance.f_r[7]" = [1.0]\n', ["disturbance.f_r[7]", "element 7"]),
    "unknown distribution kind": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                                  '"robot.m1" = {kind = "gauss", mean = 1, std = 1}\n', ["robot.m1", "kind"]),
    "unknown distribution parameter": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                                       '"robot.m1" = {kind = "uniform", low = 1, hgh = 2}\n',
                                       ["robot.m1", "hgh", "missing ['high']"]),
    "low above high": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                       '"robot.m1" = {kind = "uniform", low = 2, high = 1}\n', ["robot.m1", "low"]),
    "negative std": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                     '"robot.m1" = {kind = "normal", mean = 5, std = -1}\n', ["robot.m1", "std"]),
    "empty choice": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                     '"noise.seed" = {kind = "choice", values = []}\n', ["noise.seed", "values"]),
    "bad weights": ('[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                    '"noise.seed" = {kind = "choice", values = [1, 2], weights = [1]}\n', ["noise.seed", "weights"]),
    "no runs": ('[monte_carlo]\nruns = 0\n[monte_carlo.distributions]\n'
                '"robot.m1" = {kind = "uniform", low = 1, high = 2}\n', ["monte_carlo.runs"]),
    "key in grid and draws": ('[grid]\n"robot.m1" = [5.0]\n[monte_carlo]\nruns = 2\n[monte_carlo.distributions]\n'
                              '"robot.m1" = {kind = "uniform", low = 1, high = 2}\n', ["robot.m1", "both"]),
    "a drawn value is invalid": ('[monte_carlo]\nruns = 30\nseed = 3\n[monte_carlo.distributions]\n'
                                 '"nominal_scale.m1" = {kind = "normal", mean = 0.2, std = 0.5}\n',
                                 ["nominal_scale.m1", "run "]),
    "an invalid grid value": ('[grid]\n"gains.kp" = [100, -5]\n', ["run 1", "gains.kp", "> 0"]),
    "an invalid shared value": ('[grid]\n"trajectory.stitches" = [1]\n', ["run 0", "stitches"]),
    "unknown metric": ('[grid]\n"gains.kp" = [1]\n[outputs]\nmetrics = ["rms"]\n', ["outputs.metrics", "rms"]),
    "bad batch size": ('[grid]\n"gains.kp" = [1]\n[batch]\nsize = 0\n', ["batch.size"]),
    "bad substeps": ('[grid]\n"gains.kp" = [1]\n[batch]\nsubsteps = "fine"\n', ["batch.substeps", "auto"]),
    "unknown batch key": ('[grid]\n"gains.kp" = [1]\n[batch]\nsizes = 2\n', ["batch.sizes", "size, substeps"]),
    "observer not true/false": ('observer = "yes"\n[grid]\n"gains.kp" = [1]\n', ["'observer'", "true or false"]),
    "bad engine": ('engine = "gpu"\n[grid]\n"gains.kp" = [1]\n', ["'engine'", "gpu"]),
    "grid not a table": ('grid = 3\n', ["'grid'", "table"]),
    "runs missing": ('[monte_carlo]\nseed = 1\n[monte_carlo.distributions]\n'
                     '"robot.m1" = {kind = "uniform", low = 1, high = 2}\n', ["monte_carlo.runs"]),
    "no distributions": ('[monte_carlo]\nruns = 2\n', ["monte_carlo.distributions", "empty"]),
    "negative seed": ('[monte_carlo]\nruns = 2\nseed = -1\n[monte_carlo.distributions]\n'
                      '"robot.m1" = {kind = "uniform", low = 1, high = 2}\n', ["monte_carlo.seed", ">= 0"]),
    "bad worst count": ('[grid]\n"gains.kp" = [1]\n[outputs]\nworst_count = 0\n', ["outputs.worst_count"]),
    "worst metric not kept": ('[grid]\n"gains.kp" = [1]\n[outputs]\nmetrics = ["rms_position_error"]\n'
                              'worst_metric = "rms_tau"\n', ["outputs.worst_metric", "rms_position_error[0]"]),
    "metric needs the observer": ('observer = false\n[grid]\n"gains.kp" = [1]\n[outputs]\n'
                                  'metrics = ["rms_disturbance_error"]\n', ["outputs.metrics", "needs the observer"]),
    "key of another trajectory kind": ('[grid]\n"trajectory.omega" = [1.0]\n', ["trajectory.omega", "stitches"]),
    # a name is used in file names: one plain component, never a path
    "name climbing out": ('name = "../../../x"\n[grid]\n"gains.kp" = [1]\n', ["'name'", "plain file name"]),
    "absolute name": ('name = "/tmp/x"\n[grid]\n"gains.kp" = [1]\n', ["'name'", "no folders"]),
    "name with a folder": ('name = "a/b"\n[grid]\n"gains.kp" = [1]\n', ["'name'", "plain file name"]),
    "hidden name": ('name = ".x"\n[grid]\n"gains.kp" = [1]\n', ["'name'", "starting with a letter or digit"]),
    "empty name": ('name = ""\n[grid]\n"gains.kp" = [1]\n', ["'name'", "plain file name"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_sweep_files_fail_before_any_run_naming_the_key(tmp_path, scenario_file, case, capsys):
    text, words = BAD[case]
    path = _sweep(tmp_path, text)
    with pytest.raises(SweepError) as err:
        load_sweep(path)
    for word in words:
        assert word in str(err.value), str(err.value)
    args = _cli(["sweep", str(path), "--results", str(tmp_path / "r.jsonl"), "--no-progress"])
    assert args.func(args) == 2
    assert not (tmp_path / "r.jsonl").exists()
    assert words[0] in capsys.readouterr().err


def test_a_file_name_that_cannot_name_files_asks_for_a_name(tmp_path, scenario_file):
    path = _sweep(tmp_path, '[grid]\n"gains.kp" = [150]\n', name="my sweep")
    with pytest.raises(SweepError, match="give a plain 'name'"):
        load_sweep(path)
    path.write_text('name = "my-sweep"\nscenario = "short.toml"\n[grid]\n"gains.kp" = [150]\n')
    assert load_sweep(path).name == "my-sweep"


def test_a_results_file_of_another_sweep_is_refused(tmp_path, scenario_file):
    a = load_sweep(_sweep(tmp_path, '[grid]\n"gains.kp" = [150]\n', name="a"))
    b = load_sweep(_sweep(tmp_path, '[grid]\n"gains.kp" = [160]\n', name="b"))
    run_sweep(a, tmp_path / "r.jsonl", workers=1, progress=False)
    with pytest.raises(SweepError, match="belongs to sweep 'a'"):
        run_sweep(b, tmp_path / "r.jsonl", workers=1, progress=False)


def _cli(argv):
    import argparse
    parser = argparse.ArgumentParser(prog="dobkit")
    add_sweep_subcommand(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


def test_cli_runs_and_summarises_with_plots(tmp_path, scenario_file, capsys):
    path = _sweep(tmp_path, GRID_MC + "worst_count = 2\n")
    args = _cli(["sweep", str(path), "--no-progress", "--workers", "1"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "6 runs done now" in out
    summary_dir = tmp_path / "s-summary"
    summary = json.loads((summary_dir / "summary.json").read_text())
    assert summary["counts"] == {"runs": 6, "finished": 6, "ok": 6, "diverged": 0}
    stats = summary["statistics"]["max_tool_position_error_mm"]
    assert stats["min"] <= stats["median"] <= stats["max"] and stats["unit"] == "mm"
    worst = [w["max_tool_position_error_mm"] for w in summary["worst"]]
    assert len(worst) == 2 and worst[0] >= worst[1] and worst[0] == stats["max"]
    assert set(summary["worst"][0]["values"]) == {"gains.kp", "nominal_scale.m1", "disturbance.f_r[2]"}
    markdown = (summary_dir / "summary.md").read_text()
    assert "Worst 2 runs" in markdown and "hist_rms_position_error.png" in markdown
    for stem in ("hist_rms_position_error", "hist_max_tool_position_error_mm", "worst_vs_gains_kp"):
        assert (summary_dir / f"{stem}.png").stat().st_size > 0 and (summary_dir / f"{stem}.svg").exists()
    section = html_section(summary_dir)
    assert section.startswith("<section") and "data:image/png;base64," in section and "Worst runs" in section
    args = _cli(["sweep", str(path), "--check"])
    assert args.func(args) == 0 and "6 runs, valid" in capsys.readouterr().out


def test_summary_lists_diverged_runs(tmp_path):
    rows = [{"run_id": "a", "index": 0, "values": {"gains.kd": 36.0}, "status": "ok",
             "metrics": {"rms_position_error": [1e-3, 2e-3, 3e-4, 1e-4]}},
            {"run_id": "b", "index": 1, "values": {"gains.kd": 5000.0}, "status": "diverged", "metrics": {},
             "failed_at": 0.02}]
    summary = summarize(({"name": "x", "runs": 2, "worst_metric": "rms_position_error[1]"}, rows))
    assert summary.counts.diverged == 1 and summary.failed[0].values == {"gains.kd": 5000.0}
    assert summary.statistics["rms_position_error[2]"].unit == "m"
    files = write_summary(({"name": "x", "runs": 2, "worst_metric": "rms_position_error[1]"}, rows), tmp_path)
    assert "Diverged runs" in files["markdown"].read_text()


def test_progress_bar_reports_counts():
    stream = io.StringIO()
    bar = CountProgress(10, done=2, stream=stream)
    bar.update(3)
    bar.update(5)
    bar.close()
    text = stream.getvalue()
    assert "2/10 runs" in text and "5/10 runs" in text and "10/10 runs 100%" in text


def test_dask_cluster_gives_the_local_rows(tmp_path, scenario_file):
    distributed = pytest.importorskip("distributed")
    spec = load_sweep(_sweep(tmp_path, GRID_MC))
    run_sweep(spec, tmp_path / "local.jsonl", workers=1, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as cluster:
        outcome = run_sweep(spec, tmp_path / "dask.jsonl", scheduler=cluster.scheduler_address, progress=False)
    assert outcome.ran == 6
    _assert_same_rows(tmp_path / "local.jsonl", tmp_path / "dask.jsonl")


def test_sweep_from_dict_without_a_file():
    spec = sweep_from_dict({"scenario": "paper", "grid": {"gains.kp": [100, 200]}})
    assert len(spec.runs) == 2 and spec.base.name == "paper"


def test_rows_do_not_depend_on_how_runs_are_batched(tmp_path, scenario_file):
    grid = """
[grid]
"noise.q_std" = [[0.0, 0.0, 0.0, 0.0], [1e-4, 1e-4, 1e-4, 1e-4]]
"gains.kd" = [30, 90]
[outputs]
metrics = ["rms_position_error"]
"""
    run_sweep(load_sweep(_sweep(tmp_path, grid + "[batch]\nsize = 1\n", name="s")), tmp_path / "small.jsonl",
              workers=1, progress=False)
    run_sweep(load_sweep(_sweep(tmp_path, grid + "[batch]\nsize = 4\n", name="s")), tmp_path / "large.jsonl",
              workers=1, progress=False)
    _assert_same_rows(tmp_path / "small.jsonl", tmp_path / "large.jsonl")


def _paper_file(**sections) -> blocks.Scenario:
    """The paper scenario file with some keys set by hand, as a person edits the TOML."""
    from conftest import paper_toml_dict
    data = paper_toml_dict()
    for section, values in sections.items():
        data.setdefault(section, {}).update(values)
    return blocks.scenario_from_dict(data, source="paper")


@pytest.mark.parametrize("engine", ["batch", "fast"])
def test_each_run_is_the_base_file_edited_by_hand(engine):
    from blocks.figure2.batch import Variants
    spec = sweep_from_dict({"scenario": "paper", "engine": engine,
                            "grid": {"disturbance.f_r[2]": [1.0, 2.0], "trajectory.stitches": [3],
                                     "gains.kp": [150]}})
    assert [r.values for r in spec.runs] == [{"disturbance.f_r[2]": 1.0, "trajectory.stitches": 3, "gains.kp": 150},
                                             {"disturbance.f_r[2]": 2.0, "trajectory.stitches": 3, "gains.kp": 150}]
    for run, third in zip(spec.runs, (1.0, 2.0)):
        by_hand = _paper_file(disturbance={"f_r": [PAPER_FR[0], PAPER_FR[1], third, PAPER_FR[3]]},
                              trajectory={"stitches": 3}, gains={"kp": 150})
        assert spec.scenario(run) == by_hand
        # the way the runner builds it: the batch's shared scenario, then the member's values
        shared, member = sweep.split_changes(run.values)
        assert shared == {"trajectory.stitches": 3}
        assert member == {"disturbance.f_r[2]": third, "gains.kp": 150}
        group = spec.base.with_changes(shared)
        assert group == _paper_file(trajectory={"stitches": 3})
        variants = Variants(group, [member])
        assert variants.scenario(0) == by_hand
        np.testing.assert_array_equal(variants.disturbance.f_r[0], by_hand.disturbance.f_r)
        np.testing.assert_array_equal(variants.kp[:, 0], np.diag(by_hand.kp))


_CUDA_SWEEP = r"""
import json, sys
from pathlib import Path
import numpy as np
import blocks
from analysis.sweep.runner import read_results, run_sweep
from analysis.sweep.spec import load_sweep
folder = Path(sys.argv[1])
short = blocks.load_scenario("paper").replace(simulation={"t_final": 0.05}, trajectory={"duration": 10.0})
(folder / "short.toml").write_text(short.to_toml(), encoding="utf-8")
bodies = {"grid": '[grid]\n"gains.kp" = [120, 200]\n"nominal_scale.m1" = [0.9, 1.1]\n',
          "morris": '[sensitivity]\nmethod = "morris"\nsamples = 2\nseed = 1\n[sensitivity.distributions]\n'
                    '"gains.kp" = {kind = "uniform", low = 120, high = 200}\n'}
worst, rows = 0.0, {}
for kind, body in bodies.items():
    for engine in ("cuda", "batch"):
        path = folder / f"{kind}-{engine}.toml"
        path.write_text(f'scenario = "short.toml"\nengine = "{engine}"\n' + body, encoding="utf-8")
        run_sweep(load_sweep(path), folder / f"{kind}-{engine}.jsonl", workers=2, progress=False)
        rows[engine] = rows.get(engine, []) + sorted(read_results(folder / f"{kind}-{engine}.jsonl")[1],
                                                     key=lambda r: r["index"])
for a, b in zip(rows["cuda"], rows["batch"]):
    assert a["values"] == b["values"] and a["status"] == b["status"] == "ok"
    for name, value in b["metrics"].items():
        x, y = np.asarray(a["metrics"][name]), np.asarray(value)
        worst = max(worst, float(np.max(np.abs(x - y) / np.maximum(np.abs(y), 1e-12))))
from blocks.engines.gpu.batch import last_timings       # filled by each GPU batch: the runs went through the device
print(json.dumps({"worst": worst, "runs": len(rows["cuda"]), "engines": sorted({r["engine"] for r in rows["cuda"]}),
                  "device": "device" in last_timings,
                  "moves": float(np.ptp([r["metrics"]["rms_position_error"][0] for r in rows["cuda"]]))}))
"""


def _python(code: str, *args, env: dict | None = None) -> dict:
    """``code`` in a fresh interpreter (numba's CUDA target reads its environment once, on import); its last stdout
    line as JSON."""
    done = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), **(env or {})), timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_cuda_sweep_where_it_cannot_run_is_refused_when_checked_naming_what_is_missing(tmp_path, scenario_file):
    # before anything else of the file is checked, so before any run: the grid key here is bad too
    from blocks.engines.gpu.device import cuda_unavailable_reason
    reason = cuda_unavailable_reason()
    if reason is None:
        pytest.skip("this machine can run engine = 'cuda'")
    with pytest.raises(SweepError) as err:
        load_sweep(_sweep(tmp_path, 'engine = "cuda"\n[grid]\n"gains.nonsense" = [1, 2]\n'))
    message = str(err.value)
    assert "\n" not in message and 'engine = "cuda" cannot run here' in message and reason in message
    assert "numba-cuda" in message and 'engine = "batch"' in message


def test_without_numba_cuda_a_cuda_sweep_is_refused_naming_the_extra():
    code = ("import json, sys\nsys.modules['numba_cuda'] = None\n"      # numba-cuda hidden from the import system
            "from analysis.sweep.spec import SweepError, sweep_from_dict\n"
            "try:\n    sweep_from_dict({'engine': 'cuda', 'grid': {'gains.kp': [100, 200]}})\n"
            "except SweepError as err:\n    print(json.dumps(str(err)))\n")
    message = _python(code)
    assert 'engine = "cuda" cannot run here: numba-cuda is not installed' in message and "dobkit[gpu]" in message


@pytest.mark.skipif(importlib.util.find_spec("numba_cuda") is None, reason="numba-cuda is not installed")
def test_a_cuda_sweep_in_the_cuda_simulator_gives_the_cpu_batch_rows(tmp_path):
    # a grid sweep and a Morris sensitivity sweep, every run one thread of numba-cuda's simulator, in one process
    # (workers = 2 asked, one device), against the CPU batch sweep of the same file: the same runs and rows, the
    # numbers to rounding
    out = _python(_CUDA_SWEEP, tmp_path, env={"NUMBA_ENABLE_CUDASIM": "1"})
    assert out["runs"] == 4 + 4 and out["engines"] == ["cuda"] and out["device"]     # the grid's, Morris' r (k + 1)
    assert out["moves"] > 0                     # the runs differ: the comparison is not of one run
    assert out["worst"] <= 1e-9


@pytest.mark.skipif(importlib.util.find_spec("numba_cuda") is None or importlib.util.find_spec("pinocchio") is None,
                    reason="numba-cuda and pinocchio are needed")
def test_a_cuda_sweep_of_runs_the_gpu_cannot_batch_is_refused_while_planned():
    # a URDF arm's nominal model is generated into the loop's code: members of other nominal mass scales cannot
    # share one kernel, and the sweep says so while its runs are planned, before any run
    code = ("import json\nfrom analysis.sweep.spec import SweepError, sweep_from_dict\n"
            "try:\n    sweep_from_dict({'scenario': 'scope4', 'engine': 'cuda', "
            "'grid': {'arm.nominal_mass_scale': [0.9, 1.1]}})\n"
            "except SweepError as err:\n    print(json.dumps(str(err)))\n")
    message = _python(code, env={"NUMBA_ENABLE_CUDASIM": "1"})
    assert 'engine = "cuda" cannot run run 0' in message and "'arm.nominal_mass_scale' differs" in message
    assert "\n" not in message
