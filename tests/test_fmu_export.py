"""The exported plant FMU: archive, model description, binary, and its numbers.

References are independent of the FMU code: the constants of docs/model.md, the
Python plant of blocks integrated with SciPy, closed-form solutions,
and the standard FMI headers shipped with fmpy.
"""
from __future__ import annotations

import ctypes
import re
import shlex
import subprocess
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from conftest import PAPER_FR, PAPER_G, PAPER_K
from fmpy import read_model_description
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from blocks.diagram.systems import plant as python_plant
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.rrpr.parameters import RobotParameters
from fmu import FMUBuildError, FMUInstance, FMUStepError, check_fmu, export_plant, load

STATES = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]
X0 = np.array([0.3, 1.1, 0.05, 0.2, 0.5, -0.4, 0.1, 0.3])
PLATFORM = {2: fmpy.platform, 3: fmpy.platform_tuple}     # binaries/ folder names, as fmpy looks for them
LIBRARY = "dobkit_plant" + fmpy.sharedLibraryExtension
# the end stop of d3 switched off: runs that push the slide past its 0.48 m stroke compare the arm's dynamics alone
NO_STOPS = {"stop_stiffness[2]": 0.0, "stop_damping[2]": 0.0}


def torque(t):
    """A test input (N m, N m, N, N m) that keeps joint 3 near its start (gravity and f_r compensated)."""
    return np.array([2.0 * np.sin(3 * t), 1.5 * np.cos(2 * t), -0.25 * 9.8 - 1.4 + 0.5 * np.sin(5 * t),
                     0.3 * np.sin(t)])


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    return {v: export_plant(folder / f"plant_fmi{v}.fmu", fmi_version=v) for v in (2, 3)}


def integrate(rhs, x0, t_final, t_eval=None):
    sol = solve_ivp(rhs, (0.0, t_final), x0, method="DOP853", rtol=1e-11, atol=1e-12, t_eval=t_eval)
    assert sol.success, sol.message
    return sol.y


# --- archive and model description -----------------------------------------------------------------------

@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_fmpy_validation_finds_no_problem(fmus, version):
    assert validate_fmu(str(fmus[version])) == []


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_archive_holds_binary_and_rebuildable_sources(fmus, version):
    names = set(zipfile.ZipFile(fmus[version]).namelist())
    assert f"binaries/{PLATFORM[version]}/{LIBRARY}" in names
    for name in ("plant_model.c", "plant_instance.c", "plant_state.c", f"fmi{version}_plant.c",
                 f"fmi{version}_common.c", f"fmi{version}_common.h", "plant_config.h", "BUILD.txt"):
        assert f"sources/{name}" in names
    header = zipfile.ZipFile(fmus[version]).read(f"sources/fmi{version}Functions.h").decode()
    assert "2-Clause BSD License" in header        # the standard headers keep their notice
    assert ("sources/buildDescription.xml" in names) == (version == 3)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_every_function_of_the_standard_header_is_exported(fmus, version, tmp_path):
    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    declared = re.findall(rf"FMI{version}_Export\s+\w+TYPE\s+(\w+);", header)
    assert len(declared) == (44 if version == 2 else 75)
    with zipfile.ZipFile(fmus[version]) as zf:
        lib = tmp_path / LIBRARY
        lib.write_bytes(zf.read(f"binaries/{PLATFORM[version]}/{LIBRARY}"))
    dll = ctypes.CDLL(str(lib))
    missing = [name for name in declared if not hasattr(dll, name)]
    assert missing == []


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_the_build_command_rebuilds_every_function_from_the_shipped_sources(fmus, version, tmp_path):
    """The sources/ folder alone (shared FMI layer files included) rebuilds a binary with the whole standard API."""
    rebuilt = rebuild_from_sources(fmus[version], tmp_path)
    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    declared = re.findall(rf"FMI{version}_Export\s+\w+TYPE\s+(\w+);", header)
    dll = ctypes.CDLL(str(rebuilt))
    assert [name for name in declared if not hasattr(dll, name)] == []
    # the layer's hooks into the shared entry points stay private (-fvisibility=hidden)
    assert not hasattr(dll, f"fmi{version}_layer_refuse")


def rebuild_from_sources(fmu_path, folder):
    """Unpack an FMU's sources/ into ``folder`` and run the compile command its BUILD.txt gives; the library."""
    with zipfile.ZipFile(fmu_path) as zf:
        for name in zf.namelist():
            if name.startswith("sources/"):
                (folder / name.split("/", 1)[1]).write_bytes(zf.read(name))
    command = next(line.strip() for line in (folder / "BUILD.txt").read_text().splitlines()
                   if line.strip().startswith("cc "))
    argv = shlex.split(command)
    subprocess.run(argv, cwd=folder, check=True, capture_output=True)
    return folder / argv[argv.index("-o") + 1]


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_model_description_names_units_and_interfaces(fmus, version):
    md = read_model_description(str(fmus[version]))
    assert md.modelExchange is not None and md.coSimulation is not None
    assert md.variableNamingConvention == "structured"
    var = {v.name: v for v in md.modelVariables}
    units = {u.name: u.baseUnit for u in md.unitDefinitions}
    # one-to-one with the Python signal names, SI units per joint kind
    for i in range(4):
        prismatic = i == 2
        assert var[f"q[{i}]"].unit == ("m" if prismatic else "rad")
        assert var[f"dq[{i}]"].unit == ("m/s" if prismatic else "rad/s")
        assert var[f"tau[{i}]"].causality == "input" and var[f"tau[{i}]"].unit == ("N" if prismatic else "N.m")
        assert var[f"tau_dis[{i}]"].causality == "output"
    assert (units["N.m"].kg, units["N.m"].m, units["N.m"].s) == (1, 2, -2)
    for name in RobotParameters.names():
        assert var[name].causality == "parameter" and var[name].unit is not None, name
    for name in ["friction_velocity", "skin_height", "tissue_stiffness", "tissue_damping", "tissue_drag"] + \
            [f"{b}[{i}]" for b in ("f_r", "coulomb", "viscous") for i in range(4)]:
        assert var[name].causality == "parameter", name
    for kind in ("paper", "friction", "tissue"):
        assert var[f"disturbance_{kind}"].type == "Boolean"
    assert var["n_substeps"].type == ("Integer" if version == 2 else "Int32")
    # the plant has no direct feedthrough: no output depends on an input
    inputs = {f"tau[{i}]" for i in range(4)}
    for out in md.outputs:
        assert out.dependencies is not None and not inputs & {v.name for v in out.dependencies}


@pytest.mark.needs_cc
def test_token_is_a_hash_of_sources_and_parameters(tmp_path):
    a = export_plant(tmp_path / "a.fmu")
    b = export_plant(tmp_path / "b.fmu")
    c = export_plant(tmp_path / "c.fmu", params=RobotParameters(m1=6.0))
    guid = {p: read_model_description(str(p)).guid for p in (a, b, c)}
    assert guid[a] == guid[b] != guid[c]
    assert guid[a] in zipfile.ZipFile(a).read("sources/plant_config.h").decode()


# --- numbers ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_inertia_constants_match_the_model_facts_and_follow_table1(fmus, version):
    with FMUInstance(fmus[version], "ModelExchange") as f:
        k = f.get_real(f.value_references(["k1", "k2", "k3", "k4", "k5"]))
    np.testing.assert_allclose(k, [PAPER_K[n] for n in ("k1", "k2", "k3", "k4", "k5")], rtol=0, atol=1e-12)
    # k1 contains m1 l1^2: raising m1 by 1 kg raises k1 by l1^2 = 0.25 kg m^2
    with FMUInstance(fmus[version], "ModelExchange", start_values={"m1": 5.58 + 1.0}) as f:
        k1 = f.get_real(f.value_references(["k1"]))[0]
    assert k1 == pytest.approx(PAPER_K["k1"] + 0.25, abs=1e-12)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("kinds", [("paper",), ("paper", "friction", "tissue"), ()])
@pytest.mark.needs_cc
def test_model_exchange_matches_python_plant(fmus, version, kinds):
    # the tool starts 2 mm below the skin and is pressed into it (3 N): the contact model is active throughout
    spec = DisturbanceSpec(kinds=kinds, skin_height=0.12 - 0.048 - 0.271)
    push = np.array([0.0, 0.0, 3.0, 0.0])
    start = dict(zip(STATES, X0)) | {f"disturbance_{k}": k in kinds for k in ("paper", "friction", "tissue")} \
        | {"skin_height": spec.skin_height} | NO_STOPS
    fmu = load(fmus[version], start_values=start)
    py = python_plant(RobotParameters(), spec)
    t_eval = np.linspace(0.0, 1.0, 51)
    y_fmu = integrate(lambda t, x: fmu._rhs(t, x, torque(t) + push), X0, 1.0, t_eval)
    y_py = integrate(lambda t, x: py._rhs(t, x, torque(t) + push), X0, 1.0, t_eval)
    assert np.max(np.abs(y_fmu - y_py)) < 1e-6
    dis = [list(fmu.output_labels).index(f"tau_dis[{i}]") for i in range(4)]
    contact = []
    for k in range(0, 51, 5):
        t, x = t_eval[k], y_py[:, k]
        expected = py._out(t, x, torque(t))[8:]
        np.testing.assert_allclose(fmu._out(t, x, torque(t))[dis], expected, atol=1e-12)
        contact.append(abs(expected[2] - (1.4 if "paper" in kinds else 0.0)) > 0.5)
    assert all(contact) == ("tissue" in kinds)
    fmu.fmu.close()


@pytest.mark.needs_cc
def test_changed_table1_parameter_changes_the_dynamics(fmus):
    params = RobotParameters(m2=1.2, I4=1.3, l2=0.25)
    fmu = load(fmus[2], start_values=dict(zip(STATES, X0)) | {"m2": 1.2, "I4": 1.3, "l2": 0.25})
    py = python_plant(params, DisturbanceSpec())
    y_fmu = integrate(lambda t, x: fmu._rhs(t, x, torque(t)), X0, 0.5)
    y_py = integrate(lambda t, x: py._rhs(t, x, torque(t)), X0, 0.5)
    assert np.max(np.abs(y_fmu[:, -1] - y_py[:, -1])) < 1e-6
    fmu.fmu.close()


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_fmpy_simulates_both_interfaces(fmus, version):
    # zero torque from rest: joint 3 is decoupled, q3'' = (f_r3 + k4 g) / k4, so d3(t) = d3(0) + 7.7 t^2 (m),
    # d3(0) = 0.24 m in the default start pose (Table 1's d3), until it reaches its end stop at 0.48 m (t = 0.177 s)
    a = (PAPER_FR[2] + PAPER_K["k4"] * PAPER_G) / PAPER_K["k4"]
    for fmi_type, tol in (("ModelExchange", 1e-5), ("CoSimulation", 1e-10)):
        res = fmpy.simulate_fmu(str(fmus[version]), fmi_type=fmi_type, stop_time=0.17, output_interval=0.01,
                                relative_tolerance=1e-8, output=["q[2]", "tau_dis[0]"])
        np.testing.assert_allclose(res["q[2]"], 0.24 + 0.5 * a * res["time"] ** 2, atol=tol)
        np.testing.assert_allclose(res["tau_dis[0]"], PAPER_FR[0], atol=1e-12)


@pytest.mark.needs_cc
def test_co_simulation_error_falls_16_fold_per_halved_substep(fmus):
    h, n_steps = 0.05, 20
    py = python_plant(RobotParameters(), DisturbanceSpec())
    x_ref = X0.copy()
    for k in range(n_steps):                     # exact solution under the same zero-order hold
        u = torque(k * h)
        x_ref = solve_ivp(lambda t, x: py._rhs(t, x, u), (k * h, (k + 1) * h), x_ref, method="DOP853",
                          rtol=1e-13, atol=1e-14).y[:, -1]
    errors = []
    for substeps in (1, 2, 4):
        with FMUInstance(fmus[2], "CoSimulation", start_values=dict(zip(STATES, X0)) | {"n_substeps": substeps}
                         | NO_STOPS) as f:        # d3 passes 0.48 m at t = 0.8 s
            tau_vr, x_vr = f.value_references([f"tau[{i}]" for i in range(4)]), f.value_references(STATES)
            for k in range(n_steps):
                f.set_real(tau_vr, torque(k * h))
                f.do_step(k * h, h)
            errors.append(np.max(np.abs(f.get_real(x_vr) - x_ref)))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert errors[0] < 1e-6
    assert np.all((ratios > 13) & (ratios < 19)), (errors, ratios)   # classical RK4: 2^4 = 16


@pytest.mark.needs_cc
@pytest.mark.parametrize("version", [2, 3])
def test_co_simulation_follows_the_input_slope_and_gives_exact_output_derivatives(fmus, version):
    """Over each step the torque is u_k + (t - t_k) du_k: FMI 2 through input derivatives, FMI 3 through the
    intermediate-update callback; the reference integrates the Python plant under the same ramps."""
    h, n_steps = 0.05, 10
    py = python_plant(RobotParameters(), DisturbanceSpec(kinds=("paper", "friction")))
    start = dict(zip(STATES, X0)) | {"disturbance_friction": True, "n_substeps": 32}
    x_ref = X0.copy()
    slopes = [np.array([3.0, -2.0, 4.0, 1.0]) * np.cos(k * h) for k in range(n_steps)]
    for k in range(n_steps):
        t0, u0, du = k * h, torque(k * h), slopes[k]
        x_ref = solve_ivp(lambda t, x: py._rhs(t, x, u0 + (t - t0) * du), (t0, t0 + h), x_ref, method="DOP853",
                          rtol=1e-13, atol=1e-14).y[:, -1]
    with FMUInstance(fmus[version], "CoSimulation", start_values=start) as f:
        tau_vr, x_vr = f.value_references([f"tau[{i}]" for i in range(4)]), f.value_references(STATES)
        assert f.max_output_derivative_order == 1
        assert f.can_interpolate_inputs if version == 2 else f.provides_intermediate_update
        for k in range(n_steps):
            t0, u0, du = k * h, torque(k * h), slopes[k]
            f.set_real(tau_vr, u0)
            if version == 2:
                f.set_input_derivatives(tau_vr, du)
            else:
                f.set_input_provider(tau_vr, lambda t, t0=t0, u0=u0, du=du: u0 + (t - t0) * du)
            f.do_step(t0, h)
        x = f.get_real(x_vr)
        # RK4 with 32 sub-steps (the friction is stiff): measured 5.6e-9; the slopes move x by 1.9e-2
        np.testing.assert_allclose(x, x_ref, rtol=0, atol=2e-8)
        # derivatives at the end of the step, with the input at its end value: dq and the plant's acceleration
        t_end, u_end = n_steps * h, torque((n_steps - 1) * h) + h * slopes[-1]
        np.testing.assert_allclose(f.get_real(tau_vr), u_end, rtol=0, atol=1e-12)
        dy = f.get_output_derivatives(f.value_references(STATES + ["tau_dis[0]"]))
        expected = py._rhs(t_end, x, u_end)
        np.testing.assert_allclose(dy[:8], expected, rtol=1e-12, atol=1e-12)
        # tau_dis[0] = f_r - coulomb tanh(dq/v_s) - viscous dq: its rate follows the acceleration
        d = DisturbanceSpec(kinds=("paper", "friction"))
        rate = -(d.coulomb[0] / d.friction_velocity / np.cosh(x[4] / d.friction_velocity) ** 2 + d.viscous[0]) \
            * expected[4]
        assert dy[8] == pytest.approx(rate, rel=1e-6)
        from fmpy.fmi1 import FMICallException
        with pytest.raises(FMICallException):                  # only the first derivative is offered
            f._fmu.getRealOutputDerivatives([x_vr[0]], [2]) if version == 2 else \
                f._fmu.getOutputDerivatives([x_vr[0]], [2])
        assert "maxOutputDerivativeOrder is 1" in f.messages[-1]


@pytest.mark.needs_cc
def test_fmu_state_can_be_saved_and_restored(fmus):
    with FMUInstance(fmus[2], "CoSimulation", start_values=dict(zip(STATES, X0))) as f:
        x_vr = f.value_references(STATES)
        f.do_step(0.0, 0.1)
        saved = f._fmu.getFMUstate()
        blob = f._fmu.serializeFMUstate(saved)
        x1 = f.get_real(x_vr)
        f.do_step(0.1, 0.1)
        assert np.max(np.abs(f.get_real(x_vr) - x1)) > 1e-3
        f._fmu.setFMUstate(f._fmu.deSerializeFMUstate(blob))
        np.testing.assert_array_equal(f.get_real(x_vr), x1)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.needs_cc
def test_check_fmu_reports_validation_and_both_comparisons(fmus, version):
    # 0.15 s: with zero torque (the me_vs_cs runs) d3 reaches its end stop at 0.177 s, an impact RK4 at 0.01 s
    # resolves only to about 1 % (tests/test_fmu_end_stops.py)
    report = check_fmu(fmus[version], t_final=0.15)
    assert report["passed"] and report["validation"] == {"problems": [], "errors": [], "warnings": [],
                                                         "passed": True}
    assert report["fmi_version"] == f"{version}.0" and report["interfaces"] == ["ModelExchange", "CoSimulation"]
    me, cs = report["model_exchange"], report["co_simulation"]
    assert me["loads"] and me["states"] == 8 and me["feedthrough"] == [] and me["run"]["finite"]
    assert cs["runs"] and cs["couples"] and cs["run"]["steps"] == 100
    # under the same inputs (held at their start values) the two interfaces agree to the CS RK4 error
    assert report["me_vs_cs"]["passed"] and report["me_vs_cs"]["max_abs_difference"] < 1e-7
    plant = report["plant_comparison"]
    assert plant["model_exchange"]["max_abs_error"] < 1e-6
    assert plant["co_simulation"]["max_abs_error"] < 1e-6 and plant["co_simulation"]["n_substeps"] == 4


# --- refusals ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("start, words", [({"friction_velocity": 0.0}, "friction_velocity must be > 0"),
                                          ({"n_substeps": 0}, "n_substeps"),
                                          ({"m3": -1.0}, "m3 must be > 0"),
                                          ({"tissue_damping": -2.0}, "tissue_damping must be >= 0")])
@pytest.mark.needs_cc
def test_impossible_parameters_are_refused_at_initialization(fmus, start, words):
    with pytest.raises(FMUStepError, match="initialization") as err:
        FMUInstance(fmus[3], "CoSimulation", start_values=start)
    assert words in str(err.value) and err.value.time == 0.0 and err.value.status == "error"


@pytest.mark.needs_cc
def test_fixed_parameter_cannot_change_after_initialization(fmus):
    with FMUInstance(fmus[2], "CoSimulation") as f:
        with pytest.raises(FMUStepError, match="fixed parameter"):
            f.set_real(f.value_references(["m1"]), [6.0])


def test_missing_compiler_gives_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(FMUBuildError, match="CC environment variable"):
        export_plant(tmp_path / "p.fmu")
    monkeypatch.setenv("CC", "false")            # a compiler that fails
    with pytest.raises(FMUBuildError, match="compiling the FMU failed"):
        export_plant(tmp_path / "p.fmu")
    assert not (tmp_path / "p.fmu").exists()


def test_bad_export_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match="fmi_version"):
        export_plant(tmp_path / "p.fmu", fmi_version=1)
    with pytest.raises(ValueError, match="substeps"):
        export_plant(tmp_path / "p.fmu", substeps=0)

