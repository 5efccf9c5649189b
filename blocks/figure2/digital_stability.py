"""Is the sampled loop stable?  Its linearized one-sample map, spectral radius and largest stable observer gain.

This is the one computation of the digital loop's stability
(:mod:`blocks.diagram.digital`): the pre-run check
(:func:`blocks.figure2.digital_loop.check_observer_rate`) and the analysis
(:func:`analysis.linear.digital.observer_gain_limit`) both call it.

The loop is linearized at rest at a frozen configuration ``q`` on the
nominal model (perfect model, constant disturbance): the Coriolis terms are
quadratic in ``q'`` and the inertia's slope multiplies a residual that is
zero at rest, so neither enters; gravity's slope ``S = dG/dq``
(:func:`blocks.model.arm_derivatives.gravity_slopes`) does, because the plant
feels ``G(q(t))`` through the sample while the controller and the observer
evaluate it at the sampled ``q_k``.  In deviations from rest, with
``A = -Y M^-1`` and the state
``x = [q, v, z, p, w_prev, b_0 .. b_{d-1}]`` (positions, velocities, the
observer's ``z``; the encoder's previous position and velocity estimate
with ``velocity = "difference"``; the ``d`` buffered commands, oldest
first), a sample reads

* velocity estimate ``w = v`` (measured) or
  ``w = a w_prev + (1 - a) (q - p) / Ts`` (difference, ``a`` the low-pass pole),
* estimate ``d_hat = Y w + z``, command ``c = -M (Kp q + Kd w) + S q - d_hat``,
  applied torque ``tau = c`` (delay 0) or ``b_0``,
* plant ``q'' = M^-1 (tau - S q)`` under the held torque, exact:
  ``[q+, v+] = e^{F Ts} [q, v] + (int_0^Ts e^{F s} ds) [0, M^-1 tau]`` with
  ``F = [[0, I], [-M^-1 S, 0]]``; without gravity's slope (``S = 0``, the
  paper's arm) ``q+ = q + Ts v + Ts^2 / 2 M^-1 tau``, ``v+ = v + Ts M^-1 tau``,
* observer, ``z' = A (tau + Y w + z - S q) - w16 Y w`` (``w16`` = 1 for the paper's
  printed Eq. 16, else 0) by forward Euler, ``z+ = z + Ts z'``, or exactly with
  ``tau``, ``w`` held (``"zoh"``): ``z+ = e^{A Ts} z + (int_0^Ts e^{A s} ds) (z' - A z)``,
* ``p+ = q``, ``w_prev+ = w``, ``b+ = [b_1 .. b_{d-1}, c]``.

The loop is stable at ``q`` when the map's spectral radius is below 1.
Only forward Euler with measured velocity has a closed form: without
gravity's slope the estimate's error obeys ``e+ = (I + Ts A) e`` whatever
the torque, the map is block-triangular and the limit is
``Ts lambda_max(Y M^-1) < 2`` (for real eigenvalues), with or without a
delay as long as the delayed PD loop is stable.  Gravity's slope couples
the error to the motion within the sample (by ``Y M^-1 S`` times the
position's change over it, of order ``Ts^2``), which moves that limit
slightly, either way.  With ``"zoh"`` or a velocity difference the error and the
tracking couple and the limit is lower, and a delay lowers it further:
for ``Kp = 180``, ``Kd = 36`` the zoh loop with measured velocity loses
stability at ``Ts lambda_max = 1.9795`` at 1 kHz and ``1.7899`` at 100 Hz
(``docs/model.md``, "Digital observer").

Examples
--------
>>> import numpy as np
>>> from blocks.model.default import default_arm
>>> from blocks.diagram.digital import DigitalController
>>> from blocks.figure2.digital_stability import sampled_stability
>>> q = np.array([[0.3, 1.2, 0.1, 0.2]])
>>> s = sampled_stability(default_arm(), q, 180.0 * np.eye(4), 36.0 * np.eye(4), 10.0 * np.eye(4),
...                       DigitalController(sample_rate=100.0, observer_discretization="zoh"))
>>> round(s.ts_lambda_limit, 3)      # Ts lambda_max(Y M^-1) at the limit, below Euler's 2
1.79
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blocks.diagram.digital import DigitalController
from blocks.model import arm_derivatives
from blocks.model.arm import ArmModel

__all__ = ["SampledStability", "held_exponential", "sampled_loop_map", "spectral_radius", "largest_stable_scale",
           "sampled_stability", "path_configurations", "scenario_stability"]

#: Relative width at which the bisection on the observer gain's scale stops.
SCALE_RTOL = 1e-7
#: Past this many times the first guess the gain is taken as unlimited (``inf``).
_UNBOUNDED = 1e6
#: Below this many times the first guess no observer gain is stable (the PD loop itself is not): scale 0.
_NONE_STABLE = 1e-9


@dataclass(frozen=True)
class SampledStability:
    """The sampled loop's stability over a set of frozen configurations.

    Attributes
    ----------
    stable : bool
        Spectral radius below 1 at every configuration.
    spectral_radius : float
        Largest ``|z|`` over the configurations, with the given gain.
    q_worst : list of float
        The configuration of that radius (rad, m).
    largest_stable_scale : float
        The factor ``c`` at which the radius reaches 1 (the gain ``c Y`` is
        the largest stable one of this shape); ``inf`` if no limit was found
        below ``1e6`` times the Euler bound, 0 if no observer gain is stable.
    ts_lambda_max : float
        ``Ts lambda_max(Y M^-1)`` of the given gain, largest over the configurations (largest ``|lambda|``).
    ts_lambda_limit : float
        ``ts_lambda_max`` times ``largest_stable_scale``: the rule ``Ts lambda_max(Y M^-1) < ts_lambda_limit``
        for these settings (2 for Euler with measured velocity and a stable PD loop).
    """

    stable: bool
    spectral_radius: float
    q_worst: list
    largest_stable_scale: float
    ts_lambda_max: float
    ts_lambda_limit: float


def _settings_of(settings: DigitalController) -> tuple[float, str, bool, float, int]:
    if not isinstance(settings, DigitalController):
        raise TypeError(f"settings must be a blocks.diagram.digital.DigitalController, got {type(settings).__name__}")
    return (settings.period, settings.observer_discretization, settings.velocity == "difference",
            settings.filter_pole, settings.delay)


def held_exponential(A, period: float) -> tuple[np.ndarray, np.ndarray]:
    """``e^{A Ts}`` and ``int_0^Ts e^{A s} ds`` for a stack of matrices ``A`` (..., n, n).

    Both are blocks of the exponential of ``[[A, I], [0, 0]] Ts``, taken by
    scaling and squaring a Taylor series (norm scaled to 1/2, 18 terms:
    truncation below 1e-22) with numpy's stacked products, which stay fast
    for many small matrices where :func:`scipy.linalg.expm` calls the BLAS
    once per matrix.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[-1]
    aug = np.zeros(A.shape[:-2] + (2 * n, 2 * n))
    aug[..., :n, :n], aug[..., :n, n:] = A * period, np.eye(n) * period
    norm = float(np.abs(aug).sum(axis=-2).max()) if aug.size else 0.0
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    X = aug / 2.0 ** squarings
    term = np.broadcast_to(np.eye(2 * n), aug.shape).copy()
    total = term.copy()
    for j in range(1, 19):
        term = term @ X / j
        total += term
    for _ in range(squarings):
        total = total @ total
    return total[..., :n, :n], total[..., :n, n:]


def sampled_loop_map(inertias, kp, kd, gain, settings: DigitalController, eq16_weight: float = 0.0,
                     gravity_slopes=None) -> np.ndarray:
    """The linearized loop's one-sample map ``x_{k+1} = Phi x_k`` at frozen inertias (see the module docstring).

    Parameters
    ----------
    inertias : array_like, shape (..., n, n)
        Nominal inertia ``M(q)`` at each configuration (kg m^2, kg on a prismatic joint).
    kp, kd : array_like, shape (n, n)
        Diagonal controller gains (1/s^2, 1/s); as the digital controller, only their diagonals are used.
    gain : array_like, shape (n, n)
        Observer gain ``Y`` (kg m^2/s, kg/s on a prismatic joint).
    settings : DigitalController
        Rate, observer discretization, velocity source and filter, delay.
    eq16_weight : float
        1 for the paper's printed Eq. 16 (an extra ``- Y q'``), 0 for the correct law.
    gravity_slopes : array_like, shape (..., n, n), optional
        ``dG/dq`` at each configuration (N m/rad, N/m; :func:`blocks.model.arm_derivatives.gravity_slopes`).
        None or all zero: the closed-form double integrator (the paper's arm, whose gravity is constant).

    Returns
    -------
    numpy.ndarray, shape (..., m, m)
        ``m = n (3 + 2 [difference velocity] + delay)``, the state ordered as in the module docstring.
    """
    Ts, method, difference, pole, delay = _settings_of(settings)
    M = np.asarray(inertias, dtype=float)
    n = M.shape[-1]
    Kp, Kd = np.diag(np.diag(np.asarray(kp, dtype=float))), np.diag(np.diag(np.asarray(kd, dtype=float)))
    Y = np.asarray(gain, dtype=float)
    batch = M.shape[:-2]
    blocks_ = 3 + 2 * difference + delay
    m = n * blocks_
    eye = np.eye(n)

    def unit(j: int) -> np.ndarray:
        """The selector of state block ``j`` (n x m)."""
        out = np.zeros((n, m))
        out[:, j * n:(j + 1) * n] = eye
        return out
    Q, V, Z = unit(0), unit(1), unit(2)
    if difference:
        P, Wp = unit(3), unit(4)
        W = pole * Wp + (1.0 - pole) / Ts * (Q - P)
    else:
        W = V
    d_hat = Y @ W + Z
    S = None if gravity_slopes is None or not np.any(gravity_slopes) else np.asarray(gravity_slopes, dtype=float)
    command = -M @ (Kp @ Q + Kd @ W) - d_hat                       # (..., n, m)
    if S is not None:
        command = command + S @ Q                                   # the controller's h(q_k): gravity at q_k
    tau = command if delay == 0 else np.broadcast_to(unit(blocks_ - delay), command.shape)
    Minv = np.linalg.inv(M)
    accel = Minv @ tau
    Phi = np.zeros(batch + (m, m))
    if S is None:
        Phi[..., 0:n, :] = Q + Ts * V + 0.5 * Ts ** 2 * accel
        Phi[..., n:2 * n, :] = V + Ts * accel
    else:
        # the plant between samples, [q, v]' = F [q, v] + [0, M^-1 tau], with tau held: its exact step
        F = np.zeros(batch + (2 * n, 2 * n))
        F[..., :n, n:] = eye
        F[..., n:, :n] = -Minv @ S
        step, integral = held_exponential(F, Ts)
        Phi[..., 0:2 * n, :] = step @ np.concatenate([Q, V]) + integral[..., :, n:] @ accel
    A = -Y @ Minv
    residual = tau + Y @ W + Z if S is None else tau + Y @ W + Z - S @ Q     # the observer's h(q_k) too
    rate = A @ residual - eq16_weight * (Y @ W)                        # z' as a row map of x
    if method == "euler":
        Phi[..., 2 * n:3 * n, :] = Z + Ts * rate
    else:
        held, integral = held_exponential(A, Ts)
        Phi[..., 2 * n:3 * n, :] = held @ Z + integral @ (rate - A @ Z)
    if difference:
        Phi[..., 3 * n:4 * n, :] = Q
        Phi[..., 4 * n:5 * n, :] = np.broadcast_to(W, batch + W.shape)
    if delay:
        first = (blocks_ - delay) * n
        for j in range(delay - 1):
            Phi[..., first + j * n:first + (j + 1) * n, :] = unit(blocks_ - delay + j + 1)
        Phi[..., m - n:m, :] = command
    return Phi


def spectral_radius(inertias, kp, kd, gain, settings: DigitalController, eq16_weight: float = 0.0,
                    gravity_slopes=None) -> np.ndarray:
    """``max |z|`` of :func:`sampled_loop_map` at each configuration, shape ``inertias.shape[:-2]``."""
    Phi = sampled_loop_map(inertias, kp, kd, gain, settings, eq16_weight, gravity_slopes)
    return np.abs(np.linalg.eigvals(Phi)).max(axis=-1)


def largest_stable_scale(inertias, kp, kd, gain, settings: DigitalController, eq16_weight: float = 0.0,
                         rtol: float = SCALE_RTOL, gravity_slopes=None) -> float:
    """The largest ``c`` with the loop stable (radius < 1) at every configuration with observer gain ``c Y``.

    Bisection in ``log c`` on the largest spectral radius over the
    configurations, started from the Euler bound ``2 / (Ts lambda_max)``; the
    result is the stable end of the last bracket, within ``rtol`` below the
    limit.  Once a bracket's unstable end is found, only the configurations
    unstable there are kept (the others' limits lie above it).

    ``gravity_slopes``: ``dG/dq`` per configuration, as in :func:`sampled_loop_map`.

    Returns
    -------
    float
        ``inf`` when the loop is still stable at ``1e6`` times the Euler bound,
        0 when no observer gain is stable (the PD loop is unstable at this rate).
    """
    M = np.asarray(inertias, dtype=float)
    M = M.reshape((-1,) + M.shape[-2:])
    S = None if gravity_slopes is None else np.asarray(gravity_slopes, dtype=float).reshape(M.shape)
    Y = np.asarray(gain, dtype=float)
    active = np.arange(len(M))

    def unstable(c: float) -> np.ndarray:
        """The active configurations where the gain ``c Y`` is unstable."""
        radii = spectral_radius(M[active], kp, kd, c * Y, settings, eq16_weight, None if S is None else S[active])
        return active[radii >= 1.0]
    lam = np.abs(np.linalg.eigvals(Y @ np.linalg.inv(M))).max()
    guess = 2.0 / (settings.period * lam)
    lo, hi = guess, guess
    if unstable(guess).size == 0:
        while (bad := unstable(hi)).size == 0:
            lo, hi = hi, 2.0 * hi
            if hi > _UNBOUNDED * guess:
                return math.inf
    else:
        while (bad := unstable(lo)).size:
            hi, lo = lo, lo / 2.0
            if lo < _NONE_STABLE * guess:
                return 0.0
        bad = unstable(hi)
    # configurations stable at hi have their limit above it: only those unstable there can bind
    active = bad
    while hi > lo * (1.0 + rtol):
        mid = math.sqrt(lo * hi)
        bad = unstable(mid)
        if bad.size:
            hi, active = mid, bad
        else:
            lo = mid
    return float(lo)


def sampled_stability(nominal: ArmModel, configurations, kp, kd, gain, settings: DigitalController,
                      variant: str = "correct", limit: bool = True) -> SampledStability:
    """The loop's stability over frozen configurations, and the largest stable scale of the observer gain.

    Parameters
    ----------
    nominal : ArmModel
        The nominal model (controller and observer; the plant is taken equal to it),
        any arm: ``n`` joints from ``nominal.n``; its gravity slope ``dG/dq`` at each configuration
        enters the map (:func:`sampled_loop_map`).
    configurations : array_like, shape (N, n)
        Joint positions (rad, m).  Configurations with equal
        inertia and gravity slope are checked once.
    kp, kd, gain : array_like, shape (n, n)
        Controller gains (1/s^2, 1/s) and observer gain ``Y``.
    settings : DigitalController
        The digital controller's settings.
    variant : {"correct", "paper-eq16"}
        The observer law.
    limit : bool
        Compute the largest stable scale (a bisection); if False it is ``nan``.
    """
    if not isinstance(nominal, ArmModel):
        raise TypeError(f"nominal must be a blocks.model.arm.ArmModel, got {type(nominal).__name__}")
    q = np.atleast_2d(np.asarray(configurations, dtype=float))
    if q.ndim != 2 or q.shape[-1] != nominal.n or not np.all(np.isfinite(q)):
        raise ValueError(f"configurations must be finite joint positions of shape (N, {nominal.n}) for the joints "
                         f"{list(nominal.joints.names)}, got shape {q.shape}")
    M_all = nominal.inertia(q)
    S_all = arm_derivatives.gravity_slopes(nominal, q)
    key = M_all.reshape(len(q), -1)
    if np.any(S_all):                       # configurations differing only in gravity's slope are not one
        key = np.concatenate([key, S_all.reshape(len(q), -1)], axis=1)
    _, first = np.unique(np.round(key, 12), axis=0, return_index=True)
    first = np.sort(first)
    q, M, S = q[first], M_all[first], (S_all[first] if np.any(S_all) else None)
    weight = 1.0 if variant == "paper-eq16" else 0.0
    Y = np.asarray(gain, dtype=float)
    radii = spectral_radius(M, kp, kd, Y, settings, weight, S)
    worst = int(np.argmax(radii))
    ts_lam = settings.period * float(np.abs(np.linalg.eigvals(Y @ np.linalg.inv(M))).max())
    scale = largest_stable_scale(M, kp, kd, Y, settings, weight, gravity_slopes=S) if limit else math.nan
    return SampledStability(stable=bool(radii.max() < 1.0), spectral_radius=float(radii[worst]),
                            q_worst=q[worst].tolist(), largest_stable_scale=scale, ts_lambda_max=ts_lam,
                            ts_lambda_limit=ts_lam * scale)


def path_configurations(scenario, samples: int = 201) -> np.ndarray:
    """The reference path's positions at ``samples`` times evenly over ``[0, t_final]``, shape (samples, n)."""
    times = np.linspace(0.0, scenario.simulation.t_final, samples)
    return np.array([scenario.trajectory.evaluate(float(t))[0] for t in times])


def scenario_stability(scenario, samples: int = 201, limit: bool = True, **changes) -> SampledStability:
    """:func:`sampled_stability` of a scenario's digital loop over its reference path.

    Parameters
    ----------
    scenario : Scenario
        With a ``[controller]`` section.
    samples : int
        Configurations of the path checked.
    limit : bool
        Compute the largest stable scale of ``gains.observer``.
    **changes
        Fields of the scenario's :class:`~blocks.diagram.digital.DigitalController` to replace
        (``observer_discretization="euler"``, ``sample_rate=200.0``, ...).
    """
    settings = scenario.controller
    if not isinstance(settings, DigitalController):
        raise ValueError(f"scenario '{scenario.name}' has no [controller] section: it describes a continuous "
                         "controller")
    if changes:
        from dataclasses import replace
        settings = replace(settings, **changes)
    return sampled_stability(scenario.nominal, path_configurations(scenario, samples), scenario.kp, scenario.kd,
                             scenario.observer_gain, settings, scenario.observer_variant, limit=limit)
