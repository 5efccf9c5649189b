"""A budget's limits (blocks.engines.budget, blocks.engines.monitor): what a job may use, inclusive; shared among jobs
run at once;
the step estimate bounding the steps the schedule takes; and the right-hand-side evaluations the monitor counts
against the step budget during a run, checked with scipy's own count per step."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.engines.budget import Budget, BudgetError, Estimate
from blocks.engines.monitor import Monitor

PAPER = blocks.load_scenario("paper")
SHORT = {"simulation.t_final": 0.2, "trajectory.duration": 10.0}


def test_the_step_budget_is_enforced_during_the_run(monkeypatch):
    """The paper run is estimated at 100 steps (its PD rate 30 1/s over 10 s) and takes about 820 (4922 RK45
    evaluations): within a budget of 150 steps it starts and is stopped at 900 evaluations."""
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "150")
    with pytest.raises(blocks.SimulationError, match="more than 900 right-hand-side evaluations"):
        blocks.simulate(PAPER, engine="fast")
    monkeypatch.setenv("DOBKIT_MAX_STEPS", "lots")
    with pytest.raises(ValueError, match="DOBKIT_MAX_STEPS"):
        blocks.simulate(PAPER.with_changes(SHORT), engine="fast")


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
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
    from blocks.engines.budget import schedule_steps
    from blocks.figure2.batch import step_schedule
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
