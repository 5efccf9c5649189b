"""The digital controller as an FMU (``dobkit fmu export-controller``): validated, wired by name, and the same run.

The co-simulation check is the issue's "Done when": the controller FMU and
the plant FMU of one scenario, under a plain fmpy loop written here (set
``q``, ``dq`` -> read ``tau`` -> set ``tau`` -> step both), give the RMS
tracking error per joint that ``dobkit simulate`` reports for the same
sampled scenario, within 0.1 %.
"""
from __future__ import annotations

import csv
import json
import zipfile

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

import blocks
from dobkit.cli import main
from fmu.logger import MessageLog, fmi2_callbacks, fmi3_log_function, register, unregister

pytestmark = pytest.mark.needs_cc

_T_FINAL = 0.5          # s: 500 controller ticks; the paper scenario's first half second
_ZOH = {"controller.observer_discretization": "zoh", "controller.delay": 1,
        "controller.torque_limit": [0.0, 0.0, 6.0, 0.0]}
# a full observer gain: every entry a tunable parameter Y[i,j], d_hat = Y dq + z with coupled rows
_FULL_Y = {"gains.observer": (np.diag([10.0, 10.0, 10.0, 10.0]) + 0.5).tolist()}


def _scenario_file(folder, changes: dict, name: str):
    """``paper-digital`` with ``changes``, written as a TOML file (what the commands read)."""
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": _T_FINAL} | changes)
    path = folder / f"{name}.toml"
    path.write_text(s.to_toml().replace('name = "paper-digital"', f'name = "{name}"', 1), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The scenario files, the plant FMU (one for both: same arm, path and start) and one controller FMU each."""
    folder = tmp_path_factory.mktemp("controller_fmu")
    files = {"euler": _scenario_file(folder, {}, "pd-euler"), "zoh": _scenario_file(folder, _ZOH, "pd-zoh"),
             "fully": _scenario_file(folder, _FULL_Y, "pd-full-y")}
    plant = folder / "plant.fmu"
    assert main(["fmu", "export", "--scenario", str(files["euler"]), "--out", str(plant)]) == 0
    controllers = {}
    for key, path in files.items():
        controllers[key] = folder / f"controller-{key}.fmu"
        assert main(["fmu", "export-controller", "--scenario", str(path), "--out", str(controllers[key])]) == 0
    controllers["euler-fmi3"] = folder / "controller-euler-fmi3.fmu"
    assert main(["fmu", "export-controller", "--scenario", str(files["euler"]), "--fmi-version", "3",
                 "--out", str(controllers["euler-fmi3"])]) == 0
    return {"folder": folder, "files": files, "plant": plant, "controllers": controllers}


class _Slave:
    """A Co-Simulation instance (FMI 2 or 3) with its log messages collected (fmu.logger routes them here)."""

    def __init__(self, path, name: str) -> None:
        self.md = read_model_description(str(path))
        self.log = MessageLog()
        self.key = None
        self.v3 = self.md.fmiVersion.startswith("3")
        common = dict(unzipDirectory=extract(str(path)), modelIdentifier=self.md.coSimulation.modelIdentifier,
                      instanceName=name)
        if self.v3:
            self.fmu = FMU3Slave(guid=self.md.instantiationToken, **common)
            self.fmu.instantiate(logMessage=fmi3_log_function(self.log))
            self.fmu.enterInitializationMode(startTime=0.0)
            self.get, self.set = self.fmu.getFloat64, self.fmu.setFloat64
        else:
            self.key = register(self.log, name)
            self.callbacks = fmi2_callbacks(self.key)
            self.fmu = FMU2Slave(guid=self.md.guid, **common)
            self.fmu.instantiate(callbacks=self.callbacks)
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
            self.get, self.set = self.fmu.getReal, self.fmu.setReal
        self.fmu.exitInitializationMode()
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}

    def refs(self, prefix: str, n: int = 4) -> list[int]:
        return [self.vr[f"{prefix}[{i}]"] for i in range(n)]

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()
        if self.key is not None:
            unregister(self.key)


def _gauss_seidel(controller_path, plant_path, t_final: float, period: float) -> np.ndarray:
    """Rows ``[t, q(4), tau(4), d_hat(4)]`` at every tick: set q, dq -> get tau -> set tau -> doStep both."""
    ctrl, plant = _Slave(controller_path, "controller"), _Slave(plant_path, "plant")
    try:
        p_out = plant.refs("q") + plant.refs("dq")
        c_in = ctrl.refs("q") + ctrl.refs("dq")
        c_tau, c_dhat, p_tau = ctrl.refs("tau"), ctrl.refs("d_hat"), plant.refs("tau")
        ticks = int(round(t_final / period))
        rows = []
        for k in range(ticks + 1):
            t = k * period
            y = list(plant.get(p_out))
            ctrl.set(c_in, y)
            tau = list(ctrl.get(c_tau))
            rows.append([t] + y[:4] + tau + list(ctrl.get(c_dhat)))
            if k == ticks:
                break
            plant.set(p_tau, tau)
            ctrl.fmu.doStep(t, period)
            plant.fmu.doStep(t, period)
        return np.array(rows)
    finally:
        ctrl.close()
        plant.close()


# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, version", [("euler", "2.0"), ("euler-fmi3", "3.0")], ids=["FMI 2", "FMI 3"])
def test_fmpy_validates_the_fmu_and_its_variables_are_as_declared(made, key, version):
    path = made["controllers"][key]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.fmiVersion == version and md.modelExchange is None
    assert md.coSimulation.canHandleVariableCommunicationStepSize is False
    assert float(md.defaultExperiment.stepSize) == 1e-3          # paper-digital: 1 kHz
    by = {v.name: v for v in md.modelVariables}
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    assert inputs == [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]
    assert outputs == [f"tau[{i}]" for i in range(4)] + [f"d_hat[{i}]" for i in range(4)]
    assert [by[f"q[{i}]"].unit for i in range(4)] == ["rad", "rad", "m", "rad"]
    assert [by[f"tau[{i}]"].unit for i in range(4)] == ["N.m", "N.m", "N", "N.m"]
    # named like the plant FMU: its outputs are our inputs, its inputs our torques
    plant = read_model_description(str(made["plant"]))
    plant_out = {v.name for v in plant.modelVariables if v.causality == "output"}
    plant_in = {v.name for v in plant.modelVariables if v.causality == "input"}
    assert set(inputs) <= plant_out and plant_in == {f"tau[{i}]" for i in range(4)}
    # every output depends on every input: tau_k is there once q_k, dq_k are set
    for unknown in md.outputs:
        assert {d.name for d in unknown.dependencies} == set(inputs), unknown.variable.name
    # the gains are tunable parameters with the scenario's values (Kp = 180, Kd = 36, Y = 10: paper-notes)
    for name, value in (("kp", 180.0), ("kd", 36.0), ("Y", 10.0)):
        for i in range(4):
            v = by[f"{name}[{i}]"]
            assert (v.causality, v.variability, float(v.start)) == ("parameter", "tunable", value)
    assert float(by["sample_period"].start) == 1e-3
    assert float(by["reference_end"].start) == pytest.approx(_T_FINAL, abs=1e-12)


@pytest.mark.parametrize("key, version", [("euler", 2), ("euler-fmi3", 3)], ids=["FMI 2", "FMI 3"])
def test_the_shipped_sources_with_the_shared_fmi_layer_rebuild_the_whole_api(made, key, version, tmp_path):
    import ctypes
    import re
    from pathlib import Path

    import fmpy
    from test_fmu_export import rebuild_from_sources

    path = made["controllers"][key]
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    assert {f"sources/fmi{version}_controller.c", f"sources/fmi{version}_common.c",
            f"sources/fmi{version}_common.h"} <= names
    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    declared = re.findall(rf"FMI{version}_Export\s+\w+TYPE\s+(\w+);", header)
    assert len(declared) == (44 if version == 2 else 75)
    dll = ctypes.CDLL(str(rebuild_from_sources(path, tmp_path)))
    assert [name for name in declared if not hasattr(dll, name)] == []


@pytest.mark.slow
@pytest.mark.parametrize("key", ["euler", "zoh", "fully", "euler-fmi3"],
                         ids=["paper-digital", "zoh, difference, delay, limit", "full observer gain",
                              "paper-digital, FMI 3 controller"])
def test_gauss_seidel_loop_of_the_two_fmus_equals_dobkit_simulate(made, key):
    scenario = made["files"][key.split("-")[0]]
    out = made["folder"] / f"simulate-{key}"
    assert main(["simulate", "--scenario", str(scenario), "--out", str(out), "--no-figures",
                 "--engine", "fast"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    with open(out / "timeseries.csv", newline="") as f:
        table = list(csv.DictReader(f))
    grid = np.array([float(r["time_s"]) for r in table])
    q_ref = np.array([[float(r[f"with_dob.q_ref[{i}]"]) for i in range(4)] for r in table])
    tau_mono = np.array([[float(r[f"with_dob.tau[{i}]"]) for i in range(4)] for r in table])

    s = blocks.load_scenario(scenario)
    rows = _gauss_seidel(made["controllers"][key], made["plant"], _T_FINAL, s.controller.period)
    at = np.searchsorted(rows[:, 0], grid - 1e-9)
    assert np.allclose(rows[at, 0], grid, atol=1e-12)
    error = q_ref - rows[at, 1:5]
    rms = np.sqrt(np.mean(error ** 2, axis=0))
    expected = np.array(metrics["with_dob"]["rms_position_error"])
    np.testing.assert_allclose(rms, expected, rtol=1e-3, err_msg="RMS tracking error per joint")
    # the torques themselves, sample by sample
    scale = np.max(np.abs(tau_mono), axis=0)
    assert np.all(np.abs(rows[at, 5:9] - tau_mono) <= 1e-6 * scale + 1e-9)


@pytest.mark.parametrize("key", ["euler", "euler-fmi3"], ids=["FMI 2", "FMI 3"])
def test_a_communication_step_other_than_the_sample_period_is_refused_naming_it(made, key):
    ctrl = _Slave(made["controllers"][key], "controller-step")
    try:
        ctrl.set(ctrl.refs("q") + ctrl.refs("dq"), [0.0, 1.5, 0.24, 0.0] + [0.0] * 4)
        with pytest.raises(FMICallException):
            ctrl.fmu.doStep(0.0, 2e-3)
        text = "\n".join(ctrl.log.entries)
        assert "communication step 0.002 s refused" in text and "sample period Ts = 0.001 s" in text, text
    finally:
        ctrl.close()


def test_a_tuned_kp_changes_tau_as_the_law_says(made):
    """Eq. 11 at one state: a change of Kp on the prismatic joint changes only its force, by k4 dKp e3.

    M^ couples the prismatic joint to no other (paper-notes: its column is
    ``[0, 0, k4, 0]``, ``k4 = m3 + m4`` of the nominal model), so
    ``d tau = M^ (dKp e) = [0, 0, k4 dKp e_3, 0]`` with ``e_3 = q_ref,3 - q_s,3``
    and ``q_s`` the encoder's reading ``res * round(q / res)``.
    """
    s = blocks.load_scenario(made["files"]["euler"])
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q = np.array(q_ref0, dtype=float) + np.array([1e-3, -2e-3, -0.0123456, 5e-4])
    dq = np.array(dq_ref0, dtype=float) + np.array([0.01, 0.0, -0.02, 0.0])
    res = 1e-6                                                 # paper-digital's encoder on the prismatic joint
    e3 = q_ref0[2] - res * np.rint(q[2] / res)
    k4 = s.nominal.m3 + s.nominal.m4
    ctrl = _Slave(made["controllers"]["euler"], "controller-kp")
    try:
        ctrl.fmu.setReal(ctrl.refs("q") + ctrl.refs("dq"), list(q) + list(dq))
        tau_before = np.array(ctrl.fmu.getReal(ctrl.refs("tau")))
        ctrl.fmu.setReal([ctrl.vr["kp[2]"]], [180.0 + 50.0])
        tau_after = np.array(ctrl.fmu.getReal(ctrl.refs("tau")))
        assert ctrl.fmu.getReal([ctrl.vr["kp[2]"]]) == [230.0]
    finally:
        ctrl.close()
    expected = np.array([0.0, 0.0, k4 * 50.0 * e3, 0.0])
    assert abs(expected[2]) > 1e-3                             # the check can see a wrong law
    np.testing.assert_allclose(tau_after - tau_before, expected, rtol=1e-9, atol=1e-12)


def test_a_tuned_observer_gain_changes_the_estimate_as_the_law_says(made):
    """``d_hat = Y dq_s + z`` with ``z = d_hat(0) - Y dq_s`` set at the first tick: a new Y gives ``dY dq``."""
    s = blocks.load_scenario(made["files"]["euler"])
    q_ref0, _, _ = s.trajectory.evaluate(0.0)
    dq = np.array([0.5, -0.25, 0.1, 0.2])
    ctrl = _Slave(made["controllers"]["euler"], "controller-y")
    try:
        ctrl.fmu.setReal(ctrl.refs("q") + ctrl.refs("dq"), list(q_ref0) + list(dq))
        d_hat0 = np.array(ctrl.fmu.getReal(ctrl.refs("d_hat")))
        ctrl.fmu.setReal([ctrl.vr["Y[0]"], ctrl.vr["Y[3]"]], [15.0, 4.0])
        d_hat1 = np.array(ctrl.fmu.getReal(ctrl.refs("d_hat")))
    finally:
        ctrl.close()
    np.testing.assert_allclose(d_hat0, 0.0, atol=1e-9)         # the scenario starts the estimate at 0
    # the first velocity estimate equals dq (the encoder starts consistent with it) up to rounding
    np.testing.assert_allclose(d_hat1, [5.0 * 0.5, 0.0, 0.0, -6.0 * 0.2], rtol=1e-9, atol=1e-9)


def test_a_scenario_without_controller_or_with_noise_is_refused_saying_why(tmp_path, capsys):
    out = tmp_path / "c.fmu"
    assert main(["fmu", "export-controller", "--scenario", "paper", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "scenario 'paper' has no [controller] section" in err and "paper-digital" in err
    noisy = _scenario_file(tmp_path, {"noise.q_std": [1e-5, 1e-5, 1e-6, 1e-5], "noise.seed": 3}, "pd-noise")
    assert main(["fmu", "export-controller", "--scenario", str(noisy), "--out", str(out)]) == 2
    assert "has a [noise] section: measurement noise belongs to the plant side" in capsys.readouterr().err
    assert not out.exists()


def test_stepping_past_the_reference_table_is_refused_naming_its_end(made):
    ctrl = _Slave(made["controllers"]["euler"], "controller-end")
    period = 1e-3
    try:
        ctrl.fmu.setReal(ctrl.refs("q") + ctrl.refs("dq"), [0.0, 1.5, 0.24, 0.0] + [0.0] * 4)
        ticks = int(round(_T_FINAL / period))
        for k in range(ticks):
            ctrl.fmu.doStep(k * period, period)
        assert len(ctrl.fmu.getReal(ctrl.refs("tau"))) == 4        # the last row is there
        with pytest.raises(FMICallException):
            ctrl.fmu.doStep(ticks * period, period)
        assert any("reference table ends at t = 0.5" in e for e in ctrl.log.entries), ctrl.log.entries
    finally:
        ctrl.close()
