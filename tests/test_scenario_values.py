"""Scenario values and files: what cannot give a run is refused by key when the scenario is read, bad input to the
scenario's entry points gives only their documented errors, numbers too large for a float and arrays nested too
deeply are named, what is not a scenario file (a folder, a device, a pipe, a URDF) is said so, and a scenario's
arrays stay read-only (docs/hostile-inputs.md, "Scenario files and values" and "Round 3")."""
from __future__ import annotations

import math
import os
import threading

import numpy as np
import pytest
from dobkit_process import run_dobkit as _dobkit
from two_joint_arm import TWO
from two_joint_arm import write_urdf as _urdf

import blocks
from blocks.diagram.gains import GainError, validated_gain
from blocks.model.rrpr.joints import RRPR_JOINTS
from blocks.scenarios.scenario import ScenarioError

PAPER = blocks.load_scenario("paper")


@pytest.mark.parametrize("changes, words", [
    ({"simulation.t_final": 1e-300, "simulation.output_step": 1e-300}, "output_step' \\(1e-300 s\\) must be at least"),
    ({"simulation.rtol": 0.9}, "simulation.rtol' must be between"),
    ({"simulation.rtol": 1e6}, "simulation.rtol' must be between"),
    ({"simulation.atol": 1e3}, "simulation.atol' must be between"),
    ({"simulation.t_final": 10 ** 400}, "t_final' must be a finite number, got 1.000e\\+400"),
    ({"trajectory.stitches": 10 ** 30}, "trajectory.stitches' = 1.000e\\+30 makes each of the path's"),
    ({"trajectory.stitches": 10 ** 6}, "phases 5e-06 s long, shorter than 0.001 s"),
    ({"noise.sample_period": 1e-6, "noise.q_std": [1e-5] * 4}, "noise.sample_period' \\(1e-06 s\\) asks for 1e\\+07"),
])
def test_scenario_values_that_cannot_give_a_run_are_refused_by_key(changes, words):
    with pytest.raises(ScenarioError, match=words):
        PAPER.with_changes(changes)


def test_a_long_run_without_noise_is_not_refused_for_noise_samples():
    assert PAPER.with_changes({"simulation.t_final": 1e5, "simulation.output_step": 0.05}).noise is None


def test_scenario_files_with_a_byte_order_mark_or_given_as_folders(tmp_path):
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + b'name = "with a mark"\n')
    assert blocks.load_scenario(bom).name == "with a mark"
    with pytest.raises(ScenarioError, match="is a folder, not a scenario file"):
        blocks.load_scenario(tmp_path)


def test_entry_points_answer_bad_input_with_their_documented_errors(tmp_path):
    """A fuzz-like pass over the scenario's entry points: only ScenarioError/ValueError/TypeError escape."""
    deep: list = []
    for _ in range(3000):
        deep = [deep]
    values = [None, "x", True, {}, [], [[1.0]], 10 ** 400, -10 ** 400, [10 ** 400] * 4, math.nan, math.inf,
              -math.inf, 1e308, -1e308, deep, object()]
    keys = ["gains.kp", "gains.kd", "gains.observer", "simulation.t_final", "simulation.output_step",
            "trajectory.depth", "trajectory.start", "trajectory.stitches", "noise.seed", "noise.q_std", "initial.q",
            "disturbance.f_r", "robot.m1", "nominal_scale.I2", "controller.sample_rate", "observer.variant"]
    for key in keys:
        for value in values:
            try:
                PAPER.with_changes({key: value})
            except ScenarioError as err:
                # the key, dotted or as '[section] ... name'
                assert key.split(".")[1] in str(err) or "nested too deeply" in str(err), (key, value, err)
            # a value the scenario takes is fine: it was checked
    for given in [None, 5, 2.5, b"paper", ["paper"], {"gains": {"kp": 100}}, object(), "no-such-scenario"]:
        with pytest.raises((TypeError, ScenarioError)):
            blocks.load_scenario(given)
    for given in [None, 5, "paper", ["paper"], {"gains": 5}, {"gains": {"kp": deep}}, {"nope": 1}, object()]:
        with pytest.raises(ScenarioError):
            blocks.scenario_from_dict(given)
    for given in [None, "x", 5, [1, 2], {"kp": 1}]:
        with pytest.raises(ScenarioError):
            PAPER.with_changes(given)
    for value in [None, "x", 10 ** 400, [math.nan] * 4, deep[:1], {"a": 1}, 0.0, [[1.0] * 4] * 4]:
        with pytest.raises(GainError):
            validated_gain(value, "observer", RRPR_JOINTS)
    for name, value in [("observer", None), ("observer", 1), ("engine", 5), ("engine", "turbo"), ("progress", 5),
                        ("progress", "x"), ("plant", "x"), ("plant", 5)]:
        with pytest.raises((TypeError, ValueError), match=name):
            blocks.simulate(PAPER, **{name: value})
    for given in [None, 5, {"gains": {"kp": 1}}]:
        with pytest.raises(TypeError):
            blocks.closed_loop(given)


@pytest.mark.parametrize("key", ["kp", "observer"])
def test_gains_too_large_for_a_float_are_not_finite_numbers_in_a_file_and_in_with_changes(tmp_path, key):
    with pytest.raises(ScenarioError, match=rf"'gains\.{key}' must be a finite number, got 1\.000e\+400"):
        PAPER.with_changes({f"gains.{key}": 10 ** 400})
    path = tmp_path / "huge.toml"
    path.write_text(f"[gains]\n{key} = 1{'0' * 400}\n")
    with pytest.raises(ScenarioError, match=rf"'gains\.{key}' must be a finite number, got 1\.000e\+400"):
        blocks.load_scenario(path)
    run = _dobkit("simulate", "--scenario", path, "--out", tmp_path / "out")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.count("\n") == 1 and "must be a finite number, got 1.000e+400" in run.stderr
    assert not (tmp_path / "out").exists()


def test_a_deeply_nested_array_in_a_file_is_a_scenario_error_not_a_recursion_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("[gains]\nkp = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ScenarioError, match="nested too deeply"):
        blocks.load_scenario(path)
    path.write_text("[gains]\nkp = " + "[" * 20 + "1.0" + "]" * 20 + "\n")    # parsed, then refused by shape
    with pytest.raises(ScenarioError, match=r"'gains\.kp' must be a number, 4 numbers or a diagonal 4x4 matrix"):
        blocks.load_scenario(path)


def test_devices_and_pipes_are_not_scenario_files(tmp_path):
    with pytest.raises(ScenarioError, match="'/dev/zero' is not a regular file"):
        blocks.load_scenario("/dev/zero")
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    outcome: list = []

    def load():
        try:
            blocks.load_scenario(fifo)
        except ScenarioError as err:
            outcome.append(str(err))
    reader = threading.Thread(target=load, daemon=True)
    reader.start()
    reader.join(60)                              # a FIFO without a writer would block a plain open forever
    assert not reader.is_alive(), "reading the FIFO blocked"
    assert outcome and "is not a regular file" in outcome[0] and str(fifo) in outcome[0]


def test_a_scenarios_arrays_cannot_be_made_writable_again():
    s = blocks.load_scenario("surgical").with_changes({"initial.q": [0.1, 1.0, 0.2, 0.0]})
    arrays = {"kp": s.kp, "kd": s.kd, "observer_gain": s.observer_gain, "initial q": s.initial["q"],
              "noise table": s.noise.table, "a validated gain": validated_gain(180, "kp", RRPR_JOINTS)}
    for name, arr in arrays.items():
        before = arr.copy()
        for target in (arr, arr.base):
            with pytest.raises(ValueError, match="cannot set WRITEABLE flag"):
                target.setflags(write=True)
        with pytest.raises(ValueError, match="read-only"):
            arr[...] = 0.0
        np.testing.assert_array_equal(arr, before, err_msg=name)
    assert s.kp[0, 0] == 180.0 and s.observer_gain[0, 0] == 40.0


def test_a_urdf_given_as_the_scenario_says_where_a_urdf_goes(tmp_path):
    # `dobkit simulate --scenario arm.urdf` said "not valid TOML: Invalid statement (at line 1, column 1)"
    _urdf(tmp_path, TWO)
    done = _dobkit("simulate", "--scenario", "arm.urdf", "--no-figures", cwd=tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip() == ("dobkit simulate: error: arm.urdf is an XML or URDF file, not a scenario (TOML); a "
                                   "URDF arm is named in a scenario's [arm] section: urdf = \"...\", tool_frame = "
                                   "\"...\"")
