"""An arm is a value passed to the laws: one law, each arm's numbers, no rebound modules, one compiled copy per arm.

The RRPR's numbers are checked against its closed form written again here from the paper notes (Eq. 5, 7, 8;
the Coriolis vector as the Christoffel terms of that M by central differences), the URDF arm's against pinocchio.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest

import blocks
from blocks.diagram.digital import observer_euler_update
from blocks.kernels import computed_torque, lumped_disturbance, observer_rate, tissue_disturbance
from blocks.kernels.model import ArmLaw, arm_kernels, with_arm

pin = pytest.importorskip("pinocchio")

# Table 1 of the paper as the notes give it: k1..k5 (kg m^2, kg), g (m/s^2); lengths a1, a2, d1, d4 (m)
K = (7.88827, 0.4756, 4.36971, 0.25, 1.47486, 9.8)


def _rrpr_mass(q):
    k1, k2, k3, k4, k5, _ = K
    c2 = np.cos(q[1])
    return np.array([[k1 + k2 * c2, k3 + 0.5 * k2 * c2, 0.0, -k5],
                     [k3 + 0.5 * k2 * c2, k3, 0.0, -k5],
                     [0.0, 0.0, k4, 0.0],
                     [-k5, -k5, 0.0, k5]])


def _rrpr_bias(q, dq, eps=1e-6):
    """``N q' + G``: the Christoffel vector ``M' q' - 1/2 d/dq (q'^T M q')`` of the M above, plus Eq. 7's gravity."""
    dM = [(_rrpr_mass(q + eps * e) - _rrpr_mass(q - eps * e)) / (2 * eps) for e in np.eye(4)]
    mdot = sum(d * v for d, v in zip(dM, dq))
    coriolis = mdot @ dq - 0.5 * np.array([dq @ d @ dq for d in dM])
    return coriolis + np.array([0.0, 0.0, -K[3] * K[5], 0.0])


def _rrpr_tool(q, kin):
    a1, a2, d1, d4 = kin
    p = np.array([a1 * np.cos(q[0]) + a2 * np.cos(q[0] + q[1]), a1 * np.sin(q[0]) + a2 * np.sin(q[0] + q[1]),
                  d1 - q[2] - d4])
    J = np.array([[-a1 * np.sin(q[0]) - a2 * np.sin(q[0] + q[1]), -a2 * np.sin(q[0] + q[1]), 0.0, 0.0],
                  [a1 * np.cos(q[0]) + a2 * np.cos(q[0] + q[1]), a2 * np.cos(q[0] + q[1]), 0.0, 0.0],
                  [0.0, 0.0, -1.0, 0.0]])
    return p, J


def _scope4():
    return blocks.load_scenario("scope4").robot


def _pinocchio_terms(arm):
    """M, h, tool position and linear Jacobian of the URDF arm by pinocchio, from the URDF file itself."""
    from blocks.model.urdf.examples import scope4_urdf
    model = pin.buildModelFromUrdf(str(scope4_urdf()))
    assert model.nq == model.nv == arm.n            # no continuous joint: q is pinocchio's configuration
    data = model.createData()
    frame = model.getFrameId(arm.tool_frame)

    def terms(q, dq):
        M = pin.crba(model, data, q).copy()
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(model, data, q, dq).copy()
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        p = data.oMf[frame].translation.copy()
        J = pin.getFrameJacobian(model, data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3].copy()
        return M, h, p, J
    return terms


def _cases():
    rrpr = blocks.PAPER_PARAMETERS
    kin = rrpr.tool_params()

    def rrpr_terms(q, dq):
        p, J = _rrpr_tool(q, kin)
        return _rrpr_mass(q), _rrpr_bias(q, dq), p, J
    scope4 = _scope4()
    return [(rrpr, rrpr_terms, np.array([0.3, -0.9, 0.04, 0.5])),
            (scope4, _pinocchio_terms(scope4), np.array([0.2, -0.4, 0.05, 0.7]))]


@pytest.mark.parametrize("case", [0, 1], ids=["rrpr", "scope4"])
def test_one_law_called_with_each_arm_s_kernels_gives_that_arm_s_numbers(case):
    arm, terms, q = _cases()[case]
    model, k = arm.arm_kernels, arm.kernel_params()
    rng = np.random.default_rng(case)
    dq, tau, z = rng.normal(size=4), rng.normal(size=4) * 3, rng.normal(size=4)
    q_ref, dq_ref, ddq_ref = q + 0.1, rng.normal(size=4), rng.normal(size=4)
    kp, kd, Y = np.array([180.0, 150.0, 120.0, 90.0]), np.array([36.0, 30.0, 25.0, 20.0]), np.array([10.0, 8, 6, 4])
    M, h, p, J = terms(q, dq)
    scale = 1.0 + np.abs(M).max() + np.abs(h).max()

    v = ddq_ref + kd * (dq_ref - dq) + kp * (q_ref - q)
    np.testing.assert_allclose(computed_torque(model, k, kp, kd, q, dq, q_ref, dq_ref, ddq_ref, 0.25),
                               M @ v + h - 0.25, rtol=0, atol=1e-8 * scale * (1 + np.abs(v).max()))
    expected_rate = -Y * np.linalg.solve(M, tau + Y * dq + z - h)
    np.testing.assert_allclose(observer_rate(model, k, Y, 0.0, q, dq, tau, z), expected_rate, rtol=1e-7, atol=1e-9)
    # Eq. 2-3: on a perfect model the lumped disturbance is the external one
    tau_dis = rng.normal(size=4)
    np.testing.assert_allclose(lumped_disturbance(model, k, k, q, dq, tau, tau_dis), tau_dis, rtol=0, atol=1e-9 * scale)
    # the skin 1 cm above the tool point: J^T F with F = (-c_lat v_x, -c_lat v_y, k p - c v_z)
    stiffness, damping, drag = 400.0, 2.0, 1.5
    vel = J @ dq
    F = np.array([-drag * vel[0], -drag * vel[1], max(0.0, stiffness * 0.01 - damping * vel[2])])
    got = tissue_disturbance(model, arm.tool_params(), q, dq, p[2] + 0.01, stiffness, damping, drag)
    np.testing.assert_allclose(got, J.T @ F, rtol=1e-9, atol=1e-12)


def test_the_arm_value_is_one_per_pair_of_kernel_modules_and_the_law_stays_one_function():
    rrpr, scope4 = blocks.PAPER_PARAMETERS, _scope4()
    assert rrpr.arm_kernels is arm_kernels((rrpr.kernels, rrpr.tool_kernels))
    assert rrpr.arm_kernels.name != scope4.arm_kernels.name
    a, b = with_arm(computed_torque, rrpr), with_arm(computed_torque, scope4)
    assert a.law is b.law is computed_torque and a is with_arm(computed_torque, rrpr)
    # the compiled engine's structure keys name a kernel by module and qualified name: distinct per arm
    assert a.__module__ == b.__module__ == computed_torque.__module__ and a.__qualname__ != b.__qualname__


def test_kernel_modules_of_the_same_name_are_two_arms_with_their_own_numbers():
    """A module made again (a notebook cell run twice) is another arm: its name gets a suffix, its law its kernels."""
    first, second = _diag_kernels(), _diag_kernels()
    second.bias_forces = lambda k, q, dq: 2.0 * k[4:] + 0.0 * dq
    a, b = arm_kernels((first, first)), arm_kernels((second, second))
    assert a is not b and a.name != b.name and a is arm_kernels((first, first))
    assert a.name.split("#")[0] == b.name.split("#")[0] == "diagonal_arm_kernels+diagonal_arm_kernels"
    k, q, z = np.array([2.0, 3.0, 4.0, 5.0, 0.1, -0.2, 0.3, -0.4]), np.zeros(4), np.zeros(4)
    # -Y M^-1 (tau + Y dq + z - h) at rest with Y = I: h / m, each arm's h
    np.testing.assert_allclose(observer_rate(a, k, np.ones(4), 0.0, q, z, z, z), k[4:] / k[:4], rtol=1e-15)
    np.testing.assert_allclose(observer_rate(b, k, np.ones(4), 0.0, q, z, z, z), 2.0 * k[4:] / k[:4], rtol=1e-15)
    assert with_arm(observer_rate, a).__qualname__ != with_arm(observer_rate, b).__qualname__


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["python-control", "fast", "compiled"])
def test_a_urdf_loop_binds_no_module_and_its_blocks_carry_the_arm_s_kernels(engine):
    if engine == "compiled":
        pytest.importorskip("numba")
    s = blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.2})
    loop = blocks.closed_loop(s)
    resp = blocks.simulate(s, observer=True, engine=engine)
    assert np.isfinite(np.asarray(resp.outputs)).all()
    assert not [m for m in sys.modules if m.startswith("blocks.kernels.bound_")]
    from blocks.diagram.contract import contract_of
    from blocks.diagram.control_compat import subsystems
    laws = {b.name: contract_of(b).kernels for b in subsystems(loop) if b.name in ("plant", "controller", "observer")}
    for name, kernels in laws.items():
        assert isinstance(kernels.output, ArmLaw) and kernels.output.model is s.robot.arm_kernels, name


# -- the compiled copies: one per arm, numba's cache keeps them ----------------------------------------------------
def _diag_kernels():
    """A 4-joint arm of constant diagonal inertia ``k[:4]`` and constant joint forces ``k[4:]``: kernels of its
    own, whose numbers differ from the RRPR's at every state."""
    module = types.ModuleType("diagonal_arm_kernels")

    def mass_solve(k, q, r):
        return r / k[:4]

    def bias_forces(k, q, dq):
        return k[4:] + 0.0 * dq

    module.mass_solve, module.bias_forces = mass_solve, bias_forces
    return module


def test_two_arms_in_one_process_get_two_compiled_laws_with_their_own_numbers():
    pytest.importorskip("numba")
    from blocks.engines.compiled.jit import jit_kernel
    rrpr = blocks.PAPER_PARAMETERS
    diag = _diag_kernels()
    diag_model = arm_kernels((diag, diag))
    k_diag = np.array([2.0, 3.0, 4.0, 5.0, 0.1, -0.2, 0.3, -0.4])
    t, z = 0.0, np.array([0.1, -0.2, 0.3, 0.05])
    u = np.concatenate((np.array([1.0, -2.0, 0.5, 0.2]), np.array([0.3, -0.9, 0.04, 0.5]), np.array([0.2, 0.1, -0.3, 0.4])))
    gain, period = np.array([10.0, 10.0, 10.0, 10.0]), 1e-3
    a = jit_kernel(with_arm(observer_euler_update, rrpr))
    b = jit_kernel(with_arm(observer_euler_update, diag_model))
    assert a is not b and a is jit_kernel(with_arm(observer_euler_update, rrpr))
    k_rrpr = rrpr.kernel_params()
    got_a, got_b = a(t, z, u, k_rrpr, gain, 0.0, period), b(t, z, u, k_diag, gain, 0.0, period)
    np.testing.assert_allclose(got_a, observer_euler_update(rrpr.arm_kernels, t, z, u, k_rrpr, gain, 0.0, period),
                               rtol=1e-13, atol=1e-15)
    # the diagonal arm's Euler step by hand: z + Ts (-Y (tau + Y dq + z - h) / m)
    tau, dq = u[:4], u[8:]
    expected_b = z + period * (-gain * (tau + gain * dq + z - k_diag[4:]) / k_diag[:4])
    np.testing.assert_allclose(got_b, expected_b, rtol=1e-13, atol=1e-15)
    assert not np.allclose(got_a, got_b)


@pytest.mark.slow
def test_a_law_compiled_for_an_arm_is_loaded_from_numba_s_cache_in_another_process(tmp_path):
    """numba's on-disk cache keys a compiled function by its argument types: the arm's type is its name, so a second
    process loads the law compiled for the RRPR instead of compiling it again (a first-class dispatcher argument
    would miss every time: numba issue #6264)."""
    pytest.importorskip("numba")
    (tmp_path / "arm_law_cache_probe.py").write_text(textwrap.dedent("""
        import numba
        import blocks.engines.compiled.jit            # registers numba's type of an arm's kernels
        blocks.engines.compiled.jit.numba_or_none()

        @numba.njit(cache=True)
        def law(model, k, q, v):
            return model.mass_times(k, q, v) + model.bias_forces(k, q, v)
    """))
    script = textwrap.dedent("""
        import numpy as np, blocks, arm_law_cache_probe as probe
        from blocks.engines.compiled.jit import compiled_arm
        arm = blocks.PAPER_PARAMETERS
        compiled_arm(arm.arm_kernels)      # as the engine does before it loads a loop that calls an arm's law
        k, q, v = arm.kernel_params(), np.array([0.3, -0.9, 0.04, 0.5]), np.array([1.0, 2.0, 3.0, 4.0])
        got = probe.law(arm.arm_kernels, k, q, v)
        expected = arm.kernels.mass_times(k, q, v) + arm.kernels.bias_forces(k, q, v)
        assert np.allclose(got, expected, rtol=1e-14, atol=0), (got, expected)
        print(sum(probe.law.stats.cache_hits.values()), sum(probe.law.stats.cache_misses.values()))
    """)
    import os
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
               NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
            for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    assert runs[0].stdout.split() == ["0", "1"]          # compiled and saved
    assert runs[1].stdout.split() == ["1", "0"]          # loaded
