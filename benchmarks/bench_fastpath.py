"""The engines against a lean hand-fused numpy closed loop, on one scenario (default: the paper's 10 s run).

    PYTHONPATH=. python benchmarks/bench_fastpath.py [--scenario paper] [--repeats 9] [--json out.json]

Four ways to get the same response (states and the loop's signals on the output
grid), all with the scenario's solver settings (paper: RK45, rtol 1e-6, atol 1e-8):

* ``hand-fused``: the closed loop written once by hand, below: one lean
  right-hand side with the 4x4 formulas written out and every quantity computed
  once (the nominal model shared by controller and observer, the disturbance
  evaluated once), integrated with ``solve_ivp``; signals on the grid computed
  vectorised afterwards.  This is the baseline of the ratios.
* ``fast``: :func:`blocks.simulate` with ``engine="fast"`` (the plan's
  generated right-hand side run by Python on floats, ``solve_ivp``'s RK45).
* ``compiled``: ``engine="compiled"`` (the generated module compiled by numba,
  its Dormand-Prince 5(4)); whole ``simulate()`` calls, outputs and the
  response included.  The first call in this process (compile or load from
  numba's cache) and the first call in a new process are reported apart.
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
import time

import numpy as np
from scipy.integrate import solve_ivp

import blocks

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import machine, max_rss_mb, peak_memory, print_and_save, summary, table, time_interleaved  # noqa: E402

#: The fast path's target, as a multiple of the hand-fused time (issue 10).
TARGET_RATIO = 1.3
#: The compiled engine's target and stretch, as multiples of the hand-fused time (issue 10).
COMPILED_TARGET, COMPILED_STRETCH = 0.03, 0.01


def hand_fused_rhs(s: blocks.Scenario):
    """The Figure-2 loop with observer as one lean hand-written right-hand side ``f(t, x)``, x = [q, dq, z].

    The 4x4 formulas are written out from the paper (Eq. 1, 5-7, 11 and the
    corrected observer) with every term computed once; it calls none of the
    package's model functions (only the scenario's reference path).  Covers the
    paper scenario: Eq. 4 disturbance, diagonal gains, the correct observer, no noise.
    """
    if s.noise is not None or s.observer_variant != "correct" or tuple(s.disturbance.kinds) != ("paper",):
        raise ValueError("the lean baseline covers the paper's disturbance and observer without measurement noise")
    traj = s.trajectory
    c, n = s.robot.constants, s.nominal.constants
    k1, k2, k3, k4, k5, g = c.k1, c.k2, c.k3, c.k4, c.k5, c.g
    h1, h2, h3, h4, h5, gh = n.k1, n.k2, n.k3, n.k4, n.k5, n.g
    kp, kd, y = np.diag(s.kp).copy(), np.diag(s.kd).copy(), np.diag(s.observer_gain).copy()
    f_r = np.array(s.disturbance.f_r, dtype=float)
    out = np.empty(12)

    def solve(a00, a01, a11, m22, m33, r):
        # M x = r with M = [[a00, a01, 0, -m33], [a01, a11, 0, -m33], [0, 0, m22, 0], [-m33, -m33, 0, m33]]
        a, b, cc = a00 - m33, a01 - m33, a11 - m33
        r03, r13 = r[0] + r[3], r[1] + r[3]
        det = a * cc - b * b
        x0 = (cc * r03 - b * r13) / det
        x1 = (a * r13 - b * r03) / det
        return x0, x1, r[2] / m22, x0 + x1 + r[3] / m33

    def rhs(t, x):
        q, dq, z = x[0:4], x[4:8], x[8:12]
        refs = traj.evaluate_stacked(t)
        c2, s2 = np.cos(q[1]), np.sin(q[1])
        cor0, cor1 = -dq[1] * (dq[0] + 0.5 * dq[1]), 0.5 * dq[0] * dq[0]
        # nominal model: M^ v + N^ q' + G^ for the control law
        v = refs[8:12] + kd * (refs[4:8] - dq) + kp * (refs[0:4] - q)
        n00, n01 = h1 + h2 * c2, h3 + 0.5 * h2 * c2
        d_hat = y * dq + z
        bias_hat = np.array([h2 * s2 * cor0, h2 * s2 * cor1, -h4 * gh, 0.0])
        tau = np.array([n00 * v[0] + n01 * v[1] - h5 * v[3], n01 * v[0] + h3 * v[1] - h5 * v[3], h4 * v[2],
                        h5 * (v[3] - v[0] - v[1])]) + bias_hat - d_hat
        # true plant under tau + Eq. 4
        force = tau + f_r - np.array([k2 * s2 * cor0, k2 * s2 * cor1, -k4 * g, 0.0])
        out[0:4] = dq
        out[4:8] = solve(k1 + k2 * c2, k3 + 0.5 * k2 * c2, k3, k4, k5, force)
        out[8:12] = -y * np.array(solve(n00, n01, h3, h4, h5, tau + d_hat - bias_hat))
        return out.copy()
    return rhs


def hand_fused(s: blocks.Scenario) -> dict:
    """Simulate with :func:`hand_fused_rhs` and compute the loop's signals on the grid, vectorised."""
    rhs = hand_fused_rhs(s)
    traj, robot, nominal, spec = s.trajectory, s.robot, s.nominal, s.disturbance
    Kp, Kd, Y = s.kp, s.kd, s.observer_gain
    sim = s.simulation
    inertia, coriolis_vector, gravity, external_disturbance = _model_functions()
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


def _model_functions():
    """The package's vectorised model functions, for the baseline's signals on the grid after the solver."""
    from blocks.model.disturbances import external_disturbance
    from blocks.model.rrpr.dynamics import coriolis_vector, gravity, inertia
    return inertia, coriolis_vector, gravity, external_disturbance


def _signal(resp, name):
    labels = list(resp.output_labels)
    return np.asarray(resp.outputs)[[labels.index(f"{name}[{i}]") for i in range(4)]].T


def run(scenario: str = "paper", repeats: int = 9, pc_repeats: int = 3) -> dict:
    """Time the four paths and return the figures (seconds, ratios, MB, agreement)."""
    s = blocks.load_scenario(scenario)
    cases = {
        "hand-fused": lambda: hand_fused(s),
        "fast": lambda: blocks.simulate(s, engine="fast"),
        "python-control": lambda: blocks.simulate(s, engine="python-control"),
    }
    t0 = time.perf_counter()
    compiled_first = blocks.simulate(s, engine="compiled")        # loads (or compiles) the loop's module
    first_call = time.perf_counter() - t0
    cases["compiled"] = lambda: blocks.simulate(s, engine="compiled")
    # Warm up (imports, caches) and check that all give the same answer.
    base, fast, pc = (cases[name]() for name in ("hand-fused", "fast", "python-control"))
    agreement = {
        "fast vs hand-fused, q": float(np.abs(_signal(fast, "q") - base["q"]).max()),
        "compiled vs fast, q": float(np.abs(_signal(compiled_first, "q") - _signal(fast, "q")).max()),
        "fast vs python-control, q": float(np.abs(_signal(fast, "q") - _signal(pc, "q")).max()),
        "fast vs python-control, tau": float(np.abs(_signal(fast, "tau") - _signal(pc, "tau")).max()),
    }
    times = time_interleaved(cases, repeats, {"python-control": pc_repeats}, clock="both")
    memory = {name: peak_memory(fn) for name, fn in cases.items()}
    out = {"scenario": scenario, "machine": machine(), "repeats": repeats, "rhs_calls_hand_fused": int(base["nfev"]),
           "compiled_first_call_s": first_call, "compiled_cached_start_s": _cached_start(scenario),
           "peak_python_heap_mb": memory, "max_rss_mb": max_rss_mb(), "agreement": agreement,
           "target_ratio": TARGET_RATIO, "compiled_target": COMPILED_TARGET, "compiled_stretch": COMPILED_STRETCH,
           "load_average": os.getloadavg()}
    for k, clock in enumerate(("wall", "cpu")):
        best = {name: summary([t[k] for t in ts]) for name, ts in times.items()}
        # ratios of runs made one right after the other, which share the machine's load
        paired = {name: statistics.median([a[k] / b[k] for a, b in zip(ts, times["hand-fused"])])
                  for name, ts in times.items()}
        out[clock] = {"seconds": {name: {"min": b[0], "median": b[1]} for name, b in best.items()},
                      "ratio_min": {name: b[0] / best["hand-fused"][0] for name, b in best.items()},
                      "ratio_paired_median": paired}
    return out


def _cached_start(scenario: str) -> float:
    """Seconds of a first compiled run in a new process whose code is in numba's cache (imports excluded)."""
    import subprocess
    code = (f"import time, blocks; s = blocks.load_scenario({scenario!r}); t0 = time.perf_counter(); "
            "blocks.simulate(s, engine='compiled'); print(time.perf_counter() - t0)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return float(run.stdout.strip().splitlines()[-1]) if run.returncode == 0 else float("nan")


def report(r: dict) -> str:
    lines = [f"Scenario '{r['scenario']}' ({r['rhs_calls_hand_fused']} right-hand-side calls); {r['machine']}"]
    header = ["path", "CPU min s", "CPU ratio (min)", "CPU ratio (paired median)", "wall min s",
              "wall ratio (min)", "peak heap MB"]
    rows = [[name, f"{r['cpu']['seconds'][name]['min']:.3f}", f"{r['cpu']['ratio_min'][name]:.2f}",
             f"{r['cpu']['ratio_paired_median'][name]:.2f}", f"{r['wall']['seconds'][name]['min']:.3f}",
             f"{r['wall']['ratio_min'][name]:.2f}", f"{r['peak_python_heap_mb'][name]:.1f}"]
            for name in r["cpu"]["seconds"]]
    ratio = r["cpu"]["ratio_min"]["fast"]
    compiled = r["cpu"]["ratio_min"]["compiled"]
    verdict = lambda ok, no="NOT met": "met" if ok else no      # noqa: E731
    lines += [table(header, rows),
              f"fast path target <= {r['target_ratio']} x hand-fused (CPU time, fastest of each): "
              f"{'met' if ratio <= r['target_ratio'] else 'NOT met'} ({ratio:.2f}); python-control "
              f"{r['cpu']['ratio_min']['python-control']:.2f} x",
              f"compiled {compiled:.4f} x the lean baseline (target <= {r['compiled_target']}: "
              f"{verdict(compiled <= r['compiled_target'])}; stretch {r['compiled_stretch']}: "
              f"{verdict(compiled <= r['compiled_stretch'], 'not met')}); "
              f"first compiled call in this process {r['compiled_first_call_s']:.2f} s, "
              f"first call in a new process with the cache {r['compiled_cached_start_s']:.2f} s",
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
