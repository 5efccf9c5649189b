"""The Figure-2 loop for an arm that is not the paper's RRPR.

The arm here is a 2-link planar arm in a vertical plane, written in this file
with its closed-form M, h and forward kinematics (textbook Lagrangian), and
held against pinocchio on the same URDF.  The loop dobkit builds for it (the
numpy, compiled and python-control engines) is held against an independent
loop written here: pinocchio's ``crba`` and ``nonLinearEffects`` in a plain
``scipy.integrate.solve_ivp`` right-hand side implementing Eq. 1, Eq. 11 and
the observer of Eq. 12-16 (corrected).
"""
from __future__ import annotations

import math
import types

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import blocks
from blocks.figure2.metrics import tracking_metrics
from blocks.kernels.laws import computed_torque
from blocks.kernels.model import with_arm
from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace

pin = pytest.importorskip("pinocchio")

# m1, m2 (kg), l1 (m), lc1, lc2 (m, centres of mass), I1, I2 (kg m^2 about the centres, axis y), g (m/s^2)
PLANAR = (2.0, 1.2, 0.5, 0.22, 0.18, 0.06, 0.025, 9.81)
L2 = 0.4            # tool point at the end of link 2 (m)


# --- the arm's row kernels, closed form (joint-first rows) ----------------------------------------------------
def _entries(k, q):
    m1, m2, l1, lc1, lc2, i1, i2 = k[0], k[1], k[2], k[3], k[4], k[5], k[6]
    c2 = np.cos(q[1])
    m22 = m2 * lc2 * lc2 + i2
    m12 = m22 + m2 * l1 * lc2 * c2
    m11 = m1 * lc1 * lc1 + i1 + m2 * l1 * l1 + m22 + 2.0 * m2 * l1 * lc2 * c2
    return m11, m12, m22


def inertia_matrix(k, q):
    m11, m12, m22 = np.broadcast_arrays(*_entries(k, q))
    M = np.zeros(m11.shape + (2, 2))
    M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1] = m11, m12, m12, m22
    return M


def mass_times(k, q, v):
    m11, m12, m22 = _entries(k, q)
    out = np.empty_like(v)
    out[0] = m11 * v[0] + m12 * v[1]
    out[1] = m12 * v[0] + m22 * v[1]
    return out


def mass_solve(k, q, r):
    m11, m12, m22 = _entries(k, q)
    inv_det = 1.0 / (m11 * m22 - m12 * m12)
    out = np.empty_like(r)
    out[0] = (m22 * r[0] - m12 * r[1]) * inv_det
    out[1] = (m11 * r[1] - m12 * r[0]) * inv_det
    return out


def gravity_forces(k, q):
    # links in the x-z plane, joint axes +y: a positive angle turns x towards -z; gravity is -z
    m1, m2, l1, lc1, lc2, g = k[0], k[1], k[2], k[3], k[4], k[7]
    c1, c12 = np.cos(q[0]), np.cos(q[0] + q[1])
    out = np.empty_like(q * g)
    out[0] = -g * ((m1 * lc1 + m2 * l1) * c1 + m2 * lc2 * c12)
    out[1] = -g * m2 * lc2 * c12
    return out


def bias_forces(k, q, dq):
    h = -k[1] * k[2] * k[4] * np.sin(q[1])
    out = gravity_forces(k, q + 0.0 * dq)
    out[0] = out[0] + h * dq[1] * (2.0 * dq[0] + dq[1])
    out[1] = out[1] - h * dq[0] * dq[0]
    return out


def plant_acceleration(k, q, dq, force):
    return mass_solve(k, q, force - bias_forces(k, q, dq))


def tool_position(kin, q):
    l1, l2 = kin[0], kin[1]
    out = np.zeros((3,) + np.shape(q[0]), dtype=np.result_type(q, float))
    out[0] = l1 * np.cos(q[0]) + l2 * np.cos(q[0] + q[1])
    out[2] = -(l1 * np.sin(q[0]) + l2 * np.sin(q[0] + q[1]))
    return out


def tool_jacobian(kin, q):
    l1, l2 = kin[0], kin[1]
    s1, s12, c1, c12 = np.sin(q[0]), np.sin(q[0] + q[1]), np.cos(q[0]), np.cos(q[0] + q[1])
    out = np.zeros((3, 2) + np.shape(q[0]))
    out[0, 0], out[0, 1] = -l1 * s1 - l2 * s12, -l2 * s12
    out[2, 0], out[2, 1] = -l1 * c1 - l2 * c12, -l2 * c12
    return out


def tool_acceleration_bias(kin, q, dq):
    l1, l2 = kin[0], kin[1]
    w1, w12 = dq[0] * dq[0], (dq[0] + dq[1]) ** 2
    out = np.zeros((3,) + np.shape(dq[0]))
    out[0] = -l1 * np.cos(q[0]) * w1 - l2 * np.cos(q[0] + q[1]) * w12
    out[2] = l1 * np.sin(q[0]) * w1 + l2 * np.sin(q[0] + q[1]) * w12
    return out


_kernels = types.ModuleType("planar2_kernels")
_tool = types.ModuleType("planar2_tool_kernels")
for _f in (inertia_matrix, mass_times, mass_solve, gravity_forces, bias_forces, plant_acceleration):
    setattr(_kernels, _f.__name__, _f)
for _f in (tool_position, tool_jacobian, tool_acceleration_bias):
    setattr(_tool, _f.__name__, _f)


class Planar2(ArmModel):
    """A 2-link planar arm in a vertical plane (both joints about +y)."""

    joints = JointSpace(names=("shoulder", "elbow"), kinds=("revolute", "revolute"),
                        limits=((-math.pi, math.pi), (-2.8, 2.8)))
    kernels = _kernels
    tool_kernels = _tool
    name = "planar2"

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = scale

    def kernel_params(self):
        k = np.array(PLANAR, dtype=float)
        k[[0, 1, 5, 6]] *= self.scale           # masses and inertias: the dynamics scale with them
        return k

    def tool_params(self):
        return np.array([PLANAR[2], L2])


URDF = """<robot name="planar2">
  <link name="base"/>
  <link name="link1"><inertial><origin xyz="{lc1} 0 0"/><mass value="{m1}"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="{I1}" iyz="0" izz="0.01"/></inertial></link>
  <link name="link2"><inertial><origin xyz="{lc2} 0 0"/><mass value="{m2}"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="{I2}" iyz="0" izz="0.01"/></inertial></link>
  <link name="tool"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="link1"/><axis xyz="0 1 0"/>
    <limit lower="-3.14159" upper="3.14159" effort="100" velocity="10"/></joint>
  <joint name="elbow" type="revolute"><parent link="link1"/><child link="link2"/><origin xyz="{l1} 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2.8" upper="2.8" effort="100" velocity="10"/></joint>
  <joint name="tool_fixed" type="fixed"><parent link="link2"/><child link="tool"/><origin xyz="{l2} 0 0"/></joint>
</robot>"""


@pytest.fixture(scope="module")
def reference():
    m1, m2, l1, lc1, lc2, i1, i2, g = PLANAR
    model = pin.buildModelFromXML(URDF.format(m1=m1, m2=m2, l1=l1, lc1=lc1, lc2=lc2, I1=i1, I2=i2, l2=L2))
    model.gravity.linear = np.array([0.0, 0.0, -g])
    return model, model.createData(), model.getFrameId("tool")


def test_planar_kernels_agree_with_pinocchio(reference):
    """The test's own arm is right before it tests the loop: M, h, G and the tool point against pinocchio."""
    model, data, tool = reference
    arm = Planar2()
    rng = np.random.default_rng(3)
    for _ in range(20):
        q, dq = rng.uniform(-2.5, 2.5, 2), rng.uniform(-3, 3, 2)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        np.testing.assert_allclose(arm.inertia(q), M, rtol=0, atol=1e-12)
        np.testing.assert_allclose(arm.bias(q, dq), pin.nonLinearEffects(model, data, q, dq), rtol=0, atol=1e-12)
        np.testing.assert_allclose(arm.gravity_forces(q), pin.computeGeneralizedGravity(model, data, q), atol=1e-12)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        np.testing.assert_allclose(arm.tool_position(q), data.oMf[tool].translation, atol=1e-12)
        J = pin.computeFrameJacobian(model, data, q, tool, pin.LOCAL_WORLD_ALIGNED)[:3]
        np.testing.assert_allclose(arm.tool_jacobian(q), J, atol=1e-12)


# --- the scenario and the independent loop --------------------------------------------------------------------
KP, KD, Y = (120.0, 90.0), (22.0, 19.0), (4.0, 3.0)
F_R = (0.7, -0.4)
AMPLITUDE, OMEGA, OFFSET = (0.3, 0.5), (1.3, 2.1), (0.2, 1.0)
SCALE = 1.15            # the nominal model's masses and inertias: Eq. 3's internal disturbance


def _scenario(**changes):
    data = {"name": "planar2", "gains": {"kp": list(KP), "kd": list(KD), "observer": list(Y)},
            "trajectory": {"kind": "joint_sine", "amplitude": list(AMPLITUDE), "omega": list(OMEGA),
                           "offset": list(OFFSET)},
            "disturbance": {"kind": "step", "f_r": list(F_R)},
            "initial": {"q": [0.25, 0.95], "dq": [0.0, 0.0]},
            "simulation": {"t_final": 3.0, "output_step": 0.01, "rtol": 1e-10, "atol": 1e-12}}
    for key, value in changes.items():
        section, name = key.split(".")
        data.setdefault(section, {})[name] = value
    if "observer_bandwidth" in data["gains"]:
        del data["gains"]["observer"]
    return blocks.scenario_from_dict(data, arm=Planar2(), nominal=Planar2(SCALE))


def _pinocchio_loop(reference, t_grid, observer: bool):
    """Eq. 1 on pinocchio's M and h; Eq. 11 and the observer on pinocchio's with masses and inertias x SCALE."""
    model, data, _ = reference
    kp, kd, Yd = (np.array(v) for v in (KP, KD, Y))
    a, w, c = (np.array(v) for v in (AMPLITUDE, OMEGA, OFFSET))

    def dyn(q, dq):
        M = pin.crba(model, data, q)
        return np.triu(M) + np.triu(M, 1).T, pin.nonLinearEffects(model, data, q, dq).copy()

    def rhs(t, x):
        q, dq, z = x[:2], x[2:4], x[4:]
        q_ref, dq_ref, ddq_ref = c + a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)
        M, h = dyn(q, dq)
        Mn, hn = SCALE * M, SCALE * h                      # the nominal model (dynamics linear in the inertias)
        d_hat = Yd * dq + z if observer else 0.0
        tau = Mn @ (ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)) + hn - d_hat
        ddq = np.linalg.solve(M, tau + np.array(F_R) - h)
        dz = -Yd * np.linalg.solve(Mn, tau + d_hat - hn) if observer else np.zeros(2)
        return np.concatenate([dq, ddq, dz])

    x0 = np.array([0.25, 0.95, 0.0, 0.0, 0.0, 0.0])
    x0[4:] = -Yd * x0[2:4]                                  # d_hat(0) = 0
    sol = solve_ivp(rhs, (t_grid[0], t_grid[-1]), x0, t_eval=t_grid, rtol=1e-11, atol=1e-12, method="DOP853")
    assert sol.success
    return sol.y[:2]


def _rms_error(resp, n=2):
    out = np.asarray(resp.outputs)
    labels = list(resp.output_labels)
    e = np.array([out[labels.index(f"q_ref[{i}]")] - out[labels.index(f"q[{i}]")] for i in range(n)])
    return np.sqrt(np.mean(e * e, axis=1)), np.array([out[labels.index(f"q[{i}]")] for i in range(n)])


@pytest.mark.parametrize("engine", ["fast", "compiled", "python-control"])
@pytest.mark.parametrize("observer", [True, False])
def test_loop_of_another_arm_matches_an_independent_pinocchio_loop(reference, engine, observer):
    """Per joint RMS tracking error within 1e-6 rad of the independent loop, and the trajectories themselves."""
    if engine == "compiled":
        pytest.importorskip("numba")
    s = _scenario()
    t = s.simulation.time_grid
    q_ref = np.array([OFFSET[i] + AMPLITUDE[i] * np.sin(OMEGA[i] * t) for i in range(2)])
    q_pin = _pinocchio_loop(reference, t, observer)
    resp = blocks.simulate(s, observer=observer, engine=engine)
    rms, q = _rms_error(resp)
    rms_pin = np.sqrt(np.mean((q_ref - q_pin) ** 2, axis=1))
    np.testing.assert_allclose(rms, rms_pin, rtol=0, atol=1e-6)
    np.testing.assert_allclose(q, q_pin, rtol=0, atol=1e-6)
    assert resp.engine == engine
    assert rms.min() > 1e-5             # the disturbance and the model mismatch do move the arm off its path


def test_observer_removes_the_step_and_the_mismatch(reference):
    """With the observer (Y = omega M^(q0), omega = 20 rad/s) the arm tracks far better than without over the last
    second (the lumped disturbance is estimated and cancelled)."""
    s = _scenario(**{"gains.observer_bandwidth": 20.0}).with_changes({})
    assert "observer" not in s.data["gains"]

    def late_rms(resp):
        out, labels = np.asarray(resp.outputs), list(resp.output_labels)
        late = resp.time >= 2.0
        e = np.array([out[labels.index(f"q_ref[{i}]"), late] - out[labels.index(f"q[{i}]"), late] for i in range(2)])
        return np.sqrt(np.mean(e * e, axis=1))

    with_obs = late_rms(blocks.simulate(s, observer=True, engine="fast"))
    without = late_rms(blocks.simulate(s, observer=False, engine="fast"))
    assert np.all(with_obs < 0.2 * without), (with_obs, without)


def test_lumped_disturbance_of_another_arm_is_the_step_plus_the_mismatch(reference):
    """d = tau_dis + (M^ - M) q'' + (h^ - h) = f_r + (SCALE - 1)(M q'' + h), from pinocchio's M and h."""
    model, data, _ = reference
    s = _scenario()
    resp = blocks.simulate(s, observer=True, engine="fast")
    out, labels = np.asarray(resp.outputs), list(resp.output_labels)

    def sig(prefix, j):
        return np.array([out[labels.index(f"{prefix}[{i}]"), j] for i in range(2)])

    for j in (0, 57, 200):
        q, dq, tau = sig("q", j), sig("dq", j), sig("tau", j)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(model, data, q, dq)
        ddq = np.linalg.solve(M, tau + np.array(F_R) - h)
        expected = np.array(F_R) + (SCALE - 1.0) * (M @ ddq + h)
        np.testing.assert_allclose(sig("d", j), expected, rtol=1e-9, atol=1e-9)


def test_one_law_takes_the_arm_s_kernels_as_a_value():
    arm = Planar2()
    law = with_arm(computed_torque, arm)
    assert law.law is computed_torque and law.model is arm.arm_kernels and law.__module__ == computed_torque.__module__
    assert with_arm(computed_torque, blocks.PAPER_PARAMETERS).law is computed_torque
    # called with the arm's kernels it computes Eq. 11 with the arm's M and h: M (ddq_ref + Kd e' + Kp e) + h
    q, dq = np.array([0.3, -0.7]), np.array([0.4, 1.1])
    v = np.array([0.5, -0.2]) + np.array(KD) * (0 - dq) + np.array(KP) * (np.array([0.1, 0.2]) - q)
    tau = law(arm.kernel_params(), np.array(KP), np.array(KD), q, dq, np.array([0.1, 0.2]), np.zeros(2),
              np.array([0.5, -0.2]), 0.0)
    np.testing.assert_allclose(tau, arm.inertia(q) @ v + arm.bias(q, dq), rtol=1e-13, atol=1e-13)


def test_metrics_of_another_arm_are_per_joint_with_its_tool_point(reference):
    s = _scenario()
    resp = blocks.simulate(s, observer=True, engine="fast")
    m = tracking_metrics(resp)
    assert len(m["rms_position_error"]) == 2 and len(m["rms_disturbance_error"]) == 2
    out, labels = np.asarray(resp.outputs), list(resp.output_labels)
    q = np.array([out[labels.index(f"q[{i}]")] for i in range(2)])
    q_ref = np.array([out[labels.index(f"q_ref[{i}]")] for i in range(2)])
    model, data, tool = reference

    def tip(qq):
        pin.framesForwardKinematics(model, data, qq)
        return data.oMf[tool].translation.copy()

    dist = np.array([np.linalg.norm(tip(q_ref[:, j]) - tip(q[:, j])) for j in range(q.shape[1])])
    assert m["max_tool_position_error_mm"] == pytest.approx(1e3 * dist.max(), rel=1e-9)
    assert m["rms_tool_position_error_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(dist ** 2)), rel=1e-9)


# --- a URDF arm (blocks.model.urdf.load_urdf_arm) against the same independent loop on its pinocchio model -----------
def _urdf_loop_reference(s, observer: bool):
    """Eq. 1, Eq. 11 and the observer on pinocchio's crba / nonLinearEffects of the arm's own pinocchio model, the
    nominal model being the true one with every mass and inertia x arm.nominal_mass_scale."""
    arm = s.robot
    model = arm.pin_model
    data = model.createData()
    scale = s.data["arm"]["nominal_mass_scale"]
    kp, kd, Yg = np.diag(s.kp), np.diag(s.kd), np.asarray(s.observer_gain)
    f_r = np.array(s.disturbance.f_r)
    a, w, c = (np.array(v) for v in (s.trajectory.amplitude, s.trajectory.omega, s.trajectory.offset))
    n = arm.n

    def rhs(t, x):
        q, dq, z = x[:n], x[n:2 * n], x[2 * n:]
        q_ref, dq_ref, ddq_ref = c + a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)
        qp = arm.pinocchio_configuration(q)
        M = pin.crba(model, data, qp)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(model, data, qp, dq).copy()
        Mn, hn = scale * M, scale * h
        d_hat = Yg @ dq + z if observer else 0.0
        tau = Mn @ (ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)) + hn - d_hat
        ddq = np.linalg.solve(M, tau + f_r - h)
        dz = -Yg @ np.linalg.solve(Mn, tau + d_hat - hn) if observer else np.zeros(n)
        return np.concatenate([dq, ddq, dz])

    t = s.simulation.time_grid
    q0, dq0, _ = s.trajectory.evaluate(0.0)
    x0 = np.concatenate([q0, dq0, -Yg @ dq0])
    sol = solve_ivp(rhs, (t[0], t[-1]), x0, t_eval=t, rtol=1e-11, atol=1e-12, method="DOP853")
    assert sol.success
    return sol.y[:n]


def _urdf_scenario(name: str):
    s = blocks.load_scenario(name)
    return s.with_changes({"simulation.t_final": 2.0, "simulation.rtol": 1e-10, "simulation.atol": 1e-12})


@pytest.mark.parametrize("name, engine", [("scope4", "fast"), ("scope4", "compiled"), ("panda", "fast")])
def test_urdf_arm_loop_matches_an_independent_pinocchio_loop(name, engine):
    """The built-in URDF scenarios (nominal masses 5 % heavy, Eq. 4 step on every joint, Y = 10 M^(q0)): per joint
    RMS tracking error within 1e-6 rad (m for the insertion) of the pinocchio loop, with and without observer."""
    if engine == "compiled":
        pytest.importorskip("numba")
    if name == "panda":
        from importlib import metadata
        try:
            metadata.distribution("example-robot-data")
        except metadata.PackageNotFoundError:
            pytest.skip("example-robot-data is the extra dobkit[urdf]")
    s = _urdf_scenario(name)
    n = s.robot.n
    t = s.simulation.time_grid
    q_ref = np.asarray(s.trajectory.evaluate(t)[0]).T
    for observer in (True, False):
        q_pin = _urdf_loop_reference(s, observer)
        resp = blocks.simulate(s, observer=observer, engine=engine)
        rms, q = _rms_error(resp, n)
        np.testing.assert_allclose(rms, np.sqrt(np.mean((q_ref - q_pin) ** 2, axis=1)), rtol=0, atol=1e-6)
        np.testing.assert_allclose(q, q_pin, rtol=0, atol=1e-6)
        assert resp.engine == engine and rms.min() > 1e-6


def test_compiled_program_and_cache_key_differ_between_arms():
    """The compiled engine's structure (program cache) and its on-disk key follow the arm: the RRPR's joint-sine loop,
    the 2-link arm and scope4 get three programs."""
    pytest.importorskip("numba")
    from blocks.diagram.plan import make_plan
    from blocks.engines.compiled.codegen import program_for
    from blocks.engines.compiled.rows import loop_rows, loop_rows_of

    programs = []
    for s in (blocks.load_scenario("joint-sine"), _scenario(), _urdf_scenario("scope4")):
        loop = blocks.closed_loop(s)
        rows = loop_rows_of(loop)
        assert rows == loop_rows(s.robot)                  # the plant's arm's groups, the paper's arm too
        program, _ = program_for(make_plan(loop), loop, rows)
        programs.append(program)
    assert len({p.structure for p in programs}) == 3
    assert len({p.source for p in programs}) == 3
    assert len({p.key for p in programs}) == 3
