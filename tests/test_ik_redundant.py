"""Task-space paths of redundant arms (UR5, Panda: a 3-D tool point, 5 and 6 joints that move it).

The references come from the integrated resolved-rate law of :mod:`blocks.model.urdf.resolved_rate`.  Checked against
pinocchio's forward kinematics and Jacobian, against central differences of densely sampled references, and
against the damped least-squares references of ``method="dls"`` (the method before), which drift in the null space
and are not one curve: the checks below fail on them.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

import blocks  # noqa: E402
from blocks.model.urdf import IKUnreachableError, example_arm, joint_path  # noqa: E402
from blocks.model.urdf.resolved_rate import moving_joints  # noqa: E402
from blocks.scenarios.scenario import scenario_from_dict  # noqa: E402

# a posture of each arm well away from singularities and joint limits (rad), and its tool frame
ARMS = {"ur5": ([0.3, -1.0, 1.2, -0.5, 1.2, 0.3], "tool0"),
        "panda": ([0.0, 0.0, 0.0, -1.6, 0.0, 1.6, 0.8], "panda_hand")}
RADIUS = 0.05          # m: the circle, about 6 % of either arm's reach (0.85 m)
PERIOD = 1.0           # s per loop
W = 2 * np.pi / PERIOD
TOL = 1e-9             # m: the residual every sample must meet (joint_path's tol)


def _circle(start):
    """A circle through ``start`` in a tilted plane, one loop per PERIOD: p, p', p'' written out by hand."""
    u, v = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.6, 0.8])
    centre = np.asarray(start) - RADIUS * u

    def path(t):
        t = np.asarray(t, dtype=float)[..., None]
        c, s = np.cos(W * t), np.sin(W * t)
        return (centre + RADIUS * (c * u + s * v), RADIUS * W * (-s * u + c * v),
                -RADIUS * W ** 2 * (c * u + s * v))
    return path


@pytest.fixture(scope="module", params=sorted(ARMS))
def case(request):
    arm = example_arm(request.param)
    q0, frame = ARMS[request.param]
    q0 = np.array(q0)
    return request.param, arm, q0, frame, _circle(arm.tool_position(q0))


def _pin_tool(arm, frame, q):
    """Tool-frame position (m) and linear Jacobian in base axes, from pinocchio (the reference)."""
    model = arm.pin_model
    data, fid = model.createData(), model.getFrameId(frame)
    config = arm.pinocchio_configuration(q)
    pin.computeJointJacobians(model, data, config)
    pin.framesForwardKinematics(model, data, config)
    J = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    return data.oMf[fid].translation.copy(), J


def test_redundant_arms_take_the_resolved_rate_law_and_scope4_keeps_least_squares(case):
    name, arm, q0, frame, path = case
    lo, hi = np.array(arm.joints.limits).T
    rng = np.random.default_rng(7)
    for q in rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3), (3, arm.n)):
        # the joints that move the tool point are the non-zero columns of pinocchio's Jacobian
        J = _pin_tool(arm, frame, q)[1]
        np.testing.assert_array_equal(moving_joints(arm, q), np.linalg.norm(J, axis=0) > 1e-9)
    t = np.arange(0.0, 0.2 + 1e-9, 0.05)
    assert joint_path(arm, t, *path(t), q0=q0).method == "resolved_rate"
    scope4 = example_arm("scope4")           # three joints move its tip (its roll does not): square
    point = scope4.tool_position(np.array([0.1, 0.2, 0.12, 0.3]))
    still = np.broadcast_to(point, (2, 3))
    assert joint_path(scope4, [0.0, 0.1], still, np.zeros((2, 3)), np.zeros((2, 3))).method == "dls"


def test_the_tool_point_is_on_the_path_at_every_sample(case):
    """pinocchio's tool frame within TOL of the circle at every sample; J q' = p', J q'' + J' q' = p'' (the
    feedback terms K_p e, K_p^2 e are below 1e-7 m/s, m/s^2 here); joints in range."""
    name, arm, q0, frame, path = case
    t = np.arange(0.0, PERIOD + 1e-9, 0.05)
    p, dp, ddp = path(t)
    ref = joint_path(arm, t, p, dp, ddp, q0=q0)
    for k in range(t.size):
        tip, J = _pin_tool(arm, frame, ref.q[k])
        assert np.linalg.norm(tip - p[k]) < TOL, (name, t[k])
        np.testing.assert_allclose(J @ ref.dq[k], dp[k], rtol=0, atol=1e-7)
    # J' q' from central differences of pinocchio's Jacobian along q'
    for k in (3, 11, 17):
        h = 1e-6
        Jdot = (_pin_tool(arm, frame, ref.q[k] + h * ref.dq[k])[1] - _pin_tool(arm, frame, ref.q[k] - h * ref.dq[k])[1])
        acc = _pin_tool(arm, frame, ref.q[k])[1] @ ref.ddq[k] + Jdot / (2 * h) @ ref.dq[k]
        np.testing.assert_allclose(acc, ddp[k], rtol=0, atol=1e-6)
    assert np.max(ref.residual) < TOL
    assert arm.joints.outside_limits(ref.q) is None


def _central_difference_errors(arm, path, q0, method, h, times=(0.1, 0.2, 0.3)):
    """Signed errors of central differences of q and q' (a dense evaluation at spacing h) against q' and q''."""
    t = np.arange(0.0, 0.4 + 1e-9, h)
    ref = joint_path(arm, t, *path(t), q0=q0, method=method)
    idx = [int(round(s / h)) for s in times]
    dq = np.array([(ref.q[i + 1] - ref.q[i - 1]) / (2 * h) - ref.dq[i] for i in idx])
    ddq = np.array([(ref.dq[i + 1] - ref.dq[i - 1]) / (2 * h) - ref.ddq[i] for i in idx])
    return dq, ddq


def test_rates_are_the_time_derivatives_of_the_positions(case):
    """Central differences of q (and of q') at spacing h differ from q' (q'') by h^2/6 q''' (q''''): halving h
    cuts the error 4x, and the errors at h and h/2 cancel in E(h) - 4 E(h/2) (Richardson) to 0.2 %.  The
    least-squares references are not one curve: their q' error has a part of order h that does not cancel."""
    name, arm, q0, frame, path = case
    coarse, fine = (_central_difference_errors(arm, path, q0, "resolved_rate", h) for h in (0.01, 0.005))
    for e_h, e_h2 in zip(coarse, fine):
        ratio = np.abs(e_h).max() / np.abs(e_h2).max()
        assert 3.9 < ratio < 4.1, (name, ratio)
        assert np.abs(e_h - 4 * e_h2).max() < 2e-3 * np.abs(e_h).max()
    assert np.abs(coarse[0]).max() < 1e-3 and np.abs(coarse[1]).max() < 1e-2     # rad/s, rad/s^2 at h = 0.01 s
    old_h, old_h2 = (_central_difference_errors(arm, path, q0, "dls", h)[0] for h in (0.01, 0.005))
    assert np.abs(old_h - 4 * old_h2).max() > 0.1 * np.abs(old_h).max()


@pytest.mark.slow
def test_null_space_motion_stays_bounded_over_ten_loops(case):
    """Ten loops of the circle: at the loop ends the tool point is at the same place, so the change of q between
    them is null-space motion.  It settles (the posture term); the least-squares references drift by the same
    step every loop."""
    name, arm, q0, frame, path = case
    loops = 10
    t = np.arange(0.0, loops * PERIOD + 1e-9, 0.05)
    ends = np.rint(np.arange(loops + 1) * PERIOD / 0.05).astype(int)
    new = joint_path(arm, t, *path(t), q0=q0)
    old = joint_path(arm, t, *path(t), q0=q0, method="dls")
    drift_new = np.linalg.norm(new.q[ends] - new.q[0], axis=1)
    drift_old = np.linalg.norm(old.q[ends] - old.q[0], axis=1)
    assert np.max(drift_new) < 1.2 * drift_new[2]                       # bounded: no growth after two loops
    assert np.linalg.norm(new.q[ends[-1]] - new.q[ends[-2]]) < 1e-3 * drift_old[1]   # the last loop closes
    assert drift_old[-1] > 8 * drift_old[1]                             # the old: linear growth, loop by loop
    assert np.max(new.residual) < TOL


def _smoothstep_path(waypoints, duration, t):
    """The tool_path kind's path through waypoints (quintic smoothstep per segment), written out independently."""
    w = np.asarray(waypoints)
    segments = len(w) - 1
    T = duration / segments
    k = np.minimum((t // T).astype(int), segments - 1)
    tau = np.clip(t / T - k, 0.0, 1.0)
    s = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
    return w[k] + s[:, None] * (w[k + 1] - w[k])


@pytest.mark.slow
def test_closed_loop_on_the_new_references_tracks_better_and_keeps_its_posture():
    """The UR5 scenario of a user: five rounds of a four-point loop from the default start, the loop (numpy
    engine, with the observer) on the new references and on the least-squares ones.  With the new ones the
    joints track with a smaller error and the arm's posture at the rounds' ends settles; with the old ones it
    drifts further every round (0.05, 0.10, 0.16, 0.26 rad here), and the tool stays on the path with either."""
    arm_keys = {"urdf": "example:ur5", "tool_frame": "tool0", "nominal_mass_scale": 1.05}
    probe = example_arm("ur5")
    c = probe.tool_position(np.array(ARMS["ur5"][0]))
    r = 0.05
    loop = [list(c), list(c + [r, r, 0]), list(c + [0, 2 * r, r / 2]), list(c + [-r, r, 0])]
    rounds, duration = 5, 10.0
    waypoints = loop * rounds + [list(c)]
    scenario = scenario_from_dict({
        "arm": arm_keys, "gains": {"observer_bandwidth": 10.0},
        "trajectory": {"kind": "tool_path", "waypoints": waypoints, "duration": duration, "sample_period": 0.05},
        "disturbance": {"kind": "step", "f_r": [2.0, 3.0, 1.5, 0.3, 0.3, 0.05]},
        "simulation": {"t_final": duration, "output_step": 0.01}})
    arm, new = scenario.robot, scenario.trajectory
    t = new.sample_period * np.arange(new.table.shape[1])
    old_ref = joint_path(arm, t, *new.task_space(t), q0=new.q0, method="dls")
    old = copy.copy(new)              # the same path object with the least-squares sample table
    table = np.ascontiguousarray(np.vstack([old_ref.q.T, old_ref.dq.T, old_ref.ddq.T]))
    table.setflags(write=False)
    record = copy.copy(new._record)
    record.table = table
    object.__setattr__(old, "_record", record)
    runs = {}
    for label, path in (("new", new), ("old", old)):
        s = dataclasses.replace(scenario, trajectory=path, name=f"ur5-loop-{label}")
        res = blocks.simulate(s, observer=True, engine="fast")
        out, labels = np.asarray(res.outputs), list(res.output_labels)
        q = np.array([out[labels.index(f"q[{i}]")] for i in range(arm.n)]).T
        q_ref = np.array([out[labels.index(f"q_ref[{i}]")] for i in range(arm.n)]).T
        tips = np.array([_pin_tool(arm, "tool0", qk)[0] for qk in q])
        off_path = np.linalg.norm(tips - _smoothstep_path(waypoints, duration, res.time), axis=1)
        ends = np.searchsorted(res.time, duration / rounds * np.arange(1, rounds + 1) - 1e-9)
        runs[label] = (np.sqrt(np.mean((q_ref - q) ** 2, axis=0)), off_path.max(),
                       np.linalg.norm(q[ends] - q[ends[0]], axis=1))
    (rms_new, tip_new, drift_new), (rms_old, tip_old, drift_old) = runs["new"], runs["old"]
    assert np.sum(rms_new) < 0.97 * np.sum(rms_old), (rms_new, rms_old)
    assert np.max(drift_new) < 1.2 * drift_new[1] and drift_old[-1] > 4 * drift_old[1], (drift_new, drift_old)
    assert drift_old[-1] > 20 * drift_new[-1]
    assert tip_new < 1e-3 and tip_old < 1e-3 and tip_new <= 1.01 * tip_old       # m


def test_unreachable_point_and_joint_range_are_refused_by_name():
    ur5 = example_arm("ur5")
    q0 = np.array(ARMS["ur5"][0])
    start = ur5.tool_position(q0)
    t = np.linspace(0.0, 1.0, 21)
    out = start / np.linalg.norm(start)             # straight away from the base, 1.5 m: beyond the UR5's reach
    s = 1.5 * t ** 3 * (10 - 15 * t + 6 * t ** 2)
    ds, dds = 1.5 * 30 * t ** 2 * (1 - t) ** 2, 1.5 * 60 * t * (1 - t) * (1 - 2 * t)
    p, dp, ddp = start + s[:, None] * out, ds[:, None] * out, dds[:, None] * out
    with pytest.raises(IKUnreachableError, match=r"task-space point \(.*\) m at t = .* s is not reachable.*misses "
                                                 r"it by"):
        joint_path(ur5, t, p, dp, ddp, q0=q0)
    # a reachable point where J's smallest singular value (about 0.25 m/rad) is below the asked minimum
    with pytest.raises(IKUnreachableError, match=r"at t = 0 s \(point .*\) the arm is at a singularity for the tool "
                                                 r"point \(smallest singular value of J 0.2\d+, below 1\)"):
        joint_path(ur5, t[:3], p[:3], dp[:3], ddp[:3], q0=q0, min_sigma=1.0)
    # the Panda's hand carried 6.5 rad around its base: joints 1 and 3 (+-2.8973 rad each) cannot both turn so far
    with pytest.raises(IKUnreachableError, match=r"at t = .* s needs joint positions outside the arm's ranges: "
                                                 r"panda_joint1 reaches"):
        joint_path(example_arm("panda"), *_arc_around_the_base(6.5), q0=np.array(ARMS["panda"][0]))


def _arc_at(t, angle, duration=2.0):
    """The Panda's hand at its start height and radius, carried ``angle`` rad around the base z axis in
    ``duration`` s at a constant rate: p, p', p'' at times t (s), written out by hand."""
    c = example_arm("panda").tool_position(np.array(ARMS["panda"][0]))
    radius, height, rate = np.hypot(c[0], c[1]), c[2], angle / duration
    a = rate * np.asarray(t, dtype=float)
    return (np.stack([radius * np.cos(a), radius * np.sin(a), np.full_like(a, height)], -1),
            np.stack([-radius * rate * np.sin(a), radius * rate * np.cos(a), 0 * a], -1),
            np.stack([-radius * rate ** 2 * np.cos(a), -radius * rate ** 2 * np.sin(a), 0 * a], -1))


def _arc_around_the_base(angle, duration=2.0, samples=41):
    t = np.linspace(0.0, duration, samples)
    return (t, *_arc_at(t, angle, duration))


def test_the_null_space_term_turns_a_joint_back_from_its_end():
    """5.5 rad around the base: joint 1 alone would leave its range (refused with limit_gain = 0); the push back
    within the last tenth of the range hands the turn to joint 3.  While it acts q'' is still the derivative of q'
    (central differences of a dense evaluation, order h^2) and the hand stays on the arc (pinocchio)."""
    panda = example_arm("panda")
    q0 = np.array(ARMS["panda"][0])
    with pytest.raises(IKUnreachableError, match="panda_joint1 reaches"):
        joint_path(panda, *_arc_around_the_base(5.5), q0=q0, limit_gain=0.0)
    t, p, dp, ddp = _arc_around_the_base(5.5)
    ref = joint_path(panda, t, p, dp, ddp, q0=q0)
    lo, hi = np.array(panda.joints.limits).T
    assert np.all(ref.q >= lo) and np.all(ref.q <= hi)
    inner = hi[0] - 0.1 * (hi[0] - lo[0])
    assert ref.q[:, 0].max() > inner                          # the push acted: joint 1 went into its margin
    for k in range(t.size):
        assert np.linalg.norm(_pin_tool(panda, "panda_hand", ref.q[k])[0] - p[k]) < TOL
    # derivatives where the push acts: a window around the sample deepest in joint 1's margin
    k = int(np.argmax(ref.q[:, 0]))
    errors = []
    for h in (0.004, 0.002):
        tw = t[k] + h * np.arange(-2, 3)
        window = joint_path(panda, tw, *_arc_at(tw, 5.5), q0=ref.q[k], rest=q0)
        assert window.q[2, 0] > inner
        errors.append(np.abs((window.dq[3] - window.dq[1]) / (2 * h) - window.ddq[2]).max())
    assert 3.5 < errors[0] / errors[1] < 4.5, errors


def test_bad_options_name_themselves():
    ur5 = example_arm("ur5")
    t, p = [0.0, 0.1], np.broadcast_to(ur5.tool_position(np.array(ARMS["ur5"][0])), (2, 3))
    z = np.zeros((2, 3))
    with pytest.raises(ValueError, match="method must be one of 'auto', 'dls', 'resolved_rate', got 'newton'"):
        joint_path(ur5, t, p, z, z, method="newton")
    with pytest.raises(ValueError, match=r"posture_gain must be a finite number >= 0 \(1/s\), got -1"):
        joint_path(ur5, t, p, z, z, posture_gain=-1.0)
    with pytest.raises(ValueError, match=r"rtol must be a finite number > 0, got 0"):
        joint_path(ur5, t, p, z, z, rtol=0.0)
    with pytest.raises(ValueError, match="rest must be 6 finite joint positions"):
        joint_path(ur5, t, p, z, z, rest=[0.0, 1.0])
