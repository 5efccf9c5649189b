"""FMUs as other tools make them: no states, equations that divide by an input, FMI 3 enumerations, names
outside fmpy's naming grammar, only Scheduled Execution, odd packaging, hostile sizes, NaN outputs.

The FMUs are built here from C (tests/fmu_models) independently of the plant FMU.  References are closed
forms: two masses joined by a spring oscillate with w^2 = k (1/m1 + 1/m2) about their fixed centre of mass.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import control as ct
import numpy as np
import pytest
from fmu_models import build
from scipy.integrate import solve_ivp

from blocks.engines.fastsim import CompiledLoop
from dobkit.cli import main as dobkit_main
from fmu import (
    BudgetError,
    ExtractionLimits,
    FMUArchiveError,
    FMUModelDescriptionError,
    FMUStepError,
    FMUVersionError,
    check_fmu,
    export_plant,
    extract_fmu,
    load,
)
from fmu.archive import remove_stale_extractions

pytestmark = pytest.mark.needs_cc

M1, M2, K, R0 = 2.0, 0.5, 4.0, 1.0        # kg, kg, N/m, m (the spring's initial stretch)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("foreign")
    return {name: build(name, folder) for name in ("mass", "spring", "oscillator", "selector")}


def two_masses(models):
    """Two mass FMUs joined by the stateless spring FMU; the masses come from a Python block."""
    m1 = load(models["mass"], name="mass1")
    m2 = load(models["mass"], name="mass2", start_values={"x": R0})
    spring = load(models["spring"], name="spring", start_values={"k": K})
    masses = ct.nlsys(None, lambda t, x, u, p: [M1, M2], inputs=0, outputs=["m1", "m2"], name="masses")
    connections = [["spring.x1", "mass1.x"], ["spring.x2", "mass2.x"], ["mass1.F", "spring.f1"],
                   ["mass2.F", "spring.f2"], ["mass1.m", "masses.m1"], ["mass2.m", "masses.m2"]]
    system = ct.interconnect([m1, m2, spring, masses], connections=connections, outlist=["mass1.x", "mass2.x"],
                             outputs=["x1", "x2"], check_unused=False)
    return system, np.r_[m1.initial_state, m2.initial_state], (m1, m2, spring)


def exact_positions(t):
    w = np.sqrt(K * (1 / M1 + 1 / M2))
    centre = M2 * R0 / (M1 + M2)
    stretch = R0 * np.cos(w * t)
    return centre - M2 / (M1 + M2) * stretch, centre + M1 / (M1 + M2) * stretch


def test_an_fmu_without_states_loads_as_a_static_block(models):
    with load(models["spring"], start_values={"k": K}) as spring:
        assert spring.nstates == 0 and list(spring.input_labels) == ["x1", "x2"]
        assert spring.contract.feedthrough == frozenset({"x1", "x2"})
        np.testing.assert_allclose(spring._out(0.0, np.zeros(0), np.array([0.25, 1.0])), [K * 0.75, -K * 0.75])


def test_an_input_only_the_state_equations_need_is_not_set_for_the_outputs(models, capfd):
    """The mass divides by its input m; no output needs m, so python-control's first pass (zeros) is harmless."""
    with load(models["mass"], start_values={"x": 0.3, "v": -0.1}) as mass:
        assert mass.contract.feedthrough == frozenset()                 # x, v depend on the states only
        np.testing.assert_allclose(mass._out(0.0, np.array([0.3, -0.1]), np.zeros(2)), [0.3, -0.1])
        np.testing.assert_allclose(mass._rhs(0.0, np.array([0.3, -0.1]), np.array([3.0, 2.0])), [-0.1, 1.5])
        # the state equations do need m: zero is an error, explained by the FMU's own log line
        with pytest.raises(FMUStepError, match=r"fmi2GetDerivatives returned status 'error' at t = 0.5 s .*division "
                                               r"by zero at time 0.5.*divisor b expression is: m") as err:
            mass._rhs(0.5, np.array([0.3, -0.1]), np.array([3.0, 0.0]))
    assert any("divisor b expression is: m" in line for line in err.value.messages)
    assert "division by zero" not in capfd.readouterr().out       # the explanation reached the importer


@pytest.mark.parametrize("engine", ["python-control", "compiled loop"])
def test_fmus_that_divide_by_an_input_work_inside_an_interconnection(models, engine):
    system, x0, parts = two_masses(models)
    t = np.linspace(0.0, 2.0, 201)
    try:
        if engine == "python-control":
            resp = ct.input_output_response(system, t, 0, x0, solve_ivp_method="DOP853",
                                            solve_ivp_kwargs={"rtol": 1e-10, "atol": 1e-12})
            x1, x2 = resp.outputs
        else:
            loop = CompiledLoop(system)
            sol = solve_ivp(lambda tt, x: loop.rhs(tt, x), (0.0, 2.0), x0, method="DOP853", t_eval=t, rtol=1e-10,
                            atol=1e-12)
            x1, x2 = np.column_stack([loop.output(tt, sol.y[:, k]) for k, tt in enumerate(t)])
    finally:
        for part in parts:
            part.close()
    e1, e2 = exact_positions(t)
    np.testing.assert_allclose(x1, e1, rtol=0, atol=1e-8)
    np.testing.assert_allclose(x2, e2, rtol=0, atol=1e-8)


def test_an_fmi3_enumeration_start_value_is_set_as_int64(models):
    with load(models["selector"]) as adder:                              # mode = add (start value 1)
        assert adder._out(0.0, np.zeros(0), np.array([3.0, 1.0]))[0] == 4.0
    with load(models["selector"], start_values={"mode": 2}) as subtracter:
        assert subtracter._out(0.0, np.zeros(0), np.array([3.0, 1.0]))[0] == 2.0
    with pytest.raises(FMUStepError, match="mode = 3 is not an item of the enumeration"):
        load(models["selector"], start_values={"mode": 3})


# --- check -------------------------------------------------------------------------------------------------

def with_event_indicator(xml: str) -> str:
    return xml.replace('numberOfEventIndicators="0"', 'numberOfEventIndicators="1"')


def test_check_reports_a_load_refusal_by_name(models, tmp_path, capsys):
    events = build("mass", tmp_path, xml_edit=with_event_indicator, filename="mass_events")
    report = check_fmu(events)
    me = report["model_exchange"]
    assert me["loads"] is True and me["events"] is True
    # a block with events: its run alone is simulate_fmu's, so the check passes
    from fmu.check import stage
    assert stage(report, "model_exchange")["status"] == "not applicable"
    assert "loads as a block with events" in stage(report, "model_exchange")["why"]
    assert stage(report, "simulate_fmu")["status"] == "passed"
    assert report["co_simulation"]["runs"] and report["co_simulation"]["passed"]
    assert report["validation"]["passed"] and report["passed"]
    assert dobkit_main(["fmu", "check", str(events)]) == 0
    printed = capsys.readouterr().out
    assert "loads as a block with events" in printed and "Traceback" not in printed


def test_check_reports_a_naming_convention_finding_as_a_warning(models, capsys):
    report = check_fmu(models["oscillator"], t_final=1.0)
    v = report["validation"]
    assert v["passed"] and v["errors"] == [] and len(v["warnings"]) == 1 and "der(der(x))" in v["warnings"][0]
    assert report["passed"] and report["model_exchange"]["loads"] and report["co_simulation"]["runs"]
    # x'' = -w^2 x from x = 1 at rest: both interfaces give cos(w t); they agree to the CS RK4 error
    assert report["me_vs_cs"]["passed"] and report["me_vs_cs"]["max_abs_difference"] < 1e-6
    assert dobkit_main(["fmu", "check", str(models["oscillator"])]) == 0
    printed = capsys.readouterr().out
    assert "validation (fmpy): passed (1 naming-convention warning(s))" in printed
    assert "warning (variable-naming convention only; the FMU can still be used)" in printed
    assert printed.rstrip().endswith("passed")


def scheduled_only(models, folder: Path) -> Path:
    """The selector's description with Scheduled Execution as its only interface."""
    xml = zipfile.ZipFile(models["selector"]).read("modelDescription.xml").decode()
    xml = xml.replace('<ModelExchange modelIdentifier="selector"/>', "")
    xml = xml.replace('<CoSimulation modelIdentifier="selector" canHandleVariableCommunicationStepSize="true"/>',
                      '<ScheduledExecution modelIdentifier="selector"/>')
    path = folder / "scheduled.fmu"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", xml)
    return path


def test_an_fmu_offering_only_scheduled_execution_is_named(models, tmp_path):
    path = scheduled_only(models, tmp_path)
    with pytest.raises(FMUVersionError, match=r"does not offer ModelExchange \(it offers: ScheduledExecution\)"):
        load(path)
    report = check_fmu(path)
    assert report["interfaces"] == ["ScheduledExecution"] and not report["passed"]
    assert "it offers: ScheduledExecution" in report["model_exchange"]["skipped"]


def test_nan_outputs_fail_the_check_and_its_json_is_strict(tmp_path, capsys):
    """A plant FMU whose tau_dis outputs are NaN (its state equations are fine)."""
    source = export_plant(tmp_path / "plant.fmu")
    sources = {}
    with zipfile.ZipFile(source) as zf:
        xml = zf.read("modelDescription.xml").decode()
        for name in zf.namelist():
            if name.startswith("sources/") and name.endswith((".c", ".h")):
                sources[name.split("/", 1)[1]] = zf.read(name)
    code = sources["plant_instance.c"].decode()
    assert "*value = buf[vr - VR_TAU_DIS];" in code
    sources["plant_instance.c"] = code.replace("*value = buf[vr - VR_TAU_DIS];", "*value = NAN;")
    from fmu.export import plant_source_files
    from fmu.package import package_fmu
    bad = package_fmu(tmp_path / "nan.fmu", xml, sources, plant_source_files(2), "dobkit_plant", 2)
    report = check_fmu(bad, t_final=0.2)
    assert report["plant_comparison"]["model_exchange"]["passed"] is False
    assert np.isnan(report["plant_comparison"]["model_exchange"]["max_abs_error"])
    assert report["model_exchange"]["run"]["finite"] is False and not report["passed"]
    assert dobkit_main(["fmu", "check", str(bad), "--t-final", "0.2", "--json"]) == 1
    text = capsys.readouterr().out
    data = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert data["plant_comparison"]["model_exchange"]["max_abs_error"] is None
    assert "plant_comparison/model_exchange/max_abs_error" in data["non_finite_values"]["paths"]
    assert "not a finite number" in data["non_finite_values"]["meaning"]


def test_check_refuses_a_huge_run_before_it_starts(models, capsys):
    with pytest.raises(BudgetError, match=r"t_final = 1e\+09 s \(--t-final\).*gives 1e\+11 steps"):
        check_fmu(models["oscillator"], t_final=1e9)
    assert dobkit_main(["fmu", "check", str(models["oscillator"]), "--t-final", "1e9"]) == 2
    assert "--max-steps" in capsys.readouterr().err


# --- archives and descriptions -------------------------------------------------------------------------------

def repack(src: Path, dst: Path, extra_entries=(), replace=None) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            zout.writestr(info, (replace or {}).get(info.filename, zin.read(info.filename)))
        for name, data in extra_entries:
            zout.writestr(zipfile.ZipInfo(name), data)
    return dst


def test_duplicated_directory_entries_are_accepted_and_duplicated_files_refused(models, tmp_path):
    with pytest.warns(UserWarning, match="Duplicate name"):          # zipfile warns while writing them
        dirs = repack(models["spring"], tmp_path / "dirs.fmu", [("binaries/", b""), ("binaries/", b""),
                                                                  ("sources/", b""), ("sources/", b"")])
    with load(dirs) as spring:
        assert spring.noutputs == 2
    with pytest.warns(UserWarning, match="Duplicate name"):
        files = repack(models["spring"], tmp_path / "files.fmu", [("sources/spring.c", b"int x;")])
    with pytest.raises(FMUArchiveError, match="name the same file"):
        extract_fmu(files)


def test_an_oversized_description_is_refused_before_parsing(models, tmp_path):
    with pytest.raises(FMUArchiveError, match=r"modelDescription.xml has \d+ bytes, more than the limit of 1000 "
                                              r"\(ExtractionLimits.max_description_size\)"):
        load(models["mass"], limits=ExtractionLimits(max_description_size=1000))
    xml = zipfile.ZipFile(models["mass"]).read("modelDescription.xml").decode()
    noise = np.random.default_rng(0).bytes(2 ** 20).hex()     # 2 MiB of text that does not compress much
    commented = xml.replace("<ModelVariables>", "<!-- " + noise + " -->\n  <ModelVariables>")
    big = repack(models["mass"], tmp_path / "comment.fmu", replace={"modelDescription.xml": commented.encode()})
    line = xml[:xml.index("<ModelVariables>")].count("\n") + 1
    with pytest.raises(FMUModelDescriptionError, match=rf"a comment of \d+ bytes \(line {line}\), more than the limit "
                                                       r"of 1048576 \(ExtractionLimits.max_description_token\)"):
        load(big)
    described = xml.replace('description="point mass', 'description="' + noise)
    big = repack(models["mass"], tmp_path / "attribute.fmu", replace={"modelDescription.xml": described.encode()})
    with pytest.raises(FMUModelDescriptionError, match="an attribute value or text of more than 1048576 bytes"):
        load(big)


CRASH_SCRIPT = """
import os, sys
from fmu import load
block = load(sys.argv[1], extract_to=sys.argv[2])
print(sorted(os.listdir(sys.argv[2])), flush=True)
os.abort()                      # as a crash inside FMU code would: no finalizer runs
"""


def test_extraction_folders_of_a_crashed_process_are_removed_at_the_next_start(models, tmp_path):
    parent = tmp_path / "extractions"
    parent.mkdir()
    child = subprocess.Popen([sys.executable, "-c", CRASH_SCRIPT, str(models["mass"]), str(parent)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    child.communicate(timeout=120)
    assert child.returncode != 0
    left = list(parent.iterdir())
    assert len(left) == 1 and left[0].name.startswith(f"dobkit-fmu-{child.pid}-")
    mine = parent / f"dobkit-fmu-{os.getpid()}-alive"            # a live process's folder stays
    mine.mkdir()
    with extract_fmu(models["mass"], parent=parent) as extracted:     # the next start
        assert sorted(p.name for p in parent.iterdir()) == sorted([extracted.root.name, mine.name])
    assert remove_stale_extractions(parent) == []


def test_an_adaptive_run_stops_at_its_evaluation_budget(models):
    from fmu import Budget
    # whichever adaptive run of the check (Model Exchange, simulate_fmu) reaches the budget first stops the check
    with pytest.raises(BudgetError, match=r"(Model Exchange run|simulate_fmu of oscillator.fmu): [0-9,]+ "
                                          r"right-hand-side evaluations by t = [0-9.e-]+ s.*more than the step budget "
                                          r"allows \(110 steps, 660 evaluations\)"):
        check_fmu(models["oscillator"], t_final=1.0, budget=Budget(steps=110))
    with pytest.raises(ValueError, match="a wall-time budget must be a positive number of seconds, got inf"):
        Budget(seconds=float("inf"))
