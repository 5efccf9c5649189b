"""Scenario files: the built-in paper scenario, validation messages that name the key, TOML round trip."""
from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from conftest import PAPER_FR, PAPER_KD, PAPER_KP, PAPER_Y, paper_toml_dict

from blocks import (
    JointSine,
    LacerationPath,
    Scenario,
    ScenarioError,
    builtin_scenarios,
    load_scenario,
    scenario_from_dict,
)
from blocks.diagram.digital import DigitalController


@pytest.fixture(scope="module")
def paper():
    return load_scenario("paper")


def test_paper_is_builtin_and_loads_with_paper_gains(paper):
    assert "paper" in builtin_scenarios()
    assert paper.name == "paper"
    np.testing.assert_array_equal(paper.kp, PAPER_KP * np.eye(4))
    np.testing.assert_array_equal(paper.kd, PAPER_KD * np.eye(4))
    np.testing.assert_array_equal(paper.observer_gain, PAPER_Y * np.eye(4))
    assert paper.observer_variant == "correct"
    assert paper.disturbance.kinds == ("paper",)
    np.testing.assert_array_equal(paper.disturbance.f_r, PAPER_FR)
    assert isinstance(paper.trajectory, LacerationPath)
    assert paper.noise is None
    # perfect model: nominal == true, both Table 1
    assert paper.nominal == paper.robot
    assert paper.robot.constants.k1 == pytest.approx(7.88827)
    assert paper.simulation.t_final == 10.0 and paper.trajectory.duration == 10.0


def test_default_scenario_is_paper():
    assert load_scenario().data == load_scenario("paper").data


def _with(**sections):
    """The paper file's dict with sections updated key by key (a new trajectory kind replaces the section)."""
    data = copy.deepcopy(paper_toml_dict())
    for key, value in sections.items():
        replace = key == "trajectory" and isinstance(value, dict) and value.get("kind", "laceration") != "laceration"
        if isinstance(value, dict) and isinstance(data.get(key), dict) and not replace:
            data[key].update(value)
        else:
            data[key] = value
    return data


BAD_CASES = {
    "unknown section": (_with(robots={"m1": 1.0}), ["robots"]),
    "unknown key": (_with(gains={"kq": 1.0}), ["gains.kq"]),
    "unknown robot key": (_with(robot={"mass": 1.0}), ["robot.mass"]),
    "unknown trajectory key": (_with(trajectory={"speed": 1.0}), ["trajectory", "speed"]),
    "wrong type gain": (_with(gains={"kp": "high"}), ["gains.kp", "high"]),
    "wrong type robot": (_with(robot={"m1": "heavy"}), ["robot.m1", "heavy"]),
    "boolean": (_with(trajectory={"hover": True}), ["trajectory.hover"]),
    "section not a table": (_with(gains=3.0), ["gains"]),
    "negative kp": (_with(gains={"kp": -180.0}), ["gains.kp", "> 0"]),
    "negative kd on one joint": (_with(gains={"kd": [36.0, 36.0, -1.0, 36.0]}), ["gains.kd"]),
    "observer gain not positive": (_with(gains={"observer": -10.0}), ["gains.observer"]),
    "kp wrong shape": (_with(gains={"kp": [1.0, 2.0]}), ["kp", "shape"]),
    "negative mass": (_with(robot={"m2": -0.689}), ["robot", "'m2'"]),
    "zero nominal scale": (_with(nominal_scale={"m1": 0.0}), ["nominal_scale.m1"]),
    "bad disturbance kind": (_with(disturbance={"kind": "wind"}), ["disturbance.kind", "wind"]),
    "bad trajectory kind": (_with(trajectory={"kind": "spiral"}), ["trajectory.kind", "spiral"]),
    "bad observer variant": (_with(observer={"variant": "paper"}), ["observer.variant"]),
    "bad solver": (_with(simulation={"method": "Euler"}), ["simulation.method", "Euler"]),
    "negative t_final": (_with(simulation={"t_final": -1.0}), ["simulation.t_final"]),
    "output_step not a divisor": (_with(simulation={"t_final": 1.0, "output_step": 0.3}),
                                  ["simulation.t_final", "simulation.output_step", "multiple"]),
    "output_step above t_final": (_with(simulation={"t_final": 1.0, "output_step": 2.0}), ["simulation.output_step"]),
    "negative noise": (_with(noise={"q_std": [0.0, -1.0, 0.0, 0.0]}), ["noise.q_std"]),
    "initial wrong length": (_with(initial={"q": [0.0, 1.0]}), ["initial.q"]),
    "unreachable path": (_with(trajectory={"start": [0.8, 0.0], "end": [0.6, 0.0]}),
                         ["trajectory", "x=0.8 m", "not reachable"]),
    "negative friction": (_with(disturbance={"kind": "friction", "viscous": [0.1, -0.1, 0.0, 0.0]}),
                          ["disturbance.viscous"]),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_scenarios_raise_scenario_error_naming_the_key(case):
    data, fragments = BAD_CASES[case]
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict(data, source="case.toml")
    message = str(info.value)
    assert message.startswith("case.toml"), message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_bad_toml_and_missing_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[gains\nkp = 1\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="does not exist"):
        load_scenario(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match="no built-in scenario named 'nope'"):
        load_scenario("nope")


def test_valid_variations_load():
    s = scenario_from_dict(_with(gains={"kp": [100.0, 120.0, 140.0, 160.0], "observer": [[10.0, 1.0, 0, 0],
                                                                                      [0, 10.0, 0, 0],
                                                                                      [0, 0, 10.0, 0],
                                                                                      [0, 0, 0, 10.0]]},
                                 disturbance={"kind": ["paper", "friction", "tissue"]},
                                 nominal_scale={"m1": 1.3, "I2": 0.8},
                                 trajectory={"kind": "joint_sine", "amplitude": [0.1, 0.1, 0.01, 0.1],
                                             "omega": 2.0, "offset": [0.0, 1.5, 0.24, 0.0]}))
    np.testing.assert_array_equal(np.diag(s.kp), [100.0, 120.0, 140.0, 160.0])
    assert s.observer_gain[0, 1] == 1.0
    assert s.disturbance.kinds == ("paper", "friction", "tissue")
    assert s.nominal.m1 == pytest.approx(1.3 * s.robot.m1) and s.nominal.I2 == pytest.approx(0.8 * s.robot.I2)
    assert s.nominal.m2 == s.robot.m2
    assert isinstance(s.trajectory, JointSine) and s.trajectory.omega == (2.0,) * 4
    none = scenario_from_dict(_with(disturbance={"kind": "none"}))
    assert none.disturbance.kinds == ()


def test_noise_seed_from_toml_loads():
    """A whole-number seed written in a TOML file must be accepted (TOML integers are Python ints)."""
    s = scenario_from_dict(_with(noise={"q_std": [1e-4, 1e-4, 1e-5, 1e-4], "seed": 3}))
    assert s.noise is not None and s.noise.seed == 3


def test_to_toml_round_trip(tmp_path, paper):
    path = tmp_path / "paper_copy.toml"
    path.write_text(paper.to_toml(), encoding="utf-8")
    again = load_scenario(path)
    assert again.data == paper.data
    assert again.robot == paper.robot and again.nominal == paper.nominal
    assert again.trajectory == paper.trajectory and again.disturbance == paper.disturbance


def test_to_toml_round_trip_of_a_rich_scenario(tmp_path):
    data = _with(gains={"kp": [100.0, 120.0, 140.0, 160.0]}, disturbance={"kind": ["paper", "friction"]},
                 nominal_scale={"m1": 1.3}, noise={"q_std": [1e-4, 1e-4, 1e-5, 1e-4], "seed": 7},
                 initial={"q": [0.1, 1.0, 0.2, 0.0]}, observer={"variant": "paper-eq16"})
    s = scenario_from_dict(data, source="rich.toml")
    path = tmp_path / "rich.toml"
    path.write_text(s.to_toml(), encoding="utf-8")
    again = load_scenario(path)
    assert again.data == s.data


def test_replace_documented_example(paper):
    """The docstring example of Scenario.replace."""
    s = paper.replace(gains={"kp": 100})
    assert float(s.kp[0, 0]) == 100.0
    assert s.kd[0, 0] == PAPER_KD


def test_to_toml_escapes_control_characters(tmp_path):
    """TOML basic strings may not hold raw control characters (other than tab): they must be escaped."""
    path = tmp_path / "ctrl.toml"
    path.write_text('description = "first line\\r\\nsecond\\u0007 bell\\tand tab"\n', encoding="utf-8")
    s = load_scenario(path)
    assert s.data["description"] == "first line\r\nsecond\x07 bell\tand tab"
    out = tmp_path / "ctrl_copy.toml"
    out.write_text(s.to_toml(), encoding="utf-8")
    assert load_scenario(out).data == s.data


# --- immutability, equality, hashing ----------------------------------------------------------
def _given_everywhere():
    """A scenario with an initial state and noise given, so that every field holds something to change."""
    return scenario_from_dict(_with(initial={"q": [0.1, 1.0, 0.2, 0.0], "dq": [0.0] * 4, "d_hat": [0.5] * 4},
                                    noise={"q_std": [1e-4, 1e-4, 1e-5, 1e-4], "seed": 3}), source="full.toml")


WRITES = {
    "kp entry": lambda s: s.kp.__setitem__((0, 0), 1.0),
    "kd entry": lambda s: s.kd.__setitem__((1, 1), 1.0),
    "observer gain entry": lambda s: s.observer_gain.__setitem__((2, 2), 1.0),
    "kp in place": lambda s: s.kp.__imul__(2.0),
    "initial q entry": lambda s: s.initial["q"].__setitem__(0, 9.0),
    "initial d_hat entry": lambda s: s.initial["d_hat"].__setitem__(3, 9.0),
    "initial key": lambda s: s.initial.__setitem__("q", np.zeros(4)),
    "data section": lambda s: s.data.__setitem__("gains", {}),
    "data key": lambda s: s.data["gains"].__setitem__("kp", 1.0),
    "data list entry": lambda s: s.data["disturbance"]["f_r"].__setitem__(0, 0.0),
    "data list append": lambda s: s.data["initial"]["q"].append(0.0),
    "data update": lambda s: s.data["simulation"].update(t_final=1.0),
    "data pop": lambda s: s.data.pop("robot"),
    "user_data key": lambda s: s.user_data["gains"].__setitem__("kp", 1.0),
    "user_data delete": lambda s: s.user_data.__delitem__("gains"),
    "field": lambda s: setattr(s, "kp", np.eye(4)),
}


@pytest.mark.parametrize("case", list(WRITES))
def test_a_scenario_cannot_be_changed_through_its_fields(case):
    s = _given_everywhere()
    before = s.to_toml(), s.kp.copy(), s.initial["q"].copy()
    with pytest.raises((ValueError, TypeError, AttributeError)):
        WRITES[case](s)
    assert (s.to_toml(), s.kp.tolist(), s.initial["q"].tolist()) == (before[0], before[1].tolist(),
                                                                     before[2].tolist())
    assert s == _given_everywhere()


def test_the_issue_example_write_raises_and_equality_holds(paper):
    s = load_scenario("paper")
    with pytest.raises(ValueError, match="read-only"):
        s.kp[0, 0] = 1
    assert s == paper and s.kp[0, 0] == PAPER_KP


def test_settings_read_as_plain_dicts_and_copies_are_changeable(paper):
    import json
    import pickle
    assert json.loads(json.dumps(paper.data)) == paper.data
    assert isinstance(paper.data, dict) and isinstance(paper.data["disturbance"]["f_r"], list)
    assert paper.data["gains"] | {"kp": 1.0} == {"kp": 1.0, "kd": PAPER_KD, "observer": PAPER_Y}
    mine = copy.deepcopy(paper.data)
    mine["gains"]["kp"] = 1.0                                 # a copy is the caller's to change
    mine["disturbance"]["f_r"][0] = 0.0
    assert paper.data["gains"]["kp"] == PAPER_KP and paper.data["disturbance"]["f_r"][0] == PAPER_FR[0]
    shipped = pickle.loads(pickle.dumps(paper.data))          # as a sweep sends it to a worker process
    assert scenario_from_dict(shipped, source="paper").data == paper.data
    shipped["gains"]["kp"] = 2.0
    assert scenario_from_dict(shipped).kp[0, 0] == 2.0 and paper.kp[0, 0] == PAPER_KP


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_copies_of_a_scenario_are_equal_and_read_only(how):
    import pickle
    s = _given_everywhere()
    other = pickle.loads(pickle.dumps(s)) if how == "pickle" else copy.deepcopy(s)
    assert other == s and hash(other) == hash(s) and other is not s
    for arr in (other.kp, other.kd, other.observer_gain, other.initial["q"]):
        assert not arr.flags.writeable
    with pytest.raises(TypeError):
        other.data["gains"]["kp"] = 1.0


def _changed(s, name: str):
    """``s`` with one field set to a different, still meaningful value (built through the constructor)."""
    other = {"name": "other", "data": {**s.data, "description": "changed"}, "robot": s.robot.scaled(m1=1.1),
             "nominal": s.nominal.scaled(I2=0.9), "kp": s.kp * 2.0, "kd": s.kd + np.diag([0.0, 0.0, 1.0, 0.0]),
             "observer_gain": s.observer_gain + np.diag([0.0, 0.0, 0.0, 1e-9]),
             "observer_variant": "paper-eq16", "trajectory": JointSine(),
             "disturbance": type(s.disturbance)(kinds=("friction",)),
             "noise": None, "initial": {**s.initial, "dq": np.array([0.0, 0.0, 0.0, 1e-12])},
             "simulation": type(s.simulation)(t_final=5.0), "source": "elsewhere.toml",
             "controller": DigitalController(sample_rate=1000.0),
             "user_data": {**s.user_data, "name": "other"}}
    return dataclasses.replace(s, **{name: other[name]})


@pytest.mark.parametrize("name", [f.name for f in dataclasses.fields(Scenario)])
def test_equality_sees_a_difference_in_any_field(name):
    s = _given_everywhere()
    assert dataclasses.replace(s) == s
    assert _changed(s, name) != s and s != _changed(s, name)


def test_scenarios_are_hashable_consistently_with_equality(paper):
    same = load_scenario("paper")
    assert hash(same) == hash(paper) and len({paper, same}) == 1
    assert len({paper, paper.with_changes({"gains.kp": 100.0})}) == 2
    assert paper != "paper" and paper != paper.data
