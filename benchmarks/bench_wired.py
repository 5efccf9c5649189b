"""A hand-wired diagram with blocks of the user's own, on every engine, against a lean hand-written numpy loop.

    PYTHONPATH=. python benchmarks/bench_wired.py [--t-final 10] [--repeats 5] [--json out.json]

The diagram is the one of ``examples/wire_blocks_by_hand.py``: the Figure-2
blocks of the paper scenario wired with :func:`control.interconnect`, plus two
blocks of the user's own -- a 5 ms first-order actuator lag on joint 3's force
(``ct.tf``) and a nonlinear filter of the squared tracking error (``ct.nlsys``
with a numpy function).  Before this work such a diagram could only be run by
:func:`control.input_output_response`.  Paths, all RK45 with the scenario's
tolerances:

* ``lean``: the same dynamics as one hand-written numpy right-hand side (the
  hand-fused paper loop of ``bench_fastpath.py`` with the lag and the filter
  added), ``solve_ivp``, the four outputs on the grid vectorised afterwards.
  The baseline of the ratios.
* ``compiled``: ``blocks.simulate_system(diagram, T, X0, engine="compiled")``.
* ``fast``: ``engine="fast"`` (the numpy engine: the lowered diagram's generated
  right-hand side run on floats).
* ``python-control``: ``ct.input_output_response(diagram, T, 0, X0, ...)``.

Cases are timed in turn; the ratio is each path's fastest CPU time over the
lean loop's, with the median of paired ratios beside; the load average is printed.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import control as ct
import numpy as np
from scipy.integrate import solve_ivp

import blocks

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, run from anywhere
from _timing import machine, print_and_save, summary, table, time_interleaved  # noqa: E402

TAU_ACT = 0.005         # s, the actuator lag
TAU_E = 0.05            # s, the error filter


def error_filter_update(t, x, u, params):
    """x' = (e^2 - x) / tau_e with e = q_ref[2] - q[2] (m^2/s)."""
    e = u[0] - u[1]
    return np.array([(e * e - x[0]) / params["tau_e"]])


def error_filter_output(t, x, u, params):
    return np.sqrt(np.abs(x))


def wired(s: blocks.Scenario):
    """The diagram and its start state."""
    parts = blocks.build_blocks(s, observer=True)
    actuator = ct.tf([1.0], [TAU_ACT, 1.0], inputs="f_cmd", outputs="f_act", name="actuator")
    watch = ct.nlsys(error_filter_update, error_filter_output, inputs=["q_ref", "q"], outputs="e_rms", states="e2",
                     name="watch", params={"tau_e": TAU_E})
    conn = [[f"controller.{sig}", f"trajectory.{sig}"] for sig in ("q_ref", "dq_ref", "ddq_ref")]
    conn += [["controller.q", "plant.q"], ["controller.dq", "plant.dq"], ["controller.d_hat", "observer.d_hat"],
             ["observer.tau", "controller.tau"], ["observer.q", "plant.q"], ["observer.dq", "plant.dq"]]
    conn += [[f"plant.tau[{i}]", f"controller.tau[{i}]"] for i in (0, 1, 3)]
    conn += [["actuator.f_cmd", "controller.tau[2]"], ["plant.tau[2]", "actuator.f_act"],
             ["watch.q_ref", "trajectory.q_ref[2]"], ["watch.q", "plant.q[2]"]]
    sys_ = ct.interconnect(list(parts.values()) + [actuator, watch], connections=conn, inplist=[],
                           outlist=["plant.q[2]", "actuator.f_act", "observer.d_hat[2]", "watch.e_rms"],
                           outputs=["q[2]", "f_act", "d_hat[2]", "e_rms"], name="with_actuator", check_unused=False)
    plain = blocks.closed_loop(s)
    x0 = np.concatenate([blocks.initial_state(plain, s), [0.0, 0.0]])
    return sys_, x0


def lean(s: blocks.Scenario, x0: np.ndarray) -> tuple[np.ndarray, int]:
    """The diagram as one hand-written numpy right-hand side, x = [q, dq, z, actuator, filter]; outputs (4, T)."""
    if s.noise is not None or s.observer_variant != "correct" or tuple(s.disturbance.kinds) != ("paper",):
        raise ValueError("the lean loop covers the paper's disturbance and observer without measurement noise")
    act = ct.ss(ct.tf([1.0], [TAU_ACT, 1.0]))
    a_act, b_act, c_act = float(act.A[0, 0]), float(act.B[0, 0]), float(act.C[0, 0])
    traj = s.trajectory
    c, n = s.robot.constants, s.nominal.constants
    k1, k2, k3, k4, k5, g = c.k1, c.k2, c.k3, c.k4, c.k5, c.g
    h1, h2, h3, h4, h5, gh = n.k1, n.k2, n.k3, n.k4, n.k5, n.g
    kp, kd, y = np.diag(s.kp).copy(), np.diag(s.kd).copy(), np.diag(s.observer_gain).copy()
    f_r = np.array(s.disturbance.f_r, dtype=float)
    out = np.empty(14)

    def solve(a00, a01, a11, m22, m33, r):
        a, b, cc = a00 - m33, a01 - m33, a11 - m33
        r03, r13 = r[0] + r[3], r[1] + r[3]
        det = a * cc - b * b
        x0_ = (cc * r03 - b * r13) / det
        x1_ = (a * r13 - b * r03) / det
        return x0_, x1_, r[2] / m22, x0_ + x1_ + r[3] / m33

    def rhs(t, x):
        q, dq, z, xa, e2 = x[0:4], x[4:8], x[8:12], x[12], x[13]
        refs = traj.evaluate_stacked(t)
        c2, s2 = np.cos(q[1]), np.sin(q[1])
        cor0, cor1 = -dq[1] * (dq[0] + 0.5 * dq[1]), 0.5 * dq[0] * dq[0]
        v = refs[8:12] + kd * (refs[4:8] - dq) + kp * (refs[0:4] - q)
        n00, n01 = h1 + h2 * c2, h3 + 0.5 * h2 * c2
        d_hat = y * dq + z
        bias_hat = np.array([h2 * s2 * cor0, h2 * s2 * cor1, -h4 * gh, 0.0])
        tau = np.array([n00 * v[0] + n01 * v[1] - h5 * v[3], n01 * v[0] + h3 * v[1] - h5 * v[3], h4 * v[2],
                        h5 * (v[3] - v[0] - v[1])]) + bias_hat - d_hat
        applied = tau.copy()
        applied[2] = c_act * xa
        force = applied + f_r - np.array([k2 * s2 * cor0, k2 * s2 * cor1, -k4 * g, 0.0])
        out[0:4] = dq
        out[4:8] = solve(k1 + k2 * c2, k3 + 0.5 * k2 * c2, k3, k4, k5, force)
        out[8:12] = -y * np.array(solve(n00, n01, h3, h4, h5, tau + d_hat - bias_hat))
        out[12] = a_act * xa + b_act * tau[2]
        e = refs[2] - q[2]
        out[13] = (e * e - e2) / TAU_E
        return out.copy()

    sim = s.simulation
    t_grid = sim.time_grid
    sol = solve_ivp(rhs, (t_grid[0], t_grid[-1]), x0, method=sim.method, t_eval=t_grid, rtol=sim.rtol,
                    atol=sim.atol, max_step=sim.max_step)
    X = sol.y
    z, dq = X[8:12], X[4:8]
    d_hat2 = y[2] * dq[2] + z[2]
    return np.vstack([X[2], c_act * X[12], d_hat2, np.sqrt(np.abs(X[13]))]), sol.nfev


def run(t_final: float = 10.0, repeats: int = 5, pc_repeats: int = 2) -> dict:
    s = blocks.load_scenario("paper").with_changes({"simulation.t_final": t_final})
    sim = s.simulation
    diagram, x0 = wired(s)
    T = sim.time_grid
    kwargs = dict(rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step)
    t0 = time.perf_counter()
    compiled = blocks.simulate_system(diagram, T, x0, engine="compiled", solve_ivp_kwargs=kwargs)
    first_call = time.perf_counter() - t0
    cases = {
        "lean": lambda: lean(s, x0),
        "compiled": lambda: blocks.simulate_system(diagram, T, x0, engine="compiled", solve_ivp_kwargs=kwargs),
        "fast": lambda: blocks.simulate_system(diagram, T, x0, engine="fast", solve_ivp_kwargs=kwargs),
        "python-control": lambda: ct.input_output_response(diagram, T, 0, x0, solve_ivp_kwargs=kwargs),
    }
    base, nfev = cases["lean"]()
    fast, pc = cases["fast"](), cases["python-control"]()
    agreement = {name: float(np.abs(np.asarray(r.outputs) - base).max())
                 for name, r in (("compiled", compiled), ("fast", fast), ("python-control", pc))}
    agreement["compiled vs python-control"] = float(np.abs(compiled.outputs - pc.outputs).max())
    times = time_interleaved(cases, repeats, {"python-control": pc_repeats}, clock="both")
    out = {"t_final": t_final, "machine": machine(), "rhs_calls_lean": int(nfev), "repeats": repeats,
           "compiled_first_call_s": first_call, "agreement_vs_lean": agreement, "load_average": os.getloadavg()}
    for k, clock in enumerate(("wall", "cpu")):
        best = {name: summary([t[k] for t in ts]) for name, ts in times.items()}
        paired = {name: statistics.median([a[k] / b[k] for a, b in zip(ts, times["lean"])])
                  for name, ts in times.items()}
        out[clock] = {"seconds": {name: {"min": b[0], "median": b[1]} for name, b in best.items()},
                      "ratio_min": {name: b[0] / best["lean"][0] for name, b in best.items()},
                      "ratio_paired_median": paired}
    return out


def report(r: dict) -> str:
    header = ["path", "CPU min s", "CPU ratio (min)", "CPU ratio (paired median)", "wall min s", "wall ratio (min)"]
    rows = [[name, f"{r['cpu']['seconds'][name]['min']:.4f}", f"{r['cpu']['ratio_min'][name]:.3f}",
             f"{r['cpu']['ratio_paired_median'][name]:.3f}", f"{r['wall']['seconds'][name]['min']:.4f}",
             f"{r['wall']['ratio_min'][name]:.3f}"] for name in r["cpu"]["seconds"]]
    agree = ", ".join(f"{k} {v:.1e}" for k, v in r["agreement_vs_lean"].items())
    return "\n".join([
        f"Paper loop + actuator lag (ct.tf) + error filter (ct.nlsys), {r['t_final']:g} s, "
        f"{r['rhs_calls_lean']} rhs calls; {r['machine']}",
        f"load average {r['load_average'][0]:.2f} {r['load_average'][1]:.2f} {r['load_average'][2]:.2f}",
        table(header, rows),
        f"compiled-wired / lean = {r['cpu']['ratio_min']['compiled']:.3f}, python-control / lean = "
        f"{r['cpu']['ratio_min']['python-control']:.2f} (CPU, fastest of each); compiled first call "
        f"{r['compiled_first_call_s']:.1f} s",
        f"largest output difference from the lean loop: {agree}"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--t-final", type=float, default=10.0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json")
    a = p.parse_args(argv)
    r = run(a.t_final, a.repeats)
    return print_and_save(report(r), r, a.json)


if __name__ == "__main__":
    raise SystemExit(main())
