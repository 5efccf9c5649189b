"""Co-simulation against Co-Simulation FMUs: convergence to the monolithic loop, and exact cases.

References: the all-Python loop of blocks integrated at tight tolerance; for
the hand-written lag FMU the exact discrete recursion of a zero-order-hold
coupling (computed here, not by the master); for the moment-integrator FMU
(tests/fmu_models/integrator.c) the same moments integrated on the Python
side from the signal the master hands it.
"""
from __future__ import annotations

import json
from pathlib import Path

import control as ct
import numpy as np
import pytest
from conftest import make_scenario

import blocks
from blocks.figure2.metrics import tracking_metrics
from dobkit.cli import main as dobkit_main
from fmu import cosim_convergence, cosimulate, cosimulate_system, export_plant
from fmu.convergence import fit_order
from fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"
SINE = {"kind": "joint_sine", "amplitude": [0.3, 0.25, 0.03, 0.4], "omega": 3.0, "offset": [0.3, 1.2, 0.2, 0.1]}
T_FINAL = 0.4

# max |q_cosim - q_monolithic| = C_j h^p per joint, p = 1 for the zero-order hold and 2 for the linear coupling.
# C_j (rad/s^p; m/s^p for joint 3) was measured on the fixture's scenario with h = 4, 2 and 1 ms, where err / h^p
# stays within 5 % of these values (the largest of the three).  The tests allow 1.15 C_j h^p.  Handing the plant
# the torque one step late, or feeding the observer the controller's command instead of the applied torque,
# raises the error well past that.
ERROR_CONSTANT = {("zoh", True): np.array([0.0121, 0.0378, 0.0313, 0.0730]),        # with the observer
                  ("zoh", False): np.array([0.0135, 0.0178, 0.0249, 0.0283]),       # without
                  ("linear", True): np.array([0.0306, 0.148, 0.855, 0.250]),
                  ("linear", False): np.array([0.0175, 0.102, 0.328, 0.176])}
ORDER = {"zoh": 1, "linear": 2}


def build_lag(path: Path) -> Path:
    """Package the hand-written lag FMU (FMI 2.0, ME + CS)."""
    return package_fmu(path, (LAG_DIR / "modelDescription.xml").read_text(), {"lag.c": LAG_DIR / "lag.c"},
                       ["lag.c"], "lag", 2)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cosim")
    return {v: export_plant(folder / f"plant{v}.fmu", fmi_version=v) for v in (2, 3)}


@pytest.fixture(scope="module")
def scenario():
    # the paper's disturbance, gains and observer on a joint-space sine; friction on as well
    return make_scenario(trajectory=SINE, disturbance={"kind": ["paper", "friction"]},
                         simulation={"t_final": T_FINAL, "output_step": 0.008, "rtol": 1e-10, "atol": 1e-12})


@pytest.fixture(scope="module")
def monolithic(scenario):
    return blocks.simulate(scenario)


def q_rows(resp) -> np.ndarray:
    labels = list(resp.output_labels)
    return np.asarray(resp.outputs)[[labels.index(f"q[{i}]") for i in range(4)]]


def q_error(resp, ref) -> float:
    return float(np.max(np.abs(q_rows(resp) - q_rows(ref))))


@pytest.mark.needs_cc
@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_convergence_study_finds_the_order_of_each_coupling(fmus, scenario, monolithic, coupling):
    steps = (4e-3, 2e-3, 1e-3)
    study = cosim_convergence(fmus[2], scenario, steps=steps, coupling=coupling)
    assert study["steps"] == sorted(steps) and study["output_step"] == 4e-3 and study["t_final"] == T_FINAL
    assert study["coupling"] == coupling
    errors = np.array([study["errors"][f"q[{i}]"] for i in range(4)])      # (joint, step ascending)
    assert np.all(np.diff(errors, axis=1) > 0)                              # smaller h, smaller error
    p = ORDER[coupling]
    assert abs(study["order"] - p) < 0.1 and all(abs(o - p) < 0.1 for o in study["order_per_joint"].values())
    bound = 1.15 * np.outer(ERROR_CONSTANT[(coupling, True)], np.array(sorted(steps)) ** p)
    assert np.all(errors <= bound), errors / bound
    # the h = 4 ms error, measured independently on the fixture's coarser 8 ms grid (a subset of 4 ms)
    resp = cosimulate(fmus[2], scenario, step=4e-3, coupling=coupling)
    assert list(resp.output_labels) == list(monolithic.output_labels)
    np.testing.assert_allclose(resp.time, monolithic.time, atol=1e-12)
    assert q_error(resp, monolithic) <= errors[:, -1].max() * (1 + 1e-6)
    assert q_error(resp, monolithic) > 0.8 * errors[:, -1].max()


@pytest.mark.needs_cc
def test_the_default_coupling_of_the_plant_is_linear_and_far_better_than_the_hold(fmus, scenario, monolithic):
    default = cosimulate(fmus[2], scenario, step=2e-3)
    held = cosimulate(fmus[2], scenario, step=2e-3, coupling="zoh")
    assert default.cosim["coupling"] == "linear" and default.cosim["output_derivatives"] is True
    assert held.cosim["coupling"] == "zoh" and "zero-order hold" in held.cosim["method"]
    assert q_error(default, monolithic) < q_error(held, monolithic) / 10


@pytest.mark.needs_cc
@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_the_error_estimate_matches_the_error_against_the_monolithic_loop(fmus, scenario, monolithic, coupling):
    """Step doubling over the run (0.4 s) estimates max |q - q_monolithic| per joint: measured within 0.94-1.15."""
    resp = cosimulate(fmus[2], scenario, step=4e-3, coupling=coupling)
    estimate = resp.cosim["error_estimate"]
    assert estimate["order"] == ORDER[coupling] and estimate["t_final"] == pytest.approx(T_FINAL)
    actual = np.abs(q_rows(resp) - q_rows(monolithic)).max(axis=1)
    ratio = np.array([estimate["q"][f"q[{i}]"] for i in range(4)]) / actual
    assert np.all((ratio > 0.8) & (ratio < 1.3)), ratio
    assert set(estimate["d_hat"]) == {f"d_hat[{i}]" for i in range(4)}
    assert "skipped" in cosimulate(fmus[2], scenario, step=4e-3, error_estimate=False).cosim["error_estimate"]


def test_fit_order_recovers_a_known_slope():
    h = np.array([0.004, 0.002, 0.001, 0.0005])
    errors = np.column_stack([3.0 * h ** 1.5, 0.01 * h ** 1.5, 2e-3 * h ** 1.5 * (1 + 0.01 * np.arange(4))])
    order, per = fit_order(h, errors)
    assert order == pytest.approx(1.5, abs=0.01) and per[0] == pytest.approx(1.5, abs=1e-12)
    assert np.isnan(fit_order(h, np.column_stack([h, np.zeros(4)]))[1][1])   # zero errors: no slope


@pytest.mark.needs_cc
@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_fmi3_plant_cosimulates_like_fmi2(fmus, scenario, coupling):
    """FMI 3 has no input derivatives: the linear coupling goes through the intermediate-update callback."""
    a = cosimulate(fmus[2], scenario, step=4e-3, coupling=coupling, error_estimate=False)
    b = cosimulate(fmus[3], scenario, step=4e-3, coupling=coupling, error_estimate=False)
    assert b.cosim["coupling"] == coupling and b.cosim["fmi_version"] == 3
    np.testing.assert_allclose(np.asarray(a.outputs), np.asarray(b.outputs), rtol=0, atol=1e-12)


@pytest.mark.needs_cc
@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_cosimulation_without_observer_and_metrics(fmus, scenario, coupling):
    h = 4e-3
    resp = cosimulate(fmus[2], scenario, step=h, observer=False, coupling=coupling)
    assert "d_hat[0]" not in resp.output_labels and "tau_dis[2]" in resp.output_labels
    ref = blocks.simulate(scenario, observer=False)
    assert list(resp.output_labels) == list(ref.output_labels)
    difference = q_rows(resp) - q_rows(ref)
    assert np.all(np.abs(difference).max(axis=1) <= 1.15 * ERROR_CONSTANT[(coupling, False)] * h ** ORDER[coupling])
    m_cosim, m_ref = tracking_metrics(resp), tracking_metrics(ref)
    assert m_cosim.keys() == m_ref.keys()
    # both RMS errors (Eq. 13) are taken against the same q_ref, so by the triangle inequality of the RMS norm
    # they differ by at most the RMS of q_cosim - q_monolithic, joint by joint
    bound = np.sqrt(np.mean(difference ** 2, axis=1))
    gap = np.abs(np.array(m_cosim["rms_position_error"]) - np.array(m_ref["rms_position_error"]))
    assert np.all(gap <= bound * (1 + 1e-9)), (gap, bound)


@pytest.mark.needs_cc
def test_scenario_parameters_reach_the_fmu(fmus, scenario):
    """The FMU was exported with the paper defaults; the scenario's heavier tool must be used."""
    heavy = make_scenario(trajectory=SINE, robot={"m4": 0.4},
                          simulation={"t_final": 0.2, "output_step": 0.008, "rtol": 1e-10, "atol": 1e-12})
    ref = blocks.simulate(heavy)
    # measured 4.9e-7 at h = 1 ms (joint 3); the FMU's own parameters give 5.4e-3
    assert q_error(cosimulate(fmus[2], heavy, step=1e-3), ref) < 6e-7
    assert q_error(cosimulate(fmus[2], heavy, step=1e-3, parameters="fmu"), ref) > 1e-3


# --- an independent FMU with an exact answer -------------------------------------------------------------

@pytest.mark.needs_cc
def test_lag_fmu_under_pi_control_follows_the_exact_zoh_recursion(tmp_path):
    lag = build_lag(tmp_path / "lag.fmu")
    T, kp, ki, r, h, n = 0.5, 2.0, 3.0, 1.5, 0.05, 40
    # Python side: PI controller, state z' = r - x, output u = kp (r - x) + ki z
    pi = ct.nlsys(lambda t, z, u, p: [r - u[0]], lambda t, z, u, p: [kp * (r - u[0]) + ki * z[0]],
                  inputs=["x"], outputs=["u"], states=["z"], name="pi")
    resp = cosimulate_system(lag, pi, n * h, h, start_values={"T": T, "x": 0.1})
    assert resp.cosim["coupling"] == "zoh"          # the lag holds its input over a step: the best it supports
    # exact recursion: u held over each step, the lag solved exactly, z integrated exactly (constant rate)
    a = np.exp(-h / T)
    x, z, xs, us = 0.1, 0.0, [], []
    for _ in range(n + 1):
        u = kp * (r - x) + ki * z
        xs.append(x)
        us.append(u)
        x, z = u + (x - u) * a, z + h * (r - x)
    labels = list(resp.output_labels)
    assert labels == ["x", "e", "u"]
    np.testing.assert_allclose(resp.time, h * np.arange(n + 1), atol=1e-12)
    np.testing.assert_allclose(resp.outputs[labels.index("x")], xs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(resp.outputs[labels.index("u")], us, rtol=0, atol=1e-12)
    np.testing.assert_allclose(resp.outputs[labels.index("e")], np.array(us) - np.array(xs), atol=1e-12)


@pytest.mark.needs_cc
@pytest.mark.parametrize("given", [None, 2.5])
def test_the_python_side_sees_the_input_start_value_that_was_set(tmp_path, given):
    """Until the first command the FMU's input holds its start value: the one set by start_values (not the model
    description's 0) is what a Python side reading that input sees at t = 0, and the lag starts from it."""
    lag = build_lag(tmp_path / "lag.fmu")
    command, T, h = 1.0, 0.5, 0.1
    # outputs the command u = 1 and, as "seen", the value the FMU input u held when the output was computed
    side = ct.nlsys(None, lambda t, x, u, p: [command, u[1]], inputs=["x", "u"], outputs=["u", "seen"],
                    name="reader")
    start = {"T": T} | ({} if given is None else {"u": given})
    resp = cosimulate_system(lag, side, 3 * h, h, start_values=start, coupling="zoh")
    seen = resp.outputs[list(resp.output_labels).index("seen")]
    held = 0.0 if given is None else given
    np.testing.assert_allclose(seen, [held, command, command, command], rtol=0, atol=0)
    # the lag x' = (u - x) / T from x = 0 under the command held from t = 0 (the start value never acts)
    x = resp.outputs[list(resp.output_labels).index("x")]
    np.testing.assert_allclose(x, command * (1 - np.exp(-resp.time / T)), rtol=0, atol=1e-12)


@pytest.mark.needs_cc
def test_lag_cosimulation_approaches_the_continuous_loop(tmp_path):
    """P control around the lag: the continuous loop is a lag with time constant T / (1 + k)."""
    lag = build_lag(tmp_path / "lag.fmu")
    T, k, r, t_final = 0.5, 3.0, 2.0, 1.0
    p_ctrl = ct.nlsys(None, lambda t, x, u, p: [k * (r - u[0])], inputs=["x"], outputs=["u"], name="p")
    errors = []
    for h in (0.02, 0.01, 0.005):
        resp = cosimulate_system(lag, p_ctrl, t_final, h, start_values={"T": T})
        exact = k * r / (1 + k) * (1 - np.exp(-(1 + k) * resp.time / T))
        errors.append(np.max(np.abs(resp.outputs[0] - exact)))
    order = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((order > 0.85) & (order < 1.15)), (errors, order)


# --- command line ----------------------------------------------------------------------------------------

@pytest.mark.needs_cc
def test_cli_export_check_and_cosim(tmp_path, capsys):
    fmu = tmp_path / "plant.fmu"
    assert dobkit_main(["fmu", "export", "--fmi-version", "3", "--out", str(fmu)]) == 0
    built = fmu.read_bytes()
    assert dobkit_main(["fmu", "export", "--fmi-version", "2", "--out", str(fmu)]) == 2       # no overwriting
    assert "exists; refusing to overwrite it (use --force" in capsys.readouterr().err
    assert fmu.read_bytes() == built
    assert dobkit_main(["fmu", "export", "--fmi-version", "3", "--out", str(fmu), "--force"]) == 0
    assert dobkit_main(["fmu", "check", str(fmu), "--t-final", "0.3"]) == 0
    assert capsys.readouterr().out.rstrip().endswith("passed")
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(make_scenario(trajectory=SINE, simulation={"t_final": 0.1, "output_step": 0.01})
                             .to_toml())
    out = tmp_path / "run"
    assert dobkit_main(["fmu", "cosim", str(fmu), "--scenario", str(scenario_file), "--step", "0.005",
                        "--out", str(out), "--no-figures"]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "figures: skipped (--no-figures)" in printed and "h = 0.005 s, linear coupling" in printed
    # progress on standard error: a line per run where it is not a terminal
    assert "co-simulation with observer: done, took" in captured.err
    assert "co-simulation without observer: done, took" in captured.err
    assert dobkit_main(["fmu", "cosim", str(fmu), "--scenario", str(scenario_file), "--step", "0.005",
                        "--out", str(tmp_path / "quiet"), "--no-figures", "--no-progress"]) == 0
    assert "co-simulation" not in capsys.readouterr().err
    assert "estimated coupling error (step doubling over the first 0.1 s, order 2): q " in printed
    text = (out / "metrics.json").read_text()
    metrics = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    ref = blocks.simulate(make_scenario(trajectory=SINE, simulation={"t_final": 0.1, "output_step": 0.01}))
    assert metrics["with_dob"].keys() == tracking_metrics(ref).keys()
    assert {"scenario", "units", "definitions", "with_dob", "without_dob"} <= metrics.keys()
    co = metrics["cosimulation"]
    assert co["step"] == 0.005 and co["fmi_version"] == 3 and co["coupling"] == "linear"
    assert set(co["error_estimate"]) == {"with_dob", "without_dob"}
    assert set(co["error_estimate"]["with_dob"]["q"]) == {f"q[{i}]" for i in range(4)}


@pytest.mark.needs_cc
@pytest.mark.parametrize("coupling, low, high", [("linear", 3.4, 4.6), ("zoh", 1.7, 2.3)])
def test_cli_convergence_writes_json_and_a_labelled_figure(fmus, tmp_path, capsys, coupling, low, high):
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(make_scenario(trajectory=SINE, simulation={"t_final": 0.1, "output_step": 0.01})
                             .to_toml())
    out = tmp_path / "conv"
    assert dobkit_main(["fmu", "convergence", str(fmus[3]), "--scenario", str(scenario_file),
                        "--steps", "0.004,0.002", "--coupling", coupling, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "fitted order" in printed and "figure: convergence.png, convergence.svg" in printed
    assert f"{coupling} coupling" in printed
    assert sorted(p.name for p in out.iterdir()) == ["convergence.json", "convergence.png", "convergence.svg",
                                                     "scenario.toml"]
    study = json.loads((out / "convergence.json").read_text())
    assert study["steps"] == [0.002, 0.004] and study["fmi_version"] == 3 and study["t_final"] == 0.1
    assert study["units"] == {"q[0]": "rad", "q[1]": "rad", "q[2]": "m", "q[3]": "rad"}
    assert study["coupling"] == coupling
    ratio = np.array(study["errors"]["q[3]"][1]) / np.array(study["errors"]["q[3]"][0])
    assert low < ratio < high                             # halving h halves (zoh) or quarters (linear) the error
    svg = (out / "convergence.svg").read_text()
    for text in ("communication step h (ms)", "max |q_cosim - q_monolithic| (rad; joint 3 in m)",
                 f"fitted slope p = {study['order']:.3f}"):
        assert text in svg


def test_cli_convergence_needs_two_steps(capsys):
    with pytest.raises(SystemExit):
        dobkit_main(["fmu", "convergence", "plant.fmu", "--steps", "0.004"])   # one step: no order
    assert "at least two different steps" in capsys.readouterr().err


@pytest.mark.needs_cc
def test_cli_cosim_refuses_a_step_beyond_the_budget_before_any_work(fmus, tmp_path, capsys):
    out = tmp_path / "run"
    assert dobkit_main(["fmu", "cosim", str(fmus[2]), "--step", "1e-9", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "gives 1e+10 steps, more than the step budget of 2e+06" in err and "--max-steps" in err
    assert not out.exists() or not any(out.iterdir())
    assert dobkit_main(["fmu", "cosim", str(fmus[2]), "--step", "0.001", "--max-steps", "10",
                        "--out", str(out)]) == 2
    assert "more than the step budget of 10" in capsys.readouterr().err
