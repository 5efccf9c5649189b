"""A chain arm's row kernels traced into straight-line code, and that code compiled on its own.

The compiled engine traces a loop's blocks (:mod:`blocks.engines.compiled.codegen`);
until the arm is wired into the plant block this module traces one kernel of
an arm alone -- ``plant_acceleration(k, q, dq, f)``, ``inertia_matrix``,
``bias_forces`` -- with the same machinery (:mod:`blocks.kernels.trace`
and codegen's statement emitter), so the generated code can be counted,
read, and compiled by numba or run as plain Python.  The geometry is a
:class:`~blocks.kernels.trace.Frozen` parameter: it appears as literals.
"""
from __future__ import annotations

import numpy as np

from blocks.engines.compiled.codegen import _Function
from blocks.kernels.trace import Graph, Sym

__all__ = ["TracedKernel", "trace_rows"]


class TracedKernel:
    """The straight-line code of one row kernel: ``fn(x, out)`` with its inputs in ``x`` and rows in ``out``.

    Attributes
    ----------
    source : str
        The generated function's text.
    n_inputs, n_outputs : int
        Lengths of ``x`` and ``out``.
    nodes : int
        Expressions in the trace (graph nodes, leaves and constants included).
    statements : int
        Assignments in the generated code (the arithmetic it does, one operation each).
    """

    def __init__(self, source: str, n_inputs: int, n_outputs: int, nodes: int, statements: int) -> None:
        self.source, self.n_inputs, self.n_outputs = source, n_inputs, n_outputs
        self.nodes, self.statements = nodes, statements

    def python(self):
        """The function as plain Python (numpy scalars)."""
        namespace = {"np": np}
        exec(compile(self.source, "<traced kernel>", "exec"), namespace)
        return namespace["traced_kernel"]

    def numba(self):
        """The function compiled by numba (``nopython``, ``fastmath`` off so it rounds as the kernel does)."""
        import numba

        return numba.njit(cache=False)(self.python())


def trace_rows(kernel, k, *sizes: int) -> TracedKernel:
    """Trace ``kernel(k, *rows)`` with each row a vector of ``sizes[i]`` symbols read from ``x``.

    Parameters
    ----------
    kernel : callable
        A row kernel such as :func:`blocks.kernels.chain.plant_acceleration`.
    k : ChainParams
        The arm's parameters (frozen: constants in the code).
    *sizes : int
        Length of each row argument (``n`` for ``q``, ``dq``, ``f``).

    Examples
    --------
    >>> from blocks.model.urdf import example_arm
    >>> from blocks.kernels import chain
    >>> arm = example_arm("scope4")
    >>> traced = trace_rows(chain.plant_acceleration, arm.kernel_params(), arm.n, arm.n, arm.n)
    >>> traced.n_inputs, traced.n_outputs
    (12, 4)
    """
    graph = Graph()
    rows, offset = [], 0
    for size in sizes:
        row = np.empty(size, dtype=object)
        for i in range(size):
            row[i] = graph.leaf("x", offset + i)
        rows.append(row)
        offset += size
    result = np.asarray(kernel(k, *rows), dtype=object).ravel()
    fn = _Function(None, "traced_kernel", "x, out")
    for i, v in enumerate(result):
        fn.assign(f"out[{i}]", v if isinstance(v, Sym) else float(v))
    statements = sum(1 for line in fn.lines if not line.startswith("out["))
    return TracedKernel(fn.text(), offset, len(result), len(graph.nodes), statements)
