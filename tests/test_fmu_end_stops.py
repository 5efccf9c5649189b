"""The plant FMU's joint ranges (FMI min/max) and end stops, for the paper's arm and a URDF arm (scope4).

References: the paper's numbers (docs/model.md: d3 from 0 to 0.48 m, k4 = m3 + m4 = 0.25 kg, g = 9.8 m/s^2,
d3 decoupled from the other joints), the URDF's own <limit> elements read here with ElementTree, pinocchio's
generalized gravity for the scope4's rest, and an FMU exported without end stops for the numbers inside the ranges.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import fmpy
import numpy as np
import pytest
from conftest import PAPER_G, PAPER_K, reference_inertia
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from blocks.model.rrpr.parameters import RobotParameters
from fmu import FMUInstance, export_plant

pytestmark = pytest.mark.needs_cc

D3_RANGE = (0.0, 0.48)          # docs/model.md, "Joint ranges"
STOP_W = 200.0                  # rad/s, fmu/end_stops.py


@pytest.fixture(scope="module")
def rrpr(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stops")
    return {"fmi2": export_plant(folder / "rrpr2.fmu"), "fmi3": export_plant(folder / "rrpr3.fmu", fmi_version=3),
            "free": export_plant(folder / "free.fmu", end_stops=False)}


@pytest.fixture(scope="module")
def scope4(tmp_path_factory):
    pytest.importorskip("pinocchio")
    from blocks.model.urdf import example_arm
    folder = tmp_path_factory.mktemp("stops_scope4")
    arm = example_arm("scope4")
    return arm, {"fmi2": export_plant(folder / "scope4.fmu", params=arm),
                 "fmi3": export_plant(folder / "scope4_3.fmu", params=arm, fmi_version=3),
                 "free": export_plant(folder / "scope4_free.fmu", params=arm, end_stops=False)}


def _variables(path):
    return {v.name: v for v in read_model_description(str(path)).modelVariables}


def _urdf_limits(path, names):
    """(lower, upper) of each named joint, read from the URDF text (continuous: none)."""
    joints = {j.get("name"): j for j in ET.parse(path).getroot().iter("joint")}
    out = []
    for name in names:
        j = joints[name]
        limit = j.find("limit")
        if j.get("type") == "continuous" or limit is None:
            out.append((None, None))
        else:
            out.append((float(limit.get("lower")), float(limit.get("upper"))))
    return out


# --- the ranges as FMI reports them ----------------------------------------------------------------------------

@pytest.mark.parametrize("key", ["fmi2", "fmi3"])
def test_rrpr_ranges_are_min_max_of_the_joint_positions(rrpr, key):
    assert validate_fmu(str(rrpr[key])) == []
    v = _variables(rrpr[key])
    for i, unit in enumerate(("rad", "rad", "m", "rad")):
        assert v[f"q[{i}]"].unit == unit
        expected = D3_RANGE if i == 2 else (None, None)        # the revolute joints of a SCARA turn without end
        got = tuple(None if x is None else float(x) for x in (v[f"q[{i}]"].min, v[f"q[{i}]"].max))
        assert got == expected
    stops = sorted(n for n in v if n.startswith("stop_"))
    assert stops == ["stop_damping[2]", "stop_stiffness[2]"]
    assert (v["stop_stiffness[2]"].unit, v["stop_damping[2]"].unit) == ("N/m", "N.s/m")
    # d3 is decoupled, so its effective inertia is k4 = m3 + m4 everywhere: k = k4 w^2, c = 2 k4 w (critical)
    assert float(v["stop_stiffness[2]"].start) == pytest.approx(PAPER_K["k4"] * STOP_W ** 2, rel=1e-12)
    assert float(v["stop_damping[2]"].start) == pytest.approx(2.0 * PAPER_K["k4"] * STOP_W, rel=1e-12)


@pytest.mark.parametrize("key", ["fmi2", "fmi3"])
def test_scope4_ranges_are_the_urdf_limits(scope4, key):
    from blocks.model.urdf import scope4_urdf
    arm, fmus = scope4
    assert validate_fmu(str(fmus[key])) == []
    v = _variables(fmus[key])
    for i, (lo, hi) in enumerate(_urdf_limits(scope4_urdf(), arm.joints.names)):
        assert (float(v[f"q[{i}]"].min), float(v[f"q[{i}]"].max)) == (lo, hi)
        assert v[f"q[{i}]"].unit == ("m" if arm.joints.kinds[i] == "prismatic" else "rad")
        assert f"stop_stiffness[{i}]" in v and float(v[f"stop_stiffness[{i}]"].start) > 0


def test_a_start_pose_outside_the_ranges_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"d3 reaches 0\.6 m, outside its range 0 to 0\.48 m"):
        export_plant(tmp_path / "x.fmu", q0=[0.0, 1.0, 0.6, 0.0])
    assert not (tmp_path / "x.fmu").exists()


def test_the_panda_starts_inside_its_ranges(tmp_path):
    pytest.importorskip("pinocchio")
    from blocks.model.urdf import example_arm
    from fmu.scenario_values import default_start_q
    arm = example_arm("panda")
    q0 = default_start_q(arm)
    assert arm.joints.outside_limits(q0) is None
    # joint 4's range -3.0718 to -0.0698 rad excludes 0: the middle; every other joint at 0
    assert q0 == [0.0, 0.0, 0.0, pytest.approx(0.5 * (-3.0718 - 0.0698)), 0.0, 0.0, 0.0]


# --- the stops at work ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmi_type", ["ModelExchange", "CoSimulation"])
def test_zero_torque_rrpr_slide_rests_on_its_stop(rrpr, fmi_type):
    """Before the stops the slide fell to 7.7 m in 1 s; now it rests where the spring carries its weight."""
    k = float(_variables(rrpr["fmi2"])["stop_stiffness[2]"].start)
    rest = D3_RANGE[1] + PAPER_K["k4"] * PAPER_G / k        # k (d3 - 0.48) = (m3 + m4) g
    assert rest - D3_RANGE[1] == pytest.approx(0.245e-3, rel=1e-9)        # g / w^2
    res = fmpy.simulate_fmu(str(rrpr["fmi2"]), fmi_type=fmi_type, stop_time=1.5, output_interval=0.005,
                            relative_tolerance=1e-9, start_values={"disturbance_paper": False},
                            output=["q[0]", "q[1]", "q[2]", "q[3]", "dq[2]"])
    assert res["q[2]"].max() < D3_RANGE[1] + 0.01           # the impact at 2.2 m/s compresses the stop by mm
    assert res["q[2]"][-1] == pytest.approx(rest, abs=1e-9)
    assert abs(res["dq[2]"][-1]) < 1e-8
    # d3 is decoupled: the other joints stay at the default pose (0, pi/2, ., 0)
    np.testing.assert_allclose([res["q[0]"][-1], res["q[1]"][-1], res["q[3]"][-1]], [0.0, math.pi / 2, 0.0],
                               atol=1e-12)


def test_zero_torque_scope4_rests_in_static_equilibrium_on_its_stops(scope4):
    """At rest every joint's stop force balances gravity (pinocchio's G(q)); joints inside their range feel none."""
    import pinocchio as pin
    arm, fmus = scope4
    v = _variables(fmus["fmi2"])
    n = arm.n
    with FMUInstance(fmus["fmi2"], "CoSimulation") as f:
        states = f.value_references([f"q[{i}]" for i in range(n)] + [f"dq[{i}]" for i in range(n)])
        for k in range(300):                        # 3 s of 10 ms steps
            f.do_step(k * 0.01, 0.01)
        x = f.get_real(states).copy()
    q, dq = x[:n], x[n:]
    assert np.max(np.abs(dq)) < 1e-6
    model = arm.pin_model
    gravity = pin.computeGeneralizedGravity(model, model.createData(), arm.pinocchio_configuration(q))
    stop = np.zeros(n)
    on_stop = []
    for i, (lo, hi) in enumerate(arm.joints.limits):
        k = float(v[f"stop_stiffness[{i}]"].start)
        if q[i] > hi or q[i] < lo:             # at rest the damper is idle: the spring alone
            stop[i] = -k * (q[i] - hi) if q[i] > hi else k * (lo - q[i])
            on_stop.append(i)
    assert on_stop, "gravity should pull some joint of the scope4 onto a stop"
    np.testing.assert_allclose(stop, gravity, atol=1e-6 * max(1.0, np.max(np.abs(gravity))))
    # on its stop each joint gives by G_i / k_i, a fraction of a millimetre or milliradian
    for i in on_stop:
        lo, hi = arm.joints.limits[i]
        assert min(abs(q[i] - lo), abs(q[i] - hi)) < 2e-3
    print(f"scope4 rests with {[arm.joints.names[i] for i in on_stop]} on their stops, q = {np.round(q, 6)}")


def _inside_run(path, n, x0, torque, steps=200, h=2e-3):
    """Co-Simulation states over ``steps`` steps, then Model Exchange derivatives at every 20th of them."""
    start = {f"q[{i}]": x0[i] for i in range(n)} | {f"dq[{i}]": x0[n + i] for i in range(n)}
    with FMUInstance(path, "CoSimulation", start_values=start) as f:
        taus = f.value_references([f"tau[{i}]" for i in range(n)])
        states = f.value_references([f"q[{i}]" for i in range(n)] + [f"dq[{i}]" for i in range(n)])
        out = []
        for k in range(steps):
            f.set_real(taus, torque(k * h))
            f.do_step(k * h, h)
            out.append(f.get_real(states).copy())
    with FMUInstance(path, "ModelExchange") as f:
        taus = f.value_references([f"tau[{i}]" for i in range(n)])
        for x in np.array(out)[::20]:             # Model Exchange derivatives along the run
            f.set_time(0.1)
            f.set_states(x)
            f.set_real(taus, torque(0.1))
            out.append(f.derivatives().copy())
    return np.array(out)


def test_inside_the_ranges_the_stops_change_no_bit(rrpr, scope4):
    # the paper's arm: gravity and the Eq. 4 step on d3 compensated, d3 from 0.05 m stays inside 0 to 0.48 m
    x0 = np.array([0.3, 1.1, 0.05, 0.2, 0.5, -0.4, 0.1, 0.3])
    torque = lambda t: np.array([2.0 * np.sin(3 * t), 1.5 * np.cos(2 * t),          # noqa: E731
                                 -PAPER_K["k4"] * PAPER_G - 1.4 + 0.5 * np.sin(5 * t), 0.3 * np.sin(t)])
    with_stops, without = (_inside_run(rrpr[k], 4, x0, torque) for k in ("fmi2", "free"))
    assert np.all((with_stops[:200, 2] > 0.0) & (with_stops[:200, 2] < 0.48))
    assert np.array_equal(with_stops, without)
    # scope4 from the middle of its ranges under small torques
    arm, fmus = scope4
    n = arm.n
    x0 = np.concatenate((np.zeros(n) + [0.1, -0.1, 0.1, 0.2], [0.2, -0.1, 0.05, 0.3]))
    g0, m0 = arm.gravity_forces(x0[:n]), np.diag(arm.inertia(x0[:n]))
    torque = lambda t: g0 + 0.5 * m0 * np.sin(3 * t + np.arange(n))        # noqa: E731  (about 0.5 rad/s^2)
    with_stops, without = (_inside_run(fmus[k], n, x0, torque) for k in ("fmi2", "free"))
    assert arm.joints.outside_limits(with_stops[:200, :n]) is None
    assert np.max(np.abs(with_stops[:200] - x0)) > 0.01                 # it moved
    assert np.array_equal(with_stops, without)


@pytest.mark.parametrize("margin, stable", [(0.97, True), (1.03, False)])
def test_the_stop_is_stable_for_rk4_sub_steps_up_to_2_785_over_its_frequency(tmp_path, margin, stable):
    """fmu/end_stops.py: classical RK4 meets the negative real axis at |lambda dt| = 2.785, and the stop's double
    eigenvalue is -w (critical damping, w = 200 rad/s), so a sub-step up to 2.785 / w = 13.9 ms is stable.  The
    paper's slide is decoupled with a constant inertia (k4), so the bound is exact for it: released 1 mm into its
    stop at 0.97 x that step it settles where the spring carries its weight; at 1.03 x the contact rings up."""
    plant = export_plant(tmp_path / "one_substep.fmu", substeps=1)
    h = margin * 2.785 / STOP_W
    k = float(_variables(plant)["stop_stiffness[2]"].start)
    rest = D3_RANGE[1] + PAPER_K["k4"] * PAPER_G / k
    res = fmpy.simulate_fmu(str(plant), fmi_type="CoSimulation", stop_time=300 * h, output_interval=h,
                            start_values={"disturbance_paper": False, "q[2]": D3_RANGE[1] + 1e-3},
                            output=["q[2]"])
    late = np.abs(res["q[2]"][-100:] - rest)
    if stable:
        assert late.max() < 1e-9
    else:
        assert late.max() > 1e-4          # rings at the size of the release, not settling


PAPER = RobotParameters()


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_stops_are_set_from_the_smallest_effective_inertia_over_the_poses():
    """es-inertia-min: joint i's effective inertia 1 / (M^-1)_ii is smallest where the stop rings fastest; with
    that pose given as q0 the value taken is the one there (Eq. 5's matrix from conftest), not a larger one."""
    from fmu.end_stops import effective_inertia
    theta2 = np.linspace(-math.pi, math.pi, 20001)
    eff = 1.0 / np.diagonal(np.linalg.inv(reference_inertia(theta2)), axis1=-2, axis2=-1)    # (T, 4)
    worst = theta2[np.argmin(eff[:, 0])]
    q0 = np.array([0.1, worst, 0.2, -0.3])
    got = effective_inertia(PAPER, q0)
    at_q0 = 1.0 / np.diag(np.linalg.inv(reference_inertia(worst)))
    assert got[0] == pytest.approx(at_q0[0], rel=1e-12)
    assert np.all(got <= at_q0 * (1 + 1e-12))
    assert np.all(got >= eff.min(axis=0) * (1 - 1e-6))
    assert got[2] == pytest.approx(0.25)                       # the slide: k4 = m3 + m4 whatever the pose


def test_a_joint_bounded_on_one_side_gets_a_stop_on_that_side():
    """es-bounded-and: a slide with a floor and no ceiling (limits (0, inf)) has a stop at 0 m; its stiffness and
    damping are those of its mass k4 = 0.25 kg at 200 rad/s, critically damped: 0.25 x 200^2 N/m, 2 x 0.25 x 200."""
    from blocks.model.joints import JointSpace
    from fmu.end_stops import end_stops

    class OneSided:
        joints = JointSpace(PAPER.joints.names, PAPER.joints.kinds,
                            ((-math.inf, math.inf), (-math.inf, math.inf), (0.0, math.inf), (-math.inf, math.inf)))
        n = 4
        inertia = staticmethod(PAPER.inertia)

    stops = end_stops(OneSided())
    assert [(s.joint, s.lower, s.upper) for s in stops] == [(2, 0.0, math.inf)]
    assert (stops[0].stiffness, stops[0].damping) == pytest.approx((0.25 * 200.0 ** 2, 2 * 0.25 * 200.0))
