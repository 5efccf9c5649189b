"""LeanRK45 steps as scipy's RK45 does, to the last bit (blocks.engines.lean_rk45).

The reference is scipy's own RK45 class stepped beside it on the same problem: every accepted step's time, state,
step count and dense output must be equal, including steps after rejections, a bounded step, a given first step,
the end of the interval and a failure for a step too small.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import RK45, solve_ivp

from blocks.engines.integrate import integrate_on_grid
from blocks.engines.lean_rk45 import LeanRK45


def van_der_pol(t, y, mu=30.0):
    """Stiff enough that the error control rejects steps at the quick transitions."""
    return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0]])


def forced_pendulum(t, y):
    return np.array([y[1], -9.81 * np.sin(y[0]) - 0.3 * y[1] + np.cos(3.0 * t), 0.5 * y[0] - y[2]])


CASES = {
    "van der Pol": (van_der_pol, [2.0, 0.0], 60.0, {"rtol": 1e-6, "atol": 1e-9}),
    "pendulum, max_step": (forced_pendulum, [1.0, 0.0, 0.2], 10.0, {"rtol": 1e-8, "atol": 1e-10, "max_step": 0.05}),
    "pendulum, first_step": (forced_pendulum, [0.3, -1.0, 0.0], 3.0, {"rtol": 1e-5, "atol": 1e-8,
                                                                       "first_step": 1e-3}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_step_and_its_dense_output_are_scipys(case):
    fun, y0, t_end, options = CASES[case]
    ours, theirs = LeanRK45(fun, 0.0, y0, t_end, **options), RK45(fun, 0.0, y0, t_end, **options)
    steps = rejected = 0
    while theirs.status == "running":
        h_before = theirs.h_abs
        assert ours.step() == theirs.step()
        steps += 1
        rejected += theirs.t - theirs.t_old < h_before * 0.999       # this step was cut by the error control
        assert (ours.status, ours.t, ours.t_old, ours.nfev) == (theirs.status, theirs.t, theirs.t_old, theirs.nfev)
        np.testing.assert_array_equal(ours.y, theirs.y)
        assert ours.h_abs == theirs.h_abs
        if steps % 7 == 0:
            a, b = ours.dense_output(), theirs.dense_output()
            inside = np.linspace(theirs.t_old, theirs.t, 5)
            np.testing.assert_array_equal(a(inside), b(inside))
            np.testing.assert_array_equal(a(inside[2]), b(inside[2]))
    assert ours.status == "finished" and ours.t == t_end
    assert steps > 20
    if case == "van der Pol":
        assert rejected > 0


def test_a_step_too_small_fails_as_scipys():
    """y' = y^2 from y(0) = 1 leaves every bound at t = 1: both stop there with scipy's message."""
    def blow_up(t, y):
        return y * y
    ours, theirs = LeanRK45(blow_up, 0.0, [1.0], 2.0), RK45(blow_up, 0.0, [1.0], 2.0)
    while theirs.status == "running":
        assert ours.step() == theirs.step()
    assert ours.status == theirs.status == "failed"
    assert ours.t == theirs.t and 0.99 < ours.t < 1.0
    np.testing.assert_array_equal(ours.y, theirs.y)


def test_integrate_on_grid_is_solve_ivp_bit_for_bit():
    """The integrator loop (which steps with LeanRK45 for RK45) fills the grid as solve_ivp does."""
    grid = np.linspace(0.0, 10.0, 401)
    states, nfev = integrate_on_grid(forced_pendulum, [1.0, 0.0, 0.2], grid, rtol=1e-7, atol=1e-9)
    ref = solve_ivp(forced_pendulum, (0.0, 10.0), [1.0, 0.0, 0.2], t_eval=grid, rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(states, ref.y)
    assert nfev == ref.nfev


def test_a_vectorized_right_hand_side_is_refused():
    with pytest.raises(ValueError, match="one state at a time"):
        LeanRK45(forced_pendulum, 0.0, [1.0, 0.0, 0.0], 1.0, vectorized=True)


def test_the_integrator_steps_rk45_with_it_where_this_scipy_is_the_one_it_restates():
    from blocks.engines import integrate
    from blocks.engines.lean_rk45 import lean_rk45_usable
    assert lean_rk45_usable()
    assert integrate._STEPPERS["RK45"] is LeanRK45
    assert all(integrate._STEPPERS[name] is cls for name, cls in integrate.SOLVERS.items() if name != "RK45")
