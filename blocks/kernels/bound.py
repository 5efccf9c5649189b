"""A block's maths as kernel functions with bound parameters (:class:`Kernels`).

In the kernels layer, apart from :mod:`blocks.diagram.contract`, because it needs neither python-control nor scipy:
a reference path (an arm model's laceration path) or a scenario holds one without importing them (the command line
checks a scenario before those load).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from blocks.kernels import column_params

__all__ = ["Kernels"]


@dataclass(frozen=True)
class Kernels:
    """A block's maths as kernel functions with bound parameters.

    Parameters
    ----------
    params : tuple
        Extra arguments of both functions, in the one-point layout of
        :mod:`blocks.kernels` (arrays, numbers, named tuples of them).
    output : callable, optional
        ``output(t, x, u, *params) -> y``: outputs as rows.
    update : callable, optional
        ``update(t, x, u, *params) -> dx``: state derivative as rows.
    column_params : tuple, optional
        The parameters for column signals, when :func:`blocks.kernels.column_params`
        (a trailing axis of length 1 on every array) is not right for them
        (a lookup table, say, indexed by time rather than broadcast).

    Both take one point (``x`` of shape (nstates,), ``u`` (ninputs,), ``t``
    a float) or columns (``(nstates, K)``, ``(ninputs, K)``, ``t`` a float or
    ``(K,)``) with the parameters of :meth:`columns`.
    """

    params: tuple
    output: Callable | None = None
    update: Callable | None = None
    column_params: tuple | None = None

    def columns(self) -> tuple:
        """The parameters ready for column signals (shared by every column)."""
        return column_params(self.params) if self.column_params is None else self.column_params
