"""The fast (numpy) engine on URDF arms: each chain row kernel of the loop is one call of the generated Python, bound
to pinocchio's algorithm on a model built from the arm's ChainParams; the numbers equal the chain kernels' (and
pinocchio's on the URDF) to rounding, and the whole loop's derivative equals the numpy plan's."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks import initial_state, load_scenario  # noqa: E402
from blocks.engines.compiled import codegen, scalar  # noqa: E402
from blocks.engines.compiled.rows import loop_rows_of  # noqa: E402
from blocks.engines.compiled.scalar import ScalarFunctions  # noqa: E402
from blocks.engines.fastsim import CompiledLoop  # noqa: E402
from blocks.figure2.loop import closed_loop  # noqa: E402
from blocks.kernels import chain  # noqa: E402
from blocks.kernels.trace import Callee, Graph  # noqa: E402
from blocks.model.urdf import example_arm, pin_kernels  # noqa: E402

ARMS = ["scope4", "ur5", "panda"]


@pytest.fixture(autouse=True)
def python_right_hand_side(monkeypatch):
    """These tests are of the fast engine's Python text with pinocchio bound to its calls: the C right-hand side
    (:mod:`blocks.engines.compiled.c_loop`, tested in tests/test_c_loop.py) is switched off."""
    monkeypatch.setenv("DOBKIT_FAST_C", "0")


@pytest.fixture(scope="module", params=ARMS)
def arm(request):
    return example_arm(request.param)


def test_the_model_built_from_the_chain_is_the_urdf_model(arm):
    """pinocchio's CRBA and RNEA on the model of ``model_of`` (from the ChainParams) and on the model pinocchio read
    from the URDF (fingers locked): the same M and h."""
    model, data, _, _ = pin_kernels.model_of(arm.kernel_params())
    ref, ref_data = arm.pin_model, arm.pin_model.createData()
    rng = np.random.default_rng(11)
    for _ in range(3):
        q, dq = rng.uniform(-1.0, 1.0, arm.n), rng.uniform(-1.0, 1.0, arm.n)
        qc = arm.pinocchio_configuration(q)
        np.testing.assert_allclose(pin.crba(model, data, q), pin.crba(ref, ref_data, qc), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(pin.nonLinearEffects(model, data, q, dq), pin.nonLinearEffects(ref, ref_data, qc, dq),
                                   rtol=1e-12, atol=1e-12)


def _called(kernel, k, sizes):
    """The callee a kernel-calls trace records for ``kernel(k, *rows)``."""
    graph = Graph(calls=chain.KERNEL_CALLS)
    rows, at = [], 0
    for size in sizes:
        row = np.empty(size, dtype=object)
        for i in range(size):
            row[i] = graph.leaf("x", at + i)
        rows.append(row)
        at += size
    kernel(k, *rows)
    (callee,) = graph.callees.values()
    return callee


@pytest.mark.parametrize("name", ["plant_acceleration", "mass_solve", "mass_times", "bias_forces", "gravity_forces",
                                  "inertia_matrix"])
def test_each_binding_computes_its_kernel(arm, name):
    """pinocchio's function for each row kernel against the chain kernel on numbers (constants left out)."""
    k, n = arm.kernel_params(), arm.n
    kernel = getattr(chain, name)
    sizes = {"plant_acceleration": (n, n, n), "mass_solve": (n, n), "mass_times": (n, n), "bias_forces": (n, n),
             "gravity_forces": (n,), "inertia_matrix": (n,)}[name]
    callee = _called(kernel, k, sizes)
    # callees are kept by the arm's digest (its numbers): an equal arm read earlier in the process is the same arm
    assert callee.kernel[0] == name and callee.kernel[1].frozen_digest() == k.frozen_digest()
    assert callee.n_in == sum(sizes)
    fast = pin_kernels.binding(callee)
    kept = [i for i, v in enumerate(callee.traced[1]) if Callee.constant(v) is None]
    rng = np.random.default_rng(5)
    for _ in range(3):
        x = rng.uniform(-1.0, 1.0, sum(sizes))
        rows = np.split(x, np.cumsum(sizes)[:-1])
        expected = np.asarray(kernel(k, *rows)).ravel()[kept]
        np.testing.assert_allclose(fast(tuple(x.tolist())), expected, rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_the_fast_engine_calls_pinocchio_and_keeps_the_numpy_plans_derivative(name):
    """The fast engine's right-hand side of a URDF arm's loop calls pinocchio for its four row kernels (none of the
    generated dynamics run) and equals the numpy plan (the chain kernels on numbers) to rounding."""
    s = load_scenario(name)
    loop = closed_loop(s)
    compiled = CompiledLoop(loop)
    assert compiled.generated
    program = codegen.program_for(compiled.plan, loop, loop_rows_of(loop), scalar._calls_for(compiled.plan, loop))[0]
    kinds = sorted(c.kernel[0] for c in program.callees.values())
    assert kinds == ["bias_forces", "mass_solve", "mass_times", "plant_acceleration"]
    assert sorted(ScalarFunctions.of(program).pinocchio_calls) == sorted(program.callees)
    rng = np.random.default_rng(2)
    x0 = initial_state(loop, s)
    for _ in range(5):
        x = x0 + 0.1 * rng.standard_normal(x0.size)
        t = float(rng.uniform(0.0, 5.0))
        np.testing.assert_allclose(compiled.point_rhs(t, x), compiled.rhs(t, x), rtol=1e-9, atol=1e-9)


def test_without_pinocchio_the_generated_python_runs_bit_for_bit(monkeypatch):
    """No pinocchio for the bindings: the kernel calls run their generated bodies, the chain kernels' arithmetic."""
    monkeypatch.setattr(pin_kernels, "_pinocchio", lambda: None)
    monkeypatch.setattr(pin_kernels, "_models", type(pin_kernels._models)())
    monkeypatch.setattr(ScalarFunctions, "_made", {})
    s = load_scenario("scope4")
    loop = closed_loop(s)
    compiled = CompiledLoop(loop)
    assert compiled.generated
    program = codegen.program_for(compiled.plan, loop, loop_rows_of(loop), scalar._calls_for(compiled.plan, loop))[0]
    assert program.callees and ScalarFunctions.of(program).pinocchio_calls == []
    rng = np.random.default_rng(4)
    x0 = initial_state(loop, s)
    for _ in range(5):
        x = x0 + 0.05 * rng.standard_normal(x0.size)
        np.testing.assert_array_equal(compiled.point_rhs(0.4, x), compiled.rhs(0.4, x))


def test_the_factor_and_the_arrays_follow_q(arm):
    """``M v`` and ``M^-1 r`` share ``M(q)`` and its factor, made once per ``q``; called in any order at positions
    that come and go (and with the plant's and the nominal arm's calls in between), each equals the chain kernel
    at its own ``q``."""
    k, n = arm.kernel_params(), arm.n
    nominal = dataclasses.replace(k, masses=tuple(1.2 * m for m in k.masses))     # another arm, its own factor
    kernels = {"mass_times": (chain.mass_times, nominal, (n, n)), "mass_solve": (chain.mass_solve, nominal, (n, n)),
               "bias_forces": (chain.bias_forces, nominal, (n, n)),
               "plant_acceleration": (chain.plant_acceleration, k, (n, n, n))}
    fast = {name: pin_kernels.binding(_called(kernel, params, sizes)) for name, (kernel, params, sizes)
            in kernels.items()}
    rng = np.random.default_rng(8)
    qs = [rng.uniform(-1.0, 1.0, n) for _ in range(3)]
    for step in range(24):
        q = qs[rng.integers(3)]
        name = list(kernels)[rng.integers(4)]
        kernel, params, sizes = kernels[name]
        rest = rng.uniform(-1.0, 1.0, sum(sizes) - n)
        rows = np.split(np.concatenate((q, rest)), np.cumsum(sizes)[:-1])
        np.testing.assert_allclose(fast[name](tuple(np.concatenate((q, rest)).tolist())),
                                   np.asarray(kernel(params, *rows)).ravel(), rtol=1e-11, atol=1e-11,
                                   err_msg=f"{name} at step {step}")


def test_one_mass_matrix_per_right_hand_side(monkeypatch):
    """A right-hand side of a URDF arm's loop calls pinocchio for ``M(q)`` once (``crba`` and its Cholesky factor,
    shared by the controller's ``M v`` and the observer's ``M^-1 r``), ``h`` once and the plant's ``aba`` once: no
    second ``aba`` for ``M^-1 r`` and no ``rnea`` for ``M v``."""
    counts: dict[str, int] = {}

    def counted(module, name):
        original = getattr(module, name)

        def call(*args):
            counts[name] = counts.get(name, 0) + 1
            return original(*args)
        monkeypatch.setattr(module, name, call)

    for name in ("aba", "rnea", "crba", "nonLinearEffects", "computeMinverse"):
        counted(pin, name)
    for name in ("decompose", "solve"):
        counted(pin.cholesky, name)
    monkeypatch.setattr(pin_kernels, "_factors", type(pin_kernels._factors)())
    monkeypatch.setattr(ScalarFunctions, "_made", {})
    s = load_scenario("ur5")
    loop = closed_loop(s)
    compiled = CompiledLoop(loop)
    x0 = initial_state(loop, s)
    rhs = compiled.point_rhs
    counts.clear()                                               # the bindings are made: count their calls
    rng = np.random.default_rng(1)
    for _ in range(3):
        rhs(0.3, x0 + 0.05 * rng.standard_normal(x0.size))      # each at a new state
    counts = {name: c for name, c in counts.items() if c}
    assert counts == {"aba": 3, "crba": 3, "decompose": 3, "solve": 3, "nonLinearEffects": 3}
