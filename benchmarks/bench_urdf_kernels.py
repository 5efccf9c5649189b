"""Per-call cost of a URDF arm's M(q) and h(q, q'): dobkit's traced kernels compiled by numba beside pinocchio.

    PYTHONPATH=. python benchmarks/bench_urdf_kernels.py [--calls 20000] [--rounds 5] [--arms scope4 panda]

For each arm (scope4, the bundled 4-joint surgical arm; Panda with its fingers locked) the kernels
``inertia_matrix`` (CRBA) and ``bias_forces`` (RNEA) of :mod:`blocks.kernels.chain` are traced into
straight-line code (:mod:`blocks.engines.compiled.arm_trace`) and compiled by numba.  Rows (nanoseconds per call,
fastest of ``--rounds`` rounds of ``--calls`` calls, each call at another state):

* ``dobkit numba, in a numba loop``: the compiled function called from a numba loop: what a compiled
  engine pays;
* ``dobkit numba, from Python``: the same function called from a Python loop (numba's dispatch included);
* ``pinocchio, from Python``: ``pin.crba`` / ``pin.nonLinearEffects`` called from a Python loop (the
  binding's dispatch included; pinocchio has no call without Python here);
* ``dobkit numpy kernel, from Python``: the row kernel itself on one state, for scale.

The first compile of each traced function takes seconds (printed).  No assertion: these are timings.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402


def _numba_loop(fn):
    import numba

    @numba.njit(cache=False)
    def loop(xs, out, calls):
        m = xs.shape[0]
        acc = 0.0
        for c in range(calls):
            fn(xs[c % m], out)
            acc += out[0]
        return acc
    return loop


def _best_ns(run, calls: int, rounds: int) -> float:
    best = np.inf
    for _ in range(rounds):
        t0 = time.process_time()
        run()
        best = min(best, time.process_time() - t0)
    return best / calls * 1e9


def bench_arm(name: str, calls: int, rounds: int) -> tuple[list, dict]:
    import pinocchio as pin

    from blocks.engines.compiled.arm_trace import trace_rows
    from blocks.kernels import chain
    from blocks.model.urdf import example_arm

    arm = example_arm(name)
    n, k = arm.n, arm.kernel_params()
    model = arm.pin_model
    data = model.createData()
    rng = np.random.default_rng(0)
    states = rng.uniform(-1.0, 1.0, (256, 2 * n))
    lo, hi = np.array(arm.joints.limits).T
    states[:, :n] = np.clip(states[:, :n], lo, hi)
    pin_q = [arm.pinocchio_configuration(s[:n]) for s in states]
    rows, info = [], {}
    for label, kernel, width, out_size, pin_call in (
            ("M (CRBA)", chain.inertia_matrix, n, n * n, lambda i: pin.crba(model, data, pin_q[i])),
            ("h (RNEA)", chain.bias_forces, 2 * n, n,
             lambda i: pin.nonLinearEffects(model, data, pin_q[i], states[i, n:]))):
        traced = trace_rows(kernel, k, *([n] * (width // n)))
        t0 = time.perf_counter()
        fn = traced.numba()
        xs = np.ascontiguousarray(states[:, :width])
        out = np.empty(out_size)
        fn(xs[0], out)
        loop = _numba_loop(fn)
        loop(xs, out, 1)
        compile_s = time.perf_counter() - t0
        m = len(states)

        def from_python():
            for c in range(calls):
                fn(xs[c % m], out)

        def pinocchio():
            for c in range(calls):
                pin_call(c % m)

        few = max(calls // 20, 1)

        def numpy_kernel():
            for c in range(few):
                kernel(k, *np.split(xs[c % m], width // n))

        in_loop = _best_ns(lambda: loop(xs, out, calls), calls, rounds)
        py = _best_ns(from_python, calls, rounds)
        ref = _best_ns(pinocchio, calls, rounds)
        npk = _best_ns(numpy_kernel, few, rounds)
        rows.append([name, label, str(traced.statements), f"{in_loop:,.0f}", f"{py:,.0f}", f"{ref:,.0f}",
                     f"{npk:,.0f}", f"{compile_s:.1f}"])
        info[f"{name} {label}"] = {"statements": traced.statements, "numba_loop_ns": in_loop, "numba_python_ns": py,
                                   "pinocchio_python_ns": ref, "numpy_kernel_ns": npk, "compile_s": compile_s}
    return rows, info


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--arms", nargs="+", default=["scope4", "panda"])
    args = parser.parse_args(argv)
    rows = []
    for name in args.arms:
        rows.extend(bench_arm(name, args.calls, args.rounds)[0])
    print(table(["arm", "term", "statements", "dobkit numba in numba loop (ns)", "dobkit numba from Python (ns)",
                 "pinocchio from Python (ns)", "dobkit numpy kernel (ns)", "compile (s)"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
