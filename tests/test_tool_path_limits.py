"""A task-space path's IK: every corner checked whatever the sample spacing, its cost estimated before it is solved.

Issue 32: with waypoints ``[A, (5, 5, 5) m, A]``, ``duration`` 2 and ``sample_period`` 2 the unreachable middle
point fell between the IK samples and the run wrote a 0 mm tool-tip error; a UR5's 399 s path spent minutes in
the resolved-rate integration while the scenario was read, with no progress and no regard for
``DOBKIT_MAX_SECONDS``.  Now every waypoint is solved when the path is made (refused by time, point and
residual), no segment is longer than a sample spacing, and a long solve waits for the run: its estimate
(per-sample cost times samples) is checked against the wall-time budget first, and the solve shows progress and
stops when the budget runs out.
"""
from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pinocchio")

import blocks  # noqa: E402
from blocks.engines.budget import Budget, BudgetError  # noqa: E402
from blocks.figure2.run_limits import estimate_run  # noqa: E402
from blocks.model.urdf import example_arm  # noqa: E402
from blocks.scenarios.scenario import ScenarioError, scenario_from_dict  # noqa: E402

SCOPE4 = {"urdf": "example:scope4", "tool_frame": "tool_tip"}
UR5 = {"urdf": "example:ur5", "tool_frame": "tool0"}
A = [-0.045, 0.0, -0.148]                      # on scope4's reach (the scope4-path scenario starts there)
UR5_POSE = np.array([0.0, -1.2, 1.4, -1.5, -1.6, 0.0])


def _scope4_path(waypoints, duration, period):
    return scenario_from_dict({"arm": SCOPE4, "trajectory": {"kind": "tool_path", "waypoints": waypoints,
                                                            "duration": duration, "sample_period": period},
                               "simulation": {"t_final": duration, "output_step": 0.01}})


def test_an_unreachable_waypoint_between_samples_is_refused_by_time_point_and_residual():
    with pytest.raises(ScenarioError) as err:
        _scope4_path([A, [5.0, 5.0, 5.0], A], 2.0, 2.0)
    text = str(err.value)
    assert "(5, 5, 5) m at t = 1 s is not reachable by the tool point" in text and "misses it by" in text, text
    # the same with samples close enough to see it: refused the same way
    with pytest.raises(ScenarioError, match=r"\(5, 5, 5\) m at t = 1 s is not reachable"):
        _scope4_path([A, [5.0, 5.0, 5.0], A], 2.0, 0.05)


def test_a_sample_spacing_longer_than_a_segment_is_refused_and_one_segment_long_is_taken():
    B = [-0.03, 0.02, -0.16]
    with pytest.raises(ScenarioError, match=r"trajectory.sample_period \(2 s\) is longer than one segment of the tool "
                                            r"path \(1 s: trajectory.duration / 2 segments\)"):
        _scope4_path([A, B, A], 2.0, 2.0)
    s = _scope4_path([A, B, A], 2.0, 1.0)            # samples on the waypoints: the path goes through B
    tip = s.robot.tool_position(s.trajectory.evaluate(1.0)[0])
    np.testing.assert_allclose(tip, B, rtol=0, atol=1e-9)


def _ur5_loop(duration, period=0.02):
    c = example_arm("ur5").tool_position(UR5_POSE)
    r = 0.05
    loop = [list(c), list(c + [r, r, 0]), list(c + [0, 2 * r, r / 2]), list(c + [-r, r, 0])]
    rounds = max(1, int(duration // 2))
    return {"arm": UR5, "gains": {"observer_bandwidth": 10.0},
            "trajectory": {"kind": "tool_path", "waypoints": loop * rounds + [list(c)], "duration": duration,
                           "sample_period": period},
            "disturbance": {"kind": "step", "f_r": [2.0, 3.0, 1.5, 0.3, 0.3, 0.05]},
            "simulation": {"t_final": duration, "output_step": 0.01}}


def test_a_long_redundant_path_is_estimated_not_solved_and_refused_over_the_wall_time_budget(monkeypatch):
    s = scenario_from_dict(_ur5_loop(399.0))
    path = s.trajectory
    assert path.method == "resolved_rate" and not path.solved and path.samples == 19_951
    estimate = estimate_run(s)
    assert estimate.seconds == pytest.approx(path._record.per_sample * 19_951) and estimate.seconds > 10
    assert estimate.keys["seconds"] == "trajectory.sample_period"
    with pytest.raises(BudgetError) as err:
        Budget(seconds=10).check(estimate, "this run")
    assert err.value.limit == "seconds" and err.value.key == "trajectory.sample_period"
    assert "19,951 IK samples" in str(err.value) and "over the wall-time budget of 10 s" in str(err.value)
    monkeypatch.setenv("DOBKIT_MAX_SECONDS", "10")
    with pytest.raises(BudgetError, match="over the wall-time budget of 10 s"):
        blocks.simulate(s, engine="fast")
    assert not path.solved                                  # refused before the solve
    # the scenario's start is known without the solve (the observer gain from it, the loop's initial state)
    np.testing.assert_allclose(s.robot.tool_position(path.evaluate(0.0)[0]),
                               example_arm("ur5").tool_position(UR5_POSE), rtol=0, atol=1e-9)


def test_the_solve_shows_progress_and_stops_when_the_wall_time_budget_runs_out():
    s = scenario_from_dict(_ur5_loop(40.0, 0.05))
    path = s.trajectory
    if path.solved:
        pytest.skip("this machine solved the path within the eager limit")
    path._record.per_sample = 1e-6            # an estimate within the budget: the solve itself must stop
    log = io.StringIO()
    with pytest.raises(BudgetError, match=r"the wall-time budget of 0.3 s ran out at sample [\d,]+ of 801 \(t = "):
        path.solve(budget=Budget(seconds=0.3), progress=log)
    assert not path.solved
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("solving the tool path's joint references: 801 IK samples of the tool path by the "
                               "resolved-rate law") and "stopped after" in lines[-1], lines


@pytest.mark.slow
def test_the_command_refuses_a_long_path_at_once_under_dobkit_max_seconds(tmp_path):
    """``dobkit simulate`` with ``DOBKIT_MAX_SECONDS=10`` on the 399 s UR5 path: refused within a minute with the
    estimate and the key (before: six minutes of integration while the scenario was read)."""
    import json
    data = _ur5_loop(399.0)
    lines = ['[arm]', 'urdf = "example:ur5"', 'tool_frame = "tool0"', '[trajectory]', 'kind = "tool_path"',
             f'waypoints = {json.dumps(data["trajectory"]["waypoints"])}', 'duration = 399.0',
             'sample_period = 0.02', '[simulation]', 't_final = 399.0', 'output_step = 0.01']
    scenario = tmp_path / "ur5-long.toml"
    scenario.write_text("\n".join(lines) + "\n")
    env = dict(os.environ, DOBKIT_MAX_SECONDS="10", PYTHONPATH=str(Path(blocks.__file__).parents[1]))
    done = subprocess.run([sys.executable, "-m", "dobkit", "simulate", "--scenario", str(scenario), "--no-figures",
                           "--out", str(tmp_path / "out")], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert "over the wall-time budget of 10 s" in done.stderr and "trajectory.sample_period" in done.stderr
    assert not (tmp_path / "out").exists()
