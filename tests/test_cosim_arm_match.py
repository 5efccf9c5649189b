"""A plant FMU is co-simulated or loaded only as the plant of its own arm: another arm's FMU of the same joint
count, or an exported arm whose bodies or gravity differ from the scenario's, is refused by name unless the
FMU's own arm is asked for (docs/hostile-inputs.md, "Round 7").
"""
from __future__ import annotations

import numpy as np
import pytest
from dobkit_process import run_dobkit as _dobkit

pin = pytest.importorskip("pinocchio")



@pytest.fixture(scope="module")
def plant_fmus(tmp_path_factory):
    """The paper's RRPR plant and scope4's, exported as they are by ``dobkit fmu export`` and ``--arm scope4``."""
    from blocks.model.urdf import example_arm
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
