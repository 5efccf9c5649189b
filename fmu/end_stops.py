"""End stops of the plant FMU: where an arm's joint ranges end, and how hard the stop pushes back.

A joint with a limit (a finite side of :attr:`blocks.model.joints.JointSpace.limits`:
the RRPR's slide ``d3`` from 0 to 0.48 m, a URDF joint's ``<limit lower upper>``)
gets a spring-damper at each finite end, as a rubber-buffered mechanical stop::

    q > upper:  f = min(0, -k (q - upper) - c q')        (pushes down, never pulls)
    q < lower:  f = max(0,  k (lower - q) - c q')        (pushes up, never pulls)
    otherwise:  f = 0                                     (the arm's dynamics untouched)

``f`` (N m or N) adds to the actuator force of that joint.  Inside the range
the C takes the very path it takes without stops, so the FMU there gives the
same numbers, bit for bit, as an FMU exported with ``end_stops=False``.

Stiffness and damping are the FMU's parameters ``stop_stiffness[i]`` and
``stop_damping[i]`` (one pair per bounded joint ``i``), with start values set
from the arm's inertia: the stop of joint ``i`` alone has the natural
frequency :data:`STOP_FREQUENCY` and the damping ratio :data:`STOP_DAMPING_RATIO`
(critical: no bounce)::

    m_i = min over poses of 1 / (M(q)^-1)_ii      (the inertia the joint shows when the others move freely)
    k_i = m_i w^2,   c_i = 2 zeta m_i w

The minimum over :data:`POSES` poses drawn in the joint ranges (a fixed seed,
so an export is reproducible) is the pose where the stop rings fastest; there
its eigenvalues are ``-w`` (twice).  Classical RK4 is stable on the negative
real axis up to ``|lambda dt| = 2.785``: with ``w = 200 rad/s`` every RK4
sub-step up to 13.9 ms is stable, which at the default 4 sub-steps is a
communication step up to 55 ms (the FMU's default experiment step is 1 ms:
``w dt = 0.05``).  Under a steady force ``F`` the stop gives by ``F / k``:
gravity on the RRPR's slide (0.25 kg) compresses it by ``g / w^2 = 0.245 mm``.
The solver of Model Exchange (an implicit BDF, fmpy's CVode) is not limited by
the stop's stiffness.  With several joints on their stops at once the stiffness
matrix couples them through ``M^-1``: the fastest mode reaches up to
``sqrt(n) w`` (the eigenvalues of a unit-diagonal positive definite matrix lie
below n), so RK4 stays stable for ``w dt < 2.785 / sqrt(n)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EndStop", "end_stops", "effective_inertia", "STOP_FREQUENCY", "STOP_DAMPING_RATIO", "POSES",
           "RK4_REAL_STABILITY"]

#: Natural frequency of every stop at the pose where it rings fastest (rad/s): about 32 Hz, stiff against the
#: arm's own motion (a few Hz) and stable for RK4 sub-steps up to 13.9 ms.
STOP_FREQUENCY = 200.0
#: Damping ratio of the stops: critical damping, a stop that absorbs the impact without bouncing.
STOP_DAMPING_RATIO = 1.0
#: Poses drawn in the joint ranges to find each joint's smallest effective inertia.
POSES = 64
#: Where classical RK4's stability region meets the negative real axis (|lambda dt|).
RK4_REAL_STABILITY = 2.785


@dataclass(frozen=True)
class EndStop:
    """The stop of one bounded joint.

    Attributes
    ----------
    joint : int
        Joint index (0-based, as in ``q[i]``).
    name : str
        Joint name.
    lower, upper : float
        The joint's range (rad or m); ``-inf`` / ``inf`` for an open side.
    stiffness : float
        Start value of ``stop_stiffness[i]`` (N m/rad or N/m).
    damping : float
        Start value of ``stop_damping[i]`` (N m s/rad or N s/m).
    inertia : float
        The effective inertia the values were set from (kg m^2 or kg).
    """

    joint: int
    name: str
    lower: float
    upper: float
    stiffness: float
    damping: float
    inertia: float


def _poses(arm, count: int, seed: int) -> np.ndarray:
    """``count`` joint positions in the arm's ranges (an open range: one turn, or +-1 m), shape (count, n)."""
    rng = np.random.default_rng(seed)
    lows, highs = [], []
    for (lo, hi), kind in zip(arm.joints.limits, arm.joints.kinds):
        span = math.pi if kind == "revolute" else 1.0
        lows.append(lo if math.isfinite(lo) else (hi - 2 * span if math.isfinite(hi) else -span))
        highs.append(hi if math.isfinite(hi) else (lo + 2 * span if math.isfinite(lo) else span))
    return rng.uniform(lows, highs, size=(count, arm.n))


def effective_inertia(arm, q0=None, poses: int = POSES, seed: int = 0) -> np.ndarray:
    """Each joint's smallest effective inertia ``1 / (M(q)^-1)_ii`` over ``q0`` and ``poses`` poses in its range.

    Parameters
    ----------
    arm : blocks.model.arm.ArmModel
    q0 : n floats, optional
        A pose to include (the FMU's start pose).
    poses : int
        Poses drawn uniformly in the joint ranges (fixed ``seed``).

    Returns
    -------
    numpy.ndarray
        Shape (n,), kg m^2 on revolute joints, kg on prismatic ones.
    """
    q = _poses(arm, poses, seed)
    if q0 is not None:
        q = np.vstack([np.asarray(q0, dtype=float).reshape(1, arm.n), q])
    inv_diag = np.array([np.diag(np.linalg.inv(arm.inertia(row))) for row in q])
    return 1.0 / inv_diag.max(axis=0)


def end_stops(arm, q0=None) -> list[EndStop]:
    """The stops of an arm's bounded joints, stiffness and damping set from its inertia (see the module docstring).

    Examples
    --------
    >>> from blocks.scenarios.scenario import default_arm
    >>> [(s.name, s.lower, s.upper, round(s.stiffness), round(s.damping)) for s in end_stops(default_arm())]
    [('d3', 0.0, 0.48, 10000, 100)]
    """
    bounded = [i for i, (lo, hi) in enumerate(arm.joints.limits) if math.isfinite(lo) or math.isfinite(hi)]
    if not bounded:
        return []
    m = effective_inertia(arm, q0)
    w, zeta = STOP_FREQUENCY, STOP_DAMPING_RATIO
    return [EndStop(joint=i, name=arm.joints.names[i], lower=arm.joints.limits[i][0], upper=arm.joints.limits[i][1],
                    stiffness=float(m[i] * w * w), damping=float(2.0 * zeta * m[i] * w), inertia=float(m[i]))
            for i in bounded]
