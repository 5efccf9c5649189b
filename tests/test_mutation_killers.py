"""Tests that kill the wrong changes the rest of the suite let through (``tests/mutation_probe.py``).

Each test names the mutant(s) it kills and checks the product against a derivation of its own: the paper
notes' numbers, the geometry of the arm written out here (``tests/reference_arm.py``, ``conftest``),
finite differences, scipy's own step counts, pinocchio.  None compares the code with itself.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import D1, D4, L1, L2, reference_fk, reference_inertia

import blocks
from blocks.budget import Budget, BudgetError, Estimate
from blocks.divergence import RUNAWAY_FACTOR, RUNAWAY_STEPS, Runaway, StateBounds
from blocks.monitor import Monitor
from blocks.parameters import RobotParameters

PAPER = RobotParameters()
Q = np.array([0.4, 1.1, 0.2, 0.3])            # a pose away from every singularity (rad, rad, m, rad)


# --------------------------------------------------------------------------------------------------------------
# Kinematics (Eq. 8 corrected)
# --------------------------------------------------------------------------------------------------------------
def test_tool_velocity_is_the_time_derivative_of_the_pose():
    """kin-vel-row3: ``tool_velocity`` (exported kernel) is d/dt of Eq. 8 along q', by central differences."""
    from blocks.kernels import kinematic_lengths, tool_velocity
    dq = np.array([0.7, -1.3, 0.05, 2.1])
    h = 1e-6
    want = (reference_fk(Q + h * dq) - reference_fk(Q - h * dq)) / (2 * h)
    got = tool_velocity(kinematic_lengths(PAPER), Q, dq)
    np.testing.assert_allclose(got, want, atol=1e-8)
    assert got[3] == pytest.approx(dq[0] + dq[1] - dq[3])          # the corrected last row [1, 1, 0, -1]


def test_the_inner_reach_is_the_links_difference_whichever_is_longer():
    """kinpy-reach-abs: with a2 > a1 the annulus is |a1 - a2| to a1 + a2 (law of cosines at theta2 = pi, 0)."""
    from blocks.kinematics import UnreachableError, inverse_kinematics, planar_reach
    arm = RobotParameters(a1=0.2, a2=0.5)
    inner, outer = planar_reach(arm)
    assert (inner, outer) == pytest.approx((0.3, 0.7))
    # theta2 = pi folds the arm: the tool is then |a1 - a2| from the axis
    assert math.hypot(*reference_fk([0.0, math.pi, 0.0, 0.0], a1=0.2, a2=0.5)[:2]) == pytest.approx(inner)
    q = inverse_kinematics([0.35, 0.0, 0.0, 0.0], arm)
    np.testing.assert_allclose(reference_fk(q, a1=0.2, a2=0.5)[:2], [0.35, 0.0], atol=1e-12)
    with pytest.raises(UnreachableError, match="radii 0.3 m to 0.7 m"):
        inverse_kinematics([0.25, 0.0, 0.0, 0.0], arm)


def test_ik_with_no_singularity_margin_accepts_the_folded_and_the_stretched_arm():
    """kinpy-ik-margin-le: ``min_sin_theta2 = 0`` accepts the workspace boundary itself: r = |a1 - a2| (theta2 = pi)
    and r = a1 + a2 (theta2 = 0; one ulp beyond 0.7 m, where cos(theta2) rounds to 1 and sin(theta2) to 0)."""
    from blocks.kinematics import inverse_kinematics
    for r, theta2 in ((L1 - L2, math.pi), (np.nextafter(L1 + L2, 1.0), 0.0)):
        pose = np.array([r, 0.0, D1 - 0.1 - D4, 0.2])
        q = inverse_kinematics(pose, PAPER)
        assert q[1] == pytest.approx(theta2, abs=1e-12)
        np.testing.assert_allclose(reference_fk(q), pose, atol=1e-12)


# --------------------------------------------------------------------------------------------------------------
# The divergence rule and the monitor
# --------------------------------------------------------------------------------------------------------------
def test_a_bound_holds_the_magnitude_inclusive_on_both_sides():
    """div-violated-lt, div-violated-abs: divergence is a magnitude *beyond* the bound; at the bound, or at minus
    it, the run goes on; a hair beyond either side, or a value far below minus the bound, has diverged."""
    b = StateBounds(np.array([2.0, 5.0]), ["a", "b"], ["m", "m/s"], ["given", "given"])
    assert b.violated([2.0, -5.0]).tolist() == [False, False]
    assert b.violated([np.nextafter(2.0, 3.0), -np.nextafter(5.0, 6.0)]).tolist() == [True, True]
    assert b.violated([-1e9, 0.0]).tolist() == [True, False]
    monitor = Monitor("run", b, np.zeros(2))
    with pytest.raises(blocks.SimulationError, match="b reached -7 m/s, beyond its bound 5 m/s"):
        monitor.check(0.5, [0.0, -7.0])


def test_runaway_is_growth_beyond_the_factor_in_consecutive_steps():
    """div-runaway-factor, div-runaway-reset: a signal runs away when it grows more than RUNAWAY_FACTOR-fold in
    each of RUNAWAY_STEPS consecutive steps; slower growth, or growth interrupted by one step, does not count."""
    assert (RUNAWAY_FACTOR, RUNAWAY_STEPS) == (10.0, 3)
    fast = Runaway(1)
    values = [1.0, 11.0, 121.0, 1331.0]
    verdicts = [fast.update([a], [b]) for a, b in zip(values, values[1:])]
    assert verdicts == [None, None, 0]
    slow = Runaway(1)                                           # 9-fold each step: an unstable but slow mode
    y = 1.0
    for _ in range(6):
        assert slow.update([y], [9.0 * y]) is None
        y *= 9.0
    broken = Runaway(1)                                         # two fast steps, a pause, two fast steps
    values = [1.0, 11.0, 121.0, 100.0, 1100.0, 12100.0]
    assert [broken.update([a], [b]) for a, b in zip(values, values[1:])] == [None] * 5


@pytest.mark.parametrize("method", ["RK45", "RK23", "DOP853"])
def test_the_step_budget_allows_the_evaluations_scipy_makes_in_that_many_steps(method):
    """mon-evals-factor, mon-counted-ge: a budget of N steps allows the right-hand-side evaluations of N steps.

    scipy's explicit pairs reuse their last stage (FSAL): a step of Dormand-Prince 5(4) costs 6 new evaluations,
    Bogacki-Shampine 3(2) 3, DOP853 12.  The count per step here is scipy's own, from a fixed-step run (a step
    cap and a loose tolerance: no rejected steps) that makes one evaluation at the start and the rest in steps.
    """
    from scipy.integrate import solve_ivp
    rhs = lambda t, x: np.array([x[1], -x[0]])                  # noqa: E731 -- the harmonic oscillator
    run = solve_ivp(rhs, (0.0, 5.0), [1.0, 0.0], method=method, first_step=0.05, max_step=0.05, rtol=1e-3,
                    atol=1e6)
    steps = len(run.t) - 1
    per_step = (run.nfev - 1) / steps
    assert per_step == int(per_step)
    monitor = Monitor("probe", None, np.zeros(2), Budget(steps=steps), method=method)
    assert monitor.max_evaluations == int(per_step) * steps
    counted = monitor.counted(rhs)
    for _ in range(int(per_step) * steps):                     # every allowed evaluation is allowed ...
        counted(1.0, np.zeros(2))
    with pytest.raises(BudgetError, match="step budget"):        # ... and not one more
        counted(1.0, np.zeros(2))


# --------------------------------------------------------------------------------------------------------------
# Budgets
# --------------------------------------------------------------------------------------------------------------
def test_an_estimate_of_exactly_the_budget_fits_and_one_more_does_not():
    """bu-check-ge: the budget is what a job may use, inclusive."""
    budget = Budget(memory=1000, steps=500)
    budget.check(Estimate(memory=1000, steps=500), "job")
    with pytest.raises(BudgetError) as err:
        budget.check(Estimate(memory=1000, steps=501), "job")
    assert err.value.limit == "steps"
    with pytest.raises(BudgetError) as err:
        budget.check(Estimate(memory=1001, steps=500), "job")
    assert err.value.limit == "memory"


def test_the_step_estimate_bounds_the_steps_the_schedule_takes():
    """bu-schedule-breaks: a noise sample between grid points splits a step, one step more; the estimate holds
    the schedule's own count (its step end points, counted here) with one or three sub-steps per grid interval."""
    from blocks.batch import step_schedule
    from blocks.budget import schedule_steps
    breaks = list(np.arange(1, 40) * 0.0025 + 0.0011)          # 39 samples, none on the 0.01 s grid
    for substeps in (1, 3):
        times, _ = step_schedule(0.5, 0.01, substeps, breaks)
        taken = len(times) - 1
        assert taken == 50 * substeps + len(breaks)              # each sample splits the step it falls in
        assert schedule_steps(0.5, 0.01, substeps, breakpoints=len(breaks)) >= taken


def test_jobs_sharing_a_budget_each_get_their_part_of_the_memory():
    """bu-share: four jobs at once share 4 GiB as 1 GiB each; the steps are per run and stay."""
    shared = Budget(memory="4G", steps=1000).share(4)
    assert (shared.memory, shared.steps) == (2 ** 30, 1000)


# --------------------------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------------------------
def test_the_disturbance_error_is_against_the_lumped_disturbance_when_the_run_has_it():
    """me-d-source (killed before only because the hand-made signals had no tau_dis to read): with model mismatch
    the observer estimates the lumped d (Eq. 2-3), not tau_dis alone; the RMS of d - d_hat over five hand-made
    points is that of the constant errors chosen here."""
    import control as ct

    from blocks.metrics import tracking_metrics
    n = 5
    q = np.tile(Q[:, None], (1, n))
    d_error = np.array([1.0, 2.0, 0.5, 3.0])[:, None] * np.array([1.0, -1.0, 1.0, -1.0, 1.0])   # |.| constant
    rows = {"q_ref": q, "q": q, "d": 4.0 + d_error, "d_hat": np.full((4, n), 4.0),
            "tau_dis": np.full((4, n), 1.5)}                   # the mismatch makes d differ from tau_dis
    labels = [f"{name}[{i}]" for name in rows for i in range(4)]
    resp = ct.TimeResponseData(np.linspace(0.0, 0.4, n), np.vstack(list(rows.values())), output_labels=labels,
                               issiso=False)
    got = tracking_metrics(resp)["rms_disturbance_error"]
    np.testing.assert_allclose(got, [1.0, 2.0, 0.5, 3.0], rtol=1e-14)


# --------------------------------------------------------------------------------------------------------------
# End stops
# --------------------------------------------------------------------------------------------------------------
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
    from blocks.joints import JointSpace
    from fmu.end_stops import end_stops

    class OneSided:
        joints = JointSpace(PAPER.joints.names, PAPER.joints.kinds,
                            ((-math.inf, math.inf), (-math.inf, math.inf), (0.0, math.inf), (-math.inf, math.inf)))
        n = 4
        inertia = staticmethod(PAPER.inertia)

    stops = end_stops(OneSided())
    assert [(s.joint, s.lower, s.upper) for s in stops] == [(2, 0.0, math.inf)]
    assert (stops[0].stiffness, stops[0].damping) == pytest.approx((0.25 * 200.0 ** 2, 2 * 0.25 * 200.0))


# --------------------------------------------------------------------------------------------------------------
# IK derivatives of a URDF arm
# --------------------------------------------------------------------------------------------------------------
def test_the_ik_singularity_margin_is_on_the_smallest_singular_value():
    """ik-sigma-largest: a margin between the Jacobian's smallest and largest singular values (numpy's SVD) along
    the path is a singularity the path's velocity cannot pass; a margin below the smallest passes."""
    pytest.importorskip("pinocchio")
    from blocks.arms import IKUnreachableError, example_arm, joint_path
    arm = example_arm("scope4")
    t = np.linspace(0.0, 0.5, 6)
    p = np.stack([-0.08 + 0.03 * np.sin(t), 0.04 * np.sin(2 * t), -0.12 + 0.01 * np.cos(t)], -1)
    dp = np.stack([0.03 * np.cos(t), 0.08 * np.cos(2 * t), -0.01 * np.sin(t)], -1)
    ddp = np.stack([-0.03 * np.sin(t), -0.16 * np.sin(2 * t), -0.01 * np.cos(t)], -1)
    path = joint_path(arm, t, p, dp, ddp)
    sigmas = np.array([np.linalg.svd(arm.tool_jacobian(q), compute_uv=False) for q in path.q])
    smallest, largest = sigmas.min(axis=1), sigmas.max(axis=1)
    assert smallest.max() < largest.min()
    joint_path(arm, t, p, dp, ddp, min_sigma=0.5 * smallest.min())
    with pytest.raises(IKUnreachableError, match="singularity"):
        joint_path(arm, t, p, dp, ddp, min_sigma=0.5 * (smallest.max() + largest.min()))


# --------------------------------------------------------------------------------------------------------------
# The sampled loop's stability: the printed Eq. 16 variant and the returned limit
# --------------------------------------------------------------------------------------------------------------
def _euler_map(M, kp, kd, Y, Ts, eq16_weight):
    """One sample of the held loop, forward Euler, measured velocity, no delay, built column by column from the
    [controller] definitions: tau = -M (Kp q + Kd v) - (Y v + z); the plant under held tau exactly (a double
    integrator); z+ = z + Ts (-Y M^-1 (tau + Y v + z) - w16 Y v)."""
    n = M.shape[0]
    Minv = np.linalg.inv(M)

    def tick(x):
        q, v, z = x[:n], x[n:2 * n], x[2 * n:]
        tau = -M @ (kp * q + kd * v) - (Y @ v + z)
        a = Minv @ tau
        z_next = z + Ts * (-Y @ Minv @ (tau + Y @ v + z) - eq16_weight * (Y @ v))
        return np.concatenate([q + Ts * v + 0.5 * Ts ** 2 * a, v + Ts * a, z_next])
    return np.column_stack([tick(e) for e in np.eye(3 * n)])


def _radius(*args) -> float:
    return float(np.abs(np.linalg.eigvals(_euler_map(*args))).max())


@pytest.mark.parametrize("variant, weight", [("correct", 0.0), ("paper-eq16", 1.0)])
def test_the_sampled_map_of_each_observer_variant_and_its_stable_limit(variant, weight):
    """ds-variant-swap, ds-eq16-sign, ds-return-hi: the spectral radius of each variant equals that of the map
    built here; the largest stable scale is stable (radius at most 1, to rounding: for the correct law the limit
    is exactly 2 / (Ts lambda_max), where the error mode sits at -1) and a hair above it is not."""
    from blocks.digital import DigitalController
    from blocks.digital_stability import sampled_stability
    Ts = 0.01
    M = reference_inertia(Q[1])
    Y = np.diag([40.0, 30.0, 15.0, 20.0])
    s = sampled_stability(PAPER, [Q], 180.0 * np.eye(4), 36.0 * np.eye(4), Y,
                          DigitalController(sample_rate=1.0 / Ts), variant=variant)
    assert s.spectral_radius == pytest.approx(_radius(M, 180.0, 36.0, Y, Ts, weight), rel=1e-9)
    c = s.largest_stable_scale
    assert 0.0 < c < math.inf
    assert _radius(M, 180.0, 36.0, c * Y, Ts, weight) < 1.0 + 1e-12
    assert _radius(M, 180.0, 36.0, c * (1 + 1e-5) * Y, Ts, weight) >= 1.0


# --------------------------------------------------------------------------------------------------------------
# The divergence rule's bounds, by hand from the rule
# --------------------------------------------------------------------------------------------------------------
def test_the_bounds_of_a_held_arm_are_the_rules_numbers_by_hand():
    """div-pos-abs, div-force-no-external: holding q_ref = (-0.5, -1, 0.2, -0.3) under f_r = (0, 0, 300, 0) N:

    * positions: |q_ref| + 100 rad (revolute) or + 10 m (the slide) -- a negative reference counts by magnitude;
    * velocities: 0 + 1000 rad/s or 100 m/s;
    * d_hat on the slide: 1000 x (|300| external + |G3| + |M q'' + h|_3 at rest (= |G3|) + 1), G3 = k4 g = 2.45 N,
      one bound for every joint's estimate, the largest; z[i] adds Y_ii times joint i's velocity bound.
    """
    from conftest import hold_trajectory, make_scenario

    from blocks.divergence import state_bounds
    from blocks.loop import closed_loop
    offset = (-0.5, -1.0, 0.2, -0.3)
    s = make_scenario(trajectory=hold_trajectory(offset), disturbance={"kind": "paper", "f_r": [0.0, 0.0, 300.0, 0.0]},
                      simulation={"t_final": 0.1})
    b = state_bounds(closed_loop(s), s)
    bound = dict(zip(b.names, b.bounds))
    for i, margin in enumerate((100.0, 100.0, 10.0, 100.0)):
        assert bound[f"plant q[{i}]"] == pytest.approx(abs(offset[i]) + margin, rel=1e-12)
        assert bound[f"plant dq[{i}]"] == pytest.approx(1000.0 if i != 2 else 100.0, rel=1e-12)
    g3 = 0.25 * 9.8
    force = 1000.0 * (300.0 + 2 * g3 + 1.0)                     # the largest start force: the slide's
    assert bound["observer z[2] (= d_hat - Y dq)"] == pytest.approx(force + 10.0 * 100.0, rel=1e-9)
    assert bound["observer z[0] (= d_hat - Y dq)"] == pytest.approx(force + 10.0 * 1000.0, rel=1e-9)


# --------------------------------------------------------------------------------------------------------------
# Step-size rules
# --------------------------------------------------------------------------------------------------------------
def test_the_step_rate_takes_the_largest_mismatch_of_a_nominal_model_given_in_python():
    """rl-mismatch-min: a nominal scope4 whose first link (yaw, turning with joint 1 only) is three times heavier:
    M^ - M is positive semidefinite of rank one, so lambda(M^-1 M^) are 1 (three times) and one value in (1, 3]
    (M <= M^ <= 3 M).  The step rate is the fast PD pole times the largest, so strictly above 30 1/s, at most 90."""
    pytest.importorskip("pinocchio")
    import copy
    import dataclasses

    from blocks.run_limits import arm_rates
    from blocks.scenario import scenario_from_dict
    s = blocks.load_scenario("scope4")
    arm, chain = s.robot, s.robot.chain
    heavy = dataclasses.replace(chain, masses=(3.0 * chain.masses[0],) + tuple(chain.masses[1:]),
                                com_inertias=(tuple(tuple(3.0 * x for x in row) for row in chain.com_inertias[0]),)
                                + tuple(chain.com_inertias[1:]))
    nominal = type(arm)(heavy, arm.joints, arm.tool_frame, continuous=arm.continuous, source=arm.source)
    data = copy.deepcopy(dict(s.data))
    data.pop("arm")
    given = scenario_from_dict(data, arm=arm, nominal=nominal)
    q = np.asarray(given.trajectory.evaluate(0.0)[0], dtype=float)
    ratios = np.sort(np.linalg.eigvals(np.linalg.solve(arm.inertia(q), nominal.inertia(q))).real)
    np.testing.assert_allclose(ratios[:3], 1.0, atol=1e-9)
    assert 1.0 < ratios[3] <= 3.0
    rate = float(arm_rates(given, observer=False)["gains.kp"][0])
    assert 30.0 * ratios[3] * (1 - 1e-9) <= rate <= 90.0


def test_the_step_estimate_of_a_stiff_loop_is_scipys_step_count_on_its_fastest_mode():
    """rl-span-times: with Y = 1e5 the observer's fastest mode is Y / k4 = 4e5 1/s (the slide, exact); scipy's
    RK45 on x' = -4e5 x at the scenario's tolerances takes the steps its stability allows, about T lambda / 3.3.
    The estimate is that count to within a factor 2 (a run over budget must be refused, a run within it not)."""
    from scipy.integrate import solve_ivp

    from blocks.run_limits import estimate_run
    s = blocks.load_scenario("paper").with_changes({"gains.observer": 1e5, "simulation.t_final": 0.05})
    lam = 1e5 / 0.25
    run = solve_ivp(lambda t, x: -lam * x, (0.0, 0.05), [1.0], method="RK45", rtol=s.simulation.rtol,
                    atol=s.simulation.atol)
    taken = len(run.t) - 1
    assert 0.5 <= estimate_run(s).steps / taken <= 2.0


def test_the_observer_rate_bounds_the_slides_fastest_mode_when_the_true_arm_is_lighter():
    """sched-obs-nominal-only: the nominal slide twice as heavy as the true one (m^ = 0.5 kg, m = 0.25 kg), Y = 1e5.

    The slide is decoupled in M (Eq. 5), so its held loop is three states written here by hand, deviations from
    rest: m v' = m^ (-Kp q - Kd v) - (Y v + z) and z' = -(Y / m^) (tau + d_hat) = Y (Kp q + Kd v).  Its fastest
    mode is about Y / m = 4e5 1/s, the true mass's, twice the nominal's: the rate estimate must reach it."""
    from blocks.batch.schedule import rates_by_source
    from blocks.batch.variants import Variants
    s = blocks.load_scenario("paper").with_changes({"gains.observer": 1e5, "nominal_scale.m3": 2.0,
                                                     "nominal_scale.m4": 2.0})
    m, m_hat, Y, kp, kd = 0.25, 0.5, 1e5, 180.0, 36.0
    A = np.array([[0.0, 1.0, 0.0],
                  [-m_hat * kp / m, -(m_hat * kd + Y) / m, -1.0 / m],
                  [Y * kp, Y * kd, 0.0]])
    fastest = np.abs(np.linalg.eigvals(A)).max()
    assert fastest == pytest.approx(Y / m, rel=1e-3)
    rate = float(rates_by_source(Variants(s, [{}]))["gains.observer"][0])
    assert rate >= fastest * (1 - 1e-3)


