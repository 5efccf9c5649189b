"""The physical bounds of a scenario's states: what the Figure-2 layer gives the engines' divergence rule.

A loop has diverged when the arm moves or spins far beyond anything its
reference asks, or its disturbance estimate grows far beyond any force in
the scenario -- not when an internal state is large.  The observer's state
``z = d_hat - Y q'`` legitimately grows with the gain ``Y``, so it is judged
through ``d_hat`` and ``q'``: its bound is the estimate's bound plus what
``Y q'`` may reach within the velocity bounds.

Bounds, per joint (units rad, m; rad/s, m/s; N m, N):

* position: the reference's largest magnitude plus :data:`POSITION_MARGIN`
  (100 rad -- sixteen turns -- or 10 m);
* velocity: the reference's largest speed plus :data:`VELOCITY_MARGIN`
  (1000 rad/s or 100 m/s);
* disturbance estimate: :data:`FORCE_FACTOR` times the largest force the
  scenario holds at the start (the external disturbance, gravity, the
  reference's torque), plus 1.

Which state is which comes from the blocks' contracts
(:func:`blocks.engines.divergence.state_meanings`): the plant's ``q``, ``dq``, the
observer's ``z``, and in the digital loop the encoder's previous sample and
filtered velocity.  A batch's bounds have a column per member: the force
bound depends on the member's arm, disturbance and gain.
"""
from __future__ import annotations

import sys
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from blocks.engines.divergence import StateBounds, joint_signal_meaning, state_meanings
from blocks.kernels import disturbance_params as kernel_disturbance_params
from blocks.kernels import external_disturbance
from blocks.kernels.model import with_arm

__all__ = ["state_bounds", "cached_state_bounds", "signal_bounds", "ReferenceLimits", "reference_limits",
           "force_bounds", "batch_bounds", "evaluation_kernels", "POSITION_MARGIN", "VELOCITY_MARGIN", "FORCE_FACTOR"]

#: Added to the reference's largest position (rad for revolute joints, m for prismatic ones).
POSITION_MARGIN = {"revolute": 100.0, "prismatic": 10.0}
#: Added to the reference's largest speed (rad/s, m/s).
VELOCITY_MARGIN = {"revolute": 1e3, "prismatic": 1e2}
#: The disturbance estimate's bound in multiples of the largest force in the scenario.
FORCE_FACTOR = 1e3
@dataclass(frozen=True)
class ReferenceLimits:
    """What the bounds take from the reference: per joint position and velocity bounds and the start point."""

    position: np.ndarray
    velocity: np.ndarray
    q0: np.ndarray
    dq0: np.ndarray
    ddq0: np.ndarray
    kinds: tuple
    position_units: tuple
    velocity_units: tuple
    force_units: tuple


def reference_limits(scenario, samples: int = 201) -> ReferenceLimits:
    """The position and velocity bounds of :mod:`this module <blocks.engines.divergence>` from the scenario's reference."""
    s = scenario
    joints = s.robot.joints
    times = np.linspace(0.0, s.simulation.t_final, samples)
    q_ref, dq_ref, ddq_ref = (np.asarray(a, dtype=float) for a in s.trajectory.evaluate(times))   # (T, n) each
    pos = np.abs(q_ref).max(axis=0) + np.array([POSITION_MARGIN[k] for k in joints.kinds])
    vel = np.abs(dq_ref).max(axis=0) + np.array([VELOCITY_MARGIN[k] for k in joints.kinds])
    return ReferenceLimits(pos, vel, q_ref[0], dq_ref[0], ddq_ref[0], tuple(joints.kinds),
                           tuple(joints.position_units), tuple(joints.velocity_units), tuple(joints.force_units))


def force_bounds(k_true, disturbance, ref: ReferenceLimits, kernels, tool_kernels,
                 terms=None) -> np.ndarray:
    """The disturbance estimate's bound per member: ``FORCE_FACTOR`` (largest start force + 1) (N m, N).

    Parameters
    ----------
    k_true : numpy.ndarray
        Arm constants of the true arm, (6,) or (6, N) for N members (the RRPR's), or ``arm.kernel_params()``
        of the arm whose row kernels are ``kernels``.
    disturbance : blocks.kernels.DisturbanceParams
        The external disturbance in the same layout (rows, one column per member).
    ref : ReferenceLimits
    kernels : module
        The true arm's row kernels (``arm.kernels``).
    tool_kernels : module
        The true arm's tool kernels (``arm.tool_kernels``, the tissue contact's tool point).
    terms : optional
        Row kernels that evaluate ``G`` and ``M q'' + h`` of the arm of ``kernels`` (default ``kernels``):
        :func:`evaluation_kernels`, the same numbers in microseconds where that pays.

    Returns
    -------
    numpy.ndarray
        Shape () for one arm, (N,) for N members.
    """
    terms = kernels if terms is None else terms
    bias_forces, mass_times = terms.bias_forces, terms.mass_times
    batch = isinstance(k_true, np.ndarray) and np.ndim(k_true) == 2
    col = (lambda a: np.asarray(a, dtype=float)[:, None]) if batch else (lambda a: np.asarray(a, dtype=float))
    q0, dq0, ddq0 = col(ref.q0), col(ref.dq0), col(ref.ddq0)
    if batch:
        q0, dq0, ddq0 = (np.repeat(a, np.shape(k_true)[1], axis=1) for a in (q0, dq0, ddq0))
    gravity_only = bias_forces(k_true, q0, np.zeros_like(dq0))
    inverse = mass_times(k_true, q0, ddq0) + bias_forces(k_true, q0, dq0)
    external = _external_disturbance(kernels, tool_kernels)
    forces = np.abs(external(0.0, q0, dq0, disturbance)) + np.abs(gravity_only) + np.abs(inverse)
    return FORCE_FACTOR * (forces.max(axis=0) + 1.0)


def evaluation_kernels(arm):
    """The row kernels to evaluate ``arm``'s dynamics with before a run (force bounds, step estimate): compiled for
    a chain arm where that pays (:func:`blocks.engines.compiled.row_kernels.row_kernels`: a process that has loaded numba and
    runs the arm again and again; the same numbers in microseconds instead of milliseconds), else ``arm.kernels``."""
    if "numba" not in sys.modules:     # nothing compiled is at hand: the numpy kernels cost less than loading it
        return arm.kernels
    from blocks.engines.compiled.row_kernels import row_kernels
    return row_kernels(arm)


def _external_disturbance(kernels, tool_kernels):
    """The disturbance kernel called with the kernels of the arm of these row-kernel modules."""
    return with_arm(external_disturbance, (kernels, tool_kernels))


def _bound_of(meaning, name: str, ref: ReferenceLimits, force, gain):
    """The bound of one state by its physical meaning ``(quantity, joint)`` (None: none known): (bound, name,
    unit, reason); ``inf`` where not physical.  ``name`` is how a message names the state."""
    if meaning is None:
        return np.inf, name, "", "finite"
    quantity, i = meaning
    if i >= ref.position.size:
        raise ValueError(f"{name} is declared the {quantity} of joint {i}, but the arm has {ref.position.size} joints")
    if quantity == "position":
        return (ref.position[i], name, ref.position_units[i],
                f"the reference's largest |q[{i}]| plus {POSITION_MARGIN[ref.kinds[i]]:g} {ref.position_units[i]}")
    if quantity == "velocity":
        return (ref.velocity[i], name, ref.velocity_units[i],
                f"the reference's largest speed plus {VELOCITY_MARGIN[ref.kinds[i]]:g} {ref.velocity_units[i]}")
    if quantity == "observer_state":
        y_row = np.abs(gain[i])                      # (n,) for one run, (n, N) for a batch
        reach = (y_row * (ref.velocity if y_row.ndim == 1 else ref.velocity[:, None])).sum(axis=0)
        return (force + reach, f"{name} (= d_hat - Y dq)", ref.force_units[i],
                f"{FORCE_FACTOR:g} x the largest force at the start for d_hat, plus Y dq within the velocity "
                "bounds")
    raise ValueError(f"{name} is declared a {quantity!r}; the quantities with a bound are position, velocity and "
                     "observer_state")


def _labelled_bounds(states, ref: ReferenceLimits, force, gain) -> StateBounds:
    """Bounds for states given as ``(name, meaning)`` pairs (:func:`state_meanings`)."""
    bounds, names, units, reasons = [], [], [], []
    for state_name, meaning in states:
        bound, name, unit, reason = _bound_of(meaning, state_name, ref, force, gain)
        bounds.append(bound)
        names.append(name)
        units.append(unit)
        reasons.append(reason)
    N = np.size(force)
    if np.ndim(force) == 0:
        array = np.array([float(b) for b in bounds], dtype=float)
    else:
        array = np.array([np.broadcast_to(b, (N,)) for b in bounds], dtype=float).reshape(len(bounds), N)
    return StateBounds(array, names, units, reasons)


def state_bounds(loop, scenario, samples: int = 201) -> StateBounds:
    """The bounds of :mod:`this module <blocks.engines.divergence>` for the states of an interconnected ``loop``.

    ``loop`` is the continuous loop (:func:`blocks.closed_loop`) or the sampled one
    (:func:`blocks.figure2.digital_loop.sampled_loop`): anything with ``syslist`` of blocks with ``state_labels``.
    """
    s = scenario
    ref = reference_limits(s, samples)
    spec = kernel_disturbance_params(s.disturbance, s.robot)
    force = float(force_bounds(s.robot.kernel_params(), spec, ref, s.robot.kernels, s.robot.tool_kernels,
                               evaluation_kernels(s.robot)))
    return _labelled_bounds(state_meanings(loop), ref, force, np.asarray(s.observer_gain, dtype=float))


_kept: OrderedDict = OrderedDict()
# Scenarios whose loops' bounds are kept (scenarios are immutable and hashable; equal ones share an entry)
_KEPT = 16


def cached_state_bounds(loop, scenario) -> StateBounds:
    """:func:`state_bounds`, kept for the latest scenarios: they cost a few ms of reference evaluations, as much
    as a compiled sampled run itself."""
    key = (scenario, tuple(loop.state_labels))
    found = _kept.get(key)
    if found is None:
        found = _kept[key] = state_bounds(loop, scenario)
        while len(_kept) > _KEPT:
            _kept.popitem(last=False)
    else:
        _kept.move_to_end(key)
    return found


def batch_bounds(batch_loop, labels=None) -> StateBounds:
    """Per-member bounds (nstates, N) of a batch (:class:`blocks.figure2.batch.members.MemberLoop`).

    ``labels`` are ``(name, meaning)`` pairs in the engine's state order
    (:func:`state_meanings` of the member loop); by default the numpy
    batch's rows ``q; dq; z``.
    """
    b = batch_loop
    ref = reference_limits(b.v.base)
    n = b.joints
    if isinstance(b.k_true, np.ndarray):        # the RRPR's constants, one column per member
        force = force_bounds(b.k_true, b.disturbance, ref, b.arm.kernels, b.arm.tool_kernels)       # (N,)
    else:                                       # another arm: the members share the true arm, not its numbers' layout
        force = _shared_arm_force_bounds(b.k_true, b.arm, b.disturbance, ref, b.n)
    if labels is None:
        labels = [(f"plant q[{i}]", ("position", i)) for i in range(n)] \
            + [(f"plant dq[{i}]", ("velocity", i)) for i in range(n)]
        if b.observer:
            labels += [(f"observer z[{i}]", ("observer_state", i)) for i in range(n)]
    gain = np.asarray(b.gain, dtype=float)
    if gain.ndim == 2:                      # diagonal gains, rows (n, N): as full matrices (n, n, N)
        eye = np.eye(n)[:, :, None]
        gain = eye * gain[None, :, :]
    return _labelled_bounds(labels, ref, force, gain)


def _shared_arm_force_bounds(k, arm, disturbance, ref: ReferenceLimits, members: int) -> np.ndarray:
    """:func:`force_bounds` of ``members`` members sharing one arm (``k``, its row kernels) whose disturbances
    differ: the arm's terms at the reference's start once, each member's disturbance beside them (N,)."""
    q0, dq0, ddq0 = (np.repeat(np.asarray(a, dtype=float)[:, None], members, axis=1) for a in (ref.q0, ref.dq0, ref.ddq0))
    kernels, terms = arm.kernels, evaluation_kernels(arm)
    gravity_only = terms.bias_forces(k, q0, np.zeros_like(dq0))
    inverse = terms.mass_times(k, q0, ddq0) + terms.bias_forces(k, q0, dq0)
    external = _external_disturbance(kernels, arm.tool_kernels)
    forces = np.abs(external(0.0, q0, dq0, disturbance)) + np.abs(gravity_only) + np.abs(inverse)
    return FORCE_FACTOR * (forces.max(axis=0) + 1.0)


def signal_bounds(names, scenario, samples: int = 201) -> StateBounds:
    """Bounds for signals named as the loop names them (``q[i]``, ``dq[i]``: the plant's), e.g. a plant FMU's
    outputs; other names are judged by growth (:meth:`StateBounds.with_growth`)."""
    s = scenario
    ref = reference_limits(s, samples)
    force = float(force_bounds(s.robot.kernel_params(), kernel_disturbance_params(s.disturbance, s.robot), ref,
                               s.robot.kernels, s.robot.tool_kernels, evaluation_kernels(s.robot)))
    return _labelled_bounds([(f"plant {name}", joint_signal_meaning(name)) for name in names], ref, force,
                            np.asarray(s.observer_gain, dtype=float))


