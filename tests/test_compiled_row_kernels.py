"""A URDF arm's M and h before a run, compiled (blocks.engines.compiled.row_kernels): the step estimate and the force bounds.

The compiled row kernels must give the numpy kernels' numbers (to 1e-12), the step estimate's rates and the
divergence bounds must be those of the numpy kernels, and all of them must agree with pinocchio (``pin.crba``,
``pin.rnea``) at the states they sample: the inertia along the reference, gravity and inverse dynamics at its start.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")
numba = pytest.importorskip("numba")

from blocks import load_scenario  # noqa: E402
from blocks.engines.compiled import row_kernels as compiled_row_kernels  # noqa: E402
from blocks.engines.compiled.row_kernels import CompiledRowKernels, row_kernels  # noqa: E402
from blocks.figure2.loop import closed_loop  # noqa: E402
from blocks.figure2.physical_bounds import FORCE_FACTOR, evaluation_kernels, force_bounds, reference_limits, state_bounds  # noqa: E402
from blocks.figure2.run_limits import arm_rates, forget_inertias  # noqa: E402
from blocks.kernels import disturbance_params  # noqa: E402

ARMS = ("scope4", "panda")


@pytest.fixture(scope="module", params=ARMS)
def scenario(request):
    return load_scenario(request.param)


def _scaled_pin(model, scale: float):
    """pinocchio's model with every body's mass and rotational inertia times ``scale`` (the nominal arm)."""
    nominal = model.copy()
    for i in range(1, nominal.njoints):
        body = nominal.inertias[i]
        nominal.inertias[i] = pin.Inertia(body.mass * scale, body.lever.copy(), body.inertia * scale)
    return nominal


def _pin_inertia(model, arm, q) -> np.ndarray:
    M = pin.crba(model, model.createData(), arm.pinocchio_configuration(q))
    return np.triu(M) + np.triu(M, 1).T          # pinocchio fills the upper triangle


def _numpy_way(monkeypatch, fn, *args):
    """``fn(*args)`` as a process without numba loaded computes it (the numpy row kernels)."""
    forget_inertias()                  # what the compiled kernels gave is not kept for the numpy way to find
    with monkeypatch.context() as m:
        m.delitem(sys.modules, "numba")
        try:
            return fn(*args)
        finally:
            forget_inertias()


def test_compiled_kernels_equal_numpy_kernels(scenario):
    arm = scenario.robot
    k, n = arm.kernel_params(), arm.n
    fast = row_kernels(arm, compiled=True)
    assert isinstance(fast, CompiledRowKernels)
    rng = np.random.default_rng(7)
    Q, V = rng.uniform(-1.5, 1.5, (n, 11)), rng.uniform(-2.0, 2.0, (n, 11))
    for name, args in [("inertia_matrix", (Q,)), ("mass_times", (Q, V)), ("bias_forces", (Q, V)),
                       ("gravity_forces", (Q,)), ("inertia_matrix", (Q[:, 3],)), ("bias_forces", (Q[:, 3], V))]:
        got, want = getattr(fast, name)(k, *args), getattr(arm.kernels, name)(k, *args)
        assert got.shape == want.shape, name
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max(), err_msg=name)


def test_compiled_kernels_agree_with_pinocchio(scenario):
    arm = scenario.robot
    k, n, model = arm.kernel_params(), arm.n, arm.pin_model
    data = model.createData()
    fast = row_kernels(arm, compiled=True)
    rng = np.random.default_rng(3)
    Q, V, A = (rng.uniform(-1.0, 1.0, (n, 5)) for _ in range(3))
    M = fast.inertia_matrix(k, Q)
    h = fast.bias_forces(k, Q, V)
    G = fast.gravity_forces(k, Q)
    tau = fast.mass_times(k, Q, A) + h
    for c in range(5):
        qp = arm.pinocchio_configuration(Q[:, c])
        scale = np.abs(_pin_inertia(model, arm, Q[:, c])).max()
        np.testing.assert_allclose(M[c], _pin_inertia(model, arm, Q[:, c]), atol=1e-10 * scale)
        np.testing.assert_allclose(h[:, c], pin.rnea(model, data, qp, V[:, c], np.zeros(n)), atol=1e-10)
        np.testing.assert_allclose(G[:, c], pin.computeGeneralizedGravity(model, data, qp), atol=1e-10)
        np.testing.assert_allclose(tau[:, c], pin.rnea(model, data, qp, V[:, c], A[:, c]), atol=1e-10)


def test_rates_equal_the_numpy_way_and_pinocchio(scenario, monkeypatch):
    s = scenario
    monkeypatch.setattr(compiled_row_kernels, "COMPILE_AFTER", 0)                     # compiled from the first request
    assert isinstance(evaluation_kernels(s.robot), CompiledRowKernels)     # numba is loaded in this process
    forget_inertias()
    new = arm_rates(s)
    old = _numpy_way(monkeypatch, arm_rates, s)
    assert new.keys() == old.keys()
    for key in new:
        np.testing.assert_allclose(new[key], old[key], rtol=1e-12, err_msg=key)
    # the rules of arm_rates with pinocchio's inertia at the same nine states along the reference
    q = np.asarray(s.trajectory.evaluate(np.linspace(0.0, s.simulation.t_final, 9))[0])
    true_model = s.robot.pin_model
    nominal_model = _scaled_pin(true_model, float(s.data["arm"]["nominal_mass_scale"]))
    M = np.array([_pin_inertia(true_model, s.robot, qi) for qi in q])
    M_hat = np.array([_pin_inertia(nominal_model, s.robot, qi) for qi in q])
    mismatch = max(np.abs(np.linalg.eigvals(np.linalg.solve(Mi, Mh))).max() for Mi, Mh in zip(M, M_hat))
    kp, kd = np.diag(s.kp), np.diag(s.kd)
    disc = kd ** 2 - 4 * kp
    pd = np.where(disc >= 0, 0.5 * (kd + np.sqrt(np.abs(disc))), np.sqrt(kp)).max()
    np.testing.assert_allclose(new["gains.kp"], [pd * max(mismatch, 1.0)], rtol=1e-9)
    observer = max(np.abs(np.linalg.eigvals(s.observer_gain @ np.linalg.inv(Mi))).max()
                   for Mi in np.concatenate([M, M_hat]))
    key = next(k for k in new if k.startswith("gains.observer"))
    np.testing.assert_allclose(new[key], [observer], rtol=1e-9)


def test_force_bound_equals_the_numpy_way_and_pinocchio(scenario, monkeypatch):
    s = scenario
    arm = s.robot
    ref = reference_limits(s)
    spec = disturbance_params(s.disturbance, arm)
    k = arm.kernel_params()
    new = force_bounds(k, spec, ref, arm.kernels, arm.tool_kernels, terms=row_kernels(arm, compiled=True))
    old = force_bounds(k, spec, ref, arm.kernels, arm.tool_kernels)
    assert new == pytest.approx(float(old), rel=1e-12)
    # FORCE_FACTOR (largest of |f_r| + |G| + |M q''_ref + h| at the reference's start, + 1), with pinocchio
    model = arm.pin_model
    data = model.createData()
    qp = arm.pinocchio_configuration(ref.q0)
    forces = (np.abs(s.data["disturbance"]["f_r"]) + np.abs(pin.computeGeneralizedGravity(model, data, qp))
              + np.abs(pin.rnea(model, data, qp, ref.dq0, ref.ddq0)))
    assert new == pytest.approx(FORCE_FACTOR * (forces.max() + 1.0), rel=1e-10)
    # the loop's state bounds: the same array either way
    monkeypatch.setattr(compiled_row_kernels, "COMPILE_AFTER", 0)
    loop = closed_loop(s)
    bounds_new = state_bounds(loop, s)
    bounds_old = _numpy_way(monkeypatch, state_bounds, loop, s)
    np.testing.assert_allclose(bounds_new.bounds, bounds_old.bounds, rtol=1e-12)
    assert np.isfinite(bounds_new.bounds).any()


def test_compiled_only_after_repeated_requests(monkeypatch):
    """A one-off run keeps the numpy kernels (compiling would cost more than it saves); a process that asks for
    the same arm's kernels again and again gets the compiled ones."""
    arm = load_scenario("ur5").robot
    monkeypatch.setattr(compiled_row_kernels, "COMPILE_AFTER", 3)
    monkeypatch.setattr(compiled_row_kernels, "_asked", {})            # as in a new process
    monkeypatch.setattr(compiled_row_kernels, "_made", {})
    got = [evaluation_kernels(arm) for _ in range(5)]
    assert [g is arm.kernels for g in got] == [True, True, True, False, False]
    assert isinstance(got[-1], CompiledRowKernels) and got[-1] is got[-2]


def test_the_paper_arm_keeps_its_closed_form():
    s = load_scenario("paper")
    assert row_kernels(s.robot, compiled=True) is s.robot.kernels
    assert evaluation_kernels(s.robot) is s.robot.kernels


def test_numpy_kernels_without_numba_loaded_and_for_other_parameters(monkeypatch):
    arm = load_scenario("scope4").robot
    with monkeypatch.context() as m:
        m.delitem(sys.modules, "numba")
        assert evaluation_kernels(arm) is arm.kernels
    assert row_kernels(arm, compiled=False) is arm.kernels
    fast = row_kernels(arm, compiled=True)
    other = load_scenario("ur5").robot.kernel_params()           # not this arm's parameters: the numpy kernel runs
    q = np.full(other.n, 0.3)
    np.testing.assert_array_equal(fast.gravity_forces(other, q), arm.kernels.gravity_forces(other, q))


def test_rows_of_the_wrong_length_are_refused_by_name():
    arm = load_scenario("scope4").robot
    fast = row_kernels(arm, compiled=True)
    with pytest.raises(ValueError, match=r"bias_forces: rows of shape \[\(3,\), \(4,\)\]; each must have 4 joint"):
        fast.bias_forces(arm.kernel_params(), np.zeros(3), np.zeros(4))


def test_kept_inertias_serve_new_gains_and_never_another_path_window_or_arm():
    """A new scenario of the same arm and path (gains, noise, disturbance) takes the inverse inertias kept from the
    last; another path, window or nominal arm computes its own, and each equals the rates computed with nothing kept."""
    from blocks.figure2.run_limits import _inverses
    base = load_scenario("scope4")
    forget_inertias()
    arm_rates(base)
    assert len(_inverses) == 1
    assert (base.data["gains"]["kp"], base.data["gains"]["kd"]) == (180, 36)
    changed = {"gains.kp": 360.0}
    cases = [base.with_changes(changed),                                       # kept entry used
             base.with_changes({"simulation.t_final": 0.5 * base.simulation.t_final}),
             base.with_changes({"trajectory.amplitude": [0.05] * base.robot.n}),
             base.with_changes({"arm.nominal_mass_scale": 1.3})]
    sizes = []
    for s in cases:
        kept = arm_rates(s)
        sizes.append(len(_inverses))
        forget_inertias()
        fresh = arm_rates(s)
        for key in fresh:
            np.testing.assert_array_equal(kept[key], fresh[key], err_msg=key)
        forget_inertias()
        arm_rates(base)                                                         # back to one entry: the base
    assert sizes == [1, 2, 2, 2]                                               # gains shared; the rest their own
    # gains still count: kp 180, kd 36 has real poles, the fast one 0.5 (36 + sqrt(36^2 - 4 180)) = 30 1/s; kp 360
    # gives complex ones of modulus sqrt(360); both times the same model mismatch
    mismatch = arm_rates(base)["gains.kp"][0] / 30.0
    assert mismatch > 1.0
    np.testing.assert_allclose(arm_rates(cases[0])["gains.kp"][0], np.sqrt(360.0) * mismatch, rtol=1e-12)


def test_at_most_sixteen_arms_and_paths_keep_their_inertias_the_latest_first():
    from blocks.figure2.run_limits import _KEPT_INVERSES, _inverses
    assert _KEPT_INVERSES == 16
    base = load_scenario("scope4")
    forget_inertias()
    windows = [base.with_changes({"simulation.t_final": 1.0 + 0.1 * k}) for k in range(17)]
    for s in windows[:16]:
        arm_rates(s)
    assert len(_inverses) == 16
    arm_rates(windows[0])                                       # used again: now the latest
    arm_rates(windows[16])                                      # the 17th drops the least recently used
    kept = {key[3] for key in _inverses}
    assert len(_inverses) == 16 and 1.0 in kept and 1.1 not in kept and 2.6 in kept
