"""The sampled loop, linearized: z-plane poles, how fast the observer may be at a rate, and encoder torque noise.

The digital loop of :mod:`blocks.figure2.digital_loop` is linearized at a held
configuration (the arm at rest at ``q0`` under the scenario's constant
disturbance, the observer at ``d_hat = d``).  Each block is linearized with
:func:`control.linearize`; the continuous plant, whose torque input is held
over each sample, is discretized exactly with :func:`control.c2d` (zero-order
hold); the blocks are then closed in the order and with the connections of
the hybrid diagram's own evaluation plan (:mod:`blocks.diagram.plan`), which gives
the loop's one-sample map ``x_{k+1} = A x_k + B w_k``.

* :func:`sampled_poles`: eigenvalues ``z`` of ``A`` with their continuous
  equivalents ``s = ln(z) / Ts``, natural frequency, damping and owning block
  (participation factors, as for the continuous loop).
* :func:`observer_gain_limit`: the largest factor ``c`` for which the loop with
  observer gain ``c Y`` is stable, against the sample rate, for both
  discretizations and delays 0 and 1, the smallest over a set of
  configurations.  It is computed by :mod:`blocks.figure2.digital_stability`, the
  one computation the pre-run check also uses (its one-sample map is the
  same linearization written out, gravity's slope ``dG/dq`` included; a
  test checks the two agree).  Only forward Euler with measured velocity
  reaches ``2 / (Ts lambda_max(Y M^-1))`` exactly (with or without a delay)
  on an arm whose gravity is constant (the paper's); gravity's slope moves
  it slightly; zoh and a velocity difference stay below it, lower still
  with a delay (``docs/model.md``, "Digital observer").
* :func:`quantization_torque_noise`: the RMS torque that encoder quantization
  causes, predicted from ``A, B`` with the quantization error as white noise of
  variance ``res^2 / 12`` entering the encoder, and measured by simulation
  (the same run with and without quantization, on a moving path).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg

from analysis.linear.arm_terms import workspace_ranges
from analysis.linear.loop import equilibrium, hold_scenario
from analysis.results import JsonResult
from blocks.diagram.digital import DigitalController
from blocks.figure2.digital_loop import sampled_initial_state, sampled_loop, simulate_sampled
from blocks.figure2.digital_stability import sampled_stability
from blocks.figure2.loop import closed_loop
from blocks.figure2.metrics import signal
from blocks.scenarios.scenario import Scenario

__all__ = ["SampledMode", "SampledPoles", "GainLimitCurve", "GainLimitStudy", "QuantizationNoise",
           "linear_sampled_loop", "sampled_poles", "observer_gain_limit", "quantization_torque_noise",
           "DEFAULT_RATES_HZ"]

#: At rates where the scenario's velocity low-pass would reach this share of the sample rate (0.5 is the
#: Nyquist frequency), the gain-limit study caps the cut-off there.
NYQUIST_SHARE = 0.4
#: Sample rates of the gain-limit study (Hz).
DEFAULT_RATES_HZ = (100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0, 10000.0)
_LINEARIZATION_STEP = 1e-6


@dataclass(frozen=True)
class SampledMode(JsonResult):
    """One eigenvalue of the sampled loop's one-sample map.

    Attributes
    ----------
    z : complex
        Eigenvalue; stable when ``|z| < 1``.
    s_equivalent : complex
        ``ln(z) / Ts`` (1/s): the continuous pole with the same decay per sample.
    wn_rad_s, zeta : float
        ``|s|`` and ``-Re(s) / |s|``.
    block : str
        Owning block (largest participation).
    """

    z: complex
    s_equivalent: complex
    wn_rad_s: float
    zeta: float
    block: str


@dataclass(frozen=True)
class SampledPoles(JsonResult):
    """The poles of the sampled loop at one configuration.

    Attributes
    ----------
    sample_rate_hz : float
    q0 : list of float
        Held configuration (rad or m per joint; the paper arm: rad, rad, m, rad).
    spectral_radius : float
        ``max |z|``; the loop is stable when it is below 1.
    modes : list of SampledMode
        Sorted by ``|z|``, largest first.
    """

    sample_rate_hz: float
    q0: list
    spectral_radius: float
    modes: list


@dataclass(frozen=True)
class GainLimitCurve(JsonResult):
    """Largest stable observer-gain factor against the rate, for one discretization and delay.

    Attributes
    ----------
    discretization : str
    delay : int
    rates_hz : list of float
    largest_scale : list of float
        The factor ``c`` (the gain ``c Y`` is the largest stable one), smallest over the configurations.
    euler_bound_scale : list of float
        ``2 / (Ts lambda_max(Y M^-1))`` over the same configurations: the limit of forward Euler with measured
        velocity, a reference the others stay below.
    ts_lambda_limit : list of float
        ``Ts lambda_max(Y M^-1)`` at the largest stable gain: the loop is stable while
        ``Ts lambda_max(Y M^-1)`` is below it (2 for Euler with measured velocity).
    """

    discretization: str
    delay: int
    rates_hz: list
    largest_scale: list
    euler_bound_scale: list
    ts_lambda_limit: list = dataclasses.field(default_factory=list)


@dataclass(frozen=True)
class GainLimitStudy(JsonResult):
    """How fast the observer may be at each sample rate.

    Attributes
    ----------
    observer_gain : list
        The scenario's gain ``Y`` (n x n), which the factors multiply.
    configurations : list
        The held configurations checked (the factors are the smallest over them).
    curves : list of GainLimitCurve
    """

    observer_gain: list
    configurations: list
    curves: list


@dataclass(frozen=True)
class QuantizationNoise(JsonResult):
    """Torque noise caused by encoder quantization.

    Attributes
    ----------
    position_resolution : list of float
        Quantization step per joint (rad or m).
    predicted_rms : list of float
        RMS torque per joint (N m or N) from the linear model.
    simulated_rms : list of float or None
        RMS of the torque difference between runs with and without
        quantization (None when not simulated).
    """

    position_resolution: list
    predicted_rms: list
    simulated_rms: list | None = None


def _held(scenario: Scenario, q0) -> Scenario:
    """The scenario held at ``q0`` under a constant disturbance (the paper's step), with its controller, for
    linearization: the encoders' quantizer is taken as exact (its small-signal gain is 1; what it adds is the
    quantization error, which :func:`quantization_torque_noise` treats as noise)."""
    return hold_scenario(scenario, q0).with_changes({"controller.position_resolution": [0.0] * scenario.nominal.n})


def _operating_state(held: Scenario, loop) -> np.ndarray:
    """The sampled loop's state at the continuous loop's equilibrium (the two agree at rest)."""
    cont = closed_loop(held, observer=any(b.name == "observer" for b in loop.syslist))
    x_eq = equilibrium(cont)
    names = {}
    offset = 0
    for block in cont.syslist:
        for j, label in enumerate(block.state_labels):
            names[(block.name, label)] = x_eq[offset + j]
        offset += block.nstates
    x0 = sampled_initial_state(loop, held)
    offset = 0
    for block in loop.syslist:
        for j, label in enumerate(block.state_labels):
            if (block.name, label) in names:
                x0[offset + j] = names[(block.name, label)]
            elif label.startswith("q_prev"):
                x0[offset + j] = names[("plant", label.replace("q_prev", "q"))]
            elif label.startswith("v_prev"):
                x0[offset + j] = 0.0
        offset += block.nstates
    if held.controller.delay:                       # the buffer holds the torque that holds the arm
        y = loop.tick_outputs(0, x0, np.zeros(loop.plan.nsignals))
        offset = 0
        for block in loop.syslist:
            if block.name == "actuator":
                tau = y[_rows_of(loop, "tau_cmd")]
                x0[offset:offset + block.nstates] = np.tile(tau, held.controller.delay)
            offset += block.nstates
    return x0


def _rows_of(loop, prefix: str) -> list[int]:
    names = [n for block in loop.system.syslist for n in block.output_labels]
    count = sum(1 for name in names if name.startswith(f"{prefix}["))      # one per joint
    return [names.index(f"{prefix}[{i}]") for i in range(count)]


def _linearized_block(block, x, u, period: float, continuous: bool):
    """``(A, B, C, D)`` of a block at ``(x, u)``; a continuous block discretized at ``period`` (ZOH)."""
    plus = ct.linearize(block, x, u, eps=_LINEARIZATION_STEP)
    minus = ct.linearize(block, x, u, eps=-_LINEARIZATION_STEP)
    A, B, C, D = ((np.asarray(p) + np.asarray(m)) / 2 for p, m in zip((plus.A, plus.B, plus.C, plus.D),
                                                                     (minus.A, minus.B, minus.C, minus.D)))
    if continuous and A.size:
        n = A.shape[0]
        aug = np.zeros((n + B.shape[1], n + B.shape[1]))
        aug[:n, :n], aug[:n, n:] = A * period, B * period
        step = scipy.linalg.expm(aug)
        A, B = step[:n, :n], step[:n, n:]
    return A, B, C, D


def linear_sampled_loop(loop, x_op: np.ndarray, noise_at: str | None = None, replace: dict | None = None,
                        cache: dict | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """The one-sample map of a single-rate hybrid loop, linearized at ``x_op``.

    Parameters
    ----------
    loop : blocks.engines.hybrid.HybridSystem
        One discrete rate; continuous blocks may take inputs only from discrete blocks (held) or be static.
    x_op : numpy.ndarray
        Operating state (the loop at rest).
    noise_at : str, optional
        Name of a block whose inputs receive an additive noise ``w`` (the encoder, for quantization).
    replace : dict, optional
        Blocks to linearize instead of the loop's own, by name (same signals), e.g. an observer with another gain.
    cache : dict, optional
        Linearizations of the loop's own blocks from an earlier call at the same ``x_op``, reused (and filled).

    Returns
    -------
    A, B : numpy.ndarray
        ``x_{k+1} = A x_k + B w_k`` (``B`` empty without ``noise_at``).
    C_tau, D_tau : via the dict
    signals : dict
        ``{"tau": (C, D)}``: the applied torque as ``C x + D w``, and ``"owners"``: block name per state.
    """
    plan, period = loop.plan, loop.base_period
    if len(set(m for m in loop.multiples.values())) > 1:
        raise ValueError("the linear sampled loop takes one sample rate")
    replace = replace or {}
    held = np.zeros(plan.nsignals)
    y_op = loop.tick_outputs(0, x_op, held)
    blocks = {b.name: replace.get(b.name, b) for b in loop.syslist}
    nx = plan.nstates
    nw = blocks[noise_at].ninputs if noise_at else 0
    # every block output as a linear function of [x; w], in plan order; then every update from the full outputs
    Y = np.zeros((plan.nsignals, nx + nw))
    nxt = np.zeros((nx, nx + nw))
    linear = {}
    for s in plan.steps:
        block = blocks[s.name]
        continuous = loop.periods[s.name] == 0
        if cache is not None and s.name not in replace and s.name in cache:
            linear[s.name] = cache[s.name]
        else:
            linear[s.name] = _linearized_block(block, x_op[s.x], y_op[s.gather], period, continuous)
            if cache is not None and s.name not in replace:
                cache[s.name] = linear[s.name]
        _, _, C, D = linear[s.name]
        if block.noutputs:
            Y[s.y] = C @ _select(s.x, nx, nw) + D @ _inputs(Y, s, noise_at, nx, nw)
    for s in plan.steps:
        if s.x.stop > s.x.start:
            if loop.periods[s.name] == 0 and _feeds_from_continuous(loop, s):
                raise ValueError(f"block '{s.name}' is continuous and takes inputs from a continuous block: "
                                 "its zero-order-hold discretization would not be exact")
            A, B, _, _ = linear[s.name]
            nxt[s.x] = A @ _select(s.x, nx, nw) + B @ _inputs(Y, s, noise_at, nx, nw)
    owners = {}
    for s in plan.steps:
        for j in range(s.x.start, s.x.stop):
            owners[j] = s.name
    tau_rows = _rows_of(loop, "tau")
    maps = {"tau": (Y[tau_rows, :nx], Y[tau_rows, nx:]), "owners": owners}
    if "observer" in blocks:
        maps["d_hat"] = Y[_rows_of(loop, "d_hat"), :nx]
    return nxt[:, :nx], nxt[:, nx:], maps


def _select(xs: slice, nx: int, nw: int) -> np.ndarray:
    """The block's states as rows of ``[x; w]``."""
    X = np.zeros((xs.stop - xs.start, nx + nw))
    X[:, xs] = np.eye(xs.stop - xs.start)
    return X


def _inputs(Y: np.ndarray, step, noise_at, nx: int, nw: int) -> np.ndarray:
    """The block's inputs as rows of ``[x; w]``; the noise ``w`` adds to the inputs of block ``noise_at``."""
    U = Y[step.gather].copy()
    if step.name == noise_at:
        U[:, nx:] += np.eye(nw)
    return U


def _feeds_from_continuous(loop, step) -> bool:
    sources = set(np.arange(loop.plan.nsignals)[step.gather].tolist())
    for s in loop.plan.steps:
        if loop.periods[s.name] == 0 and s.name != step.name and sources & set(range(s.y.start, s.y.stop)):
            block = next(b for b in loop.syslist if b.name == s.name)
            if block.nstates or block.ninputs:          # a pure source (the reference) is constant here
                return True
    return False


def _modes(A: np.ndarray, owners: dict, period: float, d_hat_map: np.ndarray | None = None,
           labels: list | None = None) -> list[SampledMode]:
    """Eigenvalues with their owners.  As for the continuous loop (:func:`analysis.linear.loop.loop_modes`), the
    participation factors are taken in coordinates where each block is described by what it adds: the observer
    by its estimate ``d_hat`` rather than ``z = d_hat - Y q'``, the encoder by its errors ``q_prev - q`` and
    ``v_prev - dq`` rather than copies of the arm's motion, so that a tracking mode does not appear to move them."""
    T = np.eye(A.shape[0])
    if d_hat_map is not None:
        rows = [j for j, o in sorted(owners.items()) if o == "observer"]
        T[rows, :] = d_hat_map
    if labels is not None:
        for j, label in enumerate(labels):
            for own, arm in (("encoder_q_prev", "plant_q"), ("encoder_v_prev", "plant_dq")):
                if label.startswith(own) and label.replace(own, arm) in labels:
                    T[j, labels.index(label.replace(own, arm))] = -1.0
    A = T @ A @ np.linalg.inv(T)
    z, left, right = scipy.linalg.eig(A, left=True, right=True)
    names = sorted(set(owners.values()))
    out = []
    for k in np.argsort(-np.abs(z), kind="stable"):
        p = np.abs(left[:, k].conj() * right[:, k])
        p = p / p.sum() if p.sum() > 0 else p
        share = {n: float(sum(p[j] for j, o in owners.items() if o == n)) for n in names}
        zk = complex(z[k])
        # a pole at z = 0 (a pure delay or a dead-beat state) has no continuous equivalent
        s = complex(np.log(zk)) / period if abs(zk) > 1e-12 else complex(-np.inf)
        wn = abs(s) if np.isfinite(s.real) else float("inf")
        out.append(SampledMode(z=zk, s_equivalent=s, wn_rad_s=wn, zeta=(-s.real / wn) if wn > 0 and
                               np.isfinite(wn) else 1.0, block=max(share, key=share.get)))
    return out


def sampled_poles(scenario: Scenario, q0=None) -> SampledPoles:
    """The z-plane poles of the scenario's sampled loop held at ``q0`` (default: the path's start)."""
    q0 = np.asarray(scenario.trajectory.evaluate(0.0)[0] if q0 is None else q0, dtype=float)
    held = _held(scenario, q0)
    loop = sampled_loop(held)
    A, _, maps = linear_sampled_loop(loop, _operating_state(held, loop))
    modes = _modes(A, maps["owners"], loop.base_period, maps.get("d_hat"), loop.state_labels)
    return SampledPoles(sample_rate_hz=scenario.controller.sample_rate, q0=q0.tolist(),
                        spectral_radius=float(max(abs(m.z) for m in modes)), modes=modes)


# The joint varied by the gain-limit study's default configurations (theta2 for the paper's arm).
_MOVED = 1


def _moved_values(scenario: Scenario) -> tuple[float, ...]:
    """Values of joint ``_MOVED`` at which the gain-limit study holds the arm by default (rad or m)."""
    joints = scenario.nominal.joints
    if scenario.nominal.held_values is not None:
        return scenario.nominal.held_values
    lo, hi = workspace_ranges(joints)[min(_MOVED, joints.count - 1)]
    return tuple(lo + f * (hi - lo) for f in (0.1, 0.5, 0.9))


def observer_gain_limit(scenario: Scenario, rates_hz=DEFAULT_RATES_HZ, configurations=None,
                        discretizations=("euler", "zoh"), delays=(0, 1)) -> GainLimitStudy:
    """The largest stable observer gain ``c Y`` against the sample rate (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        Its observer gain ``Y`` is scaled; its ``[controller]`` settings (encoders, velocity) are used
        (a scenario without one is analysed with the default settings).
    rates_hz : sequence of float
        Sample rates (Hz).  A velocity low-pass whose cut-off is not below
        ``NYQUIST_SHARE`` times a rate is capped there for that rate.
    configurations : sequence of n-vectors, optional
        Held configurations; default the path's start and, there, three values of the
        second joint (the paper's arm: ``theta2`` = 0.3, 1.57 and 2.8 rad, ``M``
        depending on ``theta2`` only; other arms: 10%, 50% and 90% of its sampled range).
    """
    q_start = np.asarray(scenario.trajectory.evaluate(0.0)[0], dtype=float)
    if configurations is None:
        configurations = [q_start] + [np.where(np.arange(len(q_start)) == min(_MOVED, len(q_start) - 1), v, q_start)
                                      for v in _moved_values(scenario)]
    configurations = [np.asarray(q, dtype=float) for q in configurations]
    base = scenario.controller if scenario.controller is not None else \
        DigitalController(sample_rate=1.0, joints=scenario.robot.joints)
    curves = []
    for method in discretizations:
        for delay in delays:
            scales, bounds, limits = [], [], []
            for rate in rates_hz:
                changes = {"sample_rate": float(rate), "delay": int(delay), "observer_discretization": method}
                cutoff = base.velocity_cutoff
                if cutoff is not None and cutoff >= NYQUIST_SHARE * rate:     # keep the filter below Nyquist
                    changes["velocity_cutoff"] = NYQUIST_SHARE * rate
                verdict = sampled_stability(scenario.nominal, configurations, scenario.kp, scenario.kd,
                                            scenario.observer_gain, dataclasses.replace(base, **changes),
                                            scenario.observer_variant)
                scales.append(verdict.largest_stable_scale)
                limits.append(verdict.ts_lambda_limit)
                bounds.append(2.0 / verdict.ts_lambda_max)
            curves.append(GainLimitCurve(discretization=method, delay=int(delay), rates_hz=[float(r) for r in rates_hz],
                                         largest_scale=scales, euler_bound_scale=bounds, ts_lambda_limit=limits))
    return GainLimitStudy(observer_gain=np.asarray(scenario.observer_gain).tolist(),
                          configurations=[q.tolist() for q in configurations], curves=curves)


def quantization_torque_noise(scenario: Scenario, configurations: int = 5, simulate: bool = True) -> QuantizationNoise:
    """Torque noise from the encoders' quantization: predicted by the linear model and (optionally) simulated.

    The prediction treats the quantization error as white noise, uniform over
    one step (variance ``res^2 / 12``), entering the encoder's position
    inputs, and propagates it through the linearized loop with the discrete
    Lyapunov equation; the variance is averaged over ``configurations``
    points of the path in the window the simulation measures.  The
    simulation runs the scenario's path twice, with and without quantization,
    and takes the RMS of the difference of the applied torques after the first
    quarter of the run (the white-noise model needs the positions to move
    across many steps per sample, as they do along a path).
    """
    c = scenario.controller
    res = np.asarray(c.position_resolution, dtype=float)
    n = res.size
    t_final = scenario.simulation.t_final
    variances = []
    for t in np.linspace(t_final / 4, t_final, configurations):
        held = _held(scenario, scenario.trajectory.evaluate(float(t))[0])
        loop = sampled_loop(held)
        A, B, maps = linear_sampled_loop(loop, _operating_state(held, loop), noise_at="encoder")
        C, D = maps["tau"]
        W = np.zeros((B.shape[1], B.shape[1]))
        W[:n, :n] = np.diag(res ** 2 / 12.0)               # the position inputs; velocities carry no quantization
        P = scipy.linalg.solve_discrete_lyapunov(A, B @ W @ B.T)
        variances.append(np.clip(np.diag(C @ P @ C.T + D @ W @ D.T), 0.0, None))
    predicted = np.sqrt(np.mean(variances, axis=0))
    simulated = None
    if simulate:
        exact = scenario.with_changes({"controller.position_resolution": [0.0] * n})
        tau_q = signal(simulate_sampled(scenario), "tau")
        tau_0 = signal(simulate_sampled(exact), "tau")
        start = tau_q.shape[1] // 4
        simulated = np.sqrt(np.mean((tau_q - tau_0)[:, start:] ** 2, axis=1)).tolist()
    return QuantizationNoise(position_resolution=res.tolist(), predicted_rms=predicted.tolist(),
                             simulated_rms=simulated)


@dataclass(frozen=True)
class DigitalAnalysis(JsonResult):
    """The digital implementation of a scenario's controller, analysed.

    Attributes
    ----------
    sample_rate_hz : float
        The scenario's rate.
    settings : dict
        The scenario's ``[controller]`` settings.
    poles : SampledPoles
        At the path's start.
    gain_limit : GainLimitStudy
    quantization : QuantizationNoise or None
        None when the encoders are exact.
    largest_stable_scale : float
        For the scenario's own discretization and delay, at its rate: the observer may be this many times faster.
    ts_lambda_limit : float
        The same limit as ``Ts lambda_max(Y M^-1)``: the loop is stable while it stays below this number.
    answer : str
        The plain-language answer for the scenario's settings.
    """

    sample_rate_hz: float
    settings: dict
    poles: SampledPoles
    gain_limit: GainLimitStudy
    quantization: QuantizationNoise | None
    largest_stable_scale: float
    answer: str
    ts_lambda_limit: float = math.nan


def digital_analysis(scenario: Scenario, rates_hz=DEFAULT_RATES_HZ, configurations=None,
                     simulate_noise: bool = True) -> DigitalAnalysis:
    """Poles, gain limit and quantization noise of the scenario's digital controller, with a plain answer.

    Raises
    ------
    ValueError
        If the scenario has no ``[controller]`` section.
    """
    c = scenario.controller
    if c is None:
        raise ValueError(f"scenario '{scenario.name}' has no [controller] section: there is no digital "
                         "implementation to analyse")
    rates = sorted(set(float(r) for r in rates_hz) | {c.sample_rate})
    methods = (c.observer_discretization,) + tuple(m for m in ("euler", "zoh") if m != c.observer_discretization)
    study = observer_gain_limit(scenario, rates, configurations, discretizations=methods,
                                delays=sorted({0, 1, c.delay}))
    own = next(cv for cv in study.curves if cv.delay == c.delay and cv.discretization == c.observer_discretization)
    k = own.rates_hz.index(c.sample_rate)
    scale, limit = own.largest_scale[k], own.ts_lambda_limit[k]
    noise = quantization_torque_noise(scenario, simulate=simulate_noise) if any(c.position_resolution) else None
    return DigitalAnalysis(sample_rate_hz=c.sample_rate, settings=dict(scenario.data["controller"]),
                           poles=sampled_poles(scenario), gain_limit=study, quantization=noise,
                           largest_stable_scale=scale, answer=_answer(scenario, scale, limit, noise),
                           ts_lambda_limit=limit)


def _answer(s: Scenario, scale: float, limit: float, noise: QuantizationNoise | None) -> str:
    """The plain-language answer, every number from the results."""
    c = s.controller
    Y = np.asarray(s.observer_gain)
    gain = np.diag(Y)
    bandwidth = s.user_data.get("gains", {}).get("observer_bandwidth")
    if bandwidth is not None:                       # the scenario's own words: Y = omega M^(q0)
        shown = f"{float(bandwidth):g} M^(q0)"
    elif np.allclose(Y, gain[0] * np.eye(len(gain))):
        shown = f"{gain[0]:g} I"
    elif np.allclose(Y, np.diag(gain)):
        shown = "diag(" + ", ".join(f"{g:g}" for g in gain) + ")"
    else:
        shown = "the scenario's matrix"
    velocity = c.velocity + (f" velocity through a {c.velocity_cutoff:g} Hz low-pass" if c.velocity_cutoff
                             else " velocity")
    text = (f"At {c.sample_rate:g} Hz ({c.observer_discretization} observer update, {velocity}, delay {c.delay} "
            f"sample{'s' if c.delay != 1 else ''}) the observer gain may be raised up to {scale:.3g} times the "
            f"scenario's (Y = {shown}) before the loop becomes unstable, that is while Ts lambda_max(Y M^-1) "
            f"< {limit:.4g}")
    text += "; the scenario's gain is stable." if scale > 1 else "; the scenario's gain is NOT stable at this rate."
    if noise is not None:
        worst = int(np.argmax(np.asarray(noise.predicted_rms) / np.maximum(np.abs(gain), 1e-12)))
        units = s.nominal.joints.force_units
        values = ", ".join(f"{v:.3g} {u}" for v, u in zip(noise.predicted_rms, units))
        text += f" Encoder quantization adds torque noise of {values} RMS (joints 1-{len(units)}, linear prediction"
        if noise.simulated_rms is not None:
            text += f"; simulated {', '.join(f'{v:.3g}' for v in noise.simulated_rms)}"
        text += f"), most on joint {worst + 1}."
    return text


__all__ += ["DigitalAnalysis", "digital_analysis"]
