"""integrate_on_grid: solve_ivp's output-grid loop with a divergence check on every step."""
from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from blocks.engines.integrate import SOLVERS, DivergenceError, SolverFailure, _crossing_time, integrate_on_grid


def _oscillator(t, x):
    """A damped, forced oscillator: smooth, with a known solution for constant forcing."""
    return np.array([x[1], -4.0 * x[0] - 0.4 * x[1] + np.sin(3.0 * t)])


@pytest.mark.parametrize("method", ["RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA"])
def test_states_equal_solve_ivp_on_the_same_grid(method):
    """Every documented method name gives solve_ivp's own numbers for that name, bit for bit.

    solve_ivp maps the name to its solver class itself, so a name bound to the wrong class
    (or options passed differently) shows up as different states or a different call count.
    """
    t = np.linspace(0.0, 5.0, 101)
    states, nfev = integrate_on_grid(_oscillator, [1.0, 0.0], t, method, rtol=1e-8, atol=1e-10, max_step=0.3)
    ref = solve_ivp(_oscillator, (0.0, 5.0), [1.0, 0.0], method=method, t_eval=t, rtol=1e-8, atol=1e-10,
                    max_step=0.3)
    np.testing.assert_array_equal(states, ref.y)
    assert nfev == ref.nfev


def test_the_solver_table_holds_exactly_the_solve_ivp_methods():
    assert sorted(SOLVERS) == ["BDF", "DOP853", "LSODA", "RK23", "RK45", "Radau"]
    # the six give six different results on the same problem: no two names share a solver
    t = np.linspace(0.0, 5.0, 11)
    finals = {name: integrate_on_grid(_oscillator, [1.0, 0.0], t, name, rtol=1e-3, atol=1e-6)[0][:, -1].tobytes()
              for name in SOLVERS}
    assert len(set(finals.values())) == len(SOLVERS)


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


def test_progress_is_reported_after_a_slow_stretch_and_grows():
    """The callback fires once 0.2 s of wall time have passed since the last report.

    The right-hand side sleeps 0.25 s once, at its first call past t = 0.5 s of a 1 s run:
    a report must follow at the end of that step (or of its retry, which starts less than
    one ``max_step`` before the call).  No time is measured here: a sleep lasts at least as
    long as asked, however slow the machine.
    """
    seen, slept = [], []

    def slow_once(t, x):
        if t > 0.5 and not slept:
            slept.append(t)
            time.sleep(0.25)
        return _oscillator(t, x)

    integrate_on_grid(slow_once, [1.0, 0.0], np.linspace(0.0, 1.0, 11), progress=seen.append, max_step=0.05)
    assert slept and seen, "no progress report after a 0.25 s stretch"
    assert seen[-1] >= slept[0] - 0.05
    assert all(0.0 <= f <= 1.0 for f in seen) and seen == sorted(seen)


def test_progress_is_optional():
    t = np.linspace(0.0, 1.0, 11)
    with_none, _ = integrate_on_grid(_oscillator, [1.0, 0.0], t, progress=None)
    with_callback, _ = integrate_on_grid(_oscillator, [1.0, 0.0], t, progress=lambda f: None)
    np.testing.assert_array_equal(with_none, with_callback)


def test_the_first_crossing_in_a_step_is_reported():
    """A step whose interpolant leaves the bound at 0.1 s, comes back at 0.3 s and leaves again at 0.8 s."""
    class Step:                         # the three things _crossing_time reads of a solver after a step
        t_old, t = 0.0, 1.0
        y = np.array([1.0 + 10 * 0.9 * 0.7 * 0.2])

        @staticmethod
        def dense_output():
            return lambda t: np.array([1.0 + 10 * (t - 0.1) * (t - 0.3) * (t - 0.8)])
    assert _crossing_time(Step, 1.0) == pytest.approx(0.1, abs=1e-9)
