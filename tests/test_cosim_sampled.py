"""Co-simulation of the digital controller at h = Ts is the monolithic sampled run (no coupling error)."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
import fmu
from blocks.figure2.metrics import signal

pytestmark = pytest.mark.needs_cc


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory):
    return fmu.export_plant(tmp_path_factory.mktemp("fmu") / "plant.fmu", fmi_version=2)


def _digital(rate=500.0, **more):
    return blocks.load_scenario("paper").with_changes(
        {"controller.sample_rate": rate, "simulation.t_final": 0.4, "simulation.output_step": 0.004,
         "trajectory.duration": 10.0, "simulation.rtol": 1e-10, "simulation.atol": 1e-12} | more)


@pytest.mark.parametrize("more", [{}, {"controller.delay": 1, "controller.velocity": "difference",
                                       "controller.velocity_cutoff": 80.0, "controller.torque_limit": [0, 0, 3.5, 0],
                                       "controller.position_resolution": [1e-4, 1e-4, 1e-6, 1e-4]}],
                         ids=["plain", "delay, limit, encoders"])
def test_cosimulation_at_the_sample_period_equals_the_monolithic_sampled_run(plant_fmu, more):
    s = _digital(**more)
    mono = blocks.simulate(s)
    co = fmu.cosimulate(plant_fmu, s, step=s.controller.period)
    assert co.cosim["coupling"] == "sampled"
    np.testing.assert_array_equal(co.time, mono.time)
    for name, atol in (("q", 1e-9), ("tau", 1e-6), ("d_hat", 1e-6), ("tau_cmd", 1e-6)):
        np.testing.assert_allclose(signal(co, name), signal(mono, name), rtol=0, atol=atol, err_msg=name)


def test_another_step_is_refused_naming_the_sample_period(plant_fmu):
    s = _digital()
    with pytest.raises(fmu.CoSimulationError, match="h = 0.002 s, got 0.001 s"):
        fmu.cosimulate(plant_fmu, s, step=0.001)
