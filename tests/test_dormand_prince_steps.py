"""The compiled engine's Dormand-Prince stepper (blocks/engines/compiled/dopri.py), step by step against scipy's RK45: its
tableau, error norm, step control, dense output and initial step.

Each test checks a number against a derivation of its own; each was written for a wrong change of
tests/mutation_probe.py that the rest of the suite let through, named in its docstring
(``python tests/mutation_probe.py --only ID --killers`` shows it).
"""
from __future__ import annotations

import numpy as np
import pytest


def _van_der_pol(mu: float):
    """Forced (so that the stage times c_i matter): y0'' = mu (1 - y0^2) y0' - y0 + 1.5 cos 2t."""
    def f(t, y):
        return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0] + 1.5 * np.cos(2.0 * t)])
    return f


def _dopri_text_as_python(f):
    """The stepper's source as the code generator reads it, run as plain Python on the right-hand side ``f``."""
    from blocks.engines.compiled.codegen import _template_text

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
