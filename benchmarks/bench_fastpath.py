"""Fast path vs a hand-fused numpy closed loop vs python-control, on one scenario (default: the paper's 10 s run).

    PYTHONPATH=. python benchmarks/bench_fastpath.py [--scenario paper] [--repeats 9] [--json out.json]

Three ways to get the same response (states and the loop's signals on the output
grid), all with the scenario's solver settings (paper: RK45, rtol 1e-6, atol 1e-8):

* ``hand-fused``: the closed loop written once by hand, below: one right-hand
  side with every quantity computed once (the nominal model shared by
  controller and observer, the disturbance evaluated once), built from the same
  model functions of :mod:`blocks.dynamics`; signals on the grid
  computed vectorised afterwards.  This is the baseline of the ratios.
* ``fast``: :func:`blocks.simulate` with ``engine="fast"`` (the
  interconnected system evaluated in its precomputed block order).
* ``python-control``: the same call with ``engine="python-control"``
  (:func:`control.input_output_response` on the interconnected system).

The paths are timed in turn, ``--repeats`` times.  The machine is shared, so
each run's CPU time (:func:`time.process_time`) is recorded beside its wall
time, and the ratio that decides the target is the fastest CPU time of each
path over the fastest CPU time of the hand-fused loop; the median of the ratios
of runs made one right after the other is shown beside, and so are wall times.
Peak memory is measured separately with :mod:`tracemalloc`.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys

import numpy as np
from scipy.integrate import solve_ivp

import blocks
from blocks.disturbances import external_disturbance
from blocks.dynamics import coriolis_vector, gravity, inertia

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import print_and_save, machine, max_rss_mb, peak_memory, summary, table, time_interleaved  # noqa: E402

#: The fast path's target, as a multiple of the hand-fused time (issue "Speed and scale").
TARGET_RATIO = 1.3


def hand_fused_rhs(s: blocks.Scenario):
    """The Figure-2 loop with observer as one hand-written right-hand side ``f(t, x)``, x = [q, dq, z].

    Covers what the paper scenario uses: the correct observer and no measurement noise.
    """
    if s.noise is not None or s.observer_variant != "correct":
        raise ValueError("the hand-fused baseline covers the correct observer without measurement noise")
    traj, robot, nominal, spec = s.trajectory, s.robot, s.nominal, s.disturbance
    Kp, Kd, Y = s.kp, s.kd, s.observer_gain

    def rhs(t, x):
        q, dq, z = x[0:4], x[4:8], x[8:12]
        q_ref, dq_ref, ddq_ref = traj.evaluate(t)
        M_hat = inertia(q, nominal)
        h_hat = coriolis_vector(q, dq, nominal) + gravity(q, nominal)
        d_hat = Y @ dq + z
        tau = M_hat @ (ddq_ref + Kd @ (dq_ref - dq) + Kp @ (q_ref - q)) + h_hat - d_hat
        tau_dis = external_disturbance(t, q, dq, spec, robot)
        ddq = np.linalg.solve(inertia(q, robot), tau + tau_dis - coriolis_vector(q, dq, robot) - gravity(q, robot))
        dz = -Y @ np.linalg.solve(M_hat, tau + d_hat - h_hat)
        return np.concatenate([dq, ddq, dz])
    return rhs


def hand_fused(s: blocks.Scenario) -> dict:
    """Simulate with :func:`hand_fused_rhs` and compute the loop's signals on the grid, vectorised."""
    rhs = hand_fused_rhs(s)
    traj, robot, nominal, spec = s.trajectory, s.robot, s.nominal, s.disturbance
    Kp, Kd, Y = s.kp, s.kd, s.observer_gain
    sim = s.simulation
    t_grid = sim.time_grid
    q0, dq0, _ = traj.evaluate(0.0)
    x0 = np.concatenate([q0, dq0, -Y @ dq0])
    sol = solve_ivp(rhs, (0.0, t_grid[-1]), x0, method=sim.method, t_eval=t_grid, rtol=sim.rtol, atol=sim.atol,
                    max_step=sim.max_step)
    X = sol.y.T
    q, dq, z = X[:, 0:4], X[:, 4:8], X[:, 8:12]
    q_ref, dq_ref, ddq_ref = traj.evaluate(t_grid)
    M_hat = inertia(q, nominal)
    h_hat = coriolis_vector(q, dq, nominal) + gravity(q, nominal)
    d_hat = dq @ Y.T + z
    v = ddq_ref + (dq_ref - dq) @ Kd.T + (q_ref - q) @ Kp.T
    tau = (M_hat @ v[..., None])[..., 0] + h_hat - d_hat
    tau_dis = external_disturbance(t_grid, q, dq, spec, robot)
    d = blocks.lumped_disturbance(q, dq, tau, tau_dis, s)
    return {"q": q, "dq": dq, "q_ref": q_ref, "dq_ref": dq_ref, "ddq_ref": ddq_ref, "tau": tau, "d_hat": d_hat,
            "tau_dis": tau_dis, "d": d, "nfev": sol.nfev}


def _signal(resp, name):
    labels = list(resp.output_labels)
    return np.asarray(resp.outputs)[[labels.index(f"{name}[{i}]") for i in range(4)]].T


def run(scenario: str = "paper", repeats: int = 9, pc_repeats: int = 3) -> dict:
    """Time the three paths and return the figures (seconds, ratios, MB, agreement)."""
    s = blocks.load_scenario(scenario)
    cases = {
        "hand-fused": lambda: hand_fused(s),
        "fast": lambda: blocks.simulate(s, engine="fast"),
        "python-control": lambda: blocks.simulate(s, engine="python-control"),
    }
    # Warm up (imports, caches) and check that all three give the same answer.
    base, fast, pc = (cases[name]() for name in ("hand-fused", "fast", "python-control"))
    agreement = {
        "fast vs hand-fused, q": float(np.abs(_signal(fast, "q") - base["q"]).max()),
        "fast vs python-control, q": float(np.abs(_signal(fast, "q") - _signal(pc, "q")).max()),
        "fast vs python-control, tau": float(np.abs(_signal(fast, "tau") - _signal(pc, "tau")).max()),
    }
    times = time_interleaved(cases, repeats, {"python-control": pc_repeats}, clock="both")
    memory = {name: peak_memory(fn) for name, fn in cases.items()}
    out = {"scenario": scenario, "machine": machine(), "repeats": repeats, "rhs_calls_hand_fused": int(base["nfev"]),
           "peak_python_heap_mb": memory, "max_rss_mb": max_rss_mb(), "agreement": agreement,
           "target_ratio": TARGET_RATIO, "load_average": os.getloadavg()}
    for k, clock in enumerate(("wall", "cpu")):
        best = {name: summary([t[k] for t in ts]) for name, ts in times.items()}
        # ratios of runs made one right after the other, which share the machine's load
        paired = {name: statistics.median([a[k] / b[k] for a, b in zip(ts, times["hand-fused"])])
                  for name, ts in times.items()}
        out[clock] = {"seconds": {name: {"min": b[0], "median": b[1]} for name, b in best.items()},
                      "ratio_min": {name: b[0] / best["hand-fused"][0] for name, b in best.items()},
                      "ratio_paired_median": paired}
    return out


def report(r: dict) -> str:
    lines = [f"Scenario '{r['scenario']}' ({r['rhs_calls_hand_fused']} right-hand-side calls); {r['machine']}"]
    header = ["path", "CPU min s", "CPU ratio (min)", "CPU ratio (paired median)", "wall min s",
              "wall ratio (min)", "peak heap MB"]
    rows = [[name, f"{r['cpu']['seconds'][name]['min']:.3f}", f"{r['cpu']['ratio_min'][name]:.2f}",
             f"{r['cpu']['ratio_paired_median'][name]:.2f}", f"{r['wall']['seconds'][name]['min']:.3f}",
             f"{r['wall']['ratio_min'][name]:.2f}", f"{r['peak_python_heap_mb'][name]:.1f}"]
            for name in r["cpu"]["seconds"]]
    ratio = r["cpu"]["ratio_min"]["fast"]
    lines += [table(header, rows),
              f"fast path target <= {r['target_ratio']} x hand-fused (CPU time, fastest of each): "
              f"{'met' if ratio <= r['target_ratio'] else 'NOT met'} ({ratio:.2f}); python-control "
              f"{r['cpu']['ratio_min']['python-control']:.2f} x",
              f"process max RSS {r['max_rss_mb']:.0f} MB; load average during the run {r['load_average'][0]:.2f}",
              "agreement (max abs difference): " + ", ".join(f"{k} {v:.1e}" for k, v in r["agreement"].items())]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--pc-repeats", type=int, default=3, help="repeats of the (slow) python-control path")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    r = run(args.scenario, args.repeats, args.pc_repeats)
    return print_and_save(report(r), r, args.json)


if __name__ == "__main__":
    sys.exit(main())
