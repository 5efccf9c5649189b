"""Per-call cost of one right-hand side: the hand-fused loop, the fast path's CompiledLoop, and its blocks.

    PYTHONPATH=. python benchmarks/bench_percall.py [--rounds 40] [--calls 300]

Each function is called ``--calls`` times in a row; the rounds go over all
functions in turn and the table shows each one's fastest round (CPU time per
call, microseconds), at states near the paper scenario's start state plus 0.01 near t = 0.3 s.
This shows where the fast path's time goes (see README.md).  The blocks'
functions are timed on their own at one point, so the controller's and the
observer's shared nominal-model terms and the plant's disturbance are found
remembered there (:mod:`dobkit.blocks.model_cache`): the sum of the blocks'
rows is a lower bound of one right-hand side, not its cost.
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

from dobkit import blocks  # noqa: E402


def run(rounds: int = 40, calls: int = 300) -> dict[str, float]:
    s = blocks.load_scenario("paper")
    loop = blocks.closed_loop(s)
    compiled = blocks.CompiledLoop(loop)
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
    u_all, _ = compiled.signals(t, x)
    for k in compiled._order:                         # the blocks' own functions, on their current inputs
        block, (xs, _, _), u = compiled._blocks[k], compiled._slices[k], u_all[k]
        cases[f"block {block.name}: output"] = lambda b=block, xk=x[xs], uk=u: b.outfcn(t, xk, uk, {})
        if block.nstates:
            cases[f"block {block.name}: update"] = lambda b=block, xk=x[xs], uk=u: b.updfcn(t, xk, uk, {})
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
    blocks_sum = sum(v for k, v in best.items() if k.startswith("block "))
    print(table(["function", "us per call", "x hand-fused"], [[k, f"{v:.1f}", f"{v / base:.2f}"] for k, v in best.items()]))
    print(f"sum of the blocks' own functions: {blocks_sum:.1f} us; CompiledLoop.rhs beyond them: "
          f"{best['CompiledLoop.rhs'] - blocks_sum:.1f} us; load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
