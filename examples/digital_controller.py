"""The controller as a program running at 1 kHz against the continuous arm, beside the continuous controller.

The built-in scenario ``paper-digital`` is the paper's arm, gains and
disturbance on the default laceration path (a straight cut; ``paper``'s path
bulges) with a ``[controller]`` section: every 1 ms the controller reads 2^17-count encoders,
estimates the velocity by a backward difference through a 200 Hz low-pass,
updates the observer (forward Euler) and holds its torque until the next
sample.  ``blocks.simulate`` then runs the controller and observer as
python-control discrete-time blocks in the same Figure-2 diagram as the
continuous plant.  The same scenario without its ``[controller]`` section is
the continuous loop.  We compare the first 0.5 s: the held, quantized torque
and the tracking error of joint 4, the joint that quantization hurts most.

Writes ``digital_controller.png`` into ``$DOBKIT_EXAMPLES_OUT`` (default: the
current folder).
"""
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")                   # no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import blocks  # noqa: E402

out_dir = Path(os.environ.get("DOBKIT_EXAMPLES_OUT", "."))
out_dir.mkdir(parents=True, exist_ok=True)

# Output every 1 ms, the sample period, so the held torque shows as steps.
sampled = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.5,
                                                              "simulation.output_step": 0.001})
print(f"sample rate {sampled.controller.sample_rate:g} Hz, velocity by {sampled.controller.velocity}")
continuous = blocks.scenario_from_dict({k: v for k, v in sampled.data.items() if k != "controller"},
                                       source="paper-digital without [controller]")

# engine="fast": the numpy engines, no compile step (the default with numba compiles each loop once, ~10 s).
runs = {"continuous": blocks.simulate(continuous, engine="fast"),
        "1 kHz, sampled and quantized": blocks.simulate(sampled, engine="fast")}


def joint_signal(resp, name):
    """One output of a response by its name."""
    return resp.outputs[list(resp.output_labels).index(name)]


fig, (ax_tau, ax_err) = plt.subplots(2, 1, sharex=True, figsize=(8, 6))
for (label, resp), style in zip(runs.items(), ({}, {"drawstyle": "steps-post", "lw": 0.8})):
    error_mrad = 1e3 * (joint_signal(resp, "q_ref[3]") - joint_signal(resp, "q[3]"))
    ax_tau.plot(resp.time, joint_signal(resp, "tau[3]"), label=label, **style)
    ax_err.plot(resp.time, error_mrad, label=label)
    print(f"{label:30s} RMS joint-4 error {np.sqrt(np.mean(error_mrad ** 2)):.3f} mrad, "
          f"RMS torque {np.sqrt(np.mean(joint_signal(resp, 'tau[3]') ** 2)):.3f} N m")
ax_tau.set_ylabel("tau[3], applied (N m)")
ax_err.set_ylabel("q_ref[3] - q[3] (mrad)")
ax_err.set_xlabel("time (s)")
ax_tau.legend(loc="best")
fig.suptitle("paper-digital, first 0.5 s: joint 4 with a continuous and a 1 kHz sampled controller")
fig.tight_layout()
fig.savefig(out_dir / "digital_controller.png", dpi=80)
plt.close(fig)
print(f"wrote {out_dir / 'digital_controller.png'}")
