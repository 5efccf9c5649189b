"""Real OpenModelica exports (tests/fmu_models/openmodelica, from the gemseo-fmu package, LGPL-3.0: see its README).

References, by hand (not from the code under test):

* Mass_Damper (OpenModelica 1.19.3): the mass position p = 1 - damper.s_rel (m) obeys m p'' + d p' + c p = f with
  m = 1 kg, d = 10 N s/m, c = 1e4 N/m, output y = p - 0.5, from p(0) = 0.5 m at rest.  Closed here by a
  python-control block f = F0 - k (y + 0.5) = F0 - k p: then m p'' + d p' + (c + k) p = F0, an underdamped second
  order system, p(t) = p_ss + (p0 - p_ss) e^(-zeta wn t) (cos wd t + zeta / sqrt(1 - zeta^2) sin wd t),
  wn = sqrt((c + k) / m), zeta = d / (2 sqrt((c + k) m)), wd = wn sqrt(1 - zeta^2), p_ss = F0 / (c + k);
* ramp (OpenModelica 1.20.0, Modelica.Blocks.Sources.Ramp, two event indicators): with startTime 0.5 s, duration
  1 s, height 2, out = 0, then 2 (t - 0.5), then 2; a python-control integrator of it holds 0, (t - 0.5)^2, then
  1 + 2 (t - 1.5).
"""
from __future__ import annotations

import math
from pathlib import Path

import control as ct
import fmpy
import numpy as np
import pytest

from dobkit.cli import main as dobkit_main
from fmu import check_fmu, cosimulate_system, load, simulate_loop
from fmu.check import stage
from fmu.coupling import CouplingFallbackWarning

HERE = Path(__file__).parent / "fmu_models" / "openmodelica"
MASS_DAMPER, RAMP = HERE / "Mass_Damper.fmu", HERE / "ramp.fmu"

pytestmark = pytest.mark.skipif(fmpy.platform != "linux64", reason="the OpenModelica FMUs carry linux64 binaries")

M, D, C = 1.0, 10.0, 1e4          # the exported model's parameters (kg, N s/m, N/m)
K, F0, P0 = 5e3, 150.0, 0.5       # the feedback written here (N/m, N) and the start position (m)


def position(t):
    """p(t) in m of the closed loop, by hand (module docstring)."""
    stiffness = C + K
    wn = math.sqrt(stiffness / M)
    zeta = D / (2 * math.sqrt(stiffness * M))
    wd = wn * math.sqrt(1 - zeta ** 2)
    p_ss = F0 / stiffness
    t = np.asarray(t, dtype=float)
    return p_ss + (P0 - p_ss) * np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2)
                                                          * np.sin(wd * t))


def feedback() -> ct.NonlinearIOSystem:
    return ct.nlsys(None, lambda t, x, u, p: [F0 - K * (u[0] + 0.5)], inputs=["y"], outputs=["f"], name="feedback")


def test_the_files_are_openmodelica_model_exchange_exports():
    for path, version in ((MASS_DAMPER, "1.19.3"), (RAMP, "1.20.0")):
        md = fmpy.read_model_description(str(path))
        assert md.generationTool.startswith("OpenModelica") and version in md.generationTool
        assert md.fmiVersion == "2.0" and md.modelExchange is not None and md.coSimulation is not None
    assert fmpy.read_model_description(str(RAMP)).numberOfEventIndicators == 2


def test_the_hand_computed_closed_loop_solves_its_equation():
    """p'' + (d p' + (c + k) p - F0) / m = 0 by finite differences, p(0) = p0, p'(0) = 0."""
    t, h = np.linspace(0.01, 0.3, 30), 1e-5
    p, dp = position(t), (position(t + h) - position(t - h)) / (2 * h)
    ddp = (position(t + h) - 2 * p + position(t - h)) / h ** 2
    np.testing.assert_allclose(M * ddp + D * dp + (C + K) * p, F0, rtol=1e-4)
    assert position(0.0) == pytest.approx(P0, abs=1e-15)
    assert (position(h) - position(-h)) / (2 * h) == pytest.approx(0.0, abs=1e-4)     # peak speed ~ 30 m/s


def test_fmu_check_reports_mass_damper_and_says_which_side_is_off(capsys):
    report = check_fmu(MASS_DAMPER)
    status = {s["stage"]: s["status"] for s in report["stages"]}
    assert status["validation"] == status["model_exchange"] == status["co_simulation"] == "passed"
    assert report["passed"] is True
    me_cs = report["me_vs_cs"]
    # the FMU's own co-simulation solver (explicit Euler at the check's 10 ms step) diverges: a finding about the
    # FMU, Model Exchange matching the fine reference
    assert me_cs["me_vs_reference"] < 1e-6 and me_cs["cs_vs_reference"] > 1.0
    assert "the FMU's own co-simulation solver is" in me_cs["finding"] and "dobkit uses Model Exchange" in \
        me_cs["finding"]
    assert dobkit_main(["fmu", "check", str(MASS_DAMPER)]) == 0
    assert "Traceback" not in capsys.readouterr().out


def test_fmu_check_reports_the_ramp_as_a_block_with_events():
    report = check_fmu(RAMP)
    assert report["passed"] is True
    assert "loads as a block with events" in stage(report, "model_exchange")["why"]
    assert stage(report, "simulate_fmu")["status"] == "passed"
    assert report["me_vs_cs"]["max_abs_difference"] < 1e-6


def test_mass_damper_closed_by_a_python_control_block_matches_the_analytic_loop():
    with load(MASS_DAMPER, name="mass_damper") as plant:
        assert plant.input_labels == ["f"] and plant.output_labels == ["y"] and plant.event_source is None
        np.testing.assert_allclose(plant.initial_state, [1 - P0, 0.0])
        loop = ct.interconnect([plant, feedback()], inplist=[], outlist=["y", "f"], check_unused=False)
        resp = simulate_loop(loop, np.linspace(0.0, 0.5, 501), method="DOP853", rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(resp.outputs[0] + 0.5, position(resp.time), rtol=0, atol=1e-6)
    np.testing.assert_allclose(resp.outputs[1], F0 - K * position(resp.time), rtol=0, atol=1e-2)


def test_mass_damper_co_simulates_with_the_default_coupling_converging_to_its_model_exchange_answer():
    """Its NaN output derivatives make the default coupling fall back to zoh, saying so (F1); the FMU's own
    co-simulation solver is first order (explicit Euler), so the error against the Model Exchange answer halves with
    the step."""
    t_final = 0.1
    with load(MASS_DAMPER, name="mass_damper") as plant:
        loop = ct.interconnect([plant, feedback()], inplist=[], outlist=["y"], check_unused=False)
        me = simulate_loop(loop, np.linspace(0.0, t_final, 101), method="DOP853", rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(me.outputs[0] + 0.5, position(me.time), atol=1e-6)
    errors = {}
    for step in (2e-4, 1e-4):
        with pytest.warns(CouplingFallbackWarning, match="uses coupling 'zoh'"):
            cs = cosimulate_system(MASS_DAMPER, feedback(), t_final, step, record_every=round(1e-3 / step))
        assert cs.cosim["coupling"] == "zoh"
        assert "Mass_Damper.fmu: fmi2GetRealOutputDerivatives returned d(y)/dt = nan" in cs.cosim["coupling_fallback"]
        np.testing.assert_allclose(cs.time, me.time, atol=1e-12)
        errors[step] = np.max(np.abs(cs.outputs[cs.output_labels.index("y")] - me.outputs[0]))
    assert errors[1e-4] < 0.03 * P0 * 4          # a few % of the swing at h = 0.1 ms
    assert 1.6 < errors[2e-4] / errors[1e-4] < 2.4, errors


def test_openmodelica_ramp_events_in_a_loop_with_a_python_control_integrator():
    with load(RAMP, name="ramp", start_values={"ramp.startTime": 0.5, "ramp.height": 2.0}) as ramp:
        assert ramp.nstates == 0 and ramp.event_source.n_indicators == 2
        area = ct.nlsys(lambda t, x, u, p: [u[0]], lambda t, x, u, p: x, inputs=["out"], outputs=["A"],
                        states=["A"], name="area")
        loop = ct.interconnect([ramp, area], inplist=[], outlist=["out", "A"], check_unused=False)
        resp = simulate_loop(loop, np.linspace(0.0, 2.0, 41), rtol=1e-10, atol=1e-12)
    t = resp.time
    np.testing.assert_allclose(resp.outputs[0], np.clip(2 * (t - 0.5), 0.0, 2.0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.outputs[1], np.where(t < 0.5, 0.0, np.where(t < 1.5, (t - 0.5) ** 2,
                                                                                  1 + 2 * (t - 1.5))), atol=1e-6)
    events = resp.simulation["events"]
    assert [e["kind"] for e in events] == ["state", "state"]
    np.testing.assert_allclose([e["time"] for e in events], [0.5, 1.5], rtol=0, atol=1e-10)
