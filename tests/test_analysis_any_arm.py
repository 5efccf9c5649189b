"""``dobkit analyze`` / ``report`` on URDF arms the README does not name: Kinova (j2s6s200) and Z1.

* The held loop's equilibrium is judged by its distance from a rest in the state's own units (the Newton
  correction), not by a state derivative against a fixed number: at these configurations the root finder
  converged ("The solution converged") and left accelerations of 1e-7 rad/s^2, which the old check refused.  The
  rest found is checked against pinocchio's force balance solved here with SciPy.
* A configuration where the arm without the observer has no rest near its target is left out of the analysis
  with one line saying which and why; the rest of the analysis stands.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import fsolve

pin = pytest.importorskip("pinocchio")

from analysis.linear.loop import equilibrium, hold_scenario  # noqa: E402
from analysis.report.build import ArmAnalysisError, _explicit_observer_gain, operating_points_of  # noqa: E402
from blocks import closed_loop, load_scenario  # noqa: E402

KP, MASS_SCALE = 180.0, 1.05


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


ARMS = {   # URDF, tool frame, locked joints, Eq. 4 step f_r (N m)
    "kinova": ("kinova_description/robots/kinova.urdf", "j2s6s200_end_effector", [],
               [0.5, 0.5, 0.5, 0.2, 0.1, 0.05]),
    "z1": ("z1_description/urdf/z1.urdf", "link06", ["jointGripper"], [2.0, 3.0, 2.0, 0.5, 0.3, 0.1]),
}


def scenario_file(tmp_path, name: str, offset=(0.0,) * 6, amplitude=0.0, t_final=1.0) -> Path:
    urdf, tool, locked, f_r = ARMS[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(f"""name = "{name}"
[arm]
urdf = "{_robot_file(urdf)}"
tool_frame = "{tool}"
locked = {locked!r}
nominal_mass_scale = {MASS_SCALE}
[gains]
kp = {KP}
kd = 36
observer_bandwidth = 10.0
[trajectory]
kind = "joint_sine"
amplitude = {[amplitude] * 6!r}
omega = [0.6, 0.8, 1.0, 1.2, 1.4, 1.6]
offset = {[float(v) for v in offset]!r}
[disturbance]
kind = "step"
f_r = {f_r!r}
[simulation]
t_final = {t_final}
output_step = 0.005
""".replace("'", '"'))
    return path


def _pinocchio_rest(name: str, q0) -> np.ndarray:
    """Where the held arm rests without the observer, from pinocchio's own model (locked joints at 0):
    ``a M(q) Kp (q0 - q) + a G(q) - G(q) + f_r = 0``, the nominal model being the true one scaled by ``a``."""
    urdf, _, locked, f_r = ARMS[name]
    model = pin.buildModelFromUrdf(str(_robot_file(urdf)))
    if locked:
        model = pin.buildReducedModel(model, [model.getJointId(j) for j in locked], pin.neutral(model))
    data = model.createData()

    def config(q):
        out, k = [], 0
        for j in range(1, model.njoints):
            if model.joints[j].nq == 2:          # continuous joint: (cos, sin)
                out += [np.cos(q[k]), np.sin(q[k])]
            else:
                out.append(q[k])
            k += 1
        return np.array(out)

    def balance(q):
        qp = config(q)
        M = pin.crba(model, data, qp)
        M = np.triu(M) + np.triu(M, 1).T
        G = pin.computeGeneralizedGravity(model, data, qp)
        return MASS_SCALE * M @ (KP * (q0 - q)) + (MASS_SCALE - 1.0) * G + np.asarray(f_r)

    q, info, ok, msg = fsolve(balance, np.asarray(q0, float), xtol=1e-13, full_output=True)
    assert ok == 1 and np.max(np.abs(balance(q))) < 1e-9, msg
    return q


#: Configurations where the old check refused the root finder's converged answer (found by a scan).
CONVERGED_BUT_REFUSED = {
    "kinova": [-1.202, 2.783, 0.491, -2.254, 4.035, 0.883],
    "z1": [-0.621, 1.495, -2.832, -0.02, 1.268, -1.198],
}


@pytest.mark.parametrize("name", sorted(CONVERGED_BUT_REFUSED))
def test_the_rest_without_observer_is_found_and_is_pinocchios(name, tmp_path):
    q0 = np.array(CONVERGED_BUT_REFUSED[name])
    s = _explicit_observer_gain(load_scenario(scenario_file(tmp_path, name, offset=q0)))
    loop = closed_loop(hold_scenario(s, q0), observer=False)
    x = equilibrium(loop, 0.0)          # old: "no equilibrium found ... (root finder: The solution converged.)"
    n = len(q0)
    labels = list(loop.state_labels)
    q_eq = x[[labels.index(f"plant_q[{i}]") for i in range(n)]]
    np.testing.assert_allclose(q_eq, _pinocchio_rest(name, q0), atol=1e-8)
    assert np.max(np.abs(x[[labels.index(f"plant_dq[{i}]") for i in range(n)]])) < 1e-10


@pytest.mark.parametrize("name", sorted(CONVERGED_BUT_REFUSED))
def test_the_rest_with_observer_is_the_target(name, tmp_path):
    q0 = np.array(CONVERGED_BUT_REFUSED[name])
    s = _explicit_observer_gain(load_scenario(scenario_file(tmp_path, name, offset=q0)))
    loop = closed_loop(hold_scenario(s, q0), observer=True)
    x = equilibrium(loop, 0.0)
    labels = list(loop.state_labels)
    np.testing.assert_allclose(x[[labels.index(f"plant_q[{i}]") for i in range(len(q0))]], q0, atol=1e-9)


def test_a_configuration_without_a_rest_is_left_out_with_its_reason(tmp_path):
    # Kinova's light wrist under 0.2 N m sags by radians without the observer: no rest near this configuration
    s = _explicit_observer_gain(load_scenario(scenario_file(tmp_path, "kinova", offset=(0.0, 3.0, 1.5, 0.0, 3.0, 0.0))))
    good = np.array([0.0, 3.0, 1.5, 0.0, 3.0, 0.0])
    bad = np.array([0.088656, 3.116826, 1.643828, 0.169393, 3.193265, 0.215207])
    ops, not_done = operating_points_of(s, [("reference at t = 0", good), ("reference at mid-run", bad)])
    assert [op.label for op in ops] == ["reference at t = 0"]
    assert len(not_done) == 1 and "\n" not in not_done[0]
    assert not_done[0].startswith("linearized loop at reference at mid-run: without the observer: no equilibrium")
    # the point kept is complete: with the observer it rests on its target
    assert np.allclose(ops[0].q_equilibrium_with_dob, good, atol=1e-9) and len(ops[0].poles_without_dob) == 12
    # the first point is the one the rest of the analysis stands on: without it, a one-line refusal
    with pytest.raises(ArmAnalysisError, match=r"^linearized loop at first: without the observer: no equilibrium"):
        operating_points_of(s, [("first", bad), ("second", good)])


def test_why_kinovas_base_joint_learns_slowly_with_observer_bandwidth(tmp_path):
    """``observer_bandwidth = 10`` is 10 per second at q0 only: along the path Kinova's base-joint inertia grows
    and the slowest rate of ``Y M^-1(q)`` falls below 1 per second; the summary says so, with pinocchio's number."""
    from types import SimpleNamespace

    from analysis.linear.bandwidth import along_trajectory
    from analysis.report.view.summary import _rate_along_path

    s = load_scenario(scenario_file(tmp_path, "kinova", offset=(0.0, 3.0, 1.5, 0.0, 3.0, 0.0), amplitude=0.3))
    at = along_trajectory(s)
    model = pin.buildModelFromUrdf(str(_robot_file(ARMS["kinova"][0])))
    data = model.createData()

    def inertia(q):
        out, k = [], 0
        for j in range(1, model.njoints):
            out += [np.cos(q[k]), np.sin(q[k])] if model.joints[j].nq == 2 else [q[k]]
            k += 1
        m = pin.crba(model, data, np.array(out))
        return np.triu(m) + np.triu(m, 1).T

    t = np.asarray(at.time)
    q = np.asarray(s.trajectory.evaluate(t)[0])                 # (samples, joints)
    Y = 10.0 * MASS_SCALE * inertia(q[0])                      # observer_bandwidth x M^(q0)
    slow = [np.linalg.eigvals(Y @ np.linalg.inv(MASS_SCALE * inertia(qk))).real.min() for qk in q]
    assert at.min == pytest.approx(min(slow), rel=1e-8) and at.min < 1.0
    assert abs(at.direction_at_min[0]) > 0.9                  # the base joint
    line = _rate_along_path(SimpleNamespace(observer_bandwidth=SimpleNamespace(along_trajectory=at)), s)
    assert line is not None and f"falls to {at.min:.3g} per second" in line
    assert "a disturbance on joint 1 alone" in line or "a disturbance on joints 1," in line
    assert f"up to {4.0 / at.min:.2g} s" in line
