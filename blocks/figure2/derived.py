"""What is derived from a run after any engine: the lumped disturbance and the response object.

Every engine (python-control, numpy, compiled, the sampled loop, the
co-simulations) returns the loop's outputs on its grid; :func:`loop_response`
appends the lumped disturbance ``d`` the observer estimates
(:func:`blocks.kernels.lumped_disturbance`, Eq. 2-3 relative to the nominal
model) and makes the python-control response every engine returns, with the
scenario and the observer flag attached.  The tracking metrics are defined
once in :class:`blocks.figure2.metrics.TrackingAccumulator` (the compiled batch
accumulates the same sums in its driver and finishes them with the same
definitions).
"""
from __future__ import annotations

import control as ct
import numpy as np

from blocks.diagram.systems import signal_names
from blocks.kernels import lumped_disturbance as lumped_disturbance_rows

__all__ = ["lumped_disturbance_of", "loop_response"]


def lumped_disturbance_of(outputs: np.ndarray, labels: list, scenario) -> np.ndarray:
    """The lumped disturbance ``d`` (n, T) (N m, N) from a run's outputs (noutputs, T) labelled ``labels``.

    Needs the outputs ``q[i]``, ``dq[i]``, ``tau[i]`` and ``tau_dis[i]``; the
    true arm is the scenario's ``robot``, the model the scenario's ``nominal``.
    """
    index = {name: k for k, name in enumerate(labels)}
    arm = scenario.robot
    try:
        rows = [outputs[[index[n] for n in signal_names(sig, arm)]] for sig in ("q", "dq", "tau", "tau_dis")]
    except KeyError as err:
        raise ValueError(f"the run has no output {err.args[0]!r}, which the lumped disturbance needs") from None
    return lumped_disturbance_rows(arm.arm_kernels, arm.kernel_params(), scenario.nominal.kernel_params(), *rows)


def loop_response(time, outputs, states, labels: list, state_labels: list | None, scenario, observer: bool,
                  title: str, sysname: str, d=None, with_d: bool = False) -> ct.TimeResponseData:
    """The response of a Figure-2 run: its outputs with ``d[i]`` appended, as python-control users expect.

    Parameters
    ----------
    time : numpy.ndarray
        The output grid (s).
    outputs : numpy.ndarray
        The loop's outputs (noutputs, T), labelled ``labels``.
    states : numpy.ndarray or None
        The states (nstates, T), labelled ``state_labels``.
    scenario : blocks.scenarios.scenario.Scenario
    observer : bool
    title, sysname : str
    d : numpy.ndarray, optional
        The lumped disturbance when the engine computed it already (the compiled engine does, in its grid pass).
    with_d : bool
        ``outputs`` ends with the lumped disturbance's n rows already (the compiled engine's grid pass writes
        them there): the response takes the array as it is, without joining a copy.

    Returns
    -------
    control.TimeResponseData
        With attributes ``scenario`` and ``with_observer``.
    """
    outputs = np.asarray(outputs, dtype=float)
    if not with_d:
        d = lumped_disturbance_of(outputs, list(labels), scenario) if d is None else d
        outputs = np.vstack([outputs, d])
    resp = ct.TimeResponseData(time, outputs, states,
                               output_labels=list(labels) + signal_names("d", scenario.robot),
                               state_labels=state_labels if states is not None else None, title=title,
                               sysname=sysname, issiso=False, plot_inputs=False)
    resp.scenario = scenario
    resp.with_observer = observer
    return resp
