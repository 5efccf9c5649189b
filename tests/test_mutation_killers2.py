"""Tests written for the mutants the second pass of tests/mutation_probe.py found alive.

Each test names the mutant(s) it kills (``python tests/mutation_probe.py --only ID --killers`` shows it) and
checks a number against a derivation of its own: the FMI standard's rules and scipy's integrators for the
FMUs, closed forms and finite differences for the paths and the digital controller, scipy's RK45 step by
step for the compiled engine's Dormand-Prince stepper, scipy.stats for the sweep statistics.
"""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from scipy.integrate import solve_ivp

import blocks
from blocks.disturbances import DisturbanceSpec
from blocks.parameters import RobotParameters
from blocks.systems import plant as python_plant

STATES = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]
X0 = np.array([0.3, 1.1, 0.05, 0.2, 0.5, -0.4, 0.1, 0.3])


# ==============================================================================================================
# The plant FMU's C instance and saved states (fmu/c/plant_instance.c, plant_state.c, fmi2/3_common.c)
# ==============================================================================================================
@pytest.fixture(scope="module")
def plant_fmus(tmp_path_factory):
    """The plant exported now from the C sources in the tree (no cache: every session compiles them)."""
    from fmu import export_plant

    folder = tmp_path_factory.mktemp("killers2-plant")
    return {v: export_plant(folder / f"plant{v}.fmu", fmi_version=v) for v in (2, 3)}


def _paper_rhs():
    return python_plant(RobotParameters(), DisturbanceSpec(kinds=("paper",)))._rhs


@pytest.mark.needs_cc
def test_a_new_input_value_without_a_slope_is_held_over_the_step(plant_fmus):
    """c-set-input-keeps-slope.  FMI 2.0.4 section 4.2.1: after fmi2SetReal of an input its derivatives are
    reset to zero (a value set without derivatives is held).  Step 1 ramps the torque, step 2 sets a new value
    only: the reference integrates the Python plant under exactly that (SciPy, DOP853)."""
    from fmu import FMUInstance

    rhs, h = _paper_rhs(), 0.05
    u0, du = np.array([1.0, -0.5, -4.0, 0.2]), np.array([30.0, -20.0, 40.0, 10.0])
    u1 = np.array([0.5, 0.5, -3.5, -0.1])
    x = solve_ivp(lambda t, x: rhs(t, x, u0 + t * du), (0.0, h), X0, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
    x_ref = solve_ivp(lambda t, x: rhs(t, x, u1), (h, 2 * h), x, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
    start = dict(zip(STATES, X0)) | {"n_substeps": 32}
    with FMUInstance(plant_fmus[2], "CoSimulation", start_values=start) as f:
        tau = f.value_references([f"tau[{i}]" for i in range(4)])
        f.set_real(tau, u0)
        f.set_input_derivatives(tau, du)
        f.do_step(0.0, h)
        f.set_real(tau, u1)
        f.do_step(h, h)
        got = f.get_real(f.value_references(STATES))
    # RK4 with 32 sub-steps of a smooth plant: ~1e-10; a slope kept over step 2 moves q by du h^2 / 2 / M ~ 1e-2
    np.testing.assert_allclose(got, x_ref, rtol=0, atol=1e-7)


@pytest.mark.needs_cc
@pytest.mark.parametrize("version", [2, 3])
def test_do_step_refuses_a_zero_step_and_a_step_from_another_time(plant_fmus, version):
    """c-dostep-zero-h, c-dostep-time-check.  FMI: communicationStepSize > 0, and currentCommunicationPoint is
    the time the FMU is at.  Called on fmpy's own doStep (below dobkit's wrapper, which checks nothing of it)."""
    from fmu import FMUInstance

    with FMUInstance(plant_fmus[version], "CoSimulation", start_values=dict(zip(STATES, X0))) as f:
        fm = f._fmu
        with pytest.raises(FMICallException):
            fm.doStep(0.0, 0.0)
        with pytest.raises(FMICallException):
            fm.doStep(0.05, 0.01)               # the FMU is at t = 0
    with FMUInstance(plant_fmus[version], "CoSimulation", start_values=dict(zip(STATES, X0))) as f:
        f.do_step(0.0, 0.01)                    # an ordinary step still works, and ends at 0.01 s
        assert f.time == pytest.approx(0.01)


def _blob(f) -> bytearray:
    fm = f._fmu
    if f.fmi_version == 2:
        return bytearray(fm.serializeFMUstate(fm.getFMUstate()))
    return bytearray(fm.serializeFMUState(fm.getFMUState()))


def _restore(f, data) -> None:
    fm = f._fmu
    if f.fmi_version == 2:
        fm.setFMUstate(fm.deSerializeFMUstate(bytes(data)))
    else:
        fm.setFMUState(fm.deserializeFMUState(bytes(data)))


@pytest.mark.needs_cc
@pytest.mark.parametrize("version", [2, 3])
def test_a_serialized_state_with_a_switch_of_two_or_without_its_magic_is_refused(plant_fmus, version):
    """c-restore-switch-check, c-state-magic.  The switch's offset is found by comparing two real states that
    differ only in ``disturbance_friction`` (a Boolean: 0 or 1, nothing else); the magic is the state's first
    bytes.  An untouched state is still restored."""
    from fmu import FMUInstance

    with FMUInstance(plant_fmus[version], "CoSimulation") as off, \
            FMUInstance(plant_fmus[version], "CoSimulation", start_values={"disturbance_friction": True}) as on:
        a, b = _blob(off), _blob(on)
        diff = [i for i in range(len(a)) if a[i] != b[i]]
        assert len(diff) == 1 and (a[diff[0]], b[diff[0]]) == (0, 1), diff
        switch = bytearray(a)
        switch[diff[0]] = 2
        with pytest.raises(FMICallException):
            _restore(off, switch)
        magic = bytearray(a)
        magic[0] ^= 0xFF
        fm = off._fmu
        with pytest.raises(FMICallException):                 # refused when deserialized, not only when set
            fm.deSerializeFMUstate(bytes(magic)) if version == 2 else fm.deserializeFMUState(bytes(magic))
        _restore(off, b)                      # the friction state of the other instance, untouched: accepted
        off.do_step(0.0, 0.01)


@pytest.mark.needs_cc
def test_serializing_into_a_buffer_of_another_size_is_refused(plant_fmus):
    """c-state-size-lt.  fmi2SerializeFMUstate gets the size fmi2SerializedFMUstateSize gave; any other size is
    a caller's error the FMU reports (a larger one too: the caller would store bytes that are not the state)."""
    from fmu import FMUInstance

    with FMUInstance(plant_fmus[2], "CoSimulation") as f:
        fm = f._fmu
        state = fm.getFMUstate()
        size = ctypes.c_size_t()
        fm.fmi2SerializedFMUstateSize(fm.component, state, ctypes.byref(size))
        for wrong in (size.value + 8, size.value - 8):
            buffer = ctypes.create_string_buffer(size.value + 8)
            with pytest.raises(FMICallException):
                fm.fmi2SerializeFMUstate(fm.component, state, buffer, ctypes.c_size_t(wrong))
        buffer = ctypes.create_string_buffer(size.value)
        fm.fmi2SerializeFMUstate(fm.component, state, buffer, size)
        fm.freeFMUstate(state)


@pytest.mark.needs_cc
def test_fmi2_status_reports_the_last_successful_time_and_a_failed_step(plant_fmus):
    """c-fmi2-last-time, c-fmi2-status.  FMI 2 section 4.2.3: fmi2LastSuccessfulTime is the time of the last
    completed step; fmi2DoStepStatus after a step that returned fmi2Error is fmi2Error."""
    from fmu import FMUInstance, FMUStepError

    with FMUInstance(plant_fmus[2], "CoSimulation", start_values=dict(zip(STATES, X0))) as f:
        for k in range(3):
            f.do_step(0.01 * k, 0.01)
        fm = f._fmu
        assert fm.getRealStatus(2) == pytest.approx(0.03, abs=1e-15)      # 2 = fmi2LastSuccessfulTime
        f.set_real(f.value_references(["tau[0]"]), [1e300])               # q' overflows within the step
        with pytest.raises(FMUStepError):
            f.do_step(0.03, 0.01)
        status = ctypes.c_int(-1)
        fm.fmi2GetStatus(fm.component, 0, ctypes.byref(status))           # 0 = fmi2DoStepStatus
        assert status.value == 3                                          # 3 = fmi2Error


@pytest.mark.needs_cc
def test_fmi3_do_step_returns_the_time_it_reached(plant_fmus):
    """c-fmi3-last-time.  FMI 3 fmi3DoStep: without early return, lastSuccessfulTime = t + h."""
    from fmu import FMUInstance

    with FMUInstance(plant_fmus[3], "CoSimulation", start_values=dict(zip(STATES, X0))) as f:
        f.do_step(0.0, 0.02)
        result = f._fmu.doStep(0.02, 0.03)
        assert result[3] == pytest.approx(0.05, abs=1e-15)


# ==============================================================================================================
# The controller FMU's core (fmu/c/controller_core.c)
# ==============================================================================================================
@pytest.fixture(scope="module")
def controller_fmu(tmp_path_factory):
    """``paper-digital`` cut to 0.2 s (Ts = 1 ms: 200 ticks), exported now as an FMI 2 controller."""
    from dobkit.cli import main

    folder = tmp_path_factory.mktemp("killers2-controller")
    s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.2})
    scenario = folder / "short.toml"
    scenario.write_text(s.to_toml().replace('name = "paper-digital"', 'name = "short"', 1), encoding="utf-8")
    out = folder / "controller.fmu"
    assert main(["fmu", "export-controller", "--scenario", str(scenario), "--out", str(out)]) == 0
    return out, s.controller.period


def _controller(path):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="killer")
    fmu.instantiate()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return fmu, vr


@pytest.mark.needs_cc
def test_the_controller_runs_only_at_its_sample_period_and_its_time_is_in_seconds(controller_fmu):
    """c-ctrl-step-period, c-ctrl-time.  One doStep is one sample: h = Ts (to rounding), not 5 % more or less;
    after k samples the FMU's ``time`` is k Ts seconds."""
    path, period = controller_fmu
    fmu, vr = _controller(path)
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.setReal([vr[f"q[{i}]"] for i in range(4)] + [vr[f"dq[{i}]"] for i in range(4)],
                    [0.0, 1.5, 0.24, 0.0] + [0.0] * 4)
        for k in range(3):
            fmu.doStep(k * period, period)
        assert fmu.getReal([vr["time"]])[0] == pytest.approx(3 * period, rel=1e-12)
        for wrong in (1.05 * period, 0.95 * period):
            with pytest.raises(FMICallException):
                fmu.doStep(3 * period, wrong)
    finally:
        fmu.terminate()
        fmu.freeInstance()


@pytest.mark.needs_cc
def test_a_stop_time_past_the_reference_table_is_refused(controller_fmu):
    """c-ctrl-stop-time.  The reference table ends at t_final = 0.2 s: a stopTime of 0.3 s cannot be served."""
    path, _ = controller_fmu
    fmu, _ = _controller(path)
    try:
        with pytest.raises(FMICallException):
            fmu.setupExperiment(startTime=0.0, stopTime=0.3)      # fmi2SetupExperiment checks it
    finally:
        fmu.freeInstance()
    fmu, _ = _controller(path)
    try:
        fmu.setupExperiment(startTime=0.0, stopTime=0.2)          # its own end is fine
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.terminate()
    finally:
        fmu.freeInstance()


# ==============================================================================================================
# Start values (fmu/start_values.py)
# ==============================================================================================================
def test_the_largest_float32_is_a_float32_start_value_and_the_next_double_is_not():
    """sv-float32-max.  IEEE 754 binary32's largest finite value (numpy's finfo) is in the type; a double just
    above it is not."""
    from types import SimpleNamespace

    from fmu.errors import FMUStartValueError
    from fmu.start_values import checked_start_value

    var = SimpleNamespace(name="x", type="Float32")
    top = float(np.finfo(np.float32).max)
    assert checked_start_value(var, top, 3) == [top]
    assert checked_start_value(var, -top, 3) == [-top]
    with pytest.raises(FMUStartValueError, match="outside the Float32 range"):
        checked_start_value(var, float(np.nextafter(top, np.inf)), 3)


# ==============================================================================================================
# The compiled engine's Dormand-Prince stepper (blocks/compiled/dopri.py), step by step against scipy's RK45
# ==============================================================================================================
def _van_der_pol(mu: float):
    """Forced (so that the stage times c_i matter): y0'' = mu (1 - y0^2) y0' - y0 + 1.5 cos 2t."""
    def f(t, y):
        return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0] + 1.5 * np.cos(2.0 * t)])
    return f


def _dopri_text_as_python(f):
    """The stepper's source as the code generator reads it, run as plain Python on the right-hand side ``f``."""
    from blocks.compiled.codegen import _template_text

    space: dict = {}
    exec(compile(_template_text(), "dopri.py", "exec"), space)        # the file on disk, as every loop module gets it

    def step_rhs(t, x, theta, ext, src, work, aux, out):
        out[:] = f(t, x)

    def loop_sources(t, theta, ext, work, src):
        pass

    def loop_rhs(t, x, theta, src, ext, work, out):
        out[:] = f(t, x)

    space.update(step_rhs=step_rhs, loop_sources=loop_sources, loop_rhs=loop_rhs)
    return space


@pytest.mark.parametrize("mu, rtol, atol", [(1.0, 1e-6, 1e-9), (8.0, 1e-4, 1e-7)])
def test_dormand_prince_steps_are_scipys_rk45_steps(mu, rtol, atol):
    """dp-a31, dp-c4, dp-b4-sign, dp-e-typo, dp-p-sign, dp-safety, dp-max-factor, dp-rejected-cap, dp-dense-p3,
    dp-h0-factor, dp-h1-order, dp-err-scale, dp-rms-n.  The module docstring promises scipy's RK45: its tableau,
    error norm, step control and initial step.  scipy.integrate.RK45 is stepped beside ``dp_step`` on the
    Van der Pol oscillator (stiff-ish at mu = 8, so that steps get rejected): every step's end time, state,
    next step size and dense output agree to rounding."""
    from scipy.integrate import RK45

    f = _van_der_pol(mu)
    ns = _dopri_text_as_python(f)
    t, y, t_bound, max_step = 0.0, np.array([2.0, 0.0]), 6.0, np.inf
    ref = RK45(f, t, y.copy(), t_bound, rtol=rtol, atol=atol)
    n = y.size
    f0, f1 = f(t, y), np.zeros(n)
    h_abs = ns["initial_step"](t, y, f0, t_bound, max_step, rtol, atol, None, None, None, None, f1)
    assert h_abs == pytest.approx(ref.h_abs, rel=1e-12)
    K, y_new, f_new = np.zeros((7, n)), np.zeros(n), np.zeros(n)
    y_stage, err, out, y_old, Q, X = np.zeros(n), np.zeros(n), np.zeros(4), np.zeros(n), np.zeros((n, 4)), np.zeros((n, 1))
    rejected = steps = 0
    while ref.status == "running":
        # each step from scipy's own (t, y, f, h): a comparison of one step, no drift of rounding across steps
        t, y, f0, h_abs = ref.t, ref.y.copy(), ref.f.copy(), ref.h_abs
        ref.step()
        ok = ns["dp_step"](t, t_bound, h_abs, max_step, rtol, atol, y, f0, None, None, None, None, None, K, y_new,
                           f_new, y_stage, err, out)
        assert ok
        rejected += out[3] > 6
        np.testing.assert_allclose(out[0], ref.t, rtol=1e-13, atol=0)
        np.testing.assert_allclose(y_new, ref.y, rtol=1e-10, atol=1e-12)
        if ref.status == "running":
            np.testing.assert_allclose(out[1], ref.h_abs, rtol=1e-7)    # error_norm ** -0.2: its cancellation
        ns["dense_coefficients"](K, y, y_old, Q)
        dense = ref.dense_output()
        for frac in (0.3, 0.77):
            tm = t + frac * out[2]
            ns["dense_into"](Q, y_old, out[2], t, tm, X, 0)
            np.testing.assert_allclose(X[:, 0], dense(tm), rtol=1e-10, atol=1e-12)
        t = out[0]
        steps += 1
    assert ref.status == "finished" and t == t_bound
    assert steps > 20 and (mu < 2 or rejected > 0), (steps, rejected)      # the step control was exercised


def test_the_first_step_is_scipys_initial_step():
    """dp-h1-order, dp-h0-factor.  ``initial_step`` is scipy's select_initial_step (Hairer, Norsett, Wanner II.4,
    order 4 error estimator): over starts and tolerances where each of its candidates 100 h0 and h1 binds."""
    from scipy.integrate import RK45

    f = _van_der_pol(1.0)
    ns = _dopri_text_as_python(f)
    for y0 in ([2.0, 0.0], [1e-3, 5.0], [0.5, 0.5], [30.0, -1.0]):
        for rtol, atol in ((1e-3, 1e-6), (1e-8, 1e-12), (1e-2, 1e-2)):
            y0 = np.asarray(y0, dtype=float)
            ref = RK45(f, 0.0, y0, 10.0, rtol=rtol, atol=atol)
            h = ns["initial_step"](0.0, y0, f(0.0, y0), 10.0, np.inf, rtol, atol, None, None, None, None, np.zeros(2))
            assert h == pytest.approx(ref.h_abs, rel=1e-12), (y0, rtol, atol)


# ==============================================================================================================
# The tool path of a URDF arm (blocks/tool_path.py)
# ==============================================================================================================
def test_the_tool_paths_velocity_and_acceleration_are_the_derivatives_of_its_position():
    """tp-dds-T.  Segments of 1.5 s (not 1 s, where p''/T and p''/T^2 agree): p' and p'' against central
    differences of p and p' (the smoothstep is C2, so inside a segment the differences converge as h^2)."""
    pytest.importorskip("pinocchio")
    from blocks.scenario import scenario_from_dict

    s = scenario_from_dict({
        "arm": {"urdf": "example:scope4", "tool_frame": "tool_tip"},
        "trajectory": {"kind": "tool_path", "duration": 3.0, "sample_period": 0.05,
                       "waypoints": [[-0.045, 0.0, -0.148], [-0.03, 0.02, -0.16], [-0.045, 0.0, -0.148]]},
        "simulation": {"t_final": 3.0}})
    path, h = s.trajectory, 1e-5
    t = np.array([0.2, 0.71, 1.1, 1.9, 2.6])                    # inside the two segments of 1.5 s
    p, dp, ddp = path.task_space(t)
    p_plus, dp_plus, _ = path.task_space(t + h)
    p_minus, dp_minus, _ = path.task_space(t - h)
    np.testing.assert_allclose(dp, (p_plus - p_minus) / (2 * h), rtol=0, atol=1e-9)
    np.testing.assert_allclose(ddp, (dp_plus - dp_minus) / (2 * h), rtol=0, atol=1e-8)
    assert np.max(np.abs(ddp)) > 1e-3                          # a path that accelerates: the check means something


# ==============================================================================================================
# Sweep statistics (analysis/sweep/summary.py)
# ==============================================================================================================
def test_sweep_statistics_worst_runs_and_influence_are_the_textbook_ones():
    """su-std-ddof, su-p95, su-ranks-ties, su-mean-scale, su-worst-order.  Against Python's statistics module
    (mean, sample standard deviation, median, the 5 % and 95 % cut points of the inclusive -- linear -- method)
    and scipy.stats.spearmanr (ties get their mean rank); the worst runs are the largest values, largest first."""
    import statistics

    from scipy.stats import spearmanr

    from analysis.sweep.summary import summarize

    rng = np.random.default_rng(5)
    kp = np.repeat([100.0, 120.0, 140.0, 160.0, 180.0, 200.0, 220.0], 3)         # a swept key with ties
    metric = np.round(30.0 + 0.05 * kp + rng.normal(0.0, 4.0, kp.size), 1)     # mm; rounded: ties here too
    rows = [{"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": float(kp[i])}, "status": "ok",
             "metrics": {"max_tool_position_error_mm": float(metric[i])}} for i in range(kp.size)]
    header = {"name": "h", "runs": len(rows), "worst_metric": "max_tool_position_error_mm", "worst_count": 4}
    summary = summarize((header, rows))
    st = summary.statistics["max_tool_position_error_mm"]
    data = metric.tolist()
    cuts = statistics.quantiles(data, n=20, method="inclusive")
    assert st.mean == pytest.approx(statistics.fmean(data), rel=1e-12)
    assert st.std == pytest.approx(statistics.stdev(data), rel=1e-12)
    assert st.median == pytest.approx(statistics.median(data), rel=1e-12)
    assert st.p5 == pytest.approx(cuts[0], rel=1e-12) and st.p95 == pytest.approx(cuts[-1], rel=1e-12)
    expected = sorted(range(kp.size), key=lambda i: -metric[i])[:4]
    assert [w.value for w in summary.worst] == [metric[i] for i in expected]
    assert summary.influence["gains.kp"] == pytest.approx(spearmanr(kp, metric).statistic, rel=1e-12)


# ==============================================================================================================
# The redundant arm's resolved-rate law (blocks/arms/resolved_rate.py)
# ==============================================================================================================
def test_the_resolved_rate_acceleration_is_the_derivative_of_the_rate_along_the_motion_off_the_path():
    """rr-dv-feedback.  ``q''`` of ``rates`` is d/dt F(t, q(t)) along q' = F: a central difference of ``rate``
    at (t +- h, q +- h q').  Off the path (a task error of ~1 cm) the feedback's rate K_p (p' - J q') = -K_p^2 e
    is a large part of it (on the path it vanishes, which is why the loop tests cannot see it)."""
    pytest.importorskip("pinocchio")
    from blocks.arms import example_arm
    from blocks.arms.resolved_rate import ResolvedRate

    arm = example_arm("panda")
    q_rest = np.array([0.0, 0.0, 0.0, -1.6, 0.0, 1.6, 0.8])
    law = ResolvedRate(arm, task_gain=10.0, posture_gain=1.0, rest=q_rest, min_sigma=1e-6)
    centre, radius, w = arm.tool_position(q_rest) + np.array([0.0, -0.05, 0.0]), 0.05, 1.3

    def path(t):
        c, s = np.cos(w * t), np.sin(w * t)
        return (centre + radius * np.array([s, c, 0.0]), radius * w * np.array([c, -s, 0.0]),
                -radius * w * w * np.array([s, c, 0.0]))

    q = q_rest + np.array([0.02, -0.03, 0.01, 0.02, -0.02, 0.01, 0.03])
    t, h = 0.0, 1e-6
    assert np.linalg.norm(path(t)[0] - arm.tool_position(q)) > 5e-3             # really off the path
    dq, ddq = law.rates(q, *path(t))
    np.testing.assert_allclose(dq, law.rate(q, *path(t)[:2]), rtol=1e-12, atol=1e-14)
    ahead, behind = law.rate(q + h * dq, *path(t + h)[:2]), law.rate(q - h * dq, *path(t - h)[:2])
    np.testing.assert_allclose(ddq, (ahead - behind) / (2 * h), rtol=0, atol=1e-6 * np.max(np.abs(ddq)))


# ==============================================================================================================
# Tune margins (analysis/tune/evaluate.py)
# ==============================================================================================================
def test_the_damping_margin_is_that_of_the_least_damped_joint(tmp_path):
    """ev-damping-max.  The error dynamics of joint i are s^2 + kd_i s + kp_i: zeta_i = kd_i / (2 sqrt(kp_i)).
    The constraint is on every joint, so its margin is min zeta_i - zeta_min (here the stiffest joint's)."""
    from test_tune import write_problem

    from analysis.tune.evaluate import Evaluation, Evaluator
    from analysis.tune.spec import load_tuning

    search = {'"gains.kp"': [20, 2000], '"gains.kd"': [2, 80], "seed": 3, "population": 6, "max_evaluations": 60}
    spec = load_tuning(write_problem(tmp_path, search=search))
    limit = spec.limits.min_damping_ratio
    assert limit is not None                                   # the default constraint
    kp, kd = np.array([100.0, 150.0, 200.0, 250.0]), np.full(4, 20.0)
    zeta = kd / (2.0 * np.sqrt(kp))                            # 1.0, 0.816, 0.707, 0.632
    ev = Evaluation(gains={"gains.kp": kp, "gains.kd": kd}, torque_noise_rms=np.zeros(4), spectral_abscissa=-1.0,
                    damping_ratio=zeta)
    assert Evaluator(spec).margins(ev)["min_damping_ratio"] == pytest.approx(1.0 / np.sqrt(10.0) * 2 - limit,
                                                                             rel=1e-12)


def test_the_tune_score_of_an_infeasible_candidate_is_worse_than_every_feasible_one(tmp_path):
    """ev-energy-total.  The module's rule: an infeasible candidate scores INFEASIBLE (1 + total violation), above
    every feasible objective however small its violation.  A simulated candidate with errors of 1-2 mm that
    misses the damping constraint by a relative 1e-9 must still score above 1e9."""
    from test_tune import write_problem

    from analysis.tune.evaluate import INFEASIBLE, Evaluation, Evaluator
    from analysis.tune.spec import load_tuning

    search = {'"gains.kp"': [20, 2000], '"gains.kd"': [2, 80], "seed": 3, "population": 6, "max_evaluations": 60}
    spec = load_tuning(write_problem(tmp_path, search=search))
    zeta = np.full(4, spec.limits.min_damping_ratio * (1.0 - 1e-9))
    ev = Evaluation(gains={"gains.kp": 100.0, "gains.kd": 20.0}, torque_noise_rms=np.zeros(4), spectral_abscissa=-1.0,
                    damping_ratio=zeta, bandwidth_ratio=10.0, simulated=True, values=np.array([1.0, 2.0]),
                    peak_torque=np.zeros(4))
    judged = Evaluator(spec).judged(ev)
    assert not judged.feasible and 0 < judged.violations["min_damping_ratio"] < 1e-8
    assert judged.energy >= INFEASIBLE > 2.0


# ==============================================================================================================
# The compiled engine's trace (blocks/compiled/trace.py)
# ==============================================================================================================
def test_constant_folding_in_a_trace_is_the_arithmetic():
    """tr-fold-minus.  Two constants combine into the constant the arithmetic gives: 5 - 2 = 3, 2 - 5 = -3,
    5 / 2 = 2.5, 5 + 2 = 7, 5 * 2 = 10 (a traced kernel with a literal expression relies on it)."""
    from blocks.compiled.trace import Graph

    g = Graph()
    five, two = g.const(5.0), g.const(2.0)
    for expr, value in ((five - two, 3.0), (two - five, -3.0), (five / two, 2.5), (five + two, 7.0),
                        (five * two, 10.0), (7.0 - two, 5.0), (two - 7.0, -5.0)):
        assert expr.op == "const" and expr.args[0] == value


# ==============================================================================================================
# The report's numbers: observer gain design and frequency metrics (analysis/linear/gain_design.py, frequency.py)
# ==============================================================================================================
def test_the_designed_gain_meets_its_target_on_its_own_grid():
    """gd-return-lo.  The design's promise is "at least target_rad_s on every configuration of the grid": the
    slowest eigenvalue of Y M^-1(q), computed here with numpy on the design grid, is not below the target (to
    the rounding of the eigenvalue, 1e-13, far inside the bisection's rtol of 1e-10)."""
    from analysis.linear import gain_design

    paper = blocks.load_scenario("paper")
    grid = np.array([[0.0, t2, 0.24, 0.0] for t2 in np.linspace(0.3, 3.0, 13)])
    for base in (None, 10.0 * np.eye(4)):
        design = gain_design.design_observer_gain(paper.nominal, 10.0, grid, base=base)
        rates = np.linalg.eigvals(design.Y @ np.linalg.inv(paper.nominal.inertia(grid))).real
        assert rates.min() >= 10.0 * (1.0 - 1e-13), rates.min() / 10.0 - 1.0


def test_a_low_pass_band_ends_at_its_first_crossing_of_the_level():
    """fr-lowpass-edge.  G(s) = 1/(s + 1) + 0.8 (10 s) / (s^2 + 10 s + 100^2): low-pass (DC gain 1), below
    1/sqrt(2) from ~1 rad/s, back above it around the resonance at 100 rad/s.  The -3 dB band of a low-pass is
    [0, first crossing]: found here with scipy's freqresp and brentq."""
    import control as ct
    from scipy.optimize import brentq
    from scipy.signal import TransferFunction, freqresp

    from analysis.linear.frequency import siso_metrics

    num = np.polyadd(np.polymul([1.0], [1.0, 10.0, 1e4]), np.polymul([8.0, 0.0], [1.0, 1.0]))
    den = np.polymul([1.0, 1.0], [1.0, 10.0, 1e4])
    ref = TransferFunction(num, den)

    def gain(w):
        return abs(freqresp(ref, [w])[1][0])

    level = 1.0 / np.sqrt(2.0)
    assert gain(100.0) > level                                   # it does come back above the level
    first = brentq(lambda w: gain(w) - level, 0.1, 10.0)
    metrics = siso_metrics(ct.ss(ct.tf(num, den)), 0, 0)
    assert metrics.kind == "low-pass"
    assert metrics.band_3db_rad_s[0] == 0.0
    assert metrics.band_3db_rad_s[1] == pytest.approx(first, rel=1e-6)
