"""When a run has diverged: the rule every engine applies, on bounds it is given (the context's).

A run has diverged when a state leaves its bound (:class:`StateBounds`, one
per state; a column per member for a batch).  The engines do not make the
bounds: the layer that builds the run does (the Figure-2 layer from the
scenario, :mod:`blocks.figure2.physical_bounds`; a user's diagram from what the user
gives), and hands them over in the run's :class:`blocks.engines.context.Context`.

A state is bounded by what it is, never by the name of its block: each
block declares in its contract which of its states are a joint's position,
velocity or observer state (:attr:`blocks.diagram.contract.BlockContract.state_meanings`;
:func:`state_meanings` reads them in state order).  A state with no
declared meaning (an FMU's own states, a user's blocks, the actuator's
command buffer) is judged by growth: beyond :data:`GROWTH_FACTOR` times its
start magnitude plus :data:`GROWTH_FLOOR` (see :meth:`StateBounds.with_growth`).
Where an engine advances in fixed steps of its own and knows no bound at all
(the outputs of a foreign FMU in co-simulation), a signal that grows more
than :data:`RUNAWAY_FACTOR`-fold in each of :data:`RUNAWAY_STEPS`
consecutive steps has run away (:class:`Runaway`): the signature of an
unstable explicit step.

Every engine judges the same array of bounds (:class:`blocks.engines.monitor.Monitor`):
single runs, both batches, the sampled loop and co-simulation.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["StateBounds", "state_meanings", "joint_signal_meaning", "Runaway", "GROWTH_FACTOR", "GROWTH_FLOOR",
           "RUNAWAY_FACTOR", "RUNAWAY_STEPS"]

#: A state without a physical bound has diverged beyond this many times its start magnitude (plus the floor).
GROWTH_FACTOR = 1e6
#: Added to a state's start magnitude before the growth factor (in the state's own unit).
GROWTH_FLOOR = 1.0
#: A signal judged between fixed steps (co-simulation) runs away when it grows more than RUNAWAY_FACTOR-fold ...
RUNAWAY_FACTOR = 10.0
#: ... in each of this many consecutive steps (an unstable explicit step multiplies by a constant factor).
RUNAWAY_STEPS = 3


def _format_pair(value: float, bound: float) -> tuple[str, str]:
    """``value`` and ``bound`` with enough digits that a value beyond its bound prints beyond it."""
    for digits in range(4, 17):
        a, b = f"{value:.{digits}g}", f"{bound:.{digits}g}"
        if a != b and abs(float(a)) != abs(float(b)):
            return a, b
    return f"{value!r}", f"{bound!r}"


@dataclass(frozen=True)
class StateBounds:
    """A bound per loop state (``inf`` where no physical bound is known), and what each state is.

    Attributes
    ----------
    bounds : numpy.ndarray
        Largest magnitude of each state, shape (nstates,) or (nstates, N) for a batch (one column per member).
    names : list of str
        The signal each judged state stands for (``"plant q[2]"``), or the state's own label.
    units : list of str
    reasons : list of str
        How each bound was set, for the message.
    """

    bounds: np.ndarray
    names: list
    units: list
    reasons: list

    def with_growth(self, x0) -> StateBounds:
        """These bounds with every ``inf`` replaced by the growth bound ``GROWTH_FACTOR (|x0| + GROWTH_FLOOR)``.

        ``x0`` is the start state (nstates,) or (nstates, N).  A state with no
        physical bound is thus judged the same way by every engine: a blow-up
        by six orders of magnitude is divergence, not the state's business.
        """
        x0 = np.asarray(x0, dtype=float)
        bounds = np.array(np.broadcast_to(self.bounds, np.broadcast_shapes(self.bounds.shape, x0.shape)),
                          dtype=float)
        growth = GROWTH_FACTOR * (np.abs(np.broadcast_to(x0, bounds.shape)) + GROWTH_FLOOR)
        free = ~np.isfinite(bounds)
        bounds[free] = growth[free]
        reasons = list(self.reasons)
        rows = free if free.ndim == 1 else free.any(axis=1)
        for k in np.flatnonzero(rows):
            reasons[k] = f"no physical bound known: {GROWTH_FACTOR:g} x (its start magnitude + {GROWTH_FLOOR:g})"
        return replace(self, bounds=bounds, reasons=reasons)

    def member(self, m: int) -> StateBounds:
        """The bounds of batch member ``m`` (column ``m``), as for a single run."""
        return replace(self, bounds=self.bounds[:, m] if self.bounds.ndim == 2 else self.bounds)

    def violated(self, x) -> np.ndarray:
        """True for every state (or state and member) that is not finite or beyond its bound."""
        return ~(np.abs(np.asarray(x, dtype=float)) <= self.bounds)        # NaN counts as beyond

    def describe(self, x: np.ndarray) -> str:
        """Which state is out of bounds (or not finite) in ``x`` (one run's state), as a sentence."""
        x = np.asarray(x, dtype=float)
        bounds = self.bounds if self.bounds.ndim == 1 else self.bounds[:, 0]
        bad = ~np.isfinite(x)
        if bad.any():
            k = int(np.argmax(bad))
            return f"{self.names[k]} became {x[k]}"
        with np.errstate(divide="ignore", invalid="ignore"):
            k = int(np.argmax(np.abs(x) / bounds))
        value, bound = _format_pair(abs(float(x[k])), float(bounds[k]))
        sign = "-" if x[k] < 0 else ""
        return (f"{self.names[k]} reached {sign}{value} {self.units[k]}, beyond its bound {bound} "
                f"{self.units[k]} ({self.reasons[k]})").replace("  ", " ")


def state_meanings(blocks) -> list:
    """``(name, meaning)`` of every state of ``blocks`` in order: ``name`` as ``"block state"``, ``meaning`` the
    ``(quantity, joint)`` the block's contract declares (:attr:`blocks.diagram.contract.BlockContract.state_meanings`), or
    None.  ``blocks`` is an interconnection (its ``syslist``) or a sequence of blocks."""
    from blocks.diagram.contract import contract_of  # python-control only where there are blocks
    syslist = getattr(blocks, "syslist", blocks)
    out = []
    for block in syslist:
        contract = contract_of(block)
        out.extend((f"{block.name} {label}", contract.meaning_of(label)) for label in block.state_labels)
    return out


def joint_signal_meaning(name: str):
    """The meaning of a loop signal by the loop's naming convention (``q[i]``: a position, ``dq[i]``: a velocity;
    see ``DESIGN.md``), or None: for the outputs of a block that declares no states (a plant FMU's)."""
    stem, bracket, rest = name.partition("[")
    if bracket and rest.endswith("]") and rest[:-1].isdigit():
        quantity = {"q": "position", "dq": "velocity"}.get(stem)
        if quantity is not None:
            return quantity, int(rest[:-1])
    return None


class Runaway:
    """Watches signals between fixed steps for runaway growth (:data:`RUNAWAY_FACTOR`, :data:`RUNAWAY_STEPS`).

    Parameters
    ----------
    size : int
        Number of signals.
    """

    def __init__(self, size: int) -> None:
        self.streak = np.zeros(size, dtype=int)
        self.first = np.zeros(size)

    def update(self, y, y_next) -> int | None:
        """Take one step from ``y`` to ``y_next``; the index of a signal that has run away, or None."""
        y, y_next = np.asarray(y, dtype=float), np.asarray(y_next, dtype=float)
        with np.errstate(over="ignore"):     # a huge previous value simply does not count as growth
            grew = np.abs(y_next) > RUNAWAY_FACTOR * np.abs(y)
        self.first = np.where(grew & (self.streak == 0), np.abs(y), self.first)
        self.streak = np.where(grew, self.streak + 1, 0)
        gone = np.flatnonzero(self.streak >= RUNAWAY_STEPS)
        return int(gone[0]) if gone.size else None
