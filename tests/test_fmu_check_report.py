"""dobkit fmu check as a report that never aborts (findings F4, F6), on Reference FMUs and dobkit's test FMUs.

Independent references:

* Dahlquist (x' = -k x, k = 1, x(0) = 1): Model Exchange is e^{-t}; its Co-Simulation takes explicit Euler steps of
  0.1 s that fit before the communication point, so between them it holds x = 0.9^j on [0.1 j, 0.1 (j + 1)): the
  largest gap on the check's grid (0, 0.01, ..., 1 s) is at t = 0.09 s: 1 - e^{-0.09} = 0.0861;
* the gain FMU (y = 2 u) with its input at its start value 0 gives 0 on both interfaces: nothing is compared.
"""
from __future__ import annotations

import math
import zipfile

import numpy as np
import pytest
from fmu_models import build
from reference_fmus import reference_fmus  # noqa: F401 - the fixture

from dobkit.cli import main as dobkit_main
from fmu import FMUModelDescriptionError, check_fmu, load
from fmu.check import stage

pytestmark = pytest.mark.needs_cc
STATUSES = {"passed", "failed", "not applicable"}


def assert_complete(report: dict) -> None:
    """Every stage is there, with a status and a reason."""
    assert [s["stage"] for s in report["stages"]] == ["archive", "model_description", "validation", "model_exchange",
                                                      "simulate_fmu", "co_simulation", "me_vs_cs", "plant_comparison"]
    for entry in report["stages"]:
        assert entry["status"] in STATUSES and entry["why"]


@pytest.mark.parametrize("version", [2, 3])
def test_a_crude_co_simulation_solver_is_named_as_the_side_that_is_off(reference_fmus, version, capsys):  # noqa: F811
    path = reference_fmus(version, "Dahlquist")
    report = check_fmu(path)
    assert_complete(report)
    both = report["me_vs_cs"]
    t = np.linspace(0.0, 1.0, 101)
    held = 0.9 ** np.floor(t / 0.1 + 1e-9)
    assert both["cs_vs_reference"] == pytest.approx(np.max(np.abs(held - np.exp(-t))), abs=1e-9)
    assert both["cs_vs_reference"] == pytest.approx(1 - math.exp(-0.09), abs=1e-9)
    assert both["me_vs_reference"] < 1e-6
    assert stage(report, "me_vs_cs")["status"] == "passed" and report["passed"]
    assert both["finding"].startswith("the FMU's own co-simulation solver is 8.61 % off its Model Exchange answer")
    assert "dobkit uses Model Exchange" in both["finding"]
    assert dobkit_main(["fmu", "check", str(path)]) == 0
    printed = capsys.readouterr().out
    assert "the FMU's own co-simulation solver is 8.61 % off" in printed and printed.rstrip().endswith("passed")


def test_a_comparison_of_zero_with_zero_is_flagged_as_trivial(tmp_path):
    report = check_fmu(build("gain", tmp_path))
    assert_complete(report)
    both = report["me_vs_cs"]
    assert both["trivial"] is True and stage(report, "me_vs_cs")["status"] == "not applicable"
    why = stage(report, "me_vs_cs")["why"]
    assert why.startswith("trivially equal: every compared output is constant in both runs") and "y = 0" in why


def test_duplicate_archive_entries_fail_the_archive_stage_and_the_report_goes_on(reference_fmus, capsys):  # noqa: F811
    """Roberts as its CMake build packs it: the same file twice (F6: exit 2 and no report before)."""
    path = reference_fmus(3, "Roberts")
    names = zipfile.ZipFile(path).namelist()
    assert len(names) != len(set(names))
    report = check_fmu(path)
    assert_complete(report)
    archive = stage(report, "archive")
    assert archive["status"] == "failed" and "name the same file" in archive["why"]
    assert {s["status"] for s in report["stages"][1:]} == {"not applicable"} and report["passed"] is False
    assert dobkit_main(["fmu", "check", str(path)]) == 1
    printed = capsys.readouterr().out
    assert "archive: FAILED -- " in printed and "None" not in printed


def test_failing_derivatives_fail_their_stages_not_the_check(tmp_path, capsys):
    """The mass divides by its input m; with m = 0 as start value every evaluation returns an error status."""
    path = build("mass", tmp_path, filename="mass_m0",
                 xml_edit=lambda xml: xml.replace('name="m" valueReference="6" causality="input" '
                                                  'variability="continuous"><Real start="1"/>',
                                                  'name="m" valueReference="6" causality="input" '
                                                  'variability="continuous"><Real start="0"/>'))
    report = check_fmu(path)
    assert_complete(report)
    me = stage(report, "model_exchange")
    assert me["status"] == "failed" and "status 'error'" in me["why"]
    # its Co-Simulation part keeps the m = 1 compiled into it: it runs, and the check says so
    assert report["co_simulation"]["runs"] is True and stage(report, "validation")["status"] == "passed"
    assert dobkit_main(["fmu", "check", str(path)]) == 1
    assert capsys.readouterr().out.rstrip().endswith("FAILED")


def test_an_unreadable_description_is_reported_with_what_can_be_read(tmp_path, capsys):
    path = tmp_path / "broken.fmu"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", '<?xml version="1.0"?>\n<fmiModelDescription fmiVersion="2.0" '
                                            'modelName="broken" guid="{1}">\n  <ModelVariables>\n')
    report = check_fmu(path)
    assert_complete(report)
    assert report["fmi_version"] == "2.0" and report["model"] == "broken"
    description = stage(report, "model_description")
    assert description["status"] == "failed" and "not well-formed" in description["why"]
    assert dobkit_main(["fmu", "check", str(path)]) == 1
    printed = capsys.readouterr().out
    assert "FMI 2.0, model broken" in printed and "None" not in printed


def shifted(xml: str) -> str:
    """The oscillator's Derivatives entry pointing at the state x instead of der(x)."""
    old = '<Derivatives>\n      <Unknown index="3" dependencies="3"/>'
    assert old in xml
    return xml.replace(old, '<Derivatives>\n      <Unknown index="2" dependencies="3"/>')


def test_a_malformed_model_structure_is_an_fmu_error_not_an_attribute_error(tmp_path):
    path = build("oscillator", tmp_path, xml_edit=shifted, filename="shifted")
    with pytest.raises(FMUModelDescriptionError, match=r"ModelStructure/Derivatives entry 1 points at 'x', which is "
                                                       r"not the derivative of a state"):
        load(path)
    report = check_fmu(path)
    assert_complete(report)
    assert "ModelStructure/Derivatives entry 1" in stage(report, "model_exchange")["why"]
    assert "AttributeError" not in str(report)


def test_event_and_array_fmus_run_in_the_simulate_fmu_stage(reference_fmus):  # noqa: F811
    ball = check_fmu(reference_fmus(2, "BouncingBall"))
    assert_complete(ball)
    sim = ball["simulate_fmu"]
    assert stage(ball, "simulate_fmu")["status"] == "passed"
    assert sim["state_events"] == 1                       # one impact before t = 1 s (at 0.4515 s)
    assert "loads as a block with events" in stage(ball, "model_exchange")["why"]
    space = check_fmu(reference_fmus(3, "StateSpace"))
    assert stage(space, "simulate_fmu")["status"] == "passed"
    assert space["co_simulation"]["runs"] is True        # arrays read whole, not "Expected nValues >= 3 but was 1"
    assert "array variables (FMI 3 'dimensions'): u, y, x: the master couples scalar signals" in \
        space["co_simulation"]["refused"]
