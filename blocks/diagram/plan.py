"""The evaluation plan of an interconnection: which block to evaluate when, with which signals.

:func:`control.input_output_response` evaluates an
:class:`~control.InterconnectedSystem` by iterating every block's output
function until the internal signals stop changing.  For a loop without an
algebraic cycle one pass in dependency order suffices.  :func:`make_plan`
derives that order once, from the interconnection's connection maps (read
through :mod:`blocks.diagram.control_compat`) and each block's
:class:`~blocks.diagram.contract.BlockContract`, and records for every block the
functions to call, their arguments, the state slice and the input gather.

Engines execute a plan (:class:`blocks.engines.fastsim.CompiledLoop` with numpy);
nothing about the loop is written a second time: blocks with kernels are
called through them, other blocks through their python-control functions
with the parameters python-control would pass them.

A plan is *direct* when every block input is one signal with gain 1 and the
interconnection's outputs only select signals (true of every loop
:func:`blocks.closed_loop` builds); then a block's inputs are an index
gather from the signal vector.  Other interconnections keep their
connection matrices.

Plans are reused by structure: a loop whose blocks all carry kernels and
whose structure (:func:`blocks.diagram.structure.block_structure` of every block and
the connection matrices) equals one planned before in this process gets
that plan with its own blocks' kernels and parameters put in
(:data:`PLANS`, the latest :data:`PLANS_KEPT` structures).  The kept plans
hold no parameters, so a reused plan can only compute with the new loop's
numbers.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from blocks.diagram.contract import contract_of
from blocks.diagram.control_compat import connection_maps, merged_params, output_function, subsystems, update_function
from blocks.diagram.structure import StructureCache, blocks_structure

__all__ = ["AlgebraicLoopError", "BlockStep", "LoopPlan", "make_plan", "settle", "PLANS", "PLANS_KEPT"]

#: Plans kept for reuse: distinct loop structures, each its index arrays and connection matrices twice (in the plan
#: and in its key), about 0.18 MB for the Panda's loop, 60 kB for the paper's.
PLANS_KEPT = 32
#: The kept plans by loop structure, without parameters (see :func:`make_plan`).
PLANS = StructureCache(PLANS_KEPT)


class AlgebraicLoopError(RuntimeError):
    """The interconnection has a cycle of direct feedthrough and cannot be ordered (or does not settle).

    ``undeclared`` is True when a block in the cycle has no declared
    feedthrough: the cycle may not be real, and the plan then evaluates the
    blocks to a fixed point, as python-control does.
    """

    def __init__(self, message: str, undeclared: bool = False) -> None:
        super().__init__(message)
        self.undeclared = undeclared


@dataclass(frozen=True)
class BlockStep:
    """One block of a plan.

    Attributes
    ----------
    name : str
        Block name.
    x, y : slice
        The block's states in the loop state, and its outputs among all block outputs.
    gather : slice or numpy.ndarray
        Where its inputs are among all block outputs (direct plans only).
    output, output_args : callable, tuple
        ``output(t, x, u, *output_args)`` gives the block's outputs at one point.
    update, update_args : callable or None, tuple
        ``update(t, x, u, *update_args)`` gives its state derivative.
    column_output, column_args : callable or None, tuple
        The same for column-stacked signals, or None when the block takes one point at a time.
    kernel : bool
        Whether the functions are the block's kernels (else its python-control functions).
    """

    name: str
    x: slice
    y: slice
    gather: object
    output: object
    output_args: tuple
    update: object
    update_args: tuple
    column_output: object
    column_args: tuple
    kernel: bool


@dataclass(frozen=True)
class LoopPlan:
    """Blocks in evaluation order and what a right-hand side needs of them.

    Attributes
    ----------
    steps : tuple of BlockStep
        Every block, sources before the blocks they feed directly.
    rhs_steps : tuple of BlockStep
        The blocks whose outputs a right-hand side must evaluate (the
        others' fed signals are copies of states, read from the state).
    updates : tuple of BlockStep
        The blocks with states.
    copy_y, copy_x : slice or numpy.ndarray
        Signals read straight from the state in a right-hand side, and the states they copy.
    out_index : numpy.ndarray
        The interconnection's outputs among the signals (direct plans).
    direct : bool
        Whether every connection selects one signal with gain 1.
    nstates, nsignals : int
        Loop states and block outputs.
    connect_map, input_map, output_map : numpy.ndarray
        The interconnection's matrices (used by plans that are not direct).
    input_rows : tuple of slice
        Each block's rows of ``connect_map``, in ``steps`` order.
    fixed_point : bool
        The blocks could not be ordered because some declare no feedthrough:
        one pass over them is repeated until the signals stop changing
        (at most one pass per block and one more), as python-control does.
    """

    steps: tuple
    rhs_steps: tuple
    updates: tuple
    copy_y: object
    copy_x: object
    out_index: np.ndarray
    direct: bool
    nstates: int
    nsignals: int
    connect_map: np.ndarray
    input_map: np.ndarray
    output_map: np.ndarray
    input_rows: tuple
    fixed_point: bool = False

    @property
    def order(self) -> list[str]:
        """Block names in evaluation order."""
        return [s.name for s in self.steps]

    @property
    def rhs_order(self) -> list[str]:
        """Names of the blocks a right-hand side evaluates."""
        return [s.name for s in self.rhs_steps]

    @property
    def takes_columns(self) -> list[bool]:
        """For each step, whether it evaluates a grid of columns in one call."""
        return [s.column_output is not None for s in self.steps]


def _index_or_slice(idx: np.ndarray):
    """A slice when ``idx`` is a run of consecutive indices (a view instead of a copy), else ``idx``."""
    idx = np.asarray(idx, dtype=int)
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


def _offsets(blocks, attr: str) -> np.ndarray:
    return np.cumsum([0] + [getattr(b, attr) for b in blocks])


def _topological_order(blocks, C, u_off, y_off) -> list[int]:
    deps = []
    for k, block in enumerate(blocks):
        through = contract_of(block).feedthrough
        rows = [u_off[k] + j for j, label in enumerate(block.input_labels) if through is None or label in through]
        sources = {m for row in rows for m in range(len(blocks)) if np.any(C[row, y_off[m]:y_off[m + 1]] != 0)}
        deps.append(sources)
    order, done, visiting = [], set(), set()

    def visit(k, path):
        if k in done:
            return
        if k in visiting:
            members = path[path.index(k):] + [k]
            cycle = " -> ".join(blocks[m].name for m in members)
            undeclared = any(contract_of(blocks[m]).feedthrough is None for m in members)
            raise AlgebraicLoopError(f"algebraic loop through blocks {cycle}: no evaluation order exists",
                                     undeclared=undeclared)
        visiting.add(k)
        for m in sorted(deps[k]):
            visit(m, path + [k])
        visiting.discard(k)
        done.add(k)
        order.append(k)

    for k in range(len(blocks)):
        visit(k, [])
    return order


def _kernel_step(name: str, xs, ys, gather, kernels) -> BlockStep:
    """The step of a block with kernels: its kernels called with their own parameters."""
    return BlockStep(name, xs, ys, gather, kernels.output, kernels.params, kernels.update, kernels.params,
                     kernels.output, kernels.columns(), True)


def _step(system, block, xs, ys, gather, params) -> BlockStep:
    contract = contract_of(block)
    kernels = contract.kernels
    if kernels is not None:
        return _kernel_step(block.name, xs, ys, gather, kernels)
    local = (merged_params(system, block, params),)
    out_fn, upd_fn = output_function(block), update_function(block)
    if out_fn is None:          # python-control's default output is the state
        out_fn = _state_as_output
    return BlockStep(block.name, xs, ys, gather, out_fn, local, upd_fn, local,
                     out_fn if contract.columnwise else None, local, False)


def _state_as_output(t, x, u, params):
    return x


def _checked_state_copies(block, step: BlockStep) -> dict[int, int]:
    """``{signal index: state index}`` of the outputs the block's contract declares equal to its states.

    The declaration is checked once against the block's output function at a test point.
    """
    pairs = contract_of(block).state_outputs
    if not pairs:
        return {}
    outs, states = list(block.output_labels), list(block.state_labels)
    rel = {outs.index(o): states.index(x) for o, x in pairs}
    x_test = 0.1 * np.arange(1, block.nstates + 1)
    y_test = np.ravel(np.asarray(step.output(0.0, x_test, np.zeros(block.ninputs), *step.output_args), dtype=float))
    if any(y_test[o] != x_test[x] for o, x in rel.items()):
        raise ValueError(f"block '{block.name}': its output function does not return the states its "
                         f"contract's state_outputs {dict(pairs)} declare")
    return {step.y.start + o: step.x.start + x for o, x in rel.items()}


def make_plan(system, params: dict | None = None) -> LoopPlan:
    """The evaluation plan of ``system`` (a :class:`control.InterconnectedSystem`).

    When every block has kernels (and no python-control ``params``) and a
    loop of the same structure was planned before in this process, that plan is reused with this loop's
    kernels and parameters (see the module docstring); the plan is the one
    planning afresh would give.

    Parameters
    ----------
    system : control.InterconnectedSystem
        The interconnection.
    params : dict, optional
        Parameters given at call time; blocks without kernels receive them
        merged as python-control merges them (see
        :func:`blocks.diagram.control_compat.merged_params`).

    Raises
    ------
    AlgebraicLoopError
        If the blocks' declared feedthrough forms a cycle (a cycle through a
        block that declares none gives a fixed-point plan instead).
    ValueError
        If a block's declared state outputs are not its states.
    """
    blocks = subsystems(system)
    C, B, O = connection_maps(system)
    key = plan_key(blocks, C, B, O)
    if key is not None:
        kept = PLANS.get(key)
        if kept is not None:
            # the blocks' state copies were checked when the structure was first planned: same functions, same names
            return _with_kernels(kept, blocks)
    plan = _new_plan(system, params, blocks, C, B, O)
    if key is not None:
        PLANS.put(key, _without_numbers(plan))
    return plan


def plan_key(blocks, C, B, O) -> tuple | None:
    """The structure a plan of these blocks and connection matrices depends on, or None when it is not kept."""
    parts = blocks_structure(blocks)
    if parts is None:
        return None
    return parts, tuple((m.shape, m.tobytes()) for m in (C, B, O))


def _map_steps(plan: LoopPlan, renew) -> LoopPlan:
    """``plan`` with every step replaced by ``renew(step)`` (each step once: the lists share their steps)."""
    done: dict[int, BlockStep] = {}

    def one(step: BlockStep) -> BlockStep:
        new = done.get(id(step))
        if new is None:
            new = done[id(step)] = renew(step)
        return new
    return replace(plan, steps=tuple(map(one, plan.steps)), rhs_steps=tuple(map(one, plan.rhs_steps)),
                   updates=tuple(map(one, plan.updates)))


def _frozen(value):
    """A read-only copy of an index array or matrix (the plans made from a kept one share it), else ``value``."""
    if not isinstance(value, np.ndarray):
        return value
    value = value.copy()
    value.setflags(write=False)
    return value


def _without_numbers(plan: LoopPlan) -> LoopPlan:
    """What is kept of a plan for reuse: no function or parameter of its blocks (they come from the next loop),
    and read-only copies of its index arrays and connection matrices."""
    def strip(step: BlockStep) -> BlockStep:
        return replace(step, gather=_frozen(step.gather), output=None, output_args=None, update=None,
                       update_args=None, column_output=None, column_args=None)
    kept = _map_steps(plan, strip)
    return replace(kept, copy_y=_frozen(plan.copy_y), copy_x=_frozen(plan.copy_x), out_index=_frozen(plan.out_index),
                   connect_map=_frozen(plan.connect_map), input_map=_frozen(plan.input_map),
                   output_map=_frozen(plan.output_map))


def _with_kernels(kept: LoopPlan, blocks) -> LoopPlan:
    """The kept plan with the kernels and parameters of ``blocks`` (a loop of its structure)."""
    kernels = {b.name: contract_of(b).kernels for b in blocks}
    return _map_steps(kept, lambda s: _kernel_step(s.name, s.x, s.y, s.gather, kernels[s.name]))


def _new_plan(system, params, blocks, C, B, O) -> LoopPlan:
    x_off, u_off, y_off = (_offsets(blocks, a) for a in ("nstates", "ninputs", "noutputs"))
    n_y = int(y_off[-1])
    direct = bool(np.all(np.count_nonzero(C, axis=1) == 1) and np.all(C[C != 0] == 1) and not B.any()
                  and np.all(np.count_nonzero(O, axis=1) == 1) and np.all(O[O != 0] == 1) and not O[:, n_y:].any())
    source = np.argmax(C != 0, axis=1)
    try:
        order, fixed_point = _topological_order(blocks, C, u_off, y_off), False
    except AlgebraicLoopError as err:
        if not err.undeclared:
            raise
        order, fixed_point = list(range(len(blocks))), True     # python-control's way: iterate to a fixed point
    steps, input_rows = [], []
    for k in order:
        us = slice(int(u_off[k]), int(u_off[k + 1]))
        gather = _index_or_slice(source[us]) if direct else None
        steps.append(_step(system, blocks[k], slice(int(x_off[k]), int(x_off[k + 1])),
                           slice(int(y_off[k]), int(y_off[k + 1])), gather, params))
        input_rows.append(us)
    # A right-hand side needs only the signals that feed some block input.  A block whose fed outputs
    # are all copies of its states is not called there: those signals are read from x.
    fed = set(source.tolist()) if direct else set(range(n_y))
    rhs_steps, copy_y, copy_x = [], [], []
    for k, step in zip(order, steps):
        pairs = _checked_state_copies(blocks[k], step)
        fed_here = [j for j in range(step.y.start, step.y.stop) if j in fed]
        if direct and all(j in pairs for j in fed_here):
            copy_y += fed_here
            copy_x += [pairs[j] for j in fed_here]
        else:
            rhs_steps.append(step)
    updates = tuple(s for s in steps if s.x.stop > s.x.start)
    out_index = np.argmax(O != 0, axis=1) if direct else np.zeros(0, dtype=int)
    return LoopPlan(tuple(steps), tuple(rhs_steps), updates, _index_or_slice(np.array(copy_y, dtype=int)),
                    _index_or_slice(np.array(copy_x, dtype=int)), out_index, direct, int(x_off[-1]), n_y,
                    C, B, O, tuple(input_rows), fixed_point)


def settle(plan: LoopPlan, one_pass, y: np.ndarray) -> np.ndarray:
    """Run ``one_pass(y)`` (evaluate blocks in plan order, writing their outputs into ``y``) once, or, for a
    fixed-point plan, until ``y`` stops changing.

    Raises
    ------
    AlgebraicLoopError
        If a fixed-point plan does not settle within one pass per block and one more.
    """
    if not plan.fixed_point:
        one_pass(y)
        return y
    for _ in range(len(plan.steps) + 1):
        before = y.copy()
        one_pass(y)
        if np.array_equal(before, y):
            return y
    raise AlgebraicLoopError(f"the blocks {plan.order} did not settle: there is an algebraic loop")


def with_params(plan: LoopPlan, system, params: dict) -> LoopPlan:
    """The same plan with call-time ``params`` merged into the arguments of the blocks without kernels."""
    blocks = {b.name: b for b in subsystems(system)}

    def renew(step: BlockStep) -> BlockStep:
        if step.kernel:
            return step
        local = (merged_params(system, blocks[step.name], params),)
        return replace(step, output_args=local, update_args=local, column_args=local)

    return replace(plan, steps=tuple(map(renew, plan.steps)), rhs_steps=tuple(map(renew, plan.rhs_steps)),
                   updates=tuple(map(renew, plan.updates)))
