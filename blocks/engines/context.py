"""A run's numbers, apart from its diagram: start time and state, parameters, bounds, budget, members.

A diagram (the Figure-2 loop, or any interconnection a user wires) is built
once; what one run of it needs besides is a :class:`Context`.  The engines
take their bounds from here, never from block names: the Figure-2 layer
fills them from the scenario (:func:`blocks.figure2.physical_bounds.state_bounds`), a
user's diagram from what the user gives (by default only non-finite states
stop a run, as in python-control).

A batch is one diagram and one context with ``members`` rows: ``x0`` then
has shape (nstates, N), every array in ``params`` a leading axis of N (one
row per member) and the bounds a column per member; :meth:`Context.member`
gives one member's context.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from blocks.engines.budget import Budget
from blocks.engines.divergence import StateBounds

__all__ = ["Context", "finite_bounds", "kernels_with_params"]


def finite_bounds(labels) -> StateBounds:
    """Bounds that stop a run only at a non-finite state (no physical bound, no growth rule), named ``labels``."""
    n = len(labels)
    return StateBounds(np.full(n, np.inf), list(labels), [""] * n, ["finite"] * n)


@dataclass(frozen=True)
class Context:
    """The numbers of one run (or of a batch's members) of a diagram.

    Parameters
    ----------
    t0 : float
        Start time (s).
    x0 : numpy.ndarray
        Start state, (nstates,), or (nstates, N) with ``members``.
    params : mapping of str to tuple, optional
        Each block's kernel parameters by block name (the layout of
        :class:`blocks.diagram.contract.Kernels`); None: the blocks' own.  With
        ``members`` an array may carry a leading axis of N, one row per member.
        A single run reads them in :func:`blocks.engines.simulator.advance`
        (the numpy and the compiled engine, :func:`kernels_with_params`): the
        same diagram runs with other numbers of the same structure.
    bounds : StateBounds, optional
        The largest magnitude of every state (one column per member for a
        batch); None: the physical bounds are unknown, the growth rule of
        :meth:`StateBounds.with_growth` applies.
    growth : bool
        Whether states without a finite bound are judged by growth
        (the Figure-2 loop) or only by being finite (a user's diagram).
    budget : Budget, optional
        Steps, memory and wall time the run may take (default :meth:`Budget.from_env`).
    members : int, optional
        The member count of a batch (None: one run).
    """

    t0: float
    x0: np.ndarray
    params: Mapping | None = None
    bounds: StateBounds | None = None
    growth: bool = True
    budget: Budget | None = None
    members: int | None = None
    labels: tuple = field(default=(), compare=False)

    def __post_init__(self) -> None:
        x0 = np.asarray(self.x0, dtype=float)
        if self.members is None and x0.ndim != 1:
            raise ValueError(f"context x0 must have shape (nstates,) for one run, got {x0.shape}")
        if self.members is not None:
            if not isinstance(self.members, int) or self.members < 1:
                raise ValueError(f"context members must be a positive integer, got {self.members!r}")
            if x0.ndim != 2 or x0.shape[1] != self.members:
                raise ValueError(f"context x0 must have shape (nstates, {self.members}) for {self.members} members, "
                                 f"got {x0.shape}")
        if not np.isfinite(self.t0):
            raise ValueError(f"context t0 must be a finite time (s), got {self.t0!r}")
        object.__setattr__(self, "x0", x0)

    @property
    def nstates(self) -> int:
        return int(self.x0.shape[0])

    def state_bounds(self) -> StateBounds:
        """The bounds a Monitor judges: the given ones, or finite-only ones when none are given."""
        if self.bounds is not None:
            return self.bounds
        labels = list(self.labels) or [f"state {k}" for k in range(self.nstates)]
        return finite_bounds(labels)

    def member(self, m: int) -> Context:
        """Member ``m``'s context: its column of ``x0`` and of the bounds, its row of every params array."""
        if self.members is None:
            raise ValueError("this context has no members")
        if not 0 <= m < self.members:
            raise IndexError(f"member {m} is outside 0..{self.members - 1}")
        params = None if self.params is None else {name: _row(p, m, self.members) for name, p in self.params.items()}
        bounds = None if self.bounds is None else self.bounds.member(m)
        return replace(self, x0=self.x0[:, m], params=params, bounds=bounds, members=None)


def kernels_with_params(kernels_by_block: Mapping, params: Mapping) -> dict:
    """The blocks' kernels with the numbers of ``params`` (a :attr:`Context.params`) in place of their own.

    Parameters
    ----------
    kernels_by_block : mapping of str to Kernels
        The diagram's blocks' kernels by block name.
    params : mapping of str to tuple
        New kernel parameters by block name, in the layout of each block's own (``Kernels.params``).

    Raises
    ------
    ValueError
        Naming the block, when ``params`` names a block without kernels in the diagram, holds a number that is not
        finite, or when its numbers have
        another structure than the block's own (another length, shape, a diagonal gain for a full one, a flag):
        the engine was made for that structure, so the diagram must be built with them.
    """
    from blocks.kernels.trace import param_structure, param_values
    out = dict(kernels_by_block)
    for name, new in params.items():
        kernels = out.get(name)
        if kernels is None:
            raise ValueError(f"Context.params names block {name!r}, which is not a block with kernels of this "
                             f"diagram (those are {sorted(kernels_by_block)})")
        new = tuple(new)
        if param_structure(new) != param_structure(tuple(kernels.params)):
            raise ValueError(f"Context.params[{name!r}] has another structure than block {name!r}'s own numbers "
                             f"({param_structure(new)} against {param_structure(tuple(kernels.params))}): the "
                             "engine was made for that structure; build the block with these numbers instead")
        numbers = np.asarray(param_values(new, []), dtype=float)
        if not np.all(np.isfinite(numbers)):
            raise ValueError(f"Context.params[{name!r}] holds {int(np.sum(~np.isfinite(numbers)))} number(s) that are "
                             "not finite (NaN or infinite): a block's numbers must be finite")
        if kernels.column_params is not None and kernels.column_params is not kernels.params:
            raise ValueError(f"Context.params[{name!r}]: block {name!r} keeps column parameters of its own, which "
                             "the context cannot follow; build the block with these numbers instead")
        out[name] = replace(kernels, params=new, column_params=None if kernels.column_params is None else new)
    return out


def _row(value, m: int, members: int):
    """Member ``m``'s value of a parameter: row ``m`` of an array with a leading member axis, else the value."""
    if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == members:
        return value[m]
    if isinstance(value, tuple):
        items = [_row(v, m, members) for v in value]
        return type(value)(*items) if hasattr(value, "_fields") else tuple(items)
    return value
