"""Sweeps and tunings on a Dask cluster that loses a worker mid-batch (analysis.jobs.cluster).

One LocalCluster of two worker processes on 127.0.0.1 serves the module.  In each test a thread waits until a
worker is simulating a batch and kills its process (SIGKILL: no clean shutdown); Dask runs the lost batch again
on the other worker (the nanny restarts the killed one).  The job must end as the same job run in this process
ends, and its log must hold every run (sweep) or simulated candidate (tuning) exactly once.

The tuning is the small problem of ``test_tune`` (one gain, three runs, the optimum at the edge of the
torque-noise budget) with a shorter search; the sweep is eight single-run batches of a half-second paper run.
"""
from __future__ import annotations

import json
import os
import signal
import threading
import time

import pytest
from test_sweep import _assert_same_rows, _sweep
from test_tune import write_problem

import blocks
from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import load_sweep
from analysis.tune.runner import LOG_NAME, read_log, run_tune
from analysis.tune.spec import TuneError, load_tuning

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, silence_logs=50) as cluster:
        yield cluster


class _Killer:
    """A thread that kills the process of the first worker found simulating a batch."""

    def __init__(self, address: str) -> None:
        self.stop, self.killed = threading.Event(), []
        self.thread = threading.Thread(target=_kill_a_busy_worker, args=(address, self.stop, self.killed))

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=30)


def _kill_a_busy_worker(address: str, stop: threading.Event, killed: list) -> None:
    """Wait until a worker is simulating a batch, then kill its process outright (no clean shutdown)."""
    with distributed.Client(address, timeout="10s") as client:
        pids = client.run(os.getpid)
        while not stop.is_set():
            busy = [w for w, keys in client.processing().items() if keys and w in pids]
            if busy:
                time.sleep(0.05)          # well inside the batch (a batch takes a few tenths of a second)
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
                return
            time.sleep(0.01)


def _log_lines(path) -> list[dict]:
    lines = path.read_text().splitlines()
    return [json.loads(line) for line in lines[1:] if line.strip()]


#: A shorter search than test_tune's (the cluster's start and a lost batch cost time enough).
SHORT_SEARCH = {'"gains.kp"': [20, 2000], "seed": 3, "population": 6, "max_evaluations": 24, "polish_evaluations": 6}


def test_a_tuning_on_dask_with_a_worker_killed_mid_batch_ends_as_the_local_one(tmp_path, cluster):
    path = write_problem(tmp_path, search=SHORT_SEARCH)
    # the numpy batch engine: fresh worker processes (the restarted one too) have no compiled loop to load
    local = run_tune(load_tuning(path), tmp_path / "local", workers=1, progress=False, figures=False, engine="fast")
    with _Killer(cluster.scheduler_address) as killer:
        remote = run_tune(load_tuning(path), tmp_path / "dask", progress=False, figures=False, engine="fast",
                          scheduler=cluster.scheduler_address)
    assert killer.killed, "no worker was busy long enough to be killed: the test did not test a lost worker"
    assert remote.tuned.gains == local.tuned.gains
    assert remote.tuned.objective == local.tuned.objective and remote.base.objective == local.base.objective
    assert remote.history.objective == local.history.objective and remote.history.phase == local.history.phase
    assert remote.evaluations == local.evaluations
    # every simulated candidate once in the log: no row lost with the worker, none written twice
    rows = _log_lines(tmp_path / "dask" / LOG_NAME)
    keys = [row["key"] for row in rows]
    assert len(keys) == len(set(keys)) == local.evaluations["simulated"]
    assert set(keys) == {row["key"] for row in _log_lines(tmp_path / "local" / LOG_NAME)}
    # the rows' numbers are the local ones (seconds aside): where a batch ran does not change it
    local_rows = read_log(tmp_path / "local" / LOG_NAME)[1]
    for key, row in read_log(tmp_path / "dask" / LOG_NAME)[1].items():
        assert row["values"] == local_rows[key]["values"] and row["peak_torque"] == local_rows[key]["peak_torque"]


def test_an_unreachable_scheduler_is_named_and_leaves_no_output_folder(tmp_path):
    path = write_problem(tmp_path)
    with pytest.raises(TuneError, match="cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'"):
        run_tune(load_tuning(path), tmp_path / "out", progress=False, scheduler="tcp://127.0.0.1:9",
                 scheduler_timeout=1.0)
    assert not (tmp_path / "out").exists()


def test_a_sweep_on_dask_with_a_worker_killed_mid_batch_ends_as_the_local_one(tmp_path, cluster):
    short = blocks.load_scenario("paper").replace(simulation={"t_final": 0.5}, trajectory={"duration": 10.0})
    (tmp_path / "short.toml").write_text(short.to_toml(), encoding="utf-8")
    spec = load_sweep(_sweep(tmp_path, """
[grid]
"gains.kp" = [100, 130, 160, 190, 220, 250, 280, 310]
[batch]
size = 1
[outputs]
metrics = ["rms_position_error", "max_tool_position_error_mm"]
"""))
    run_sweep(spec, tmp_path / "local.jsonl", workers=1, progress=False)
    with _Killer(cluster.scheduler_address) as killer:
        outcome = run_sweep(spec, tmp_path / "dask.jsonl", scheduler=cluster.scheduler_address, progress=False)
    assert killer.killed, "no worker was busy long enough to be killed: the test did not test a lost worker"
    assert (outcome.ran, outcome.skipped, outcome.diverged) == (8, 0, 0)
    ids = [row["run_id"] for row in _log_lines(tmp_path / "dask.jsonl")]
    assert len(ids) == len(set(ids)) == 8
    _assert_same_rows(tmp_path / "local.jsonl", tmp_path / "dask.jsonl")
