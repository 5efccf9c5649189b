"""A tool frame whose name a link and a joint share (Z1's ``gripperStator``): the link's frame is taken.

pinocchio's ``getFrameId(name)`` refuses such a name ("Several frames match the filter"); URDF places a link's
frame at the joint that carries it, so the two frames are one place.  The tool's position is checked against
pinocchio's own frame placement of the link (``FrameType.BODY``), and the refusal of a name that stays ambiguous.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks.model.urdf.urdf import UnknownFrameError, load_urdf_arm, tool_frame_id  # noqa: E402


def _robot_file(relative: str) -> Path:
    """A URDF of the installed example-robot-data (a cmeel package: share/example-robot-data/robots/...)."""
    from importlib import metadata
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    for f in dist.files or ():
        if str(f).replace("\\", "/").endswith("example-robot-data/robots/" + relative):
            return Path(str(dist.locate_file(f)))
    pytest.skip(f"example-robot-data has no {relative}")


SHARED = """<?xml version="1.0"?>
<robot name="shared">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <link name="l1"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <link name="l2"><inertial><origin xyz="0.1 0 0"/><mass value="0.5"/>
    <inertia ixx="0.005" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.005"/></inertial></link>
  <joint name="tool" type="fixed"><parent link="l2"/><child link="tool"/><origin xyz="0.25 0 0.05" rpy="0 0.4 0"/>
  </joint>
  <link name="tool"/>
</robot>
"""


def _body_position(model, name, q_pin):
    data = model.createData()
    pin.framesForwardKinematics(model, data, q_pin)
    return np.array(data.oMf[model.getFrameId(name, pin.FrameType.BODY)].translation)


def test_a_small_arm_with_a_fixed_joint_named_as_its_tool_link(tmp_path):
    path = tmp_path / "shared.urdf"
    path.write_text(SHARED)
    model = pin.buildModelFromUrdf(str(path))
    with pytest.raises(Exception, match="Several frames"):     # what the user saw before
        model.getFrameId("tool")
    arm = load_urdf_arm(path, "tool")
    for q in ([0.0, 0.0], [0.3, -0.7], [-1.2, 1.1]):
        q = np.array(q)
        # by hand: the tool sits 0.25 m along l2's x and 0.05 m along its z, l2 turned by q1 about y after q0 about z
        c0, s0, c1, s1 = np.cos(q[0]), np.sin(q[0]), np.cos(q[1]), np.sin(q[1])
        r = 0.3 + 0.25 * c1 + 0.05 * s1
        expected = np.array([r * c0, r * s0, 0.2 - 0.25 * s1 + 0.05 * c1])
        np.testing.assert_allclose(arm.tool_position(q), expected, atol=1e-12)
        np.testing.assert_allclose(arm.tool_position(q), _body_position(model, "tool", q), atol=1e-12)


def test_z1_with_its_gripper_stator_as_the_tool():
    path = _robot_file("z1_description/urdf/z1.urdf")
    arm = load_urdf_arm(path, "gripperStator", locked=["jointGripper"])
    model = arm.pin_model
    names = [f.name for f in model.frames]
    assert names.count("gripperStator") == 2                    # a fixed joint and a link of that name
    rng = np.random.default_rng(3)
    lo, hi = np.array(arm.joints.limits).T
    for q in rng.uniform(lo, hi, size=(4, arm.n)):
        np.testing.assert_allclose(arm.tool_position(q),
                                   _body_position(model, "gripperStator", arm.pinocchio_configuration(q)),
                                   atol=1e-12)


def test_a_name_that_stays_ambiguous_is_refused_by_name(tmp_path):
    path = tmp_path / "shared.urdf"
    path.write_text(SHARED)
    model = pin.buildModelFromUrdf(str(path))
    assert model.frames[tool_frame_id(model, "tool")].type == pin.FrameType.BODY
    # a joint and an operational frame of one name, no link: nothing to prefer
    joint = model.frames[model.getFrameId("j2", pin.FrameType.JOINT)]
    model.addFrame(pin.Frame("j2", joint.parentJoint, joint.parentFrame, joint.placement, pin.FrameType.OP_FRAME))
    assert [f.name for f in model.frames].count("j2") == 2
    with pytest.raises(UnknownFrameError, match=r"'j2' names 2 frames of the model \(joint, op_frame\) and not"):
        tool_frame_id(model, "j2")
