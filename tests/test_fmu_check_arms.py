"""``fmu check`` holds a plant FMU of any arm against that arm's Python plant, and refuses another arm by name.

The reference of a URDF arm is its own ``forward_dynamics``; the arm comes from the record the export wrote
into the FMU, or from the caller (``arm=``, ``--arm``).  A failing check is shown with FMUs that are not the
arm's plant: a scope4 FMU held against the Panda (another joint count), a scope4 whose insertion stage is
2 kg heavier held against the scope4, and a paper-arm FMU with another m2 held against Table 1.
"""
from __future__ import annotations

import dataclasses
import json
import zipfile

import numpy as np
import pytest

from fmu import check_fmu, export_plant

pytestmark = pytest.mark.needs_cc
pin = pytest.importorskip("pinocchio")

from blocks.model.urdf import example_arm  # noqa: E402
from blocks.model.urdf.chain_model import ChainArm  # noqa: E402
from dobkit.cli import main as dobkit_main  # noqa: E402


@pytest.fixture(scope="module")
def scope4(tmp_path_factory):
    folder = tmp_path_factory.mktemp("check_arms")
    arm = example_arm("scope4")
    return arm, export_plant(folder / "scope4.fmu", params=arm)


def test_the_export_records_the_arm_exactly(scope4):
    from fmu.arm_record import ARM_RECORD, arm_from_record
    arm, path = scope4
    with zipfile.ZipFile(path) as zf:
        text = zf.read(ARM_RECORD).decode()
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    rebuilt = arm_from_record(text)
    assert rebuilt.joints == arm.joints and rebuilt.tool_frame == "tool_tip"
    assert rebuilt.chain.frozen_key() == arm.chain.frozen_key()          # every float, bit for bit
    rng = np.random.default_rng(0)
    q, dq, tau = rng.uniform(-0.5, 0.5, 4), rng.normal(size=4), rng.normal(size=4)
    model = arm.pin_model
    ddq = pin.aba(model, model.createData(), arm.pinocchio_configuration(q), dq, tau)
    np.testing.assert_allclose(rebuilt.forward_dynamics(q, dq, tau), ddq, rtol=1e-10, atol=1e-10)


def test_check_compares_a_scope4_fmu_with_its_arm(scope4):
    arm, path = scope4
    for given in (None, arm):                       # the recorded arm, then the one given
        report = check_fmu(path, t_final=0.5, arm=given)
        plant = report["plant_comparison"]
        assert report["passed"] and plant["passed"], plant
        assert plant["joints"] == ["yaw", "pitch", "insertion", "roll"]
        assert plant["model_exchange"]["max_abs_error"] < 1e-9
        assert plant["co_simulation"]["max_abs_error"] < 1e-6
        # every bounded joint's stop at both ends, pushing and letting go
        stops = plant["end_stops"]
        assert stops["passed"] and len(stops["states"]) == 4 * 4
        assert any(s["stop_force"] == 0.0 for s in stops["states"])
        assert all(s["stop_force"] != 0.0 for s in stops["states"][::2])
    # the comparison moved every joint and stayed inside the ranges (its reference has no stops)
    per_state = plant["model_exchange"]["max_abs_error_per_state"]
    assert sorted(per_state) == sorted([f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)])


def test_check_refuses_a_scope4_fmu_held_against_the_panda(scope4):
    _, path = scope4
    report = check_fmu(path, t_final=0.2, arm=example_arm("panda"))
    plant = report["plant_comparison"]
    assert not report["passed"] and not plant["passed"]
    assert "the FMU has 4 joints (inputs tau[0..3]); the 7-joint arm" in plant["error"]
    assert "the FMU is not this arm's plant" in plant["error"]


def test_check_fails_a_scope4_with_a_heavier_insertion_stage(scope4, tmp_path):
    arm, _ = scope4
    masses = list(arm.chain.masses)
    masses[2] += 2.0
    heavy = ChainArm(dataclasses.replace(arm.chain, masses=tuple(masses)), arm.joints, arm.tool_frame,
                     source="scope4 with a 2 kg heavier insertion stage")
    path = export_plant(tmp_path / "heavy.fmu", params=heavy)
    assert check_fmu(path, t_final=0.3)["passed"]            # against its own record it is consistent
    report = check_fmu(path, t_final=0.3, arm=arm)
    plant = report["plant_comparison"]
    assert not report["passed"] and not plant["passed"]
    assert plant["model_exchange"]["max_abs_error"] > 1e-3
    assert "Model Exchange differs from the 4-joint arm ['yaw', 'pitch', 'insertion', 'roll']" in plant["why"]
    assert "the FMU is not this arm's plant, or its parameters differ" in plant["why"]


def test_the_command_line_checks_urdf_and_paper_fmus_against_an_arm(tmp_path, capsys):
    path = tmp_path / "scope4.fmu"
    assert dobkit_main(["fmu", "export", "--arm", "scope4", "--out", str(path)]) == 0
    assert "end stops at the range of yaw, pitch, insertion, roll" in capsys.readouterr().out
    assert dobkit_main(["fmu", "check", str(path), "--t-final", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "comparison with the Python plant of the 4-joint arm ['yaw', 'pitch', 'insertion', 'roll']" in out
    assert "end stops (16 states beyond the joint ranges)" in out
    assert dobkit_main(["fmu", "check", str(path), "--t-final", "0.2", "--arm", "panda"]) == 1
    assert "the FMU has 4 joints" in capsys.readouterr().out
    # a paper-arm FMU whose m2 start value is not Table 1's: consistent with itself, not with Table 1
    from blocks.model.rrpr.parameters import RobotParameters
    changed = export_plant(tmp_path / "m2.fmu", params=RobotParameters(m2=1.2))
    assert dobkit_main(["fmu", "check", str(changed), "--t-final", "0.2"]) == 0
    capsys.readouterr()
    assert dobkit_main(["fmu", "check", str(changed), "--t-final", "0.2", "--arm", "rrpr"]) == 1
    out = capsys.readouterr().out
    assert "Model Exchange differs from the paper's RRPR arm by" in out


@pytest.mark.slow
def test_check_compares_a_panda_fmu_with_its_arm(tmp_path):
    """Seven joints, wrist inertias of a few 1e-3 kg m^2: the PD law on the whole M keeps the light joints calm."""
    arm = example_arm("panda")
    report = check_fmu(export_plant(tmp_path / "panda.fmu", params=arm), t_final=0.5)
    plant = report["plant_comparison"]
    assert plant["passed"], plant
    assert plant["joints"] == [f"panda_joint{i}" for i in range(1, 8)]
    assert plant["model_exchange"]["max_abs_error"] < 1e-9 and plant["co_simulation"]["max_abs_error"] < 1e-6
    assert plant["end_stops"]["passed"] and len(plant["end_stops"]["states"]) == 7 * 4


def test_a_scope4_fmu_is_the_true_plant_of_the_scope4_scenario(scope4):
    """``fmu.load(path, scenario=...)`` takes the joint count from the scenario's arm and sets Table-1 parameters
    only on the paper's arm (a URDF arm's FMU failed with an AttributeError on m1); the loop equals Python's."""
    import blocks
    from blocks.scenarios.scenario import load_scenario
    from fmu import load
    _, path = scope4
    s = load_scenario("scope4").with_changes({"simulation.t_final": 0.3})
    plant = load(path, scenario=s)
    try:
        with_fmu = blocks.simulate(s, plant=plant, engine="fast")
    finally:
        plant.fmu.close()
    python = blocks.simulate(s, engine="fast")
    rows = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]

    def pick(resp):
        labels = list(resp.output_labels)
        return np.array([resp.outputs[labels.index(name)] for name in rows])

    got, want = pick(with_fmu), pick(python)
    assert np.max(np.abs(want - want[:, :1])) > 1e-3                 # the arm moved
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
