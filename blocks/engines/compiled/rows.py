"""Rows the generated code computes beside a loop's outputs: the lumped disturbance and the tracking-error rows.

A :class:`RowGroup` is a function of the interconnection's outputs (by
signal name, as rows), of values shared by every run at that time (``aux``)
and of the blocks' parameters, written with the kernels of
:mod:`blocks.kernels`.  :func:`blocks.engines.compiled.codegen.loop_program` traces
it beside the right-hand side and beside the outputs, so that it shares
their terms (the true arm's acceleration, the nominal model's inertia) and
costs only what it adds.

The groups of the Figure-2 loop:

``d``
    the lumped disturbance the observer estimates,
    :func:`~blocks.kernels.lumped_disturbance` of the true arm (the plant's
    constants) and the nominal model (the controller's), as
    :func:`blocks.figure2.loop.lumped_disturbance` computes it for a response;
``position_error``
    ``q_ref - q``;
``tool_distance``
    the tool tip's distance from the reference's (m), the arm's
    ``tool_position`` at ``q`` against the reference's tool position
    ``aux[0:3]``, as :class:`blocks.figure2.metrics.TrackingAccumulator` computes it;
``disturbance_error``
    ``d - d_hat``.

The batch accumulates the last three into the tracking metrics inside the
compiled driver (:mod:`blocks.engines.compiled.batch`).

The group functions take the arm's kernels first (``model``,
:class:`~blocks.kernels.model.ArmKernels`); :func:`loop_rows` gives the
groups for an arm, with its kernels passed (:func:`~blocks.kernels.model.with_arm`),
and :func:`loop_rows_of` for an interconnection, from the arm of its plant
block (every arm's, the paper's too).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blocks.kernels import lumped_disturbance
from blocks.kernels.model import with_arm

__all__ = ["RowGroup", "TOOL_AUX", "loop_rows", "loop_rows_of"]

#: Shared values the tool-distance rows read: the reference's tool position x, y, z (m).
TOOL_AUX = 3


@dataclass(frozen=True)
class RowGroup:
    """Rows computed from a loop's outputs, traced into the generated code.

    Parameters
    ----------
    name : str
        The group's name.
    rows : callable
        ``rows(signals, aux, params) -> sequence`` (a group function with its arm's kernels passed) with ``signals`` the
        outputs by name (object arrays of rows), ``aux`` the shared values
        and ``params`` each traced block's parameters by block name.
    signals : tuple of str
        Output signals it reads.
    blocks : tuple of str
        Blocks whose parameters it reads (they must be traced).
    aux : int
        How many shared values it reads.
    """

    name: str
    rows: Callable
    signals: tuple
    blocks: tuple = ()
    aux: int = 0

    def available(self, labels, traced) -> bool:
        """Whether a loop with output ``labels`` and ``traced`` blocks has what the group reads."""
        names = {label.partition("[")[0] for label in labels}
        return set(self.signals) <= names and set(self.blocks) <= set(traced)


def _lumped(model, signals, aux, params):
    # the plant's first parameter is the true arm's constants, the controller's the nominal model's
    # (blocks.diagram.systems.plant and .controller)
    return lumped_disturbance(model, params["plant"][0], params["controller"][0], signals["q"], signals["dq"],
                              signals["tau"], signals["tau_dis"])


def _position_error(model, signals, aux, params):
    return _reference_minus_measured(signals, aux, params)


def _reference_minus_measured(signals, aux, params):
    return signals["q_ref"] - signals["q"]


def _tool_distance(model, signals, aux, params):
    # the arm's tool parameters travel with the plant's disturbance parameters (blocks.kernels.disturbance_params)
    pose = model.tool_position(params["plant"][1].kin, signals["q"])
    dx, dy, dz = aux[0] - pose[0], aux[1] - pose[1], aux[2] - pose[2]
    return [np.sqrt(dx * dx + dy * dy + dz * dz)]


def _disturbance_error(model, signals, aux, params):
    return _lumped(model, signals, aux, params) - signals["d_hat"]


#: The group functions of the Figure-2 loop (``model`` first), in the order of their flags.
_GROUPS = (
    RowGroup("d", _lumped, ("q", "dq", "tau", "tau_dis"), ("plant", "controller")),
    RowGroup("position_error", _position_error, ("q", "q_ref")),
    RowGroup("tool_distance", _tool_distance, ("q",), ("plant",), TOOL_AUX),
    RowGroup("disturbance_error", _disturbance_error, ("q", "dq", "tau", "tau_dis", "d_hat"), ("plant", "controller")),
)


def loop_rows(arm) -> tuple:
    """The row groups of the Figure-2 loop for ``arm`` (an :class:`~blocks.model.arm.ArmModel`, its
    :class:`~blocks.kernels.model.ArmKernels` or its two kernel modules): each group's function called with the
    arm's kernels (the same tuple for the same arm)."""
    return tuple(RowGroup(g.name, with_arm(g.rows, arm), g.signals, g.blocks, g.aux) for g in _GROUPS)


def _armless_rows() -> tuple:
    """The groups that read no arm (``position_error``), for a loop without a Python plant."""
    return (RowGroup("position_error", _reference_minus_measured, ("q", "q_ref")),)


def loop_rows_of(system) -> tuple:
    """The row groups for an interconnection: those of the arm of its block ``plant``; without a Python plant
    (an FMU's) only those that read no arm."""
    from blocks.diagram.control_compat import subsystems
    for block in subsystems(system):
        arm = getattr(block, "arm", None)
        if block.name == "plant" and arm is not None:
            return loop_rows(arm)
    return _armless_rows()
