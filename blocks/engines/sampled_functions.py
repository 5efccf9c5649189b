"""A sampled diagram's tick and right-hand side as functions on lists of floats, for :mod:`blocks.engines.tick_stepper`.

The functions are the sampled program's (:func:`blocks.engines.compiled.codegen.sampled_program`, the compiled
sampled engine's text) run by CPython on Python floats, as :mod:`blocks.engines.compiled.scalar` runs the continuous
loop's: a tick and a right-hand side are a few hundred float operations, no array and no call per block.
A diagram the generator cannot take (a block without kernels, sampled blocks at several rates) gets the
diagram's plan with numpy (:meth:`blocks.engines.hybrid.HybridSystem.tick_outputs`,
:meth:`~blocks.engines.hybrid.HybridSystem.continuous_rhs`); a call whose float arithmetic raises (a division by
zero, an overflow) is repeated on the plan, so a diverging run diverges as it does there.
"""
from __future__ import annotations

import numpy as np

__all__ = ["SampledFunctions"]


# the generated functions' namespaces, by program (kept with the program, as blocks.engines.compiled.scalar does)
_made: dict[int, tuple] = {}


def _rint(v):
    return float(round(v))         # round half to even, as numpy.rint; inf and nan raise (the plan takes over)


class _FloatMath:
    """``np`` for the generated text: the scalar functions of :mod:`blocks.engines.compiled.scalar` and the encoder's rint."""

    def __init__(self) -> None:
        from blocks.engines.compiled.scalar import SCALAR_MATH
        self.__dict__.update(vars(SCALAR_MATH))
        self.rint = _rint


_float_math: list = []


def _math() -> _FloatMath:
    if not _float_math:
        _float_math.append(_FloatMath())
    return _float_math[0]


class SampledFunctions:
    """A diagram's tick and right-hand side on lists of floats: the generated functions, else the numpy plan.

    Parameters
    ----------
    hybrid : blocks.engines.hybrid.HybridSystem

    Attributes
    ----------
    generated : bool
        Whether they are the generated functions (else the plan with numpy).
    cont : list of int
        The continuous states (the others keep their value between ticks).
    tick : callable
        ``tick(k, t, x, held) -> (x, held)``: the blocks' outputs and the sampled blocks' updates at tick ``k``
        (time ``t``, s); ``held`` the held outputs of every block (lists of floats).
    rhs_full : callable
        ``rhs_full(t, x, held) -> dx``: the continuous states' derivative with the outputs ``held`` (all states).
    scatter, gather : callable
        ``scatter(x, values)``: ``x`` with its continuous states set to ``values``; ``gather(x)``: those states.
    """

    def __init__(self, hybrid) -> None:
        self.hybrid = hybrid
        plan = hybrid.plan
        self.n, self.nsignals = plan.nstates, plan.nsignals
        # the continuous states (the others keep their value between ticks: their derivative is zero)
        discrete = set(hybrid.multiples)
        cont = []
        for s in plan.updates:
            if s.name not in discrete:
                cont += list(range(s.x.start, s.x.stop))
        self.cont = sorted(cont)
        self.generated = False
        try:
            self._generated()
            self.generated = True
        except Exception as err:            # noqa: BLE001  any reason the generator gives: run the plan instead
            from blocks.engines.compiled.codegen import CompiledUnavailable
            from blocks.kernels.trace import TraceError
            if not isinstance(err, (CompiledUnavailable, TraceError)):
                raise
            self._planned()

    # -- the generated functions, on floats -----------------------------------------------------------------
    def _generated(self) -> None:
        from blocks.engines.compiled.codegen import sampled_program_for
        from blocks.engines.compiled.scalar import _called
        program, kernels = sampled_program_for(self.hybrid)
        found = _made.get(id(program))
        if found is None or found[0] is not program:
            namespace = {"np": _math(), "__name__": "dobkit_scalar_sampled", "NO_ARRAY": np.empty(0)}
            namespace.update({name: _called(fn) for name, fn in program.kernels.items()})
            exec(compile(program.source, "<dobkit generated sampled loop>", "exec"), namespace)
            found = _made[id(program)] = (program, namespace)
        ns = found[1]
        theta_array, ext = program.numbers(kernels)
        theta = tuple(theta_array.tolist())
        sources, tick, rhs = ns["loop_sources"], ns["sampled_tick"], ns["sampled_rhs"]
        src = [0.0] * program.n_src
        work = np.zeros(program.n_work)
        n, cont = self.n, self.cont
        plan_tick, plan_rhs = self._planned_functions()

        def tick_fn(k: int, t: float, x: list, held: list) -> tuple[list, list]:
            xn, new = x[:], held[:]
            try:
                sources(t, theta, ext, work, src)
                tick(t, x, theta, src, ext, work, held, new, xn)
            except (ArithmeticError, ValueError):
                return plan_tick(k, t, x, held)
            return xn, new

        def rhs_fn(t: float, x: list, held: list) -> list:
            dx = [0.0] * n
            try:
                rhs(t, x, theta, src, ext, work, held, dx)
            except (ArithmeticError, ValueError):
                return plan_rhs(t, x, held)
            return dx

        self.tick, self.rhs_full = tick_fn, rhs_fn
        self._bind_cont(cont)

    # -- the plan with numpy ----------------------------------------------------------------------------------
    def _planned_functions(self):
        hybrid = self.hybrid
        cache: dict = {}

        def tick_fn(k: int, t: float, x: list, held: list) -> tuple[list, list]:
            h = np.array(held, dtype=float)
            xa = np.array(x, dtype=float)
            y = hybrid.tick_outputs(k, xa, h)
            return hybrid.tick_updates(k, xa, y).tolist(), h.tolist()

        def rhs_fn(t: float, x: list, held: list) -> list:
            key = tuple(held)
            f = cache.get(key)
            if f is None:
                cache.clear()
                f = cache[key] = hybrid.continuous_rhs(np.array(held, dtype=float))
            return np.asarray(f(t, np.array(x, dtype=float)), dtype=float).tolist()

        return tick_fn, rhs_fn

    def _planned(self) -> None:
        self.tick, self.rhs_full = self._planned_functions()
        self._bind_cont(self.cont)

    def _bind_cont(self, cont: list) -> None:
        contiguous = cont == list(range(cont[0], cont[-1] + 1)) if cont else True
        a, b = (cont[0], cont[-1] + 1) if cont else (0, 0)

        if contiguous:
            def scatter(base: list, values: list) -> list:
                full = base[:]
                full[a:b] = values
                return full

            def gather(full: list) -> list:
                return full[a:b]
        else:
            def scatter(base: list, values: list) -> list:
                full = base[:]
                for i, v in zip(cont, values):
                    full[i] = v
                return full

            def gather(full: list) -> list:
                return [full[i] for i in cont]
        self.scatter, self.gather = scatter, gather
