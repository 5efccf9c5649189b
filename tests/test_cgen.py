"""The C back end of the trace: generated C, compiled with the system compiler, called through ctypes.

The generated functions must give the numpy kernels' numbers at random states
(1e-13 relative: the same operations in the same order), read every number
from ``theta`` (new parameters need no new code), and agree with the arm
written independently from its definitions (tests/reference_arm.py).
"""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
import reference_arm as ref

from blocks.diagram.contract import contract_of
from blocks.diagram.systems import controller, observer, plant, sensor
from blocks.engines.compiled.c_backend import C_FLAGS, CodegenError, emit_c_function, system_c, theta_names
from blocks.kernels.trace import Graph, param_values
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.noise import MeasurementNoise
from blocks.model.rrpr.parameters import RobotParameters
from fmu.build import find_compiler

pytestmark = pytest.mark.needs_cc

ALL = DisturbanceSpec(kinds=("paper", "friction", "tissue"))
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


def _compile(source: str, folder, name: str) -> ctypes.CDLL:
    import subprocess
    c_file, lib = folder / f"{name}.c", folder / f"lib{name}.so"
    c_file.write_text(source)
    cmd = find_compiler() + ["-shared", "-fPIC", "-Wall", "-Wextra", "-Werror", *C_FLAGS, str(c_file), "-o",
                             str(lib), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return ctypes.CDLL(str(lib))


def _caller(lib, cname: str, n_out: int):
    fn = getattr(lib, cname)
    fn.restype = None
    fn.argtypes = [ctypes.c_double, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P]

    def call(t, x, u, theta):
        x, u = np.ascontiguousarray(x, float), np.ascontiguousarray(u, float)
        theta = np.ascontiguousarray(theta, float)
        out = np.full(n_out, np.nan)
        ptr = lambda a: (a if a.size else np.zeros(1)).ctypes.data_as(_DOUBLE_P)   # noqa: E731
        fn(float(t), ptr(x), ptr(u), ptr(theta), out.ctypes.data_as(_DOUBLE_P))
        return out
    return call


def _states(rng, n: int):
    """Random plant states: some tools below the skin plane (d3 around 0.24 m), some above."""
    q = rng.uniform([-3, -3, 0.0, -3], [3, 3, 0.45, 3])
    dq = rng.normal(0.0, 2.0, 4)
    return np.concatenate((q, dq))


def _check_block(block, tmp_path, rng, n_x: int, n_u: int, samples: int = 40, param_names=None):
    prog = system_c(block, param_names=param_names)
    lib = _compile(prog.source, tmp_path, block.name)
    k = contract_of(block).kernels
    worst = 0.0
    for which, cname in prog.functions.items():
        call = _caller(lib, cname, prog.sizes[cname])
        for _ in range(samples):
            t = rng.uniform(-0.2, 3.0)
            x = rng.normal(0.0, 1.5, n_x) if block.name != "plant" else _states(rng, n_x)
            u = rng.normal(0.0, 3.0, n_u)
            if block.name == "controller":
                u[12:16] = _states(rng, 8)[:4]
            expected = np.asarray(getattr(k, which)(t, x, u, *k.params), dtype=float)
            got = call(t, x, u, prog.theta)
            np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13 * np.max(np.abs(expected)),
                                       err_msg=f"{block.name} {which}")
            worst = max(worst, float(np.max(np.abs(got - expected) / np.maximum(np.abs(expected), 1e-300))))
    return prog, lib, worst


def test_plant_c_matches_the_numpy_kernel(tmp_path):
    rng = np.random.default_rng(1)
    block = plant(RobotParameters(), ALL)
    prog, _, _ = _check_block(block, tmp_path, rng, 8, 4, param_names=("k", "disturbance"))
    assert prog.functions == {"update": "plant_update", "output": "plant_output"}
    assert prog.sizes == {"plant_update": 8, "plant_output": 12}
    assert prog.theta_names[:6] == [f"k[{i}]" for i in range(6)]
    assert "disturbance.tissue_stiffness" in prog.theta_names


@pytest.mark.parametrize("use_observer", [True, False])
def test_controller_c_matches_the_numpy_kernel(tmp_path, use_observer):
    rng = np.random.default_rng(2)
    block = controller(RobotParameters().scaled(m2=1.3), [120, 150, 900, 80], 30, use_observer=use_observer)
    _check_block(block, tmp_path, rng, 0, 24 if use_observer else 20)


@pytest.mark.parametrize("variant,gain,matrix", [("correct", 10.0, False), ("paper-eq16", [1, 2, 40, 0.5], False),
                                                  ("correct", np.diag([3.0, 4, 5, 6]) + 0.5, True)])
def test_observer_c_matches_the_numpy_kernel(tmp_path, variant, gain, matrix):
    rng = np.random.default_rng(3)
    block = observer(RobotParameters(), gain, variant=variant, matrix_gain=matrix)
    _check_block(block, tmp_path, rng, 4, 12)


def test_the_c_reads_its_numbers_from_theta(tmp_path):
    """Code traced with one arm, called with another arm's theta, gives the other arm's numbers."""
    rng = np.random.default_rng(4)
    traced = plant(RobotParameters(), ALL)
    other_params = RobotParameters().scaled(m1=1.7, I4=0.6, l2=1.2)
    other_spec = DisturbanceSpec(kinds=ALL.kinds, f_r=(0.1, -2.0, 3.0, 0.4), tissue_stiffness=900.0,
                                 skin_height=ALL.skin_height + 0.05)
    other = contract_of(plant(other_params, other_spec)).kernels
    prog = system_c(traced)
    call = _caller(_compile(prog.source, tmp_path, "plant"), "plant_update", 8)
    theta = np.array(param_values(other.params, []))
    for _ in range(20):
        x, u, t = _states(rng, 8), rng.normal(0, 3, 4), rng.uniform(0, 2)
        np.testing.assert_allclose(call(t, x, u, theta), other.update(t, x, u, *other.params), rtol=1e-13,
                                   atol=1e-12)


def test_the_c_plant_agrees_with_the_arm_from_its_definitions(tmp_path):
    """Independent of the kernels: M, N, G and the disturbances of tests/reference_arm.py (Lagrange by hand)."""
    rng = np.random.default_rng(5)
    p = RobotParameters()
    prog = system_c(plant(p, ALL))
    call = _caller(_compile(prog.source, tmp_path, "plant"), "plant_update", 8)
    below = 0
    for _ in range(25):
        x, u, t = _states(rng, 8), rng.normal(0, 3, 4), rng.uniform(0, 2)
        q, dq = x[:4], x[4:]
        below += ALL.skin_height - ref.tool_pose(q, p)[2] > 0
        expected = ref.plant_acceleration(q, dq, u + ref.disturbance(t, q, dq, ALL, p), p)
        got = call(t, x, u, prog.theta)
        np.testing.assert_array_equal(got[:4], dq)
        np.testing.assert_allclose(got[4:], expected, rtol=1e-6, atol=1e-8 * np.max(np.abs(expected)))
    assert 0 < below < 25                 # both sides of the skin plane were visited


def test_shared_terms_are_written_once(tmp_path):
    """The update and output of the plant share one graph: cos(theta2) appears once per function."""
    prog = system_c(plant(RobotParameters(), ALL))
    update = prog.source.split("void plant_update")[1].split("void plant_output")[0]
    assert update.count("cos(x[1])") == 1
    assert prog.n_nodes < sum(prog.statements.values())           # both functions use common nodes


def test_tables_and_unknown_leaves_are_refused():
    noisy = sensor(MeasurementNoise(q_std=(1e-3,) * 4, seed=1, sample_period=0.01, t_final=2.0,
                                    joints=RobotParameters.joints))
    with pytest.raises(CodegenError, match="cannot be written as C numbers"):
        system_c(noisy)
    g = Graph()
    with pytest.raises(CodegenError, match="'aux'"):
        emit_c_function("f", [g.leaf("aux", 3) * 2.0])
    text = emit_c_function("f", [g.leaf("aux", 3) * 2.0], leaves={"aux": "held[{i}]"}, args="const double *held, "
                           "double *out")
    assert "held[3] * 2.0" in text


def test_theta_names():
    assert theta_names((np.ones((2, 2)), 1.0), ("Y", "w")) == ["Y[0,0]", "Y[0,1]", "Y[1,0]", "Y[1,1]", "w"]


def _sampled_blocks():
    from blocks.diagram.digital import DigitalController, actuator, digital_observer, encoder
    settings = DigitalController(sample_rate=500.0, delay=2, observer_discretization="zoh", velocity="difference",
                                 velocity_cutoff=80.0, position_resolution=(1e-3, 0.0, 2e-4, 1e-3),
                                 torque_limit=(5.0, 0.0, 20.0, 2.0))
    euler = DigitalController(sample_rate=1000.0)
    return {"encoder": encoder(settings), "actuator": actuator(settings),
            "observer_zoh": digital_observer(RobotParameters(), [10, 20, 5, 1], settings),
            "observer_euler": digital_observer(RobotParameters(), 10, euler)}


@pytest.mark.parametrize("which", ["encoder", "actuator", "observer_euler"])
def test_sampled_controller_blocks_give_their_kernels_numbers(tmp_path, which):
    """The blocks of a sampled controller (next-state updates, rint quantization, saturation) in C."""
    block = _sampled_blocks()[which]
    block.name = which
    rng = np.random.default_rng(6)
    _check_block(block, tmp_path, rng, block.nstates, block.ninputs, samples=30)


def test_a_kernel_that_fills_a_float_array_is_refused_by_name():
    """The zero-order-hold observer writes symbols into a float matrix (the numba engine calls it compiled):
    no C, and the message says which function and why."""
    with pytest.raises(CodegenError, match="update kernel cannot be traced into C: .*Python number"):
        system_c(_sampled_blocks()["observer_zoh"])


def test_a_traced_result_of_the_wrong_length_or_with_an_unset_row_is_refused_by_both_back_ends():
    """Both back ends read a kernel's traced rows through one function; it names what returned them."""
    import numpy as np

    from blocks.engines.compiled.c_backend import CodegenError
    from blocks.kernels.trace import TraceError, result_rows

    assert result_rows(np.array([1.0, 2.0]), 2) == [1.0, 2.0]
    assert result_rows(np.array([[1.0], [2.0], [3.0]]), None) == [1.0, 2.0, 3.0]
    with pytest.raises(TraceError, match="a kernel returned 3 rows where 2 were expected"):
        result_rows(np.zeros(3), 2)
    unset = np.empty(2, dtype=object)
    unset[0] = 1.0
    with pytest.raises(CodegenError, match="the block's update left a row unset"):
        result_rows(unset, 2, "the block's update", CodegenError)
