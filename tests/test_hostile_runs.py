"""Hostile and extreme input to a single run: clear errors before the work, bounded work, honest divergence,
output folders that are checked before the work and never mixed (docs/hostile-inputs.md, "Single runs")."""
from __future__ import annotations

import os

import numpy as np
import pytest

import blocks
from blocks.budget import BudgetError
from blocks.metrics import signal
from blocks.outputs import staged_output
from blocks.scenario import ScenarioError

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.2, "trajectory.duration": 10.0}


@pytest.mark.parametrize("changes, words", [
    ({"simulation.t_final": 1e-300, "simulation.output_step": 1e-300}, "output_step' \\(1e-300 s\\) must be at least"),
    ({"simulation.rtol": 0.9}, "simulation.rtol' must be between"),
    ({"simulation.rtol": 1e6}, "simulation.rtol' must be between"),
    ({"simulation.atol": 1e3}, "simulation.atol' must be between"),
    ({"simulation.t_final": 10 ** 400}, "t_final' must be a finite number, got 1.000e\\+400"),
    ({"trajectory.stitches": 10 ** 30}, "trajectory.stitches' = 1.000e\\+30 makes each of the path's"),
    ({"trajectory.stitches": 10 ** 6}, "phases 5e-06 s long, shorter than 0.001 s"),
    ({"noise.sample_period": 1e-6, "noise.q_std": [1e-5] * 4}, "noise.sample_period' \\(1e-06 s\\) asks for 1e\\+07"),
])
def test_scenario_values_that_cannot_give_a_run_are_refused_by_key(changes, words):
    with pytest.raises(ScenarioError, match=words):
        PAPER.with_changes(changes)


def test_a_long_run_without_noise_is_not_refused_for_noise_samples():
    assert PAPER.with_changes({"simulation.t_final": 1e5, "simulation.output_step": 0.05}).noise is None


@pytest.mark.parametrize("given, words", [(None, "got NoneType"), (123, "got int 123"),
                                          ({"gains": {"kp": 1}}, "scenario_from_dict")])
def test_what_is_not_a_scenario_is_named(given, words):
    with pytest.raises(TypeError, match=words):
        blocks.simulate(given)


def test_bad_arguments_to_simulate_are_named():
    with pytest.raises(TypeError, match="plant must be a python-control NonlinearIOSystem.*str 'x'"):
        blocks.simulate(PAPER.with_changes(SHORT), plant="x")
    with pytest.raises(TypeError, match="observer must be True or False, got 'yes'"):
        blocks.simulate(PAPER.with_changes(SHORT), observer="yes")


def test_scenario_files_with_a_byte_order_mark_or_given_as_folders(tmp_path):
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + b'name = "with a mark"\n')
    assert blocks.load_scenario(bom).name == "with a mark"
    with pytest.raises(ScenarioError, match="is a folder, not a scenario file"):
        blocks.load_scenario(tmp_path)


@pytest.mark.parametrize("changes, key", [
    ({"gains.kp": 1e12, "gains.kd": 2e6}, "gains.kp"),
    ({"gains.observer": 1e6}, "gains.observer"),
    ({"gains.observer": 1e300}, "gains.observer"),
    ({"noise.sample_period": 1e-5, "noise.q_std": [1e-5] * 4}, "noise.sample_period"),
])
def test_runs_that_would_never_finish_are_refused_before_they_start_with_the_key(changes, key, monkeypatch):
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "500000")     # the noisy run's million steps would be allowed by default
    with pytest.raises(BudgetError, match=f"integrator steps per run .*set by '{key}'.*DOBKIT_MAX_STEPS") as err:
        blocks.simulate(PAPER.with_changes(changes), engine="fast")
    assert err.value.key == key


def test_a_stiff_but_stable_loop_runs_with_an_implicit_method_and_is_not_called_diverged():
    """Y = 1e6: d_hat = Y dq + z, with z of the order of Y |dq|; the loop is stable and the estimate converges
    within milliseconds (time constant k4 / Y = 0.25 us on the prismatic joint, 0.1 s / 1e5 on the slowest)."""
    s = PAPER.with_changes({"gains.observer": 1e6, "simulation.method": "Radau"} | SHORT)
    run = blocks.simulate(s, engine="fast")
    error = np.abs(signal(run, "d") - signal(run, "d_hat"))[:, run.time >= 0.01]
    assert error.max() < 1e-3


def test_the_step_budget_is_enforced_during_the_run(monkeypatch):
    """The paper run is estimated at 100 steps (its PD rate 30 1/s over 10 s) and takes about 820 (4922 RK45
    evaluations): within a budget of 150 steps it starts and is stopped at 900 evaluations."""
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "150")
    with pytest.raises(blocks.SimulationError, match="more than 900 right-hand-side evaluations"):
        blocks.simulate(PAPER, engine="fast")
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "lots")
    with pytest.raises(ValueError, match="DOBKIT_MAX_STEPS"):
        blocks.simulate(PAPER.with_changes(SHORT), engine="fast")


@pytest.mark.parametrize("engine", ["fast", "compiled"])
def test_divergence_is_judged_on_physical_signals_and_named(engine):
    if engine == "compiled":
        pytest.importorskip("numba")
    s = PAPER.with_changes({"noise.q_std": [1e3] * 4, "noise.dq_std": [0.0] * 4} | SHORT)
    with pytest.raises(blocks.SimulationError,
                       match=r"diverged (at|by) t = .*plant dq\[\d\] reached .* beyond its bound .*reference's "
                             r"largest speed plus"):
        blocks.simulate(s, engine=engine)


# --------------------------------------------------------------------------------------------------------------
# Output folders
# --------------------------------------------------------------------------------------------------------------
def _fill(target) -> None:
    with staged_output(target) as stage:
        (stage / "result.txt").write_text("done")


def test_an_empty_folder_or_a_link_to_one_is_filled_in_place(tmp_path):
    volume = tmp_path / "volume"                # like a container's mounted volume: it exists, empty, and stays
    volume.mkdir()
    _fill(volume)
    assert sorted(p.name for p in volume.iterdir()) == ["result.txt"]
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real)
    _fill(link)
    assert link.is_symlink() and (real / "result.txt").read_text() == "done"


def test_unusable_folders_are_refused_before_the_work(tmp_path):
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="symbolic link.*which does not exist"):
        staged_output(dangling)
    full = tmp_path / "full"
    full.mkdir()
    (full / "old.txt").write_text("old")
    with pytest.raises(FileExistsError, match="exists and is not empty"):
        staged_output(full)
    if os.geteuid() != 0:                        # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        with pytest.raises(PermissionError, match="cannot be written"):
            staged_output(locked)


def test_a_second_run_for_the_same_folder_is_refused_at_once_and_a_killed_runs_lock_is_cleared(tmp_path):
    target = tmp_path / "out"
    first = staged_output(target)
    with pytest.raises(FileExistsError, match=f"being written by another dobkit run \\(process {os.getpid()}\\)"):
        staged_output(target)
    del first                                    # the work failed before writing: the reservation goes
    assert not target.exists()
    target.mkdir()
    (target / ".dobkit-writing").write_text("999999999")                   # no such process
    (target / ".partial-left").mkdir()
    _fill(target)
    assert sorted(p.name for p in target.iterdir()) == ["result.txt"]


def test_a_failure_leaves_nothing_and_the_umask_is_honoured(tmp_path):
    target = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with staged_output(target) as stage:
            (stage / "half.txt").write_text("half")
            raise RuntimeError("the run failed")
    assert not target.exists()
    old = os.umask(0o027)
    try:
        _fill(target)
    finally:
        os.umask(old)
    assert (target.stat().st_mode & 0o777) == 0o750
