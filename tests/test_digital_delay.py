"""The controller's delay line, pinned against its definition: at tick k the applied torque is the command of tick k - n.

``[controller] delay = n`` means the torque computed at ``t_k`` is applied from
``t_{k+n}`` (blocks/diagram/digital.py).  The expected values here are written from that
sentence alone: a sequence of distinct commands, shifted by ``n`` ticks, with the
buffer's initial contents (oldest first) filling the first ``n`` ticks.  Every
delay from 0 to 5 is checked, so that a buffer read from the wrong end (which
is the same thing for ``n <= 1``) fails.
"""
from __future__ import annotations

import control as ct
import numpy as np
import pytest
from test_digital import SINE, TIGHT, _reference_sampled_run, _scenario

from blocks.diagram.digital import DigitalController, actuator
from blocks.figure2.digital_loop import simulate_sampled
from blocks.figure2.metrics import signal

RATE = 500.0                    # Hz: Ts = 2 ms
TICKS = 12


def _commands(ticks: int) -> np.ndarray:
    """Distinct commands per joint and tick, shape (4, ticks): 100 i + k + 0.25 (no two equal)."""
    return np.array([[100.0 * i + k + 0.25 for k in range(ticks)] for i in range(4)])


def _run(block, t, commands, x0) -> np.ndarray:
    """The block's outputs at the ticks ``t`` for the commands (4, K), by python-control's discrete-time simulation."""
    if block.nstates == 0:      # python-control hands a stateless block a list for its state: one tick at a time
        return np.column_stack([block.output(tk, np.zeros(0), commands[:, k]) for k, tk in enumerate(t)])
    return np.asarray(ct.input_output_response(block, t, commands, x0).outputs)


@pytest.mark.parametrize("delay", range(6))
def test_the_actuator_applies_the_command_of_tick_k_minus_delay(delay):
    block = actuator(DigitalController(sample_rate=RATE, delay=delay))
    Ts = 1.0 / RATE
    t = np.arange(TICKS) * Ts
    commands = _commands(TICKS)
    # the buffer before the first tick, oldest first: -(j + 1) - 10 i for slot j, joint i
    initial = np.array([[-(j + 1.0) - 10.0 * i for i in range(4)] for j in range(delay)])
    applied = _run(block, t, commands, initial.ravel())
    expected = np.empty((4, TICKS))
    for k in range(TICKS):
        expected[:, k] = commands[:, k - delay] if k >= delay else initial[k]
    np.testing.assert_array_equal(applied, expected)


@pytest.mark.parametrize("delay", [2, 5])
def test_the_delayed_command_is_saturated_when_it_is_applied(delay):
    limit = (100.0, 0.0, 203.0, 0.0)           # joints 1 and 3 limited, 2 and 4 free (0 = none)
    block = actuator(DigitalController(sample_rate=RATE, delay=delay, torque_limit=limit))
    t = np.arange(TICKS) / RATE
    commands = _commands(TICKS)
    commands[0] *= -20.0                        # joint 1: -5, -25, ... -225 N m, beyond -100 from the 6th
    applied = _run(block, t, commands, np.zeros(4 * delay))
    for k in range(delay, TICKS):
        c = commands[:, k - delay]
        want = [max(c[0], -100.0), c[1], min(c[2], 203.0), c[3]]
        np.testing.assert_array_equal(applied[:, k], want)
    assert applied[0].min() == -100.0 and applied[2].max() == 203.0      # both limits were reached


@pytest.mark.parametrize("delay", range(6))
def test_in_the_loop_the_applied_torque_is_the_command_of_delay_samples_before(delay):
    """The whole sampled loop, recorded at the sample instants: tau(t_k) = tau_cmd(t_{k-n}), and the held command
    of t = 0 before that (the arm was being held by it)."""
    s = _scenario(SINE | {"simulation.t_final": 0.03, "simulation.output_step": 1.0 / RATE,
                          "controller.sample_rate": RATE, "controller.delay": delay})
    r = simulate_sampled(s)
    tau, cmd = signal(r, "tau"), signal(r, "tau_cmd")
    assert tau.shape[1] == 16
    # the command moves between samples (a sine reference): consecutive commands differ, so a shift is visible
    assert np.abs(np.diff(cmd, axis=1)).min() > 1e-6
    for k in range(tau.shape[1]):
        np.testing.assert_array_equal(tau[:, k], cmd[:, max(k - delay, 0)])


def test_the_loop_with_three_samples_of_delay_follows_the_definition_of_the_controller_section():
    """The definition check of issue 23: 500 Hz, delay 3, against the sampled loop written from the definition."""
    s = _scenario(SINE | TIGHT | {"simulation.t_final": 0.1, "simulation.output_step": 0.002,
                                  "controller.sample_rate": 500.0, "controller.delay": 3})
    got = signal(simulate_sampled(s), "q")
    want = _reference_sampled_run(s, got.shape[1])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
