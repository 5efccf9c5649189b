"""Linearize the Figure-2 loop and draw its disturbance rejection as a Bode plot.

The arm is held at the start of the paper's path (a constant reference) under
the paper's constant disturbance.  ``analysis.linear.frequency.frozen_response`` adds
an input torque ``w[i]`` at the plant, finds the loop's equilibrium with
``control.find_operating_point`` and linearizes the interconnection itself
with ``control.linearize``.  Its poles are the PD error dynamics, roots of
``s^2 + Kd s + Kp`` (-6 and -30 for Kp = 180, Kd = 36), and with the observer
the eigenvalues of ``-Y M^-1(q0)``.  The Bode plot is the prismatic joint's
tracking error per unit force, ``w[2] -> e[2]``, with and without the observer:
the observer turns a constant offset into zero DC gain.

Writes ``linearize_and_bode.png`` into ``$DOBKIT_EXAMPLES_OUT`` (default: the
current folder).
"""
import os
from pathlib import Path

import control as ct
import matplotlib

matplotlib.use("Agg")                   # no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import blocks  # noqa: E402
from analysis.linear.frequency import closed_form, frozen_response  # noqa: E402

out_dir = Path(os.environ.get("DOBKIT_EXAMPLES_OUT", "."))
out_dir.mkdir(parents=True, exist_ok=True)

scenario = blocks.load_scenario("paper")
q0, _, _ = scenario.trajectory.evaluate(0.0)            # the path's first pose (rad, rad, m, rad)

# Linear state-space models: inputs w[i] (N m, N), outputs e[i] (rad, m) and, with the observer, e_d[i].
with_observer = frozen_response(scenario, q0, observer=True)
without_observer = frozen_response(scenario, q0, observer=False)

# The poles against the analytic split (perfect nominal model in the paper scenario).
M = blocks.inertia(q0, scenario.nominal)
analytic_observer = np.sort(np.linalg.eigvals(-scenario.observer_gain @ np.linalg.inv(M)).real)
print("poles with the observer:   ", np.round(np.sort(with_observer.poles().real), 3))
print("analytic PD roots:          -6, -30 (each joint); observer poles:", np.round(analytic_observer, 3))

# One channel: force on the prismatic joint (N) -> its tracking error (m), picked by signal name.
omega = np.logspace(-2, 3, 300)                          # rad/s
channel_dob = with_observer["e[2]", "w[2]"]
channel_ctc = without_observer["e[2]", "w[2]"]
resp_dob = ct.frequency_response(channel_dob, omega)
resp_ctc = ct.frequency_response(channel_ctc, omega)
print(f"DC gain w[2] -> e[2]: without observer {abs(channel_ctc.dcgain()):.2e} m/N "
      f"(1/(Kp M33) = {1 / (scenario.kp[2, 2] * M[2, 2]):.2e}), with observer {abs(channel_dob.dcgain()):.1e} m/N")

cplt = ct.bode_plot([resp_ctc, resp_dob], dB=False, label=["computed torque only", "with the observer"], title=(
    "Disturbance rejection at the path's start: force on joint 3 (N) -> its tracking error (m)"))
# the closed form of docs/model.md at a few frequencies, as a check on the linearization
marks = np.logspace(-2, 3, 11)
exact = np.abs(closed_form(scenario, q0, marks, observer=True)[:, 2, 2])
cplt.axes[0, 0].plot(marks, exact, "k.", label="closed form, with the observer")
cplt.axes[0, 0].legend(loc="lower left")
cplt.axes[0, 0].set_ylabel("|e[2] / w[2]| (m/N)")
cplt.axes[1, 0].set_xlabel("frequency (rad/s)")
cplt.figure.set_size_inches(8, 6)
cplt.figure.savefig(out_dir / "linearize_and_bode.png", dpi=80)
plt.close(cplt.figure)
print(f"wrote {out_dir / 'linearize_and_bode.png'}")
