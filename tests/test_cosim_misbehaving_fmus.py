"""The co-simulation master on FMUs that misbehave as exported FMUs do (findings F1 and F3).

The test FMU nanlag (tests/fmu_models/nanlag.c) is the lag x' = k (u - x); it declares output derivatives and
returns NaN for them with status OK, as some OpenModelica exports do.  Its Co-Simulation solver is 10 classical
RK4 steps per communication step.  References written here:

* F1, closed by u = 2 - x under a zero-order hold: x_{j+1} = u_j + (x_j - u_j) e^{-k h} (exact for a held input);
* F3, k = 5000 /s: RK4's amplification at k dt = 5 is |1 - 5 + 25/2 - 125/6 + 625/24| = 13.7 per sub-step, so
  the FMU's own solver is unstable at h = 10 ms; at h = 1 ms (k dt = 0.5) it is stable and x -> 1 - e^{-k t}.
"""
from __future__ import annotations

import warnings

import control as ct
import numpy as np
import pytest
from fmu_models import build

from fmu import CoSimulationError, cosimulate_system
from fmu.coupling import CouplingFallbackWarning

pytestmark = pytest.mark.needs_cc


@pytest.fixture(scope="module")
def nanlag(tmp_path_factory):
    return build("nanlag", tmp_path_factory.mktemp("nanlag"))


def proportional():
    return ct.nlsys(None, lambda t, x, u, p: [2.0 - u[0]], inputs=["x"], outputs=["u"], name="p")


def constant_one():
    return ct.nlsys(None, lambda t, x, u, p: [1.0], inputs=0, outputs=["u"], name="one")


def test_nan_output_derivatives_fall_back_to_zoh_with_one_note(nanlag):
    h, n = 0.05, 40
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resp = cosimulate_system(nanlag, proportional(), t_final=n * h, step=h)      # default: linear
    notes = [w for w in caught if issubclass(w.category, CouplingFallbackWarning)]
    assert len(notes) == 1
    assert str(notes[0].message).startswith("nanlag.fmu: fmi2GetRealOutputDerivatives returned d(x)/dt = nan at "
                                            "t = 0 s (the FMU declares maxOutputDerivativeOrder = 1)")
    assert "uses coupling 'zoh'" in str(notes[0].message) and "diverging" not in str(notes[0].message)
    assert resp.cosim["coupling"] == "zoh" and resp.cosim["coupling_fallback"] == str(notes[0].message)
    x = [0.0]
    for _ in range(n):
        u = 2.0 - x[-1]
        x.append(u + (x[-1] - u) * np.exp(-h))
    np.testing.assert_allclose(resp.outputs[list(resp.output_labels).index("x")], x, rtol=0, atol=1e-9)


def test_an_unstable_fmu_solver_is_caught_and_named(nanlag):
    with pytest.raises(CoSimulationError, match=r"the FMU output x grew more than 10-fold in each of 3 consecutive "
                                                r"communication steps.*inputs held over each step this is "
                                                r"nanlag.fmu's own co-simulation solver being unstable at h = 0.01 s"):
        cosimulate_system(nanlag, constant_one(), t_final=0.2, step=0.01, coupling="zoh", start_values={"k": 5000.0})


def test_the_same_fmu_at_a_stable_step_runs_to_the_exact_answer(nanlag):
    resp = cosimulate_system(nanlag, constant_one(), t_final=0.01, step=1e-3, coupling="zoh",
                             start_values={"k": 5000.0})
    x = resp.outputs[list(resp.output_labels).index("x")]
    np.testing.assert_allclose(x, 1 - np.exp(-5000.0 * resp.time), atol=1e-3)
