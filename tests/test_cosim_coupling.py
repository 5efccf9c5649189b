"""What crosses between the two sides of a co-simulation, and when the master stops.

The moment-integrator FMU (tests/fmu_models/integrator.c) integrates ``u``
and ``t u`` exactly for an input that is linear over each step; a Python
block integrates the same moments of the input it reads.  Equal moments at
every communication point mean equal signals at every instant of every step
(two moments fix a straight line).  The gain FMU (tests/fmu_models/gain.c)
closes an algebraic loop through both sides.
"""
from __future__ import annotations

import control as ct
import numpy as np
import pytest
from conftest import make_scenario
from fmu_models import build

from blocks.engines.fastsim import CompiledLoop
from fmu import Budget, BudgetError, CoSimulationError, controller_side, cosimulate, cosimulate_system, export_plant

pytestmark = pytest.mark.needs_cc


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coupling")
    return {name: build(name, folder) for name in ("integrator", "gain")} | {
        "plant": export_plant(folder / "plant.fmu")}


def command(t, y_i0):
    """The Python side's output: smooth in time and fed back from the FMU's output."""
    return np.sin(3.0 * t) + 0.5 * y_i0


def moments_side(reads_applied: bool) -> ct.NonlinearIOSystem:
    """A side that commands ``u`` and integrates the moments of the ``u`` it reads: the applied one, or its own."""
    def update(t, x, u, params):
        v = u[2] if reads_applied else command(t, u[0])
        return [v, t * v]

    def output(t, x, u, params):
        return [command(t, u[0]), x[0], x[1]]

    inputs = ["I0", "I1"] + (["u"] if reads_applied else ["u_unused"])
    return ct.nlsys(update, output, inputs=inputs if reads_applied else ["I0", "I1"], outputs=["u", "J0", "J1"],
                    states=["J0", "J1"], name="side")


def moments(resp):
    labels = list(resp.output_labels)
    return {n: np.asarray(resp.outputs[labels.index(n)]) for n in ("I0", "I1", "J0", "J1")}


@pytest.mark.parametrize("coupling", ["zoh", "linear"])
def test_the_python_side_reads_exactly_the_input_the_fmu_received(models, coupling):
    resp = cosimulate_system(models["integrator"], moments_side(True), 1.0, 0.05, coupling=coupling)
    assert resp.cosim["coupling"] == coupling
    m = moments(resp)
    np.testing.assert_allclose(m["J0"], m["I0"], rtol=0, atol=1e-13)
    np.testing.assert_allclose(m["J1"], m["I1"], rtol=0, atol=1e-13)


def test_linear_coupling_moves_the_input_within_the_step_and_zoh_holds_it(models):
    linear = moments(cosimulate_system(models["integrator"], moments_side(True), 1.0, 0.05, coupling="linear"))
    held = moments(cosimulate_system(models["integrator"], moments_side(True), 1.0, 0.05, coupling="zoh"))
    # over [0, 0.05] the command starts at sin(0) = 0 with slope 3: held, its integral is 0; on the slope, 3 h^2/2
    assert held["I0"][1] == pytest.approx(0.0, abs=1e-15)
    assert linear["I0"][1] == pytest.approx(3.0 * 0.05 ** 2 / 2, rel=1e-9)
    # and both approach the continuous loop I0' = sin 3t + I0 / 2 (closed form), the linear one much closer
    t = 1.0
    exact = (3.0 * np.exp(t / 2) - 3.0 * np.cos(3 * t) - 0.5 * np.sin(3 * t)) / (9.0 + 0.25)
    assert abs(linear["I0"][-1] - exact) < abs(held["I0"][-1] - exact) / 10


def test_a_side_that_integrates_its_own_command_sees_another_signal(models):
    """The negative control: reading the command as it moves within the step is not what the FMU got."""
    resp = cosimulate_system(models["integrator"], moments_side(False), 1.0, 0.05, coupling="zoh")
    m = moments(resp)
    assert np.abs(m["J0"] - m["I0"]).max() > 1e-3


def test_the_observer_reads_the_applied_torque_and_the_controller_does_not():
    side = controller_side(make_scenario(simulation={"t_final": 0.1, "output_step": 0.01}))
    labels = list(side.input_labels)
    assert labels == [f"{s}[{i}]" for s in ("q", "dq", "tau") for i in range(4)]
    loop = CompiledLoop(side)
    u = np.r_[0.1, 1.2, 0.2, 0.3, 0.1, -0.2, 0.0, 0.3, np.zeros(4)]
    u2 = u.copy()
    u2[8:] = [1.0, -2.0, 0.5, 0.3]                      # another applied torque, the same arm state
    x = np.zeros(side.nstates)
    out, out2 = loop.output(0.0, x, u), loop.output(0.0, x, u2)
    tau = [list(side.output_labels).index(f"tau[{i}]") for i in range(4)]
    np.testing.assert_array_equal(out[tau], out2[tau])           # the command does not depend on it
    assert np.abs(loop.rhs(0.0, x, u) - loop.rhs(0.0, x, u2)).max() > 0.1     # the observer integrates it


def test_a_loop_gain_above_one_through_both_sides_raises_naming_signal_and_time(models):
    """y = 2 u in the FMU, u = y + 1 in Python: both feed through, so y doubles every step until it overflows."""
    side = ct.nlsys(None, lambda t, x, u, p: [u[0] + 1.0], inputs=["y"], outputs=["u"], name="adder")
    with pytest.raises(CoSimulationError, match=r"(FMU output y|output u) = (inf|-inf|nan) at t = [0-9.]+ s is not "
                                                r"finite; no result") as err:
        cosimulate_system(models["gain"], side, 2.0, 1e-3, budget=Budget(steps=10_000))
    # 2^k overflows a double after about 1024 steps
    t = float(str(err.value).split(" at t = ")[1].split(" s")[0])
    assert 1.0 < t < 1.1


def test_linear_coupling_is_refused_for_an_fmu_that_holds_its_inputs(models):
    side = ct.nlsys(None, lambda t, x, u, p: [1.0], inputs=["y"], outputs=["u"], name="source")
    with pytest.raises(CoSimulationError, match="canInterpolateInputs.*use coupling 'zoh'"):
        cosimulate_system(models["gain"], side, 0.1, 0.01, coupling="linear")
    with pytest.raises(CoSimulationError, match="coupling must be one of"):
        cosimulate_system(models["gain"], side, 0.1, 0.01, coupling="cubic")


@pytest.mark.parametrize("step, words", [(0, "finite number > 0"), (float("nan"), "finite number > 0"),
                                         (-1e-3, "finite number > 0"), ("1e-3", "finite number > 0"),
                                         (float("inf"), "finite number > 0")])
def test_bad_steps_are_named_before_anything_divides_by_them(models, step, words):
    with pytest.raises(CoSimulationError, match=f"communication step h must be a {words} s, got"):
        cosimulate(models["plant"], make_scenario(), step=step)


def test_a_huge_t_final_is_named(models):
    with pytest.raises(CoSimulationError, match="t_final must be a finite number > 0 s"):
        cosimulate(models["plant"], make_scenario(), step=1e-3, t_final=10 ** 400)


def test_a_run_beyond_the_step_budget_is_refused_before_it_starts(models):
    with pytest.raises(BudgetError, match=r"t_final = 10 s / step h = 1e-09 s gives 1e\+10 steps, more than the "
                                          r"step budget of 2e\+06; .* --max-steps or DOBKIT_MAX_STEPS"):
        cosimulate(models["plant"], "paper", step=1e-9)


def test_the_wall_time_limit_stops_a_run(models):
    with pytest.raises(BudgetError, match="wall-time budget of 1e-06 s ran out at .*no result is returned"):
        cosimulate(models["plant"], make_scenario(simulation={"t_final": 0.5, "output_step": 0.01}), step=1e-3,
                   budget=Budget(seconds=1e-6))
