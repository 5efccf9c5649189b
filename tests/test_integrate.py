"""integrate_on_grid: solve_ivp's output-grid loop with a divergence check on every step."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from blocks.integrate import SOLVERS, DivergenceError, SolverFailure, _crossing_time, integrate_on_grid


def _oscillator(t, x):
    """A damped, forced oscillator: smooth, with a known solution for constant forcing."""
    return np.array([x[1], -4.0 * x[0] - 0.4 * x[1] + np.sin(3.0 * t)])


@pytest.mark.parametrize("method", ["RK45", "DOP853", "Radau", "LSODA"])
def test_states_equal_solve_ivp_on_the_same_grid(method):
    t = np.linspace(0.0, 5.0, 101)
    states, nfev = integrate_on_grid(_oscillator, [1.0, 0.0], t, method, rtol=1e-8, atol=1e-10, max_step=0.3)
    ref = solve_ivp(_oscillator, (0.0, 5.0), [1.0, 0.0], method=method, t_eval=t, rtol=1e-8, atol=1e-10,
                    max_step=0.3)
    np.testing.assert_array_equal(states, ref.y)
    assert nfev == ref.nfev


def test_an_exponential_matches_its_closed_form():
    t = np.linspace(0.0, 2.0, 41)
    states, _ = integrate_on_grid(lambda t, x: -1.5 * x, [2.0], t, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(states[0], 2.0 * np.exp(-1.5 * t), rtol=1e-8)


def test_growth_past_the_bound_stops_with_the_time_it_happened():
    t = np.linspace(0.0, 10.0, 11)
    with pytest.raises(DivergenceError) as err:
        integrate_on_grid(lambda t, x: x, [1.0], t, bound=1e3, rtol=1e-9, atol=1e-12)
    # x = e^t passes 1e3 at t = ln(1e3) = 6.91 s, found inside the step that crossed it
    assert err.value.time == pytest.approx(np.log(1e3), rel=1e-7)


def test_a_start_beyond_the_bound_is_divergence_at_the_start():
    with pytest.raises(DivergenceError) as err:
        integrate_on_grid(lambda t, x: -x, [2e6], np.linspace(0.5, 1.0, 3), bound=1e6)
    assert err.value.time == 0.5


def test_a_right_hand_side_turning_non_finite_stops_the_solver_at_that_time():
    # RK45 rejects every step whose error estimate is not finite, so the state never becomes NaN:
    # the step size collapses at t = 0.5 s and that is reported
    t = np.linspace(0.0, 1.0, 5)
    with pytest.raises(SolverFailure, match="step size") as err:
        integrate_on_grid(lambda t, x: np.array([np.nan]) if t > 0.5 else np.array([1.0]), [0.0], t, max_step=0.1)
    assert err.value.time == pytest.approx(0.5, abs=1e-9)


def test_a_blow_up_in_finite_time_is_a_solver_failure_or_divergence():
    # x' = x^2 from 1 reaches infinity at t = 1 s
    with pytest.raises((SolverFailure, DivergenceError)) as err:
        integrate_on_grid(lambda t, x: x ** 2, [1.0], np.linspace(0.0, 2.0, 5))
    assert err.value.time <= 1.0 + 1e-6


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="Euler"), "method must be one of"),
    (dict(t_grid=[0.0, 1.0, 1.0]), "increasing"),
    (dict(t_grid=[0.0]), "at least two"),
    (dict(t_grid=[0.0, 0.5, np.nan]), "finite"),
])
def test_bad_arguments_are_named(kwargs, match):
    args = dict(fun=_oscillator, x0=[0.0, 0.0], t_grid=np.linspace(0.0, 1.0, 3))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        integrate_on_grid(**args)


def test_progress_reaches_one_or_is_not_called_for_a_short_run():
    seen = []
    integrate_on_grid(_oscillator, [1.0, 0.0], np.linspace(0.0, 1.0, 11), progress=seen.append)
    assert all(0.0 <= f <= 1.0 for f in seen)


def test_solver_names_are_scipy_solvers():
    from scipy.integrate import OdeSolver
    assert all(issubclass(cls, OdeSolver) for cls in SOLVERS.values())


def test_the_first_crossing_in_a_step_is_reported():
    """A step whose interpolant leaves the bound at 0.1 s, comes back at 0.3 s and leaves again at 0.8 s."""
    class Step:                         # the three things _crossing_time reads of a solver after a step
        t_old, t = 0.0, 1.0
        y = np.array([1.0 + 10 * 0.9 * 0.7 * 0.2])

        @staticmethod
        def dense_output():
            return lambda t: np.array([1.0 + 10 * (t - 0.1) * (t - 0.3) * (t - 0.8)])
    assert _crossing_time(Step, 1.0) == pytest.approx(0.1, abs=1e-9)
