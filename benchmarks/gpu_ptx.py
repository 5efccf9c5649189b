"""Compile a scenario's GPU batch kernel to PTX without a GPU: does numba-cuda type and lower the generated loop?

    PYTHONPATH=. python benchmarks/gpu_ptx.py paper [--changes '{"noise.q_std": [1e-5, 1e-5, 1e-6, 1e-5]}'] [--cc 9.0]

The CUDA simulator (the tests' check of the numbers) runs the kernel as Python, so it cannot tell whether numba-cuda
compiles it (a numpy function without a device version, a type the device lacks).  This compiles the kernel of
:mod:`blocks.engines.gpu.module` for one compute capability with NVVM, as a first launch on a device would, and prints the
PTX size and the compile time.  It needs NVVM and NVRTC (``pip install "nvidia-cuda-nvcc>=13,<14"
"nvidia-cuda-nvrtc>=13,<14"``) but no driver: numba-cuda asks the current device for its compute capability while
compiling the device functions, so the script answers that question with ``--cc``.

Measured on the 2-core machine (load about 12): the paper's loop 10 s (300 kB of PTX), scope4 about 17 s, the Panda
340 s (1.1 MB).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import types as pytypes


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenario")
    p.add_argument("--changes", default="{}", help="scenario changes, as JSON")
    p.add_argument("--cc", default="9.0", help="compute capability (9.0: H100/H200)")
    args = p.parse_args(argv)
    cc = tuple(int(x) for x in args.cc.split("."))

    from blocks.engines.gpu.device import cuda_or_none
    cuda = cuda_or_none()
    if cuda is None:
        print("gpu_ptx: numba-cuda is not installed", file=sys.stderr)
        return 2
    import numba.cuda.dispatcher as dispatcher
    from numba import types

    from blocks import load_scenario
    from blocks.engines.compiled.engine import CompiledLoopEngine
    from blocks.engines.gpu.module import cuda_module
    from blocks.figure2.batch import Variants
    from blocks.figure2.batch.rows import member_rows

    dispatcher.get_current_device = lambda: pytypes.SimpleNamespace(compute_capability=cc)   # no driver here
    base = load_scenario(args.scenario).with_changes(json.loads(args.changes))
    members = member_rows(Variants(base, [{}, {"gains.kp": 150.0}]), True)
    engine = CompiledLoopEngine(members.loop)
    program = engine.program
    module = cuda_module(program, engine.nstates)
    A = lambda nd, dt=types.float64: types.Array(dt, nd, "C")             # noqa: E731
    ext = types.Tuple(tuple(A(2) if i in program.tables else A(1) for i in range(len(engine.ext))) or (A(1),))
    # the argument types of blocks.engines.gpu.batch.run_cuda_batch's launch
    signature = (A(1), A(1, types.int64), A(2), A(2), A(2), A(2), A(2), ext, types.UniTuple(A(3), 1),
                 A(1, types.int64), A(1, types.int64), A(1, types.int64), A(1, types.int64), types.int64, A(2), A(3),
                 A(2), A(2), A(2), A(1), A(2))
    t0 = time.perf_counter()
    ptx, _ = cuda.compile_ptx(module.rk4_members.py_func, signature, cc=cc)
    print(f"gpu_ptx: {args.scenario}: {engine.generated_lines} generated lines -> {len(ptx) / 1e3:.0f} kB of PTX for "
          f"sm_{cc[0]}{cc[1]} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
