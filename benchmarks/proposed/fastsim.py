"""Proposed replacement for ``dobkit.blocks.fastsim.CompiledLoop`` (same API, same numbers, less overhead).

Not part of the package: ``benchmarks/bench_fastpath.py --proposed`` times it
in place of the current class.  What it changes, and why:

1. **An evaluation plan with direct calls.**  The order is derived once from
   the interconnected system (``connect_map``, ``output_map`` and each block's
   ``feedthrough``, exactly as now), then turned into a list of
   ``(output function, parameters, state slice, input indices, output slice)``.
   A right-hand-side call walks that list and calls each block's ``outfcn`` /
   ``updfcn`` directly, skipping ``NonlinearIOSystem._out`` / ``_rhs`` and the
   per-call gather closures.
2. **Fewer gathers.**  The current ``signals`` gathers every block's inputs
   twice per call (once before the block runs, once more for all blocks
   afterwards) through closures.  Here a block's inputs are one fancy index
   into the signal vector when it runs, and once more only for blocks with
   states, after all outputs are current (the observer's ``tau`` comes from
   the controller, which runs after it).
3. **Outputs by index.**  When the interconnection's ``output_map`` only
   selects signals (true for every loop :func:`dobkit.blocks.closed_loop`
   builds) the outputs are an index into the signal vector rather than a dense
   product over all block outputs and inputs.

Every step still calls the blocks' own functions: nothing about the loop is
written a second time.  Anything the plan does not cover (a gain other than 1
in a connection, external inputs) falls back to the current class.
"""
from __future__ import annotations

import numpy as np

from dobkit.blocks.fastsim import CompiledLoop

__all__ = ["PlannedLoop"]


class PlannedLoop(CompiledLoop):
    """:class:`~dobkit.blocks.fastsim.CompiledLoop` evaluated through a precomputed plan of direct calls."""

    def __init__(self, system) -> None:
        super().__init__(system)
        C = np.asarray(system.connect_map, dtype=float)
        B = np.asarray(system.input_map, dtype=float)
        O = np.asarray(system.output_map, dtype=float)
        blocks = self._blocks
        n_y = self._n_out_total
        one_source = np.count_nonzero(C, axis=1) == 1
        self._planned = bool(one_source.all() and np.all(C[C != 0] == 1) and not B.any()
                             and np.all(np.count_nonzero(O, axis=1) == 1) and np.all(O[O != 0] == 1)
                             and not O[:, n_y:].any())
        if not self._planned:
            return
        source = np.argmax(C != 0, axis=1)             # the one block output feeding each block input
        self._plan = [(blocks[k].outfcn, blocks[k]._current_params, self._slices[k][0],
                       source[self._slices[k][1]], self._slices[k][2]) for k in self._order]
        self._update = [(blocks[k].updfcn, blocks[k]._current_params, self._slices[k][0],
                         source[self._slices[k][1]]) for k in self._stateful]
        self._out_idx = np.argmax(O != 0, axis=1)
        self._y = np.zeros(n_y)

    def rhs(self, t, x, u_ext=None):
        if not self._planned:
            return super().rhs(t, x, u_ext)
        y = self._y
        for fn, params, xs, idx, ys in self._plan:
            y[ys] = fn(t, x[xs], y[idx], params)
        # every output is current now: one gather per update
        return np.concatenate([fn(t, x[xs], y[idx], params) for fn, params, xs, idx in self._update])

    def output(self, t, x, u_ext=None):
        if not self._planned:
            return super().output(t, x, u_ext)
        y = self._y
        for fn, params, xs, idx, ys in self._plan:
            y[ys] = fn(t, x[xs], y[idx], params)
        return y[self._out_idx].copy()
