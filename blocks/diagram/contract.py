"""What a block promises the engines: one typed declaration, made with the block and checked.

An engine that evaluates an interconnection faster than python-control's own
fixed-point iteration relies on facts about each block that python-control
does not record:

* which inputs reach its outputs directly (feedthrough), so that the blocks
  can be ordered once instead of iterated;
* which outputs are copies of its states, so that a right-hand side can read
  them from the state without calling the output function;
* whether its output function takes column-stacked signals (a whole time
  grid in one call);
* its maths as kernel functions (:mod:`blocks.kernels`) with their
  parameters, which an engine can call directly, vectorise over a batch or
  compile;
* which of its states are physical quantities of a joint (a position, a
  velocity, a disturbance observer's state), so that the divergence rule
  (:mod:`blocks.engines.divergence`) bounds them by what they are, whatever the
  block is called.

:class:`BlockContract` holds these facts; :class:`Block` is a
:class:`control.NonlinearIOSystem` made with one.  :func:`contract_of` gives
the contract of any system: a system made elsewhere (a user's own
python-control block) gets the safe default, every input feeding through and
nothing else promised.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import control as ct

from blocks.diagram.bound_kernels import Kernels  # defined apart: a path or a scenario holds one without python-control

__all__ = ["Kernels", "BlockContract", "STATE_QUANTITIES", "joint_states", "Block", "ContractError", "contract_of",
           "kernel_block", "kernels_only"]


class ContractError(ValueError):
    """A block's contract names signals it does not have, or promises what its functions do not keep."""


#: The physical quantities a block may declare a state to be (see :func:`blocks.figure2.physical_bounds.state_bounds`):
#: a joint position (rad, m), a joint velocity (rad/s, m/s), the state ``z = d_hat - Y q'`` of a disturbance
#: observer (N m, N).
STATE_QUANTITIES = ("position", "velocity", "observer_state")


def joint_states(labels, quantity: str) -> tuple:
    """``(label, quantity, joint)`` triples declaring the states ``labels`` (joint 0, 1, ... in order) to be
    ``quantity`` (one of :data:`STATE_QUANTITIES`), for :attr:`BlockContract.state_meanings`."""
    return tuple((str(label), quantity, i) for i, label in enumerate(labels))


@dataclass(frozen=True)
class BlockContract:
    """The facts an engine may rely on about one block.

    Parameters
    ----------
    feedthrough : frozenset of str, optional
        Names of the inputs that reach the outputs directly.  None (the
        default) means every input does, which is always safe.
    state_outputs : tuple of (str, str)
        ``(output, state)`` pairs: outputs that equal a state at every instant.
    columnwise : bool
        The output function also takes column-stacked signals (see
        :class:`Kernels`).  Blocks with kernels take columns through them.
    kernels : Kernels, optional
        The block's maths as kernels; None for a block written otherwise.
    state_meanings : tuple of (str, str, int)
        ``(state, quantity, joint)`` triples: the states that are a physical
        quantity (:data:`STATE_QUANTITIES`) of joint ``joint``.  A state not
        named here has no known physical bound (the divergence rule judges it
        by growth).
    """

    feedthrough: frozenset | None = None
    state_outputs: tuple = ()
    columnwise: bool = False
    kernels: Kernels | None = None
    state_meanings: tuple = ()

    def __post_init__(self) -> None:
        if self.feedthrough is not None:
            object.__setattr__(self, "feedthrough", frozenset(self.feedthrough))
        pairs = self.state_outputs.items() if isinstance(self.state_outputs, Mapping) else self.state_outputs
        object.__setattr__(self, "state_outputs", tuple((str(o), str(x)) for o, x in pairs))
        meanings = tuple((str(x), str(quantity), int(joint)) for x, quantity, joint in self.state_meanings)
        for state, quantity, joint in meanings:
            if quantity not in STATE_QUANTITIES or joint < 0:
                raise ContractError(f"state_meanings: state {state!r} is declared {quantity!r} of joint {joint}; "
                                    f"a quantity is one of {STATE_QUANTITIES} of a joint 0, 1, ...")
        object.__setattr__(self, "state_meanings", meanings)

    def meaning_of(self, state: str) -> tuple | None:
        """``(quantity, joint)`` of the state labelled ``state``, or None where the block declares none."""
        for label, quantity, joint in self.state_meanings:
            if label == state:
                return quantity, joint
        return None

    @property
    def takes_columns(self) -> bool:
        """Whether the block's outputs can be evaluated for many columns in one call."""
        return self.columnwise or (self.kernels is not None and self.kernels.output is not None)

    def check(self, system) -> BlockContract:
        """Raise :class:`ContractError` unless every name refers to a signal of ``system``; return self."""
        inputs, outputs = list(system.input_labels), list(system.output_labels)
        states = list(system.state_labels)
        if self.feedthrough is not None:
            unknown = sorted(self.feedthrough - set(inputs))
            if unknown:
                raise ContractError(f"block '{system.name}': feedthrough names {unknown}, which are not its "
                                    f"inputs {inputs}")
        for out, state in self.state_outputs:
            if out not in outputs or state not in states:
                raise ContractError(f"block '{system.name}': state_outputs pair ({out!r}, {state!r}) names a "
                                    f"signal it does not have (outputs {outputs}, states {states})")
        for state, quantity, _ in self.state_meanings:
            if state not in states:
                raise ContractError(f"block '{system.name}': state_meanings declares {state!r} a {quantity}, "
                                    f"which is not one of its states {states}")
        k = self.kernels
        if k is not None and ((system.noutputs and k.output is None) or (system.nstates and k.update is None)):
            raise ContractError(f"block '{system.name}': its kernels lack an "
                                f"{'output' if k.output is None else 'update'} function")
        return self


class Block(ct.NonlinearIOSystem):
    """A :class:`control.NonlinearIOSystem` made with a :class:`BlockContract`.

    It behaves as any python-control system (interconnect, simulate,
    linearize); engines read :attr:`contract`.

    Parameters
    ----------
    updfcn, outfcn : callable or None
        As for :class:`control.NonlinearIOSystem`.
    contract : BlockContract
        Checked against the block's signal names here.
    **kwargs
        Passed to :class:`control.NonlinearIOSystem` (``inputs``, ``outputs``,
        ``states``, ``name``, ``params``, ``dt``).
    """

    def __init__(self, updfcn, outfcn, *, contract: BlockContract = BlockContract(), **kwargs) -> None:
        super().__init__(updfcn, outfcn, **kwargs)
        self.contract = contract.check(self)

    def __enter__(self) -> Block:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release what the block holds (nothing for a Python block; an FMU block frees its instance)."""


def contract_of(system) -> BlockContract:
    """The contract of a block, or the safe default for a system made without one."""
    contract = getattr(system, "contract", None)
    return contract if isinstance(contract, BlockContract) else BlockContract()


def kernel_block(kernels: Kernels, *, name: str, inputs, outputs, states=(), feedthrough=(),
                 state_outputs=(), dt: float = 0, state_meanings=()) -> Block:
    """A :class:`Block` whose python-control functions are its kernels bound to their parameters.

    Parameters
    ----------
    kernels : Kernels
        The maths; the block's update and output call them with ``kernels.params``.
    name : str
        Block name.
    inputs, outputs, states : list of str
        Signal names (python-control's).
    feedthrough : iterable of str
        Inputs that reach the outputs directly.
    state_outputs : iterable of (str, str)
        Outputs that are copies of states.
    dt : float
        0 for a continuous block, or the sample period (s) of a discrete one,
        whose update gives the next state (python-control's convention).
    state_meanings : iterable of (str, str, int)
        States that are a joint's physical quantity (see :class:`BlockContract`; :func:`joint_states`).
    """
    if _KERNELS_ONLY.get():
        return KernelsOnly(name, BlockContract(feedthrough=frozenset(feedthrough), state_outputs=tuple(state_outputs),
                                               columnwise=True, kernels=kernels, state_meanings=tuple(state_meanings)))
    params = kernels.params
    output, update = kernels.output, kernels.update
    outfcn = None if output is None else (lambda t, x, u, _p: output(t, x, u, *params))
    updfcn = None if update is None else (lambda t, x, u, _p: update(t, x, u, *params))
    contract = BlockContract(feedthrough=frozenset(feedthrough), state_outputs=tuple(state_outputs),
                             columnwise=True, kernels=kernels, state_meanings=tuple(state_meanings))
    signals = dict(name=name, inputs=list(inputs), outputs=list(outputs), dt=dt)
    if states:      # python-control refuses a state count of 0 without an update function
        signals["states"] = list(states)
    return Block(updfcn, outfcn, contract=contract, **signals)


# Whether kernel_block makes only the contract (see kernels_only); per thread and task, not per process
_KERNELS_ONLY: ContextVar[bool] = ContextVar("dobkit_kernels_only", default=False)


class KernelsOnly:
    """What :func:`kernel_block` makes inside :func:`kernels_only`: the block's name and contract (its kernels
    and their parameters), without a python-control system."""

    def __init__(self, name: str, contract: BlockContract) -> None:
        self.name, self.contract = name, contract


@contextmanager
def kernels_only() -> Iterator[None]:
    """Within this context :func:`kernel_block` returns :class:`KernelsOnly` stand-ins instead of blocks.

    For engines that need only a block's numbers, made exactly as the block's
    factory makes them, many times over: a batch makes every member's blocks
    this way (:mod:`blocks.figure2.batch.members`), where building a python-control
    system per member would cost more than integrating it.
    """
    token = _KERNELS_ONLY.set(True)
    try:
        yield
    finally:
        _KERNELS_ONLY.reset(token)
