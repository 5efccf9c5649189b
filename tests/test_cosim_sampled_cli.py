"""``dobkit fmu cosim`` with a digital controller: runs to the end, and serves any output grid exactly.

The plant FMU is exported with ``dobkit fmu export``.  The reference is the
monolithic sampled run of the same scenario (``blocks.simulate``: the hybrid
engine, the continuous plant integrated by scipy to rtol 1e-10 between
samples), which shares no code with the FMU's C plant and its RK4 steps.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import blocks
import fmu
from blocks.figure2.metrics import signal, tracking_metrics
from dobkit.cli import main as dobkit_main

pytestmark = pytest.mark.needs_cc


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory):
    path = tmp_path_factory.mktemp("fmu") / "plant.fmu"
    assert dobkit_main(["fmu", "export", "--out", str(path)]) == 0
    return path


def _digital(rate: float, output_step: float):
    return blocks.load_scenario("paper").with_changes(
        {"controller.sample_rate": rate, "simulation.t_final": 0.2, "simulation.output_step": output_step,
         "trajectory.duration": 10.0, "simulation.rtol": 1e-10, "simulation.atol": 1e-12})


def _cosim_cli(plant_fmu, scenario, step: float, folder):
    scenario_file = folder / "s.toml"
    scenario_file.write_text(scenario.to_toml())
    out = folder / "run"
    status = dobkit_main(["fmu", "cosim", str(plant_fmu), "--scenario", str(scenario_file), "--step", str(step),
                          "--out", str(out), "--no-figures"])
    return status, out


@pytest.mark.parametrize("rate, output_step, step", [(1000.0, 0.005, 0.001), (500.0, 0.005, 0.002)],
                         ids=["1 kHz, output 5 h", "500 Hz, output 2.5 h"])
def test_cli_cosim_of_a_digital_controller_writes_the_monolithic_runs_metrics(plant_fmu, tmp_path, capsys, rate,
                                                                                output_step, step):
    s = _digital(rate, output_step)
    status, out = _cosim_cli(plant_fmu, s, step, tmp_path)
    printed = capsys.readouterr()
    assert status == 0, printed.err
    assert f"h = {step:g} s, the digital controller's samples as communication points" in printed.out
    assert "error estimate: skipped (no coupling error" in printed.out
    metrics = json.loads((out / "metrics.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    co = metrics["cosimulation"]
    assert co["coupling"] == "sampled" and co["step"] == step and co["output_step"] == output_step
    assert "side_substeps" in co and co["side_substeps"] is None       # no Python-side integration to sub-step
    # the metrics are computed on the output grid: equal to the monolithic run's on the same grid
    for key, observer in (("with_dob", True), ("without_dob", False)):
        reference = tracking_metrics(blocks.simulate(s, observer=observer))
        assert metrics[key].keys() == reference.keys()
        for name, value in reference.items():
            np.testing.assert_allclose(metrics[key][name], value, rtol=1e-6, atol=1e-12, err_msg=f"{key} {name}")


@pytest.mark.parametrize("output_step", [0.005, 0.0008], ids=["5 ms (2.5 Ts)", "0.8 ms (0.4 Ts)"])
def test_output_points_between_samples_are_served_exactly(plant_fmu, output_step):
    """Ts = 2 ms; the output grid falls between samples: each point equals the monolithic run's there."""
    s = _digital(500.0, output_step)
    mono = blocks.simulate(s)
    co = fmu.cosimulate(plant_fmu, s, step=s.controller.period)
    np.testing.assert_array_equal(co.time, mono.time)
    between = np.abs(co.time / 0.002 - np.round(co.time / 0.002)) > 1e-6
    assert between.sum() >= co.time.size // 2          # most points are not samples
    for name, atol in (("q", 1e-9), ("dq", 1e-7), ("tau", 1e-6), ("d_hat", 1e-6), ("tau_cmd", 1e-6),
                       ("tau_dis", 1e-6)):
        np.testing.assert_allclose(signal(co, name), signal(mono, name), rtol=0, atol=atol, err_msg=name)


def test_cli_refuses_a_step_other_than_the_sample_period_naming_it(plant_fmu, tmp_path, capsys):
    status, out = _cosim_cli(plant_fmu, _digital(500.0, 0.005), 0.001, tmp_path)
    assert status == 2
    assert "co-simulate it with the communication step h = 0.002 s, got 0.001 s" in capsys.readouterr().err
    assert not out.exists()


def test_cli_refuses_side_substeps_for_a_digital_controller(plant_fmu, tmp_path, capsys):
    """A digital controller has no continuous side to sub-step: the flag is refused, not silently ignored."""
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(_digital(500.0, 0.005).to_toml())
    out = tmp_path / "run"
    assert dobkit_main(["fmu", "cosim", str(plant_fmu), "--scenario", str(scenario_file), "--step", "0.002",
                        "--side-substeps", "4", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--side-substeps 4: scenario" in err and "digital controller ([controller])" in err and "0.002" in err
    assert not out.exists()
