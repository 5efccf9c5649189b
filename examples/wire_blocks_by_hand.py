"""Build the Figure-2 blocks, wire them by signal name and simulate with python-control.

The blocks of the paper's Figure 2 (trajectory, controller, plant with its
disturbance models inside, observer; a sensor too when the scenario has
measurement noise) are ordinary ``control.NonlinearIOSystem`` objects whose
signals are named ``q[i]``, ``dq[i]``, ``tau[i]``, ``d_hat[i]``, ...
``control.interconnect`` connects
equal names, so wiring the loop by hand is one call.  We keep four outputs
(joint 3, the prismatic joint: position, torque, disturbance and its estimate),
simulate the first second of the paper's 10 s path with
``control.input_output_response`` and compare with ``blocks.simulate``, which
runs the same interconnection on a faster engine.

Writes ``wire_blocks_by_hand.png`` into ``$DOBKIT_EXAMPLES_OUT`` (default: the
current folder).

Then two blocks of our own join the loop: a first-order actuator lag on the
prismatic joint's force (``ct.tf``, 5 ms: the controller and the observer
believe in the commanded force, the plant gets the lagged one) and a
nonlinear filter (``ct.nlsys`` with a numpy function) that watches the
tracking error.  ``blocks.simulate_system`` takes what
``ct.input_output_response`` takes and runs this diagram on the compiled
engine: the lag becomes ``A x + B u`` kernels, the filter is traced into the
generated code.
"""
import os
from pathlib import Path

import control as ct
import matplotlib

matplotlib.use("Agg")                   # no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import blocks  # noqa: E402

out_dir = Path(os.environ.get("DOBKIT_EXAMPLES_OUT", "."))
out_dir.mkdir(parents=True, exist_ok=True)

# The paper scenario, first second only: the path keeps its own 10 s duration, the run simply ends early.
scenario = blocks.load_scenario("paper").with_changes({"simulation.t_final": 1.0})

# The blocks, keyed by name: trajectory, controller, plant, observer.
parts = blocks.build_blocks(scenario, observer=True)
for name, block in parts.items():
    print(f"{name:10s} inputs {block.ninputs:2d}  outputs {block.noutputs:2d}  states {block.nstates}")

# Wire by signal name.  The loop has no external input; its outputs are the signals we choose to see.
chosen = ["q[2]", "tau[2]", "tau_dis[2]", "d_hat[2]"]
# (check_unused=False: the plant's tau_dis of the other joints feeds nothing, and that is intended.)
loop = ct.interconnect(list(parts.values()), inplist=[], outlist=chosen, outputs=chosen, name="hand_wired",
                       check_unused=False)

# Start on the reference with d_hat(0) = 0 (blocks.initial_state finds the states by block and signal name).
x0 = blocks.initial_state(loop, scenario)
t = scenario.simulation.time_grid                                  # s, the scenario's output grid
sim = scenario.simulation
resp = ct.input_output_response(loop, t, 0, x0, solve_ivp_method=sim.method,
                                solve_ivp_kwargs=dict(rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step))

# The same scenario through blocks.simulate, on the numpy engine (engine="fast": no compile step; with numba the
# default engine compiles the loop once, about 10 s, and caches it).  It returns every loop signal by name; pick
# the same four by name.
full = blocks.simulate(scenario, engine="fast")
rows = [list(full.output_labels).index(name) for name in chosen]
picked = ct.TimeResponseData(full.time, full.outputs[rows], output_labels=chosen, sysname="blocks.simulate",
                             issiso=False, plot_inputs=False)
print(f"blocks.simulate has {full.noutputs} outputs (engine {full.engine}); largest difference from the "
      f"hand-wired run: q[2] {np.max(np.abs(picked.outputs[0] - resp.outputs[0])):.1e} m, "
      f"d_hat[2] {np.max(np.abs(picked.outputs[3] - resp.outputs[3])):.1e} N")

# resp.plot() draws one axis per output; the second response goes onto the same axes.
cplt = resp.plot(plot_inputs=False)
picked.plot("C1--", ax=cplt.axes, plot_inputs=False)
cplt.axes[0, 0].legend(["ct.input_output_response", "blocks.simulate"], loc="best")
units = ["q[2] (m)", "tau[2] (N)", "tau_dis[2] (N)", "d_hat[2] (N)"]
for ax, unit in zip(cplt.axes[:, 0], units):
    ax.set_ylabel(unit)
cplt.axes[-1, 0].set_xlabel("time (s)")
cplt.set_plot_title("Joint 3 (prismatic), paper scenario, first 1 s: hand-wired loop vs blocks.simulate")
cplt.figure.set_size_inches(8, 8)
cplt.figure.savefig(out_dir / "wire_blocks_by_hand.png", dpi=80)
plt.close(cplt.figure)
print(f"wrote {out_dir / 'wire_blocks_by_hand.png'}")

# -- two blocks of our own -------------------------------------------------------------------------------------
# A 5 ms first-order lag between the commanded force on joint 3 and the plant.
actuator = ct.tf([1.0], [0.005, 1.0], inputs="f_cmd", outputs="f_act", name="actuator")


def error_filter_update(t, x, u, params):
    """A smoothed squared tracking error of joint 3 (m^2): x' = (e^2 - x) / tau_e with e = q_ref[2] - q[2]."""
    e = u[0] - u[1]
    return np.array([(e * e - x[0]) / params["tau_e"]])


watch = ct.nlsys(error_filter_update, lambda t, x, u, params: np.sqrt(np.abs(x)), inputs=["q_ref", "q"],
                 outputs="e_rms", states="e2", name="watch", params={"tau_e": 0.05})

# Wired by name as before, except the force on joint 3, which now passes the actuator.
connections = [[f"controller.{sig}", f"trajectory.{sig}"] for sig in ("q_ref", "dq_ref", "ddq_ref")]
connections += [["controller.q", "plant.q"], ["controller.dq", "plant.dq"], ["controller.d_hat", "observer.d_hat"],
                ["observer.tau", "controller.tau"], ["observer.q", "plant.q"], ["observer.dq", "plant.dq"]]
connections += [[f"plant.tau[{i}]", f"controller.tau[{i}]"] for i in (0, 1, 3)]
connections += [["actuator.f_cmd", "controller.tau[2]"], ["plant.tau[2]", "actuator.f_act"],
                ["watch.q_ref", "trajectory.q_ref[2]"], ["watch.q", "plant.q[2]"]]
seen = ["plant.q[2]", "actuator.f_act", "observer.d_hat[2]", "watch.e_rms"]
own = ct.interconnect(list(parts.values()) + [actuator, watch], connections=connections, inplist=[], outlist=seen,
                      outputs=["q[2]", "f_act", "d_hat[2]", "e_rms"], name="with_actuator", check_unused=False)
x0_own = np.concatenate([blocks.initial_state(loop, scenario), [0.0, 0.0]])  # the lag and the filter start at 0
kwargs = dict(rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step)
mine = blocks.simulate_system(own, t, x0_own, solve_ivp_kwargs=kwargs)           # engine="auto": compiled here
theirs = ct.input_output_response(own, t, 0, x0_own, solve_ivp_kwargs=kwargs)
lag_effect = np.max(np.abs(mine.outputs[0] - resp.outputs[0]))
print(f"with the actuator lag: engine {mine.engine}; largest difference from ct.input_output_response "
      f"{np.max(np.abs(mine.outputs - theirs.outputs)):.1e}; the lag moves q[2] by up to {1e3 * lag_effect:.4f} mm; "
      f"smoothed |error| of joint 3 at 1 s: {1e3 * mine.outputs[3, -1]:.4f} mm")
