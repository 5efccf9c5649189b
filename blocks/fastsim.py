"""Fast evaluation of a python-control interconnection as one right-hand side.

:func:`control.input_output_response` evaluates an
:class:`~control.InterconnectedSystem` by iterating every block's output
function until the internal signals stop changing (python-control 0.10 runs
the loop up to ``len(syslist) + 1`` times per call).  For a loop without an
algebraic cycle one pass in dependency order suffices.  :class:`CompiledLoop`
derives that order once from the interconnected system itself -- its
``syslist``, ``connect_map``, ``input_map`` and ``output_map`` -- and then
evaluates each block's output at most once per right-hand-side call.  Nothing
about the loop is written a second time: the blocks' own update and output
functions are called.

When every connection selects one signal with gain 1 and the outputs only
select signals (true of every loop :func:`blocks.closed_loop` builds),
the order becomes a plan of direct calls to the blocks' ``outfcn``/``updfcn``
with index gathers, skipping python-control's per-call wrappers; other
interconnections take the general path with the connection matrices.

Which inputs of a block reach its outputs directly is read from the block's
``feedthrough`` attribute (a set of input names) when it has one; a block
without it is assumed to feed every input through, which is always safe but
may report an algebraic loop that is not there.  The declaration is trusted,
not checked: a block that declares too little would be evaluated before an
input it reads is current (the blocks of :mod:`blocks.systems` are
tested against python-control's own evaluation, an FMU's come from its model
description).

A block may declare in ``state_outputs`` (output name -> state name) outputs
that are copies of its states, as the plant does for ``q[i]``, ``dq[i]``.
A right-hand side needs only the signals that feed some block input; when all
of a block's fed signals are such copies, the right-hand side reads them from
the state and does not call the block's output function at all (the plant's
``tau_dis`` output feeds nothing, so the disturbance is evaluated once, in the
plant's update).  The declaration is checked against the output function at a
test point when the plan is made.

After the solver, the loop's outputs on the time grid are needed.  When every
block declares ``columnwise = True`` (its output function accepts
column-stacked signals, see :mod:`blocks.systems`),
:meth:`CompiledLoop.outputs_on_grid` runs the same plan once with (n, T)
arrays; otherwise it evaluates one grid point at a time.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CompiledLoop", "AlgebraicLoopError"]


class AlgebraicLoopError(RuntimeError):
    """The interconnection has a cycle of direct feedthrough and cannot be ordered."""


@dataclass(frozen=True)
class _Plan:
    """Direct calls in evaluation order: each step ``(fn, params, state slice, input gather, output slice)``."""

    outputs: list            # every block's output, for the loop's outputs
    rhs_outputs: list        # only the blocks a right-hand side needs (see CompiledLoop._direct_plan)
    rhs_order: tuple         # their names
    copy_y: object           # signals read straight from the state in a right-hand side ...
    copy_x: object           # ... and the states they copy (index arrays or slices)
    updates: list            # (fn, params, state slice, input gather) of the blocks with states
    out_index: np.ndarray    # the interconnection's outputs among the signals


def _index_or_slice(idx: np.ndarray):
    """A slice when ``idx`` is a run of consecutive indices (a view instead of a copy), else ``idx``."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


class CompiledLoop:
    """An interconnected system evaluated in a fixed, precomputed block order.

    Parameters
    ----------
    system : control.InterconnectedSystem
        The interconnection (for example from :func:`blocks.closed_loop`).

    Attributes
    ----------
    order : list of str
        Names of the blocks in evaluation order.
    rhs_order : list of str
        The blocks whose output functions a right-hand side calls, in order
        (the others' fed signals are copies of states, read from ``x``).
    """

    def __init__(self, system) -> None:
        self.system = system
        blocks = list(system.syslist)
        self._blocks = blocks
        n_out_total = sum(b.noutputs for b in blocks)
        x_off = np.cumsum([0] + [b.nstates for b in blocks])
        u_off = np.cumsum([0] + [b.ninputs for b in blocks])
        y_off = np.cumsum([0] + [b.noutputs for b in blocks])
        self._slices = [(slice(x_off[k], x_off[k + 1]), slice(u_off[k], u_off[k + 1]),
                         slice(y_off[k], y_off[k + 1])) for k in range(len(blocks))]
        C = np.asarray(system.connect_map, dtype=float)
        B = np.asarray(system.input_map, dtype=float)
        self._n_out_total = n_out_total
        self._output_map = np.asarray(system.output_map, dtype=float)
        self._gather = [self._make_gather(C[us, :], B[us, :]) for _, us, _ in self._slices]
        self._order = self._topological_order(C, u_off, y_off)
        self.order = [blocks[k].name for k in self._order]
        self._stateful = [k for k in range(len(blocks)) if blocks[k].nstates > 0]
        self.nstates = int(x_off[-1])
        self._plan = self._direct_plan(C, B, np.asarray(system.output_map, dtype=float))
        self.rhs_order = list(self._plan.rhs_order) if self._plan is not None else list(self.order)

    def _direct_plan(self, C, B, O):
        """Direct-call plan, or None when some connection is more than a selection of one signal."""
        n_y = self._n_out_total
        selects = (np.all(np.count_nonzero(C, axis=1) == 1) and np.all(C[C != 0] == 1) and not B.any()
                   and np.all(np.count_nonzero(O, axis=1) == 1) and np.all(O[O != 0] == 1) and not O[:, n_y:].any())
        if not selects:
            return None
        source = np.argmax(C != 0, axis=1)      # the block output feeding each block input
        blocks = self._blocks
        gather = [_index_or_slice(source[self._slices[k][1]]) for k in range(len(blocks))]
        outputs = [(blocks[k].outfcn, blocks[k]._current_params, self._slices[k][0], gather[k], self._slices[k][2])
                   for k in self._order]
        # In a right-hand side only the outputs that feed some block input matter.  A block whose fed
        # outputs are all copies of its states is not called there: those signals are read from x.
        fed = set(source.tolist())
        rhs_outputs, rhs_order, copy_y, copy_x = [], [], [], []
        for k, step in zip(self._order, outputs):
            pairs = self._state_output_pairs(k)
            fed_here = [j for j in range(self._slices[k][2].start, self._slices[k][2].stop) if j in fed]
            if all(j in pairs for j in fed_here):
                copy_y += fed_here
                copy_x += [pairs[j] for j in fed_here]
            else:
                rhs_outputs.append(step)
                rhs_order.append(blocks[k].name)
        updates = [(blocks[k].updfcn, blocks[k]._current_params, self._slices[k][0], gather[k])
                   for k in self._stateful]
        return _Plan(outputs, rhs_outputs, tuple(rhs_order), _index_or_slice(np.array(copy_y, dtype=int)),
                     _index_or_slice(np.array(copy_x, dtype=int)), updates, np.argmax(O != 0, axis=1))

    def _state_output_pairs(self, k: int) -> dict[int, int]:
        """``{signal index: state index}`` for the outputs block ``k`` declares equal to its states.

        Read from the block's ``state_outputs`` attribute (output name -> state
        name) and checked once against its output function at a test point.
        """
        block = self._blocks[k]
        declared = getattr(block, "state_outputs", None)
        if not declared:
            return {}
        xs, _, ys = self._slices[k]
        outs, states = list(block.output_labels), list(block.state_labels)
        try:
            rel = {outs.index(o): states.index(x) for o, x in declared.items()}
        except ValueError:
            raise ValueError(f"block '{block.name}': state_outputs {dict(declared)} names a signal it does not "
                             f"have (outputs {outs}, states {states})") from None
        x_test = 0.1 * np.arange(1, block.nstates + 1)
        y_test = np.asarray(block.outfcn(0.0, x_test, np.zeros(block.ninputs), block._current_params), dtype=float)
        if any(y_test[o] != x_test[x] for o, x in rel.items()):
            raise ValueError(f"block '{block.name}': its output function does not return the states its "
                             f"state_outputs {dict(declared)} declare")
        return {ys.start + o: xs.start + x for o, x in rel.items()}

    def _planned_signals(self, t, x) -> np.ndarray:
        # x is (nstates,) with a scalar t, or (nstates, T) with t of shape (T,) for a grid pass
        y = np.empty((self._n_out_total,) + x.shape[1:])
        one_point = x.ndim == 1
        for fn, params, xs, idx, ys in self._plan.outputs:
            out = fn(t, x[xs], y[idx], params)
            y[ys] = out if not one_point or getattr(out, "ndim", 0) == 1 else np.ravel(out)
        return y

    @staticmethod
    def _make_gather(C_rows: np.ndarray, B_rows: np.ndarray):
        """Return ``f(y, u) -> block input``; pure index selection when every input is one signal with gain 1."""
        one_source = (np.count_nonzero(C_rows, axis=1) + np.count_nonzero(B_rows, axis=1)) == 1
        simple = one_source.all() and np.all(C_rows[C_rows != 0] == 1) and not B_rows.any()
        if simple:
            idx = np.argmax(C_rows != 0, axis=1)
            return lambda y, u: y[idx]
        if not B_rows.any():
            return lambda y, u: C_rows @ y
        return lambda y, u: C_rows @ y + B_rows @ u

    def _topological_order(self, C, u_off, y_off) -> list[int]:
        blocks = self._blocks
        deps = []
        for k, block in enumerate(blocks):
            through = getattr(block, "feedthrough", None)
            labels = block.input_labels
            rows = [u_off[k] + j for j, lab in enumerate(labels) if through is None or lab in through]
            sources = set()
            for row in rows:
                for m in range(len(blocks)):
                    if np.any(C[row, y_off[m]:y_off[m + 1]] != 0):
                        sources.add(m)
            deps.append(sources)
        order, done, visiting = [], set(), set()

        def visit(k, path):
            if k in done:
                return
            if k in visiting:
                cycle = " -> ".join(blocks[m].name for m in path[path.index(k):] + [k])
                raise AlgebraicLoopError(f"algebraic loop through blocks {cycle}: no evaluation order exists")
            visiting.add(k)
            for m in sorted(deps[k]):
                visit(m, path + [k])
            visiting.discard(k)
            done.add(k)
            order.append(k)

        for k in range(len(blocks)):
            visit(k, [])
        return order

    def signals(self, t: float, x: np.ndarray, u_ext: np.ndarray | None = None):
        """All block inputs and outputs at ``(t, x)``: ``(u_all, y_all)`` in the interconnect's layout."""
        u_ext = np.zeros(0) if u_ext is None else u_ext
        y = np.zeros(self._n_out_total)
        for k in self._order:
            xs, _, ys = self._slices[k]
            y[ys] = self._blocks[k]._out(t, x[xs], self._gather[k](y, u_ext))
        # Inputs of blocks without feedthrough were gathered before their sources ran: gather all again.
        u_all = [gather(y, u_ext) for gather in self._gather]
        return u_all, y

    def rhs(self, t: float, x: np.ndarray, u_ext: np.ndarray | None = None) -> np.ndarray:
        """State derivative of the whole loop, each block output evaluated once."""
        plan = self._plan
        if plan is not None and u_ext is None:
            y = np.empty(self._n_out_total)
            y[plan.copy_y] = x[plan.copy_x]
            for fn, params, xs, idx, ys in plan.rhs_outputs:
                out = fn(t, x[xs], y[idx], params)
                y[ys] = out if getattr(out, "ndim", 0) == 1 else np.ravel(out)
            # every fed signal is current now, so each update gathers its inputs once (signals that
            # feed no block, like the plant's tau_dis, are left unset in this buffer and never read)
            dx = np.empty(self.nstates)
            for fn, params, xs, idx in plan.updates:
                dx_block = fn(t, x[xs], y[idx], params)
                # (n, 1) arrays and lists are accepted, as python-control accepts them
                dx[xs] = dx_block if getattr(dx_block, "ndim", 0) == 1 else np.ravel(dx_block)
            return dx
        u_all, _ = self.signals(t, x, u_ext)
        dx = np.empty(self.nstates)
        for k in self._stateful:
            xs = self._slices[k][0]
            dx[xs] = self._blocks[k]._rhs(t, x[xs], u_all[k])
        return dx

    def output(self, t: float, x: np.ndarray, u_ext: np.ndarray | None = None) -> np.ndarray:
        """The interconnection's outputs (its ``outlist``) at ``(t, x)``."""
        if self._plan is not None and u_ext is None:
            return self._planned_signals(t, x)[self._plan.out_index]
        u_all, y = self.signals(t, x, u_ext)
        u_flat = np.concatenate([u for u in u_all]) if u_all else np.zeros(0)
        return self._output_map @ np.concatenate([y, u_flat])

    @property
    def columnwise(self) -> bool:
        """Whether :meth:`outputs_on_grid` evaluates the grid in one pass per block."""
        return self._plan is not None and all(getattr(b, "columnwise", False) for b in self._blocks)

    def outputs_on_grid(self, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The interconnection's outputs at many times: ``t`` (T,) s, states ``X`` (nstates, T) -> (noutputs, T).

        One pass per block over the whole grid when :attr:`columnwise`, else one
        :meth:`output` call per time point; the values agree to rounding.
        """
        t = np.asarray(t, dtype=float)
        X = np.asarray(X, dtype=float)
        if X.shape != (self.nstates, t.size):
            raise ValueError(f"states must have shape ({self.nstates}, {t.size}) for {t.size} times, got {X.shape}")
        if self.columnwise:
            return self._planned_signals(t, X)[self._plan.out_index]
        out = np.empty((self.system.noutputs, t.size))
        for k, tk in enumerate(t):
            out[:, k] = self.output(tk, X[:, k])
        return out
