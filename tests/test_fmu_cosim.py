"""Co-simulation against Co-Simulation FMUs: convergence to the monolithic loop, and an exact linear case.

References: the all-Python loop of dobkit.blocks integrated at tight
tolerance, and for the hand-written lag FMU the exact discrete recursion of a
zero-order-hold coupling (computed here, not by the master).
"""
from __future__ import annotations

import json
from pathlib import Path

import control as ct
import numpy as np
import pytest

from conftest import make_scenario
from dobkit import blocks
from dobkit.analysis.metrics import tracking_metrics
from dobkit.cli import main as dobkit_main
from dobkit.fmu import cosimulate, cosimulate_system, export_plant
from dobkit.fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"
SINE = {"kind": "joint_sine", "amplitude": [0.3, 0.25, 0.03, 0.4], "omega": 3.0, "offset": [0.3, 1.2, 0.2, 0.1]}
T_FINAL = 0.4


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


def q_error(resp, ref) -> float:
    labels = list(ref.output_labels)
    rows = [labels.index(f"q[{i}]") for i in range(4)]
    return float(np.max(np.abs(np.asarray(resp.outputs)[rows] - np.asarray(ref.outputs)[rows])))


def test_cosimulation_converges_to_the_monolithic_loop_at_first_order(fmus, scenario, monolithic):
    steps = (4e-3, 2e-3, 1e-3)
    errors = []
    for h in steps:
        resp = cosimulate(fmus[2], scenario, step=h)
        assert list(resp.output_labels) == list(monolithic.output_labels)
        np.testing.assert_allclose(resp.time, monolithic.time, atol=1e-12)
        errors.append(q_error(resp, monolithic))
    order = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < 5e-3
    assert np.all((order > 0.8) & (order < 1.2)), (errors, order)   # zero-order hold: first order in h


def test_fmi3_plant_cosimulates_like_fmi2(fmus, scenario):
    a = cosimulate(fmus[2], scenario, step=4e-3)
    b = cosimulate(fmus[3], scenario, step=4e-3)
    np.testing.assert_allclose(np.asarray(a.outputs), np.asarray(b.outputs), rtol=0, atol=1e-12)


def test_cosimulation_without_observer_and_metrics(fmus, scenario):
    resp = cosimulate(fmus[2], scenario, step=4e-3, observer=False)
    assert "d_hat[0]" not in resp.output_labels and "tau_dis[2]" in resp.output_labels
    ref = blocks.simulate(scenario, observer=False)
    assert list(resp.output_labels) == list(ref.output_labels)
    assert q_error(resp, ref) < 2e-2
    m_cosim, m_ref = tracking_metrics(resp), tracking_metrics(ref)
    assert m_cosim.keys() == m_ref.keys()
    np.testing.assert_allclose(m_cosim["rms_position_error"], m_ref["rms_position_error"], rtol=0.5, atol=1e-4)


def test_scenario_parameters_reach_the_fmu(fmus, scenario):
    """The FMU was exported with the paper defaults; the scenario's heavier tool must be used."""
    heavy = make_scenario(trajectory=SINE, robot={"m4": 0.4},
                          simulation={"t_final": 0.2, "output_step": 0.008, "rtol": 1e-10, "atol": 1e-12})
    ref = blocks.simulate(heavy)
    assert q_error(cosimulate(fmus[2], heavy, step=1e-3), ref) < 2e-3
    assert q_error(cosimulate(fmus[2], heavy, step=1e-3, parameters="fmu"), ref) > q_error(
        cosimulate(fmus[2], heavy, step=1e-3), ref)


# --- an independent FMU with an exact answer -------------------------------------------------------------

def test_lag_fmu_under_pi_control_follows_the_exact_zoh_recursion(tmp_path):
    lag = build_lag(tmp_path / "lag.fmu")
    T, kp, ki, r, h, n = 0.5, 2.0, 3.0, 1.5, 0.05, 40
    # Python side: PI controller, state z' = r - x, output u = kp (r - x) + ki z
    pi = ct.nlsys(lambda t, z, u, p: [r - u[0]], lambda t, z, u, p: [kp * (r - u[0]) + ki * z[0]],
                  inputs=["x"], outputs=["u"], states=["z"], name="pi")
    resp = cosimulate_system(lag, pi, n * h, h, start_values={"T": T, "x": 0.1})
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

def test_cli_export_check_and_cosim(tmp_path, capsys):
    fmu = tmp_path / "plant.fmu"
    assert dobkit_main(["fmu", "export", "--fmi-version", "3", "--out", str(fmu)]) == 0
    assert dobkit_main(["fmu", "check", str(fmu), "--t-final", "0.3"]) == 0
    assert "passed" in capsys.readouterr().out
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(make_scenario(trajectory=SINE, simulation={"t_final": 0.1, "output_step": 0.01})
                             .to_toml())
    out = tmp_path / "run"
    assert dobkit_main(["fmu", "cosim", str(fmu), "--scenario", str(scenario_file), "--step", "0.005",
                        "--out", str(out), "--no-figures"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    ref = blocks.simulate(make_scenario(trajectory=SINE, simulation={"t_final": 0.1, "output_step": 0.01}))
    assert metrics["with_dob"].keys() == tracking_metrics(ref).keys()
    assert {"scenario", "units", "definitions", "with_dob", "without_dob"} <= metrics.keys()
    assert metrics["cosimulation"]["step"] == 0.005 and metrics["cosimulation"]["fmi_version"] == 3
