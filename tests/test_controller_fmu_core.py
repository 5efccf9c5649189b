"""The controller FMU's step (fmu/c/controller_core.c): one doStep is one sample, its time is in seconds, a stop
time past the reference table is refused, and ``fmu check`` steps it by its own sample period.
"""
from __future__ import annotations

import pytest
from fmpy.fmi1 import FMICallException

import blocks


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


@pytest.fixture(scope="module")
def controller_fmu(tmp_path_factory):
    """``paper-digital`` cut to 0.2 s (Ts = 1 ms: 200 ticks), exported now as an FMI 2 controller."""
    from dobkit.cli import main

    folder = tmp_path_factory.mktemp("controller-core")
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.2})
    scenario = folder / "short.toml"
    scenario.write_text(s.to_toml().replace('name = "paper-digital"', 'name = "short"', 1), encoding="utf-8")
    out = folder / "controller.fmu"
    assert main(["fmu", "export-controller", "--scenario", str(scenario), "--out", str(out)]) == 0
    return out, s.controller.period


def _controller(path):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="killer")
    fmu.instantiate()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return fmu, vr


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
@pytest.mark.needs_cc
def test_the_controller_runs_only_at_its_sample_period_and_its_time_is_in_seconds(controller_fmu):
    """c-ctrl-step-period, c-ctrl-time.  One doStep is one sample: h = Ts (to rounding), not 5 % more or less;
    after k samples the FMU's ``time`` is k Ts seconds."""
    path, period = controller_fmu
    fmu, vr = _controller(path)
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.setReal([vr[f"q[{i}]"] for i in range(4)] + [vr[f"dq[{i}]"] for i in range(4)],
                    [0.0, 1.5, 0.24, 0.0] + [0.0] * 4)
        for k in range(3):
            fmu.doStep(k * period, period)
        assert fmu.getReal([vr["time"]])[0] == pytest.approx(3 * period, rel=1e-12)
        for wrong in (1.05 * period, 0.95 * period):
            with pytest.raises(FMICallException):
                fmu.doStep(3 * period, wrong)
    finally:
        fmu.terminate()
        fmu.freeInstance()


@pytest.mark.needs_cc
def test_a_stop_time_past_the_reference_table_is_refused(controller_fmu):
    """c-ctrl-stop-time.  The reference table ends at t_final = 0.2 s: a stopTime of 0.3 s cannot be served."""
    path, _ = controller_fmu
    fmu, _ = _controller(path)
    try:
        with pytest.raises(FMICallException):
            fmu.setupExperiment(startTime=0.0, stopTime=0.3)      # fmi2SetupExperiment checks it
    finally:
        fmu.freeInstance()
    fmu, _ = _controller(path)
    try:
        fmu.setupExperiment(startTime=0.0, stopTime=0.2)          # its own end is fine
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.terminate()
    finally:
        fmu.freeInstance()
