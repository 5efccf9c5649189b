"""Bounds on how long an FMU job may run: steps, right-hand-side evaluations, wall time.

A co-simulation at ``--step 1e-9`` or a check over ``--t-final 1e9`` would
run for days.  Every job of :mod:`fmu` therefore

* estimates its fixed steps before it starts, from the numbers it is given,
  and refuses with :class:`~fmu.errors.BudgetError` when the estimate
  exceeds :attr:`Budget.max_steps` -- the message gives the estimate, the
  budget, the value that makes it so large and how to raise the budget;
* counts the right-hand-side evaluations of adaptive integrations (a stiff
  FMU drives them up) against :attr:`Budget.max_rhs_evaluations`;
* checks the wall time between steps against :attr:`Budget.max_wall_time`.

A call that hangs inside FMU code cannot be interrupted from Python: the
wall-time check happens between calls.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

from .errors import BudgetError

__all__ = ["Budget", "Deadline", "DEFAULT_BUDGET", "counted"]


@dataclass(frozen=True)
class Budget:
    """The limits of one job (a command, or one Python call).

    Parameters
    ----------
    max_steps : int
        Largest number of fixed steps of one run: communication steps of a
        co-simulation times the Python side's RK4 sub-steps, or the steps of a
        check's Co-Simulation run (default 2,000,000: about 10 minutes of
        co-simulation of the paper's loop).
    max_rhs_evaluations : int
        Largest number of right-hand-side evaluations of one adaptive
        integration (default 5,000,000).
    max_wall_time : float
        Largest wall time of the whole job in s (default 3600).
    """

    max_steps: int = 2_000_000
    max_rhs_evaluations: int = 5_000_000
    max_wall_time: float = 3600.0

    def __post_init__(self) -> None:
        for name in ("max_steps", "max_rhs_evaluations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"Budget.{name} must be an integer >= 1, got {value!r}")
        value = self.max_wall_time
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise ValueError(f"Budget.max_wall_time must be a finite number > 0 s, got {value!r}")

    def check_steps(self, steps: float, what: str, cause: str) -> None:
        """Refuse a run of ``steps`` fixed steps beyond :attr:`max_steps`.

        Parameters
        ----------
        steps : float
            The estimate (may be huge or infinite).
        what : str
            The run, e.g. ``"co-simulation of plant.fmu"``.
        cause : str
            The values that give the estimate, e.g. ``"t_final = 10 s / step = 1e-09 s"``.
        """
        if not steps <= self.max_steps:
            raise BudgetError(f"{what}: {cause} gives {steps:.3g} steps, more than the budget of "
                              f"{self.max_steps:.3g} steps (max_steps; command line --max-steps); choose a larger "
                              f"step or a shorter time, or raise the budget")

    def deadline(self, what: str) -> Deadline:
        """A wall-time deadline starting now."""
        return Deadline(self.max_wall_time, what)


DEFAULT_BUDGET = Budget()


class Deadline:
    """The wall-time limit of a job, checked between steps.

    Parameters
    ----------
    seconds : float
        Wall time allowed from now (s).
    what : str
        The job, for the message.
    """

    def __init__(self, seconds: float, what: str):
        self.seconds = seconds
        self.what = what
        self.start = time.monotonic()

    def check(self, progress: str) -> None:
        """Raise :class:`~fmu.errors.BudgetError` if the wall time is up; ``progress`` says how far the job got."""
        if time.monotonic() - self.start > self.seconds:
            raise BudgetError(f"{self.what}: wall-time limit of {self.seconds:g} s reached ({progress}); raise it "
                              "with max_wall_time (command line --max-wall-time) or make the run smaller; no partial "
                              "result is returned")


def counted(rhs, budget: Budget, deadline: Deadline, what: str):
    """Wrap ``rhs(t, x)`` so that it raises when the evaluations or the wall time exceed the budget.

    The message gives the simulated time reached and the evaluations per
    simulated second there: many evaluations for little time mean stiff or
    fast dynamics (for example a large gain or a small time constant).
    """
    count = [0]

    def wrapped(t, x):
        count[0] += 1
        n = count[0]
        if n > budget.max_rhs_evaluations:
            rate = n / max(abs(float(t)), 1e-300)
            raise BudgetError(f"{what}: {n - 1} right-hand-side evaluations by t = {float(t):.6g} s ({rate:.3g} per "
                              f"simulated second), more than the budget of {budget.max_rhs_evaluations:.3g} "
                              "(max_rhs_evaluations): the dynamics are stiff or fast there; shorten the run or "
                              "raise the budget")
        if n % 1000 == 0:
            deadline.check(f"t = {float(t):.6g} s after {n} evaluations")
        return rhs(t, x)

    wrapped.count = count
    return wrapped
