"""URDF arms: dobkit's CRBA/RNEA/Cholesky/tool kernels against pinocchio at random states, and bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks.model.urdf import (  # noqa: E402
    ChainArm,
    InertiaError,
    UnknownFrameError,
    UnknownJointError,
    UnsupportedJointError,
    UrdfError,
    UrdfFileError,
    UrdfParseError,
    example_arm,
    load_urdf_arm,
    scope4_urdf,
)
from blocks.model.urdf.examples import example_urdf  # noqa: E402

TOL = 1e-10

_INERTIAL = ('<inertial><origin xyz="{c}" rpy="{r}"/><mass value="{m}"/>'
             '<inertia ixx="{a}" ixy="0.001" ixz="-0.002" iyy="{b}" iyz="0.0015" izz="{d}"/></inertial>')


def _link(name, m=1.0, c="0.05 0.02 0.1", r="0.1 -0.2 0.3", a=0.03, b=0.04, d=0.05):
    return f'<link name="{name}">{_INERTIAL.format(m=m, c=c, r=r, a=a, b=b, d=d)}</link>'


#: An arm written for the test: a continuous joint on an unaligned axis, a prismatic joint on a negative axis,
#: a fixed joint carrying mass mid-chain, rotated placements, and a revolute joint on -x.
MIXED = f"""<?xml version="1.0"?>
<robot name="mixed">
  <link name="base"/>
  <joint name="spin" type="continuous"><parent link="base"/><child link="a"/>
    <origin xyz="0.1 0 0.2" rpy="0.2 0 0"/><axis xyz="0.3 0.4 0.8660254037844386"/></joint>
  {_link("a", m=2.0)}
  <joint name="slide" type="prismatic"><parent link="a"/><child link="b"/>
    <origin xyz="0 0.1 0.3" rpy="0 0.5 -0.4"/><axis xyz="0 0 -1"/>
    <limit lower="-0.1" upper="0.3" effort="10" velocity="1"/></joint>
  {_link("b", m=0.8, c="0 0 -0.1")}
  <joint name="weld" type="fixed"><parent link="b"/><child link="c"/><origin xyz="0.2 0 0" rpy="0 0 1.2"/></joint>
  {_link("c", m=0.5, c="0.1 0 0")}
  <joint name="bend" type="revolute"><parent link="c"/><child link="d"/>
    <origin xyz="0.15 0.05 0" rpy="1.5707963267948966 0 0"/><axis xyz="-1 0 0"/>
    <limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
  {_link("d", m=0.3, c="0.1 0.01 0")}
  <joint name="tip_mount" type="fixed"><parent link="d"/><child link="tip"/><origin xyz="0.2 0.01 -0.03"/></joint>
  <link name="tip"/>
</robot>
"""


@pytest.fixture(scope="module")
def mixed_urdf(tmp_path_factory):
    path = tmp_path_factory.mktemp("urdf") / "mixed.urdf"
    path.write_text(MIXED)
    return path


def _arms(mixed_urdf):
    return {"scope4": example_arm("scope4"), "ur5": example_arm("ur5"), "panda": example_arm("panda"),
            "mixed": load_urdf_arm(mixed_urdf, "tip")}


@pytest.fixture(scope="module")
def arms(mixed_urdf):
    return _arms(mixed_urdf)


def _pin_reference(arm: ChainArm, q, dq):
    """M, h, G, tool position, LOCAL_WORLD_ALIGNED linear Jacobian and J'q' from pinocchio."""
    model = arm.pin_model
    data = model.createData()
    fid = model.getFrameId(arm.tool_frame)
    qp = arm.pinocchio_configuration(q)
    M = pin.crba(model, data, qp)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.nonLinearEffects(model, data, qp, dq)
    h_rnea = pin.rnea(model, data, qp, dq, np.zeros(arm.n))
    G = pin.computeGeneralizedGravity(model, data, qp)
    J = pin.computeFrameJacobian(model, data, qp, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
    pin.forwardKinematics(model, data, qp, dq, np.zeros(arm.n))
    pin.updateFramePlacements(model, data)
    p = data.oMf[fid].translation.copy()
    a = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear.copy()
    np.testing.assert_allclose(h, h_rnea, atol=1e-12)
    return M, h, G, p, J, a


@pytest.mark.parametrize("name", ["scope4", "ur5", "panda", "mixed"])
def test_dynamics_and_tool_agree_with_pinocchio(arms, name):
    arm = arms[name]
    rng = np.random.default_rng(7)
    lo, hi = np.array(arm.joints.limits).T
    lo, hi = np.maximum(lo, -3.0), np.minimum(hi, 3.0)
    for _ in range(6):
        q, dq, ddq = rng.uniform(lo, hi), rng.uniform(-2, 2, arm.n), rng.uniform(-3, 3, arm.n)
        M, h, G, p, J, a = _pin_reference(arm, q, dq)
        np.testing.assert_allclose(arm.inertia(q), M, rtol=0, atol=TOL)
        np.testing.assert_allclose(arm.bias(q, dq), h, rtol=0, atol=TOL)
        np.testing.assert_allclose(arm.gravity_forces(q), G, rtol=0, atol=TOL)
        np.testing.assert_allclose(arm.tool_position(q), p, rtol=0, atol=TOL)
        np.testing.assert_allclose(arm.tool_jacobian(q), J, rtol=0, atol=TOL)
        np.testing.assert_allclose(arm.tool_acceleration_bias(q, dq), a, rtol=0, atol=TOL)
        tau = pin.rnea(arm.pin_model, arm.pin_model.createData(), arm.pinocchio_configuration(q), dq, ddq)
        np.testing.assert_allclose(arm.inverse_dynamics(q, dq, ddq), tau, rtol=0, atol=TOL)
        # the Cholesky solve inverts M: relative to the size of the accelerations (M's condition enters)
        ddq_back = arm.forward_dynamics(q, dq, tau)
        np.testing.assert_allclose(ddq_back, ddq, rtol=0, atol=1e-9 * max(1.0, np.linalg.cond(M) * 1e-6))


def test_batch_rows_equal_single_states(arms):
    arm = arms["panda"]
    rng = np.random.default_rng(3)
    q, dq, tau = rng.uniform(-1, 1, (3, 5, arm.n)), rng.uniform(-1, 1, (3, 5, arm.n)), rng.uniform(-5, 5, (3, 5, arm.n))
    M, h, ddq, J = arm.inertia(q), arm.bias(q, dq), arm.forward_dynamics(q, dq, tau), arm.tool_jacobian(q)
    assert M.shape == (3, 5, arm.n, arm.n) and J.shape == (3, 5, 3, arm.n) and ddq.shape == (3, 5, arm.n)
    for idx in np.ndindex(3, 5):
        np.testing.assert_array_equal(M[idx], arm.inertia(q[idx]))
        np.testing.assert_array_equal(h[idx], arm.bias(q[idx], dq[idx]))
        np.testing.assert_array_equal(ddq[idx], arm.forward_dynamics(q[idx], dq[idx], tau[idx]))


def test_energy_balance_of_the_mixed_arm(arms):
    """Without gravity and torque, M q'' + h = 0 conserves 1/2 q'^T M q': an independent check of N(q, q')."""
    arm = arms["mixed"]
    rng = np.random.default_rng(11)
    q, dq = rng.uniform(-1, 1, arm.n), rng.uniform(-1, 1, arm.n)
    ddq = arm.forward_dynamics(q, dq, arm.gravity_forces(q))          # gravity cancelled: free motion
    # d/dt (1/2 q'^T M q') = q'^T M q'' + 1/2 q'^T M' q' with M' by central differences along q'
    eps = 1e-6
    Mdot = (arm.inertia(q + eps * dq) - arm.inertia(q - eps * dq)) / (2 * eps)
    power = dq @ arm.inertia(q) @ ddq + 0.5 * dq @ Mdot @ dq
    assert abs(power) < 1e-8


def test_joint_space_from_the_urdf(arms):
    arm = arms["mixed"]
    assert arm.joints.names == ("spin", "slide", "bend")
    assert arm.joints.kinds == ("revolute", "prismatic", "revolute")
    assert arm.joints.limits == ((-math.inf, math.inf), (-0.1, 0.3), (-2.0, 2.0))
    assert arm.continuous == (True, False, False)
    assert arm.joints.position_units == ("rad", "m", "rad")
    np.testing.assert_array_equal(arm.gravity, [0.0, 0.0, -9.81])
    s4 = arms["scope4"]
    assert s4.joints.names == ("yaw", "pitch", "insertion", "roll")
    assert s4.joints.limits == ((-1.2, 1.2), (-0.9, 0.9), (0.0, 0.2), (-3.0, 3.0))


def test_scope4_remote_centre(arms):
    """Yaw, pitch and the insertion axis meet at the remote centre (0, 0, 0.30) m: the shaft line passes through it."""
    arm = arms["scope4"]
    rc = np.array([0.0, 0.0, 0.30])
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(*np.array(arm.joints.limits).T)
        p = arm.tool_position(q)
        shaft = arm.tool_jacobian(q)[:, 2]                     # the insertion moves the tip along the shaft
        offset = p - rc
        assert np.linalg.norm(np.cross(offset, shaft)) < 1e-14
        assert np.linalg.norm(offset) == pytest.approx(0.35 + q[2], abs=1e-14)


def test_locked_joint_at_a_value_and_gravity_override(mixed_urdf):
    arm = load_urdf_arm(mixed_urdf, "tip", locked=["slide"], locked_values={"slide": 0.2}, gravity=(0.0, -9.81, 0.0))
    assert arm.joints.names == ("spin", "bend")
    full = load_urdf_arm(mixed_urdf, "tip", gravity=(0.0, -9.81, 0.0))
    q = np.array([0.4, -0.7])
    q_full = np.array([0.4, 0.2, -0.7])
    np.testing.assert_allclose(arm.tool_position(q), full.tool_position(q_full), atol=1e-14)
    np.testing.assert_allclose(arm.inertia(q), full.inertia(q_full)[np.ix_([0, 2], [0, 2])], atol=1e-14)
    np.testing.assert_allclose(arm.gravity_forces(q), full.gravity_forces(q_full)[[0, 2]], atol=1e-14)


def test_panda_fingers_locked_and_kept():
    locked = example_arm("panda")
    assert locked.n == 7
    tree = load_urdf_arm(example_urdf("panda"), "panda_hand", mimic="independent")  # a tree: both fingers joints
    assert tree.n == 9 and "panda_finger_joint2" in tree.joints.names
    rng = np.random.default_rng(2)
    q, dq = np.concatenate([rng.uniform(-1, 1, 7), [0.02, 0.03]]), rng.uniform(-1, 1, 9)
    M, h, G, p, J, a = _pin_reference(tree, q, dq)
    np.testing.assert_allclose(tree.inertia(q), M, atol=TOL)
    np.testing.assert_allclose(tree.bias(q, dq), h, atol=TOL)


# -- bad input ---------------------------------------------------------------------------------------------------
def test_missing_file(tmp_path):
    with pytest.raises(UrdfFileError, match="nothere.urdf"):
        load_urdf_arm(tmp_path / "nothere.urdf", "tip")


def test_unparsable_file(tmp_path):
    path = tmp_path / "bad.urdf"
    path.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(UrdfParseError, match="not well-formed"):
        load_urdf_arm(path, "a")
    path.write_text("<model name='x'/>")
    with pytest.raises(UrdfParseError, match="<robot>"):
        load_urdf_arm(path, "a")


def test_unknown_tool_frame_lists_frames(mixed_urdf):
    with pytest.raises(UnknownFrameError, match=r"'nib'.*'tip'"):
        load_urdf_arm(mixed_urdf, "nib")


def test_unknown_locked_joint_lists_joints(mixed_urdf):
    with pytest.raises(UnknownJointError, match=r"'wrist'.*\['spin', 'slide', 'bend'\]"):
        load_urdf_arm(mixed_urdf, "tip", locked=["wrist"])
    with pytest.raises(UnknownJointError, match="outside its range"):
        load_urdf_arm(mixed_urdf, "tip", locked=["slide"], locked_values={"slide": 0.5})
    with pytest.raises(UnknownJointError, match="not in locked"):
        load_urdf_arm(mixed_urdf, "tip", locked=["slide"], locked_values={"bend": 0.5})


@pytest.mark.parametrize("kind", ["floating", "planar", "spherical"])
def test_unsupported_joint_type_named(tmp_path, kind):
    path = tmp_path / "float.urdf"
    path.write_text(MIXED.replace('name="spin" type="continuous"', f'name="spin" type="{kind}"'))
    with pytest.raises(UnsupportedJointError, match=f"'spin' is of type '{kind}'"):
        load_urdf_arm(path, "tip")


def test_massless_joint_and_bad_inertia(tmp_path):
    path = tmp_path / "massless.urdf"
    # the last joint moves a link without <inertial>: nothing resists it, M(q) is singular
    path.write_text(MIXED.replace(_link("d", m=0.3, c="0.1 0.01 0"), '<link name="d"/>'))
    with pytest.raises(InertiaError, match="'bend'"):
        load_urdf_arm(path, "tip")
    path.write_text(MIXED.replace('iyy="0.04"', 'iyy="-0.04"', 1))
    with pytest.raises(InertiaError, match="'spin'.*positive semi-definite"):
        load_urdf_arm(path, "tip")


@pytest.mark.parametrize("mass", [1e13, 1e300])
def test_a_link_heavier_than_double_precision_can_set_beside_the_rest_is_said_so(tmp_path, mass):
    """Link b at 1e13 kg (or 1e300) beside 0.3 kg: 'bend' does move mass, but M's entries differ by more than 1e12
    and the check says that (it said 'moves no mass'); at 1e10 kg the arm loads."""
    path = tmp_path / "heavy.urdf"
    heavy = MIXED.replace(_link("b", m=0.8, c="0 0 -0.1"), _link("b", m=mass, c="0 0 -0.1"))
    path.write_text(heavy)
    with pytest.raises(InertiaError, match=r"'bend' .* moves 0\.0\d+ kg m\^2 .*largest diagonal entry is 1e\+(13|300)"
                                           r": the arm's inertias differ by more than 1e12.*wrong unit"):
        load_urdf_arm(path, "tip")
    path.write_text(MIXED.replace(_link("b", m=0.8, c="0 0 -0.1"), _link("b", m=1e10, c="0 0 -0.1")))
    assert load_urdf_arm(path, "tip").n == 3


def test_bad_gravity_and_errors_are_value_errors(mixed_urdf):
    with pytest.raises(UrdfError, match="gravity"):
        load_urdf_arm(mixed_urdf, "tip", gravity=(0, 9.81))
    assert issubclass(UrdfError, ValueError)


def test_scope4_is_packaged():
    assert scope4_urdf().is_file()


def test_example_names_and_missing_package(monkeypatch):
    with pytest.raises(ValueError, match=r"'kuka' is unknown; the example arms are .*panda, .*ur5, .*z1"):
        example_urdf("kuka")
    assert example_urdf("ur5").name == "ur5_robot.urdf" and example_urdf("panda").name == "panda.urdf"
    from importlib import metadata

    def absent(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "distribution", absent)
    with pytest.raises(ModuleNotFoundError, match=r"dobkit\[urdf\]"):
        example_urdf("panda")


def _chain_urdf(path, n: int) -> str:
    """A serial chain of ``n`` revolute joints about z, each link 1 kg with a unit inertia, as a URDF file."""
    links = ['<link name="base"/>']
    for i in range(n):
        parent = "base" if i == 0 else f"l{i - 1}"
        links.append(f'<link name="l{i}"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>'
                     '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                     f'<joint name="j{i}" type="revolute"><parent link="{parent}"/><child link="l{i}"/>'
                     '<origin xyz="0.2 0 0"/><axis xyz="0 0 1"/>'
                     '<limit lower="-3" upper="3" effort="10" velocity="1"/></joint>')
    path.write_text('<robot name="chain">' + "".join(links) + "</robot>")
    return str(path)


def test_the_joint_count_limit_at_both_sides_and_locking_brings_an_arm_under_it(tmp_path):
    from blocks.model.urdf.urdf import MAX_JOINTS, UnsupportedJointError

    at_limit = load_urdf_arm(_chain_urdf(tmp_path / "at.urdf", MAX_JOINTS), f"l{MAX_JOINTS - 1}")
    assert at_limit.n == MAX_JOINTS
    over = _chain_urdf(tmp_path / "over.urdf", MAX_JOINTS + 1)
    with pytest.raises(UnsupportedJointError, match=f"{MAX_JOINTS + 1} moving joints .* at most {MAX_JOINTS}"):
        load_urdf_arm(over, f"l{MAX_JOINTS}")
    assert load_urdf_arm(over, f"l{MAX_JOINTS}", locked=["j0"]).n == MAX_JOINTS
