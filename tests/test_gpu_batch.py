"""The GPU batch (``simulate_batch(..., engine="cuda")``, :mod:`blocks.engines.gpu`) without a GPU.

The kernels run in numba-cuda's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, which must be set before numba's CUDA
target is first imported, hence a fresh process per check) on a few members and a short run, against the numpy
batch: another implementation of the same loop (numpy kernels over a member axis) integrated on the same RK4 step
schedule.  The refusals are real: numba-cuda hidden from the import system, and this machine's missing driver.
"""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba")
#: The checks that run numba-cuda (its simulator, or its driver query); the refusal without it runs anyway.
needs_numba_cuda = pytest.mark.skipif(importlib.util.find_spec("numba_cuda") is None,
                                      reason="numba-cuda is not installed (the gpu extra)")

ROOT = Path(__file__).resolve().parents[1]
#: Stated agreement of the GPU batch with the CPU batch on the same step schedule (relative, and absolute floor).
RTOL, FLOOR = 1e-9, 1e-12

_COMPARE = r"""
import json, sys
import numpy as np
from blocks import load_scenario
from blocks.figure2.batch import simulate_batch
name, t_final, records, FLOOR = sys.argv[1], float(sys.argv[2]), json.loads(sys.argv[3]), float(sys.argv[4])
changes = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
base = load_scenario(name).with_changes({"simulation.t_final": t_final, **changes})
signals = ("q", "tau", "d_hat", "d") + (("q_meas",) if changes else ())
gpu = simulate_batch(base, records, engine="cuda", signals=signals)
cpu = simulate_batch(base, records, engine="fast", method="RK4", signals=signals)
worst = {}
for group, a, b in (("metrics", gpu.metrics, cpu.metrics), ("signals", gpu.signals, cpu.signals)):
    for key in b:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        assert x.shape == y.shape, (key, x.shape, y.shape)
        worst[key] = float(np.max(np.abs(x - y) / np.maximum(np.abs(y), FLOOR)))
print(json.dumps({"worst": worst, "steps": [gpu.steps, cpu.steps], "method": gpu.method,
                  "failed": [np.isnan(gpu.failed_at).tolist(), np.isnan(cpu.failed_at).tolist()],
                  "q_moves": float(np.ptp(cpu.signals["q"]))}))
"""


def _python(code: str, *args, env: dict | None = None, timeout: float = 120) -> dict:
    """Run ``code`` in a fresh interpreter (with the environment ``env`` added); its last stdout line as JSON."""
    full = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
    done = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=full,
                          timeout=timeout, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _simulated(code: str, *args) -> dict:
    return _python(code, *args, env={"NUMBA_ENABLE_CUDASIM": "1"})


def _check_agreement(out: dict) -> None:
    assert out["method"] == "RK4" and out["steps"][0] == out["steps"][1] >= 10        # 5 ms grid (noise: 1 ms)
    assert out["failed"][0] == out["failed"][1] == [True] * len(out["failed"][0])     # nobody diverged
    assert out["q_moves"] > 1e-4                    # the run goes somewhere: the comparison is not of constants
    for key, worst in out["worst"].items():
        assert worst <= RTOL, (key, worst)


@needs_numba_cuda
def test_paper_arm_on_the_simulated_device_equals_the_cpu_batch():
    records = [{"gains.kp": 120.0}, {"gains.kd": 40.0, "nominal_scale.m1": 0.8}, {"nominal_scale.m3": 1.2}]
    _check_agreement(_simulated(_COMPARE, "paper", 0.05, json.dumps(records), FLOOR))


@needs_numba_cuda
def test_members_with_their_own_measurement_noise_read_their_own_table_on_the_simulated_device():
    noise = {"noise.q_std": [1e-5, 1e-5, 1e-6, 1e-5], "noise.dq_std": [1e-4, 1e-4, 1e-5, 1e-4]}
    records = [{"noise.seed": 1}, {"noise.seed": 2, "gains.kp": 150.0}]
    _check_agreement(_simulated(_COMPARE, "paper", 0.05, json.dumps(records), FLOOR, json.dumps(noise)))


@needs_numba_cuda
def test_members_sharing_the_base_noise_read_its_one_table_on_the_simulated_device():
    # members without a seed of their own read the base's table (one copy on the device), beside one with its own
    noise = {"noise.q_std": [1e-5, 1e-5, 1e-6, 1e-5], "noise.dq_std": [1e-4, 1e-4, 1e-5, 1e-4]}
    records = [{}, {"gains.kp": 150.0}, {"noise.seed": 2}]
    _check_agreement(_simulated(_COMPARE, "paper", 0.05, json.dumps(records), FLOOR, json.dumps(noise)))


@needs_numba_cuda
def test_urdf_arm_scope4_on_the_simulated_device_equals_the_cpu_batch():
    pytest.importorskip("pinocchio")
    records = [{"gains.kp": 120.0}, {"gains.kd": 30.0}]
    _check_agreement(_simulated(_COMPARE, "scope4", 0.05, json.dumps(records), FLOOR))


_DIVERGE = r"""
import json
import numpy as np
from blocks import load_scenario
from blocks.figure2.batch import simulate_batch
base = load_scenario("paper").with_changes({"simulation.t_final": 0.05})
records = [{}, {"gains.kp": 1e6, "gains.kd": 1e3}]
gpu = simulate_batch(base, records, engine="cuda", substeps=1)
cpu = simulate_batch(base, records, engine="fast", method="RK4", substeps=1)
print(json.dumps({"failed_at": [gpu.failed_at.tolist(), cpu.failed_at.tolist()],
                  "failures": [gpu.failures, cpu.failures],
                  "rms": [gpu.metrics["rms_position_error"].tolist(), cpu.metrics["rms_position_error"].tolist()]},
                 default=str))
"""


@needs_numba_cuda
def test_a_diverging_member_stops_where_the_cpu_batch_stops_it_and_the_others_go_on():
    out = _simulated(_DIVERGE)
    gpu_at, cpu_at = out["failed_at"]
    assert str(gpu_at[0]) == str(cpu_at[0]) == "nan"                   # the paper's member finishes
    assert gpu_at[1] == cpu_at[1] and 0 < gpu_at[1] <= 0.05            # Kd = 1e3 at 5 ms steps: RK4 blows up
    assert out["failures"][0] == out["failures"][1] and list(out["failures"][0]) == ["1"]
    assert out["rms"][0][0] == pytest.approx(out["rms"][1][0], rel=RTOL)
    assert all(str(v) == "nan" for v in out["rms"][0][1])


_BUDGET = r"""
import json, os
import numpy as np
from numba import cuda
from blocks import load_scenario
from blocks.figure2.batch import simulate_batch
from blocks.engines.budget import BudgetError
import blocks.engines.gpu.batch as gb
base = load_scenario("paper").with_changes({"simulation.t_final": 0.05})
records = [{}, {"gains.kp": 150.0}]
signals = ("q", "dq", "tau", "d_hat", "d")
# every array put on the device, by its bytes
placed = []
to_device, device_array = cuda.to_device, cuda.device_array
cuda.to_device = lambda a, *r, **k: (placed.append(np.asarray(a).nbytes), to_device(a, *r, **k))[1]
cuda.device_array = lambda shape, *r, **k: (placed.append(int(np.prod(shape)) * 8), device_array(shape, *r, **k))[1]
estimates = []
estimate = gb.estimate_gpu_batch
gb.estimate_gpu_batch = lambda *a, **k: (estimates.append(estimate(*a, **k)), estimates[-1])[-1]
simulate_batch(base, records, engine="cuda", signals=signals)
need = estimates[-1]
out = {"placed": sum(placed), "estimate": need.memory, "key": need.memory_key}
os.environ["DOBKIT_MAX_GPU_MEMORY"] = str(need.memory)
simulate_batch(base, records, engine="cuda", signals=signals)       # at the budget: runs
os.environ["DOBKIT_MAX_GPU_MEMORY"] = str(need.memory - 1)
try:
    simulate_batch(base, records, engine="cuda", signals=signals)
except BudgetError as err:
    out["refused"], out["refused_key"] = str(err), err.key
print(json.dumps(out))
"""


@needs_numba_cuda
def test_device_memory_estimate_covers_what_is_placed_and_is_refused_one_byte_over_the_budget():
    out = _simulated(_BUDGET)
    assert out["placed"] <= out["estimate"] <= 1.05 * out["placed"] + 4096
    assert out["key"] == out["refused_key"] == "signals"              # 5 signals x 4 joints x 11 points dominate
    assert "GPU memory" in out["refused"] and "'signals'" in out["refused"] and "DOBKIT_MAX_GPU_MEMORY" in out["refused"]


_BAD_CAP = r"""
import json, os
from blocks.engines.gpu import device
out = {}
for value in ("abc", "-1", "0", "nan", "1e400", "4G"):
    os.environ["DOBKIT_MAX_GPU_MEMORY"] = value
    try:
        out[value] = device.device_free_bytes()
    except ValueError as err:
        out[value] = str(err)
print(json.dumps(out))
"""


@needs_numba_cuda
def test_a_gpu_memory_cap_that_is_not_a_size_is_refused_naming_the_variable():
    out = _simulated(_BAD_CAP)
    for value in ("abc", "-1", "nan"):
        assert out[value] == ("DOBKIT_MAX_GPU_MEMORY: a memory size must be a number of bytes or like '4G', '512M', "
                              f"got '{value}'")
    for value in ("0", "1e400"):
        assert out[value] == f"DOBKIT_MAX_GPU_MEMORY: a memory size must be positive and finite, got '{value}'"
    assert out["4G"] == 4 * 2 ** 30


_REFUSED = r"""
import json, sys
if sys.argv[1] == "hidden":
    sys.modules["numba_cuda"] = None            # as if numba-cuda were not installed
from blocks.figure2.batch import simulate_batch
from blocks.engines.compiled import CompiledUnavailable
try:
    simulate_batch("paper", [{}], engine="cuda")
except CompiledUnavailable as err:
    print(json.dumps({"message": str(err)}))
else:
    print(json.dumps({"message": None}))
"""


def test_without_numba_cuda_the_gpu_engine_is_refused_naming_the_extra():
    message = _python(_REFUSED, "hidden")["message"]
    assert message and "numba-cuda is not installed" in message and 'dobkit[gpu]' in message


@needs_numba_cuda
def test_without_a_driver_or_device_the_gpu_engine_is_refused_naming_what_is_missing():
    probe = _python("import json\nfrom numba import cuda\nprint(json.dumps(cuda.is_available()))")
    if probe:
        pytest.skip("this machine has a CUDA device")
    message = _python(_REFUSED, "real")["message"]
    assert message and "numba-cuda is installed but found no" in message and "driver" in message


def test_the_gpu_engine_takes_fixed_step_rk4_only():
    from blocks.figure2.batch import simulate_batch
    with pytest.raises(ValueError, match="engine='cuda' integrates fixed-step RK4"):
        simulate_batch("paper", [{}], engine="cuda", method="RK45")


_TUNE = r"""
import json
import numpy as np
from blocks import load_scenario
from analysis.tune.evaluate import _simulate_payload
base = load_scenario("paper").with_changes({"simulation.t_final": 0.05})
payload = {"records": [{"gains.kp": 120.0}, {"gains.kp": 200.0, "gains.kd": 40.0}], "candidates": 2, "chunk": 0,
           "metric": "rms_tool_position_error_mm", "substeps": 1, "workers": 1}
gpu, cpu = (_simulate_payload(base, dict(payload, engine=engine)) for engine in ("cuda", "fast"))
print(json.dumps({"values": [gpu["values"].tolist(), cpu["values"].tolist()],
                  "peaks": [gpu["peaks"].tolist(), cpu["peaks"].tolist()]}))
"""


@needs_numba_cuda
def test_a_tuning_set_runs_its_candidates_on_the_simulated_device_with_the_cpu_batchs_numbers():
    out = _simulated(_TUNE)
    (gv, cv), (gp, cp) = out["values"], out["peaks"]
    assert gv == pytest.approx(cv, rel=RTOL) and min(cv) > 0.5                  # mm: the tool is off the path
    assert sum(gp, []) == pytest.approx(sum(cp, []), rel=RTOL)                  # peak |tau| from the kept signal
