"""GPU batch throughput: members/s of ``simulate_batch(engine="cuda")`` against the compiled CPU batch on the same
fixed-step RK4 schedule, for the paper's arm and the Panda, transfers included.

    PYTHONPATH=. python benchmarks/bench_gpu.py [--arms paper,panda] [--members 1e3,1e4,1e5,1e6]
        [--panda-members 1e3,1e4,1e5] [--cpu-members 1000] [--t-final 10] [--repeats 3] [--json out.json]

Without a GPU, end to end in numba-cuda's simulator (the kernel runs in Python: a handful of members only)::

    NUMBA_ENABLE_CUDASIM=1 PYTHONPATH=. python benchmarks/bench_gpu.py --members 4 --t-final 0.05 --arms paper

For each arm and member count N the members are a Monte Carlo draw (fixed seed; the paper's: every nominal mass and
inertia x U(0.9, 1.1), Kp ~ U(120, 250), Kd ~ U(30, 45), Eq. 4 amplitudes x U(0.5, 2); the Panda's: Kp ~ U(150, 220),
Kd ~ U(30, 42)), all seven metrics accumulated on the device, no signals kept.  Timed, fastest of ``--repeats``:
the whole ``simulate_batch`` call (wall), and its parts -- set-up on the CPU (the members' rows, start states,
bounds, the shared reference tables) and the device part (transfers in, kernel, transfers out).  The first call,
which compiles the kernel (numba-cuda, NVVM) and the CPU source table, is timed apart.  The CPU batch
(``engine="compiled"``, ``method="RK4"``, every core) runs ``--cpu-members`` members of the same draw: its members/s
is the baseline (the CPU batch's members are independent, so its rate does not grow with N), and the GPU's metrics
for those members are compared with it (largest relative difference printed).  Printed: the device, the CPU cores,
the load average before and after.

Running it on the GPU machine (one H200, Python 3.12 with numpy 2.5, numba 0.68, numba-cuda; no python-control, no
fmpy, no pinocchio; nothing can be installed there from a registry): the project travels as this folder on
PYTHONPATH, and these wheels (built for CPython 3.12, manylinux x86-64) go with it and are installed with
``pip install --no-index --no-deps <wheels>``:

* always: ``control`` (0.10.x, pure Python), ``fmpy`` (pure Python; imported by ``blocks`` only where FMUs are
  used -- carry it if ``import blocks`` asks for it), and, if ``python -c "import matplotlib, pandas, jinja2, tqdm"``
  fails there, the ones it names (matplotlib with contourpy, cycler, fonttools, kiwisolver, pillow, pyparsing,
  python-dateutil; pandas with tzdata; jinja2 with markupsafe; tqdm);
* for the Panda (``--arms ...,panda``): ``pin`` (pinocchio) and its cmeel dependencies (``cmeel``,
  ``cmeel-boost``, ``cmeel-urdfdom``, ``cmeel-console-bridge``, ``cmeel-tinyxml2``, ``eigenpy``, ``coal``/``hpp-fcl``
  and what ``pip download pin --python-version 3.12 --platform manylinux_2_28_x86_64 --only-binary=:all:`` lists),
  and ``example-robot-data`` (the Panda's URDF).  Without pinocchio the Panda is skipped with a note and the paper
  arm still runs.

numba-cuda there needs ``numpy.row_stack`` (removed in numpy 2.5): :mod:`blocks.engines.gpu.device` sets it to
``numpy.vstack`` before importing numba's CUDA target.  Device time budget: the paper's kernel compiles in about
10 s; the Panda's generated loop (about 14,000 lines) took 340 s of NVVM time to PTX on a loaded 2-core machine,
and its CPU batch compiles in about a minute -- use ``--cpu-members 0`` to skip the CPU batch when time is short.

Targets (issue 29): 10^6 paper members x 10 s in at most 0.5 s of device time on one H200; 10^5 Panda members in
at most 5 s.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

import blocks
from blocks.figure2.batch import Variants, simulate_batch

#: Issue 29's targets: seconds for (arm, members) on one H200, 10 s runs.
TARGETS = {("paper", 1_000_000): 0.5, ("panda", 100_000): 5.0}
_SCALED = ("m1", "m2", "m3", "m4", "I1", "I2", "I3", "I4")


def draw(arm: str, scenario, n: int, seed: int = 2024) -> dict:
    """N Monte Carlo variants of the arm's scenario, as columns of dotted keys."""
    rng = np.random.default_rng(seed)
    if arm == "paper":
        cols = {f"nominal_scale.{k}": rng.uniform(0.9, 1.1, n) for k in _SCALED}
        cols["gains.kp"] = rng.uniform(120.0, 250.0, n)
        cols["gains.kd"] = rng.uniform(30.0, 45.0, n)
        cols["disturbance.f_r"] = np.array(scenario.disturbance.f_r) * rng.uniform(0.5, 2.0, (n, 1))
        return cols
    return {"gains.kp": rng.uniform(150.0, 220.0, n), "gains.kd": rng.uniform(30.0, 42.0, n)}


def subset(cols: dict, n: int) -> dict:
    return {k: v[:n] for k, v in cols.items()}


def gpu_run(s, cols: dict) -> tuple[float, dict, object]:
    """One GPU batch: its wall seconds, its phases (blocks.engines.gpu.batch.last_timings) and the result."""
    from blocks.engines.gpu import batch as gpu_batch
    t0 = time.perf_counter()
    result = simulate_batch(s, Variants(s, cols), engine="cuda")
    wall = time.perf_counter() - t0
    return wall, dict(gpu_batch.last_timings), result


def bench_arm(arm: str, sizes: list[int], cpu_members: int, t_final: float, repeats: int) -> dict:
    name = "paper" if arm == "paper" else arm
    s = blocks.load_scenario(name).with_changes({"simulation.t_final": t_final})
    cols = draw(arm, s, max(sizes + [cpu_members]))
    out = {"arm": arm, "t_final": t_final, "sizes": {}}
    first_n = min(sizes)
    t0 = time.perf_counter()
    _, _, first = gpu_run(s, subset(cols, first_n))
    out["first_call_s"] = time.perf_counter() - t0
    out["steps"] = first.steps
    print(f"  {arm}: first call ({first_n} members, compiles the kernel): {out['first_call_s']:.2f} s; "
          f"{first.steps} RK4 steps a member", flush=True)
    for n in sizes:
        runs = [gpu_run(s, subset(cols, n)) for _ in range(repeats if n < 1_000_000 else max(1, repeats - 1))]
        wall, phases, result = min(runs, key=lambda r: r[0])
        target = TARGETS.get((arm, n)) if t_final == 10.0 else None
        row = {"wall_s": wall, "setup_s": phases.get("setup"), "device_s": phases.get("device"),
               "device_memory_mb": phases.get("device_memory", 0) / 2 ** 20, "members_per_s": n / wall,
               "device_members_per_s": n / phases["device"] if phases.get("device") else None,
               "failed": int((~result.ok).sum()), "target_s": target}
        out["sizes"][n] = row
        print(f"  {arm} N={n:>8}: {wall:8.3f} s wall ({row['members_per_s']:,.0f} members/s); set-up "
              f"{row['setup_s']:.3f} s, device {row['device_s']:.3f} s ({row['device_members_per_s']:,.0f} "
              f"members/s) {row['device_memory_mb']:.1f} MiB; failed {row['failed']}"
              + (f"; target <= {target} s: {'met' if row['device_s'] <= target else 'NOT met'} (device part)"
                 if target else ""), flush=True)
    if cpu_members:
        part = subset(cols, cpu_members)
        v = Variants(s, part)
        t0 = time.perf_counter()
        simulate_batch(s, v, engine="compiled", method="RK4")            # compiles (or loads) the CPU batch
        out["cpu_first_call_s"] = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            cpu = simulate_batch(s, Variants(s, part), engine="compiled", method="RK4")
            times.append(time.perf_counter() - t0)
        _, _, gpu = gpu_run(s, part)
        worst = max(float(np.nanmax(np.abs(gpu.metrics[k] - cpu.metrics[k]) / np.maximum(np.abs(cpu.metrics[k]),
                                                                                           1e-300)))
                    for k in cpu.metrics)
        out["cpu"] = {"members": cpu_members, "wall_s": min(times), "members_per_s": cpu_members / min(times),
                      "first_call_s": out["cpu_first_call_s"], "metrics_max_rel_diff": worst}
        print(f"  {arm} CPU batch (compiled, RK4, {os.cpu_count()} cores) N={cpu_members}: {min(times):.3f} s "
              f"({cpu_members / min(times):,.0f} members/s; first call {out['cpu_first_call_s']:.1f} s); GPU metrics "
              f"vs CPU: max relative difference {worst:.2e}", flush=True)
        for n, row in out["sizes"].items():
            row["speedup_vs_cpu"] = row["members_per_s"] / out["cpu"]["members_per_s"]
            print(f"    N={n:>8}: GPU / CPU members/s = {row['speedup_vs_cpu']:,.1f}")
    return out


def _sizes(text: str) -> list[int]:
    return [int(float(x)) for x in text.split(",") if x.strip()]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arms", default="paper,panda")
    p.add_argument("--members", default="1e3,1e4,1e5,1e6", help="paper arm member counts")
    p.add_argument("--panda-members", default="1e3,1e4,1e5")
    p.add_argument("--cpu-members", type=int, default=1000, help="members of the CPU batch baseline (0: skip)")
    p.add_argument("--t-final", type=float, default=10.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    from blocks.engines.gpu import cuda_unavailable_reason
    from blocks.engines.gpu.device import device_name
    reason = cuda_unavailable_reason()
    if reason is not None:
        print(f"bench_gpu: cannot run: {reason}", file=sys.stderr)
        return 2
    report = {"device": device_name(), "cores": os.cpu_count(), "load_before": os.getloadavg(), "arms": {}}
    print(f"bench_gpu: {report['device']}; {report['cores']} CPU cores; load {report['load_before']}", flush=True)
    for arm in [a.strip() for a in args.arms.split(",") if a.strip()]:
        sizes = _sizes(args.members if arm == "paper" else args.panda_members)
        if arm != "paper":
            try:
                import pinocchio  # noqa: F401
            except ImportError:
                print(f"  {arm}: skipped (a URDF arm needs pinocchio: see this script's docstring)", flush=True)
                continue
        cpu_members = min(args.cpu_members, max(sizes)) if args.cpu_members else 0
        report["arms"][arm] = bench_arm(arm, sizes, cpu_members, args.t_final, args.repeats)
    report["load_after"] = os.getloadavg()
    print(f"bench_gpu: load after {report['load_after']}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(report, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
