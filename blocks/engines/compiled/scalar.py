"""A loop's generated functions run by CPython on Python floats: the ``fast`` engine's right-hand side.

The functions :func:`blocks.engines.compiled.codegen.loop_program` writes are plain
Python.  Here they are executed as they are, with ``np`` bound to
:data:`SCALAR_MATH` -- scalar functions with numpy's results -- and the
called kernels (the laceration path, a noise table) bound to their numpy
versions: a right-hand-side call is then a few hundred float operations
with no array temporaries, no gathers and no function call per block.  The
numbers are the numpy kernels' to the last bit: the traced statements are
the kernels' own operations in their order, ``math.sin``/``math.cos``/
``math.sqrt``/``math.atan2`` round as numpy's do, and ``tanh``/``exp`` are
numpy's.

Where Python's float arithmetic and numpy's part ways -- a division by zero
or a domain error raise in Python and give inf or nan in numpy -- the call
is repeated by the numpy plan (:class:`blocks.engines.fastsim.CompiledLoop`), so
a diverging run diverges as it does there.

numba is not needed: this is the engine the toolkit runs without the
extra ``dobkit[fast]``.
"""
from __future__ import annotations

import math
import types
from collections.abc import Callable

import numpy as np

from blocks.engines.compiled.codegen import CompiledUnavailable, LoopProgram, program_for
from blocks.engines.compiled.fold import fold_single_use
from blocks.engines.compiled.rows import loop_rows_of

__all__ = ["SCALAR_MATH", "scalar_rhs", "ScalarFunctions"]


def _sign(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return v * 0.0 if v == v else v          # +-0 keeps its sign, nan stays nan, as numpy.sign


def _maximum(a, b):
    return a if (a >= b or a != a) else b      # nan wins, as numpy.maximum


def _minimum(a, b):
    return a if (a <= b or a != a) else b


def _floor(v):
    return float(math.floor(v))


def _numpy_scalar(fn):
    def scalar(v):
        return float(fn(v))
    scalar.__name__ = fn.__name__
    return scalar


#: The ``np.<name>`` functions the generated code calls, for Python floats.
SCALAR_MATH = types.SimpleNamespace(
    cos=math.cos, sin=math.sin, tan=math.tan, sqrt=math.sqrt, arctan2=math.atan2, abs=abs,
    tanh=_numpy_scalar(np.tanh), exp=_numpy_scalar(np.exp), sign=_sign, floor=_floor,
    maximum=_maximum, minimum=_minimum, nan=math.nan, inf=math.inf)


def _called(fn):
    """A kernel as the generated code calls it: states as an array, rows back as Python floats."""
    def call(t, x, u, *params):
        if isinstance(x, list):
            x = np.array(x, dtype=float)
        out = fn(t, x, u, *params)
        return out.tolist() if isinstance(out, np.ndarray) else out
    return call


#: The generated functions a run calls at every step, folded for CPython (:mod:`blocks.engines.compiled.fold`).
_FOLDED = ("loop_sources", "loop_rhs", "loop_outputs")


class ScalarFunctions:
    """The generated functions of one program, executed by Python (once per loop structure and process)."""

    _made: dict[int, ScalarFunctions] = {}

    def __init__(self, program: LoopProgram) -> None:
        namespace = {"np": SCALAR_MATH, "__name__": "dobkit_scalar_loop", "NO_ARRAY": np.empty(0)}
        namespace.update({name: _called(fn) for name, fn in program.kernels.items()})
        #: the chain row kernels the functions call as pinocchio's algorithms (by name in the module)
        bound = {name: fast for name, fast in ((name, _bound_callee(callee)) for name, callee in
                                               program.callees.items()) if fast is not None}
        self.pinocchio_calls = list(bound)
        # the per-call functions (and the callees run as generated) with their single-use temporaries folded:
        # the same floats, fewer statements
        unbound = [name for name in program.callees if name not in bound]
        source = fold_single_use(program.source, _FOLDED + tuple(unbound))
        exec(compile(source, "<dobkit generated loop>", "exec"), namespace)
        namespace.update(bound)
        self.sources, self.rhs = namespace["loop_sources"], namespace["loop_rhs"]
        self.outputs = namespace["loop_outputs"]
        self.program = program

    @classmethod
    def of(cls, program: LoopProgram) -> ScalarFunctions:
        found = cls._made.get(id(program))
        if found is None or found.program is not program:
            found = cls._made[id(program)] = cls(program)
        return found


def _bound_callee(callee):
    """pinocchio's function for a chain row kernel recorded as a call (:mod:`blocks.model.urdf.pin_kernels`), or None."""
    if getattr(callee, "kernel", None) is None:
        return None
    from blocks.model.urdf.pin_kernels import binding
    return binding(callee)


def _chain_arm(system) -> bool:
    """Whether a block of the loop carries a chain arm's numbers (a URDF arm: :mod:`blocks.kernels.chain`)."""
    from blocks.diagram.contract import contract_of
    from blocks.diagram.control_compat import subsystems
    from blocks.kernels.chain import ChainParams

    def has_chain(value) -> bool:
        if isinstance(value, ChainParams):
            return True
        return isinstance(value, tuple) and any(has_chain(v) for v in value)

    for block in subsystems(system):
        kernels = contract_of(block).kernels
        if kernels is not None and has_chain(kernels.params):
            return True
    return False


def _calls_for(plan, system):
    """What the fast engine's trace calls: every chain row kernel when the loop has a chain arm and pinocchio is
    installed (bound to pinocchio's algorithms), else what the compiled engine's trace calls (its program)."""
    return _calls(_chain_arm(system))


def _calls(chain_arm: bool):
    from blocks.kernels.chain import KERNEL_CALLS

    if chain_arm:
        try:
            import pinocchio  # noqa: F401
        except ImportError:
            return None
        return KERNEL_CALLS
    return None


def scalar_rhs(plan, system, fallback: Callable) -> Callable | None:
    """``f(t, x) -> dx`` running the loop's generated right-hand side on floats, or None when it cannot.

    Parameters
    ----------
    plan : LoopPlan
        The loop's plan.
    system : control.InterconnectedSystem
        The loop.
    fallback : callable
        ``fallback(t, x)``: the numpy plan's right-hand side, for a call on
        which float arithmetic raises (see the module docstring).

    Returns None when a block has no kernels or the plan is not direct
    (:class:`~blocks.engines.compiled.CompiledUnavailable`).
    """
    chain_arm = _chain_arm(system)
    if chain_arm:
        # a chain arm's loop through C when a compiler builds it: the same floats as the text below with the
        # arm's M and h generated, about a tenth of its time (blocks.engines.compiled.c_loop)
        from blocks.engines.compiled.c_loop import c_rhs
        found = c_rhs(plan, system)
        if found is not None:
            return found
    try:
        program, kernels = program_for(plan, system, loop_rows_of(system), _calls(chain_arm))
    except CompiledUnavailable:
        return None
    fns = ScalarFunctions.of(program)
    theta_array, ext = program.numbers(kernels)
    theta = tuple(theta_array.tolist())
    loop_sources, loop_rhs = fns.sources, fns.rhs
    work = np.zeros(program.n_work)
    src = [0.0] * program.n_src
    n = plan.nstates
    array = np.array

    def rhs(t, x):
        t = float(t)
        dx = [0.0] * n
        try:
            loop_sources(t, theta, ext, work, src)
            loop_rhs(t, x.tolist(), theta, src, ext, work, dx)
        except (ArithmeticError, ValueError):
            return fallback(t, x)
        return array(dx)

    return rhs
