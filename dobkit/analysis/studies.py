"""Gain and noise studies from nonlinear simulations: what Kp, Kd and the observer gain buy, and what they cost.

Every point of a study is one run of :func:`dobkit.blocks.simulate` on a copy
of the scenario with other gains.  Per run, for each joint error
``e = q_ref - q`` (rad, m) and for the tool-tip position error (mm):

``settling_time_s``
    The time after which the signal stays within a band around its final
    value: ``|x - x_final| <= settle_fraction * max|x - x_final|``, with
    ``x_final`` the mean over the last ``final_window`` fraction of the run.
    None if the signal leaves the band inside that final window (it has not
    settled within the run).
``steady_state_error``
    ``|x_final|``.
``peak_error``, ``rms_error``
    ``max|x|`` and the root mean square over the run (Eq. 13).

The noise study repeats a run with measurement noise on ``q`` and ``q'`` and
reports the torque noise ``rms(tau_noisy - tau_clean)`` per joint (N m, N):
the price of a faster observer, whose ``d_hat = Y q' + z`` passes velocity
noise through ``Y``.
"""
from __future__ import annotations

import copy
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ..blocks import SimulationError, forward_kinematics, scenario_from_dict, simulate
from ..blocks.scenario import Scenario
from .metrics import signal

__all__ = ["DEFAULT_NOISE", "run_metrics", "signal_metrics", "gain_grid_study", "observer_gain_study"]

# Used when the scenario has no [noise] section: an encoder of about 0.01 deg (2e-4 rad, 20 um) and
# velocities from differentiated positions (5e-3 rad/s, 0.5 mm/s).  Assumed values, not from the paper.
DEFAULT_NOISE = {"q_std": [2e-4, 2e-4, 2e-5, 2e-4], "dq_std": [5e-3, 5e-3, 5e-4, 5e-3], "seed": 1,
                 "sample_period": 0.001}


def signal_metrics(t, x, settle_fraction: float = 0.02, final_window: float = 0.1) -> dict:
    """Settling time, steady-state, peak and RMS of one signal ``x(t)`` (units of ``x``; time in s)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    start = min(len(x) - 1, int(np.floor((1.0 - final_window) * (len(x) - 1))))
    final = float(np.mean(x[start:]))
    dev = np.abs(x - final)
    band = settle_fraction * float(dev.max())
    outside = np.nonzero(dev > band)[0]
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] >= start:
        settling = None
    else:
        settling = float(t[outside[-1] + 1])
    return {"settling_time_s": settling, "steady_state_error": abs(final), "peak_error": float(np.max(np.abs(x))),
            "rms_error": float(np.sqrt(np.mean(x ** 2)))}


def run_metrics(response, settle_fraction: float = 0.02, final_window: float = 0.1) -> dict:
    """Study metrics of one run: per joint (``joints``, rad or m) and for the tool tip (``tool_mm``, mm)."""
    t = np.asarray(response.time)
    e = signal(response, "q_ref") - signal(response, "q")
    out = {"joints": [signal_metrics(t, e[i], settle_fraction, final_window) for i in range(4)]}
    robot = response.scenario.robot
    tip = 1e3 * np.linalg.norm(forward_kinematics(signal(response, "q_ref").T, robot)[:, :3]
                               - forward_kinematics(signal(response, "q").T, robot)[:, :3], axis=1)
    out["tool_mm"] = signal_metrics(t, tip, settle_fraction, final_window)
    return out


def _variant_data(scenario: Scenario, gains: dict, t_final: float | None) -> dict:
    """The scenario's data with other gains, no noise and optionally a shorter run."""
    data = copy.deepcopy(scenario.data)
    data["gains"] = {**data["gains"], **gains}
    data["noise"] = {"q_std": [0.0] * 4, "dq_std": [0.0] * 4}
    if t_final is not None:
        # only the first t_final seconds of the same path (its duration is kept in the data)
        data["simulation"]["t_final"] = float(t_final)
    return data


def _run(job) -> dict:
    """One study point (runs in a worker process): clean run, and a noisy one when asked."""
    data, source, observer, noise, max_step = job
    try:
        clean_data = copy.deepcopy(data)
        if noise is not None:
            clean_data["simulation"]["max_step"] = max_step
        clean = simulate(scenario_from_dict(clean_data, source), observer=observer)
        result = {"ok": True, **run_metrics(clean)}
        if noise is not None:
            noisy_data = copy.deepcopy(clean_data)
            noisy_data["noise"] = noise
            noisy = simulate(scenario_from_dict(noisy_data, source), observer=observer)
            diff = signal(noisy, "tau") - signal(clean, "tau")
            result["torque_noise_rms"] = np.sqrt(np.mean(diff ** 2, axis=1)).tolist()
            result["noisy"] = run_metrics(noisy)
        return result
    except SimulationError as err:
        return {"ok": False, "error": str(err)}


def _map(jobs, workers: int) -> list:
    if workers <= 1 or len(jobs) <= 1:
        return [_run(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(_run, jobs))


def gain_grid_study(scenario: Scenario, kp_values, kd_values, observer: bool = True, t_final: float | None = None,
                    workers: int = 1) -> dict:
    """Runs over a grid of scalar ``Kp`` (1/s^2) and ``Kd`` (1/s), the same on every joint.

    Parameters
    ----------
    scenario : Scenario
        Everything but the PD gains is kept (noise is removed).
    kp_values, kd_values : sequence of float
        Grid values, > 0.
    observer : bool
        With or without the disturbance observer.
    t_final : float, optional
        Shorter runs (s): the first ``t_final`` seconds of the same path.
    workers : int
        Processes to use (results do not depend on it).

    Returns
    -------
    dict
        ``kp``, ``kd``, ``observer`` and ``runs[i][j]`` (metrics of
        :func:`run_metrics` for ``kp[i]``, ``kd[j]``, or ``{"ok": False, "error"}``).
    """
    kp_values, kd_values = [float(v) for v in kp_values], [float(v) for v in kd_values]
    if not kp_values or not kd_values or min(kp_values + kd_values) <= 0:
        raise ValueError(f"gain grids must be non-empty and > 0, got kp={kp_values}, kd={kd_values}")
    jobs = [(_variant_data(scenario, {"kp": kp, "kd": kd}, t_final), scenario.source, observer, None, None)
            for kp in kp_values for kd in kd_values]
    flat = _map(jobs, workers)
    runs = [flat[i * len(kd_values):(i + 1) * len(kd_values)] for i in range(len(kp_values))]
    return {"kp": kp_values, "kd": kd_values, "observer": observer, "runs": runs,
            "t_final_s": t_final if t_final is not None else scenario.simulation.t_final}


def observer_gain_study(scenario: Scenario, gains, noise: dict | None = None, t_final: float | None = None,
                        workers: int = 1) -> dict:
    """Runs with each observer gain, clean and with measurement noise, plus one without the observer.

    Parameters
    ----------
    scenario : Scenario
    gains : sequence of (str, gain)
        Labels and observer gains (scalar, 4 numbers or 4x4; kg m^2/s).
    noise : dict, optional
        A ``[noise]`` table (default: the scenario's, else :data:`DEFAULT_NOISE`).
    t_final : float, optional
        Shorter runs (s).
    workers : int
        Processes to use.

    Returns
    -------
    dict
        ``noise`` (the table used), ``labels`` (``"none"`` first: no observer),
        ``gains`` and ``runs`` (metrics of :func:`run_metrics` plus
        ``torque_noise_rms`` per joint (N m, N) and ``noisy`` metrics).
    """
    if noise is None:
        noise = dict(scenario.data["noise"]) if scenario.noise is not None else dict(DEFAULT_NOISE)
    # The noise is linear between samples; steps no longer than a sample keep the solver from
    # rejecting steps at every kink (measured: 6x faster, same torques to 1e-4).
    max_step = float(noise.get("sample_period", DEFAULT_NOISE["sample_period"]))
    labels, specs, jobs = ["none"], [None], []
    jobs.append((_variant_data(scenario, {}, t_final), scenario.source, False, noise, max_step))
    for label, gain in gains:
        g = np.asarray(gain, dtype=float)
        labels.append(str(label))
        specs.append(g.tolist())
        jobs.append((_variant_data(scenario, {"observer": g.tolist() if g.ndim else float(g)}, t_final),
                     scenario.source, True, noise, max_step))
    return {"noise": noise, "labels": labels, "gains": specs, "runs": _map(jobs, workers),
            "t_final_s": t_final if t_final is not None else scenario.simulation.t_final}
