"""The one Monitor every engine calls while it runs: divergence, budget, progress, interruption.

An engine advances a loop; what it must not decide on its own is *when to
stop*.  A :class:`Monitor` is made once per job, before the work, from

* the physical bounds of the loop's states (:mod:`blocks.engines.divergence`, with
  the growth rule for states without a physical bound), one column per
  member for a batch;
* the :class:`~blocks.engines.budget.Budget` (steps per run, memory, wall time),
  already checked against the job's estimate before the Monitor is made;
* the user's progress callback.

Every engine -- python-control, numpy, compiled, both batches, the sampled
loop, co-simulation -- asks it the same questions: are these states within
their bounds (:meth:`Monitor.check`, :meth:`Monitor.check_members`), may I
go on (:meth:`Monitor.check_time`, :meth:`Monitor.check_evaluations`), and
tells it how far it got (:meth:`Monitor.report`).  Compiled engines return
to Python at least every :data:`CHUNK_SECONDS` so that the wall-time budget,
Ctrl-C and SIGTERM (which the commands turn into :class:`KeyboardInterrupt`)
are honoured while native code runs.

The messages name the job, the time, the signal, its value and its bound,
or the budget, how far the job got and how to raise the budget.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from blocks.engines.budget import ENVIRONMENT, Budget, BudgetError
from blocks.engines.divergence import StateBounds

__all__ = ["Monitor", "SimulationError", "CHUNK_SECONDS", "PROGRESS_PERIOD", "EVALUATIONS_PER_STEP"]

#: Longest stretch of wall time a compiled engine runs without returning to the Monitor (s).
CHUNK_SECONDS = 0.1
#: Progress is reported at most this often (s of wall time).
PROGRESS_PERIOD = 0.2
#: Right-hand-side evaluations per integrator step, for the step budget of adaptive solvers.
EVALUATIONS_PER_STEP = {"RK45": 6, "RK23": 3, "DOP853": 12}


class SimulationError(RuntimeError):
    """The simulation failed or diverged; the message gives the time and the reason.

    Attributes
    ----------
    time : float or None
        When it happened (s).
    signal : str
        The diverging signal (``"plant dq[2]"``), when divergence is the cause.
    """

    def __init__(self, message: str, time: float | None = None, signal: str = "") -> None:
        super().__init__(message)
        self.time, self.signal = time, signal


class Monitor:
    """What an engine asks while it runs (see :mod:`blocks.engines.monitor`).

    Parameters
    ----------
    what : str
        The job, for messages (``"scenario 'paper'"``).
    bounds : StateBounds or None
        Physical bounds of the states (:func:`blocks.figure2.physical_bounds.state_bounds`), or None: every state judged by
        growth alone.
    x0 : array_like
        The start state, (nstates,) or (nstates, N); sets the growth bounds.
    budget : Budget, optional
        Default :meth:`Budget.from_env`.
    t_final : float
        The end of simulated time (s), for progress and messages.
    progress : callable, optional
        Called with the fraction of simulated time done (0..1), at most every :data:`PROGRESS_PERIOD`.
    method : str
        The solver, for the step budget in right-hand-side evaluations.
    growth : bool
        Whether states without a finite bound are judged by growth (:meth:`StateBounds.with_growth`, the
        Figure-2 loop's rule) or only by being finite (a user's own diagram, as python-control runs it).
    """

    @classmethod
    def for_job(cls, what: str, budget: Budget | None = None, t_final: float = math.inf,
                progress: Callable[[float], None] | None = None) -> Monitor:
        """A Monitor of the budget and progress of a job whose states it does not judge (an FMU check, a study)."""
        return cls(what, None, np.zeros(0), budget, t_final, progress)

    def __init__(self, what: str, bounds: StateBounds | None, x0, budget: Budget | None = None,
                 t_final: float = math.inf, progress: Callable[[float], None] | None = None,
                 method: str = "RK45", growth: bool = True) -> None:
        if progress is not None and not callable(progress):
            raise TypeError(f"progress must be a callable taking the fraction done (0..1), got {progress!r}")
        x0 = np.asarray(x0, dtype=float)
        if bounds is None:
            n = x0.shape[0]
            bounds = StateBounds(np.full(n, np.inf), [f"state {k}" for k in range(n)], [""] * n, ["finite"] * n)
        self.what = what
        self.bounds = bounds.with_growth(x0) if growth else bounds
        self.budget = Budget.from_env() if budget is None else budget
        self.t_final = float(t_final)
        self.method = method
        self.started = time.monotonic()
        self.deadline = None if self.budget.seconds is None else self.started + self.budget.seconds
        self._progress, self._last_report = progress, self.started

    # -- bounds ---------------------------------------------------------------------------------------
    @property
    def limits(self) -> np.ndarray:
        """The bound of every state, (nstates,) or (nstates, N): what compiled engines take as an array."""
        return self.bounds.bounds

    def diverged(self, t: float, x) -> SimulationError:
        """The error for a run whose state ``x`` left its bounds at time ``t`` (s)."""
        x = np.asarray(x, dtype=float)
        sentence = self.bounds.describe(x)
        signal = sentence.split(" reached ")[0].split(" became ")[0]
        return SimulationError(f"{self.what}: the loop diverged at t = {t:.6g} s: {sentence}; no result is returned",
                               time=float(t), signal=signal)

    def check(self, t: float, x) -> None:
        """Raise :class:`SimulationError` when a state of ``x`` (one run) is not finite or beyond its bound."""
        if self.bounds.violated(x).any():
            raise self.diverged(t, x)

    def check_grid(self, t_grid, states) -> None:
        """Judge a run's states on its grid (nstates, T) after the fact (engines that do not stop themselves)."""
        states = np.asarray(states, dtype=float)
        bad = self.bounds.violated(states.T).any(axis=1)          # one run: bounds (nstates,), states (nstates, T)
        if bad.any():
            k = int(np.argmax(bad))
            raise self.diverged(float(t_grid[k]), states[:, k])

    def check_members(self, t: float, X, failed_at: np.ndarray) -> np.ndarray:
        """Mark the members of a batch whose states ``X`` (nstates, N) left their bounds at ``t``.

        Returns ``failed_at`` (N,) with ``t`` for the members that failed now (NaN: not failed); members that
        failed earlier keep their time.
        """
        bad = self.bounds.violated(X).any(axis=0)
        new = bad & np.isnan(failed_at)
        if new.any():
            failed_at = failed_at.copy()
            failed_at[new] = t
        return failed_at

    def member_reason(self, m: int, x) -> str:
        """Why member ``m`` failed, from its state ``x`` at that time (nstates,)."""
        return self.bounds.member(m).describe(x)

    # -- budget ---------------------------------------------------------------------------------------
    @property
    def max_evaluations(self) -> int:
        """Right-hand-side evaluations one run may make (the step budget in the solver's evaluations)."""
        return self.budget.steps * EVALUATIONS_PER_STEP.get(self.method, 6)

    def out_of_time(self) -> bool:
        return self.deadline is not None and time.monotonic() > self.deadline

    def time_error(self, t: float | None, where: str = "") -> BudgetError:
        """The error for a job whose wall-time budget ran out at simulated time ``t`` (or at ``where``)."""
        at = where or f"t = {t:.6g} s of {self.t_final:g} s"
        return BudgetError(f"{self.what}: the wall-time budget of {self.budget.seconds:g} s ran out at {at}; raise it "
                           f"with --max-seconds or {ENVIRONMENT['seconds']}; no result is returned", key="",
                           limit="seconds")

    def check_time(self, t: float | None = None, where: str = "") -> None:
        """Raise :class:`~blocks.engines.budget.BudgetError` when the wall-time budget has run out."""
        if self.out_of_time():
            raise self.time_error(t, where)

    def counted(self, rhs: Callable, what: str = "") -> Callable:
        """``rhs(t, x)`` that counts its calls against the step budget and checks the wall time every 1000 calls.

        For integrations the Monitor does not step itself (an FMU's Model Exchange run by scipy).  The count is
        ``wrapped.count[0]``.
        """
        count = [0]
        label = what or self.what

        def wrapped(t, x):
            count[0] += 1
            if count[0] > self.max_evaluations:
                raise BudgetError(
                    f"{label}: {count[0] - 1:,} right-hand-side evaluations by t = {float(t):.6g} s "
                    f"({count[0] / max(abs(float(t)), 1e-300):.3g} per simulated second), more than the step budget "
                    f"allows ({self.budget.steps:,} steps, {self.max_evaluations:,} evaluations): the dynamics are "
                    f"stiff or fast there; shorten the run or raise it with --max-steps or {ENVIRONMENT['steps']}",
                    key="", limit="steps")
            if count[0] % 1000 == 0:
                self.check_time(float(t))
            return rhs(t, x)

        wrapped.count = count
        return wrapped

    def steps_error(self, t: float, count: int, unit: str = "right-hand-side evaluations") -> SimulationError:
        rate = count / max(float(t), 1e-300)
        return SimulationError(f"{self.what}: the solver stopped at t = {t:.6g} s of {self.t_final:g} s: it needed "
                               f"more than {count:,} {unit}, {rate:.3g} per simulated second: the problem is stiff "
                               f"or fast (the step budget is {self.budget.steps:,} steps; raise it with --max-steps "
                               f"or {ENVIRONMENT['steps']})", time=float(t))

    def check_evaluations(self, t: float, count: int) -> None:
        """Raise :class:`SimulationError` when ``count`` right-hand-side evaluations exceed the step budget."""
        if count > self.max_evaluations:
            raise self.steps_error(t, self.max_evaluations)

    # -- progress ---------------------------------------------------------------------------------------
    def report(self, t: float, final: bool = False) -> None:
        """Tell the progress callback how far simulated time got (at most every :data:`PROGRESS_PERIOD`)."""
        if self._progress is None:
            return
        now = time.monotonic()
        if final or now - self._last_report >= PROGRESS_PERIOD:
            self._last_report = now
            done = 1.0 if final else (min(1.0, max(0.0, t / self.t_final)) if self.t_final > 0 else 1.0)
            self._progress(done)
