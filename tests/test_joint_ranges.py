"""The joints' ranges are part of the arm (``JointSpace.limits``): the paper's prismatic stroke ``0 <= d3 <= 0.48 m``
(docs/model.md, "Joint ranges") bounds the laceration path, a joint sine and the initial positions, each refused
naming the joint, the value reached and the range; the revolute joints turn without limit.

Expected numbers are worked by hand from docs/model.md and the paper's Table 1 (conftest): the prismatic
joint's position is ``d3 = d1 - d4 - z``.
"""
from __future__ import annotations

import math

import pytest
from conftest import D1, D4, SKIN_DEFAULT

import blocks
from blocks import ScenarioError

PAPER = blocks.load_scenario("paper")


D3_STROKE = (0.0, 0.48)            # docs/model.md, "Joint ranges": 0 to twice Table 1's d3 = 0.24 m


def test_a_stitch_a_million_metres_deep_is_refused_naming_the_joint_its_reach_and_its_range():
    with pytest.raises(ScenarioError) as err:
        PAPER.with_changes({"trajectory.depth": 1e6})
    text = str(err.value)
    # d3 = d1 - d4 - z at the stitch's bottom z = skin - depth; the paper's skin is at Table 1's d3 = 0.24 m
    deepest = D1 - D4 - (SKIN_DEFAULT - 1e6)
    assert deepest == pytest.approx(1e6 + 0.24)
    assert f"d3 reaches {deepest:.6g} m, outside its range 0 to 0.48 m" in text
    assert "trajectory.depth" in text and "[trajectory]" in text


@pytest.mark.parametrize("key, inside, outside", [
    # d3 at the stitch's bottom is 0.24 + depth (<= 0.48), at the hover height 0.24 - hover (>= 0)
    ("trajectory.depth", 0.235, 0.245),
    ("trajectory.hover", 0.235, 0.245),
])
def test_the_stroke_bounds_the_stitch_where_the_hand_computation_says(key, inside, outside):
    assert PAPER.with_changes({key: inside}).data["trajectory"][key.split(".")[1]] == inside
    with pytest.raises(ScenarioError, match=r"d3 reaches .* outside its range 0 to 0\.48 m"):
        PAPER.with_changes({key: outside})


def test_joint_sines_and_initial_positions_outside_the_stroke_are_refused():
    sine = {"trajectory.kind": "joint_sine", "trajectory.offset": [0.0, 2.0, 0.3, 0.0], "trajectory.omega": 1.0,
            "trajectory.amplitude": [0.1, 0.1, 0.25, 0.1]}
    # 0.3 + 0.25 sin(t) reaches 0.55 m at t = pi/2, within the 10 s run (and 0.05 m, inside, at 3 pi/2)
    with pytest.raises(ScenarioError, match=r"joint sine: d3 reaches 0\.55 m, outside its range 0 to 0\.48 m"):
        PAPER.with_changes(sine)
    # over a 0.5 s run the same sine reaches only 0.3 + 0.25 sin(0.5) = 0.420 m: inside the stroke
    short = PAPER.with_changes(sine | {"simulation.t_final": 0.5, "simulation.output_step": 0.01})
    assert short.trajectory.amplitude[2] == 0.25
    with pytest.raises(ScenarioError, match=r"'initial\.q\[2\]' = -0\.01 m is outside the range of joint d3, 0 to "
                                            r"0\.48 m"):
        PAPER.with_changes({"initial.q": [0.0, 1.0, -0.01, 0.0]})


def test_the_revolute_joints_turn_without_limit():
    assert blocks.RRPR_JOINTS.limits[0] == (-math.inf, math.inf)
    assert blocks.RRPR_JOINTS.limits[2] == D3_STROKE
    assert blocks.RRPR_JOINTS.outside_limits([[50.0, -50.0, 0.1, 1e6]]) is None
