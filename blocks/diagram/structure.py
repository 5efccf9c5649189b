"""What a loop is apart from its numbers: the key under which its wiring and its plan are reused.

Building a loop's interconnection (:func:`control.interconnect` matches
signal names) and its evaluation plan (:func:`blocks.diagram.plan.make_plan`) costs
milliseconds, as much as a short compiled run.  Two scenarios that differ
only in numbers -- gains, disturbance size, noise, ``t_final``, masses of the
same model -- have the same wiring and the same plan; only the numbers their
blocks' kernels carry differ.  :func:`block_structure` says what of a block
the wiring, the plan and the generated code depend on; two loops whose blocks
give equal structures (and, for a plan, equal connection matrices) share
them, and the numbers flow in from the new loop's own blocks.

A block is shared only when everything an engine reads of it is declared:
a :class:`~blocks.diagram.contract.Block` with kernels and no python-control
``params``.  Its structure is its type, name, signal names, sample period,
contract (feedthrough, state copies, columns), its kernel functions (by
identity: a bound copy for another arm is another function) and the layout
of their parameters (:func:`blocks.kernels.trace.param_structure`: types,
shapes, structural values such as a disturbance kind or a URDF arm's
geometry, never the numbers).  Any other block (a user's python-control
system, an FMU, a path without kernels) makes its loop unshared: it is built
as before.

:class:`StructureCache` keeps the latest structures of a process, a bounded
number of them, and holds no parameter values: what it keeps is wiring and
plans stripped of their numbers.
"""
from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

from blocks.diagram.contract import Block, BlockContract

__all__ = ["block_structure", "blocks_structure", "StructureCache"]


def block_structure(block) -> tuple | None:
    """What of ``block`` its loop's wiring, plan and generated code depend on, or None when it is not shared.

    Parameters
    ----------
    block : control.NonlinearIOSystem
        A block of an interconnection.

    Returns
    -------
    tuple or None
        Hashable; equal for two blocks that differ only in the numbers of
        their kernels' parameters.  None for a block that is not a
        :class:`~blocks.diagram.contract.Block` with kernels and empty ``params``.
    """
    contract = getattr(block, "contract", None)
    if not isinstance(block, Block) or not isinstance(contract, BlockContract) or contract.kernels is None \
            or block.params:
        return None
    k = contract.kernels
    return (type(block), block.name, tuple(block.input_labels), tuple(block.output_labels),
            tuple(block.state_labels), block.dt, contract.feedthrough, contract.state_outputs, contract.columnwise,
            k.output, k.update) + _layout(block, contract)


# block -> (its contract, the layout of its kernels' parameters): a loop's blocks are asked for their structure
# two or three times as it is built (its wiring, its plan); the layout walks every parameter
_layouts: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _layout(block, contract: BlockContract) -> tuple:
    """The layout (:func:`blocks.kernels.trace.param_structure`) of the block's kernel parameters, kept per block
    while its contract stays the one it was computed for."""
    try:
        found = _layouts.get(block)
    except TypeError:               # a block class that is not hashable: computed each time
        found = None
    if found is not None and found[0] is contract:
        return found[1]
    # imported here: blocks.engines.compiled imports the plan, which imports this module
    from blocks.kernels.trace import param_structure
    k = contract.kernels
    layout = (param_structure(k.params), None if k.column_params is None else param_structure(k.column_params))
    try:
        _layouts[block] = (contract, layout)
    except TypeError:
        pass
    return layout


def blocks_structure(blocks) -> tuple | None:
    """The structures of ``blocks`` in order, or None when any one of them is not shared."""
    parts = []
    for block in blocks:
        part = block_structure(block)
        if part is None:
            return None
        parts.append(part)
    return tuple(parts)


class StructureCache:
    """The latest ``capacity`` entries by structure key, least recently used dropped first; safe across threads.

    Parameters
    ----------
    capacity : int
        Entries kept (at least 1).
    """

    def __init__(self, capacity: int) -> None:
        if int(capacity) != capacity or capacity < 1:
            raise ValueError(f"capacity must be a whole number >= 1, got {capacity!r}")
        self.capacity = int(capacity)
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        """The entry of ``key`` (now the most recent), or None."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
            return entry

    def put(self, key, entry) -> None:
        """Keep ``entry`` under ``key``, dropping the least recently used beyond the capacity."""
        with self._lock:
            self._entries[key] = entry
            self._entries.move_to_end(key)
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)

    def clear(self) -> None:
        """Forget every entry (the next loop of each structure is built afresh)."""
        with self._lock:
            self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
