"""``--scheduler local[:N]``: a Dask LocalCluster started for one sweep or tuning and closed when it ends
(analysis.jobs.cluster.dask_session).

Each job runs through the command line with ``--scheduler local:2`` and must end as the same job run in this
process ends, its log holding every run (sweep) or simulated candidate (tuning) exactly once.  The cluster's
processes are this process's children: after the job, on success, on an error and on Ctrl-C, none of those the
job started may be left.
"""
from __future__ import annotations

import json
import os
import sys

import psutil
import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep
from test_job_integrity import CTRL_C_RUNS, interrupted_sweep
from test_sweep import _assert_same_rows
from test_tune import write_problem

from analysis.jobs.cluster import dask_session, local_workers
from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import SweepError, load_sweep
from analysis.tune.runner import LOG_NAME, RESULT_NAME, run_tune
from analysis.tune.spec import load_tuning
from dobkit.cli import main

pytest.importorskip("distributed")


GRID = '[grid]\n"gains.kp" = [100, 140, 180, 220]\n[batch]\nsize = 1\n[outputs]\nmetrics = ["rms_position_error"]\n'
SHORT_SEARCH = {'"gains.kp"': [20, 2000], "seed": 3, "population": 6, "max_evaluations": 24, "polish_evaluations": 6}


def _children() -> set[int]:
    """This process's descendants but multiprocessing's resource tracker (one for the life of the process)."""
    out = set()
    for p in psutil.Process().children(recursive=True):
        try:
            if "resource_tracker" not in " ".join(p.cmdline()):
                out.add(p.pid)
        except psutil.NoSuchProcess:
            pass
    return out


def _assert_none_left(before: set[int]) -> None:
    """Every process started since ``before`` has ended (waited for: a closing cluster ends them in turn)."""
    started = [psutil.Process(pid) for pid in _children() - before if psutil.pid_exists(pid)]
    gone, alive = psutil.wait_procs(started, timeout=30)
    assert not alive, f"cluster processes left running: {[(p.pid, p.cmdline()) for p in alive]}"


def _log_ids(path, key: str) -> list[str]:
    lines = path.read_text().splitlines()
    return [json.loads(line)[key] for line in lines[1:] if line.strip()]


def test_local_and_local_n_name_the_worker_count():
    assert local_workers("local") == (os.cpu_count() or 1)
    assert local_workers("local:3") == 3
    assert local_workers("tcp://127.0.0.1:8786") is None and local_workers("localhost:8786") is None
    for bad in ("local:0", "local:x", "local:", "local:-2"):
        with pytest.raises(SweepError, match=rf"--scheduler '{bad}': the number of local worker processes must be "
                                             r"a whole number >= 1 \(local or local:N"):
            local_workers(bad, SweepError)


def test_a_sweep_on_a_local_cluster_gives_every_row_once(tmp_path):
    write_short_scenario(tmp_path, t_final=0.3)
    path = write_sweep(tmp_path, GRID)
    run_sweep(load_sweep(path), tmp_path / "here.jsonl", workers=1, progress=False)
    before = _children()
    code = run_sweep_command(["sweep", str(path), "--results", str(tmp_path / "cluster.jsonl"), "--no-progress",
                              "--scheduler", "local:2"])
    assert code == 0
    _assert_none_left(before)
    ids = _log_ids(tmp_path / "cluster.jsonl", "run_id")
    assert len(ids) == len(set(ids)) == 4
    _assert_same_rows(tmp_path / "here.jsonl", tmp_path / "cluster.jsonl")


def test_a_tuning_on_a_local_cluster_ends_as_the_one_here(tmp_path, capsys):
    path = write_problem(tmp_path, search=SHORT_SEARCH)
    # the numpy batch engine: fresh worker processes have no compiled loop to load
    here = run_tune(load_tuning(path), tmp_path / "here", workers=1, progress=False, figures=False, engine="fast")
    before = _children()
    remote = run_tune(load_tuning(path), tmp_path / "cluster", progress=False, figures=False, engine="fast",
                      scheduler="local:2")
    _assert_none_left(before)
    assert remote.tuned.gains == here.tuned.gains and remote.tuned.objective == here.tuned.objective
    assert remote.history.objective == here.history.objective and remote.evaluations == here.evaluations
    keys = _log_ids(tmp_path / "cluster" / LOG_NAME, "key")
    assert len(keys) == len(set(keys)) == here.evaluations["simulated"]
    # through the command line too: the finished log is replayed, nothing simulated again, the cluster closed
    code = main(["tune", str(path), "--out", str(tmp_path / "cluster"), "--scheduler", "local:2", "--no-progress"])
    assert code == 0, capsys.readouterr()
    _assert_none_left(before)
    assert json.loads((tmp_path / "cluster" / RESULT_NAME).read_text())["evaluations"]["simulated"] == 0


@pytest.mark.parametrize("stop", [RuntimeError("a failing row consumer"), KeyboardInterrupt()])
def test_the_cluster_is_closed_when_the_sweep_stops_on_an_error_or_ctrl_c(tmp_path, stop):
    write_short_scenario(tmp_path, t_final=0.3)
    path = write_sweep(tmp_path, GRID)
    before = _children()

    def on_rows(rows):
        raise stop

    with pytest.raises(type(stop)):
        run_sweep(load_sweep(path), tmp_path / "r.jsonl", scheduler="local:2", progress=False, on_rows=on_rows)
    _assert_none_left(before)
    assert len(_log_ids(tmp_path / "r.jsonl", "run_id")) >= 1          # the rows written before it are kept


def test_without_dask_the_error_names_the_cluster_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)        # as if the 'cluster' extra were not installed
    with pytest.raises(SweepError, match=r"--scheduler local:2 needs Dask: pip install 'dobkit\[cluster\]' \(the "
                                         r"'cluster' extra"):
        with dask_session("local:2", 1.0, SweepError):
            pass


@pytest.mark.slow
def test_ctrl_c_on_a_sweep_on_a_local_cluster_says_one_line_and_ends_the_cluster(tmp_path):
    """A terminal's Ctrl-C reaches the whole process group: the command and the cluster's processes.  The command
    says one line and closes the cluster; the workers, which ignore Ctrl-C, print nothing."""
    code, err, started, results = interrupted_sweep(tmp_path, "--scheduler", "local:2")
    assert code == 130, err
    # the workers' notes of a first numba compile come before when the cache does not hold the loop yet (a new
    # cache, or no earlier test compiled it): the interrupt itself says one line
    lines = [line for line in err.splitlines() if not line.startswith("dobkit: compil")]
    assert lines == [f"dobkit sweep: interrupted; every finished run is kept in {results}, and the same "
                     "command resumes"], err
    assert len(started) >= 2                          # the cluster's two worker processes at least
    gone, alive = psutil.wait_procs([p for p in started if p.is_running()], timeout=30)
    assert not alive, f"cluster processes left running: {[p.pid for p in alive]}"
    assert 1 <= len(_log_ids(results, "run_id")) < CTRL_C_RUNS


def test_a_local_cluster_larger_than_the_machine_is_refused_at_its_limit(monkeypatch):
    """local:N is taken up to MAX_LOCAL_WORKERS_PER_CORE per core and refused one above, naming both."""
    from analysis.jobs.cluster import MAX_LOCAL_WORKERS_PER_CORE

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    most = 2 * MAX_LOCAL_WORKERS_PER_CORE
    assert local_workers(f"local:{most}") == most
    with pytest.raises(SweepError, match=rf"{most + 1} local worker processes on 2 core\(s\); at most {most}"):
        local_workers(f"local:{most + 1}", SweepError)
    with pytest.raises(SweepError, match=rf"at most {most} "):
        local_workers("local:100000", SweepError)


@pytest.mark.parametrize("address", ["local:\u00b2", "local:\u0663"])
def test_a_local_worker_count_in_other_digits_is_refused_naming_the_flag(address):
    # 'local:²' passed str.isdigit and failed in int(): "invalid literal for int() with base 10: '²'"
    from analysis.jobs.cluster import local_workers
    with pytest.raises(ValueError, match=r"--scheduler 'local:.': the number of local worker processes must be a "
                                         r"whole number >= 1"):
        local_workers(address)
