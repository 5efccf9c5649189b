"""Per-call cost of one right-hand side: the lean hand-fused loop, the numpy engine's two forms, and each block.

    PYTHONPATH=. python benchmarks/bench_percall.py [--rounds 40] [--calls 300]

Each function is called ``--calls`` times in a row; the rounds go over all
functions in turn and the table shows each one's fastest round (CPU time per
call, microseconds), at states near the paper scenario's start state plus 0.01
near t = 0.3 s.  Every call is made at another point, as a solver makes them.

Rows:

* ``lean hand-fused right-hand side``: the baseline of ``bench_fastpath.py``;
* ``CompiledLoop.point_rhs``: what the ``fast`` engine integrates, the loop's
  generated right-hand side run by Python on floats (:mod:`blocks.engines.compiled.scalar`);
* ``CompiledLoop.rhs``: the plan executed with numpy, one kernel call per block;
* ``block ...``: each block's kernel on its own, as the numpy plan calls it
  (trajectory, controller, observer; the plant's update), on the inputs it
  gets in a right-hand side;
* ``compiled loop_derivative``: the numba module's right-hand side called
  from Python (with numba installed), which includes the call from Python.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import table  # noqa: E402
from bench_fastpath import hand_fused_rhs  # noqa: E402

import blocks  # noqa: E402
from blocks.engines.fastsim import CompiledLoop  # noqa: E402


def _cycling(fn, args: list):
    """A function of no arguments calling ``fn`` on the next of ``args`` each time."""
    it = iter(())

    def call():
        nonlocal it
        try:
            return fn(*next(it))
        except StopIteration:
            it = iter(args)
            return fn(*next(it))
    return call


def run(rounds: int = 40, calls: int = 300) -> dict[str, float]:
    s = blocks.load_scenario("paper")
    loop = blocks.closed_loop(s)
    compiled = CompiledLoop(loop)
    plan = compiled.plan
    x = blocks.initial_state(loop, s) + 0.01
    t = 0.3
    # each call at another (t, x), as in a solver, so nothing is found remembered from the call before
    points = [(t + 1e-4 * k, x + 1e-6 * k) for k in range(calls)]
    fused = hand_fused_rhs(s)
    cases = {"lean hand-fused right-hand side": _cycling(fused, points),
             "CompiledLoop.point_rhs (generated, on floats)": _cycling(compiled.point_rhs, points),
             "CompiledLoop.rhs (numpy plan, a call per block)": _cycling(compiled.rhs, points),
             "(cost of taking the next point)": _cycling(lambda tk, xk: None, points)}
    # every block's inputs at every point, as the plan gathers them
    signals = []
    for tk, xk in points:
        y = np.empty(plan.nsignals)
        y[plan.copy_y] = xk[plan.copy_x]
        for step in plan.rhs_steps:
            y[step.y] = np.ravel(step.output(tk, xk[step.x], y[step.gather], *step.output_args))
        signals.append(y)
    for step in plan.rhs_steps:
        args = [(tk, xk[step.x], y[step.gather]) + tuple(step.output_args) for (tk, xk), y in zip(points, signals)]
        cases[f"block {step.name}: output"] = _cycling(step.output, args)
    for step in plan.updates:
        args = [(tk, xk[step.x], y[step.gather]) + tuple(step.update_args) for (tk, xk), y in zip(points, signals)]
        cases[f"block {step.name}: update"] = _cycling(step.update, args)
    try:
        from blocks.engines.compiled import CompiledLoopEngine
        engine = CompiledLoopEngine(loop)
        engine.warm()
        cases["compiled loop_derivative (called from Python)"] = _cycling(engine.rhs, points)
    except Exception as err:        # numba missing: the row is left out
        print(f"(compiled row left out: {err})", file=sys.stderr)
    best = {name: float("inf") for name in cases}
    for _ in range(rounds):
        for name, fn in cases.items():
            t0 = time.process_time()
            for _ in range(calls):
                fn()
            best[name] = min(best[name], (time.process_time() - t0) / calls * 1e6)
    return best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--calls", type=int, default=300)
    args = parser.parse_args(argv)
    best = run(args.rounds, args.calls)
    base = best["lean hand-fused right-hand side"]
    print(table(["function", "us per call (CPU)", "x lean"], [[k, f"{v:.2f}", f"{v / base:.2f}"]
                                                            for k, v in best.items()]))
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
