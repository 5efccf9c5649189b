"""The Figure-2 loop linearized at an operating point: poles, modes and robustness to model mismatch.

The operating point is the arm held at a configuration ``q0`` (a constant
reference), the scenario's disturbance acting at time ``t`` and every block at
equilibrium.  With the observer the arm rests exactly at ``q0`` and
``d_hat = d`` (the lumped disturbance); without it the arm rests at
``q0 + Kp^-1 M^-1 d`` (docs/model.md).  The equilibrium is solved for with
:func:`control.find_operating_point` on the interconnected system itself, and
the loop is linearized with :func:`control.linearize` -- nothing about the
loop is written twice.

Analytic split (perfect model, docs/model.md): the closed-loop poles are the
roots of ``s^2 + Kd_i s + Kp_i`` for every joint (the PD error dynamics) and,
with the observer, the eigenvalues of ``-Y M^-1(q0)`` (the observer error
dynamics ``e_d' = -Y M^-1 e_d``).

The joint count, names and units come from the scenario's arm model
(``scenario.nominal``, a :class:`~blocks.model.arm.ArmModel`).  For an arm model
without a scenario, :mod:`analysis.linear.arm_linear` linearizes the same loop from the
model's own derivatives (it agrees with this module on the paper's arm to 1e-10).

Model mismatch: with the nominal masses and inertias scaled by ``a`` the nominal
inertia is ``M^ = a M``.  Linearizing by hand then gives the characteristic
polynomial matrix ``s^2 (s M + Y) + (a s M + Y)(s Kd + Kp)`` with the observer
and ``s^2 I + a (s Kd + Kp)`` without it (see :func:`mismatch_polynomial`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg
from scipy.optimize import brentq, linear_sum_assignment

from analysis.linear.arm_linear import arm_analytic_poles
from analysis.linear.arm_terms import joint_vector
from analysis.results import JsonResult
from blocks import closed_loop, external_disturbance
from blocks.scenarios.scenario import Scenario

__all__ = [
    "INERTIA_PARAMETERS", "EQUILIBRIUM_RTOL", "Mode", "ModeResult", "OperatingPoint", "MismatchSweep",
    "StabilityBoundary", "BoundaryScan", "BoundarySearch", "MismatchLoop", "MismatchStudy", "hold_scenario",
    "first_seconds", "scale_nominal_inertia", "equilibrium", "linearize_loop", "loop_modes", "analytic_poles",
    "match_poles", "operating_point_analysis", "spectral_abscissa", "mismatch_sweep", "stability_boundaries",
    "mismatch_analysis", "mismatch_polynomial", "boundary_search", "arm_mismatch_analysis",
]

# Scaling all of these by ``a`` scales the inertia matrix M(q) (and gravity) by ``a``.
INERTIA_PARAMETERS = ("m1", "m2", "m3", "m4", "I1", "I2", "I3", "I4")

# Central difference step of the linearization (state units: rad, m, rad/s, m/s, N m).  Averaging
# ct.linearize with +h and -h cancels the O(h) error of its forward difference.
LINEARIZATION_STEP = 1e-5

# An equilibrium is accepted when its Newton correction (its distance from the rest, in the state's units) is at
# most this times (1 + largest |state|): far below the linearization step of 1e-5.
EQUILIBRIUM_RTOL = 1e-8


def hold_scenario(scenario: Scenario, q0, disturbance: dict | None = None, **sections) -> Scenario:
    """The scenario with the reference held at ``q0``, the arm starting there at rest, and no measurement noise.

    Derived with :meth:`Scenario.replace`: the trajectory becomes a
    ``joint_sine`` of zero amplitude with offset ``q0``; the noise standard
    deviations become zero; the initial state is set explicitly to ``q0`` at
    rest with ``d_hat(0) = 0`` (so a start state given for the scenario's own
    path does not carry over).  Everything else (models, gains, disturbance,
    solver settings) is the scenario's.

    Parameters
    ----------
    scenario : Scenario
    q0 : array_like, shape (n,)
        Held configuration (rad, m).
    disturbance : dict, optional
        Keys of the ``[disturbance]`` table to change (merged, as :meth:`Scenario.replace` does).
    **sections : dict
        Further sections to change (merged), e.g. ``gains={"kp": 90.0}``.
    """
    q0 = _joint_vector(q0, "q0", scenario)
    zeros = [0.0] * len(q0)
    changes = {
        "trajectory": {"kind": "joint_sine", "amplitude": zeros, "omega": 1.0, "offset": q0.tolist()},
        "noise": {"q_std": zeros, "dq_std": zeros},
        "initial": {"q": q0.tolist(), "dq": zeros, "d_hat": zeros},
    }
    if disturbance is not None:
        changes["disturbance"] = disturbance
    for key, value in sections.items():
        changes[key] = {**changes.get(key, {}), **value} if isinstance(value, dict) else value
    return scenario.replace(**changes)


def first_seconds(scenario: Scenario, t_final: float | None, **sections) -> Scenario:
    """The first ``t_final`` seconds of the scenario's run (the same path, not a compressed one).

    The path keeps its own duration (``simulation.t_final`` never rescales it);
    it is also written into the changes here.  Other sections can be changed at the
    same time (merged, as :meth:`Scenario.replace` does).  ``t_final=None``
    keeps the run length.
    """
    changes = dict(sections)
    if t_final is not None:
        changes["simulation"] = {**changes.get("simulation", {}), "t_final": float(t_final)}
        duration = getattr(scenario.trajectory, "duration", None)
        if duration is not None and "trajectory" not in changes:
            changes["trajectory"] = {"duration": float(duration)}
    return scenario.replace(**changes)


def scale_nominal_inertia(scenario: Scenario, factor: float) -> Scenario:
    """The scenario with every nominal mass and inertia multiplied by ``factor`` (so ``M^ -> factor * M^``)."""
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise ValueError(f"inertia scale factor must be a finite number > 0, got {factor!r}")
    old = scenario.data["nominal_scale"]
    return scenario.replace(nominal_scale={k: float(old[k]) * float(factor) for k in INERTIA_PARAMETERS})


def _joint_vector(value, name: str, scenario: Scenario) -> np.ndarray:
    """``value`` as one finite number per joint of the scenario's arm."""
    return joint_vector(value, name, scenario.nominal.joints)


def _block_slices(system) -> dict:
    """State slices of each block of an interconnected system, by block name."""
    out, offset = {}, 0
    for block in system.syslist:
        out[block.name] = slice(offset, offset + block.nstates)
        offset += block.nstates
    return out


def equilibrium(loop, t: float = 0.0, inputs=None) -> np.ndarray:
    """The equilibrium state of a held loop (see :func:`hold_scenario`).

    The guess is the arm at its reference at rest and, with an observer,
    ``z = d`` (``d_hat = Y q' + z = d``) with ``d`` the external disturbance at
    the guess plus the nominal-minus-true gravity; the guess is then refined
    with :func:`control.find_operating_point`.

    Parameters
    ----------
    loop : control.InterconnectedSystem
        From :func:`blocks.closed_loop` (or a variant with external inputs).
    t : float
        Time (s) at which the (time-varying) disturbance is evaluated.
    inputs : array_like, optional
        Values of the loop's external inputs (default zero).

    Raises
    ------
    RuntimeError
        If no equilibrium is found near the guess: after the root finder and
        Newton steps on its answer (:func:`_polish`), the Newton correction --
        how far the state is from a rest, in the state's own units (rad, m,
        rad/s, m/s, N m) -- exceeds ``EQUILIBRIUM_RTOL * (1 + max|x|)``.  The
        state derivative itself is not compared with a fixed number: its size
        is the arm's (a light joint's accelerations are thousands of rad/s^2
        per radian), so a root the finder reports converged may leave
        3e-7 rad/s^2 that is a state 1e-9 rad from the rest.  The root
        finder's own flag is not used either: it reports failure when it
        merely stops improving on an already exact root.
    """
    s = loop.scenario
    n = s.nominal.n
    u0 = np.zeros(loop.ninputs) if inputs is None else np.asarray(inputs, dtype=float)
    q_ref, _, _ = s.trajectory.evaluate(t)
    x = np.zeros(loop.nstates)
    slices = _block_slices(loop)
    plant_labels = [b for b in loop.syslist if b.name == "plant"][0].state_labels
    for i in range(n):
        x[slices["plant"].start + plant_labels.index(f"q[{i}]")] = q_ref[i]
    if "observer" in slices:
        d = external_disturbance(t, q_ref, np.zeros(n), s.disturbance, s.robot) \
            + s.nominal.gravity_forces(q_ref) - s.robot.gravity_forces(q_ref)
        x[slices["observer"]] = d
    xeq, _, result = ct.find_operating_point(loop, x, u0, t=t, return_result=True)
    xeq, residual, distance = _polish(loop, t, np.asarray(xeq, dtype=float), u0)
    tolerance = EQUILIBRIUM_RTOL * (1.0 + float(np.max(np.abs(xeq))))
    if not np.all(np.isfinite(xeq)) or not distance <= tolerance:
        raise RuntimeError(f"no equilibrium found for loop '{loop.name}' of scenario '{s.name}' near q = "
                           f"{np.round(q_ref, 6).tolist()}: the best state found is {distance:.3g} from a rest "
                           f"(tolerance {tolerance:.3g}; largest state derivative there {residual:.3g}; root finder: "
                           f"{' '.join(result.message.split())})")
    return xeq


def _polish(loop, t: float, x: np.ndarray, u0: np.ndarray, steps: int = 4) -> tuple[np.ndarray, float, float]:
    """Newton steps on the loop's state derivative from the root finder's answer, and how far from a rest it is.

    The state derivative mixes units and sizes (rad/s, m/s, rad/s^2 and m/s^2 that a light wrist joint makes
    large, N m/s): a residual means nothing without the rates of the loop itself.  The Newton correction
    ``|A^-1 f(x)|`` (``A`` the Jacobian of the state derivative, central differences) is the distance to the
    rest in the state's own units (rad, m, rad/s, m/s, N m): that is what is judged.  A root finder that
    converged in its step (``xtol``) leaves a distance of that order whatever the accelerations' size.

    Returns
    -------
    (x, residual, distance)
        The polished state, its largest state derivative and its Newton correction's largest entry
        (inf where the Jacobian is singular or not finite).
    """
    def f(z):
        return np.asarray(loop.dynamics(t, z, u0), dtype=float)

    def newton(z):
        r = f(z)
        if not np.all(np.isfinite(r)):
            return r, None
        h = LINEARIZATION_STEP * (1.0 + np.abs(z))
        cols = [(f(z + hk * e) - f(z - hk * e)) / (2.0 * hk) for hk, e in zip(h, np.eye(len(z)))]
        A = np.array(cols).T
        try:
            dx = np.linalg.solve(A, r) if np.all(np.isfinite(A)) else None
        except np.linalg.LinAlgError:
            dx = None
        return r, dx

    best = None
    for _ in range(steps + 1):
        if not np.all(np.isfinite(x)):
            break
        r, dx = newton(x)
        distance = float(np.max(np.abs(dx))) if dx is not None and np.all(np.isfinite(dx)) else math.inf
        if best is None or distance < best[2]:
            best = (x, float(np.max(np.abs(r))), distance)
        if dx is None or distance > best[2] or distance <= 1e-15 * (1.0 + float(np.max(np.abs(x)))):
            break
        x = x - dx
    return best if best is not None else (x, math.inf, math.inf)


def linearize_loop(loop, x_eq, t: float = 0.0, inputs=None, step: float = LINEARIZATION_STEP) -> ct.StateSpace:
    """Linearize an interconnected loop at ``x_eq`` with :func:`control.linearize`, central differences.

    ``control.linearize`` uses a forward difference; averaging it with a step of
    ``+step`` and ``-step`` gives a central difference (error ``O(step^2)``).
    State, input and output names of the loop are kept.
    """
    u0 = np.zeros(loop.ninputs) if inputs is None else np.asarray(inputs, dtype=float)
    names = dict(states=list(loop.state_labels), inputs=list(loop.input_labels), outputs=list(loop.output_labels))
    plus = ct.linearize(loop, x_eq, u0, t=t, eps=step)
    minus = ct.linearize(loop, x_eq, u0, t=t, eps=-step)
    mats = [(p + m) / 2.0 for p, m in zip((plus.A, plus.B, plus.C, plus.D), (minus.A, minus.B, minus.C, minus.D))]
    return ct.ss(*mats, name=f"{loop.name}_linearized", **names)


@dataclass(frozen=True)
class Mode:
    """One closed-loop pole and the block it belongs to.

    Attributes
    ----------
    pole : complex
        Eigenvalue of the linearized loop (rad/s).
    wn : float
        Natural frequency ``|pole|`` (rad/s).
    zeta : float
        Damping ratio ``-Re(pole) / |pole|`` (1 for a real negative pole, < 0 if unstable).
    block : str
        ``"plant"`` (the PD tracking-error dynamics live in the plant states) or ``"observer"``.
    participation : dict
        Share of the mode in each block's states (participation factors, summing to 1).
    """

    pole: complex
    wn: float
    zeta: float
    block: str
    participation: dict


@dataclass(frozen=True)
class ModeResult(JsonResult):
    """One mode of a linearized loop, paired with its partner in the analytic split.

    Attributes
    ----------
    pole : complex
        Eigenvalue (rad/s); JSON ``[re, im]``.
    wn_rad_s, zeta : float
        Natural frequency (rad/s) and damping ratio (see :class:`Mode`).
    time_constant_s : float or None
        ``-1 / Re(pole)`` (s); None when the mode does not decay (``Re(pole) >= 0``).
    block : str
        Owning block by participation, ``"plant"`` or ``"observer"``.
    participation : dict of str to float
        Share of the mode in each block's states.
    analytic_block : str
        The block whose analytic pole set holds its partner.
    analytic_pole : complex
        The partner in the analytic split (rad/s).
    rel_error_vs_analytic : float
        ``|pole - partner| / |partner|``.
    """

    pole: complex
    wn_rad_s: float
    zeta: float
    time_constant_s: float | None
    block: str
    participation: dict[str, float]
    analytic_block: str
    analytic_pole: complex
    rel_error_vs_analytic: float

    @property
    def decay_rate_rad_s(self) -> float:
        """``-Re(pole)`` (rad/s; < 0: growing)."""
        return -self.pole.real


@dataclass(frozen=True)
class OperatingPoint(JsonResult):
    """The held loop linearized at one configuration, with and without the observer.

    Attributes
    ----------
    label : str
        What the configuration is (for example "reference at t = 0").
    q0 : list of float
        Held configuration (rad or m per joint; the paper arm: rad, rad, m, rad).
    t_s : float
        Time (s) at which the disturbance is evaluated.
    poles_with_dob, poles_without_dob : list of complex
        Poles of the linearized loop (rad/s), slowest first; JSON ``[re, im]`` each.
    modes_with_dob, modes_without_dob : list of ModeResult
        The same poles with damping, owner and analytic partner.
    q_equilibrium_with_dob, q_equilibrium_without_dob : list of float
        Where the held arm rests (rad or m per joint; the paper arm: rad, rad, m, rad).
    disturbance_at_rest : list of float
        The lumped disturbance the held arm feels (N m or N per joint), read from the observer's estimate at rest.
    max_rel_error_with_dob, max_rel_error_without_dob : float
        Largest relative distance of the linearized poles from the analytic split (meaningful on a perfect model).
    attribution_agrees_with_dob, attribution_agrees_without_dob : bool
        Whether every mode was attributed to the block whose analytic set holds its partner.
    analytic_with_dob, analytic_without_dob : dict of str to list of complex
        The analytic poles by block (see :func:`analytic_poles`).
    perfect_model : bool
        Whether the scenario's nominal model is the true one.
    """

    label: str
    q0: list[float]
    t_s: float
    poles_with_dob: list[complex]
    modes_with_dob: list[ModeResult]
    q_equilibrium_with_dob: list[float]
    disturbance_at_rest: list[float]
    max_rel_error_with_dob: float
    attribution_agrees_with_dob: bool
    analytic_with_dob: dict[str, list[complex]]
    poles_without_dob: list[complex]
    modes_without_dob: list[ModeResult]
    q_equilibrium_without_dob: list[float]
    max_rel_error_without_dob: float
    attribution_agrees_without_dob: bool
    analytic_without_dob: dict[str, list[complex]]
    perfect_model: bool

    def poles(self, observer: bool) -> list[complex]:
        """The poles of the loop with (True) or without (False) the observer."""
        return self.poles_with_dob if observer else self.poles_without_dob

    def modes(self, observer: bool) -> list[ModeResult]:
        """The modes of the loop with (True) or without (False) the observer."""
        return self.modes_with_dob if observer else self.modes_without_dob

    def q_equilibrium(self, observer: bool) -> list[float]:
        """Where the held arm rests with (True) or without (False) the observer."""
        return self.q_equilibrium_with_dob if observer else self.q_equilibrium_without_dob

    def max_rel_error(self, observer: bool) -> float:
        """Largest relative distance from the analytic split, with or without the observer."""
        return self.max_rel_error_with_dob if observer else self.max_rel_error_without_dob

    def attribution_agrees(self, observer: bool) -> bool:
        """Whether the mode owners agree with the analytic split, with or without the observer."""
        return self.attribution_agrees_with_dob if observer else self.attribution_agrees_without_dob

    def largest_real_part(self, observer: bool) -> float:
        """The spectral abscissa (rad/s; >= 0: not asymptotically stable)."""
        return max(p.real for p in self.poles(observer))

    def pd_slowest_analytic_rad_s(self) -> float:
        """Slowest decay rate of the analytic PD roots ``s^2 + Kd s + Kp`` (rad/s)."""
        return min(-m.analytic_pole.real for m in self.modes_without_dob)


def loop_modes(lin: ct.StateSpace, loop) -> list[Mode]:
    """Poles of a linearized loop with natural frequency, damping and owning block.

    The owner is found from participation factors ``|l_k r_k|`` (left and right
    eigenvectors).  They are computed in coordinates where the observer is
    described by its estimate ``d_hat`` (read from the linearized output map)
    instead of its internal state ``z = d_hat - Y q'``: the PD modes then leave
    ``d_hat`` untouched and the observer modes are the only ones that move it,
    so on a perfect model each mode belongs wholly to one block.
    """
    A = np.asarray(lin.A)
    slices = _block_slices(loop)
    T = np.eye(A.shape[0])
    if "observer" in slices and slices["observer"].stop > slices["observer"].start:
        n = slices["observer"].stop - slices["observer"].start       # the observer holds z, one per joint
        rows = [list(lin.output_labels).index(f"d_hat[{i}]") for i in range(n)]
        T[slices["observer"], :] = np.asarray(lin.C)[rows, :]
    A_t = T @ A @ np.linalg.inv(T)
    poles, left, right = scipy.linalg.eig(A_t, left=True, right=True)
    modes = []
    for k in np.argsort(-poles.real, kind="stable"):
        p = np.abs(left[:, k].conj() * right[:, k])
        p = p / p.sum()
        shares = {name: float(p[sl].sum()) for name, sl in slices.items() if sl.stop > sl.start}
        lam = complex(poles[k])
        wn = abs(lam)
        modes.append(Mode(pole=lam, wn=wn, zeta=(-lam.real / wn) if wn > 0 else 1.0,
                          block=max(shares, key=shares.get), participation=shares))
    return modes


def analytic_poles(scenario: Scenario, q0, observer: bool = True) -> dict:
    """The analytic closed-loop poles on a perfect model (docs/model.md).

    Returns
    -------
    dict
        ``"plant"``: the ``2 n`` roots of ``s^2 + Kd_i s + Kp_i`` (i = 1..n) and, with
        the observer, ``"observer"``: the ``n`` eigenvalues of ``-Y M^-1(q0)``
        (nominal inertia), all in rad/s.
    """
    q0 = _joint_vector(q0, "q0", scenario)
    return arm_analytic_poles(scenario.kp, scenario.kd, scenario.observer_gain, scenario.nominal.inertia(q0),
                              observer)


def match_poles(numeric, analytic) -> tuple[np.ndarray, np.ndarray]:
    """Pair numeric poles with analytic ones (minimum total distance).

    Returns
    -------
    order : numpy.ndarray of int
        ``analytic[order[k]]`` is the partner of ``numeric[k]``.
    rel_error : numpy.ndarray
        ``|numeric - partner| / |partner|`` per pole.
    """
    numeric = np.asarray(numeric, dtype=complex)
    analytic = np.asarray(analytic, dtype=complex)
    if numeric.shape != analytic.shape:
        raise ValueError(f"cannot match {numeric.size} numeric poles with {analytic.size} analytic ones")
    cost = np.abs(numeric[:, None] - analytic[None, :])
    rows, cols = linear_sum_assignment(cost)
    order = np.empty(numeric.size, dtype=int)
    order[rows] = cols
    partner = analytic[order]
    return order, np.abs(numeric - partner) / np.maximum(np.abs(partner), 1e-300)


def operating_point_analysis(scenario: Scenario, q0, t: float = 0.0, label: str = "") -> OperatingPoint:
    """Linearize the held loop at ``q0`` with and without the observer; compare with the analytic split.

    Parameters
    ----------
    scenario : Scenario
        Its gains, models and disturbance are used; its trajectory is replaced by ``q0``.
    q0 : array_like, shape (n,)
        Held configuration (rad, m).
    t : float
        Time (s) at which the disturbance is evaluated.
    label : str
        What the configuration is, kept with the result.

    Returns
    -------
    OperatingPoint
        Poles and modes (slowest first), where the arm rests, the disturbance
        the held arm feels, and the comparison with the analytic split.
    """
    q0 = _joint_vector(q0, "q0", scenario)
    n = len(q0)
    held = hold_scenario(scenario, q0)
    out = {"label": str(label), "q0": q0.tolist(), "t_s": float(t)}
    for observer, key in ((True, "with_dob"), (False, "without_dob")):
        loop = closed_loop(held, observer=observer)
        try:
            x_eq = equilibrium(loop, t)
        except RuntimeError as err:      # say which loop: without the observer the arm may sag far or nowhere
            raise RuntimeError(f"{'with' if observer else 'without'} the observer: {err}") from err
        lin = linearize_loop(loop, x_eq, t)
        modes = loop_modes(lin, loop)
        numeric = np.array([m.pole for m in modes])
        plant_slice = _block_slices(loop)["plant"]
        labels = list(loop.state_labels)[plant_slice]
        q_eq = [float(x_eq[plant_slice][labels.index(f"plant_q[{i}]")]) for i in range(n)]
        analytic = analytic_poles(held, q0, observer)
        flat = np.concatenate(list(analytic.values()))
        owner = np.concatenate([[name] * len(v) for name, v in analytic.items()])
        order, rel = match_poles(numeric, flat)
        out[f"poles_{key}"] = [complex(p) for p in numeric]
        out[f"modes_{key}"] = [
            ModeResult(pole=m.pole, wn_rad_s=m.wn, zeta=m.zeta,
                       time_constant_s=(-1.0 / m.pole.real) if m.pole.real < 0 else None, block=m.block,
                       participation=m.participation, analytic_block=str(owner[order[k]]),
                       analytic_pole=complex(flat[order[k]]), rel_error_vs_analytic=float(rel[k]))
            for k, m in enumerate(modes)]
        out[f"q_equilibrium_{key}"] = q_eq
        if observer:
            # at rest the estimate equals the lumped disturbance the held arm feels
            y = np.asarray(loop.output(t, x_eq, np.zeros(loop.ninputs)), dtype=float)
            labels_out = list(loop.output_labels)
            out["disturbance_at_rest"] = [float(y[labels_out.index(f"d_hat[{i}]")]) for i in range(n)]
        out[f"max_rel_error_{key}"] = float(rel.max())
        out[f"attribution_agrees_{key}"] = bool(all(m.block == owner[order[k]] for k, m in enumerate(modes)))
        out[f"analytic_{key}"] = {name: [complex(p) for p in v] for name, v in analytic.items()}
    return OperatingPoint(**out, perfect_model=scenario.nominal == scenario.robot)


def spectral_abscissa(scenario: Scenario, q0, observer: bool, t: float = 0.0) -> tuple[float, np.ndarray]:
    """Largest real part of the linearized loop's poles (rad/s; > 0 means unstable) and the poles."""
    loop = closed_loop(hold_scenario(scenario, q0), observer=observer)
    lin = linearize_loop(loop, equilibrium(loop, t), t)
    poles = np.linalg.eigvals(np.asarray(lin.A))
    return float(poles.real.max()), poles


@dataclass(frozen=True)
class MismatchSweep(JsonResult):
    """Closed-loop poles against the scale ``a`` of the nominal inertia (``M^ = a M``).

    Attributes
    ----------
    factors : list of float
        The factors ``a``.
    poles : list of list of complex
        Per factor, the poles (rad/s), slowest first; JSON ``[re, im]`` each.
    spectral_abscissa : list of float
        Per factor, the largest real part (rad/s; > 0: unstable).
    """

    factors: list[float]
    poles: list[list[complex]]
    spectral_abscissa: list[float]


@dataclass(frozen=True)
class StabilityBoundary(JsonResult):
    """A factor ``a`` at which the loop changes stability; ``stable_side`` is ``"above"`` or ``"below"`` it."""

    factor: float
    stable_side: str


@dataclass(frozen=True)
class BoundaryScan(JsonResult):
    """The logarithmic scan of a boundary search: factors and their spectral abscissa (rad/s)."""

    factors: list[float]
    spectral_abscissa: list[float]


@dataclass(frozen=True)
class BoundarySearch(JsonResult):
    """Where the loop changes stability over a range of inertia factors.

    Attributes
    ----------
    boundaries : list of StabilityBoundary
        In increasing ``a``; empty when the stability does not change in the range.
    range : list of float
        ``[low, high]`` searched.
    scan : BoundaryScan
    """

    boundaries: list[StabilityBoundary]
    range: list[float]
    scan: BoundaryScan

    @property
    def factors(self) -> list[float]:
        """The boundary factors ``a``."""
        return [b.factor for b in self.boundaries]

    @property
    def stable_at_low_end(self) -> bool:
        """Whether the loop is stable at the low end of the range."""
        return self.scan.spectral_abscissa[0] < 0


@dataclass(frozen=True)
class MismatchLoop(JsonResult):
    """The pole sweep and the stability-boundary search of one loop."""

    sweep: MismatchSweep
    boundaries: BoundarySearch


@dataclass(frozen=True)
class MismatchStudy(JsonResult):
    """Robustness to inertia mismatch at ``q0`` (rad or m per joint), with and without the observer."""

    q0: list[float]
    with_dob: MismatchLoop
    without_dob: MismatchLoop

    def loop(self, observer: bool) -> MismatchLoop:
        """The loop with (True) or without (False) the observer."""
        return self.with_dob if observer else self.without_dob


def mismatch_sweep(scenario: Scenario, q0, factors, observer: bool, t: float = 0.0) -> MismatchSweep:
    """Closed-loop poles as the nominal inertia is scaled by each factor (``M^ = a M``)."""
    factors = [float(a) for a in factors]
    poles, abscissa = [], []
    for a in factors:
        alpha, p = spectral_abscissa(scale_nominal_inertia(scenario, a), q0, observer, t)
        poles.append([complex(z) for z in p[np.argsort(-p.real)]])
        abscissa.append(alpha)
    return MismatchSweep(factors=factors, poles=poles, spectral_abscissa=abscissa)


def stability_boundaries(scenario: Scenario, q0, observer: bool, low: float = 0.02, high: float = 50.0,
                         points: int = 25, rtol: float = 1e-6, t: float = 0.0) -> BoundarySearch:
    """Inertia scale factors ``a`` (``M^ = a M``) at which the linearized loop changes stability.

    A logarithmic scan of ``points`` factors over ``[low, high]`` brackets the
    sign changes of the spectral abscissa (continuous in ``a``); each bracket is
    then narrowed on ``log a`` with Brent's method until the boundary is known
    to ``rtol`` (relative).  A change of stability between two scan points that
    reverses again before the next one is not seen.

    Returns
    -------
    BoundarySearch
        ``boundaries`` (each with the side on which the loop is stable), the
        ``range`` searched and the ``scan``.
    """
    def alpha(a):
        return spectral_abscissa(scale_nominal_inertia(scenario, a), q0, observer, t)[0]

    return boundary_search(alpha, low, high, points, rtol)


def boundary_search(alpha, low: float = 0.02, high: float = 50.0, points: int = 25,
                    rtol: float = 1e-6) -> BoundarySearch:
    """Where ``alpha(a)`` (a spectral abscissa, rad/s, continuous in ``a``) changes sign over ``[low, high]``.

    The scan and Brent refinement of :func:`stability_boundaries`, for any
    family of loops (for example :func:`arm_mismatch_analysis`).
    """
    if not (0 < low < high) or points < 2:
        raise ValueError(f"need 0 < low < high and points >= 2, got low={low}, high={high}, points={points}")
    grid = np.geomspace(low, high, points)
    values = [alpha(a) for a in grid]
    boundaries = []
    for k in range(points - 1):
        if (values[k] < 0) == (values[k + 1] < 0):
            continue
        # the bracket's ends keep their scanned values: alpha at exp(log(a)), one ulp off a, may take the other
        # sign where it jumps (a loop without a resting position), and Brent's method would refuse the bracket
        ends = {math.log(grid[k]): values[k], math.log(grid[k + 1]): values[k + 1]}
        root = brentq(lambda log_a: ends[log_a] if log_a in ends else alpha(math.exp(log_a)), math.log(grid[k]),
                      math.log(grid[k + 1]), xtol=rtol / 2.0, rtol=4 * np.finfo(float).eps)
        boundaries.append(StabilityBoundary(factor=math.exp(root), stable_side="below" if values[k] < 0 else "above"))
    return BoundarySearch(boundaries=boundaries, range=[float(low), float(high)],
                          scan=BoundaryScan(factors=grid.tolist(), spectral_abscissa=[float(v) for v in values]))


def mismatch_analysis(scenario: Scenario, q0, factors, low: float = 0.02, high: float = 50.0,
                      points: int = 25) -> MismatchStudy:
    """The pole sweep over ``factors`` and the boundary search over ``[low, high]``, with and without the observer."""
    q0 = _joint_vector(q0, "q0", scenario)
    loops = {key: MismatchLoop(sweep=mismatch_sweep(scenario, q0, factors, observer),
                               boundaries=stability_boundaries(scenario, q0, observer, low, high, points=points))
             for observer, key in ((True, "with_dob"), (False, "without_dob"))}
    return MismatchStudy(q0=q0.tolist(), **loops)


def mismatch_polynomial(M, Y, kp, kd, factor: float, observer: bool = True) -> np.ndarray:
    """Roots of the hand-derived characteristic polynomial matrix of the loop with ``M^ = a M``.

    With the observer ``P(s) = s^3 M + s^2 (Y + a M Kd) + s (a M Kp + Y Kd) + Y Kp``;
    without it ``P(s) = s^2 I + a s Kd + a Kp``.  Solved as a generalized
    eigenvalue problem of the block companion form.  An independent check of
    the linearization (it does not use the loop).

    Parameters
    ----------
    M : array_like, shape (n, n)
        True inertia at the operating point.
    Y : array_like, shape (n, n)
        Observer gain.
    kp, kd : array_like, shape (n, n)
        Diagonal PD gains.
    factor : float
        ``a`` in ``M^ = a M``.
    """
    M, Y, Kp, Kd = (np.asarray(v, dtype=float) for v in (M, Y, kp, kd))
    n = M.shape[0]
    I = np.eye(n)
    if observer:
        coeffs = [Y @ Kp, factor * M @ Kp + Y @ Kd, Y + factor * M @ Kd, M]     # ascending powers
    else:
        coeffs = [factor * Kp, factor * Kd, I]
    deg = len(coeffs) - 1
    C = np.zeros((deg * n, deg * n))
    B = np.eye(deg * n)
    for k in range(deg - 1):
        C[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = I
    for k in range(deg):
        C[(deg - 1) * n:, k * n:(k + 1) * n] = -coeffs[k]
    B[(deg - 1) * n:, (deg - 1) * n:] = coeffs[-1]
    return scipy.linalg.eigvals(C, B)


# Spectral abscissa (rad/s) given to a loop without a resting position in the arm-model mismatch study.
_NO_REST_RATE = 1e6


def arm_mismatch_analysis(arm, kp, kd, Y, q0, factors, d=None, low: float = 0.02, high: float = 50.0,
                          points: int = 25) -> MismatchStudy:
    """:func:`mismatch_analysis` for any arm model: the nominal model is ``arm`` with every mass and inertia
    scaled by ``a`` (:class:`~analysis.linear.arm_linear.ScaledArm`), the loop linearized by
    :func:`~analysis.linear.arm_linear.arm_linearization` at ``q0`` under the constant disturbance ``d`` (N m, N).

    Without the observer a factor at which the arm has no resting position near
    ``q0`` (gravity, mis-scaled, pulls it away) has no poles (an empty list) and
    counts as unstable with a spectral abscissa of 1e6 rad/s.
    """
    from analysis.linear.arm_linear import ArmLoop, ScaledArm, arm_linearization

    loop = ArmLoop.make(arm, kp, kd, Y, q0, d)

    def poles(a, observer):
        """The loop's poles, or None when the arm has no resting position near q0 (without the observer)."""
        try:
            lin = arm_linearization(loop.arm, loop.kp, loop.kd, loop.Y, loop.q0, loop.d, ScaledArm(loop.arm, a),
                                    observer)
        except RuntimeError:
            return None
        return np.linalg.eigvals(np.asarray(lin.A))

    def abscissa(p):
        # no resting position: counted as unstable (a large finite rate keeps Brent's method working)
        return _NO_REST_RATE if p is None else float(p.real.max())

    loops = {}
    for observer, key in ((True, "with_dob"), (False, "without_dob")):
        factor_list = [float(a) for a in factors]
        sweep_poles = [poles(a, observer) for a in factor_list]
        sweep = MismatchSweep(factors=factor_list,
                              poles=[[] if p is None else [complex(z) for z in p[np.argsort(-p.real)]]
                                     for p in sweep_poles],
                              spectral_abscissa=[abscissa(p) for p in sweep_poles])
        search = boundary_search(lambda a, obs=observer: abscissa(poles(a, obs)), low, high, points)
        loops[key] = MismatchLoop(sweep=sweep, boundaries=search)
    return MismatchStudy(q0=loop.q0.tolist(), **loops)
