"""The compiled closed loop of a URDF arm against a lean pinocchio + numpy loop of the same closed loop.

    PYTHONPATH=. python benchmarks/bench_urdf_loop.py [--arms scope4 panda] [--rounds 3] [--no-percall]

The loop is the DOB loop of Figure 2 on a URDF arm: the plant (the true arm), computed torque and the
disturbance observer on the nominal arm (``arm.nominal_mass_scale``), the scenario's joint sines and Eq. 4
step, over the scenario's 10 s (built-in ``scope4`` and ``panda``).  Two ways to run it:

* ``dobkit compiled``: ``blocks.simulate(scenario, engine="compiled")``, the generated, numba-compiled loop
  (RK45 at the scenario's tolerances), setup and outputs included; the fastest of ``--rounds`` runs after a
  first run, which compiles the loop (or loads it from the cache: printed, and timed separately); and the
  fastest run of a scenario not run before (Kp changed by 1e-9 relative: its loop is prepared anew, the
  compiled code reused), which is what each run of a sweep pays, two ways: with the loop's wiring and plan
  reused from the scenario of the same structure run just before (what a process does), and with nothing kept
  (``blocks.figure2.loop.WIRINGS`` and ``blocks.diagram.plan.PLANS`` cleared first: ``control.interconnect`` and ``make_plan``
  run again, as before they were kept);
* ``lean pinocchio + numpy``: written here as an expert would write it without dobkit: ``scipy`` ``solve_ivp``
  (RK45, the same tolerances and output grid) on a right-hand side that calls ``pin.crba`` and
  ``pin.nonLinearEffects`` on the nominal model (a copy of the URDF model with every body's mass and inertia
  scaled), ``pin.aba`` on the true one, and numpy for the laws (computed torque, the observer's
  ``z' = -Y M^-1 (tau + d_hat - h)``, ``d_hat = Y q' + z``).  The fastest of ``--rounds`` runs, as for the
  compiled run (one run varies by half on a shared machine).

A second table times what each run does before it integrates that depends on the arm (the step estimate
``blocks.figure2.run_limits.estimate_run`` and the loop's divergence bounds
``blocks.figure2.physical_bounds.state_bounds``: M along the
reference for the true and the nominal arm, G and ``M q'' + h`` at its start) two ways: with the arm's numpy row
kernels (what a one-off run, or a process without numba loaded, uses) and with its compiled row kernels
(:mod:`blocks.engines.compiled.row_kernels`, what the runs of a process that runs the arm again and again use, as in the
"new scenario" column); the mean of ``--rounds`` x 10 calls after one call (here they are compiled or loaded
already: the runs above asked for them).

Times are CPU times (``time.process_time``), as in the other benchmarks here.  The ratio is compiled / lean
(target <= 0.05, issue 18); the two runs' positions on the output grid are compared
(largest difference, rad or m) as a check that they are the same loop.  With ``--percall`` (default) the per-call rows of
``bench_urdf_kernels.py`` follow: M (CRBA) and h (RNEA) of dobkit's traced kernels in a numba loop beside
pinocchio's own per-call time.  The Panda's loop is about 7,700 generated lines (each arm's M and h one function
called where needed, ``blocks.engines.compiled.codegen.ARM_CALLS``; 14,250 inlined): its first compile takes 13-14 s of CPU,
a minute or more of wall time on a loaded small machine (``bench_urdf_compile.py``).  No assertion: these
are timings.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402


def _clock() -> float:
    """CPU time of this process (s): waiting for a core on a shared machine does not inflate it."""
    return time.process_time()


def _scaled_model(model, scale: float):
    """A copy of a pinocchio model with every body's mass and rotational inertia times ``scale``."""
    import pinocchio as pin
    nominal = model.copy()
    for i in range(1, nominal.njoints):
        body = nominal.inertias[i]
        nominal.inertias[i] = pin.Inertia(body.mass * scale, body.lever.copy(), body.inertia * scale)
    return nominal


def lean_loop(scenario):
    """The DOB loop of ``scenario`` with pinocchio and numpy under ``solve_ivp``: (run, final q (n,), rhs calls)."""
    import pinocchio as pin
    from scipy.integrate import solve_ivp

    s = scenario
    arm = s.robot
    n = arm.n
    true_model = arm.pin_model
    nominal_model = _scaled_model(true_model, float(s.data["arm"]["nominal_mass_scale"]))
    true_data, nominal_data = true_model.createData(), nominal_model.createData()
    tr = s.data["trajectory"]
    amp, omega, offset = (np.array(tr[k], dtype=float) for k in ("amplitude", "omega", "offset"))
    kp, kd = np.diag(s.kp).copy(), np.diag(s.kd).copy()
    Y = np.asarray(s.observer_gain, dtype=float)
    f_r = np.array(s.data["disturbance"]["f_r"], dtype=float)
    continuous = np.array(arm.continuous)
    sim = s.simulation

    def configuration(q):
        if not continuous.any():
            return q
        return arm.pinocchio_configuration(q)

    def rhs(t, x):
        q, dq, z = x[:n], x[n:2 * n], x[2 * n:]
        sin, cos = np.sin(omega * t), np.cos(omega * t)
        q_ref, dq_ref, ddq_ref = offset + amp * sin, amp * omega * cos, -amp * omega ** 2 * sin
        qc = configuration(q)
        M = pin.crba(nominal_model, nominal_data, qc)
        M = np.triu(M) + np.triu(M, 1).T                    # pinocchio fills the upper triangle
        h = pin.nonLinearEffects(nominal_model, nominal_data, qc, dq)
        d_hat = Y @ dq + z
        tau = M @ (ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)) + h - d_hat
        ddq = pin.aba(true_model, true_data, qc, dq, tau + f_r)
        dz = -Y @ np.linalg.solve(M, tau + d_hat - h)
        return np.concatenate((dq, ddq, dz))

    q0, dq0 = offset.copy(), amp * omega
    x0 = np.concatenate((q0, dq0, -Y @ dq0))
    t_eval = sim.time_grid

    def run():
        return solve_ivp(rhs, (0.0, sim.t_final), x0, method="RK45", t_eval=t_eval, rtol=sim.rtol, atol=sim.atol)
    run.rhs, run.x0 = rhs, x0           # for a per-call comparison (bench_urdf_numpy.py)
    return run


def bench_arm(name: str, rounds: int) -> tuple[list, dict]:
    from blocks import load_scenario, simulate
    from blocks.diagram.plan import PLANS
    from blocks.engines.compiled.engine import CompiledLoopEngine
    from blocks.figure2.loop import WIRINGS, _prepared
    from blocks.figure2.metrics import signal

    s = load_scenario(name)
    engine = CompiledLoopEngine(_prepared(s, True).loop)
    cached, lines = engine.cached, engine.generated_lines
    t0 = _clock()
    first = simulate(s, engine="compiled")
    first_s = _clock() - t0
    best = fresh = unkept = np.inf
    for r in range(rounds):
        t0 = _clock()
        res = simulate(s, engine="compiled")
        best = min(best, _clock() - t0)
        # a scenario not run before (its loop prepared anew, the compiled code reused): what a sweep pays per run,
        # first with no structure kept (wired and planned again), then reusing the structure that run kept
        kp = float(s.kp[0, 0])
        unreused, other = (s.with_changes({"gains.kp": kp * (1.0 + 1e-9 * (2 * r + k + 1))}) for k in range(2))
        WIRINGS.clear()
        PLANS.clear()
        t0 = _clock()
        simulate(unreused, engine="compiled")
        unkept = min(unkept, _clock() - t0)
        t0 = _clock()
        simulate(other, engine="compiled")
        fresh = min(fresh, _clock() - t0)
    assert np.array_equal(signal(first, "q"), signal(res, "q"))

    run = lean_loop(s)
    lean_s = np.inf
    for _ in range(max(rounds, 1)):
        t0 = _clock()
        lean = run()
        lean_s = min(lean_s, _clock() - t0)
    if not lean.success:
        raise RuntimeError(f"{name}: the lean loop failed: {lean.message}")
    diff = float(np.max(np.abs(lean.y[:s.robot.n] - signal(res, "q"))))
    ratio = best / lean_s
    row = [name, str(s.robot.n), f"{lines:,}", "loaded from cache" if cached else "compiled",
           f"{first_s:.1f}", f"{best * 1e3:.2f}", f"{fresh * 1e3:.2f}", f"{unkept * 1e3:.2f}", f"{lean_s:.3f}",
           f"{lean.nfev:,}", f"{ratio:.4f}", f"{fresh / lean_s:.4f}", f"{unkept / lean_s:.4f}", f"{diff:.1e}"]
    info = {"arm": name, "joints": s.robot.n, "generated_lines": lines, "first_run_s": first_s,
            "first_run_compiled": not cached, "compiled_s": best, "compiled_new_scenario_s": fresh,
            "compiled_new_scenario_nothing_kept_s": unkept, "lean_s": lean_s, "lean_rhs_calls": lean.nfev,
            "ratio": ratio, "ratio_new_scenario": fresh / lean_s, "ratio_new_scenario_nothing_kept": unkept / lean_s,
            "max_q_difference": diff}
    return [row], info


def bench_before_run(name: str, rounds: int) -> tuple[list, dict]:
    """The step estimate and the divergence bounds of scenario ``name`` with numpy and with compiled row kernels."""
    from unittest import mock

    from blocks import load_scenario
    from blocks.figure2.loop import closed_loop
    from blocks.figure2.physical_bounds import state_bounds
    from blocks.figure2.run_limits import estimate_run

    s = load_scenario(name)
    loop = closed_loop(s)

    def both():
        return estimate_run(s), state_bounds(loop, s)

    def timed():
        t0 = _clock()
        first = both()
        first_s = _clock() - t0
        t0 = _clock()
        for _ in range(10 * rounds):
            both()
        return first, first_s, (_clock() - t0) / (10 * rounds)

    import numba  # noqa: F401  (loaded: the compiled row kernels are used)

    from blocks.engines.compiled import row_kernels as compiled_row_kernels

    # a scenario loaded here is a new arm object: without this, its first COMPILE_AFTER requests would take the
    # numpy kernels and the compile (or cache load) would land inside the timed calls
    saved, compiled_row_kernels.COMPILE_AFTER = compiled_row_kernels.COMPILE_AFTER, 0
    try:
        compiled, compiled_first, compiled_s = timed()
    finally:
        compiled_row_kernels.COMPILE_AFTER = saved
    with mock.patch.dict(sys.modules):
        del sys.modules["numba"]             # as in a process that has not loaded numba: the numpy row kernels
        numpy_way, _, numpy_s = timed()
    same = compiled[0].steps == numpy_way[0].steps and np.array_equal(compiled[1].bounds, numpy_way[1].bounds)
    row = [name, f"{numpy_s * 1e3:.2f}", f"{compiled_s * 1e3:.3f}", f"{compiled_first:.2f}", f"{numpy_s / compiled_s:.0f}x",
           "equal" if same else "differ"]
    return [row], {"arm": name, "numpy_ms": numpy_s * 1e3, "compiled_ms": compiled_s * 1e3,
                   "compiled_first_s": compiled_first, "equal": same}


def _load(values) -> str:
    return " ".join(f"{v:.2f}" for v in values)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=["scope4", "panda"])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--percall", action=argparse.BooleanOptionalAction, default=True,
                        help="also the per-call rows of bench_urdf_kernels.py (M and h beside pinocchio)")
    parser.add_argument("--calls", type=int, default=20000, help="calls per round of the per-call rows")
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    rows = []
    for name in args.arms:
        rows.extend(bench_arm(name, args.rounds)[0])
    print(f"load average (1, 5, 15 min) {_load(load_start)} at the start, {_load(os.getloadavg())} now, on "
          f"{os.cpu_count()} cores")
    print(table(["arm", "n", "generated lines", "first run", "first run (s)", "compiled (ms)",
                 "new scenario (ms)", "new scenario, nothing kept (ms)", "lean (s)", "lean rhs calls",
                 "compiled / lean", "new scenario / lean", "nothing kept / lean", "max q diff"], rows))
    before = []
    for name in args.arms:
        before.extend(bench_before_run(name, args.rounds)[0])
    print()
    print(table(["arm", "estimate + bounds, numpy kernels (ms)", "compiled kernels (ms)",
                 "compiled kernels, first call (s)", "saved", "steps and bounds"], before))
    if args.percall:
        from bench_urdf_kernels import bench_arm as percall
        per = []
        for name in args.arms:
            per.extend(percall(name, args.calls, 5)[0])
        print()
        print(table(["arm", "kernel", "statements", "dobkit numba, in a numba loop (ns)",
                     "dobkit numba, from Python (ns)", "pinocchio, from Python (ns)",
                     "dobkit numpy kernel, from Python (ns)", "compile (s)"], per))
    return 0


if __name__ == "__main__":
    sys.exit(main())
