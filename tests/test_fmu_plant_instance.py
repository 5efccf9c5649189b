"""The plant FMU's C instance and saved states against the FMI standard (fmu/c/plant_instance.c, plant_state.c,
fmi2/3_common.c): an input set without a slope is held, doStep refuses a zero step and a step from another
time, a damaged serialized state is refused, and the status functions report the last successful time.

The references are the FMI standard's rules and scipy's integrators on the Python plant.

Each test checks a number against a derivation of its own; each was written for a wrong change of
tests/mutation_probe.py that the rest of the suite let through, named in its docstring
(``python tests/mutation_probe.py --only ID --killers`` shows it).
"""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from scipy.integrate import solve_ivp

from blocks.diagram.systems import plant as python_plant
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.rrpr.parameters import RobotParameters

STATES = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]


X0 = np.array([0.3, 1.1, 0.05, 0.2, 0.5, -0.4, 0.1, 0.3])


@pytest.fixture(scope="module")
def plant_fmus(tmp_path_factory):
    """The plant exported now from the C sources in the tree (no cache: every session compiles them)."""
    from fmu import export_plant

    folder = tmp_path_factory.mktemp("plant-instance")
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
