"""One simulator: a diagram and a context stepped on an output grid by the engine chosen in one place.

:func:`advance` is where time is stepped for every continuous engine: it
takes an engine made for a diagram (:func:`make_engine`), a
:class:`~blocks.engines.context.Context` (start state, bounds, budget) and the
solver settings, makes the run's :class:`~blocks.engines.monitor.Monitor` (its
per-step hook: bounds from the context, budget, progress, Ctrl-C), and
returns the states and outputs on the grid, or raises
:class:`~blocks.engines.monitor.SimulationError` saying when and why it stopped.

The engines (all with ``integrate`` and ``outputs_on_grid``):

``compiled``
    :class:`blocks.engines.compiled.CompiledLoopEngine`: the diagram's generated,
    numba-compiled module (Dormand-Prince 5(4), ``solve_ivp``'s RK45 step control);
``fast``
    :class:`NumpyEngine`: the diagram's plan (:class:`blocks.engines.fastsim.CompiledLoop`)
    on ``solve_ivp``'s solvers through :func:`blocks.engines.integrate.integrate_on_grid`
    (stopping at the events of hybrid blocks);
``python-control``
    :class:`PythonControlEngine`: :func:`control.input_output_response`,
    judged by the Monitor after the fact.

Front doors: :func:`blocks.simulate` (the Figure-2 loop of a scenario: it
fills the context from the scenario) and :func:`simulate_system` (any
diagram a user wires, with python-control's arguments).  The choice of
engine is :func:`blocks.engines.engine_choice.select_engine`'s.
"""
from __future__ import annotations

import copy
import math
import numbers
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import control as ct
import numpy as np

from blocks.engines.budget import Budget
from blocks.engines.context import Context
from blocks.engines.engine_choice import ENGINES, select_engine
from blocks.engines.fastsim import CompiledLoop
from blocks.engines.integrate import SOLVERS, DivergenceError, SolverFailure, integrate_on_grid, loop_events
from blocks.engines.monitor import Monitor, SimulationError

__all__ = ["Solver", "advance", "make_engine", "NumpyEngine", "PythonControlEngine", "simulate_system",
           "SOLVE_IVP_KWARGS"]


@dataclass(frozen=True)
class Solver:
    """Solver settings of a run (those of :func:`scipy.integrate.solve_ivp`; times in s)."""

    method: str = "RK45"
    rtol: float = 1e-3
    atol: float = 1e-6
    max_step: float = math.inf
    first_step: float | None = None

    @classmethod
    def of(cls, settings) -> Solver:
        """The solver of anything with ``method``, ``rtol``, ``atol``, ``max_step`` (a scenario's ``simulation``)."""
        if isinstance(settings, Solver):
            return settings
        return cls(settings.method, settings.rtol, settings.atol, settings.max_step,
                   getattr(settings, "first_step", None))


class NumpyEngine:
    """The numpy engine with the interface of :class:`blocks.engines.compiled.CompiledLoopEngine`.

    Parameters
    ----------
    system : control.InterconnectedSystem
    method : str
        A :data:`blocks.engines.integrate.SOLVERS` name.
    params : dict, optional
        Call-time parameters for blocks without kernels (as python-control merges them).
    """

    def __init__(self, system, method: str, params: dict | None = None) -> None:
        self.compiled, self.method = CompiledLoop(system, params), method
        # blocks with events (FMUs): the run stops at them and keeps the outputs as it passes the grid
        self.events = loop_events(system, self.compiled.rhs, self.compiled.output)

    def with_params(self, params) -> NumpyEngine:
        """This engine running its diagram with the kernel parameters ``params`` (block name -> tuple, a
        :attr:`blocks.engines.context.Context.params`) in place of the blocks' own: the same plan with those
        blocks' kernels given the numbers, evaluated step by step (the generated right-hand side carries the
        blocks' own numbers)."""
        from blocks.engines.compiled.codegen import block_kernels
        from blocks.engines.context import kernels_with_params
        kernels = kernels_with_params(block_kernels(self.compiled.plan, self.compiled.system), params)
        twin = copy.copy(self)
        twin.compiled = self.compiled.with_kernels(kernels)
        twin.events = loop_events(twin.compiled.system, twin.compiled.rhs, twin.compiled.output)
        return twin

    def integrate(self, x0, t_grid, rtol, atol, max_step, monitor: Monitor, first_step=None):
        rhs = self.compiled.point_rhs if self.compiled.params is None else self.compiled.rhs
        return integrate_on_grid(rhs, x0, t_grid, self.method, rtol=rtol, atol=atol, max_step=max_step,
                                 bound=monitor.limits, monitor=monitor, events=self.events, first_step=first_step)

    def _c_loop(self):
        """The loop's C library when the run's right-hand side is it (no events, the blocks' own numbers)."""
        if self.events is not None or self.compiled.params is not None:
            return None
        return self.compiled.c_loop

    @property
    def row_groups(self) -> dict:
        """Row groups computed beside the outputs (:mod:`blocks.engines.compiled.rows`): those of the loop's C
        library's grid pass when it runs the loop (the lumped disturbance ``d`` ...), else none."""
        c = self._c_loop()
        return c.row_groups if c is not None else {}

    def outputs_on_grid(self, t_grid, X, rows: tuple = (), stacked: bool = False):
        """The outputs at the grid times (and, with ``rows``, the named row groups' rows: ``(outputs, {name:
        rows})``, or with ``stacked`` one array, the outputs and then the rows in the order asked)."""
        if self.events is not None:
            return np.array(self.events.outputs).T
        c = self._c_loop()
        if c is None:
            return self.compiled.outputs_on_grid(t_grid, X)
        outputs, by_name = c.outputs_on_grid(t_grid, X, tuple(rows))
        if not rows:
            return outputs
        return np.vstack([outputs] + [by_name[name] for name in rows]) if stacked else (outputs, by_name)


class PythonControlEngine:
    """:func:`control.input_output_response` with the engine interface (the reference engine).

    Its solver does not stop at the bounds: the Monitor judges the states on
    the grid after the run (:meth:`blocks.engines.monitor.Monitor.check_grid`).
    """

    def __init__(self, system, method: str, U=0, params: dict | None = None) -> None:
        self.system, self.method, self.U, self.params = system, method, U, params
        self._outputs = None

    def integrate(self, x0, t_grid, rtol, atol, max_step, monitor: Monitor, first_step=None):
        kwargs = dict(rtol=rtol, atol=atol, max_step=max_step)
        if first_step is not None:
            kwargs["first_step"] = first_step
        resp = ct.input_output_response(self.system, t_grid, self.U, x0, params=self.params,
                                        solve_ivp_method=self.method, solve_ivp_kwargs=kwargs, return_states=True)
        states, self._outputs = np.atleast_2d(resp.states), np.atleast_2d(resp.outputs)
        if not resp.success:
            # a solver that gave up on a diverging loop: name the signal where the states left their bounds
            finite = np.all(np.isfinite(states), axis=0)
            monitor.check_grid(np.asarray(t_grid)[finite], states[:, finite])
            raise SolverFailure(float(t_grid[-1]), f"solver failed: {resp.message}")
        return states, 0

    def outputs_on_grid(self, t_grid, X):
        return self._outputs

    def with_params(self, params):
        """Refused: python-control calls the blocks' own functions with their own numbers."""
        raise ValueError("Context.params: the python-control engine runs the blocks' own functions with their own "
                         "numbers; use engine='fast' or 'compiled', or build the blocks with these numbers")


def make_engine(engine: str, system, method: str, *, U=0, params: dict | None = None):
    """The engine object of a resolved ``engine`` name for ``system``.

    Parameters
    ----------
    engine : {"compiled", "fast", "python-control"}
    system : control.InterconnectedSystem
        For ``compiled`` and ``fast`` a diagram with external inputs only for ``fast``'s plan; see
        :func:`simulate_system` for any diagram.
    method : str
    U, params
        External inputs and call-time parameters (``python-control`` and ``fast``).
    """
    if engine == "compiled":
        from blocks.engines.compiled import CompiledLoopEngine
        return CompiledLoopEngine(system, rows=())
    if engine == "fast":
        return NumpyEngine(system, method, params)
    if engine == "python-control":
        return PythonControlEngine(system, method, U, params)
    raise ValueError(f"engine must be one of 'compiled', 'fast', 'python-control' here, got {engine!r}")


def advance(engine, context: Context, t_grid, solver: Solver, *, what: str = "the diagram",
            progress: Callable[[float], None] | None = None, rows: tuple = ()) -> tuple[np.ndarray, np.ndarray, int]:
    """Step ``engine``'s diagram from ``context`` over ``t_grid``: ``(states, outputs, extra rows)``.

    The one stepping function every continuous front door calls.  The run's
    :class:`~blocks.engines.monitor.Monitor` is made here from the context (bounds,
    budget) and is the engine's per-step hook: it stops the run at a state
    beyond its bound, at the step and wall-time budgets, and takes the
    progress reports.

    Parameters
    ----------
    engine
        From :func:`make_engine` (or a :class:`blocks.engines.compiled.CompiledLoopEngine` made before).
    context : Context
        Start time and state, bounds, budget (one run).
    t_grid : numpy.ndarray
        Output times (s), increasing, starting at ``context.t0``.
    solver : Solver
    what : str
        The job, for messages (``"scenario 'paper'"``).
    progress : callable, optional
        Called with the fraction of simulated time done.
    rows : tuple of str
        Row groups of the compiled engine to compute beside the outputs (``("d",)``); their rows follow the
        outputs, and the third value says how many there are (0 when the engine has none).

    Raises
    ------
    SimulationError
        If the solver fails or a state leaves its bound (the message says when and why).
    blocks.engines.budget.BudgetError
        If the wall-time budget runs out.
    """
    if context.members is not None:
        raise ValueError("advance runs one member; a batch runs in blocks.figure2.batch")
    if context.params is not None:
        engine = engine.with_params(context.params)
    t_grid = np.asarray(t_grid, dtype=float)
    if t_grid.size and t_grid[0] != context.t0:
        raise ValueError(f"the output grid must start at the context's t0 = {context.t0:g} s, not {t_grid[0]:g} s")
    budget = context.budget if context.budget is not None else Budget.from_env()
    monitor = Monitor(what, context.state_bounds(), context.x0, budget, float(t_grid[-1]), progress, solver.method,
                      growth=context.growth)
    try:
        if solver.first_step is None:
            states, _ = engine.integrate(context.x0, t_grid, solver.rtol, solver.atol, solver.max_step,
                                         monitor=monitor)
        else:
            states, _ = engine.integrate(context.x0, t_grid, solver.rtol, solver.atol, solver.max_step,
                                         monitor=monitor, first_step=solver.first_step)
    except DivergenceError as err:
        raise monitor.diverged(err.time, err.state) from None
    except SolverFailure as err:
        if err.reason.startswith("solver failed: "):
            raise SimulationError(f"{what}: {err.reason}", time=None) from None
        raise SimulationError(f"{what}: the solver stopped at t = {err.time:.6g} s of {t_grid[-1]:g} s: "
                              f"{err.reason}", time=err.time) from None
    monitor.check_grid(t_grid, states)
    groups = getattr(engine, "row_groups", {})
    wanted = tuple(name for name in rows if name in groups)
    if wanted:
        outputs = engine.outputs_on_grid(t_grid, states, rows=wanted, stacked=True)
        extra = sum(groups[name][1].stop - groups[name][1].start for name in wanted)
    else:
        outputs, extra = engine.outputs_on_grid(t_grid, states), 0
    monitor.report(t_grid[-1], final=True)
    return states, outputs, extra


# -- any wired diagram ------------------------------------------------------------------------------------------
#: The ``solve_ivp_kwargs`` :func:`simulate_system` takes (solve_ivp's defaults where absent).
SOLVE_IVP_KWARGS = ("rtol", "atol", "max_step", "first_step")


def _times(T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 1 or T.size < 2 or not np.all(np.isfinite(T)) or np.any(np.diff(T) <= 0):
        raise ValueError(f"T must be at least two finite, increasing times (s), got shape {T.shape}")
    return T


def _inputs(U, ninputs: int, T: np.ndarray) -> np.ndarray:
    """``U`` as python-control reads it: (ninputs, len(T)), a scalar or a list of per-input values broadcast."""
    n = T.size
    if isinstance(U, (tuple, list)) and len(U) != n:
        parts = []
        for i, u in enumerate(U):
            u = np.array(u, dtype=float)
            if u.ndim == 0 or (u.ndim == 1 and u.shape[0] != n):
                u = np.outer(u, np.ones(n))
            elif not ((u.ndim == 1 and u.shape[0] == n) or (u.ndim == 2 and u.shape[1] == n)):
                raise ValueError(f"U: input element {i} has shape {u.shape}, not consistent with {n} times")
            parts.append(np.atleast_2d(u))
        U = np.vstack(parts) if parts else np.zeros((0, n))
    U = np.asarray(U, dtype=float)
    _finite("U", U, lambda ij: f"input {ij[0]} at t = {T[ij[-1]]:g} s" if U.ndim == 2 else
            (f"at t = {T[ij[0]]:g} s" if U.size == n else "the number given for every input and time"))
    if U.ndim == 0:
        return np.full((ninputs, n), float(U))
    if ninputs == 1 and U.shape == (n,):
        return U.reshape(1, n)
    if U.shape != (ninputs, n):
        raise ValueError(f"U must be a number or have shape ({ninputs}, {n}) for {ninputs} inputs and {n} times, "
                         f"got {U.shape}")
    return U


def _finite(name: str, values: np.ndarray, where) -> None:
    """Refuse a NaN or infinite value of ``name`` before any solver sees it (it would stop it at a tiny step)."""
    bad = np.argwhere(~np.isfinite(np.atleast_1d(values)))
    if bad.size:
        first = tuple(int(i) for i in bad[0])
        raise ValueError(f"{name} must be finite numbers, got {np.atleast_1d(values)[first]} ({where(first)}); "
                         f"{len(bad)} value(s) are not finite")


def _initial_state(X0, nstates: int) -> np.ndarray:
    """``X0`` as python-control reads it: a number for every state, a list of pieces, zero-padded when short."""
    try:
        if isinstance(X0, (tuple, list)):
            X0 = np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in X0]) if X0 else np.zeros(0)
        X0 = np.asarray(X0, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"X0 must be numbers (a number for every state, or an array), got {X0!r:.80}: {error}") \
            from None
    _finite("X0", X0, lambda ij: f"state {ij[0] if ij else 0}")
    if X0.ndim == 0:
        return np.full(nstates, float(X0))
    X0 = X0.ravel()
    if X0.size > nstates:
        raise ValueError(f"X0 has {X0.size} values for {nstates} states")
    if X0.size < nstates:
        if X0.size and X0[-1] != 0:         # python-control's note
            warnings.warn("X0 too short; padding with zeros", UserWarning, stacklevel=3)
        X0 = np.concatenate([X0, np.zeros(nstates - X0.size)])
    return X0


def _bounds(bounds, nstates: int) -> np.ndarray:
    """``bounds`` as one positive magnitude per state (inf: no bound), from one number or ``nstates`` of them."""
    b = np.asarray(bounds, dtype=float)
    if b.ndim > 1 or (b.ndim == 1 and b.size not in (1, nstates)):
        raise ValueError(f"bounds must be one number or {nstates} (one per state), got shape {b.shape}")
    b = np.broadcast_to(b.reshape(-1) if b.ndim else b, (nstates,)).copy()
    bad = np.flatnonzero(~(b > 0))          # NaN, 0 and negatives: every state would be out at once
    if bad.size:
        raise ValueError(f"bounds must be positive magnitudes (inf: no bound), got {b[bad[0]]} for state {bad[0]}")
    return b


def _check_grid_memory(sys, T: np.ndarray, budget: Budget | None) -> None:
    """Refuse, before anything is allocated, a grid whose arrays (states twice: the solver's and the result's,
    outputs, inputs; float64 at every time of ``T``) exceed the memory budget."""
    from blocks.engines.budget import Estimate
    rows = {"states": 2 * sys.nstates, "outputs": sys.noutputs, "inputs": sys.ninputs}
    parts = {name: 8 * T.size * n for name, n in rows.items()}
    reasons = {name: f"{rows[name]} rows x {T.size:,} times of T x 8 bytes" for name in rows}
    (budget or Budget.from_env()).check(Estimate(sum(parts.values()), 0, parts, dict.fromkeys(parts, "T"), reasons),
                                        f"system '{sys.name}' on {T.size:,} output times")


def _solver(method: str, kwargs: dict | None) -> Solver:
    if method not in SOLVERS:
        raise ValueError(f"solve_ivp_method must be one of {list(SOLVERS)}, got {method!r}")
    kwargs = dict(kwargs or {})
    unknown = sorted(set(kwargs) - set(SOLVE_IVP_KWARGS))
    if unknown:
        raise ValueError(f"solve_ivp_kwargs {unknown} are not taken by simulate_system (it takes "
                         f"{list(SOLVE_IVP_KWARGS)}); use control.input_output_response for them")
    for key, value in kwargs.items():
        if value is not None and (not isinstance(value, numbers.Real) or not value > 0):
            raise ValueError(f"solve_ivp_kwargs[{key!r}] must be a positive number, got {value!r}")
    return Solver(method, float(kwargs.get("rtol", 1e-3)), float(kwargs.get("atol", 1e-6)),
                  float(kwargs.get("max_step", math.inf)), kwargs.get("first_step"))


# Prepared runs of the latest diagrams (lowered diagram and engine), by diagram, grid, inputs, parameters, solver
_RUNS_KEPT = 8
_runs: dict = {}


def _run_key(sys, T, U, params, method: str, engine: str) -> tuple:
    """What a prepared run depends on: the diagram object and the numbers its blocks read now."""
    from blocks.diagram.control_compat import subsystems
    blocks = subsystems(sys) if isinstance(sys, ct.InterconnectedSystem) else [sys]
    numbers = repr([(b.name, sorted((k, repr(v)) for k, v in dict(b.params).items())) for b in blocks]) + \
        repr(sorted((k, repr(v)) for k, v in dict(getattr(sys, "params", {}) or {}).items()))
    from blocks.engines.wired import function_key
    # what the user's functions read from outside (a traced function takes it as constants)
    functions = tuple(function_key(fn) for b in blocks for fn in (getattr(b, "updfcn", None), getattr(b, "outfcn", None))
                      if fn is not None and getattr(getattr(b, "contract", None), "kernels", None) is None
                      and not isinstance(b, ct.StateSpace))
    return (id(sys), sys, T.tobytes(), U.shape, U.tobytes(), repr(sorted((params or {}).items())), numbers, functions,
            method, engine)


def _prepare(sys, T, U, params, method: str, engine: str) -> tuple:
    """``(engine name, engine, why not compiled)`` for a diagram: lowered, the engine chosen and made."""
    from blocks.engines.wired import lower
    lowered = lower(sys, T, U, params)
    reason = lowered.reason
    if reason is None:
        from blocks.engines.compiled import unavailable_reason
        reason = unavailable_reason(lowered.system, method)
    chosen = select_engine(engine, reason)
    if chosen == "compiled":
        return chosen, make_engine("compiled", lowered.system, method), reason
    # blocks kept as they are (refused) get python-control's parameters
    system_params = None
    if lowered.refused:
        system_params = dict(getattr(sys, "params", {}) or {})
        system_params.update(params or {})
    return chosen, NumpyEngine(lowered.system, method, system_params), reason


def simulate_system(sys, T, X0=0, U=0, params: dict | None = None, engine: str = "auto", *,
                    solve_ivp_method: str = "RK45", solve_ivp_kwargs: dict | None = None, bounds=None,
                    budget: Budget | None = None, progress: Callable[[float], None] | None = None
                    ) -> ct.TimeResponseData:
    """Simulate any python-control system on any engine: :func:`control.input_output_response`'s arguments and result.

    A diagram a user wired with :func:`control.interconnect` -- the Figure-2
    blocks, blocks of their own (``ct.nlsys`` with numpy functions, ``ct.ss``,
    ``ct.tf``), sums and gains on the wires, external inputs -- runs on the
    compiled engine when every block can be compiled (see :mod:`blocks.engines.wired`:
    a user's function is traced, else compiled by numba as it stands, else
    refused by the block's name); ``engine="auto"`` then falls back to the
    numpy engine with one :class:`~blocks.engines.engine_choice.EngineFallbackWarning`
    saying which block and why.

    Parameters
    ----------
    sys : control.InterconnectedSystem or control.NonlinearIOSystem
        A continuous-time system.
    T : array_like
        Output times (s), increasing; the run goes from ``T[0]`` to ``T[-1]`` and reports at every ``T``.
    X0 : array_like or float
        Start state; a number for every state, or fewer values, zero-padded (as python-control).
    U : array_like or float
        External inputs, (ninputs, len(T)) or a number for every input and time; linearly interpolated
        between the times of ``T`` (as python-control).
    params : dict, optional
        Parameters for the blocks' functions (merged as python-control merges them).
    engine : {"auto", "compiled", "fast", "python-control"}
    solve_ivp_method : str
        A :func:`scipy.integrate.solve_ivp` method; the compiled engine runs RK45.
    solve_ivp_kwargs : dict, optional
        ``rtol``, ``atol``, ``max_step``, ``first_step`` (solve_ivp's defaults 1e-3, 1e-6, inf).
    bounds : array_like, optional
        The largest magnitude of each state (or one for all); a run stops with
        :class:`~blocks.engines.monitor.SimulationError` where a state leaves it.
        Default: only a non-finite state stops a run.
    budget : Budget, optional
        Steps and wall time the run may take (default :meth:`Budget.from_env`).
    progress : callable, optional
        Called with the fraction of simulated time done (0..1).

    Returns
    -------
    control.TimeResponseData
        As :func:`control.input_output_response` returns it (time, outputs,
        states, inputs, labels), with ``engine``: the engine that ran.

    Raises
    ------
    SimulationError
        If the solver fails or a state leaves its bound.
    blocks.engines.compiled.CompiledUnavailable
        With ``engine="compiled"`` when a block cannot be compiled (its name and why).
    ValueError
        For arguments python-control would refuse, or settings this function does not take.

    Examples
    --------
    >>> import control as ct, numpy as np, blocks
    >>> lag = ct.tf([1], [0.1, 1], inputs="u", outputs="y", name="lag")
    >>> resp = blocks.simulate_system(lag, np.linspace(0, 1, 11), U=1.0, engine="fast")
    >>> round(float(resp.outputs[-1]), 4)
    0.9999
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    if isinstance(sys, ct.TransferFunction):
        # python-control wires a tf into an interconnection as its state-space form; taken alone, the same
        sys = ct.ss(sys, inputs=sys.input_labels, outputs=sys.output_labels, name=sys.name)
    if not isinstance(sys, ct.NonlinearIOSystem):
        raise TypeError(f"sys must be a python-control system (ct.nlsys, ct.ss, ct.tf, ct.interconnect...), got "
                        f"{type(sys).__name__}")
    if not sys.isctime():
        raise ValueError(f"system '{sys.name}' is discrete-time (dt = {sys.dt}); simulate_system runs continuous "
                         "systems (use control.input_output_response)")
    if params is not None and not isinstance(params, dict):
        raise TypeError(f"params must be a dict of parameter values, got {type(params).__name__}")
    T = _times(T)
    _check_grid_memory(sys, T, budget)
    U = _inputs(U, sys.ninputs, T)
    x0 = _initial_state(X0, sys.nstates)
    solver = _solver(solve_ivp_method, solve_ivp_kwargs)
    state_bounds = None
    if bounds is not None:
        from blocks.engines.divergence import StateBounds
        b = _bounds(bounds, sys.nstates)
        state_bounds = StateBounds(b, list(sys.state_labels), [""] * sys.nstates, ["the bound given"] * sys.nstates)
    context = Context(float(T[0]), x0, bounds=state_bounds, growth=False, budget=budget,
                      labels=tuple(sys.state_labels))
    if engine == "python-control":
        run_engine = PythonControlEngine(sys, solver.method, U, params)
        chosen = engine
    else:
        key = _run_key(sys, T, U, params, solver.method, engine)
        found = _runs.get(key)
        if found is None:
            found = _runs[key] = _prepare(sys, T, U, params, solver.method, engine)
            while len(_runs) > _RUNS_KEPT:
                _runs.pop(next(iter(_runs)))
        else:
            select_engine(engine, found[2])          # the same verdict (a fallback is noted once anyway)
        chosen, run_engine, _ = found
    if sys.nstates == 0:
        states = np.zeros((0, T.size))
        outputs = run_engine.outputs_on_grid(T, states) if chosen != "python-control" else \
            np.atleast_2d(ct.input_output_response(sys, T, U, x0, params=params).outputs)
    else:
        states, outputs, _ = advance(run_engine, context, T, solver, what=f"system '{sys.name}'", progress=progress)
    resp = ct.TimeResponseData(T, np.asarray(outputs).reshape(sys.noutputs, T.size), states,
                               U if sys.ninputs else None, issiso=sys.issiso(),
                               output_labels=sys.output_labels, input_labels=sys.input_labels,
                               state_labels=sys.state_labels, title="Input/output response for " + sys.name,
                               sysname=sys.name)
    resp.engine = chosen
    return resp
