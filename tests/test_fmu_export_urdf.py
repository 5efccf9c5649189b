"""The plant FMU of URDF arms (scope4, Panda): C generated from the chain kernels, held against pinocchio.

Model Exchange: the FMU's state derivative at random states against
``pin.aba`` (and ``M^-1 (tau - nle)``), with the friction model written here
from its definition.  Co-Simulation: a short run of the FMU's own RK4 against
SciPy integrating pinocchio's forward dynamics under the same held torque.
"""
from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from fmpy.validation import validate_fmu  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from blocks.model.urdf import example_arm  # noqa: E402
from fmu import FMUInstance, export_plant  # noqa: E402

pytestmark = pytest.mark.needs_cc

TOL = 1e-10


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("urdf_fmus")
    arms = {"scope4": example_arm("scope4"), "panda": example_arm("panda")}
    fmus = {(name, 2): export_plant(folder / f"{name}.fmu", params=arm) for name, arm in arms.items()}
    fmus[("scope4", 3)] = export_plant(folder / "scope4_fmi3.fmu", params=arms["scope4"], fmi_version=3)
    return arms, fmus


def _random_state(arm, rng):
    lo = np.array([max(a, -2.5) for a, _ in arm.joints.limits])
    hi = np.array([min(b, 2.5) for _, b in arm.joints.limits])
    return rng.uniform(lo, hi), rng.normal(0.0, 1.0, arm.n)


def _aba(arm, q, dq, tau):
    model = arm.pin_model
    return pin.aba(model, model.createData(), arm.pinocchio_configuration(q), dq, tau)


@pytest.mark.parametrize("key", [("scope4", 2), ("scope4", 3), ("panda", 2)])
def test_fmpy_validates_the_urdf_plant(exported, key):
    _, fmus = exported
    assert validate_fmu(str(fmus[key])) == []


@pytest.mark.parametrize("key", [("scope4", 2), ("scope4", 3), ("panda", 2)])
def test_model_exchange_derivatives_agree_with_pinocchio(exported, key):
    arms, fmus = exported
    arm = arms[key[0]]
    n = arm.n
    rng = np.random.default_rng(n)
    friction = {"disturbance_friction": True, "friction_velocity": 0.05}
    coulomb = rng.uniform(0.1, 2.0, n)
    viscous = rng.uniform(0.0, 0.5, n)
    friction |= {f"coulomb[{i}]": coulomb[i] for i in range(n)} | {f"viscous[{i}]": viscous[i] for i in range(n)}
    worst = 0.0
    for start, with_friction in (({}, False), (friction, True)):
        with FMUInstance(fmus[key], "ModelExchange", start_values=start) as f:
            assert f.n_states == 2 * n
            taus = f.value_references([f"tau[{i}]" for i in range(n)])
            for _ in range(25):
                q, dq = _random_state(arm, rng)
                u = rng.normal(0.0, 5.0, n)
                f.set_time(0.3)
                f.set_states(np.concatenate((q, dq)))
                f.set_real(taus, u)
                got = f.derivatives()
                tau = u - (coulomb * np.tanh(dq / 0.05) + viscous * dq) if with_friction else u
                ddq = _aba(arm, q, dq, tau)
                model = arm.pin_model
                data = model.createData()
                qp = arm.pinocchio_configuration(q)
                M = pin.crba(model, data, qp)
                M = np.triu(M) + np.triu(M, 1).T
                ddq_solve = np.linalg.solve(M, tau - pin.nonLinearEffects(model, data, qp, dq))
                np.testing.assert_array_equal(got[:n], dq)
                # the kernel the C was generated from, run by numpy: the same operations
                kernel = arm.kernels.plant_acceleration(arm.kernel_params(), q, dq, tau)
                np.testing.assert_allclose(got[n:], kernel, rtol=1e-13, atol=1e-13 * max(np.max(np.abs(kernel)), 1))
                scale = max(np.max(np.abs(ddq)), 1.0)
                np.testing.assert_allclose(got[n:], ddq, rtol=TOL, atol=TOL * scale)
                np.testing.assert_allclose(got[n:], ddq_solve, rtol=TOL, atol=TOL * scale)
                worst = max(worst, float(np.max(np.abs(got[n:] - ddq)) / scale))
    print(f"{key}: largest |FMU - pin.aba| / max|q''| = {worst:.3g}")


def test_co_simulation_follows_scipy_on_pinocchio(exported):
    arms, fmus = exported
    arm = arms["scope4"]
    n, h, steps = arm.n, 2e-3, 150
    x0 = np.concatenate(_random_state(arm, np.random.default_rng(3)))
    hold = lambda t: np.array([3.0 * np.sin(5 * t + i) for i in range(n)])      # noqa: E731
    start = {f"q[{i}]": x0[i] for i in range(n)} | {f"dq[{i}]": x0[n + i] for i in range(n)} | {"n_substeps": 4}
    # 3 N m spins the roll (1.5e-6 kg m^2) past its range: compare the arm's dynamics alone, end stops off
    start |= {f"stop_{p}[{i}]": 0.0 for i in range(n) for p in ("stiffness", "damping")}
    with FMUInstance(fmus[("scope4", 2)], "CoSimulation", start_values=start) as f:
        taus = f.value_references([f"tau[{i}]" for i in range(n)])
        states = f.value_references([f"q[{i}]" for i in range(n)] + [f"dq[{i}]" for i in range(n)])
        fmu_x = []
        for k in range(steps):
            f.set_real(taus, hold(k * h))
            f.do_step(k * h, h)
            fmu_x.append(f.get_real(states).copy())
    x, ref = x0.copy(), []
    for k in range(steps):                          # the same torque held over each step
        u = hold(k * h)
        sol = solve_ivp(lambda t, y: np.concatenate((y[n:], _aba(arm, y[:n], y[n:], u))), (k * h, (k + 1) * h), x,
                        method="DOP853", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        ref.append(x.copy())
    err = np.max(np.abs(np.array(fmu_x) - np.array(ref)))
    assert np.max(np.abs(np.array(ref) - x0)) > 0.05          # the arm moved
    assert err < 1e-7, err
    print(f"scope4 co-simulation 0.3 s, h = 2 ms, 4 RK4 sub-steps: max |FMU - SciPy(pin.aba)| = {err:.3g}")


def test_the_tissue_model_is_taken_for_a_urdf_arm_and_bad_starts_are_refused(exported):
    # the tissue contact runs on a URDF arm's FMU (tests/test_tissue_any_arm.py checks its forces against
    # pinocchio); the default skin plane goes through the tool point at the start pose q0 = 0
    arms, fmus = exported
    with FMUInstance(fmus[("scope4", 2)], "CoSimulation", start_values={"disturbance_tissue": True}) as f:
        skin = f.get_real(f.value_references(["skin_height"]))[0]
    model = arms["scope4"].pin_model
    data = model.createData()
    pin.framesForwardKinematics(model, data, arms["scope4"].pinocchio_configuration(np.zeros(4)))
    assert skin == pytest.approx(data.oMf[model.getFrameId("tool_tip")].translation[2], abs=1e-12)
    with pytest.raises(ValueError, match="q0 must be 7 finite numbers"):
        export_plant("never.fmu", params=arms["panda"], q0=[0.0] * 4)


def test_the_command_line_exports_a_urdf_arm(tmp_path, capsys):
    from blocks.model.urdf import scope4_urdf
    from dobkit.cli import main
    out = tmp_path / "scope4.fmu"
    assert main(["fmu", "export", "--arm", str(scope4_urdf()), "--tool-frame", "tool_tip", "--out", str(out)]) == 0
    assert "arm 4 joints" in capsys.readouterr().out
    assert validate_fmu(str(out)) == []
    assert main(["fmu", "export", "--arm", str(scope4_urdf()), "--out", str(tmp_path / "x.fmu")]) == 2
    assert "give its tool frame with --tool-frame" in capsys.readouterr().err
    assert main(["fmu", "export", "--arm", "kuka", "--out", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err
    assert "--arm must be one of [" in err and "or a path to a .urdf file" in err
    assert all(f"'{name}'" in err for name in ("scope4", "panda", "ur5", "z1", "so101"))   # every example arm
    assert not (tmp_path / "x.fmu").exists()
