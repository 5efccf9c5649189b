"""What the FMU's input holds at the start and at the end of every communication step, for every coupling.

The Python side commands ``u = c(t) = sin 3t`` into the moment-integrator FMU
(tests/fmu_models/integrator.c) and reads the input the FMU holds (a side input
named like the FMU input).  The side observes that input two ways:

* ``echo``, an output equal to the input it reads: at ``t_k`` it is what the
  FMU's input held at the end of the step before;
* its states ``A0' = v``, ``A1' = t v`` (the moments of the input ``v`` it
  reads over each step): for ``v = a + b (t - t_k)`` the two increments over a
  step fix ``a`` (the start value) and ``a + b h`` (the end value).  RK4 is
  exact for these integrands (polynomials of degree <= 2 in t).

The FMU's own outputs ``I0``, ``I1`` are the same moments of what it received.

The expected values are written from the couplings' definitions (fmu/coupling.py):
``zoh`` holds ``c(t_k)`` over the step; ``linear`` hands over ``c(t_k) + (t - t_k)
c'(t_k)``, with ``c' = 3 cos 3t`` (the master takes a one-sided difference over
1e-4 h, within 3e-5 of it: 2e-6 at the end of a step).
"""
from __future__ import annotations

import control as ct
import numpy as np
import pytest
from fmu_models import build

from fmu import cosimulate_system

pytestmark = pytest.mark.needs_cc

H, STEPS = 0.05, 10
TOL = 1e-5          # the one-sided slope: 2e-6 at the end of a step; rounding far below


def c(t):
    return np.sin(3.0 * t)


def dc(t):
    return 3.0 * np.cos(3.0 * t)


@pytest.fixture(scope="module")
def integrator(tmp_path_factory):
    return build("integrator", tmp_path_factory.mktemp("pinned-coupling"))


def echo_side() -> ct.NonlinearIOSystem:
    """Commands ``u = c(t)``, echoes the input ``u`` it reads as ``echo`` and integrates its moments."""
    return ct.nlsys(lambda t, x, u, p: [u[0], t * u[0]], lambda t, x, u, p: [c(t), u[0]], inputs=["u"],
                    outputs=["u", "echo"], states=["A0", "A1"], name="echo")


def start_and_end(m0: np.ndarray, m1: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the start and end values of a signal linear over the step, from the increments of its moments
    ``int v dt`` (``m0``) and ``int t v dt`` (``m1``) at the communication points ``t``."""
    d0, d1 = np.diff(m0), np.diff(m1) - t[:-1] * np.diff(m0)       # d1: int (t - t_k) v dt over the step
    h = np.diff(t)
    # d0 = h a + h^2 b / 2,  d1 = h^2 a / 2 + h^3 b / 3   (v = a + b (t - t_k))
    det = h * h ** 3 / 3 - (h ** 2 / 2) ** 2
    a = (d0 * h ** 3 / 3 - d1 * h ** 2 / 2) / det
    b = (h * d1 - h ** 2 / 2 * d0) / det
    return a, a + b * h


def expected(coupling: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The FMU input's value at the start and at the end of each step starting at ``t``."""
    start = c(t)
    return start, start + (H * dc(t) if coupling == "linear" else 0.0)


def test_the_moments_give_back_a_known_line():
    """The decoding itself, on the closed-form moments of v = 2 + 5 (t - t_k) over [0.3, 0.35]."""
    t = np.array([0.3, 0.35])
    m0 = np.array([0.0, 2 * 0.05 + 5 * 0.05 ** 2 / 2])
    # int t (2 + 5 (t - 0.3)) dt = int (0.5 t + 5 t^2) dt = 0.25 t^2 + 5 t^3 / 3
    F = lambda s: 0.25 * s ** 2 + 5 * s ** 3 / 3          # noqa: E731
    m1 = np.array([0.0, F(0.35) - F(0.3)])
    a, end = start_and_end(m0, m1, t)
    assert a[0] == pytest.approx(2.0, abs=1e-12) and end[0] == pytest.approx(2.25, abs=1e-12)


@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_the_input_the_fmu_holds_at_the_end_of_a_step_is_what_the_side_reads_next(integrator, coupling):
    resp = cosimulate_system(integrator, echo_side(), STEPS * H, H, coupling=coupling)
    assert resp.cosim["coupling"] == coupling
    labels = list(resp.output_labels)
    t = np.asarray(resp.time)
    echo = np.asarray(resp.outputs[labels.index("echo")])
    np.testing.assert_allclose(t, np.arange(STEPS + 1) * H, rtol=0, atol=1e-15)
    assert echo[0] == 0.0                        # before the first command: the input's start value (XML: 0)
    _, end = expected(coupling, t[:-1])
    np.testing.assert_allclose(echo[1:], end, rtol=0, atol=TOL)
    if coupling == "linear":                     # issue 23: 0.15 at the second point (c(0) = 0, c'(0) = 3, h = 0.05)
        assert echo[1] == pytest.approx(0.15, abs=TOL)


@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_both_sides_see_the_input_start_at_the_command_and_end_where_the_coupling_puts_it(integrator, coupling):
    resp = cosimulate_system(integrator, echo_side(), STEPS * H, H, coupling=coupling)
    labels, states = list(resp.output_labels), list(resp.state_labels)
    t = np.asarray(resp.time)
    want_start, want_end = expected(coupling, t[:-1])
    python_side = start_and_end(*(np.asarray(resp.states[states.index(n)]) for n in ("A0", "A1")), t)
    fmu_side = start_and_end(*(np.asarray(resp.outputs[labels.index(n)]) for n in ("I0", "I1")), t)
    for start, end in (python_side, fmu_side):
        np.testing.assert_allclose(start, want_start, rtol=0, atol=TOL)
        np.testing.assert_allclose(end, want_end, rtol=0, atol=TOL)
    # the command recorded at t_k is c(t_k) itself
    np.testing.assert_allclose(np.asarray(resp.outputs[labels.index("u")]), c(t), rtol=0, atol=1e-15)


# --- the exported plant, FMI 2 (input derivatives) and FMI 3 (intermediate update): four inputs ----------------------
AMPLITUDE = np.array([1.0, -2.0, 0.5, 3.0])          # tau[i] = AMPLITUDE[i] c(t), N m or N


@pytest.fixture(scope="module")
def plants(tmp_path_factory):
    from fmu import export_plant
    folder = tmp_path_factory.mktemp("pinned-plant")
    return {v: export_plant(folder / f"plant{v}.fmu", fmi_version=v) for v in (2, 3)}


def torque_side() -> ct.NonlinearIOSystem:
    """Commands ``tau[i] = a_i c(t)``, echoes the applied ``tau[i]`` and integrates their moments."""
    names = [f"tau[{i}]" for i in range(4)]
    return ct.nlsys(lambda t, x, u, p: np.concatenate([u, t * u]),
                    lambda t, x, u, p: np.concatenate([AMPLITUDE * c(t), u]), inputs=names,
                    outputs=names + [f"echo[{i}]" for i in range(4)],
                    states=[f"A0[{i}]" for i in range(4)] + [f"A1[{i}]" for i in range(4)], name="torques")


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_the_plants_torques_start_and_end_each_step_where_the_coupling_puts_them(plants, version, coupling):
    resp = cosimulate_system(plants[version], torque_side(), STEPS * H, H, coupling=coupling)
    assert (resp.cosim["coupling"], resp.cosim["fmi_version"]) == (coupling, version)
    labels, states = list(resp.output_labels), list(resp.state_labels)
    t = np.asarray(resp.time)
    want_start, want_end = expected(coupling, t[:-1])
    for i, a in enumerate(AMPLITUDE):
        echo = np.asarray(resp.outputs[labels.index(f"echo[{i}]")])
        assert echo[0] == 0.0
        np.testing.assert_allclose(echo[1:], a * want_end, rtol=0, atol=abs(a) * TOL)
        start, end = start_and_end(*(np.asarray(resp.states[states.index(f"A{j}[{i}]")]) for j in (0, 1)), t)
        np.testing.assert_allclose(start, a * want_start, rtol=0, atol=abs(a) * TOL)
        np.testing.assert_allclose(end, a * want_end, rtol=0, atol=abs(a) * TOL)


@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_before_the_first_command_the_side_reads_the_inputs_start_value(tmp_path, coupling):
    """An integrator whose input starts at 0.7 (its model description): that is what the side reads at t = 0."""
    def start_at_07(xml: str) -> str:
        old = 'causality="input" variability="continuous"><Real start="0"/>'
        assert xml.count(old) == 1
        return xml.replace(old, 'causality="input" variability="continuous"><Real start="0.7"/>')
    fmu = build("integrator", tmp_path, xml_edit=start_at_07, filename="integrator07")
    resp = cosimulate_system(fmu, echo_side(), 2 * H, H, coupling=coupling)
    echo = np.asarray(resp.outputs[list(resp.output_labels).index("echo")])
    assert echo[0] == 0.7
    np.testing.assert_allclose(echo[1:], expected(coupling, np.array([0.0, H]))[1], rtol=0, atol=TOL)
