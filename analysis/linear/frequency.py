"""Disturbance rejection in frequency: frozen-configuration transfer functions of the linearized loop.

The Figure-2 blocks are reconnected with one change: an external input
``w[i]`` adds to the plant's input torque (``plant.tau = controller.tau + w``),
a disturbance the observer does not see directly.  Outputs are the tracking
error ``e[i] = q_ref[i] - q[i]`` and, with the observer, the estimation error
``e_d[i] = tau_dis[i] + w[i] - d_hat[i]`` (on a perfect model this is the
lumped disturbance minus its estimate).  The loop is linearized at its
equilibrium with the arm held at ``q0`` (see :mod:`analysis.linear.loop`).

:func:`arm_frequency_analysis` gives the same responses for any arm model
(:class:`~blocks.model.arm.ArmModel`, n joints) from :func:`analysis.linear.arm_linear.arm_linearization`.

Closed forms on a perfect model (docs/model.md, "Frozen-configuration transfer
functions"), for ``W`` the disturbance:

* without observer ``E = -(s^2 + Kd s + Kp)^-1 M^-1 W``;
* with observer ``E = -s (s^2 + Kd s + Kp)^-1 (s M + Y)^-1 W`` (zero DC gain);
* with observer ``E_d = s M (s M + Y)^-1 W``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy.optimize import brentq, minimize_scalar

from analysis.linear.arm_linear import ArmLoop, arm_linearization
from analysis.linear.loop import equilibrium, hold_scenario, linearize_loop
from analysis.results import JsonResult
from blocks import build_blocks
from blocks.model.arm import ArmModel
from blocks.scenarios.scenario import Scenario

__all__ = ["DEFAULT_OMEGA", "ChannelMetrics", "ResponseSet", "FrequencyAnalysis", "disturbance_loop",
           "frozen_response", "closed_form", "closed_form_matrices", "siso_metrics", "frequency_analysis",
           "arm_frequency_analysis"]

DEFAULT_OMEGA = np.logspace(-2, 3, 501)     # rad/s


def _names(prefix: str, n: int) -> list[str]:
    return [f"{prefix}[{i}]" for i in range(n)]


def disturbance_loop(scenario: Scenario, observer: bool = True) -> ct.InterconnectedSystem:
    """The Figure-2 loop with disturbance inputs ``w[i]`` at the plant and error outputs.

    Parameters
    ----------
    scenario : Scenario
        Typically a held scenario (:func:`~analysis.linear.loop.hold_scenario`).
    observer : bool
        With or without the disturbance observer.

    Returns
    -------
    control.InterconnectedSystem
        Inputs ``w[i]`` (N m, N); outputs ``e[i]`` (rad, m) and, with the
        observer, ``e_d[i]`` (N m, N).
    """
    n = scenario.nominal.n
    blocks = build_blocks(scenario, observer=observer)
    if "sensor" in blocks:
        raise ValueError(f"scenario '{scenario.name}' has measurement noise; remove it (hold_scenario does) "
                         "before building the frequency-response loop")
    outlist = [[f"trajectory.q_ref[{i}]", f"-plant.q[{i}]"] for i in range(n)]
    outputs = _names("e", n)
    if observer:
        # plant.tau - controller.tau is w; plus the plant's own tau_dis gives the disturbance the observer sees
        outlist += [[f"plant.tau_dis[{i}]", f"plant.tau[{i}]", f"-controller.tau[{i}]", f"-observer.d_hat[{i}]"]
                    for i in range(n)]
        outputs += _names("e_d", n)
    loop = ct.interconnect(list(blocks.values()), inplist=[[f"plant.tau[{i}]"] for i in range(n)],
                           inputs=_names("w", n), outlist=outlist, outputs=outputs,
                           name="dob_disturbance_loop" if observer else "ctc_disturbance_loop", check_unused=False)
    loop.scenario = scenario
    loop.with_observer = observer
    return loop


def frozen_response(scenario: Scenario, q0, observer: bool = True, t: float = 0.0) -> ct.StateSpace:
    """The loop linearized with the arm held at ``q0``: inputs ``w[i]``, outputs ``e[i]`` (and ``e_d[i]``)."""
    loop = disturbance_loop(hold_scenario(scenario, q0), observer)
    x_eq = equilibrium(loop, t)
    return linearize_loop(loop, x_eq, t)


def closed_form(scenario: Scenario, q0, omega, observer: bool = True, output: str = "e") -> np.ndarray:
    """The closed forms of docs/model.md at ``s = j omega``, shape (len(omega), n, n), perfect model.

    Parameters
    ----------
    output : {"e", "e_d"}
        Tracking error (rad/(N m), m/N) or estimation error (dimensionless).
    """
    M = scenario.nominal.inertia(np.asarray(q0, dtype=float))
    return closed_form_matrices(M, scenario.kp, scenario.kd, scenario.observer_gain, omega, observer, output)


def closed_form_matrices(M, kp, kd, Y, omega, observer: bool = True, output: str = "e") -> np.ndarray:
    """:func:`closed_form` from the matrices: inertia ``M`` and gains ``kp``, ``kd``, ``Y``, all ``n x n``."""
    if output not in ("e", "e_d"):
        raise ValueError(f"output must be 'e' or 'e_d', got {output!r}")
    M, Kp, Kd, Y = (np.asarray(v, dtype=float) for v in (M, kp, kd, Y))
    eye = np.eye(M.shape[-1])
    out = []
    for w in np.atleast_1d(np.asarray(omega, dtype=float)):
        s = 1j * w
        pd_inv = np.linalg.inv(s * s * eye + s * Kd + Kp)
        if output == "e":
            out.append(-pd_inv @ np.linalg.inv(M) if not observer else -s * pd_inv @ np.linalg.inv(s * M + Y))
        else:
            out.append(s * M @ np.linalg.inv(s * M + Y) if observer else eye.astype(complex))
    return np.array(out)


def _gain(sys: ct.StateSpace, out: int, inp: int, omega) -> np.ndarray:
    """``|G_out,inp(j omega)|`` evaluated from the state-space matrices."""
    A, B, C, D = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    resolvent = 1j * w[:, None, None] * np.eye(A.shape[0]) - A
    x = np.linalg.solve(resolvent, np.broadcast_to(B[:, inp], (len(w), A.shape[0]))[..., None])[..., 0]
    return np.abs(x @ C[out] + D[out, inp])


@dataclass(frozen=True)
class ChannelMetrics(JsonResult):
    """DC gain, peak and -3 dB band of one channel (gains in its units: rad/(N m), m/N or 1).

    Attributes
    ----------
    dc_gain : float
        Signed gain at s = 0.
    hf_gain : float
        ``|D|``, the gain as the frequency goes to infinity.
    peak_gain : float
        The largest gain.
    peak_rad_s : float or None
        Where it is reached (rad/s): 0 for a low-pass channel without resonance; None when at infinity.
    band_3db_rad_s : list of (float or None)
        ``[low, high]`` edges of the -3 dB band; None for an edge at infinity.
    kind : str
        ``"low-pass"``, ``"high-pass"`` or ``"band-pass"``.
    """

    dc_gain: float
    hf_gain: float
    peak_gain: float
    peak_rad_s: float | None
    band_3db_rad_s: list[float | None]
    kind: str


@dataclass(frozen=True)
class ResponseSet(JsonResult):
    """The n diagonal channels ``w[i] -> y[i]`` of one response.

    Attributes
    ----------
    magnitude : list of list of float
        Per joint, ``|G_ii(j omega)|`` over the frequency grid.
    metrics : list of ChannelMetrics
        Per joint.
    closed_form_max_rel_error : float
        Largest relative distance from the closed form over the grid, all n^2 channels.
    """

    magnitude: list[list[float]]
    metrics: list[ChannelMetrics]
    closed_form_max_rel_error: float


@dataclass(frozen=True)
class FrequencyAnalysis(JsonResult):
    """Disturbance responses of the loop held at ``q0`` (rad, m) on the grid ``omega_rad_s`` (rad/s).

    ``units`` gives the gain units of each joint's ``tracking`` and ``estimation`` channel.
    """

    q0: list[float]
    omega_rad_s: list[float]
    units: dict[str, list[str]]
    tracking_with_dob: ResponseSet
    estimation_with_dob: ResponseSet
    tracking_without_dob: ResponseSet

    def tracking(self, observer: bool) -> ResponseSet:
        """Disturbance to tracking error, with (True) or without (False) the observer."""
        return self.tracking_with_dob if observer else self.tracking_without_dob


def siso_metrics(sys: ct.StateSpace, out: int, inp: int, omega=DEFAULT_OMEGA) -> ChannelMetrics:
    """DC gain, peak gain and its frequency, and the -3 dB band of one channel.

    The channel is classed by where its gain is largest: *low-pass* if the DC
    gain is within 3 dB of the peak (band ``[0, omega_c]`` below the DC level
    minus 3 dB), *high-pass* if the high-frequency gain ``|D|`` is (band
    ``[omega_c, None]``), otherwise *band-pass* (band ``[omega_lo, omega_hi]``
    around the peak).  ``None`` stands for an edge at infinity.

    Returns
    -------
    ChannelMetrics
    """
    omega = np.asarray(omega, dtype=float)
    A, B, C, D = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
    dc = float(np.real(D[out, inp] - C[out] @ np.linalg.solve(A, B[:, inp])))
    hf = float(abs(D[out, inp]))
    mag = _gain(sys, out, inp, omega)
    k = int(np.argmax(mag))
    peak_w, peak = float(omega[k]), float(mag[k])
    if 0 < k < len(omega) - 1:
        res = minimize_scalar(lambda lw: -_gain(sys, out, inp, 10.0 ** lw)[0],
                              bounds=(math.log10(omega[k - 1]), math.log10(omega[k + 1])), method="bounded",
                              options={"xatol": 1e-10})
        if -res.fun > peak:
            peak_w, peak = float(10.0 ** res.x), float(-res.fun)
    if abs(dc) >= peak:
        peak_w, peak = 0.0, abs(dc)
    if hf >= peak:
        peak_w, peak = None, hf
    if abs(dc) >= peak / math.sqrt(2.0):
        kind, level = "low-pass", abs(dc) / math.sqrt(2.0)
    elif hf >= peak / math.sqrt(2.0):
        kind, level = "high-pass", hf / math.sqrt(2.0)
    else:
        kind, level = "band-pass", peak / math.sqrt(2.0)

    def crossing(i):
        """The level crossing between grid points i and i + 1."""
        return float(10.0 ** brentq(lambda lw: _gain(sys, out, inp, 10.0 ** lw)[0] - level,
                                    math.log10(omega[i]), math.log10(omega[i + 1]), xtol=1e-13))

    above = mag >= level
    change = np.nonzero(above[1:] != above[:-1])[0]
    if kind == "low-pass":
        band = [0.0, crossing(change[0]) if change.size else None]
    elif kind == "high-pass":
        band = [crossing(change[-1]) if change.size else 0.0, None]
    else:
        left, right = change[change < k], change[change >= k]
        band = [crossing(left[-1]) if left.size else 0.0, crossing(right[0]) if right.size else None]
    return ChannelMetrics(dc_gain=dc, hf_gain=hf, peak_gain=peak, peak_rad_s=peak_w, band_3db_rad_s=band, kind=kind)


def _gain_units(joints) -> list[str]:
    """Tracking-channel units per joint: position per generalised force, e.g. ``rad/(N m)``, ``m/N``."""
    return [f"{p}/({f})" if " " in f else f"{p}/{f}" for p, f in zip(joints.position_units, joints.force_units)]


def _response_sets(responses, exact, joints, omega) -> dict:
    """The :class:`ResponseSet` of each channel from linearized responses and the closed forms."""
    n = joints.count
    out = {"units": {"tracking": _gain_units(joints), "estimation": ["1"] * n}}
    for observer, key in ((True, "with_dob"), (False, "without_dob")):
        lin = responses[observer]
        channels = [("tracking", "e", 0)] + ([("estimation", "e_d", n)] if observer else [])
        for name, output, offset in channels:
            # squeeze=False: a one-joint arm without the observer is SISO, whose response python-control squeezes
            full = np.moveaxis(np.asarray(lin(1j * omega, squeeze=False))[offset:offset + n, :, :], -1, 0)
            ref = exact(observer, output)
            scale = np.maximum(np.abs(ref), np.abs(ref).max(axis=(1, 2), keepdims=True) * 1e-9)
            out[f"{name}_{key}"] = ResponseSet(
                magnitude=[np.abs(full[:, i, i]).tolist() for i in range(n)],
                metrics=[siso_metrics(lin, offset + i, i, omega) for i in range(n)],
                closed_form_max_rel_error=float(np.max(np.abs(full - ref) / scale)),
            )
    return out


def frequency_analysis(scenario: Scenario, q0, omega=DEFAULT_OMEGA, t: float = 0.0) -> FrequencyAnalysis:
    """Bode magnitudes and per-joint metrics of ``w[i] -> e[i]`` (with/without) and ``w[i] -> e_d[i]``.

    Returns
    -------
    FrequencyAnalysis
        ``tracking_with_dob``, ``estimation_with_dob`` and
        ``tracking_without_dob`` (see :class:`ResponseSet`).
    """
    q0 = np.asarray(q0, dtype=float)
    omega = np.asarray(omega, dtype=float)
    held = hold_scenario(scenario, q0)
    responses = {observer: frozen_response(scenario, q0, observer, t) for observer in (True, False)}
    sets = _response_sets(responses, lambda observer, output: closed_form(held, q0, omega, observer, output),
                          scenario.nominal.joints, omega)
    return FrequencyAnalysis(q0=q0.tolist(), omega_rad_s=omega.tolist(), **sets)


def arm_frequency_analysis(arm: ArmModel, kp, kd, Y, q0, omega=DEFAULT_OMEGA, d=None,
                           nominal: ArmModel | None = None) -> FrequencyAnalysis:
    """:func:`frequency_analysis` for any arm model, from :func:`~analysis.linear.arm_linear.arm_linearization`.

    Parameters
    ----------
    arm, nominal : ArmModel
        True plant and the model of controller and observer (default: the true one).
    kp, kd, Y : scalar, n numbers or n x n
        Controller gains (1/s^2, 1/s) and observer gain (kg m^2/s, kg/s).
    q0 : array_like, shape (n,)
        Held configuration (rad, m).
    d : array_like, shape (n,), optional
        Constant disturbance (N m, N) at which the loop rests.
    """
    loop = ArmLoop.make(arm, kp, kd, Y, q0, d, nominal)
    omega = np.asarray(omega, dtype=float)
    responses = {observer: arm_linearization(loop.arm, loop.kp, loop.kd, loop.Y, loop.q0, loop.d, loop.nominal,
                                             observer) for observer in (True, False)}
    M = loop.nominal.inertia(loop.q0)
    sets = _response_sets(
        responses, lambda observer, output: closed_form_matrices(M, loop.kp, loop.kd, loop.Y, omega, observer, output),
        loop.arm.joints, omega)
    return FrequencyAnalysis(q0=loop.q0.tolist(), omega_rad_s=omega.tolist(), **sets)
