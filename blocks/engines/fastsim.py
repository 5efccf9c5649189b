"""The numpy engine: an interconnection's evaluation plan executed as one right-hand side.

:class:`CompiledLoop` executes the :class:`~blocks.diagram.plan.LoopPlan` of an
interconnection (see :mod:`blocks.diagram.plan`): each right-hand-side call
evaluates the blocks it needs once, in dependency order, and then every
block's update.  After the solver, :meth:`CompiledLoop.outputs_on_grid`
evaluates the loop's outputs on the whole time grid, in one call per block
for blocks that take column-stacked signals (kernel blocks, and blocks whose
contract says ``columnwise``) and one point at a time for the others.

Parameters given to python-control at call time are honoured as
python-control honours them: merged into the parameters of every block that
reads python-control's ``params`` (blocks made with kernels bind theirs when
they are made and ignore them, as they do in python-control).

When every block has kernels and the plan is direct (every loop
:func:`blocks.closed_loop` builds), :attr:`CompiledLoop.point_rhs` runs the
plan's generated right-hand side on Python floats instead
(:mod:`blocks.engines.compiled.scalar`: the kernels traced into scalar statements,
the same numbers to the last bit, several times faster than a call per
block on small arrays); :meth:`CompiledLoop.rhs` is the plan executed with
numpy, the definition it is tested against.

This is an engine for :func:`blocks.simulate`, not part of the public API.
"""
from __future__ import annotations

import copy

import numpy as np

from blocks.diagram.plan import AlgebraicLoopError, LoopPlan, make_plan, settle, with_params

__all__ = ["CompiledLoop", "AlgebraicLoopError"]


def _rows(value) -> np.ndarray:
    """A block function's result as a 1-D array (python-control also accepts (n, 1) arrays and lists)."""
    return value if getattr(value, "ndim", 0) == 1 else np.ravel(value)


class CompiledLoop:
    """An interconnected system evaluated by its precomputed plan.

    Parameters
    ----------
    system : control.InterconnectedSystem
        The interconnection (for example from :func:`blocks.closed_loop`).
    params : dict, optional
        Parameters for the blocks that read python-control's ``params``, as if
        given to :func:`control.input_output_response`.

    Attributes
    ----------
    plan : LoopPlan
        The evaluation plan.
    order, rhs_order : list of str
        Block names in evaluation order, and those a right-hand side calls.
    """

    def __init__(self, system, params: dict | None = None) -> None:
        self.system = system
        self.plan: LoopPlan = make_plan(system, params)
        self.params = dict(params) if params else None
        self.nstates = self.plan.nstates
        self.order = self.plan.order
        self.rhs_order = self.plan.rhs_order
        self._other: tuple[dict, LoopPlan] | None = None
        self._point_rhs = self._plan_rhs_function = None

    def with_kernels(self, kernels_by_block: dict) -> CompiledLoop:
        """The same loop evaluated with these kernels (their parameters) for the blocks named; its right-hand side
        is the plan's (the generated one carries the blocks' own numbers)."""
        from blocks.diagram.plan import _kernel_step, _map_steps
        twin = copy.copy(self)
        twin.plan = _map_steps(self.plan, lambda s: _kernel_step(s.name, s.x, s.y, s.gather, kernels_by_block[s.name])
                               if s.name in kernels_by_block else s)
        twin._other = None
        twin._plan_rhs_function = twin._point_rhs = twin._plan_rhs
        return twin

    @property
    def point_rhs(self):
        """``f(t, x) -> dx`` for a solver: the generated right-hand side on floats when the loop allows it
        (see the module docstring), else :meth:`rhs`.  Made on first use (tracing takes tens of ms once per
        loop structure and process)."""
        if self._point_rhs is None:
            from blocks.engines.compiled.scalar import scalar_rhs
            self._plan_rhs_function = fallback = self._plan_rhs
            self._point_rhs = (scalar_rhs(self.plan, self.system, fallback) if self.params is None else None) \
                or fallback
        return self._point_rhs

    @property
    def c_loop(self):
        """The loop's C library (:class:`blocks.engines.compiled.c_loop.CLoop`) when :attr:`point_rhs` runs it
        (a chain arm's loop where a C compiler is found), else None."""
        owner = getattr(self.point_rhs, "__self__", None)
        if owner is None:
            return None
        from blocks.engines.compiled.c_loop import CLoop
        return owner if isinstance(owner, CLoop) else None

    @property
    def generated(self) -> bool:
        """Whether :attr:`point_rhs` runs the plan's generated code (else the numpy plan)."""
        return self.point_rhs is not self._plan_rhs_function

    def _plan_rhs(self, t, x):
        return self.rhs(t, x)

    def _plan_for(self, params: dict | None) -> LoopPlan:
        if params is None or params == self.params:
            return self.plan
        if self._other is None or self._other[0] != params:
            self._other = (dict(params), with_params(self.plan, self.system, params))
        return self._other[1]

    # -- one point ------------------------------------------------------------------------------------
    def _signals(self, plan: LoopPlan, t: float, x: np.ndarray, u_ext: np.ndarray | None,
                 steps) -> tuple[np.ndarray, list]:
        """All block outputs at ``(t, x)`` and, for plans that are not direct, every block's inputs."""
        y = np.zeros(plan.nsignals)
        if plan.direct:
            y[plan.copy_y] = x[plan.copy_x]

            def one_pass(y):
                for s in steps:
                    y[s.y] = _rows(s.output(t, x[s.x], y[s.gather], *s.output_args))
            return settle(plan, one_pass, y), []
        u_ext = np.zeros(plan.input_map.shape[1]) if u_ext is None else np.asarray(u_ext, dtype=float)
        y[:] = 0.0
        inputs = []
        for s, rows in zip(plan.steps, plan.input_rows):
            u = plan.connect_map[rows] @ y + plan.input_map[rows] @ u_ext
            y[s.y] = _rows(s.output(t, x[s.x], u, *s.output_args))
            inputs.append(u)
        # inputs of blocks without feedthrough were gathered before their sources ran: gather again
        inputs = [plan.connect_map[rows] @ y + plan.input_map[rows] @ u_ext for rows in plan.input_rows]
        return y, inputs

    def rhs(self, t: float, x: np.ndarray, u_ext: np.ndarray | None = None, params: dict | None = None) -> np.ndarray:
        """State derivative of the whole loop at ``(t, x)``, each needed block output evaluated once.

        Parameters
        ----------
        t : float
            Time (s).
        x : numpy.ndarray
            Loop state, shape (nstates,).
        u_ext : numpy.ndarray, optional
            The interconnection's external inputs.
        params : dict, optional
            Call-time parameters (see the class docstring).
        """
        plan = self._plan_for(params)
        if plan.direct and u_ext is not None and np.size(u_ext):
            raise ValueError("this interconnection has no external inputs; u_ext must be empty")
        y, inputs = self._signals(plan, t, x, u_ext, plan.rhs_steps)
        dx = np.empty(plan.nstates)
        if plan.direct:
            for s in plan.updates:
                dx[s.x] = _rows(s.update(t, x[s.x], y[s.gather], *s.update_args))
            return dx
        by_name = {s.name: u for s, u in zip(plan.steps, inputs)}
        for s in plan.updates:
            dx[s.x] = _rows(s.update(t, x[s.x], by_name[s.name], *s.update_args))
        return dx

    def output(self, t: float, x: np.ndarray, u_ext: np.ndarray | None = None, params: dict | None = None) -> np.ndarray:
        """The interconnection's outputs (its ``outlist``) at ``(t, x)``."""
        plan = self._plan_for(params)
        y, inputs = self._signals(plan, t, x, u_ext, plan.steps)
        if plan.direct:
            return y[plan.out_index]
        order = np.argsort([r.start for r in plan.input_rows])      # the interconnection's input order
        u_all = np.concatenate([inputs[i] for i in order]) if inputs else np.zeros(0)
        return plan.output_map @ np.concatenate([y, u_all])

    # -- a time grid ----------------------------------------------------------------------------------
    def outputs_on_grid(self, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The interconnection's outputs at many times: ``t`` (T,) s, states ``X`` (nstates, T) -> (noutputs, T).

        Blocks that take column-stacked signals are evaluated once over the
        whole grid; the others one point at a time, in the same order.  The
        values agree with :meth:`output` to rounding.
        """
        t = np.asarray(t, dtype=float)
        X = np.asarray(X, dtype=float)
        if X.shape != (self.nstates, t.size):
            raise ValueError(f"states must have shape ({self.nstates}, {t.size}) for {t.size} times, got {X.shape}")
        plan = self.plan
        if not plan.direct:
            return np.column_stack([self.output(tk, X[:, k]) for k, tk in enumerate(t)]) if t.size else \
                np.empty((self.system.noutputs, 0))
        Y = np.zeros((plan.nsignals, t.size))

        def one_pass(Y):
            for s in plan.steps:
                if s.column_output is not None:
                    Y[s.y] = s.column_output(t, X[s.x], Y[s.gather], *s.column_args)
                else:
                    U = Y[s.gather]
                    for k in range(t.size):
                        Y[s.y, k] = _rows(s.output(t[k], X[s.x, k], U[:, k], *s.output_args))
        return settle(plan, one_pass, Y)[plan.out_index]
