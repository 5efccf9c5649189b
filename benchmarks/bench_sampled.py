"""The digital controller's loop (paper-digital, 10 s at 1 kHz) against lean hand-written runs of the same scenario.

    PYTHONPATH=. python benchmarks/bench_sampled.py [--repeats 9] [--numpy-repeats 3] [--members 200] [--json out.json]

Cases, timed in turn (interleaved) in one run, CPU time and wall time:

* ``lean continuous``: the baseline of the compiled engine's ratios, :func:`bench_fastpath.hand_fused`
  on the same scenario: its continuous Figure-2 loop (no sampling) as one hand-written right-hand
  side, integrated by ``solve_ivp`` (RK45, the scenario's tolerances), signals computed afterwards;
* ``lean sampled``: the baseline of the numpy sampled engine's ratio, :func:`hand_sampled`: the
  digital loop written once by hand -- per tick the encoders, the velocity difference and its
  low-pass, Eq. 11 on the nominal model and the Euler observer; between ticks one classical RK4
  step of the plant under the held torque (no error control) -- with the states kept on the grid;
* ``compiled sampled``: ``blocks.simulate(s, engine="compiled")``, the whole call (the loop's set-up,
  the run, the lumped disturbance and the response);
* ``numpy sampled``: ``blocks.simulate(s, engine="fast")``, the numpy hybrid engine (one embedded
  Dormand-Prince step per tick, :mod:`blocks.engines.tick_stepper`), the whole call;
* ``compiled sampled batch``: :func:`blocks.engines.compiled.sampled.simulate_sampled_batch` over
  ``--members`` measurement-noise seeds (the scenario with position and velocity noise), members on
  both cores; its ratio is per member and by wall time as well.

Targets: the compiled sampled run at most 0.2 x one lean continuous run (issue 17); the numpy sampled
run at most 1.5 x the lean sampled loop (issue 28); CPU time, fastest of each.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

import blocks

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # _timing, bench_fastpath, run from anywhere
from _timing import machine, max_rss_mb, print_and_save, summary, table, time_interleaved  # noqa: E402
from bench_fastpath import hand_fused  # noqa: E402

#: The compiled sampled run's target, as a multiple of one lean continuous run (issue 17).
TARGET = 0.2
#: The numpy sampled run's target, as a multiple of the lean hand-written sampled loop (issue 28).
NUMPY_TARGET = 1.5
#: Measurement noise of the batch's members (rad, rad, m, rad; per second the same).
NOISE = {"noise.q_std": [1e-4, 1e-4, 1e-5, 1e-4], "noise.dq_std": [1e-3, 1e-3, 1e-4, 1e-3]}


def hand_sampled(s: blocks.Scenario) -> dict:
    """The paper's digital loop written once by hand: ``q``, ``dq`` on the output grid and the right-hand sides.

    Per tick ``k Ts``: the encoders (``res * rint(q / res)``), the backward difference through the
    low-pass ``v = a v_prev + (1 - a) diff``, ``d_hat = Y v + z``, Eq. 11 on the nominal model with
    the sampled signals, the forward-Euler observer ``z += Ts (-Y M^^-1 (tau + d_hat - h^))``; then one
    classical RK4 step of the true plant ``q'' = M^-1 (tau + f_r - h)`` over the tick under the held
    torque.  The 4x4 formulas are written out (those of :func:`bench_fastpath.hand_fused_rhs`);
    it covers ``paper-digital`` (difference velocity with a low-pass, Euler observer, no delay, no
    torque limit, no noise, output grid on ticks).
    """
    d = s.controller
    if (s.noise is not None or d.delay or d.observer_discretization != "euler" or d.velocity != "difference"
            or any(d.torque_limit) or tuple(s.disturbance.kinds) != ("paper",)):
        raise ValueError("the lean sampled loop covers paper-digital's settings only")
    traj = s.trajectory
    c, nm = s.robot.constants, s.nominal.constants
    k1, k2, k3, k4, k5, g = c.k1, c.k2, c.k3, c.k4, c.k5, c.g
    h1, h2, h3, h4, h5, gh = nm.k1, nm.k2, nm.k3, nm.k4, nm.k5, nm.g
    kp, kd, y = np.diag(s.kp).copy(), np.diag(s.kd).copy(), np.diag(s.observer_gain).copy()
    f_r = np.array(s.disturbance.f_r, dtype=float)
    res, Ts, a = np.array(d.position_resolution), d.period, d.filter_pole
    quantize = res > 0
    safe_res = np.where(quantize, res, 1.0)

    def solve(a00, a01, a11, m22, m33, r):
        aa, b, cc = a00 - m33, a01 - m33, a11 - m33
        r03, r13 = r[0] + r[3], r[1] + r[3]
        det = aa * cc - b * b
        x0 = (cc * r03 - b * r13) / det
        x1 = (aa * r13 - b * r03) / det
        return np.array([x0, x1, r[2] / m22, x0 + x1 + r[3] / m33])

    def plant(x, tau):
        q, dq = x[0:4], x[4:8]
        c2, s2 = np.cos(q[1]), np.sin(q[1])
        force = tau + f_r - np.array([-k2 * s2 * dq[1] * (dq[0] + 0.5 * dq[1]), 0.5 * k2 * s2 * dq[0] * dq[0],
                                      -k4 * g, 0.0])
        return np.concatenate((dq, solve(k1 + k2 * c2, k3 + 0.5 * k2 * c2, k3, k4, k5, force)))

    t_grid = s.simulation.time_grid
    every = int(round(s.simulation.output_step / Ts))
    n_ticks = int(round(t_grid[-1] / Ts))
    q0, dq0, _ = traj.evaluate(0.0)
    x = np.concatenate([q0, dq0])
    q_prev = np.where(quantize, safe_res * np.rint(q0 / safe_res), q0) - Ts * dq0
    v_prev = dq0.copy()
    z = -y * dq0
    out = np.empty((t_grid.size, 8))
    for k in range(n_ticks + 1):
        if k % every == 0:
            out[k // every] = x
        if k == n_ticks:
            break
        refs = traj.evaluate_stacked(k * Ts)
        q_s = np.where(quantize, safe_res * np.rint(x[0:4] / safe_res), x[0:4])
        v = a * v_prev + (1.0 - a) * (q_s - q_prev) / Ts
        q_prev, v_prev = q_s, v
        d_hat = y * v + z
        c2, s2 = np.cos(q_s[1]), np.sin(q_s[1])
        n00, n01 = h1 + h2 * c2, h3 + 0.5 * h2 * c2
        u = refs[8:12] + kd * (refs[4:8] - v) + kp * (refs[0:4] - q_s)
        bias_hat = np.array([-h2 * s2 * v[1] * (v[0] + 0.5 * v[1]), 0.5 * h2 * s2 * v[0] * v[0], -h4 * gh, 0.0])
        tau = np.array([n00 * u[0] + n01 * u[1] - h5 * u[3], n01 * u[0] + h3 * u[1] - h5 * u[3], h4 * u[2],
                        h5 * (u[3] - u[0] - u[1])]) + bias_hat - d_hat
        z = z - Ts * y * solve(n00, n01, h3, h4, h5, tau + d_hat - bias_hat)
        # one RK4 step of the plant over the tick, the torque held
        r1 = plant(x, tau)
        r2 = plant(x + 0.5 * Ts * r1, tau)
        r3 = plant(x + 0.5 * Ts * r2, tau)
        r4 = plant(x + Ts * r3, tau)
        x = x + Ts / 6.0 * (r1 + 2.0 * r2 + 2.0 * r3 + r4)
    return {"q": out[:, 0:4], "dq": out[:, 4:8], "nfev": 4 * n_ticks}


def run(scenario: str = "paper-digital", repeats: int = 9, numpy_repeats: int = 3, members: int = 200) -> dict:
    """Time the cases and return the figures (seconds, ratios, agreement)."""
    from blocks.engines.compiled.sampled import simulate_sampled_batch
    s = blocks.load_scenario(scenario)
    noisy = s.with_changes(NOISE)
    seeds = list(range(members))
    t0 = time.perf_counter()
    compiled = blocks.simulate(s, engine="compiled")          # compiles, or loads numba's cache
    first_call = time.perf_counter() - t0
    t0 = time.perf_counter()
    simulate_sampled_batch(noisy, seeds=seeds[:2])
    batch_first_call = time.perf_counter() - t0
    cases = {
        "lean continuous": lambda: hand_fused(s),
        "lean sampled": lambda: hand_sampled(s),
        "compiled sampled": lambda: blocks.simulate(s, engine="compiled"),
        "numpy sampled": lambda: blocks.simulate(s, engine="fast"),
    }
    if members:
        cases["compiled sampled batch"] = lambda: simulate_sampled_batch(noisy, seeds=seeds)
    numpy_run = cases["numpy sampled"]()
    agreement = float(np.max(np.abs(compiled.outputs - numpy_run.outputs)))
    lean = cases["lean sampled"]()
    labels = list(numpy_run.output_labels)
    q_numpy = np.asarray(numpy_run.outputs)[[labels.index(f"q[{i}]") for i in range(4)]].T
    lean_agreement = float(np.max(np.abs(q_numpy - lean["q"])))
    times = time_interleaved(cases, repeats, {"numpy sampled": numpy_repeats}, clock="both")
    out = {"scenario": scenario, "machine": machine(), "repeats": repeats, "members": members,
           "compiled_first_call_s": first_call, "batch_first_call_s": batch_first_call, "target": TARGET,
           "agreement_outputs_max_abs": agreement, "lean_sampled_agreement_q_max_abs": lean_agreement,
           "numpy_target": NUMPY_TARGET, "max_rss_mb": max_rss_mb(), "load_average": os.getloadavg()}
    for k, clock in enumerate(("wall", "cpu")):
        best = {name: summary([t[k] for t in ts]) for name, ts in times.items()}
        lean = times["lean continuous"]
        paired = {name: statistics.median([a[k] / b[k] for a, b in zip(ts, lean)]) for name, ts in times.items()}
        out[clock] = {"seconds": {name: {"min": b[0], "median": b[1]} for name, b in best.items()},
                      "ratio_min": {name: b[0] / best["lean continuous"][0] for name, b in best.items()},
                      "ratio_paired_median": paired}
    return out


def report(r: dict) -> str:
    lines = [f"Scenario '{r['scenario']}' (10 s at 1 kHz unless changed); {r['machine']}"]
    header = ["case", "CPU min s", "CPU ratio (min)", "CPU ratio (paired median)", "wall min s", "wall ratio (min)"]
    rows = [[name, f"{r['cpu']['seconds'][name]['min']:.4f}", f"{r['cpu']['ratio_min'][name]:.3f}",
             f"{r['cpu']['ratio_paired_median'][name]:.3f}", f"{r['wall']['seconds'][name]['min']:.4f}",
             f"{r['wall']['ratio_min'][name]:.3f}"] for name in r["cpu"]["seconds"]]
    ratio = r["cpu"]["ratio_min"]["compiled sampled"]
    lean = r["cpu"]["seconds"]["lean sampled"]["min"]
    numpy_ratio = r["cpu"]["seconds"]["numpy sampled"]["min"] / lean
    paired = r["cpu"]["ratio_paired_median"]["numpy sampled"] / r["cpu"]["ratio_paired_median"]["lean sampled"]
    lines += [table(header, rows),
              f"compiled sampled run {ratio:.3f} x one lean continuous run (target <= {r['target']}: "
              f"{'met' if ratio <= r['target'] else 'NOT met'})",
              f"numpy sampled run {numpy_ratio:.2f} x the lean sampled loop (RK4 per tick; target <= "
              f"{r['numpy_target']}: {'met' if numpy_ratio <= r['numpy_target'] else 'NOT met'}; paired medians "
              f"{paired:.2f}); lean sampled vs numpy sampled engine, q: max abs difference "
              f"{r['lean_sampled_agreement_q_max_abs']:.1e} rad",
              f"first compiled call in this process {r['compiled_first_call_s']:.2f} s (compile or cache load); "
              f"the batch's first call {r['batch_first_call_s']:.2f} s",
              f"compiled vs numpy sampled engine, outputs: max abs difference {r['agreement_outputs_max_abs']:.1e}",
              f"process max RSS {r['max_rss_mb']:.0f} MB; load average during the run {r['load_average'][0]:.2f}"]
    if "compiled sampled batch" in r["cpu"]["seconds"]:
        m = r["members"]
        lines.append(f"batch of {m} noise seeds: {r['wall']['ratio_min']['compiled sampled batch'] / m:.3f} lean "
                     f"runs per member by wall time, {r['cpu']['ratio_min']['compiled sampled batch'] / m:.3f} by CPU "
                     f"time (all threads); {r['wall']['ratio_min']['compiled sampled batch']:.1f} lean runs in all")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="paper-digital")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--numpy-repeats", type=int, default=3, help="repeats of the numpy sampled engine")
    parser.add_argument("--members", type=int, default=200, help="members of the batch case (0: none)")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    r = run(args.scenario, args.repeats, args.numpy_repeats, args.members)
    return print_and_save(report(r), r, args.json)


if __name__ == "__main__":
    sys.exit(main())
