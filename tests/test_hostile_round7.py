"""Hostile inputs, round 7: what a careless or hostile user does to the newest features (URDF arms, FMUs of any
arm, local clusters, interrupts of the job commands), each held to a one-line refusal or a whole result.

docs/hostile-inputs.md, "Round 7", lists each case with its test.  The URDF files are the two-joint test arm
(tests/small_arms/two_joints.urdf) with one thing changed; pinocchio is the reference for what a file means.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks.arms.urdf import UnknownJointError, UnsupportedJointError, UrdfParseError, load_urdf_arm  # noqa: E402

TWO = (Path(__file__).parent / "small_arms" / "two_joints.urdf").read_text(encoding="utf-8")
ARM_LINK = '<mass value="1.2"/>'


def _dobkit(*args, cwd=None, env=None, timeout=600):
    return subprocess.run([sys.executable, "-m", "dobkit", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=timeout)


def _urdf(folder: Path, text: str, name: str = "arm.urdf") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def _changed(old: str, new: str) -> str:
    assert TWO.count(old) == 1, old
    return TWO.replace(old, new)


# --------------------------------------------------------------------------------------------
# URDF files: what urdfdom reads differently from what is written, and what dobkit cannot model
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["nan", "heavy", "inf", "1e400"])
def test_a_mass_urdfdom_cannot_read_is_refused_not_dropped(tmp_path, value):
    # urdfdom drops the whole <inertial> it cannot read, silently: the arm's 1.2 kg link became massless
    path = _urdf(tmp_path, _changed(ARM_LINK, f'<mass value="{value}"/>'))
    dropped = pin.buildModelFromUrdf(str(path))
    assert float(dropped.inertias[1].mass) == 0.0          # what pinocchio makes of it: the mass is gone
    with pytest.raises(UrdfParseError, match=rf"link 'arm' <inertial> <mass> value='{value}'; it must be 1 finite"):
        load_urdf_arm(path, "rod")


@pytest.mark.parametrize("old, new, says", [
    ('ixx="0.004"', 'ixx="big"', r"link 'arm' <inertial> <inertia> ixx='big'"),
    ('<origin xyz="0.1 0 0.02"/>', '<origin xyz="0.1 x 0.02"/>', r"link 'arm' <inertial> <origin> xyz='0.1 x 0.02'"),
    ('<mass value="1.2"/>', '', r"link 'arm' <inertial> has no <mass value=\.\.\.>"),
    ('<origin xyz="0 0 0.3" rpy="0 0 0"/>', '<origin xyz="0 0.3" rpy="0 0 0"/>',
     r"joint 'pitch' <origin> xyz='0 0.3'; it must be 3 finite numbers"),
    ('lower="-2"', 'lower="abc"', r"joint 'pitch' <limit> lower='abc'"),
], ids=["inertia", "inertial-origin", "no-mass", "joint-origin", "limit"])
def test_every_number_of_the_file_is_read_or_refused_by_element(tmp_path, old, new, says):
    with pytest.raises(UrdfParseError, match=says):
        load_urdf_arm(_urdf(tmp_path, _changed(old, new)), "rod")


def test_a_zero_axis_an_inverted_range_and_a_missing_limit_are_refused_by_joint(tmp_path):
    # a zero axis became a NaN gain ("'gains.observer' must be a finite number, got [[nan, ...") after a numpy warning
    with pytest.raises(UrdfParseError, match=r"joint 'pitch' <axis> xyz='0 0 0' has no direction"):
        load_urdf_arm(_urdf(tmp_path, _changed('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>')), "rod")
    # lower > upper was read as "no limits": the joint turned without end
    with pytest.raises(UrdfParseError, match=r"joint 'slide' <limit> lower=0.2 is above upper=-0.1"):
        load_urdf_arm(_urdf(tmp_path, _changed('lower="-0.1" upper="0.2"', 'lower="0.2" upper="-0.1"')), "rod")
    with pytest.raises(UrdfParseError, match=r"joint 'pitch' is revolute without <limit"):
        load_urdf_arm(_urdf(tmp_path, _changed('<limit lower="-2" upper="2" effort="10" velocity="2"/>', '')),
                      "rod")


def test_loops_two_roots_and_dangling_links_are_named_before_pinocchio(tmp_path):
    loop = TWO.replace("</robot>", '<joint name="back" type="fixed"><parent link="rod"/><child link="arm"/></joint>'
                                   "\n</robot>")
    with pytest.raises(UrdfParseError, match=r"link 'arm' is the child of joints 'pitch' and 'back'"):
        load_urdf_arm(_urdf(tmp_path, loop), "rod")
    two_roots = TWO.replace('<link name="base"/>', '<link name="base"/><link name="stand"/>')
    with pytest.raises(UrdfParseError, match=r"2 trees \(root links \['base', 'stand'\]\)"):
        load_urdf_arm(_urdf(tmp_path, two_roots), "rod")
    with pytest.raises(UrdfParseError, match=r"joint 'slide' has <child link='tip'>, which is not a link"):
        load_urdf_arm(_urdf(tmp_path, _changed('<child link="rod"/>', '<child link="tip"/>')), "rod")


def test_what_pinocchio_refuses_is_said_in_the_error_not_on_stderr(tmp_path, capfd):
    # an effort that is not a number: urdfdom's reason went to the process's stderr, the error said only
    # "does not contain a valid URDF model"
    path = _urdf(tmp_path, _changed('effort="10" velocity="2"', 'effort="lots" velocity="2"'))
    with pytest.raises(UrdfParseError, match=r"pinocchio cannot read URDF file .*effort.*lots") as err:
        load_urdf_arm(path, "rod")
    assert "at line" not in str(err.value)
    assert "Error" not in capfd.readouterr().err


def test_a_mimic_joint_is_refused_unless_locked_or_asked_for(tmp_path):
    # pinocchio reads <mimic> as a joint of its own: dobkit drove the mimicking joint freely
    text = _changed('<limit lower="-0.1" upper="0.2" effort="10" velocity="1"/>',
                    '<limit lower="-0.1" upper="0.2" effort="10" velocity="1"/><mimic joint="pitch" multiplier="0.1"/>')
    path = _urdf(tmp_path, text)
    with pytest.raises(UnsupportedJointError, match=r"joint 'slide' .* mimics joint 'pitch'.*lock it"):
        load_urdf_arm(path, "rod")
    assert load_urdf_arm(path, "arm", locked=["slide"], locked_values={"slide": 0.05}).joints.names == ("pitch",)
    assert load_urdf_arm(path, "rod", mimic="independent").n == 2


def test_locking_twice_everything_or_outside_the_range_by_default_is_named(tmp_path):
    path = _urdf(tmp_path, TWO)
    with pytest.raises(UnknownJointError, match=r"locked joint\(s\) \['slide'\] named more than once"):
        load_urdf_arm(path, "arm", locked=["slide", "slide"])       # pinocchio: "two identical indexes"
    with pytest.raises(UnknownJointError, match=r"holds every moving joint .* nothing is left to move"):
        load_urdf_arm(path, "arm", locked=["pitch", "slide"])       # "joint names () and kinds () must be ..."
    # a joint whose range excludes 0, locked without a value, was held at 0, outside its range
    shifted = _urdf(tmp_path, _changed('lower="-0.1" upper="0.2"', 'lower="0.05" upper="0.2"'), "shifted.urdf")
    with pytest.raises(UnknownJointError, match=r"'slide' at 0.0 \(the default; give its position: arm.locked_values, "
                                                r"or --locked NAME=VALUE on the command line\) is outside its range "
                                                r"0.05 to 0.2"):
        load_urdf_arm(shifted, "arm", locked=["slide"])
    arm = load_urdf_arm(shifted, "arm", locked=["slide"], locked_values={"slide": 0.1})
    assert arm.n == 1


def test_the_command_line_refuses_a_urdf_with_an_unreadable_mass_in_one_line(tmp_path):
    _urdf(tmp_path, _changed(ARM_LINK, '<mass value="nan"/>'))
    (tmp_path / "s.toml").write_text('name = "s"\n[arm]\nurdf = "arm.urdf"\ntool_frame = "rod"\n[gains]\nkp = 180\n'
                                     'kd = 36\nobserver_bandwidth = 10.0\n[trajectory]\nkind = "joint_sine"\n'
                                     '[simulation]\nt_final = 0.1\noutput_step = 0.01\n', encoding="utf-8")
    done = _dobkit("simulate", "--scenario", "s.toml", "--out", "o", "--no-figures", "--engine", "fast", cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "<mass> value='nan'" in lines[0] and "Traceback" not in done.stderr
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------------------------
# Plant FMUs of one arm co-simulated with another arm's scenario
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def plant_fmus(tmp_path_factory):
    """The paper's RRPR plant and scope4's, exported as they are by ``dobkit fmu export`` and ``--arm scope4``."""
    from blocks.arms import example_arm
    from fmu import export_plant
    folder = tmp_path_factory.mktemp("plants")
    return {"rrpr": export_plant(folder / "rrpr.fmu"), "scope4": export_plant(folder / "scope4.fmu",
                                                                              params=example_arm("scope4"))}


def _short(name: str, **changes):
    import blocks
    return blocks.load_scenario(name).with_changes({"simulation.t_final": 0.02, "simulation.output_step": 0.01}
                                                    | changes)


def test_the_paper_plant_fmu_is_not_run_as_another_arms_plant(plant_fmus, tmp_path):
    from fmu import FMUError, cosimulate
    # both have 4 joints: the scope4 scenario ran on the RRPR plant to "results written", exit 0
    with pytest.raises(FMUError, match=r"rrpr.fmu \(as the plant of the loop\): q\[2\] of the FMU ranges from 0 to "
                                       r"0.48 m; joint insertion of the arm of scenario 'scope4'.* from 0 to 0.2 m"):
        cosimulate(plant_fmus["rrpr"], _short("scope4"), step=1e-3, error_estimate=False)
    with pytest.raises(FMUError, match=r"q\[0\] of the FMU ranges from -1.2 to 1.2 rad; joint theta1 of the arm of "
                                       r"scenario 'paper', the paper's RRPR arm from -inf to inf rad"):
        cosimulate(plant_fmus["scope4"], _short("paper"), step=1e-3, error_estimate=False)
    done = _dobkit("fmu", "cosim", plant_fmus["rrpr"], "--scenario", "scope4", "--out", "o", "--no-figures",
                   cwd=tmp_path)
    assert done.returncode == 2 and "the FMU is not this arm's plant" in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_an_exported_arm_whose_bodies_differ_from_the_scenarios_is_refused_unless_its_own_are_asked_for(plant_fmus):
    from fmu import FMUError, cosimulate, load
    heavier = _short("scope4", **{"arm.gravity": 9.0})
    with pytest.raises(FMUError, match=r"whose gravity differs from the arm of scenario 'scope4'.*--parameters fmu"):
        cosimulate(plant_fmus["scope4"], heavier, step=1e-3, error_estimate=False)
    with pytest.raises(FMUError, match=r"as the true plant of scenario 'scope4'.*whose gravity differs"):
        load(plant_fmus["scope4"], scenario=heavier)
    # the FMU's own arm, asked for: runs; the scenario's own arm: runs and agrees with the monolithic loop
    own = cosimulate(plant_fmus["scope4"], heavier, step=1e-3, parameters="fmu", error_estimate=False)
    assert own.cosim["parameters"] == "fmu"
    same = _short("scope4")
    import blocks
    ref = blocks.simulate(same, engine="fast")
    got = cosimulate(plant_fmus["scope4"], same, step=1e-3, error_estimate=False)
    np.testing.assert_allclose(got.outputs[:4], ref.outputs[:4], atol=1e-6)


# --------------------------------------------------------------------------------------------
# Interrupts: no process or file of the command outlives it, and an interrupt is never called an error
# --------------------------------------------------------------------------------------------
def _processes_mentioning(text: str) -> list[str]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                line = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
            except OSError:
                continue
            if text in line:
                found.append(line[:120])
    return found


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="needs /proc to see the compiler's processes")
def test_sigterm_while_the_fmu_is_compiled_leaves_no_compiler_process_or_temporary_file(tmp_path):
    # the compiler's driver was killed, its cc1 ran on and left /tmp/cc*.s and cc*.o behind after "interrupted;
    # nothing partial was written"
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = dict(os.environ, TMPDIR=str(temp))
    proc = subprocess.Popen([sys.executable, "-m", "dobkit", "fmu", "export", "--arm", "scope4", "--out", "x.fmu"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not any("cc1" in p for p in _processes_mentioning(str(temp))):
        assert proc.poll() is None and time.monotonic() < deadline, "the compiler never ran"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "dobkit fmu: interrupted; nothing partial was written"
    time.sleep(1.0)                                    # what outlived the command has had time to write
    assert _processes_mentioning(str(temp)) == []
    assert sorted(p.name for p in temp.iterdir()) == []
    assert not (tmp_path / "x.fmu").exists()


def test_an_interrupt_while_a_module_makes_its_classes_is_not_reported_as_an_error(monkeypatch, capsys):
    # SIGTERM during `import scipy...` ended `dobkit fmu export` with "error: Error calling __set_name__ on
    # 'cached_property' instance 'nodes_and_weights' in 'GaussLegendreQuadrature'" and exit 2 (Python 3.11 wraps
    # an exception of __set_name__ in RuntimeError)
    import dobkit.cli

    class Descriptor:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt("received signal SIGTERM")

    def command(args):
        type("Quadrature", (), {"nodes_and_weights": Descriptor()})     # what an import does when it makes a class
        return 0
    monkeypatch.setattr(dobkit.cli, "_cmd_simulate", command)
    assert dobkit.cli.main(["simulate"]) == 130
    assert capsys.readouterr().err.strip() == "dobkit simulate: interrupted; nothing partial was written"


def test_an_interrupted_job_says_nothing_was_written_when_its_log_was_not_made(tmp_path, capsys):
    # "every finished run is kept in s-results.jsonl, and the same command resumes" with no such file
    import argparse

    from dobkit.job_commands import run_job
    args = argparse.Namespace(max_memory=None, max_steps=None, max_seconds=None)
    results = tmp_path / "s-results.jsonl"

    def body(args, budget, state):
        state["results"] = results
        raise KeyboardInterrupt
    assert run_job("sweep", args, body, (), "run", "results") == 130
    assert capsys.readouterr().err.strip() == "dobkit sweep: interrupted before any run finished; nothing was written"
    results.write_text("{}\n")
    assert run_job("sweep", args, body, (), "run", "results") == 130
    assert f"every finished run is kept in {results}" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Flags: what would be ignored, or read as a number Python cannot convert
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, says", [
    (["fmu", "export", "--tool-frame", "tip", "--out", "x.fmu"], "--tool-frame goes with --arm X.urdf"),
    (["fmu", "export", "--locked", "a,b", "--out", "x.fmu"], "--locked goes with --arm X.urdf"),
    (["fmu", "export", "--arm", "scope4", "--scenario", "paper", "--out", "x.fmu"],
     "--arm scope4 and --scenario paper both name the plant to export; give one"),
    (["fmu", "check", "x.fmu", "--arm", "rrpr", "--tool-frame", "tip"], "--tool-frame goes with --arm X.urdf"),
])
def test_fmu_flags_that_would_be_ignored_are_refused(tmp_path, monkeypatch, capsys, argv, says):
    # `fmu export --tool-frame tip` exported the paper's plant, the flag ignored; `--arm X --scenario Y` exported X
    from dobkit.cli import main
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dobkit fmu: error: ") and says in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.fmu").exists()


@pytest.mark.parametrize("address", ["local:\u00b2", "local:\u0663"])
def test_a_local_worker_count_in_other_digits_is_refused_naming_the_flag(address):
    # 'local:²' passed str.isdigit and failed in int(): "invalid literal for int() with base 10: '²'"
    from analysis.jobs.cluster import local_workers
    with pytest.raises(ValueError, match=r"--scheduler 'local:.': the number of local worker processes must be a "
                                         r"whole number >= 1"):
        local_workers(address)


# --------------------------------------------------------------------------------------------
# A tuning's results: whole or not at all
# --------------------------------------------------------------------------------------------
TUNING = """
name = "tiny"
scenario = "base.toml"
objective = "worst"
[search]
"gains.kp" = [100, 400]
seed = 1
population = 5
max_evaluations = 13
polish_evaluations = 2
[monte_carlo]
runs = 2
seed = 1
[monte_carlo.distributions]
"nominal_scale.m1" = {kind = "choice", values = [0.9, 1.1]}
"""


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    """A tiny tuning of the paper scenario's first 0.2 s, run once to the end: (tuning file, output folder)."""
    import blocks
    from analysis.tune.runner import run_tune
    folder = tmp_path_factory.mktemp("tiny-tune")
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 0.2}, trajectory={"duration": 10.0})
    (folder / "base.toml").write_text(base.to_toml(), encoding="utf-8")
    (folder / "tiny.toml").write_text(TUNING, encoding="utf-8")
    run_tune(folder / "tiny.toml", folder / "out", workers=1, progress=False, engine="fast")
    return folder / "tiny.toml", folder / "out"


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_an_interrupt_while_a_tuning_writes_its_results_leaves_the_previous_results_or_none(tuned, monkeypatch):
    # Ctrl-C or SIGTERM after the figures, before tune.json: the tuned scenario file and the figures were left
    # without tune.json (or beside the previous run's tune.json)
    import analysis.tune.report
    from analysis.tune.runner import LOG_NAME, run_tune
    path, out = tuned
    whole = _files(out)
    assert {"tune.json", "paper-tuned.toml", "figures/tune_history.png", LOG_NAME} <= set(whole)
    real = analysis.tune.report.write_figures

    def drawn_then_interrupted(*args, **kwargs):
        real(*args, **kwargs)
        raise KeyboardInterrupt("received signal SIGTERM")
    monkeypatch.setattr(analysis.tune.report, "write_figures", drawn_then_interrupted)
    with pytest.raises(KeyboardInterrupt):                 # resumed from the log: straight to the results
        run_tune(path, out, workers=1, progress=False, engine="fast")
    assert _files(out) == whole                            # the previous results, byte for byte, and nothing else
    shutil.rmtree(out / "figures")                        # only the evaluations left: the first writing of results
    (out / "tune.json").unlink()
    (out / "paper-tuned.toml").unlink()
    with pytest.raises(KeyboardInterrupt):
        run_tune(path, out, workers=1, progress=False, engine="fast")
    assert [p.name for p in out.iterdir()] == [LOG_NAME]  # no tuned file, figure or staging folder
    monkeypatch.setattr(analysis.tune.report, "write_figures", real)
    run_tune(path, out, workers=1, progress=False, engine="fast")
    again = _files(out)
    assert set(again) == set(whole)
    assert again["paper-tuned.toml"] == whole["paper-tuned.toml"]


# --------------------------------------------------------------------------------------------
# A sweep's summary folder: the CI race of the output folders (7315085), in the summary's own staging
# --------------------------------------------------------------------------------------------
SUMMARY_HEADER = {"name": "h", "runs": 3, "worst_metric": "max_tool_position_error_mm", "worst_count": 3}
SUMMARY_ROWS = [{"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": 100.0 + i}, "status": "ok",
                 "metrics": {"max_tool_position_error_mm": 1.0 + i, "rms_position_error": [1e-4] * 4}}
                for i in range(3)]


@pytest.mark.parametrize("previous", [False, True], ids=["first summary", "over a previous summary"])
def test_an_interrupt_as_the_summarys_staging_folder_is_made_leaves_nothing_of_it(tmp_path, monkeypatch, previous):
    # Ctrl-C or SIGTERM after mkdtemp made '.NAME.partial-XXXX' and before its name came back: the folder stayed
    from analysis.sweep.summary import write_summary
    out = tmp_path / "s-summary"
    if previous:
        write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    before = _files(tmp_path)
    real = os.mkdir

    def made_then_interrupted(path, *args, **kwargs):
        real(path, *args, **kwargs)
        if ".partial-" in os.fspath(path):
            raise KeyboardInterrupt("received signal SIGTERM")
    monkeypatch.setattr(os, "mkdir", made_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    monkeypatch.setattr(os, "mkdir", real)
    assert _files(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == (["s-summary"] if previous else [])
    files = write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    assert files["json"] == out / "summary.json" and files["json"].is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s-summary"]


def test_a_scenario_with_a_relative_urdf_path_changes_after_the_working_folder_does(tmp_path, monkeypatch):
    # scenario_from_dict with urdf = "arm.urdf" read the file; after os.chdir, with_changes read the user's data
    # again, relative to the new folder: "URDF file 'arm.urdf' does not exist"
    import blocks
    _urdf(tmp_path, TWO)
    data = {"arm": {"urdf": "arm.urdf", "tool_frame": "rod"}, "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
            "trajectory": {"kind": "joint_sine"}, "simulation": {"t_final": 0.1, "output_step": 0.01}}
    monkeypatch.chdir(tmp_path)
    s = blocks.scenario_from_dict(data)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    changed = s.with_changes({"gains.kp": 100})
    assert changed.robot is s.robot and float(changed.kp[0, 0]) == 100.0
    assert changed.data["arm"]["urdf"] == str(tmp_path / "arm.urdf")
    with pytest.raises(blocks.ScenarioError, match=r"URDF file .*other.urdf' does not exist"):
        s.with_changes({"arm.urdf": "other.urdf"})      # a path given now is relative to the folder of now


DRAWS = '[monte_carlo.distributions]\n"disturbance.f_r[0]" = {kind = "uniform", low = 0.01, high = 0.1}\n'


def test_tuning_y_of_a_scenario_that_sets_the_observer_bandwidth_is_refused_when_the_file_is_read(tmp_path):
    # scope4 gives Y as 'gains.observer_bandwidth': every candidate of a search over gains.observer was refused,
    # the first as "variant 0: ... 'gains.observer' (50.0) and 'gains.observer_bandwidth' (10.0 rad/s) both set ..."
    from analysis.tune.spec import TuneError, load_tuning
    path = tmp_path / "t.toml"
    path.write_text('scenario = "scope4"\n[search]\n"gains.kp" = [50, 400]\n"gains.observer" = [1, 50]\n'
                    '[monte_carlo]\nruns = 2\n' + DRAWS, encoding="utf-8")
    with pytest.raises(TuneError, match=r"search.\"gains.observer\" tunes Y, which the scenario 'scope4' sets through "
                                        r"'gains.observer_bandwidth' \(10 rad/s"):
        load_tuning(path)
    path.write_text('scenario = "scope4"\n[search]\n"gains.kp" = [50, 400]\n[monte_carlo]\nruns = 2\n' + DRAWS,
                    encoding="utf-8")
    assert [p.key for p in load_tuning(path).parameters] == ["gains.kp"]


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


def test_a_urdf_given_as_the_scenario_says_where_a_urdf_goes(tmp_path):
    # `dobkit simulate --scenario arm.urdf` said "not valid TOML: Invalid statement (at line 1, column 1)"
    _urdf(tmp_path, TWO)
    done = _dobkit("simulate", "--scenario", "arm.urdf", "--no-figures", cwd=tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip() == ("dobkit simulate: error: arm.urdf is an XML or URDF file, not a scenario (TOML); a "
                                   "URDF arm is named in a scenario's [arm] section: urdf = \"...\", tool_frame = "
                                   "\"...\"")


def test_an_interrupted_tunings_progress_says_its_stage_stopped(tuned, monkeypatch, capsys):
    # "tuning: writing results: done, took 2.6 s" was printed above "dobkit tune: interrupted"
    import analysis.tune.report
    from analysis.tune.runner import run_tune
    path, out = tuned

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(analysis.tune.report, "write_figures", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_tune(path, out, workers=1, progress=True, engine="fast")
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("tuning: writing results: stopped after ")
    assert not any(line.startswith("tuning: writing results: done") for line in lines)


def test_fmu_export_locks_a_joint_at_a_position_given_on_the_command_line(tmp_path, capsys):
    # --locked took names only: a joint whose range excludes 0 could not be locked from the command line
    from dobkit.cli import main
    path = _urdf(tmp_path, _changed('lower="-0.1" upper="0.2"', 'lower="0.05" upper="0.2"'))
    out = tmp_path / "x.fmu"
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide", "--out",
                 str(out)]) == 2
    assert "--locked NAME=VALUE" in capsys.readouterr().err and not out.exists()
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide=x", "--out",
                 str(out)]) == 2
    assert "--locked 'slide=x': the position after '=' must be a number" in capsys.readouterr().err
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide=0.1", "--out",
                 str(out)]) == 0
    assert "arm 1 joints ['pitch']" in capsys.readouterr().out
    # the record in the FMU is the arm with the slide held at 0.1 m: the rod's centre of mass then sits 0.1 m
    # further along the slide's axis (0.8, 0, -0.6) in the arm's frame, so the pitch inertia is pinocchio's
    import zipfile

    from fmu.arm_record import ARM_RECORD, arm_from_record
    recorded = arm_from_record(zipfile.ZipFile(out).read(ARM_RECORD).decode("utf-8"))
    reference = load_urdf_arm(path, "arm", locked=["slide"], locked_values={"slide": 0.1})
    model = reference.pin_model
    data = model.createData()
    q = np.array([0.3])
    np.testing.assert_allclose(recorded.inertia(q), pin.crba(model, data, q), rtol=1e-12)


# --------------------------------------------------------------------------------------------
# Arms of other joint counts than the paper's 4: one joint, six joints
# --------------------------------------------------------------------------------------------
def test_tuning_a_six_joint_arm_without_a_noise_section_takes_the_arms_own_default_noise(tmp_path):
    # the paper's 4-joint default sensor noise was taken for any arm: tuning the UR5 (or the Panda) stopped with
    # "matmul: Input operand 1 has a mismatch in its core dimension 0 ... (size 8 is different from 12)"
    import blocks
    from analysis.simulation.studies import default_noise
    from analysis.tune.evaluate import Evaluator
    from analysis.tune.linear import torque_noise_rms
    from analysis.tune.runner import check_linear_feasibility
    from analysis.tune.spec import load_tuning
    ur5 = blocks.load_scenario("ur5").with_changes({"simulation.t_final": 0.2})
    assert ur5.noise is None
    (tmp_path / "ur5.toml").write_text(ur5.to_toml(), encoding="utf-8")
    path = tmp_path / "t.toml"
    path.write_text('scenario = "ur5.toml"\n[search]\n"gains.kp" = [50, 400]\n[monte_carlo]\nruns = 2\n' + DRAWS,
                    encoding="utf-8")
    spec = load_tuning(path)
    expected = default_noise(ur5.robot.joints)            # six revolute joints: the revolute default six times
    assert spec.limits.sensor_noise["q_std"] == expected["q_std"] and len(expected["q_std"]) == 6
    assert len(set(expected["q_std"])) == 1 and len(set(expected["dq_std"])) == 1
    check_linear_feasibility(spec, Evaluator(spec, workers=1, engine="fast"))      # the matmul error was here
    q0 = np.asarray(ur5.trajectory.evaluate(0.0)[0])
    M, M_hat = ur5.robot.inertia(q0), ur5.nominal.inertia(q0)
    rms = torque_noise_rms(M, M_hat, ur5.kp, ur5.kd, ur5.observer_gain, expected["q_std"], expected["dq_std"], 0.001)
    assert rms.shape == (6,) and np.all(np.isfinite(rms)) and np.all(rms > 0)


def test_a_one_joint_arm_is_analysed(tmp_path):
    # `dobkit analyze` of a one-joint arm: "error: f(a) and f(b) must have different signs" (the mismatch search
    # re-evaluated its bracket's ends one ulp off, where a loop without a resting position jumps), then an
    # IndexError traceback (python-control squeezes the SISO response of the loop without the observer)
    import blocks
    from analysis.report.build import run_analysis
    one = TWO.replace('<joint name="slide"', '<joint name="slide_unused"').split('<joint name="slide_unused"')[0]
    one += '<joint name="tip_joint" type="fixed"><parent link="arm"/><child link="tip"/><origin xyz="0.3 0 0"/>' \
           '</joint><link name="tip"/></robot>\n'
    _urdf(tmp_path, one)
    s = blocks.scenario_from_dict({"arm": {"urdf": str(tmp_path / "arm.urdf"), "tool_frame": "tip",
                                           "nominal_mass_scale": 1.05},
                                   "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
                                   "trajectory": {"kind": "joint_sine", "amplitude": [0.3], "omega": [1.0],
                                                  "offset": [0.1]},
                                   "disturbance": {"kind": "step", "f_r": [0.1]},
                                   "simulation": {"t_final": 0.5, "output_step": 0.01}})
    assert s.robot.n == 1
    result = run_analysis(s)
    f = result.frequency
    # without the observer, w -> e is 1 / (M s^2 + M^ kd s + M^ kp + gravity's stiffness); at 1000 rad/s the
    # gravity term (about 0.06 N m/rad) is 3e-6 of M w^2, so the magnitude there is pinocchio's M and the gains'
    model = s.robot.pin_model
    M = float(pin.crba(model, model.createData(), np.asarray(f.q0))[0, 0])
    w = np.asarray(f.omega_rad_s)
    expected = 1.0 / abs(-M * w ** 2 + 1j * 1.05 * M * 36.0 * w + 1.05 * M * 180.0)
    assert w[-1] == 1000.0 and len(f.tracking_without_dob.magnitude) == 1
    assert f.tracking_without_dob.magnitude[0][-1] == pytest.approx(expected[-1], rel=1e-4)
    assert len(f.tracking_with_dob.magnitude) == 1 and len(f.estimation_with_dob.magnitude) == 1
    without = result.mismatch.without_dob.boundaries
    scan = without.scan
    for boundary in without.boundaries:                     # each boundary lies between scan points of both signs
        k = np.searchsorted(scan.factors, boundary.factor)
        assert (scan.spectral_abscissa[k - 1] < 0) != (scan.spectral_abscissa[k] < 0)


def test_a_two_joint_arms_digital_controller_is_cosimulated_against_its_plant_fmu(tmp_path):
    # the sampled co-simulation named its signals for the paper's 4 joints: a 2-joint arm with [controller]
    # ended in a KeyError: 'q[2]' traceback from `dobkit fmu cosim`
    import blocks
    from fmu import cosimulate, export_plant
    _urdf(tmp_path, TWO)
    s = blocks.scenario_from_dict({"arm": {"urdf": str(tmp_path / "arm.urdf"), "tool_frame": "rod",
                                           "nominal_mass_scale": 1.05},
                                   "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
                                   "trajectory": {"kind": "joint_sine"},
                                   "disturbance": {"kind": "step", "f_r": [0.1, 0.1]},
                                   "controller": {"sample_rate": 1000},
                                   "simulation": {"t_final": 0.2, "output_step": 0.01}})
    q0 = s.trajectory.evaluate(0.0)[0]
    plant = export_plant(tmp_path / "two.fmu", s.robot, disturbance=s.disturbance, q0=q0)
    got = cosimulate(plant, s, step=1e-3)
    ref = blocks.simulate(s, engine="fast")                 # the monolithic sampled loop
    for name in ("q[0]", "q[1]", "tau[0]", "tau[1]"):
        i, j = list(got.output_labels).index(name), list(ref.output_labels).index(name)
        np.testing.assert_allclose(got.outputs[i], ref.outputs[j], rtol=0, atol=1e-9)


def test_the_compiled_sampled_batch_measures_every_joint_of_the_arm(tmp_path):
    # simulate_sampled_batch measured the errors of the paper's 4 joints by name: a 2-joint arm failed
    # ("'q_ref[2]' is not in list"), a 6-joint arm's RMS errors held only its first 4 joints
    import blocks
    pytest.importorskip("numba")
    from blocks.compiled import simulate_sampled_batch
    _urdf(tmp_path, TWO)
    s = blocks.scenario_from_dict({"arm": {"urdf": str(tmp_path / "arm.urdf"), "tool_frame": "rod"},
                                   "gains": {"kp": 180, "kd": 36, "observer_bandwidth": 10.0},
                                   "trajectory": {"kind": "joint_sine"},
                                   "disturbance": {"kind": "step", "f_r": [0.1, 0.1]},
                                   "controller": {"sample_rate": 1000},
                                   "simulation": {"t_final": 0.2, "output_step": 0.01}})
    variants = [s, s.with_changes({"gains.kp": 100})]
    result = simulate_sampled_batch(s, variants=variants)
    assert result.rms_error.shape == (2, 2)
    for m, member in enumerate(variants):                   # each member's own run on the numpy engine
        ref = blocks.simulate(member, engine="fast")
        labels = list(ref.output_labels)
        e = np.array([ref.outputs[labels.index(f"q_ref[{i}]")] - ref.outputs[labels.index(f"q[{i}]")]
                      for i in range(2)])
        np.testing.assert_allclose(result.rms_error[m], np.sqrt(np.mean(e ** 2, axis=1)), rtol=1e-9)


def test_the_file_checks_refuse_no_urdf_of_example_robot_data_that_pinocchio_reads():
    # the checks added in this round (numbers, tree, limits, axes) must not refuse real arms' files
    from blocks.arms.examples import example_urdf
    from blocks.arms.urdf import UrdfError, _read_urdf
    robots = example_urdf("ur5").parents[2]                # .../example-robot-data/robots
    files = sorted(robots.rglob("*.urdf"))
    assert len(files) > 20
    read = 0
    for path in files:
        try:
            pin.buildModelFromUrdf(str(path))
        except (RuntimeError, ValueError):
            continue
        try:
            _read_urdf(path)
        except UnsupportedJointError:                      # a joint type dobkit does not model: refused as before
            continue
        except UrdfError as err:
            pytest.fail(f"{path.relative_to(robots)} is read by pinocchio but refused: {err}")
        read += 1
    assert read > 20
