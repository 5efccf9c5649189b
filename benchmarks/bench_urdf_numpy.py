"""The numpy engine (``engine="fast"``) on URDF arms against a lean pinocchio + numpy loop of the same closed loop.

    PYTHONPATH=. python benchmarks/bench_urdf_numpy.py [--arms ur5 panda] [--rounds 5] [--calls 5000]

The loop and the lean baseline are those of ``bench_urdf_loop.py`` (the DOB loop of Figure 2 on the arm's built-in
scenario; the baseline an expert's ``solve_ivp`` over a right-hand side calling ``pin.crba``,
``pin.nonLinearEffects`` and ``pin.aba``, numpy for the laws).  Beside it a leaner one (:func:`leaner_loop`): the
same loop as an expert who knows pinocchio 3 would trim it (pinocchio's Cholesky factor for ``M^-1 r`` instead of
``numpy.linalg.solve``, ``crba``'s full ``M`` used as it is, the configuration map decided once): the lean loop
spends about half its call on those three.  The leaner loop is the honest baseline; the lean one is kept for the
numbers measured against it before.

The numpy engine is measured three ways: as it runs where a C compiler is found (the loop's generated right-hand
side compiled to C, :mod:`blocks.engines.compiled.c_loop`, and scipy's RK45 stepped by
:class:`blocks.engines.lean_rk45.LeanRK45`), with the C switched off (``DOBKIT_FAST_C=0``: the generated Python with
each chain row kernel bound to pinocchio's algorithm, :mod:`blocks.model.urdf.pin_kernels`), and -- per call only --
as the generated Python with neither pinocchio nor C (M and h its generated functions).  Two measures, both CPU time
(``time.process_time``), fastest of ``--rounds``:

* one right-hand-side call, at states and times near the trajectory (each call at another one, as in a run): the
  numpy engine's (``CompiledLoop.point_rhs``) against the loops', the mean of ``--calls`` calls;
* the whole run: ``blocks.simulate(scenario, engine="fast")`` (outputs and the lumped disturbance on the grid
  included) against the loops' ``solve_ivp`` runs.  All integrate with RK45 at the same tolerances and take the
  same steps.

Also printed: the C library's compile time in a fresh cache folder (wall time: the compiler is a child process; once
per loop structure, then it is loaded from the cache), the largest difference of ``q`` on the output grid between
the numpy engine's run and the two loops' runs (rad), and the machine's load.  Target (issue 30): numpy engine /
lean pinocchio loop <= 0.5 per run.  No assertion: these are timings.
"""
from __future__ import annotations

import argparse
import itertools
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402
from bench_urdf_loop import _scaled_model, lean_loop  # noqa: E402


def leaner_loop(scenario):
    """``lean_loop(scenario)`` as an expert who knows pinocchio 3 would trim it: ``M^-1 r`` by pinocchio's Cholesky
    factor of the ``M`` that ``crba`` made (``cholesky.decompose``/``solve``, as the numpy engine now does)
    instead of ``numpy.linalg.solve``; ``crba``'s ``M`` used as it is (pinocchio's Python ``crba`` fills both
    triangles: checked here, else this loop is refused); the joints' configuration map decided once.  The same
    run otherwise (``solve_ivp``, RK45, the same tolerances and grid)."""
    import pinocchio as pin
    from scipy.integrate import solve_ivp

    s = scenario
    arm, n, sim = s.robot, s.robot.n, s.simulation
    true_model = arm.pin_model
    nominal_model = _scaled_model(true_model, float(s.data["arm"]["nominal_mass_scale"]))
    true_data, nominal_data = true_model.createData(), nominal_model.createData()
    probe = pin.crba(nominal_model, nominal_data, pin.neutral(nominal_model))
    if not np.array_equal(probe, probe.T):
        raise RuntimeError("this pinocchio's crba fills one triangle: the leaner loop needs both")
    tr = s.data["trajectory"]
    amp, omega, offset = (np.array(tr[k], dtype=float) for k in ("amplitude", "omega", "offset"))
    kp, kd = np.diag(s.kp).copy(), np.diag(s.kd).copy()
    Y = np.asarray(s.observer_gain, dtype=float)
    f_r = np.array(s.data["disturbance"]["f_r"], dtype=float)
    configuration = arm.pinocchio_configuration if any(arm.continuous) else (lambda q: q)
    crba, nle, aba = pin.crba, pin.nonLinearEffects, pin.aba
    decompose, solve = pin.cholesky.decompose, pin.cholesky.solve
    sin, cos, concatenate = np.sin, np.cos, np.concatenate
    amp_omega, amp_omega2 = amp * omega, amp * omega ** 2

    def rhs(t, x):
        q, dq, z = x[:n], x[n:2 * n], x[2 * n:]
        wt = omega * t
        s_wt = sin(wt)
        q_ref, dq_ref, ddq_ref = offset + amp * s_wt, amp_omega * cos(wt), -amp_omega2 * s_wt
        qc = configuration(q)
        M = crba(nominal_model, nominal_data, qc)
        h = nle(nominal_model, nominal_data, qc, dq)
        d_hat = Y @ dq + z
        tau = M @ (ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)) + h - d_hat
        ddq = aba(true_model, true_data, qc, dq, tau + f_r)
        decompose(nominal_model, nominal_data)
        dz = -Y @ solve(nominal_model, nominal_data, tau + d_hat - h)
        return concatenate((dq, ddq, dz))

    q0, dq0 = offset.copy(), amp * omega
    x0 = np.concatenate((q0, dq0, -Y @ dq0))

    def run():
        return solve_ivp(rhs, (0.0, sim.t_final), x0, method="RK45", t_eval=sim.time_grid, rtol=sim.rtol,
                         atol=sim.atol)
    run.rhs, run.x0 = rhs, x0
    return run


def _clock() -> float:
    return time.process_time()


def _per_call(fn, calls: int, rounds: int) -> float:
    fn()
    best = np.inf
    for _ in range(rounds):
        t0 = _clock()
        for _ in range(calls):
            fn()
        best = min(best, (_clock() - t0) / calls)
    return best


def _best(fn, rounds: int) -> tuple[float, object]:
    out, best = fn(), np.inf
    for _ in range(rounds):
        t0 = _clock()
        out = fn()
        best = min(best, _clock() - t0)
    return best, out


def _points(x0, count: int = 97) -> list:
    """``count`` distinct ``(t, x)`` near the start of the run, as a solver's calls are: every call at a new state
    and time (a right-hand side may keep what it made for the last ``q``; the same state again would find it)."""
    rng = np.random.default_rng(3)
    x0 = np.asarray(x0, dtype=float)
    return [(float(t), x0 + 0.05 * rng.standard_normal(x0.size)) for t in rng.uniform(0.0, 1.0, count)]


def _calling(rhs, points):
    """A function of no arguments calling ``rhs`` at the next of ``points`` (in turn)."""
    turn = itertools.cycle(points)

    def call():
        t, x = next(turn)
        return rhs(t, x)
    return call


def _without_c():
    """A context in which the fast engine keeps its Python text (``DOBKIT_FAST_C=0``)."""
    from unittest import mock
    return mock.patch.dict(os.environ, {"DOBKIT_FAST_C": "0"})


def _without_pinocchio():
    """Contexts in which the fast engine runs the compiled engine's program as Python (M and h its generated
    functions, no pinocchio, no C): the numpy engine as it was before the kernel calls."""
    from unittest import mock

    from blocks.engines.compiled import scalar
    return (mock.patch.object(scalar, "_calls", lambda chain_arm: None),
            mock.patch.object(scalar.ScalarFunctions, "_made", {}), _without_c())


def _c_compile_seconds(scenario) -> float:
    """Wall time of compiling the loop's C into a fresh cache folder (s); nan when no compiler is found."""
    import tempfile
    from unittest import mock

    from blocks.engines.compiled import c_loop
    from blocks.engines.compiled.codegen import program_for
    from blocks.engines.compiled.rows import loop_rows_of
    from blocks.engines.fastsim import CompiledLoop
    from blocks.figure2.loop import closed_loop

    if c_loop.c_compiler() is None:
        return float("nan")
    loop = closed_loop(scenario)
    program = program_for(CompiledLoop(loop).plan, loop, loop_rows_of(loop))[0]
    with tempfile.TemporaryDirectory() as folder, mock.patch.dict(os.environ, {"DOBKIT_CACHE_DIR": folder}), \
            mock.patch.object(c_loop, "_libraries", {}):
        start = time.perf_counter()
        c_loop.loop_library(program)
        return time.perf_counter() - start


def bench_arm(name: str, rounds: int, calls: int) -> list:
    from blocks import load_scenario, simulate
    from blocks.engines.fastsim import CompiledLoop
    from blocks.figure2.loop import closed_loop
    from blocks.figure2.metrics import signal

    s = load_scenario(name)
    lean, leaner = lean_loop(s), leaner_loop(s)
    points = _points(lean.x0)
    lean_call = _per_call(_calling(lean.rhs, points), calls, rounds)
    leaner_call = _per_call(_calling(leaner.rhs, points), calls, rounds)
    c_call = _per_call(_calling(CompiledLoop(closed_loop(s)).point_rhs, points), calls, rounds)
    with _without_c():
        pin_call = _per_call(_calling(CompiledLoop(closed_loop(s)).point_rhs, points), calls, rounds)
    patches = _without_pinocchio()
    with patches[0], patches[1], patches[2]:
        python_rhs = CompiledLoop(closed_loop(s)).point_rhs
        python_call = _per_call(_calling(python_rhs, points), max(calls // 10, 100), rounds)

    lean_s, lean_res = _best(lean, rounds)
    leaner_s, leaner_res = _best(leaner, rounds)
    c_s, c_res = _best(lambda: simulate(s, engine="fast"), rounds)
    with _without_c():
        pin_s, _ = _best(lambda: simulate(s, engine="fast"), rounds)
    q = signal(c_res, "q")
    diff = max(float(np.max(np.abs(res.y[:s.robot.n] - q))) for res in (lean_res, leaner_res))
    return [name, str(s.robot.n), f"{lean_call * 1e6:.1f}", f"{leaner_call * 1e6:.1f}", f"{c_call * 1e6:.1f}",
            f"{pin_call * 1e6:.1f}", f"{python_call * 1e6:.1f}", f"{c_call / lean_call:.2f}",
            f"{c_call / leaner_call:.2f}", f"{pin_call / leaner_call:.2f}",
            f"{lean_s:.3f}", f"{leaner_s:.3f}", f"{c_s:.3f}", f"{pin_s:.3f}", f"{c_s / lean_s:.2f}",
            f"{c_s / leaner_s:.2f}", f"{pin_s / leaner_s:.2f}", f"{_c_compile_seconds(s):.2f}",
            f"{lean_res.nfev:,}", f"{diff:.1e}"]


def _load(values) -> str:
    return " ".join(f"{v:.2f}" for v in values)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=["ur5", "panda"])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=5000)
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    rows = [bench_arm(name, args.rounds, args.calls) for name in args.arms]
    print(f"load average (1, 5, 15 min) {_load(load_start)} at the start, {_load(os.getloadavg())} now, on "
          f"{os.cpu_count()} cores")
    print(table(["arm", "n", "lean rhs (us)", "leaner rhs (us)", "numpy engine rhs (us)", "without C (us)",
                 "generated Python rhs (us)", "rhs: numpy / lean", "rhs: numpy / leaner", "rhs: without C / leaner",
                 "lean run (s)", "leaner run (s)", "numpy engine run (s)", "without C run (s)", "run: numpy / lean",
                 "run: numpy / leaner", "run: without C / leaner", "C compile, cold (s)", "rhs calls",
                 "max q diff (rad)"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
