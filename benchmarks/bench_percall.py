"""Per-call cost of one right-hand side: the hand-fused loop, the fast path's CompiledLoop, and its blocks.

    PYTHONPATH=. python benchmarks/bench_percall.py [--rounds 40] [--calls 300]

Each function is called ``--calls`` times in a row; the rounds go over all
functions in turn and the table shows each one's fastest round (CPU time per
call, microseconds), at states near the paper scenario's start state plus 0.01 near t = 0.3 s.
This shows where the fast path's time goes (see README.md).  Every call is
made at another point, as a solver makes them.  The blocks' functions are
timed on their own, so the observer's update pays for the nominal-model terms
that, in a right-hand side, it finds remembered from the controller
(:mod:`blocks.model_cache`), and the plant's output, which a
right-hand side does not call, is listed too.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_fastpath import hand_fused_rhs  # noqa: E402
from _timing import table  # noqa: E402

import blocks  # noqa: E402
from blocks.fastsim import CompiledLoop  # noqa: E402


def run(rounds: int = 40, calls: int = 300) -> dict[str, float]:
    s = blocks.load_scenario("paper")
    loop = blocks.closed_loop(s)
    compiled = CompiledLoop(loop)
    x = blocks.initial_state(loop, s) + 0.01
    t = 0.3
    t_grid = s.simulation.time_grid
    X = x[:, None] + 1e-3 * np.sin(t_grid)          # a state per grid point
    fused = hand_fused_rhs(s)
    # each call at another (t, x), as in a solver, so nothing is found remembered from the call before
    points = [(t + 1e-4 * k, x + 1e-6 * k) for k in range(calls)]
    it = iter(())

    def next_point():
        nonlocal it
        try:
            return next(it)
        except StopIteration:
            it = iter(points)
            return next(it)

    cases = {"hand-fused right-hand side": lambda: fused(*next_point()),
             "CompiledLoop.rhs": lambda: compiled.rhs(*next_point()),
             "CompiledLoop.output (one point)": lambda: compiled.output(*next_point()),
             "(cost of taking the next point)": lambda: next_point(),
             f"CompiledLoop.outputs_on_grid / {t_grid.size} points": None}
    inputs = [compiled.signals(tk, xk)[0] for tk, xk in points]      # every block's input at every point
    for k in compiled._order:                         # the blocks' own functions, on their inputs
        block, xs = compiled._blocks[k], compiled._slices[k][0]
        args = [(tk, xk[xs], u_all[k], {}) for (tk, xk), u_all in zip(points, inputs)]
        for kind in ("output", "update") if block.nstates else ("output",):
            fn = block.outfcn if kind == "output" else block.updfcn
            cycle = iter(())

            def call(fn=fn, args=args):
                nonlocal cycle
                try:
                    return fn(*next(cycle))
                except StopIteration:
                    cycle = iter(args)
                    return fn(*next(cycle))
            cases[f"block {block.name}: {kind}"] = call
    best = {name: float("inf") for name in cases}
    grid_case = f"CompiledLoop.outputs_on_grid / {t_grid.size} points"
    for _ in range(rounds):
        for name, fn in cases.items():
            t0 = time.process_time()
            if name == grid_case:       # one grid pass, shown per point
                compiled.outputs_on_grid(t_grid, X)
                best[name] = min(best[name], (time.process_time() - t0) / t_grid.size * 1e6)
                continue
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
    base = best["hand-fused right-hand side"]
    print(table(["function", "us per call", "x hand-fused"], [[k, f"{v:.1f}", f"{v / base:.2f}"] for k, v in best.items()]))
    print(f"CompiledLoop.rhs / hand-fused right-hand side: {best['CompiledLoop.rhs'] / base:.2f}; "
          f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
