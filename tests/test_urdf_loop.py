"""A URDF arm's plant in the compiled engine: the codegen traces the chain kernels into a loop that numba runs,
and the run equals an independent loop written here with pinocchio (ABA and generalized gravity) and scipy."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks.engines.compiled import numba_or_none  # noqa: E402

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(numba_or_none() is None, reason="the compiled engine needs numba")]

import control as ct  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from blocks.diagram.contract import Kernels, kernel_block  # noqa: E402
from blocks.engines.compiled.engine import CompiledLoopEngine  # noqa: E402
from blocks.kernels import chain  # noqa: E402
from blocks.model.urdf import load_urdf_arm  # noqa: E402

KP, KD = 60.0, 12.0


def _plant_update(t, x, u, k):
    n = k.n
    return np.concatenate((x[n:], chain.plant_acceleration(k, x[:n], x[n:], u)))


def _plant_output(t, x, u, k):
    return x * 1.0


def _pd_gravity(t, x, u, k, kp, kd, q_ref):
    """tau = G(q) + kp (q_ref - q) - kd q' (N m, N)."""
    n = k.n
    q, dq = u[:n], u[n:]
    return chain.gravity_forces(k, q) + kp * (q_ref - q) - kd * dq


def _loop(arm, q_ref):
    n, k = arm.n, arm.kernel_params()
    qs, dqs, taus = [f"q[{i}]" for i in range(n)], [f"dq[{i}]" for i in range(n)], [f"tau[{i}]" for i in range(n)]
    plant = kernel_block(Kernels((k,), _plant_output, _plant_update), name="plant", inputs=taus, outputs=qs + dqs,
                         states=qs + dqs, state_outputs=list(zip(qs + dqs, qs + dqs)))
    gains = (k, np.full(n, KP), np.full(n, KD), np.asarray(q_ref, dtype=float))
    controller = kernel_block(Kernels(gains, _pd_gravity), name="controller", inputs=qs + dqs, outputs=taus,
                              feedthrough=qs + dqs)
    return ct.interconnect([plant, controller], outlist=qs + dqs + taus, name="loop")


#: A small arm keeps the run short: a pitch joint, then a slide on an unaligned axis.  (scope4 runs the same
#: way, but its roll joint turns 1.4e-6 kg m^2, so this fixed-gain PD loop is stiff: 18 million RK45 steps.)
TWO_JOINTS = (Path(__file__).parent / "small_arms" / "two_joints.urdf").read_text()


def test_compiled_chain_plant_equals_a_pinocchio_loop(tmp_path):
    path = tmp_path / "two.urdf"
    path.write_text(TWO_JOINTS)
    arm = load_urdf_arm(path, "rod")
    n, model = arm.n, arm.pin_model
    data = model.createData()
    q0, q_ref = np.array([0.1, 0.05]), np.array([-0.3, 0.12])
    x0 = np.concatenate((q0, np.zeros(n)))
    t = np.linspace(0.0, 1.0, 101)

    engine = CompiledLoopEngine(_loop(arm, q_ref))
    assert "plant" in engine.program.traced and "controller" in engine.program.traced
    # warm() also evaluates the paper loop's row group "d" (lumped disturbance), which this loop has not:
    # skip it; the first integrate compiles
    engine._announce = False
    X, _ = engine.integrate(x0, t, rtol=1e-10, atol=1e-12)

    def rhs(_t, x):
        q, dq = x[:n], x[n:]
        tau = pin.computeGeneralizedGravity(model, data, q).copy() + KP * (q_ref - q) - KD * dq
        return np.concatenate((dq, pin.aba(model, data, q, dq, tau)))

    ref = solve_ivp(rhs, (t[0], t[-1]), x0, t_eval=t, rtol=1e-10, atol=1e-12, method="RK45")
    assert ref.success
    np.testing.assert_allclose(X, ref.y, rtol=0, atol=1e-8)
    assert np.max(np.abs(X[:n, -1] - q_ref)) < 0.05        # the gravity-compensated PD loop settles
