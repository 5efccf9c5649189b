"""numba-cuda, when installed, and the CUDA device it finds: what ``engine="cuda"`` needs and why it cannot run.

numba-cuda is the optional extra ``dobkit[gpu]``.  Without it, or with it but
no NVIDIA driver or device, ``engine="cuda"`` is refused with
:func:`cuda_unavailable_reason`'s sentence, and ``engine="auto"`` never picks
it (the GPU runs only when asked for).  With ``NUMBA_ENABLE_CUDASIM=1`` in the
environment *before* numba's CUDA target is first imported, numba-cuda runs
kernels in Python on the CPU (its simulator): slowly, but the same code and
numbers, which is how the tests check the kernels on machines without a GPU.
"""
from __future__ import annotations

import importlib
import os

import numpy as np

__all__ = ["cuda_or_none", "cuda_unavailable_reason", "simulated", "device_name", "device_free_bytes",
           "GPU_MEMORY_VARIABLE"]

#: Environment variable capping the device memory a GPU batch may take (a size such as ``8G``), below what the
#: device reports free.
GPU_MEMORY_VARIABLE = "DOBKIT_MAX_GPU_MEMORY"

_UNSET = object()
_cuda = _UNSET
_import_error = ""


def simulated() -> bool:
    """Whether numba's CUDA simulator is asked for (``NUMBA_ENABLE_CUDASIM=1``)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")


def cuda_or_none():
    """``numba.cuda`` from numba-cuda, or None when numba-cuda cannot be imported (the reason is kept for
    :func:`cuda_unavailable_reason`)."""
    global _cuda, _import_error
    if _cuda is _UNSET:
        try:
            importlib.import_module("numba_cuda")
            # numba-cuda reads numpy.row_stack, which numpy 2.5 removed (vstack is the same function)
            if not hasattr(np, "row_stack"):
                np.row_stack = np.vstack
            _cuda = importlib.import_module("numba.cuda")
        except (ImportError, OSError) as err:
            _cuda, _import_error = None, f"{type(err).__name__}: {err}"
    return _cuda


def cuda_unavailable_reason() -> str | None:
    """Why ``engine="cuda"`` cannot run here (None: it can): no numba-cuda, or numba-cuda and no driver or device."""
    cuda = cuda_or_none()
    if cuda is None:
        return (f"numba-cuda is not installed (it comes with the optional extra: pip install \"dobkit[gpu]\"; "
                f"importing it said {_import_error})")
    if simulated():
        return None
    try:
        available = cuda.is_available()
    except Exception as err:                # the driver's own errors differ between versions  # noqa: BLE001
        return f"numba-cuda is installed but found no CUDA driver ({_first_line(err)})"
    if not available:
        try:
            cuda.current_context()
        except Exception as err:            # noqa: BLE001
            return f"numba-cuda is installed but found no usable CUDA driver or device ({_first_line(err)})"
        return "numba-cuda is installed but found no CUDA device"
    return None


def _first_line(err: BaseException) -> str:
    lines = [line.strip() for line in str(err).splitlines() if line.strip().strip(":")]
    return " ".join(lines[:2]) or type(err).__name__


def device_name() -> str:
    """The device the batch runs on, in words (``"the CUDA simulator"`` when simulated)."""
    if simulated():
        return "the CUDA simulator (numba-cuda on the CPU)"
    device = cuda_or_none().get_current_device()
    name = device.name.decode() if isinstance(device.name, bytes) else str(device.name)
    return f"{name} (compute capability {'.'.join(map(str, device.compute_capability))})"


def device_free_bytes() -> float:
    """Bytes free on the current device (infinite in the simulator), capped by :data:`GPU_MEMORY_VARIABLE`."""
    free = float(cuda_or_none().current_context().get_memory_info()[0])
    cap = os.environ.get(GPU_MEMORY_VARIABLE, "").strip()
    if cap:
        from blocks.engines.budget import parse_size
        try:
            free = min(free, float(parse_size(cap)))
        except ValueError as err:
            raise ValueError(f"{GPU_MEMORY_VARIABLE}: {err}") from None
    return free
