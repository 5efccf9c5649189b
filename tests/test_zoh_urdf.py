"""The zoh observer on URDF arms (scope4, example-robot-data's Z1): compiled engine, numpy engine and controller FMU.

The reference is a sampled loop written here from pinocchio and the definitions alone: the plant
``M q'' + h = tau + f_r`` (``crba``, ``nonLinearEffects``) integrated by scipy between ticks under the held
torque; at each tick Eq. 11 on a nominal model made here by scaling the URDF's bodies, and the observer
``z' = -Y M^^-1 (tau + Y dq + z - h^)`` advanced over the tick exactly with everything but ``z`` frozen:
``scipy.linalg.expm`` of ``[[A, c], [0, 0]] Ts``.
"""
from __future__ import annotations

from importlib import metadata

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from scipy.integrate import solve_ivp  # noqa: E402
from scipy.linalg import expm  # noqa: E402

from blocks.engines.compiled import numba_or_none  # noqa: E402
from blocks.figure2.digital_loop import simulate_sampled  # noqa: E402
from blocks.model.urdf.examples import scope4_urdf  # noqa: E402
from blocks.scenarios.scenario import load_scenario  # noqa: E402

pytestmark = pytest.mark.slow

KP, KD, BANDWIDTH, MASS_SCALE = 180.0, 36.0, 10.0, 1.05


def _z1_urdf() -> str:
    """example-robot-data's Z1 (Unitree), found through the package's installed-file record."""
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    for f in dist.files or ():
        if str(f).replace("\\", "/").endswith("robots/z1_description/urdf/z1.urdf"):
            return str(dist.locate_file(f))
    pytest.skip("example-robot-data has no z1.urdf")


# The arms: URDF, locked joints, reference (amplitude, omega, offset per joint), disturbance, sample rate
Z1 = {"amplitude": [0.3, 0.2, 0.2, 0.3, 0.3, 0.5], "omega": [0.8, 1.1, 1.5, 2.0, 1.2, 1.6],
      "offset": [0.0, 1.2, -1.0, 0.0, 0.0, 0.0], "f_r": [0.2, 0.3, 0.2, 0.05, 0.05, 0.02], "rate": 200.0}
SCOPE4 = {"amplitude": [0.3, 0.2, 0.03, 0.8], "omega": [0.8, 1.1, 1.5, 2.0], "offset": [0.0, 0.1, 0.1, 0.0],
          "f_r": [0.05, 0.1, 0.4, 0.00002], "rate": 1000.0}


def _z1_toml(folder, t_final: float) -> str:
    a = Z1
    text = f"""name = "z1-zoh"
[arm]
urdf = "{_z1_urdf()}"
tool_frame = "link06"
locked = ["jointGripper"]
nominal_mass_scale = {MASS_SCALE}
[gains]
kp = {KP}
kd = {KD}
observer_bandwidth = {BANDWIDTH}
[trajectory]
kind = "joint_sine"
amplitude = {a['amplitude']}
omega = {a['omega']}
offset = {a['offset']}
[disturbance]
kind = "step"
f_r = {a['f_r']}
[controller]
sample_rate = {a['rate']}
delay = 0
observer_discretization = "zoh"
velocity = "measured"
[simulation]
t_final = {t_final}
output_step = {1.0 / a['rate']}
"""
    path = folder / "z1-zoh.toml"
    path.write_text(text, encoding="utf-8")
    return str(path)


def _scenario(arm: str, folder, t_final: float):
    if arm == "z1":
        return load_scenario(_z1_toml(folder, t_final))
    return load_scenario("scope4-digital").with_changes({
        "simulation.t_final": t_final, "simulation.output_step": 0.001, "controller.position_resolution": 0.0,
        "controller.torque_limit": 0.0, "noise.q_std": 0.0, "noise.dq_std": 0.0,
        "controller.observer_discretization": "zoh"})


def _models(arm: str):
    """The true arm from the URDF (the Z1's gripper locked at 0), and the nominal one with every body x 1.05."""
    def build():
        if arm == "scope4":
            return pin.buildModelFromUrdf(str(scope4_urdf()))
        full = pin.buildModelFromUrdf(_z1_urdf())
        return pin.buildReducedModel(full, [full.getJointId("jointGripper")], pin.neutral(full))
    true, nominal = build(), build()
    for i in range(1, nominal.njoints):
        body = nominal.inertias[i]
        nominal.inertias[i] = pin.Inertia(body.mass * MASS_SCALE, body.lever.copy(), body.inertia * MASS_SCALE)
    return true, nominal


def _mass(model, data, q):
    M = pin.crba(model, data, q).copy()
    return np.triu(M) + np.triu(M, 1).T


def _hand_loop(arm: str, t_out: np.ndarray) -> dict:
    """The sampled loop, tick by tick (exact encoders, measured velocity, zoh observer, no delay, no limit)."""
    p = Z1 if arm == "z1" else SCOPE4
    amp, om, off, f_r = (np.array(p[k]) for k in ("amplitude", "omega", "offset", "f_r"))

    def reference(t):
        return off + amp * np.sin(om * t), amp * om * np.cos(om * t), -amp * om ** 2 * np.sin(om * t)
    true, nominal = _models(arm)
    d_true, d_nom = true.createData(), nominal.createData()
    Ts = 1.0 / p["rate"]
    q, dq, _ = reference(0.0)
    n = q.size
    Y = BANDWIDTH * _mass(nominal, d_nom, q)
    z = -Y @ dq
    x = np.concatenate((q, dq))
    out = {"q": np.empty((t_out.size, n)), "tau": np.empty((t_out.size, n)), "d_hat": np.empty((t_out.size, n))}
    ticks = int(round(t_out[-1] * p["rate"]))
    for k in range(ticks + 1):
        t_k = k * Ts
        q, dq = x[:n], x[n:]
        q_ref, dq_ref, ddq_ref = reference(t_k)
        M_nom = _mass(nominal, d_nom, q)
        h_nom = pin.nonLinearEffects(nominal, d_nom, q, dq).copy()
        d_hat = Y @ dq + z
        tau = M_nom @ (ddq_ref + KD * (dq_ref - dq) + KP * (q_ref - q)) + h_nom - d_hat
        # z' = A z + c over the tick: A = -Y M^-1, c = -Y M^-1 (tau + Y dq - h^)
        A = -Y @ np.linalg.inv(M_nom)
        c = A @ (tau + Y @ dq - h_nom)
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n], aug[:n, n] = A * Ts, c * Ts
        E = expm(aug)
        row = int(np.argmin(np.abs(t_out - t_k)))
        out["q"][row], out["tau"][row], out["d_hat"][row] = q, tau, d_hat
        if k == ticks:
            break
        z = E[:n, :n] @ z + E[:n, n]

        def rhs(_t, xs, tau=tau):
            qs, dqs = xs[:n], xs[n:]
            return np.concatenate((dqs, np.linalg.solve(_mass(true, d_true, qs),
                                                        tau + f_r - pin.nonLinearEffects(true, d_true, qs, dqs))))
        sol = solve_ivp(rhs, (t_k, t_k + Ts), x, method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        x = sol.y[:, -1]
    return out


def _signal(response, prefix):
    labels = list(response.output_labels)
    n = sum(1 for name in labels if name.startswith(f"{prefix}["))
    return np.array([response.outputs[labels.index(f"{prefix}[{i}]")] for i in range(n)]).T


@pytest.mark.parametrize("arm, t_final", [("scope4", 0.3), ("z1", 0.5)], ids=["scope4 1 kHz", "Z1 200 Hz"])
def test_zoh_on_a_urdf_arm_compiled_equals_numpy_and_a_loop_written_with_pinocchio(arm, t_final, tmp_path):
    if numba_or_none() is None:
        pytest.skip("the compiled engine needs numba")
    s = _scenario(arm, tmp_path, t_final)
    assert s.controller.observer_discretization == "zoh" and s.noise is None
    compiled = simulate_sampled(s, engine="compiled")       # raised numba's TypingError before (a ChainParams)
    fast = simulate_sampled(s, engine="fast")
    for prefix in ("q", "dq", "tau", "d_hat"):
        scale = max(1.0, float(np.max(np.abs(_signal(fast, prefix)))))
        np.testing.assert_allclose(_signal(compiled, prefix), _signal(fast, prefix), rtol=0, atol=1e-10 * scale,
                                   err_msg=prefix)
    t = np.asarray(fast.time)
    hand = _hand_loop(arm, t)
    q = _signal(fast, "q")
    np.testing.assert_allclose(q, hand["q"], rtol=0, atol=1e-7)
    np.testing.assert_allclose(_signal(fast, "tau"), hand["tau"], rtol=0,
                               atol=1e-6 * max(1.0, float(np.max(np.abs(hand["tau"])))))
    np.testing.assert_allclose(_signal(fast, "d_hat"), hand["d_hat"], rtol=0,
                               atol=1e-6 * max(1.0, float(np.max(np.abs(hand["d_hat"])))))
    # the loop tracks (a 13 rad/s PD loop on a 1 - 2 rad/s path), so the comparison is not of a broken run
    p = Z1 if arm == "z1" else SCOPE4
    q_ref = np.array(p["offset"]) + np.array(p["amplitude"]) * np.sin(np.array(p["omega"]) * t[:, None])
    rms = np.sqrt(np.mean((hand["q"] - q_ref) ** 2, axis=0))
    assert np.all(rms < 0.05) and np.all(np.isfinite(rms))


@pytest.mark.needs_cc
@pytest.mark.parametrize("arm", ["scope4", "z1"], ids=["scope4 1 kHz", "Z1 200 Hz"])
def test_the_zoh_controller_fmu_of_a_urdf_arm_exports_validates_and_gives_the_python_controllers_torques(arm,
                                                                                                        tmp_path):
    from fmpy.validation import validate_fmu
    from test_controller_fmu import _Slave

    from dobkit.cli import main
    s = _scenario(arm, tmp_path, 0.2)
    scenario_file = tmp_path / f"{arm}-zoh-controller.toml"
    scenario_file.write_text(s.to_toml(), encoding="utf-8")
    fmu_path = tmp_path / f"{arm}-controller.fmu"
    # exit 2 before: "a kernel converts a traced value to a Python number" (the URDF arm's zoh update)
    assert main(["fmu", "export-controller", "--scenario", str(scenario_file), "--out", str(fmu_path)]) == 0
    assert validate_fmu(str(fmu_path)) == []
    # the Python sampled controller's run: at every tick its inputs (q, dq) and what it computed (tau, d_hat)
    run = simulate_sampled(s, engine="fast")
    q, dq, tau, d_hat = (_signal(run, p) for p in ("q", "dq", "tau", "d_hat"))
    n, Ts = q.shape[1], s.controller.period
    assert np.allclose(np.diff(np.asarray(run.time)), Ts)
    ctrl = _Slave(fmu_path, f"{arm}-controller")
    try:
        c_in = ctrl.refs("q", n) + ctrl.refs("dq", n)
        c_tau, c_dhat = ctrl.refs("tau", n), ctrl.refs("d_hat", n)
        got_tau, got_dhat = [], []
        for k in range(q.shape[0]):
            ctrl.set(c_in, list(q[k]) + list(dq[k]))
            got_tau.append(list(ctrl.get(c_tau)))
            got_dhat.append(list(ctrl.get(c_dhat)))
            if k < q.shape[0] - 1:
                ctrl.fmu.doStep(k * Ts, Ts)
    finally:
        ctrl.close()
    np.testing.assert_allclose(np.array(got_tau), tau, rtol=0, atol=1e-9 * max(1.0, float(np.max(np.abs(tau)))))
    np.testing.assert_allclose(np.array(got_dhat), d_hat, rtol=0,
                               atol=1e-9 * max(1.0, float(np.max(np.abs(d_hat)))))
    # the zoh update acted: d_hat moved from its start 0 by more than rounding
    assert np.max(np.abs(d_hat[-1])) > 1e-3
