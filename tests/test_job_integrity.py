"""The job logs' integrity (analysis.jobs.files): a checksum per row, conflicting repeats refused naming both
lines, bytes that are not UTF-8 named with the remedy, and Ctrl-C on a sweep with worker processes in one line."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

from analysis.jobs.files import JobLog, row_line
from analysis.sweep.runner import RESULTS_LOG, read_results, run_sweep
from analysis.sweep.spec import SweepError, load_sweep
from analysis.sweep.summary import summarize
from analysis.tune.evaluate import gains_key
from analysis.tune.runner import EVALUATION_LOG, read_log
from analysis.tune.spec import TuneError

ROOT = Path(__file__).resolve().parents[1]
GRID = '[grid]\n"gains.kp" = [{}]\n[outputs]\nmetrics = ["rms_position_error", "max_tool_position_error_mm"]\n'


@pytest.fixture()
def short_file(tmp_path):
    return write_short_scenario(tmp_path, t_final=0.3)


@pytest.fixture()
def finished(tmp_path, short_file):
    """A sweep of three runs, run to the end: (sweep file, results file, the file's lines)."""
    path = write_sweep(tmp_path, GRID.format("150, 200, 250"))
    results = tmp_path / "s-results.jsonl"
    run_sweep(load_sweep(path), results, workers=1, progress=False)
    return path, results, results.read_text(encoding="utf-8").splitlines(keepends=True)


def _independent_checksum(row: dict) -> str:
    """The documented checksum, computed here from its definition: SHA-256 of the sorted, compact JSON."""
    body = {k: v for k, v in row.items() if k != "checksum"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:16]


def test_every_row_carries_the_checksum_of_its_contents(finished):
    _, _, lines = finished
    header = json.loads(lines[0])
    assert header["row_checksum"] == "sha256-16" and "checksum" not in header["sweep"]
    rows = [json.loads(line) for line in lines[1:]]
    assert len(rows) == 3
    for row in rows:
        assert row["checksum"] == _independent_checksum(row)


def test_a_changed_row_is_not_used_and_its_run_is_done_again(finished):
    path, results, lines = finished
    row = json.loads(lines[2])
    worse = json.dumps(row).replace(json.dumps(row["metrics"]["max_tool_position_error_mm"]), "999.0")
    results.write_text("".join(lines[:2]) + worse + "\n" + "".join(lines[3:]), encoding="utf-8")
    summary = summarize(results, load_sweep(path))
    assert summary.counts.finished == 2 and summary.statistics["max_tool_position_error_mm"].max < 999.0
    assert "line 3: its checksum does not match its contents" in summary.problems[0]
    outcome = run_sweep(load_sweep(path), results, workers=1, progress=False)
    assert outcome.ran == 1 and summarize(results, load_sweep(path)).counts.finished == 3


def test_two_rows_of_one_run_with_different_values_are_refused_naming_both_lines(finished, capsys):
    path, results, lines = finished
    row = json.loads(lines[1])
    other = dict(row, metrics=dict(row["metrics"], max_tool_position_error_mm=999.0))
    results.write_text("".join(lines) + row_line(other), encoding="utf-8")     # a valid row: line 5
    code = run_sweep_command(["sweep", str(path), "--results", str(results), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "line 2 and line 5" in err and "metrics.max_tool_position_error_mm" in err and "999.0" in err
    assert str(results) in err and "--restart" in err
    assert not (results.parent / "s-summary").exists()             # no summary naming 999.0 the worst run
    with pytest.raises(SweepError, match="line 2 and line 5"):
        summarize(results, load_sweep(path))


def test_a_repeat_that_differs_only_in_its_time_counts_once(finished):
    path, results, lines = finished
    row = json.loads(lines[1])
    results.write_text("".join(lines) + row_line(dict(row, seconds=row["seconds"] + 1.0)), encoding="utf-8")
    header, rows = read_results(results)
    assert len(rows) == 3 and sorted(r["index"] for r in rows) == [0, 1, 2]
    summary = summarize(results, load_sweep(path))
    assert summary.counts.finished == 3 and any("1 repeated row" in p for p in summary.problems)


def test_bytes_that_are_not_utf8_are_named_by_file_and_line_and_restart_starts_anew(finished, capsys):
    path, results, lines = finished
    data = "".join(lines).encode("utf-8")
    at = data.index(b"\n", data.index(b"\n") + 1) + 5           # inside line 3
    results.write_bytes(data[:at] + b"\xff" + data[at + 1:])
    code = run_sweep_command(["sweep", str(path), "--results", str(results), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "codec" not in err
    assert f"'{results}' line 3 is not UTF-8" in err and "0xff" in err and "--restart" in err
    code = run_sweep_command(["sweep", str(path), "--results", str(results), "--no-progress", "--restart"])
    assert code == 0
    (old,) = results.parent.glob("s-results.old-*.jsonl")
    assert old.read_bytes()[at] == 0xFF
    assert len(read_results(results)[1]) == 3


def test_the_header_line_alone_undecodable_is_refused_too(tmp_path, finished):
    path, results, lines = finished
    results.write_bytes(b"\xfe" + "".join(lines).encode("utf-8"))
    with pytest.raises(SweepError, match=r"line 1 is not UTF-8 .*--restart"):
        run_sweep(load_sweep(path), results, workers=1, progress=False)


def test_the_evaluation_log_refuses_two_rows_of_one_candidate_that_differ(tmp_path):
    gains = {"gains.kp": 200.0}
    row = {"key": gains_key(gains), "gains": gains, "phase": "search", "values": [0.5, 0.25],
           "peak_torque": [1.0, 2.0, 0.5, 1.0], "diverged": 0, "substeps": 4, "seconds": 0.1}
    log = tmp_path / "evaluations.jsonl"
    writer = JobLog(log, EVALUATION_LOG).writer({"name": "t", "definition": "d"})
    writer.write([row, dict(row, seconds=0.2, phase="polish"), dict(row, values=[0.5, 9.0])])
    writer.close()
    with pytest.raises(TuneError) as err:
        read_log(log)
    message = str(err.value)
    assert "evaluation log" in message and "line 2 and line 4" in message and "values [0.5, 0.25] against " \
        "[0.5, 9.0]" in message


def test_one_log_reader_serves_both_jobs():
    """The sweep and the tuning name the same reader and writer, with their own words and row ids."""
    assert (RESULTS_LOG.id_key, EVALUATION_LOG.id_key) == ("run_id", "key")
    assert (RESULTS_LOG.error, EVALUATION_LOG.error) == (SweepError, TuneError)


# --------------------------------------------------------------------------------------------
# Ctrl-C through the command line
# --------------------------------------------------------------------------------------------
def _rows_in(results: Path) -> int:
    try:
        return max(0, results.read_bytes().count(b"\n") - 1)
    except FileNotFoundError:
        return 0


#: Runs of the Ctrl-C sweep and the simulated seconds of each (a tenth of a second of CPU or more per run): what
#: is left after the first row is minutes of work for two workers, not the moment it takes to send the signal.
CTRL_C_RUNS, CTRL_C_T_FINAL = 1000, 120.0


def interrupted_sweep(tmp_path: Path, *flags: str) -> tuple[int, str, list, Path]:
    """``dobkit sweep --no-progress FLAGS`` of :data:`CTRL_C_RUNS` long runs, in a session of its own, sent Ctrl-C
    (SIGINT to its process group, as a terminal sends it) once the results file shows its first row.

    Returns the exit status, standard error, the processes it had started by then (psutil) and the results file.
    The sweep cannot end first: its runs of two simulated minutes (batches of one) leave minutes of work after the
    first row, however loaded the machine, where the signal follows the row within one poll of the file.
    """
    import psutil
    write_short_scenario(tmp_path, t_final=CTRL_C_T_FINAL)
    path = write_sweep(tmp_path, GRID.format(", ".join(str(100 + 0.5 * i) for i in range(CTRL_C_RUNS)))
                       + "[batch]\nsize = 1\n")
    results = tmp_path / "s-results.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "dobkit", "sweep", str(path), "--no-progress", *flags],
                            env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 600           # a cold numba cache compiles the loop first
        while _rows_in(results) < 1:                # watch the file: the first row is written
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no row was written"
            time.sleep(0.02)
        started = psutil.Process(proc.pid).children(recursive=True)
        assert proc.poll() is None and _rows_in(results) < CTRL_C_RUNS, \
            f"the sweep ended before the interrupt ({_rows_in(results)} of {CTRL_C_RUNS} rows): make its runs longer"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, err, started, results


@pytest.mark.slow
def test_ctrl_c_on_a_sweep_with_two_workers_says_one_line(tmp_path):
    code, err, _, results = interrupted_sweep(tmp_path, "--workers", "2")
    runs = CTRL_C_RUNS
    assert code == 130, err
    lines = [line for line in err.splitlines() if not line.startswith("dobkit: compil")]
    assert lines == [f"dobkit sweep: interrupted; every finished run is kept in {results}, and the same command "
                     "resumes"], err
    data = results.read_bytes()
    assert data.endswith(b"\n")
    rows = read_results(results)[1]
    assert 1 <= len(rows) < runs and len(rows) == _rows_in(results)
    assert not results.with_name(results.name + ".lock").exists()
