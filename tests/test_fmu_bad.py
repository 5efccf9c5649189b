"""Bad FMUs: every case gives a clear FMUError, and nothing is written outside the extraction folder.

Each test extracts under its own ``sandbox`` folder (``extract_to``) and checks
afterwards that the sandbox is empty again (the private extraction folder was
removed) and that nothing appeared beside it.
"""
from __future__ import annotations

import re
import stat
import sys
import tempfile
import zipfile
from pathlib import Path

import control as ct
import fmpy
import numpy as np
import pytest
from conftest import make_scenario

from fmu import (
    CoSimulationError,
    ExtractionLimits,
    FMUArchiveError,
    FMUError,
    FMUInstance,
    FMUInstantiationError,
    FMUMissingVariablesError,
    FMUModelDescriptionError,
    FMUPlatformError,
    FMUStepError,
    FMUUnsupportedError,
    FMUVersionError,
    check_fmu,
    cosimulate,
    cosimulate_system,
    export_plant,
    extract_fmu,
    load,
    require_variables,
)
from fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    folder = tmp_path_factory.mktemp("good")
    lag_xml = (LAG_DIR / "modelDescription.xml").read_text()
    return {
        2: export_plant(folder / "plant2.fmu", fmi_version=2),
        3: export_plant(folder / "plant3.fmu", fmi_version=3),
        "lag": package_fmu(folder / "lag.fmu", lag_xml, {"lag.c": LAG_DIR / "lag.c"}, ["lag.c"], "lag", 2),
    }


@pytest.fixture
def sandbox(tmp_path, private_temp_folder):
    """An extraction parent inside a watched folder; asserts both are clean after the test.

    The test's own temporary folder (conftest) must stay clean too: an extraction that
    ignored ``extract_to`` would land there.  Only this test writes to it, so other
    processes loading FMUs at the same time cannot disturb the check.
    """
    watched = tmp_path / "watched"
    box = watched / "sandbox"
    box.mkdir(parents=True)
    assert tempfile.gettempdir() == str(private_temp_folder)
    yield box
    assert list(box.iterdir()) == [], "the private extraction folder was not removed"
    assert [p.name for p in watched.iterdir()] == ["sandbox"], "something was written beside the sandbox"
    assert list(private_temp_folder.glob("dobkit-fmu-*")) == [], "an extraction went to the temporary folder"


def rewrite(src: Path, dst: Path, replace: dict | None = None, drop=(), add: dict | None = None) -> Path:
    """Copy an FMU, replacing, dropping or adding entries (content as bytes or str)."""
    replace = replace or {}
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            if info.filename in drop:
                continue
            data = replace.get(info.filename, zin.read(info.filename))
            zout.writestr(info.filename, data.encode() if isinstance(data, str) else data)
        for name, data in (add or {}).items():
            zout.writestr(name, data.encode() if isinstance(data, str) else data)
    return dst


def model_xml(path: Path) -> str:
    return zipfile.ZipFile(path).read("modelDescription.xml").decode()


# --- the archive ------------------------------------------------------------------------------------------

def test_not_a_zip(tmp_path, sandbox):
    bad = tmp_path / "plant.fmu"
    bad.write_text("this is not a zip file")
    with pytest.raises(FMUArchiveError, match="not a zip archive"):
        load(bad, extract_to=sandbox)


def test_missing_file(tmp_path, sandbox):
    with pytest.raises(FMUArchiveError, match="no such file"):
        load(tmp_path / "absent.fmu", extract_to=sandbox)


@pytest.mark.parametrize("entry, words", [
    ("../escaped.txt", "parent folder"),
    ("resources/../../escaped.txt", "parent folder"),
    ("ABSOLUTE", "absolute path"),
    ("..\\escaped.txt", "backslash"),
    ("C:/escaped.txt", "drive letter"),
    ("resources/a:stream", "colon"),
])
@pytest.mark.needs_cc
def test_entries_escaping_the_folder_are_refused(good, tmp_path, sandbox, entry, words):
    target = tmp_path / "watched" / "escaped.txt"
    if entry == "ABSOLUTE":
        entry = str(target)
    bad = rewrite(good[2], tmp_path / "bad.fmu", add={entry: "escape attempt"})
    with pytest.raises(FMUArchiveError, match=words) as err:
        load(bad, extract_to=sandbox)
    assert repr(entry)[1:-1] in str(err.value) or entry in str(err.value)
    assert not target.exists() and not (tmp_path / "escaped.txt").exists()


@pytest.mark.needs_cc
def test_symbolic_link_entry_is_refused(good, tmp_path, sandbox):
    bad = tmp_path / "bad.fmu"
    rewrite(good[2], bad)
    with zipfile.ZipFile(bad, "a") as zf:
        info = zipfile.ZipInfo("resources/link")
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, "/etc/passwd")
    with pytest.raises(FMUArchiveError, match="symbolic link"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_total_size_limit(good, sandbox):
    with pytest.raises(FMUArchiveError, match="uncompressed size exceeds the limit of 20000 bytes"):
        load(good[2], extract_to=sandbox, limits=ExtractionLimits(max_total_size=20_000))


@pytest.mark.needs_cc
def test_compression_ratio_limit(good, tmp_path, sandbox):
    bomb = rewrite(good[2], tmp_path / "bomb.fmu", add={"resources/zeros.bin": bytes(4 * 2 ** 20)})
    with pytest.raises(FMUArchiveError, match=r"resources/zeros.bin.*expands \d+-fold.*zip bomb"):
        load(bomb, extract_to=sandbox)


@pytest.mark.needs_cc
def test_many_small_entries_adding_up_to_a_bomb_are_refused_before_extraction(good, tmp_path, sandbox):
    """Each entry (256 KiB of zeros) is below the per-entry ratio threshold; together they expand ~1000-fold."""
    bomb = rewrite(good[2], tmp_path / "bomb.fmu", add={f"resources/z{i}.bin": bytes(2 ** 18) for i in range(40)})
    with zipfile.ZipFile(bomb) as zf:
        infos = zf.infolist()
        assert all(i.file_size <= ExtractionLimits().ratio_min_size for i in infos)
        total, packed = sum(i.file_size for i in infos), sum(i.compress_size for i in infos)
    assert total / packed > 100                        # the aggregate ratio, computed here from the archive
    with pytest.raises(FMUArchiveError, match=r"expands \d+-fold as a whole .* more than the limit of 100"):
        extract_fmu(bomb, parent=sandbox)
    assert list(sandbox.iterdir()) == []               # refused before any folder was made


@pytest.mark.needs_cc
def test_a_normal_fmu_is_well_below_the_aggregate_ratio(good):
    for key in (2, 3, "lag"):
        with zipfile.ZipFile(good[key]) as zf:
            infos = zf.infolist()
        assert sum(i.file_size for i in infos) / sum(i.compress_size for i in infos) < 10


def test_a_directory_is_not_an_fmu(tmp_path, sandbox):
    folder = tmp_path / "plant.fmu"
    folder.mkdir()
    with pytest.raises(FMUArchiveError, match="plant.fmu: is a directory, not an FMU file"):
        load(folder, extract_to=sandbox)


@pytest.mark.needs_cc
def test_too_many_entries(good, tmp_path, sandbox):
    many = rewrite(good[2], tmp_path / "many.fmu", add={f"resources/f{i}.txt": "x" for i in range(30)})
    with pytest.raises(FMUArchiveError, match="entries, more than the limit of 20"):
        extract_fmu(many, limits=ExtractionLimits(max_entries=20), parent=sandbox)


# --- the model description --------------------------------------------------------------------------------

@pytest.mark.needs_cc
def test_missing_model_description(good, tmp_path, sandbox):
    bad = rewrite(good[2], tmp_path / "bad.fmu", drop=("modelDescription.xml",))
    with pytest.raises(FMUModelDescriptionError, match="no modelDescription.xml"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_malformed_model_description(good, tmp_path, sandbox):
    xml = model_xml(good[2])
    bad = rewrite(good[2], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml[: len(xml) // 2]})
    with pytest.raises(FMUModelDescriptionError, match="not well-formed XML"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_schema_invalid_model_description(good, tmp_path, sandbox):
    xml = model_xml(good[2]).replace('causality="input"', 'causality="sideways"', 1)
    bad = rewrite(good[2], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    with pytest.raises(FMUModelDescriptionError, match="invalid|cannot be read"):
        load(bad, extract_to=sandbox)


@pytest.mark.parametrize("version", ["1.0", "3.5", "4.0"])
@pytest.mark.needs_cc
def test_unsupported_fmi_version(good, tmp_path, sandbox, version):
    xml = model_xml(good[2]).replace('fmiVersion="2.0"', f'fmiVersion="{version}"')
    bad = rewrite(good[2], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    with pytest.raises(FMUVersionError, match=rf"unsupported FMI version '{version}' \(supported: 2.0, 3.0\)"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_check_fmu_names_an_unsupported_fmi_version(good, tmp_path):
    xml = model_xml(good[3]).replace('fmiVersion="3.0"', 'fmiVersion="3.5"')
    bad = rewrite(good[3], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    report = check_fmu(bad)            # reported, not raised: the check never aborts on the FMU's problems
    assert report["fmi_version"] == "3.5" and report["passed"] is False
    failed = [s for s in report["stages"] if s["stage"] == "model_description"][0]
    assert failed["status"] == "failed" and "unsupported FMI version '3.5'" in failed["why"]


@pytest.mark.needs_cc
def test_check_fmu_reports_schema_problems_instead_of_raising(good, tmp_path):
    xml = model_xml(good[2]).replace('causality="input"', 'causality="sideways"', 1)
    bad = rewrite(good[2], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    report = check_fmu(bad)
    assert report["passed"] is False and report["validation"]["passed"] is False
    assert any("sideways" in p for p in report["validation"]["problems"])
    assert "model description is invalid" in report["model_exchange"]["skipped"]


# --- outside the supported subset -------------------------------------------------------------------------

_E_REAL = 'causality="output" variability="continuous" initial="calculated">\n      <Real/>'
_E_INTEGER = 'causality="output" variability="discrete" initial="calculated">\n      <Integer/>'


@pytest.mark.parametrize("old, new, words", [
    (_E_REAL, _E_INTEGER, r"inputs/outputs that are not Real/Float64: e \(Integer\)"),
])
@pytest.mark.needs_cc
def test_fmi2_features_outside_the_subset_are_refused_at_load(good, tmp_path, sandbox, old, new, words):
    xml = model_xml(good["lag"])
    assert old in xml
    bad = rewrite(good["lag"], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml.replace(old, new, 1)})
    with pytest.raises(FMUUnsupportedError, match=words):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_fmi3_array_input_is_refused_at_load(good, tmp_path, sandbox):
    xml = model_xml(good[3])
    start = xml.index('<Float64 name="tau[0]"')
    end = xml.index("/>", start)
    xml = xml[:start] + xml[start:end] + '><Dimension start="2"/></Float64>' + xml[end + 2:]
    bad = rewrite(good[3], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    with pytest.raises(FMUUnsupportedError, match=r"array variables \(FMI 3 'dimensions'\): tau\[0\]"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_time_event_announced_at_load_makes_an_event_block(tmp_path, sandbox):
    """The lag compiled with LAG_TIME_EVENT announces a time event at t = 1 s during initialization (and again
    after it, which the numpy engine refuses: tests/test_fmu_events_loop.py)."""
    variant = package_fmu(tmp_path / "lag_te.fmu", (LAG_DIR / "modelDescription.xml").read_text(),
                          {"lag.c": LAG_DIR / "lag.c", "lag_te.c": '#define LAG_TIME_EVENT\n#include "lag.c"\n'},
                          ["lag_te.c"], "lag", 2)
    with load(variant, extract_to=sandbox) as block:
        assert block.event_source is not None and block.event_source.next_event_time == 1.0


@pytest.mark.needs_cc
def test_missing_interface(good, tmp_path, sandbox):
    xml = model_xml(good["lag"])
    start = xml.index("<CoSimulation")
    xml = xml[:start] + xml[xml.index("/>", start) + 2:]
    me_only = rewrite(good["lag"], tmp_path / "me_only.fmu", replace={"modelDescription.xml": xml})
    p_ctrl = ct.nlsys(None, lambda t, x, u, p: [-u[0]], inputs=["x"], outputs=["u"])
    with pytest.raises(FMUVersionError, match="does not offer CoSimulation"):
        cosimulate_system(me_only, p_ctrl, 0.1, 0.01, extract_to=sandbox)


# the plant's FMI 2 binary for this machine, named as fmpy looks for it
BINARY = f"binaries/{fmpy.platform}/dobkit_plant{fmpy.sharedLibraryExtension}"
OTHER_PLATFORM, OTHER_BINARY = (("win64", "binaries/win64/dobkit_plant.dll") if fmpy.platform != "win64"
                                else ("linux64", "binaries/linux64/dobkit_plant.so"))


@pytest.mark.needs_cc
def test_no_binary_for_this_platform(good, tmp_path, sandbox):
    with zipfile.ZipFile(good[2]) as zf:
        so = zf.read(BINARY)
    bad = rewrite(good[2], tmp_path / "bad.fmu", drop=(BINARY,),
                  add={OTHER_BINARY: so})
    with pytest.raises(FMUPlatformError, match=rf"{re.escape(BINARY)}.*\['{OTHER_PLATFORM}'\].*sources"):
        load(bad, extract_to=sandbox)


@pytest.mark.needs_cc
def test_corrupt_binary(good, tmp_path, sandbox):
    bad = rewrite(good[2], tmp_path / "bad.fmu", replace={BINARY: b"\x7fELF junk"})
    with pytest.raises(FMUError, match="cannot load the binary"):
        load(bad, extract_to=sandbox)


@pytest.mark.parametrize("version, word", [(2, "GUID"), (3, "instantiationToken")])
@pytest.mark.needs_cc
def test_token_mismatch_is_detected_at_instantiation(good, tmp_path, sandbox, version, word):
    xml = model_xml(good[version])
    attr = "guid" if version == 2 else "instantiationToken"
    start = xml.index(f'{attr}="') + len(attr) + 2
    xml = xml[:start] + "{11111111-2222-3333-4444-555555555555}" + xml[xml.index('"', start):]
    bad = rewrite(good[version], tmp_path / "bad.fmu", replace={"modelDescription.xml": xml})
    with pytest.raises(FMUInstantiationError, match=f"{word} mismatch.*11111111-2222") as err:
        load(bad, extract_to=sandbox)
    assert "do not belong to the same export" in str(err.value)


# --- variables and run-time errors ------------------------------------------------------------------------

@pytest.mark.needs_cc
def test_cosimulating_an_fmu_without_the_loop_variables(good, sandbox):
    scenario = make_scenario(simulation={"t_final": 0.1, "output_step": 0.01})
    with pytest.raises(FMUMissingVariablesError,
                       match=r"as the plant of the loop.*missing variable\(s\): q\[0\]") as err:
        cosimulate(good["lag"], scenario, step=0.01, extract_to=sandbox)
    assert "q[0]" in err.value.missing


@pytest.mark.needs_cc
def test_require_variables_suggests_close_names(good, sandbox):
    with FMUInstance(good[2], extract_to=sandbox) as fmu:
        require_variables(fmu.model_description, ["q[0]", "tau[3]"], source="plant")
        with pytest.raises(FMUMissingVariablesError, match=r"tau_dist\[1\] \(did you mean tau_dis\[1\]"):
            require_variables(fmu.model_description, ["tau_dist[1]"], source="plant")
        with pytest.raises(FMUMissingVariablesError, match="not of causality 'input'"):
            require_variables(fmu.model_description, ["q[0]"], causality="input", source="plant")


@pytest.mark.needs_cc
def test_cosimulation_refuses_an_output_step_that_is_not_a_multiple_of_h(good, sandbox):
    scenario = make_scenario(simulation={"t_final": 0.1, "output_step": 0.005})
    with pytest.raises(CoSimulationError, match=r"output step \(0.005 s\) is not a whole multiple of the "
                                                r"communication step h = 0.002 s"):
        cosimulate(good[2], scenario, step=0.002, extract_to=sandbox)


@pytest.mark.parametrize("kw, words", [({"q0": [0.1, 0.2, 0.3]}, "q0 must be 4 finite numbers"),
                                       ({"dq0": [0.0, float("nan"), 0.0, 0.0]}, "dq0 must be 4 finite numbers"),
                                       ({"q0": "abcd"}, "q0 must be 4 finite numbers")])
def test_export_checks_the_start_state(tmp_path, kw, words):
    with pytest.raises(ValueError, match=words):
        export_plant(tmp_path / "p.fmu", **kw)
    assert not (tmp_path / "p.fmu").exists()


@pytest.mark.needs_cc
def test_unknown_start_value(good, sandbox):
    with pytest.raises(FMUModelDescriptionError, match=r"unknown variable\(s\) \['mass1'\]"):
        load(good[2], start_values={"mass1": 1.0}, extract_to=sandbox)


@pytest.mark.needs_cc
def test_error_status_during_a_cosimulation_step(good, sandbox):
    """The lag reports an error once |x| > x_max: the master stops, names time and status, returns nothing."""
    T, h, x_max = 0.5, 0.01, 0.5
    push = ct.nlsys(None, lambda t, x, u, p: [1.0], inputs=["x"], outputs=["u"])
    with pytest.raises(FMUStepError, match=r"fmi2DoStep returned status 'error' at t = .*exceeds x_max") as err:
        cosimulate_system(good["lag"], push, 2.0, h, start_values={"T": T, "x_max": x_max}, extract_to=sandbox)
    t_cross = -T * np.log(1 - x_max)                # x(t) = 1 - exp(-t/T) reaches x_max here
    assert err.value.status == "error" and err.value.function == "fmi2DoStep"
    assert t_cross - h - 1e-9 <= err.value.time <= t_cross + 1e-9


@pytest.mark.needs_cc
def test_non_finite_torque_stops_the_master_and_fails_the_plant_step(good, sandbox):
    """A NaN torque: the master stops before handing it over, naming signal and time; the FMU refuses it too."""
    scenario = make_scenario(simulation={"t_final": 0.1, "output_step": 0.01})
    from fmu.cosim import controller_side
    side = controller_side(scenario)
    names = list(side.output_labels)
    bad_side = ct.nlsys(None, lambda t, x, u, p: np.where(np.array([n.startswith("tau[2") for n in names]) &
                                                          (t >= 0.05), np.nan, 0.0),
                        inputs=list(side.input_labels), outputs=names)
    with pytest.raises(CoSimulationError, match=r"output tau\[2\] = nan at t = 0.05 s is not finite"):
        cosimulate_system(good[3], bad_side, 0.1, 0.01, extract_to=sandbox)
    with FMUInstance(good[3], kind="CoSimulation", extract_to=sandbox) as inst:
        inst.set_real(inst.value_references(["tau[2]"]), [np.nan])
        with pytest.raises(FMUStepError, match=r"fmi3DoStep returned status 'error' at t = 0 s.*non-finite") as err:
            inst.do_step(0.0, 0.01)
    assert err.value.time == 0.0 and err.value.messages


@pytest.mark.needs_cc
def test_error_status_in_model_exchange(good, sandbox):
    """A Model Exchange evaluation with a non-finite input raises with the time of the call."""
    sys = load(good[2], extract_to=sandbox)
    with pytest.raises(FMUStepError, match=r"fmi2GetDerivatives returned status 'error' at t = 0.3 s"):
        sys._rhs(0.3, np.zeros(8), np.array([0.0, np.inf, 0.0, 0.0]))
    sys.fmu.close()


# --- one extraction per command ---------------------------------------------------------------------------

_EXTRACTIONS: list[str] | None = None


def _watch_extractions(event: str, args) -> None:
    # an audit hook (it cannot be removed): records extraction folders while a test switches it on
    if _EXTRACTIONS is not None and event == "tempfile.mkdtemp" and Path(args[0]).name.startswith("dobkit-fmu-"):
        _EXTRACTIONS.append(str(args[0]))


sys.addaudithook(_watch_extractions)


def count_extractions(run) -> int:
    global _EXTRACTIONS
    _EXTRACTIONS = []
    try:
        run()
        return len(_EXTRACTIONS)
    finally:
        _EXTRACTIONS = None


@pytest.mark.needs_cc
def test_each_command_extracts_the_fmu_once(good, tmp_path):
    from dobkit.cli import main as dobkit_main
    scenario = make_scenario(simulation={"t_final": 0.02, "output_step": 0.01})
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(scenario.to_toml())
    assert count_extractions(lambda: check_fmu(good[2], t_final=0.05)) == 1
    assert count_extractions(lambda: cosimulate(good[2], scenario, step=0.01)) == 1
    assert count_extractions(lambda: dobkit_main(["fmu", "cosim", str(good[3]), "--scenario", str(scenario_file),
                                                  "--step", "0.01", "--out", str(tmp_path / "run"),
                                                  "--no-figures"])) == 1
