"""The GPU batch: ``simulate_batch(..., engine="cuda")``, one thread per member, the whole loop on the device.

The loop's functions are those :mod:`blocks.compiled.codegen` generates from
the trace for the CPU (numba) and for C; :mod:`blocks.gpu.module` compiles the
same text with numba-cuda as device functions beside the kernel of
:mod:`blocks.gpu.template` (fixed-step RK4 on the batch's shared schedule, the
metrics summed on the device), and :mod:`blocks.gpu.batch` moves the numbers
in and the sums (and kept signals) out.  numba-cuda is the optional extra
``dobkit[gpu]``; :mod:`blocks.gpu.device` says why the GPU cannot run when it
cannot.  ``engine="auto"`` never picks the GPU.
"""
from __future__ import annotations

from .device import cuda_unavailable_reason, simulated

__all__ = ["cuda_unavailable_reason", "simulated"]
