"""The laceration path as a user asks for it: ``simulation.t_final`` never rescales the path (a short window is
the start of the same path, a longer one holds its end, a path duration of its own is kept), the path starts
where the file says, and the skin is one plane, given by ``disturbance.skin_height``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import D1, D4

import blocks
from blocks import ScenarioError, load_scenario

# paper.toml's laceration (read from the file, not from the code): start, end and hover above the skin (m)
PAPER_START, PAPER_END, PAPER_HOVER = (0.36, -0.05), (0.46, 0.05), 0.003


def _rows(resp, name: str) -> np.ndarray:
    labels = list(resp.output_labels)
    return np.array([resp.outputs[labels.index(f"{name}[{i}]")] for i in range(4)])


def _tool_tip(q) -> np.ndarray:
    """Tool tip ``x, y, z`` of Eq. 8 by hand (link lengths l1 = 0.5 m, l2 = 0.2 m; z = d1 - d3 - d4)."""
    t1, t2, d3 = q[0], q[1], q[2]
    return np.array([0.5 * np.cos(t1) + 0.2 * np.cos(t1 + t2), 0.5 * np.sin(t1) + 0.2 * np.sin(t1 + t2),
                     D1 - d3 - D4])


# --- simulation.t_final never rescales the path ---------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_runs():
    paper = load_scenario("paper")
    short = paper.with_changes({"simulation.t_final": 2.0})
    return (blocks.simulate(paper, engine="fast"), blocks.simulate(short, engine="fast"), paper, short)


def test_a_short_window_is_the_start_of_the_same_path(paper_runs):
    full, short, paper, two = paper_runs
    assert two.trajectory.duration == paper.trajectory.duration == 10.0
    n = len(short.time)
    assert n == 401 and short.time[-1] == pytest.approx(2.0)
    np.testing.assert_array_equal(short.time, full.time[:n])
    # the reference is the same function of time: identical numbers on the shared grid
    for name in ("q_ref", "dq_ref", "ddq_ref"):
        np.testing.assert_array_equal(_rows(short, name), _rows(full, name)[:, :n])
    # and the run follows it as the 10 s run does (same solver, same tolerances)
    np.testing.assert_allclose(_rows(short, "q"), _rows(full, "q")[:, :n], rtol=0, atol=1e-7)
    tau_short, tau_full = _rows(short, "tau"), _rows(full, "tau")
    np.testing.assert_allclose(tau_short, tau_full[:, :n], rtol=1e-5, atol=1e-5)
    # peak |tau|: about 30 N m, as in the whole paper run (a path squeezed into 2 s needed 718 N m)
    peak = np.abs(tau_short).max()
    assert peak <= np.abs(tau_full).max() * (1 + 1e-9)
    assert 20.0 < peak < 40.0


def test_the_path_starts_where_the_file_says(paper_runs):
    _, short, _, _ = paper_runs
    tip = _tool_tip(_rows(short, "q_ref")[:, 0])
    skin = load_scenario("paper").disturbance.skin_height
    np.testing.assert_allclose(tip, [*PAPER_START, skin + PAPER_HOVER], atol=1e-12)


def test_a_longer_window_holds_the_end_of_the_path():
    long = load_scenario("paper").with_changes({"simulation.t_final": 12.0})
    assert long.trajectory.duration == 10.0
    q, dq, ddq = long.trajectory.evaluate(np.array([10.0, 11.0, 12.0]))
    skin = long.disturbance.skin_height
    for k in range(3):
        np.testing.assert_allclose(_tool_tip(q[k]), [*PAPER_END, skin + PAPER_HOVER], atol=1e-12)
    np.testing.assert_array_equal(dq, 0.0)
    np.testing.assert_array_equal(ddq, 0.0)


def test_a_path_duration_of_its_own_is_kept():
    s = load_scenario("paper").with_changes({"trajectory.duration": 6.0, "simulation.t_final": 3.0})
    assert s.trajectory.duration == 6.0 and s.simulation.t_final == 3.0
    # the stitch phases are 6 / 9 s long: at t = 6 s the path is at its end, at 3 s it is not
    tip_end = _tool_tip(s.trajectory.evaluate(6.0)[0])
    np.testing.assert_allclose(tip_end[:2], PAPER_END, atol=1e-12)
    assert not np.allclose(_tool_tip(s.trajectory.evaluate(3.0)[0])[:2], PAPER_END, atol=1e-3)


# --- one skin plane ---------------------------------------------------------------------------------------------
def test_the_skin_plane_is_the_disturbance_key():
    s = load_scenario("paper").with_changes({"disturbance.skin_height": -0.35})
    assert s.trajectory.skin_height == -0.35
    q0 = s.trajectory.evaluate(0.0)[0]
    assert _tool_tip(q0)[2] == pytest.approx(-0.35 + PAPER_HOVER, abs=1e-12)
    assert "skin_height" not in s.data["trajectory"] and s.data["disturbance"]["skin_height"] == -0.35
    # the written scenario has the plane once and reads back the same
    assert load_scenario("paper").with_changes({"disturbance.skin_height": -0.35}).to_toml().count("skin_height") == 1


def test_an_agreeing_second_skin_height_is_accepted():
    s = load_scenario("paper").with_changes({"disturbance.skin_height": -0.36, "trajectory.skin_height": -0.36})
    assert s.trajectory.skin_height == s.disturbance.skin_height == -0.36


@pytest.mark.parametrize("changes", [{"trajectory.skin_height": -0.35},
                                     {"disturbance.skin_height": -0.36, "trajectory.skin_height": -0.35}])
def test_a_disagreeing_second_skin_height_is_refused(changes):
    with pytest.raises(ScenarioError) as err:
        load_scenario("paper").with_changes(changes)
    text = str(err.value)
    assert "'trajectory.skin_height' (-0.35 m)" in text and "'disturbance.skin_height'" in text
    expected = changes.get("disturbance.skin_height", load_scenario("paper").disturbance.skin_height)
    assert repr(expected) in text and math.isfinite(expected)
