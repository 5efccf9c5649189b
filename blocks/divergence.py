"""When a run has diverged: bounds on the physical signals, derived from the scenario (the one rule).

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

The digital controller's states are physical too: the encoder's previous
sample is a position, its filtered velocity a velocity.  A state with no
physical meaning known here (an FMU's own states, a user's blocks, the
actuator's command buffer) is judged by growth: beyond :data:`GROWTH_FACTOR`
times its start magnitude plus :data:`GROWTH_FLOOR` (see
:meth:`StateBounds.with_growth`).  Where an engine advances in fixed steps
of its own and knows no bound at all (the outputs of a foreign FMU in
co-simulation), a signal that grows more than :data:`RUNAWAY_FACTOR`-fold
in each of :data:`RUNAWAY_STEPS` consecutive steps has run away
(:class:`Runaway`): the signature of an unstable explicit step.

Every engine judges the same array of bounds (:class:`blocks.monitor.Monitor`):
single runs, both batches (one column of bounds per member: the force bound
depends on the member's arm, disturbance and gain), the sampled loop and
co-simulation.
"""
from __future__ import annotations

import sys
from collections import OrderedDict
from dataclasses import dataclass, replace

import numpy as np

from .kernels import bias_forces as _rrpr_bias_forces
from .kernels import disturbance_params as kernel_disturbance_params
from .kernels import external_disturbance
from .kernels import mass_times as _rrpr_mass_times
from .kernels.bind import bound

__all__ = ["StateBounds", "state_bounds", "cached_state_bounds", "signal_bounds", "ReferenceLimits",
           "reference_limits", "force_bounds", "batch_bounds", "Runaway", "POSITION_MARGIN", "VELOCITY_MARGIN",
           "FORCE_FACTOR", "GROWTH_FACTOR", "GROWTH_FLOOR", "RUNAWAY_FACTOR", "RUNAWAY_STEPS"]

#: Added to the reference's largest position (rad for revolute joints, m for prismatic ones).
POSITION_MARGIN = {"revolute": 100.0, "prismatic": 10.0}
#: Added to the reference's largest speed (rad/s, m/s).
VELOCITY_MARGIN = {"revolute": 1e3, "prismatic": 1e2}
#: The disturbance estimate's bound in multiples of the largest force in the scenario.
FORCE_FACTOR = 1e3
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
    """The position and velocity bounds of :mod:`this module <blocks.divergence>` from the scenario's reference."""
    s = scenario
    joints = s.robot.joints
    times = np.linspace(0.0, s.simulation.t_final, samples)
    q_ref, dq_ref, ddq_ref = (np.asarray(a, dtype=float) for a in s.trajectory.evaluate(times))   # (T, n) each
    pos = np.abs(q_ref).max(axis=0) + np.array([POSITION_MARGIN[k] for k in joints.kinds])
    vel = np.abs(dq_ref).max(axis=0) + np.array([VELOCITY_MARGIN[k] for k in joints.kinds])
    return ReferenceLimits(pos, vel, q_ref[0], dq_ref[0], ddq_ref[0], tuple(joints.kinds),
                           tuple(joints.position_units), tuple(joints.velocity_units), tuple(joints.force_units))


def force_bounds(k_true, disturbance, ref: ReferenceLimits, kernels=None, tool_kernels=None,
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
    kernels : module, optional
        The true arm's row kernels (``arm.kernels``); default the paper's RRPR's.
    tool_kernels : module, optional
        The true arm's tool kernels (``arm.tool_kernels``, the tissue contact's tool point); default the RRPR's.
    terms : optional
        Row kernels that evaluate ``G`` and ``M q'' + h`` of the arm of ``kernels`` (default ``kernels``):
        :func:`evaluation_kernels`, the same numbers in microseconds where that pays.

    Returns
    -------
    numpy.ndarray
        Shape () for one arm, (N,) for N members.
    """
    if terms is not None or kernels is not None:
        terms = kernels if terms is None else terms
        bias_forces, mass_times = terms.bias_forces, terms.mass_times
    else:
        bias_forces, mass_times = _rrpr_bias_forces, _rrpr_mass_times
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
    a chain arm where that pays (:func:`blocks.compiled.row_kernels.row_kernels`: a process that has loaded numba and
    runs the arm again and again; the same numbers in microseconds instead of milliseconds), else ``arm.kernels``."""
    if "numba" not in sys.modules:     # nothing compiled is at hand: the numpy kernels cost less than loading it
        return arm.kernels
    from .compiled.row_kernels import row_kernels
    return row_kernels(arm)


def _external_disturbance(kernels, tool_kernels):
    """The disturbance kernel for the arm of these row-kernel modules (the RRPR's when not given)."""
    if kernels is None:
        return external_disturbance
    if tool_kernels is None:
        from .model.rrpr import tool_kernels
    return bound(external_disturbance, (kernels, tool_kernels))


def _bound_of(block: str, label: str, ref: ReferenceLimits, force, gain):
    """The bound of one state by its block and label: (bound, name, unit, reason); ``inf`` if not physical."""
    n = ref.position.size
    for i in range(n):
        if (block == "plant" and label == f"q[{i}]") or (block == "encoder" and label == f"q_prev[{i}]"):
            return (ref.position[i], f"{block} {label}", ref.position_units[i],
                    f"the reference's largest |q[{i}]| plus {POSITION_MARGIN[ref.kinds[i]]:g} {ref.position_units[i]}")
        if (block == "plant" and label == f"dq[{i}]") or (block == "encoder" and label == f"v_prev[{i}]"):
            return (ref.velocity[i], f"{block} {label}", ref.velocity_units[i],
                    f"the reference's largest speed plus {VELOCITY_MARGIN[ref.kinds[i]]:g} {ref.velocity_units[i]}")
        if block == "observer" and label == f"z[{i}]":
            y_row = np.abs(gain[i])                      # (n,) for one run, (n, N) for a batch
            reach = (y_row * (ref.velocity if y_row.ndim == 1 else ref.velocity[:, None])).sum(axis=0)
            return (force + reach, f"observer z[{i}] (= d_hat - Y dq)", ref.force_units[i],
                    f"{FORCE_FACTOR:g} x the largest force at the start for d_hat, plus Y dq within the velocity "
                    "bounds")
    return np.inf, f"{block} {label}", "", "finite"


def _labelled_bounds(labels, ref: ReferenceLimits, force, gain) -> StateBounds:
    """Bounds for states given as ``(block name, state label)`` pairs."""
    bounds, names, units, reasons = [], [], [], []
    for block, label in labels:
        bound, name, unit, reason = _bound_of(block, label, ref, force, gain)
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
    """The bounds of :mod:`this module <blocks.divergence>` for the states of an interconnected ``loop``.

    ``loop`` is the continuous loop (:func:`blocks.closed_loop`) or the sampled one
    (:func:`blocks.digital_loop.sampled_loop`): anything with ``syslist`` of blocks with ``state_labels``.
    """
    s = scenario
    ref = reference_limits(s, samples)
    spec = kernel_disturbance_params(s.disturbance, s.robot)
    force = float(force_bounds(s.robot.kernel_params(), spec, ref, s.robot.kernels, s.robot.tool_kernels,
                               evaluation_kernels(s.robot)))
    labels = [(block.name, label) for block in loop.syslist for label in block.state_labels]
    return _labelled_bounds(labels, ref, force, np.asarray(s.observer_gain, dtype=float))


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
    """Per-member bounds (nstates, N) of a batch (:class:`blocks.batch.members.MemberLoop`).

    ``labels`` are ``(block, label)`` pairs in the engine's state order; by
    default the numpy batch's rows ``q; dq; z``.
    """
    b = batch_loop
    ref = reference_limits(b.v.base)
    n = b.joints
    if isinstance(b.k_true, np.ndarray):        # the RRPR's constants, one column per member
        force = force_bounds(b.k_true, b.disturbance, ref)                               # (N,)
    else:                                       # another arm: the members share the true arm, not its numbers' layout
        force = _shared_arm_force_bounds(b.k_true, b.arm, b.disturbance, ref, b.n)
    if labels is None:
        labels = [("plant", f"q[{i}]") for i in range(n)] + [("plant", f"dq[{i}]") for i in range(n)]
        if b.observer:
            labels += [("observer", f"z[{i}]") for i in range(n)]
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
    return _labelled_bounds([("plant", name) for name in names], ref, force, np.asarray(s.observer_gain, dtype=float))


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
