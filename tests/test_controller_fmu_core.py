"""The controller FMU's step (fmu/c/controller_core.c): one doStep is one sample, its time is in seconds, a stop
time past the reference table is refused, and ``fmu check`` steps it by its own sample period.
"""
from __future__ import annotations

import pytest


def test_fmu_check_steps_a_sampled_controller_fmu_by_its_own_sample_period(tmp_path):
    # `dobkit fmu check ctrl.fmu` of dobkit's own controller FMU said FAILED: the check stepped by 0.01 s, which
    # the controller refuses (its step is one sample), and ran past the end of its reference table
    import blocks
    from fmu import check_fmu
    from fmu.check import stage
    from fmu.controller_export import export_controller
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.2})
    path = export_controller(tmp_path / "ctrl.fmu", s)
    report = check_fmu(path)
    assert stage(report, "co_simulation")["status"] == "passed", report["co_simulation"]
    run = report["co_simulation"]["run"]
    assert run["step"] == pytest.approx(1.0 / s.controller.sample_rate, rel=1e-12)    # the sample period
    assert run["t_final"] == 0.2 and report["passed"]                                   # the table's end
    explicit = check_fmu(path, cs_step=0.01)                   # a step the user asks for is still the user's
    assert not explicit["passed"] and "every step must be one sample" in explicit["co_simulation"]["error"]
