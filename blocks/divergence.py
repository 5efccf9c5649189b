"""When a run has diverged: bounds on the physical signals, derived from the scenario.

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

States of other blocks (an FMU's own states, a user's blocks, the digital
controller's buffers) are judged only for being finite.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import gravity, inverse_dynamics

__all__ = ["StateBounds", "state_bounds", "POSITION_MARGIN", "VELOCITY_MARGIN", "FORCE_FACTOR"]

#: Added to the reference's largest position (rad for revolute joints, m for prismatic ones).
POSITION_MARGIN = {"revolute": 100.0, "prismatic": 10.0}
#: Added to the reference's largest speed (rad/s, m/s).
VELOCITY_MARGIN = {"revolute": 1e3, "prismatic": 1e2}
#: The disturbance estimate's bound in multiples of the largest force in the scenario.
FORCE_FACTOR = 1e3


@dataclass(frozen=True)
class StateBounds:
    """A bound per loop state (``inf`` where only finiteness is judged), and what each state is.

    Attributes
    ----------
    bounds : numpy.ndarray
        Largest magnitude of each state.
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

    def describe(self, x: np.ndarray) -> str:
        """Which state is out of bounds (or not finite) in ``x``, as a sentence."""
        x = np.asarray(x, dtype=float)
        bad = ~np.isfinite(x)
        if bad.any():
            k = int(np.argmax(bad))
            return f"{self.names[k]} became {x[k]}"
        k = int(np.argmax(np.abs(x) / self.bounds))
        value, bound = _apart(float(x[k]), float(self.bounds[k]))
        return (f"{self.names[k]} reached {value} {self.units[k]}, beyond its bound {bound} "
                f"{self.units[k]} ({self.reasons[k]})")


def _apart(value: float, bound: float) -> tuple[str, str]:
    """``value`` and ``bound`` with as many digits (4 at least) as it takes for a value beyond the bound to read
    beyond it: 100.2 and 100.2 become 100.23 and 100.2."""
    for digits in range(4, 18):
        a, b = f"{abs(value):.{digits}g}", f"{bound:.{digits}g}"
        if a != b:
            break
    return f"{value:.{digits}g}", b


def state_bounds(loop, scenario, samples: int = 201) -> StateBounds:
    """The bounds of :mod:`this module <blocks.divergence>` for the states of an interconnected ``loop``."""
    s = scenario
    joints = s.robot.joints
    times = np.linspace(0.0, s.simulation.t_final, samples)
    refs = [np.array(a) for a in zip(*(s.trajectory.evaluate(float(t)) for t in times))]   # (T, 4) each
    q_ref, dq_ref, ddq_ref = refs
    pos = np.abs(q_ref).max(axis=0) + np.array([POSITION_MARGIN[k] for k in joints.kinds])
    vel = np.abs(dq_ref).max(axis=0) + np.array([VELOCITY_MARGIN[k] for k in joints.kinds])
    q0, dq0 = q_ref[0], dq_ref[0]
    from .disturbances import external_disturbance
    forces = np.abs(external_disturbance(0.0, q0, dq0, s.disturbance, s.robot)) + np.abs(gravity(q0, s.robot)) \
        + np.abs(inverse_dynamics(q0, dq0, ddq_ref[0], s.robot))
    force = FORCE_FACTOR * (forces.max() + 1.0)
    Y = np.abs(np.asarray(s.observer_gain))
    bounds, names, units, reasons = [], [], [], []
    for block in loop.syslist:
        labels = list(block.state_labels)
        for label in labels:
            bound, name, unit, reason = np.inf, f"{block.name} {label}", "", "finite"
            for i in range(joints.count):
                if block.name == "plant" and label == f"q[{i}]":
                    bound, name, unit = pos[i], f"plant q[{i}]", joints.position_units[i]
                    reason = f"the reference's largest |q[{i}]| plus {POSITION_MARGIN[joints.kinds[i]]:g} {unit}"
                elif block.name == "plant" and label == f"dq[{i}]":
                    bound, name, unit = vel[i], f"plant dq[{i}]", joints.velocity_units[i]
                    reason = f"the reference's largest speed plus {VELOCITY_MARGIN[joints.kinds[i]]:g} {unit}"
                elif block.name == "observer" and label == f"z[{i}]":
                    bound, unit = force + float(Y[i] @ vel), joints.force_units[i]
                    name = f"observer z[{i}] (= d_hat - Y dq)"
                    reason = (f"{FORCE_FACTOR:g} x the largest force at the start for d_hat, plus Y dq within the "
                              "velocity bounds")
            bounds.append(bound)
            names.append(name)
            units.append(unit)
            reasons.append(reason)
    return StateBounds(np.array(bounds, dtype=float), names, units, reasons)
