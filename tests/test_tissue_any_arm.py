"""The tissue (skin contact) disturbance for any arm, held against pinocchio, the paper's closed form and physics.

The contact force is written here from its definition: the tool frame's
height and linear Jacobian from pinocchio (``framesForwardKinematics`` and
``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)``), the depth ``p = skin - z``,
the tool velocity ``v = J q'``, ``F = (-c_lat v_x, -c_lat v_y, max(0, k p -
c v_z))`` while ``p > 0`` and ``tau = J^T F``.  On the paper's RRPR the
numbers must be those of its closed form (Eq. 8's planar Jacobian) bit for
bit; with drag and damping only the contact must take energy out of a
passive arm and never put any in; a closed loop of a URDF arm with the
contact must give one answer on every engine.
"""
from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

import blocks  # noqa: E402
from blocks.diagram.systems import plant  # noqa: E402
from blocks.engines.compiled import numba_or_none  # noqa: E402
from blocks.model.disturbances import DisturbanceSpec, external_disturbance, tissue_disturbance  # noqa: E402
from blocks.model.rrpr.parameters import RobotParameters  # noqa: E402
from blocks.model.urdf import example_arm  # noqa: E402
from blocks.scenarios.scenario import scenario_from_dict  # noqa: E402

TOL = 1e-12
K_TISSUE, C_TISSUE, DRAG = 800.0, 10.0, 20.0
needs_numba = pytest.mark.skipif(numba_or_none() is None, reason="the compiled engines need numba")


@pytest.fixture(scope="module")
def arms():
    return {name: example_arm(name) for name in ("scope4", "panda")}


def _spec(n: int, skin: float, **kw) -> DisturbanceSpec:
    values = dict(tissue_stiffness=K_TISSUE, tissue_damping=C_TISSUE, tissue_drag=DRAG) | kw
    return DisturbanceSpec(kinds=("tissue",), f_r=(0.0,) * n, coulomb=(0.0,) * n, viscous=(0.0,) * n,
                           skin_height=skin, **values)


def _random_states(arm, rng, count: int):
    lo = np.array([max(a, -2.5) for a, _ in arm.joints.limits])
    hi = np.array([min(b, 2.5) for _, b in arm.joints.limits])
    return rng.uniform(lo, hi, (count, arm.n)), rng.normal(0.0, 1.0, (count, arm.n))


def _pinocchio_tool(arm, q):
    """The tool frame's position (m) and linear Jacobian in base axes (3, n), by pinocchio."""
    model = arm.pin_model
    data = model.createData()
    qp = arm.pinocchio_configuration(q)
    pin.framesForwardKinematics(model, data, qp)
    pin.computeJointJacobians(model, data, qp)
    frame = model.getFrameId(arm.tool_frame)
    J = pin.getFrameJacobian(model, data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    return data.oMf[frame].translation.copy(), J


def _reference_tissue(arm, q, dq, spec) -> np.ndarray:
    """tau = J^T F of the skin contact, from the definition with pinocchio's kinematics."""
    p, J = _pinocchio_tool(arm, q)
    depth = spec.skin_height - p[2]
    if depth <= 0.0:
        return np.zeros(arm.n)
    v = J @ dq
    F = np.array([-spec.tissue_drag * v[0], -spec.tissue_drag * v[1],
                  max(0.0, spec.tissue_stiffness * depth - spec.tissue_damping * v[2])])
    return J.T @ F


# --------------------------------------------------------------------------------------------------------------
# The force against pinocchio
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["scope4", "panda"])
def test_tissue_force_of_a_urdf_arm_agrees_with_pinocchio(arms, name):
    arm = arms[name]
    rng = np.random.default_rng(len(name))
    q, dq = _random_states(arm, rng, 60)
    heights = np.array([_pinocchio_tool(arm, qi)[0][2] for qi in q])
    spec = _spec(arm.n, float(np.median(heights)))          # about half of the states below the skin
    inside = 0
    for qi, dqi in zip(q, dq):
        ref = _reference_tissue(arm, qi, dqi, spec)
        inside += bool(np.any(ref != 0.0))
        scale = max(1.0, float(np.max(np.abs(ref))))
        np.testing.assert_allclose(tissue_disturbance(qi, dqi, spec, arm), ref, rtol=0, atol=TOL * scale)
        np.testing.assert_allclose(external_disturbance(0.4, qi, dqi, spec, arm), ref, rtol=0, atol=TOL * scale)
    assert 15 <= inside <= 45                               # both sides of the skin were visited
    # many states at once (rows of the batch layout): the same numbers
    many = tissue_disturbance(q, dq, spec, arm)
    one_by_one = np.array([tissue_disturbance(qi, dqi, spec, arm) for qi, dqi in zip(q, dq)])
    np.testing.assert_allclose(many, one_by_one, rtol=0, atol=1e-13 * max(1.0, np.abs(one_by_one).max()))


def test_a_urdf_arm_is_no_longer_refused(arms):
    spec = _spec(4, -0.1)
    spec.check_arm(arms["scope4"], "scope4")                # no error
    block = plant(arms["scope4"], spec)
    assert block.name == "plant"


# --------------------------------------------------------------------------------------------------------------
# The paper's RRPR: the closed form's numbers, bit for bit
# --------------------------------------------------------------------------------------------------------------
def _rrpr_closed_form(kin, q, dq, skin, k, c, drag):
    """The RRPR's contact in closed form (Eq. 8: planar Jacobian in theta1, theta2, the tool's z' = -d3')."""
    t12 = q[0] + q[1]
    j00 = -kin[0] * np.sin(q[0]) - kin[1] * np.sin(t12)
    j01 = -kin[1] * np.sin(t12)
    j10 = kin[0] * np.cos(q[0]) + kin[1] * np.cos(t12)
    j11 = kin[1] * np.cos(t12)
    depth = skin - (kin[2] - q[2] - kin[3])
    inside = depth > 0.0
    vx, vy = j00 * dq[0] + j01 * dq[1], j10 * dq[0] + j11 * dq[1]
    fz = np.maximum(0.0, k * depth + c * dq[2]) * inside
    fx, fy = -drag * vx * inside, -drag * vy * inside
    return np.array([j00 * fx + j10 * fy, j01 * fx + j11 * fy, -fz, np.zeros_like(fz)])


def test_rrpr_numbers_are_the_closed_form_bit_for_bit():
    p = RobotParameters()
    kin = np.array([p.a1, p.a2, p.d1, p.d4])
    rng = np.random.default_rng(2019)
    count = 100_000
    q = np.column_stack([rng.uniform(-np.pi, np.pi, count), rng.uniform(-np.pi, np.pi, count),
                         rng.uniform(0.0, 0.5, count), rng.uniform(-np.pi, np.pi, count)])
    dq = rng.normal(0.0, 2.0, (count, 4))
    spec = DisturbanceSpec(kinds=("paper", "friction", "tissue"))
    expected = _rrpr_closed_form(kin, q.T, dq.T, spec.skin_height, spec.tissue_stiffness, spec.tissue_damping,
                                 spec.tissue_drag).T
    inside = np.any(expected != 0.0, axis=1)
    assert 0.3 < inside.mean() < 0.7
    got = tissue_disturbance(q, dq, spec, p)
    assert np.array_equal(got, expected)
    # the total of every model, bit patterns included (signed zeros too)
    friction = -(np.array(spec.coulomb) * np.tanh(dq / spec.friction_velocity) + np.array(spec.viscous) * dq)
    total = ((np.zeros_like(dq) + np.array(spec.f_r)) + friction) + expected
    got_total = external_disturbance(0.0, q, dq, spec, p)
    assert np.array_equal(got_total.view(np.uint64), total.view(np.uint64))
    # one state at a time (scalar rows) as well
    for i in range(0, count, 5000):
        assert np.array_equal(tissue_disturbance(q[i], dq[i], spec, p), expected[i])


# --------------------------------------------------------------------------------------------------------------
# Physics: drag and damping only take energy out
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["scope4", "panda"])
def test_drag_and_damping_do_no_positive_work(arms, name):
    # power tau^T q' = F . v = -c_lat (v_x^2 + v_y^2) - c min(v_z, 0)^2 <= 0 when k = 0
    arm = arms[name]
    rng = np.random.default_rng(7 + arm.n)
    q, dq = _random_states(arm, rng, 200)
    skin = float(np.median([_pinocchio_tool(arm, qi)[0][2] for qi in q]))
    spec = _spec(arm.n, skin, tissue_stiffness=0.0)
    power = np.einsum("ij,ij->i", tissue_disturbance(q, dq, spec, arm), dq)
    expected = np.zeros(len(q))
    for i, (qi, dqi) in enumerate(zip(q, dq)):
        p, J = _pinocchio_tool(arm, qi)
        if skin - p[2] > 0.0:
            v = J @ dqi
            expected[i] = -DRAG * (v[0] ** 2 + v[1] ** 2) - C_TISSUE * min(v[2], 0.0) ** 2
    assert np.all(power <= 1e-12)
    assert np.count_nonzero(expected) > 50
    np.testing.assert_allclose(power, expected, rtol=1e-11, atol=1e-12)


def test_a_passive_arm_loses_the_energy_the_contact_dissipates(arms):
    # scope4 with no torque, falling along its insertion axis into tissue of drag and damping only: its energy
    # (pinocchio's kinetic + potential) never rises, and falls by the work the contact does
    from scipy.integrate import solve_ivp

    arm = arms["scope4"]
    model = arm.pin_model
    data = model.createData()
    q0 = np.array([0.2, 0.3, 0.05, 0.4])
    dq0 = np.array([0.5, -0.4, 0.3, 1.0])
    skin = float(_pinocchio_tool(arm, q0)[0][2]) + 0.002      # the tool starts 2 mm deep
    spec = _spec(arm.n, skin, tissue_stiffness=0.0)
    n = arm.n

    def rhs(t, y):
        q, dq = y[:n], y[n:2 * n]
        tau = tissue_disturbance(q, dq, spec, arm)
        return np.concatenate((dq, arm.forward_dynamics(q, dq, tau), [tau @ dq]))

    t = np.linspace(0.0, 0.3, 301)
    sol = solve_ivp(rhs, (0.0, 0.3), np.concatenate((q0, dq0, [0.0])), t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-12)
    assert sol.success

    def energy(y):
        q = arm.pinocchio_configuration(y[:n])
        return pin.computeKineticEnergy(model, data, q, y[n:2 * n]) + pin.computePotentialEnergy(model, data, q)

    E = np.array([energy(y) for y in sol.y.T])
    work = sol.y[-1]                                        # the integral of tau^T q' (J)
    assert work[-1] < -1e-3                                 # the contact did dissipate
    assert np.all(np.diff(E) <= 1e-9)
    np.testing.assert_allclose(E - E[0], work, atol=1e-8)


# --------------------------------------------------------------------------------------------------------------
# A URDF scenario with the contact: every engine gives one answer
# --------------------------------------------------------------------------------------------------------------
def _signal(resp, name: str, n: int) -> np.ndarray:
    return np.array([resp.outputs[resp.output_labels.index(f"{name}[{i}]")] for i in range(n)])


@pytest.fixture(scope="module")
def scope4_tissue():
    s = blocks.load_scenario("scope4").replace(disturbance={"kind": ["step", "tissue"]},
                                               simulation={"t_final": 0.3, "rtol": 1e-10, "atol": 1e-12})
    return s


def test_scope4_skin_defaults_to_the_tool_height_at_the_reference_start(scope4_tissue):
    s = scope4_tissue
    p, _ = _pinocchio_tool(s.robot, np.asarray(s.trajectory.evaluate(0.0)[0]))
    assert s.disturbance.skin_height == pytest.approx(p[2], abs=TOL)
    assert s.data["disturbance"]["skin_height"] == s.disturbance.skin_height     # the written scenario says it
    again = scenario_from_dict(s.data)
    assert again.disturbance.skin_height == s.disturbance.skin_height


@pytest.fixture(scope="module")
def single_runs(scope4_tissue):
    engines = ("fast", "python-control") + (("compiled",) if numba_or_none() is not None else ())
    return {e: blocks.simulate(scope4_tissue, engine=e) for e in engines}


def test_scope4_closed_loop_with_tissue_agrees_across_engines(scope4_tissue, single_runs):
    n = scope4_tissue.robot.n
    reference = _signal(single_runs["python-control"], "q", n)
    for engine, resp in single_runs.items():
        np.testing.assert_allclose(_signal(resp, "q", n), reference, rtol=0, atol=1e-6, err_msg=engine)
    # the contact acted: tau_dis beyond the Eq. 4 step on the insertion joint, as the definition gives it
    resp = single_runs["fast"]
    q, dq, tau_dis = (_signal(resp, k, n) for k in ("q", "dq", "tau_dis"))
    contact = tau_dis - np.array(scope4_tissue.disturbance.f_r)[:, None]
    assert np.abs(contact[2]).max() > 1.0
    spec = scope4_tissue.disturbance
    for j in range(0, q.shape[1], 7):
        ref = _reference_tissue(scope4_tissue.robot, q[:, j], dq[:, j], spec)
        np.testing.assert_allclose(contact[:, j], ref, rtol=0, atol=1e-10 * max(1.0, np.abs(ref).max()))


@needs_numba
def test_scope4_batch_with_tissue_agrees_with_the_single_run(scope4_tissue, single_runs):
    from blocks.figure2.batch.simulate import simulate_batch

    n = scope4_tissue.robot.n
    single = _signal(single_runs["fast"], "q", n)
    records = [{}, {"disturbance.tissue_stiffness": 400.0}]
    # the contact's kinks make fixed-step RK4 first order: a fine step for 1e-6 rad
    fine = simulate_batch(scope4_tissue, records, signals=("q",), engine="compiled", substeps=200)
    np.testing.assert_allclose(fine.signals["q"][0].T, single, rtol=0, atol=1e-6)
    assert np.abs(fine.signals["q"][1].T - single).max() > 1e-5        # the stiffness reached the member
    # the numpy batch on the same schedule as the compiled one (a short one: it is slow for a URDF arm)
    short = scope4_tissue.replace(simulation={"t_final": 0.05})
    numpy_batch = simulate_batch(short, records, signals=("q",), engine="fast", substeps=5)
    compiled_batch = simulate_batch(short, records, signals=("q",), engine="compiled", substeps=5)
    np.testing.assert_allclose(numpy_batch.signals["q"], compiled_batch.signals["q"], rtol=0, atol=1e-12)


@needs_numba
def test_scope4_sampled_loop_with_tissue_agrees_across_engines():
    from blocks.figure2.digital_loop import simulate_sampled

    s = blocks.load_scenario("scope4-digital").replace(disturbance={"kind": ["step", "tissue"]},
                                                       simulation={"t_final": 0.3})
    n = s.robot.n
    runs = {e: simulate_sampled(s, engine=e) for e in ("fast", "compiled")}
    q = {e: _signal(r, "q", n) for e, r in runs.items()}
    np.testing.assert_allclose(q["compiled"], q["fast"], rtol=0, atol=1e-6)
    contact = _signal(runs["fast"], "tau_dis", n) - np.array(s.disturbance.f_r)[:, None]
    assert np.abs(contact[2]).max() > 1.0


# --------------------------------------------------------------------------------------------------------------
# The plant FMU of a URDF arm with the contact
# --------------------------------------------------------------------------------------------------------------
@pytest.mark.needs_cc
def test_urdf_plant_fmu_tissue_forces_agree_with_pinocchio(arms, tmp_path):
    from fmu import FMUInstance, export_plant

    arm = arms["panda"]
    n = arm.n
    path = export_plant(tmp_path / "panda.fmu", params=arm)
    rng = np.random.default_rng(11)
    q, dq = _random_states(arm, rng, 30)
    skin = float(np.median([_pinocchio_tool(arm, qi)[0][2] for qi in q]))
    start = {"disturbance_tissue": True, "skin_height": skin, "tissue_stiffness": K_TISSUE,
             "tissue_damping": C_TISSUE, "tissue_drag": DRAG}
    spec = _spec(n, skin)
    inside = 0
    with FMUInstance(path, "ModelExchange", start_values=start) as f:
        taus = f.value_references([f"tau[{i}]" for i in range(n)])
        tau_dis = f.value_references([f"tau_dis[{i}]" for i in range(n)])
        for qi, dqi in zip(q, dq):
            f.set_time(0.2)
            f.set_states(np.concatenate((qi, dqi)))
            f.set_real(taus, np.zeros(n))
            f.derivatives()
            got = f.get_real(tau_dis)
            ref = _reference_tissue(arm, qi, dqi, spec)
            inside += bool(np.any(ref != 0.0))
            np.testing.assert_allclose(got, ref, rtol=0, atol=TOL * max(1.0, np.abs(ref).max()))
    assert 5 <= inside <= 25
