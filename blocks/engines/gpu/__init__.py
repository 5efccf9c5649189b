"""The GPU batch: ``simulate_batch(..., engine="cuda")``, one thread per member, the whole loop on the device.

The loop's functions are those :mod:`blocks.engines.compiled.codegen` generates from
the trace for the CPU (numba) and for C; :mod:`blocks.engines.gpu.module` compiles the
same text with numba-cuda as device functions beside the kernel of
:mod:`blocks.engines.gpu.template` (fixed-step RK4 on the batch's shared schedule, the
metrics summed on the device), and :mod:`blocks.engines.gpu.batch` moves the numbers
in and the sums (and kept signals) out.  numba-cuda is the optional extra
``dobkit[gpu]``; :mod:`blocks.engines.gpu.device` says why the GPU cannot run when it
cannot.  ``engine="auto"`` never picks the GPU.
"""
from __future__ import annotations

from blocks.engines.gpu.device import cuda_unavailable_reason, simulated

__all__ = ["cuda_unavailable_reason", "simulated"]
