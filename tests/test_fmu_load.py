"""Model Exchange FMUs as python-control blocks: the plant FMU and an independent first-order lag.

The lag FMU (tests/fmu_lag) is hand-written C unrelated to the plant's FMU
code; its step response is known in closed form.
"""
from __future__ import annotations

import copy
from pathlib import Path

import control as ct
import numpy as np
import pytest
from conftest import make_scenario

import blocks
from blocks.diagram.contract import contract_of
from blocks.diagram.systems import plant as python_plant
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.rrpr.parameters import RobotParameters
from fmu import FMUMissingVariablesError, check_fmu, export_plant, load
from fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"

pytestmark = pytest.mark.needs_cc          # every test builds the plant or the lag FMU
SINE = {"kind": "joint_sine", "amplitude": [0.3, 0.25, 0.03, 0.4], "omega": 3.0, "offset": [0.3, 1.2, 0.2, 0.1]}


def build_lag(path: Path) -> Path:
    """Package the hand-written lag FMU (FMI 2.0, ME + CS)."""
    return package_fmu(path, (LAG_DIR / "modelDescription.xml").read_text(), {"lag.c": LAG_DIR / "lag.c"},
                       ["lag.c"], "lag", 2)


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory):
    return export_plant(tmp_path_factory.mktemp("load") / "plant.fmu", fmi_version=2)


@pytest.fixture(scope="module")
def lag_fmu(tmp_path_factory):
    return build_lag(tmp_path_factory.mktemp("lag") / "lag.fmu")


def test_plant_block_has_the_python_plants_signals(plant_fmu, tmp_path):
    sys = load(plant_fmu, extract_to=tmp_path)
    ref = python_plant(RobotParameters(), DisturbanceSpec())
    assert list(sys.input_labels) == list(ref.input_labels)
    assert list(sys.output_labels) == list(ref.output_labels)
    assert list(sys.state_labels) == list(ref.state_labels)
    assert contract_of(sys).feedthrough == frozenset()   # from ModelStructure: no output depends on tau
    # the export's default start: at rest, theta2 = pi/2 and Table 1's d3 = 0.24 m (not the singular theta2 = 0)
    np.testing.assert_allclose(sys.initial_state, [0.0, np.pi / 2, 0.24, 0.0, 0.0, 0.0, 0.0, 0.0], atol=1e-15)
    x, u = np.array([0.1, 0.9, 0.2, -0.3, 0.5, 0.1, -0.2, 0.3]), np.array([1.0, -2.0, 0.5, 0.1])
    np.testing.assert_allclose(sys._rhs(0.2, x, u), ref._rhs(0.2, x, u), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(sys._out(0.2, x, u), ref._out(0.2, x, u), rtol=1e-13, atol=1e-13)


def test_closing_the_block_removes_its_extraction_folder(plant_fmu, tmp_path):
    sys = load(plant_fmu, extract_to=tmp_path)
    (folder,) = list(tmp_path.iterdir())
    assert (folder / "modelDescription.xml").is_file()
    sys.fmu.close()
    assert list(tmp_path.iterdir()) == []


def test_start_values_set_parameters_and_initial_state(plant_fmu):
    start = {"q[1]": 0.7, "dq[3]": -0.2, "m4": 0.5, "disturbance_friction": True, "disturbance_paper": False}
    sys = load(plant_fmu, start_values=start)
    assert sys.initial_state[1] == 0.7 and sys.initial_state[7] == -0.2
    ref = python_plant(RobotParameters(m4=0.5), DisturbanceSpec(kinds=("friction",)))
    x, u = np.array([0.1, 0.9, 0.2, -0.3, 0.5, 0.1, -0.2, 0.3]), np.array([1.0, -2.0, 0.5, 0.1])
    np.testing.assert_allclose(sys._rhs(0.0, x, u), ref._rhs(0.0, x, u), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("version", [2, 3])
def test_closed_loop_with_the_fmu_block_matches_the_python_loop(plant_fmu, tmp_path, version):
    fmu_path = plant_fmu if version == 2 else export_plant(tmp_path / "p3.fmu", fmi_version=3)
    s = make_scenario(trajectory=SINE, simulation={"t_final": 0.5, "output_step": 0.01, "rtol": 1e-10,
                                                   "atol": 1e-12})
    ref = blocks.simulate(s)
    fmu_plant = load(fmu_path)
    got = blocks.simulate(s, plant=fmu_plant, engine="fast")        # an FMU has no kernels to compile
    assert list(got.output_labels) == list(ref.output_labels)
    assert np.max(np.abs(np.asarray(got.outputs) - np.asarray(ref.outputs))) < 1e-6


def test_scenario_makes_the_fmu_the_scenarios_true_plant(plant_fmu):
    """The FMU was exported with Table 1 and the paper disturbance; the scenario has a heavier tool and friction."""
    s = make_scenario(trajectory=SINE, robot={"m4": 0.4}, disturbance={"kind": ["paper", "friction"]},
                      simulation={"t_final": 0.3, "output_step": 0.01, "rtol": 1e-10, "atol": 1e-12})
    ref = np.asarray(blocks.simulate(s).outputs)
    got = np.asarray(blocks.simulate(s, plant=load(plant_fmu, scenario=s)).outputs)
    assert np.max(np.abs(got - ref)) < 1e-6
    # without it the FMU keeps its export's parameters: a different plant
    own = np.asarray(blocks.simulate(s, plant=load(plant_fmu)).outputs)
    assert np.max(np.abs(own - ref)) > 1e-3


def test_explicit_start_values_override_the_scenario(plant_fmu):
    s = make_scenario(robot={"m4": 0.4})
    sys = load(plant_fmu, scenario=s, start_values={"m4": 0.3})
    ref = python_plant(RobotParameters(m4=0.3), DisturbanceSpec())
    x, u = np.array([0.1, 0.9, 0.2, -0.3, 0.5, 0.1, -0.2, 0.3]), np.array([1.0, -2.0, 0.5, 0.1])
    np.testing.assert_allclose(sys._rhs(0.0, x, u), ref._rhs(0.0, x, u), rtol=1e-13, atol=1e-13)
    q_ref0 = s.trajectory.evaluate(0.0)[0]
    np.testing.assert_allclose(sys.initial_state[:4], q_ref0, atol=1e-15)   # starts on the reference
    sys.fmu.close()


def test_scenario_for_an_fmu_without_the_plant_signals(lag_fmu):
    with pytest.raises(FMUMissingVariablesError, match=r"as the true plant of scenario 'paper'.*q\[0\]"):
        load(lag_fmu, scenario="paper")


def test_python_control_response_with_the_fmu_block(plant_fmu):
    """The same loop through python-control's own evaluation (not the fast path)."""
    s = make_scenario(trajectory=SINE, simulation={"t_final": 0.2, "output_step": 0.01, "rtol": 1e-9,
                                                   "atol": 1e-11})
    fmu_loop = blocks.closed_loop(s, plant=load(plant_fmu))
    py_loop = blocks.closed_loop(s)
    x0 = blocks.initial_state(py_loop, s)
    t = s.simulation.time_grid
    kw = dict(solve_ivp_method="RK45", solve_ivp_kwargs=dict(rtol=1e-9, atol=1e-11))
    a = ct.input_output_response(fmu_loop, t, 0, blocks.initial_state(fmu_loop, s), **kw)
    b = ct.input_output_response(py_loop, t, 0, x0, **kw)
    assert np.max(np.abs(np.asarray(a.outputs) - np.asarray(b.outputs))) < 1e-6


def test_copies_of_the_block_share_the_fmu(plant_fmu):
    sys = load(plant_fmu)
    twin = copy.deepcopy(sys)
    assert twin.fmu is sys.fmu
    x, u = np.full(8, 0.1), np.ones(4)
    np.testing.assert_array_equal(twin._rhs(0.0, x, u), sys._rhs(0.0, x, u))


# --- an independent FMU ----------------------------------------------------------------------------------

def test_lag_fmu_loads_with_its_own_names_and_feedthrough(lag_fmu):
    sys = load(lag_fmu, name="lag")
    assert (list(sys.input_labels), list(sys.output_labels), list(sys.state_labels)) == (["u"], ["x", "e"], ["x"])
    assert contract_of(sys).feedthrough == frozenset({"u"})   # e = u - x depends on u (ModelStructure)
    assert sys.initial_state.tolist() == [0.0]


def test_lag_step_response_matches_the_closed_form(lag_fmu):
    T = 0.25
    sys = load(lag_fmu, name="lag", start_values={"T": T, "x": 0.2})
    t = np.linspace(0.0, 1.5, 151)
    resp = ct.input_output_response(sys, t, np.ones_like(t), sys.initial_state, solve_ivp_method="RK45",
                                    solve_ivp_kwargs=dict(rtol=1e-10, atol=1e-12))
    x_exact = 1.0 + (0.2 - 1.0) * np.exp(-t / T)
    np.testing.assert_allclose(resp.outputs[0], x_exact, atol=1e-8)
    np.testing.assert_allclose(resp.outputs[1], 1.0 - x_exact, atol=1e-8)


def test_lag_block_in_an_interconnection(lag_fmu):
    """Proportional feedback around the lag: x' = (k (r - x) - x) / T, a lag with time constant T / (1 + k)."""
    T, k, r = 0.5, 3.0, 2.0
    lag = load(lag_fmu, name="lag", start_values={"T": T})
    ctrl = ct.nlsys(None, lambda t, x, u, p: [k * (r - u[0])], inputs=["x"], outputs=["u"], name="ctrl")
    loop = ct.interconnect([lag, ctrl], inplist=[], outlist=["x"], outputs=["x"], check_unused=False)
    t = np.linspace(0.0, 1.0, 101)
    resp = ct.input_output_response(loop, t, 0, [0.0], solve_ivp_kwargs=dict(rtol=1e-10, atol=1e-12))
    x_inf = k * r / (1 + k)
    np.testing.assert_allclose(resp.outputs[0], x_inf * (1 - np.exp(-(1 + k) * t / T)), atol=1e-8)


def test_check_fmu_on_another_fmu_validates_and_skips_the_plant_comparison(lag_fmu):
    report = check_fmu(lag_fmu)
    assert report["validation"]["passed"] and report["passed"]
    assert report["model_exchange"]["loads"] and report["co_simulation"]["runs"]
    assert report["me_vs_cs"]["passed"]
    assert "not a dobkit plant FMU" in report["plant_comparison"]["skipped"]
