"""One results file, one sweep: its definition recorded, one writer at a time, rows of other runs left out,
unusable lines listed, and Ctrl-C or a failed connection leaving nothing partial."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

from analysis.jobs.files import row_line
from analysis.sweep.runner import read_results, run_sweep
from analysis.sweep.spec import SweepError, load_sweep
from analysis.sweep.summary import summarize, write_summary

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def short_file(tmp_path):
    """The first 0.3 s of the paper scenario (its 10 s path), as a file the sweep files refer to."""
    return write_short_scenario(tmp_path, t_final=0.3)


_write = write_sweep

_cli = run_sweep_command


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _wait_for_file(path: Path, proc, seconds: float = 1800) -> None:
    """Until ``path`` exists; the limit only guards against a hung run (a slow machine is not a failure)."""
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert proc.poll() is None, ("the sweep ended before it could be stopped", proc.communicate())
        assert time.monotonic() < deadline, "the sweep wrote no row"
        time.sleep(0.05)


GRID = '[grid]\n"gains.kp" = [{}]\n[outputs]\nmetrics = ["rms_position_error", "max_tool_position_error_mm"]\n'


def test_an_edited_grid_is_refused_and_restart_moves_the_old_file_aside(tmp_path, short_file, capsys):
    path = _write(tmp_path, GRID.format("150, 200"))
    results = tmp_path / "s-results.jsonl"
    assert _cli(["sweep", str(path), "--workers", "1", "--no-progress"]) == 0
    before = results.read_bytes()
    path.write_text('scenario = "short.toml"\n' + GRID.format("150, 250, 300"), encoding="utf-8")
    capsys.readouterr()
    assert _cli(["sweep", str(path), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "[grid]" in err and "--restart" in err and "belongs to sweep 's'" in err
    assert results.read_bytes() == before                          # nothing appended to the old sweep's file
    assert _cli(["sweep", str(path), "--workers", "1", "--no-progress", "--restart"]) == 0
    out = capsys.readouterr().out
    (old,) = tmp_path.glob("s-results.old-*.jsonl")
    assert f"moved to {old}" in out and old.read_bytes() == before
    header, rows = read_results(results)
    assert header["grid"] == {"gains.kp": [150, 250, 300]} and sorted(r["index"] for r in rows) == [0, 1, 2]
    summary = json.loads((tmp_path / "s-summary" / "summary.json").read_text())
    assert summary["counts"] == {"runs": 3, "finished": 3, "ok": 3, "diverged": 0}
    assert summary["sweep"]["grid"] == {"gains.kp": [150, 250, 300]}
    assert {w["values"]["gains.kp"] for w in summary["worst"]} <= {150, 250, 300}


def test_a_results_file_without_a_definition_is_refused(tmp_path, short_file):
    spec = load_sweep(_write(tmp_path, GRID.format("150")))
    results = tmp_path / "old.jsonl"
    row = {"run_id": spec.runs[0].run_id, "index": 0, "values": {"gains.kp": 150}, "status": "ok", "metrics": {}}
    results.write_text(json.dumps({"sweep": {"name": "s", "runs": 1}}) + "\n" + json.dumps(row) + "\n")
    with pytest.raises(SweepError, match="older dobkit"):
        run_sweep(spec, results, workers=1, progress=False)
    with pytest.raises(SweepError, match="does not start with a sweep header"):
        (tmp_path / "notes.jsonl").write_text("my notes\n")
        run_sweep(spec, tmp_path / "notes.jsonl", workers=1, progress=False)


def test_renaming_or_reranking_keeps_the_finished_runs(tmp_path, short_file):
    results = tmp_path / "r.jsonl"
    run_sweep(load_sweep(_write(tmp_path, GRID.format("150, 200") + "worst_count = 2\n")), results, workers=1,
              progress=False)
    rows = read_results(results)[1]
    renamed = load_sweep(_write(tmp_path, 'name = "t"\ndescription = "the same runs"\n' + GRID.format("150, 200")
                                + "worst_count = 1\n"))
    outcome = run_sweep(renamed, results, workers=1, progress=False)
    assert (outcome.skipped, outcome.ran) == (2, 0)
    header, again = read_results(results)
    assert (header["name"], header["worst_count"], header["description"]) == ("t", 1, "the same runs")
    assert again == rows


def test_a_second_sweep_on_one_results_file_says_who_holds_it(tmp_path, short_file):
    path = _write(tmp_path, GRID.format(", ".join(str(100 + 10 * i) for i in range(12))) + "[batch]\nsize = 1\n")
    results, marker = tmp_path / "r.jsonl", tmp_path / "first-batch-written"
    # the first sweep holds the file after its first batch (it says so in the marker) until it is killed
    code = ("import time; from pathlib import Path; from analysis.sweep.runner import run_sweep; "
            f"held = lambda rows: (Path({str(marker)!r}).write_text('1'), time.sleep(3600)); "
            f"run_sweep({str(path)!r}, {str(results)!r}, workers=1, progress=False, on_rows=held)")
    proc = subprocess.Popen([sys.executable, "-c", code], env=_env())
    try:
        _wait_for_file(marker, proc)
        with pytest.raises(SweepError) as err:
            run_sweep(load_sweep(path), results, workers=1, progress=False)
        assert f"pid {proc.pid}" in str(err.value) and "in use" in str(err.value)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    outcome = run_sweep(load_sweep(path), results, workers=1, progress=False)     # the lock ended with it
    rows = read_results(results)[1]
    assert outcome.skipped + outcome.ran == 12
    assert len(rows) == 12 == len({r["run_id"] for r in rows})
    assert not results.with_name("r.jsonl.lock").exists()


def test_rows_of_other_runs_and_repeated_rows_are_left_out(tmp_path, short_file):
    spec = load_sweep(_write(tmp_path, GRID.format("150, 200, 250")))
    results = tmp_path / "r.jsonl"
    run_sweep(spec, results, workers=1, progress=False)
    rows = read_results(results)[1]
    foreign = dict(rows[1], run_id="0123456789abcdef", metrics={"rms_position_error": [9.0] * 4,
                                                               "max_tool_position_error_mm": 99.0})
    beyond = dict(rows[0], run_id="fedcba9876543210", index=99)
    with results.open("a") as fh:          # whole rows as a writer writes them (checksummed)
        for row in (foreign, rows[0], beyond):
            fh.write(row_line(row))
    summary = summarize(results, spec)
    assert summary.counts.finished == 3 and summary.statistics["max_tool_position_error_mm"].max < 99.0
    assert any("2 row(s) of runs that are not in this sweep" in p for p in summary.problems)
    assert any("1 repeated row" in p for p in summary.problems)
    files = write_summary(results, tmp_path / "sum", spec=spec)
    assert "Left out of this summary" in files["markdown"].read_text()


def test_unusable_lines_are_listed_and_their_runs_done_again(tmp_path, short_file):
    spec = load_sweep(_write(tmp_path, GRID.format("150, 200, 250")))
    results = tmp_path / "r.jsonl"
    run_sweep(spec, results, workers=1, progress=False)
    lines = results.read_text().splitlines(keepends=True)
    broken = json.loads(lines[2])
    del broken["values"]
    lines[2] = row_line(broken)                              # checksummed: only the row's own check refuses it
    results.write_text("".join(lines) + "not json at all\n")
    summary = summarize(results, spec)                     # a KeyError traceback before
    assert summary.counts.finished == 2
    assert any(p.startswith("line 3: missing values") for p in summary.problems)
    assert any(p.startswith("line 5: not JSON") for p in summary.problems)
    outcome = run_sweep(spec, results, workers=1, progress=False)
    assert outcome.ran == 1 and len(outcome.problems) == 2
    assert summarize(results, spec).counts.finished == 3


@pytest.mark.parametrize("workers", ["0", "-5", "two", "1.5"])
def test_workers_must_be_a_whole_number_of_at_least_one(tmp_path, short_file, workers, capsys):
    path = _write(tmp_path, GRID.format("150"))
    with pytest.raises(SystemExit) as exit_:
        _cli(["sweep", str(path), "--workers", workers])
    assert exit_.value.code == 2 and "--workers must be a whole number >= 1" in capsys.readouterr().err
    with pytest.raises(SweepError, match="workers must be a whole number >= 1"):
        run_sweep(load_sweep(path), tmp_path / "r.jsonl", workers=0, progress=False)
    assert not (tmp_path / "r.jsonl").exists() and not (tmp_path / "s-results.jsonl").exists()


def test_an_unreachable_dask_scheduler_leaves_no_results_file(tmp_path, short_file):
    pytest.importorskip("distributed")
    results = tmp_path / "r.jsonl"
    with pytest.raises(SweepError, match="cannot reach the Dask scheduler"):
        run_sweep(load_sweep(_write(tmp_path, GRID.format("150"))), results, scheduler="tcp://127.0.0.1:9",
                  progress=False, scheduler_timeout=1.0)
    assert not results.exists() and not results.with_name("r.jsonl.lock").exists()


# `dobkit sweep ...` whose run waits, after writing its first batch, for the Ctrl-C: it says so in the marker file
# (argv[1]).  The interrupt then arrives mid-sweep however fast or slow the machine is; the sweep itself is the real one.
_HELD_AFTER_FIRST_BATCH = """
import signal, sys, time
from pathlib import Path
signal.signal(signal.SIGINT, signal.default_int_handler)   # as at a terminal, even if started with Ctrl-C ignored
import analysis.sweep.runner as runner
from dobkit.cli import main
marker, run_sweep = Path(sys.argv[1]), runner.run_sweep

def wait_for_ctrl_c(rows):
    marker.write_text(str(len(rows)))
    while True:
        time.sleep(0.01)

runner.run_sweep = lambda *args, **kwargs: run_sweep(*args, on_rows=wait_for_ctrl_c, **kwargs)
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
def test_ctrl_c_ends_the_sweep_in_one_line_keeping_whole_rows(tmp_path, short_file):
    runs = 12
    path = _write(tmp_path, GRID.format(", ".join(str(100 + 0.5 * i) for i in range(runs))) + "[batch]\nsize = 1\n")
    results, marker = tmp_path / "s-results.jsonl", tmp_path / "first-batch-written"
    # a session of its own: Ctrl-C on a terminal reaches the whole process group, workers included
    proc = subprocess.Popen([sys.executable, "-c", _HELD_AFTER_FIRST_BATCH, str(marker), "sweep", str(path),
                             "--workers", "2", "--no-progress"],
                            env=_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _wait_for_file(marker, proc)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, (out, err)
    # the workers' notes of a first numba compile (a cold cache) come before; the interrupt says one line
    lines = [line for line in err.strip().splitlines() if not line.startswith(("dobkit: compiling", "dobkit: compiled"))]
    assert "Traceback" not in err and len(lines) == 1 and "interrupted" in lines[0], err
    assert str(results) in lines[0] and "resumes" in lines[0]
    data = results.read_bytes()
    assert data.endswith(b"\n") and all(json.loads(line) for line in data.splitlines())
    rows = read_results(results)[1]
    assert len(rows) == int(marker.read_text()) == 1          # the first batch (one run), whole; nothing after it
    assert not results.with_name(results.name + ".lock").exists()
    assert not (tmp_path / "s-summary").exists() and not list(tmp_path.glob(".*partial*"))
    outcome = run_sweep(load_sweep(path), results, workers=1, progress=False)
    assert (outcome.skipped, outcome.ran) == (len(rows), runs - len(rows))
