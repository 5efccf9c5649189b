"""blocks.simulate_system: any hand-wired diagram on every engine, with python-control's arguments and result.

The reference is control.input_output_response on the same system (and, for a first-order lag, its analytic
step response); the compiled engine must equal it to 1e-6 with user blocks of three kinds: a ct.tf lag (linear
kernels), an nlsys filter the trace follows, and one it cannot follow (a branch on a value), compiled by numba
as it stands.  A block neither can take is refused by name and the diagram runs on numpy with one note.
"""
import math
import warnings

import control as ct
import numpy as np
import pytest
import scipy.special

import blocks
from blocks.engines.compiled import CompiledUnavailable
from blocks.engines.engine_choice import EngineFallbackWarning
from blocks.engines.monitor import SimulationError
from blocks.engines.wired import lower

TIGHT = dict(rtol=1e-9, atol=1e-11)


def _filter_update(t, x, u, params):
    """A nonlinear first-order filter: x' = -a x + sin(u)."""
    return np.array([-params.get("a", 2.0) * x[0] + np.sin(u[0])])


def _filter_output(t, x, u, params):
    return np.array([x[0] * x[0] + 0.5 * u[0]])


def _user_diagram():
    """Two blocks of the user's own, a sum on a wire and an external input: e = r - y, f = filter(e), y = lag(f)."""
    filt = ct.nlsys(_filter_update, _filter_output, inputs="e", outputs="f", states="xf", name="filt",
                    params={"a": 3.0})
    lag = ct.tf([1.0], [0.2, 1.0], inputs="f", outputs="y", name="lag")
    return ct.interconnect([filt, lag], connections=[["filt.e", "-lag.y"]], inplist=["filt.e"], inputs="r",
                           outlist=["lag.y", "filt.f"], outputs=["y", "f"], check_unused=False)


def _branchy_update(t, x, u, params):
    """A branch on the state's value: the trace cannot follow it, numba compiles it as it stands."""
    if x[0] > 0.5:
        return np.array([-params["k"] * (x[0] - 0.5) + u[0]])
    return np.array([math.sin(u[0]) - x[0]])


def _erf_update(t, x, u, params):
    """scipy.special.erf: neither the trace nor numba takes it."""
    return np.array([scipy.special.erf(u[0]) - x[0]])


@pytest.mark.slow
def test_user_blocks_are_lowered_by_kind():
    T = np.linspace(0.0, 1.0, 5)
    low = lower(_user_diagram(), T, np.zeros((1, 5)))
    assert low.how == {"filt": "traced", "lag": "linear"}
    assert low.reason is None
    branchy = ct.nlsys(_branchy_update, None, inputs="e", outputs="s", states="xs", name="branchy", params={"k": 4.0})
    erf = ct.nlsys(_erf_update, None, inputs="s", outputs="z", states="xz", name="erfblock")
    low = lower(ct.interconnect([branchy, erf], inplist=["branchy.e"], inputs="r", outlist=["erfblock.z"],
                                outputs="z"), T, np.zeros((1, 5)))
    assert low.how["branchy"] == "compiled"
    assert low.how["erfblock"] == "refused"
    assert "block 'erfblock'" in low.reason and "cannot be traced" in low.reason


@pytest.mark.slow
def test_two_user_blocks_run_compiled_and_equal_python_control():
    sys = _user_diagram()
    T = np.linspace(0.0, 4.0, 81)
    U = np.sin(2.0 * T)
    ref = ct.input_output_response(sys, T, U, [0.5, 0.1], solve_ivp_kwargs=TIGHT)
    resp = blocks.simulate_system(sys, T, [0.5, 0.1], U, engine="compiled", solve_ivp_kwargs=TIGHT)
    assert resp.engine == "compiled"
    np.testing.assert_array_equal(resp.time, T)
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-6)
    np.testing.assert_allclose(resp.states, ref.states, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(resp.inputs, ref.inputs)
    assert list(resp.output_labels) == ["y", "f"] and list(resp.state_labels) == list(sys.state_labels)
    # U as a scalar: a constant input; auto picks the compiled engine too (same structure, cached)
    ref = ct.input_output_response(sys, T, 0.7, 0, solve_ivp_kwargs=TIGHT)
    resp = blocks.simulate_system(sys, T, 0, 0.7, solve_ivp_kwargs=TIGHT)
    assert resp.engine == "compiled"
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-6)


@pytest.mark.parametrize("engine", ["fast", "python-control"])
def test_numpy_and_reference_engines_equal_python_control(engine):
    sys = _user_diagram()
    T = np.array([0.0, 0.1, 0.25, 0.3, 1.0, 1.7, 3.0])        # a grid that is not uniform
    U = np.array([0.0, 1.0, -0.5, 0.2, 0.9, 0.0, 0.3])         # interpolated linearly between the times
    with pytest.warns(UserWarning, match="X0 too short; padding with zeros"):
        ref = ct.input_output_response(sys, T, U, [0.5], solve_ivp_kwargs=TIGHT)     # X0 short: zero-padded
    with pytest.warns(UserWarning, match="X0 too short; padding with zeros"):
        resp = blocks.simulate_system(sys, T, [0.5], U, engine=engine, solve_ivp_kwargs=TIGHT)
    assert resp.engine == engine
    np.testing.assert_array_equal(resp.time, T)
    np.testing.assert_allclose(resp.states[:, 0], [0.5, 0.0])
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-9)


def test_a_lag_matches_its_analytic_step_response():
    """y' = (u - y) / tau with u = 1 from y(0) = 0: y = 1 - exp(-t / tau); a single ct.tf, not interconnected."""
    tau = 0.2
    lag = ct.ss(ct.tf([1.0], [tau, 1.0]), inputs="u", outputs="y", name="lag")
    T = np.linspace(0.0, 1.0, 21)
    resp = blocks.simulate_system(lag, T, 0, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(resp.outputs, 1.0 - np.exp(-T / tau), atol=1e-8)
    assert resp.outputs.shape == (21,)                     # SISO squeezed, as python-control does


def test_refused_block_runs_on_numpy_with_one_note_naming_it():
    branchy = ct.nlsys(_branchy_update, None, inputs="e", outputs="s", states="xs", name="branchy",
                       params={"k": 4.0})
    erf = ct.nlsys(_erf_update, None, inputs="s", outputs="z", states="xz", name="erfblock")
    sys = ct.interconnect([branchy, erf], inplist=["branchy.e"], inputs="r", outlist=["erfblock.z", "branchy.s"],
                          outputs=["z", "s"])
    T = np.linspace(0.0, 3.0, 31)
    ref = ct.input_output_response(sys, T, 1.0, 0, solve_ivp_kwargs=TIGHT)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        resp = blocks.simulate_system(sys, T, 0, 1.0, solve_ivp_kwargs=TIGHT)
        blocks.simulate_system(sys, T, 0, 1.0, solve_ivp_kwargs=TIGHT)          # the note is not repeated
    notes = [w for w in seen if issubclass(w.category, EngineFallbackWarning)]
    assert len(notes) <= 1
    if notes:           # once per process: an earlier test may have given it
        assert "block 'erfblock'" in str(notes[0].message)
    assert resp.engine == "fast"
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-9)
    with pytest.raises(CompiledUnavailable, match="block 'erfblock'"):
        blocks.simulate_system(sys, T, 0, 1.0, engine="compiled")


@pytest.mark.slow
def test_block_the_trace_cannot_follow_is_compiled_as_it_stands():
    branchy = ct.nlsys(_branchy_update, None, inputs="e", outputs="s", states="xs", name="branchy",
                       params={"k": 4.0})
    sys = ct.interconnect([branchy], inplist=["branchy.e"], inputs="r", outlist=["branchy.s"], outputs=["s"])
    T = np.linspace(0.0, 3.0, 61)
    ref = ct.input_output_response(sys, T, 1.0, 0, solve_ivp_kwargs=TIGHT)
    resp = blocks.simulate_system(sys, T, 0, 1.0, engine="compiled", solve_ivp_kwargs=TIGHT)
    assert resp.engine == "compiled"
    assert np.max(resp.states) > 0.5                   # both branches were taken
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-6)


def test_params_at_call_time_override_the_blocks():
    sys = _user_diagram()
    T = np.linspace(0.0, 2.0, 21)
    ref = ct.input_output_response(sys, T, 1.0, 0, params={"a": 7.0}, solve_ivp_kwargs=TIGHT)
    resp = blocks.simulate_system(sys, T, 0, 1.0, params={"a": 7.0}, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-9)
    other = blocks.simulate_system(sys, T, 0, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    assert np.max(np.abs(other.outputs - resp.outputs)) > 1e-3       # the parameter mattered


def test_bad_arguments_are_refused_with_the_value():
    sys = _user_diagram()
    T = np.linspace(0.0, 1.0, 11)
    with pytest.raises(ValueError, match=r"U must be a number or have shape \(1, 11\)"):
        blocks.simulate_system(sys, T, 0, np.zeros((2, 11)), engine="fast")
    with pytest.raises(ValueError, match="T must be at least two finite, increasing times"):
        blocks.simulate_system(sys, T[::-1], 0, 0.0, engine="fast")
    with pytest.raises(ValueError, match=r"solve_ivp_kwargs \['t_eval'\]"):
        blocks.simulate_system(sys, T, 0, 0.0, engine="fast", solve_ivp_kwargs={"t_eval": T})
    with pytest.raises(ValueError, match="engine must be one of"):
        blocks.simulate_system(sys, T, 0, 0.0, engine="gpu")
    with pytest.raises(ValueError, match="X0 has 3 values for 2 states"):
        blocks.simulate_system(sys, T, [1, 2, 3], 0.0, engine="fast")


def test_a_state_beyond_the_given_bound_stops_the_run_and_unbounded_growth_does_not():
    """x' = x from 1: e^t; a bound of 10 is crossed at ln 10 s; without bounds the run goes on (python-control's
    way: only a non-finite state stops it)."""
    grow = ct.nlsys(lambda t, x, u, p: x, None, inputs=0, outputs="x", states="x", name="grow")
    T = np.linspace(0.0, 20.0, 11)
    resp = blocks.simulate_system(grow, T, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(np.ravel(resp.outputs)[-1], math.exp(20.0), rtol=1e-6)
    with pytest.raises(SimulationError) as err:
        blocks.simulate_system(grow, T, 1.0, engine="fast", bounds=10.0, solve_ivp_kwargs=TIGHT)
    assert err.value.time == pytest.approx(math.log(10.0), abs=1e-6)



@pytest.mark.parametrize("engine", ["fast", "python-control"])
def test_non_finite_start_or_inputs_are_refused_before_a_solver_sees_them(engine):
    """A NaN in U stopped the solver at a tiny step ("Required step size is less than spacing ..."); a NaN start
    was "the loop diverged at t = 0" (python-control: "y0 must be finite"): both are the caller's numbers."""
    sys = _user_diagram()
    T = np.linspace(0.0, 1.0, 11)
    with pytest.raises(ValueError, match=r"U must be finite numbers, got nan \(the number given"):
        blocks.simulate_system(sys, T, 0, np.nan, engine=engine)
    with pytest.raises(ValueError, match=r"U must be finite numbers, got inf \(input 0 at t = 0.9 s\)"):
        blocks.simulate_system(sys, T, 0, [np.r_[np.zeros(9), np.inf, 0.0]], engine=engine)
    with pytest.raises(ValueError, match=r"X0 must be finite numbers, got inf \(state 1\)"):
        blocks.simulate_system(sys, T, [0.0, np.inf], 0.0, engine=engine)
    with pytest.raises(ValueError, match="X0 must be numbers .* got 'a'"):
        blocks.simulate_system(sys, T, "a", 0.0, engine=engine)


def test_bounds_that_are_not_positive_magnitudes_are_refused_by_value():
    """A NaN or negative bound stopped every run at t = 0 ("reached 0, beyond its bound nan"); three bounds for
    two states were numpy's broadcast error."""
    sys = _user_diagram()
    T = np.linspace(0.0, 1.0, 11)
    for bad in (np.nan, -1.0, 0.0, [1.0, np.nan]):
        with pytest.raises(ValueError, match="bounds must be positive magnitudes"):
            blocks.simulate_system(sys, T, 0, 0.0, engine="fast", bounds=bad)
    with pytest.raises(ValueError, match=r"bounds must be one number or 2 \(one per state\), got shape \(3,\)"):
        blocks.simulate_system(sys, T, 0, 0.0, engine="fast", bounds=[1.0, 2.0, 3.0])
    ok = blocks.simulate_system(sys, T, 0, 0.0, engine="fast", bounds=[np.inf, 1e3])
    assert ok.states.shape == (2, 11)


def test_a_grid_beyond_the_memory_budget_is_refused_before_it_is_allocated():
    """Every time of T holds the states (twice), outputs and inputs as float64: 2 states x 2 + 2 outputs + 1 input
    = 7 rows x 8 bytes = 56 bytes per time; a budget of 56 x 1000 bytes takes 1000 times and refuses 1001."""
    from blocks.engines.budget import Budget, BudgetError
    sys = _user_diagram()
    assert (sys.nstates, sys.noutputs, sys.ninputs) == (2, 2, 1)
    budget = Budget(memory=56 * 1000)
    blocks.simulate_system(sys, np.linspace(0.0, 1.0, 1000), 0, 0.0, engine="fast", budget=budget)
    with pytest.raises(BudgetError, match=r"1,001 output times needs about .*set by 'T'.* over the memory budget"):
        blocks.simulate_system(sys, np.linspace(0.0, 1.0, 1001), 0, 0.0, engine="fast", budget=budget)


def _scalar_branchy_update(t, x, u, params):
    """A number, not an array (python-control takes it), behind a branch the trace cannot follow."""
    if x[0] > 0.5:
        return 2.0 * (u[0] - x[0])
    return u[0] - x[0]


def test_a_function_returning_a_number_behind_a_branch_runs_as_python_control_runs_it():
    """numba compiled it as it stands and the loop indexed its number: a TypingError on "auto" and "compiled", and
    "'float' object is not subscriptable" on the numpy engine.  Now it is refused for the compiled engine (by the
    block's name and why), and "auto" and "fast" run it: x' = 1 - x from 0.1 until x = 0.5 (t = ln(0.9/0.5) s),
    then x' = 2 (1 - x), so x(1) = 1 - 0.5 exp(-2 (1 - ln 1.8))."""
    block = ct.nlsys(_scalar_branchy_update, None, inputs=1, states=1, outputs=1, name="numberfn")
    T = np.linspace(0.0, 1.0, 11)
    exact = 1.0 - 0.5 * math.exp(-2.0 * (1.0 - math.log(1.8)))
    for engine in ("auto", "fast"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EngineFallbackWarning)
            resp = blocks.simulate_system(block, T, 0.1, 1.0, engine=engine, solve_ivp_kwargs=TIGHT)
        assert resp.engine == "fast"
        assert np.ravel(resp.outputs)[-1] == pytest.approx(exact, rel=1e-5)
    with pytest.raises(CompiledUnavailable, match="block 'numberfn' .*its update function returns a number, not an "
                                                  "array"):
        blocks.simulate_system(block, T, 0.1, 1.0, engine="compiled")


def _three_outputs(t, x, u, params):
    """Three values for a block of one output, behind a branch (neither traced nor compiled by numba)."""
    if x[0] > 0.5:
        return np.zeros(3)
    return np.array([x[0], 0.0, 0.0])


@pytest.mark.parametrize("engine", ["auto", "compiled", "fast"])
def test_a_function_giving_the_wrong_number_of_values_is_refused_by_its_block(engine):
    """The numpy engine failed mid-run with numpy's "could not broadcast input array from shape (3,) into shape
    (1,)", naming no block; now every engine names it before the run."""
    block = ct.nlsys(lambda t, x, u, p: -x, _three_outputs, inputs=1, states=1, outputs=1, name="three")
    with pytest.raises(ValueError, match="block 'three': its output function returns 3 values at the zero state "
                                         "and input, where it has 1 outputs"):
        blocks.simulate_system(block, np.linspace(0.0, 1.0, 11), 0.1, 1.0, engine=engine)


GAIN = 1.0


def _gain_update(t, x, u, params):
    return np.array([-GAIN * x[0] + u[0]])


def test_a_prepared_run_is_not_reused_when_what_the_function_reads_changed():
    """The run is prepared once per diagram, grid, inputs and parameters; a module number the user's function
    reads is part of that key, so a changed one is traced again (python-control would use it too)."""
    global GAIN
    block = ct.nlsys(_gain_update, None, inputs="u", outputs="y", states="x", name="gain")
    T = np.linspace(0.0, 2.0, 11)
    first = blocks.simulate_system(block, T, 0, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(first.outputs, 1.0 - np.exp(-T), atol=1e-8)         # x' = -x + 1
    try:
        GAIN = 4.0
        second = blocks.simulate_system(block, T, 0, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    finally:
        GAIN = 1.0
    np.testing.assert_allclose(second.outputs, (1.0 - np.exp(-4.0 * T)) / 4.0, atol=1e-8)
    block.params["unused"] = 2.0        # a changed parameter prepares again too (and changes nothing here)
    third = blocks.simulate_system(block, T, 0, 1.0, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(third.outputs, first.outputs, atol=1e-12)


def _saturate(t, x, u, params):
    """A static block (no states): a smooth saturation, traced (np.tanh)."""
    return np.array([params["limit"] * np.tanh(u[0] / params["limit"])])


def test_wiring_of_every_kind_is_lowered_to_the_same_dynamics():
    """A MIMO ct.ss, a controller with a D term, a summing junction, a static nlsys, a scaled wire, outputs that are sums
    and a block input as an output: the lowered diagram (junction and source blocks, direct wires) gives
    python-control's numbers."""
    plant = ct.ss([[0.0, 1.0], [-4.0, -0.8]], [[0.0], [1.0]], [[1.0, 0.0], [0.0, 1.0]], [[0.0], [0.0]],
                  inputs="f", outputs=["p", "v"], states=["p", "v"], name="plant2")
    sat = ct.nlsys(None, _saturate, inputs="w", outputs="f", name="sat", params={"limit": 0.8})
    ctrl = ct.ss([[-2.0]], [[1.0, 0.0]], [[3.0]], [[5.0, -0.5]], inputs=["e", "ev"], outputs="w", states="i",
                 name="pi")
    err = ct.summing_junction(inputs=["r", "-p"], output="e", name="err")
    sys = ct.interconnect([plant, sat, ctrl, err], connections=[["pi.ev", "-plant2.v"], ["sat.w", "pi.w"],
                                                                 ["plant2.f", "sat.f"], ["pi.e", "err.e"],
                                                                 ["err.p", "plant2.p"]],
                          inplist=["err.r"], inputs="r", outlist=[["plant2.p", "plant2.v"], "sat.f", "-pi.e"],
                          outputs=["pv", "f", "minus_e"])
    low = lower(sys, np.array([0.0, 1.0]), np.zeros((1, 2)))
    assert low.how == {"plant2": "linear", "sat": "traced", "pi": "linear", "err": "linear"}
    T = np.linspace(0.0, 6.0, 61)
    U = np.where(T < 2.0, 1.0, -0.5)
    ref = ct.input_output_response(sys, T, U, [0.2, 0.0, 0.1], solve_ivp_kwargs=TIGHT)
    resp = blocks.simulate_system(sys, T, [0.2, 0.0, 0.1], U, engine="fast", solve_ivp_kwargs=TIGHT)
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.states, ref.states, rtol=0, atol=1e-9)


@pytest.mark.slow
def test_a_ring_of_blocks_whose_feedthrough_is_unknown_runs_on_numpy_as_python_control_iterates_it():
    """Two blocks compiled as they stand (their feedthrough unknown: every input) fed by each other cannot be
    ordered: the compiled engine says so, and auto runs the numpy engine's fixed-point plan."""
    from blocks.engines.compiled import unavailable_reason
    one = ct.nlsys(_branchy_update, None, inputs="e", outputs="s", states="xs", name="one", params={"k": 4.0})
    two = ct.nlsys(_branchy_update, None, inputs="e2", outputs="s2", states="xs2", name="two", params={"k": 2.0})
    sys = ct.interconnect([one, two], connections=[["two.e2", "one.s"], ["one.e", "two.s2"]], inplist=[],
                          outlist=["one.s", "two.s2"], outputs=["a", "b"])
    T = np.linspace(0.0, 2.0, 21)
    low = lower(sys, T, np.zeros((0, 21)))
    assert low.how == {"one": "compiled", "two": "compiled"}
    assert "cannot be put in an order" in unavailable_reason(low.system)
    ref = ct.input_output_response(sys, T, 0, [1.0, 0.2], solve_ivp_kwargs=TIGHT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EngineFallbackWarning)
        resp = blocks.simulate_system(sys, T, [1.0, 0.2], solve_ivp_kwargs=TIGHT)
    assert resp.engine == "fast"
    np.testing.assert_allclose(resp.outputs, ref.outputs, rtol=0, atol=1e-9)


def test_a_block_with_events_is_refused_by_name_without_a_trace():
    """A hybrid block (an FMU with events) stays on the numpy engine, which stops at its events."""
    from blocks.engines.integrate import EventSource

    def never(t, x, u, params):
        raise AssertionError("a block with events must not be traced or compiled")
    block = ct.nlsys(never, None, inputs=0, outputs="x", states="x", name="hybrid")
    block.event_source = EventSource()
    low = lower(block)
    assert low.how == {"hybrid": "refused"}
    assert "block 'hybrid' has events" in low.reason
