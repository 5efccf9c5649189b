"""Every example arm by name: example-robot-data's serial arms found from its files, read lightly, loaded by name,
their defaults in a scenario, the error for an unknown name, and ``dobkit arms``."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from blocks.model.urdf import examples
from blocks.model.urdf.examples import UnknownExampleError, example_arms, example_urdf, serial_chain

pin = pytest.importorskip("pinocchio")
if examples._distribution() is None:
    pytest.skip("example-robot-data is not installed", allow_module_level=True)


def test_the_serial_arms_are_listed_and_the_others_not():
    arms = example_arms()
    for name in ("scope4", "ur5", "panda", "z1", "so101", "so100", "kinova", "double_pendulum", "xarm7", "ur10"):
        assert name in arms, name
    files = {a.file for a in arms.values()}
    # legged robots, humanoids, two-armed robots, hands and mobile manipulators branch before their chain ends
    for other in ("a1_description/urdf/a1.urdf", "talos_data/robots/talos_full_v2.urdf",
                  "baxter_description/urdf/baxter.urdf", "allegro_hand_description/urdf/allegro_right_hand.urdf",
                  "tiago_description/robots/tiago.urdf", "solo_description/robots/solo12.urdf"):
        assert other not in files
    # ur3.urdf in example-robot-data 6 is an empty <robot>: not an arm; ur3_robot.urdf is, and takes the name
    assert arms["ur3"].file.endswith("ur3_robot.urdf")
    assert arms["ur5"].tool_frame == "tool0" and arms["panda"].tool_frame == "panda_hand"
    assert arms["panda"].locked == ("panda_finger_joint1", "panda_finger_joint2")


@pytest.mark.parametrize("name", sorted(set(example_arms()) - {"scope4"}))
def test_each_listed_arm_is_what_pinocchio_reads(name):
    """The light reading (XML only) against pinocchio's model of the same file: the moving joints once the
    listed ones are locked, in order; the default tool frame is a frame of the model; dobkit loads it by name."""
    info = example_arms()[name]
    model = pin.buildModelFromUrdf(str(example_urdf(name)))
    moving = [model.names[j] for j in range(1, model.njoints) if model.names[j] not in info.locked]
    assert tuple(moving) == info.joints
    assert model.existFrame(info.tool_frame)
    arm = examples.example_arm(name)
    assert arm.joints.names == info.joints and arm.tool_frame == info.tool_frame


def test_an_example_arm_has_pinocchio_dynamics():
    """The Z1 by name: M(q) and h(q, q') of its kernels equal pinocchio's CRBA and RNEA on the file."""
    arm = examples.example_arm("z1")
    model = pin.buildModelFromUrdf(str(example_urdf("z1")))
    data = model.createData()
    rng = np.random.default_rng(3)
    for _ in range(3):
        q, dq = rng.uniform(-1.0, 1.0, arm.n), rng.uniform(-1.0, 1.0, arm.n)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        np.testing.assert_allclose(arm.kernels.inertia_matrix(arm.kernel_params(), q), M, rtol=1e-10, atol=1e-12)
        h = pin.rnea(model, data, q, dq, np.zeros(arm.n))
        np.testing.assert_allclose(arm.kernels.bias_forces(arm.kernel_params(), q, dq), h, rtol=1e-10, atol=1e-12)


def _xml(text: str):
    """A robot of the joints ``text`` and the links they name (only those: an unused link is another tree)."""
    root = ET.fromstring(f"<robot name='r'>{text}</robot>")
    names = {e.get("link") for e in root.iter() if e.tag in ("parent", "child")}
    for name in sorted(names):
        ET.SubElement(root, "link", name=name)
    return root


def _joint(name, kind, parent, child, limits=True):
    limit = "<limit lower='-1' upper='1' effort='1' velocity='1'/>" if limits else ""
    return (f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
            f"<axis xyz='0 0 1'/>{limit}</joint>")


def test_serial_chain_reads_a_chain_a_gripper_and_refuses_a_branch():
    links = ""
    chain = serial_chain(_xml(links + _joint("j1", "revolute", "base", "a") + _joint("j2", "prismatic", "a", "b")
                              + _joint("fix", "fixed", "b", "hand") + _joint("g1", "prismatic", "hand", "f1")
                              + _joint("g2", "prismatic", "hand", "f2")))
    joints, tool, locked = chain
    assert [j.get("name") for j in joints] == ["j1", "j2"] and tool == "hand" and locked == ("g1", "g2")
    # a fixed joint on from the last link: the tool frame follows it
    joints, tool, locked = serial_chain(_xml(links + _joint("j1", "revolute", "base", "a")
                                             + _joint("fix", "fixed", "a", "tip")))
    assert tool == "tip" and locked == ()
    # two moving branches at the root (two arms, legs): no serial chain; nor a floating joint
    assert serial_chain(_xml(links + _joint("j1", "revolute", "base", "a") + _joint("j2", "revolute", "base", "b")))\
        is None
    assert serial_chain(_xml(links + _joint("j1", "floating", "base", "a", limits=False))) is None
    # branches of two joints each past the chain (a hand's fingers) are no gripper
    assert serial_chain(_xml(links + _joint("j1", "revolute", "base", "hand") + _joint("g1", "revolute", "hand", "f1")
                             + _joint("g1b", "revolute", "f1", "a") + _joint("g2", "revolute", "hand", "f2")
                             + _joint("g2b", "revolute", "f2", "b"))) is None


def test_an_unknown_name_lists_the_choices():
    with pytest.raises(UnknownExampleError) as err:
        example_urdf("z2")
    message = str(err.value)
    assert "'z2'" in message and "z1" in message and "panda" in message and "so101" in message


def test_a_name_in_the_wrong_case_is_pointed_to_and_a_very_long_one_is_not_echoed_whole():
    """`example:UR5` was "unknown" without a word of ur5; a 5,000-character name was echoed whole."""
    with pytest.raises(UnknownExampleError, match=r"example arm 'UR5' is unknown \(did you mean 'ur5'\?\)"):
        example_urdf("UR5")
    with pytest.raises(UnknownExampleError) as err:
        example_urdf("a" * 5000)
    assert "(5,000 characters)" in str(err.value) and "a" * 61 not in str(err.value)
    for name in ("", "../../etc/passwd", "scope4/../ur5"):
        with pytest.raises(UnknownExampleError, match="the example arms are"):
            example_urdf(name)


def test_dobkit_arms_with_an_empty_name_is_an_unknown_name_not_the_whole_list(capsys):
    from dobkit.cli import main

    assert main(["arms", ""]) == 2
    captured = capsys.readouterr()
    assert "example arm '' is unknown" in captured.err and captured.out == ""


def test_a_scenario_names_an_example_arm_and_takes_its_defaults():
    from blocks.scenarios.scenario import ScenarioError, scenario_from_dict

    s = scenario_from_dict({"arm": {"urdf": "example:z1"}})
    assert s.robot.n == 7 and s.robot.tool_frame == "gripperMover"
    panda = scenario_from_dict({"arm": {"urdf": "example:panda"}})
    assert panda.robot.n == 7 and "panda_finger_joint1" not in panda.robot.joints.names
    given = scenario_from_dict({"arm": {"urdf": "example:ur5", "tool_frame": "wrist_3_link"}})
    assert given.robot.tool_frame == "wrist_3_link"
    with pytest.raises(ScenarioError, match=r"'arm.urdf' = 'example:nosuch'.*so101"):
        scenario_from_dict({"arm": {"urdf": "example:nosuch"}})


def test_dobkit_arms_lists_them(capsys):
    from dobkit.cli import main

    assert main(["arms"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:] if line and not line.startswith("kinds")}
    assert rows["z1"][1:4] == ["7", "RRRRRRR", "gripperMover"]
    assert rows["kinova"][2] == "CRRCRC"                   # continuous joints are C
    assert rows["scope4"][2] == "RRPR" and "0 to 0.2 m" in out
    assert {"ur5", "panda", "so101", "double_pendulum"} <= set(rows)
    assert main(["arms", "so101"]) == 0
    one = capsys.readouterr().out
    assert "shoulder_pan" in one and "moving_jaw_so101_v1_link" in one
    assert main(["arms", "nosuch"]) == 2
    assert "the example arms are" in capsys.readouterr().err


def test_limits_are_read_as_written():
    kinova = example_arms()["kinova"]
    assert kinova.kinds[0] == "continuous" and kinova.limits[0] == (-math.inf, math.inf)
    assert kinova.limits[1] == pytest.approx((0.820304748437, 5.46288055874))


def test_a_known_example_without_the_package_names_the_extra(monkeypatch):
    """Without example-robot-data, example:panda says to install it (not that the name is unknown); z1 is unknown."""
    from importlib import metadata

    from blocks.scenarios.scenario import ScenarioError, scenario_from_dict

    def absent(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "distribution", absent)
    with pytest.raises(ScenarioError, match=r"example:panda.*dobkit\[urdf\]"):
        scenario_from_dict({"arm": {"urdf": "example:panda"}})
    with pytest.raises(ScenarioError, match=r"example arm 'z1' is unknown; the example arms are scope4 .*dobkit\[urdf\]"):
        scenario_from_dict({"arm": {"urdf": "example:z1"}})
    assert scenario_from_dict({"arm": {"urdf": "example:scope4"}}).robot.n == 4
