"""A new scenario of a loop structure built before reuses its wiring and plan, and computes with its own numbers.

The reference of every comparison is the same scenario built with nothing kept (:func:`blocks.figure2.loop.clear_reuse`,
and once in a fresh process): a reused structure must give the same numbers to the last bit, and numbers that
differ from the scenario it was first built for (a reused object holding the old numbers would fail here).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import control as ct
import numpy as np
import pytest

import blocks
from blocks.diagram.control_compat import connection_maps
from blocks.diagram.plan import PLANS, make_plan, plan_key
from blocks.diagram.structure import StructureCache, block_structure, blocks_structure
from blocks.figure2 import loop as loop_module
from blocks.figure2.loop import WIRINGS, clear_reuse, closed_loop

ROOT = Path(__file__).resolve().parents[1]


def _has_urdf() -> bool:
    from importlib import metadata
    try:
        metadata.distribution("example-robot-data")
        import pinocchio  # noqa: F401
    except (metadata.PackageNotFoundError, ImportError):
        return False
    return True


needs_urdf = pytest.mark.skipif(not _has_urdf(), reason="URDF arms need the extra dobkit[urdf]")


@pytest.fixture(autouse=True)
def nothing_kept():
    """Each test starts and ends with no kept structure (others' runs must not decide what is reused here)."""
    clear_reuse()
    yield
    clear_reuse()


def _base(name: str):
    """A short run of a built-in scenario with measurement noise (so that noise numbers can change within it)."""
    return blocks.load_scenario(name).with_changes({
        "simulation.t_final": 0.5, "noise.q_std": 1e-5, "noise.dq_std": 1e-4, "noise.seed": 3,
        "noise.sample_period": 0.005})


def _changes(s) -> dict:
    """Numbers that change and structure that does not: gains, disturbance, noise, t_final, observer."""
    n = s.robot.n
    observer = {"gains.observer_bandwidth": 14.0} if "observer_bandwidth" in s.data["gains"] else \
        {"gains.observer": 25.0}
    return {
        "gains": {"gains.kp": 150.0, "gains.kd": 30.0},
        "disturbance": {"disturbance.f_r": [0.5 * float(v) + 0.01 for v in s.data["disturbance"]["f_r"]]},
        "noise": {"noise.q_std": [2e-5] * n, "noise.seed": 11},
        "t_final": {"simulation.t_final": 0.35},
        "observer": observer,
    }


def _arrays(resp) -> dict:
    return {"t": np.asarray(resp.time), "outputs": np.asarray(resp.outputs), "states": np.asarray(resp.states)}


def _assert_same_bits(a, b) -> None:
    assert a.output_labels == b.output_labels and a.state_labels == b.state_labels
    for key, value in _arrays(a).items():
        other = _arrays(b)[key]
        assert value.shape == other.shape, key
        assert np.array_equal(value, other), f"{key} differ by up to {np.max(np.abs(value - other)):.3g}"


def _kept() -> tuple[int, int]:
    return len(WIRINGS), len(PLANS)


# ----------------------------------------------------------------------------------------------------------------
# Same structure, new numbers: reused, and the numbers of a loop built afresh
# ----------------------------------------------------------------------------------------------------------------
CASES = [("paper", "compiled"), pytest.param("scope4", "compiled", marks=needs_urdf),
         pytest.param("panda", "fast", marks=needs_urdf)]


@pytest.mark.parametrize("name, engine", CASES)
def test_new_numbers_reuse_the_structure_and_give_the_fresh_numbers(name, engine):
    """For each change (gains, disturbance, noise, t_final, observer) the run reuses the wiring and plan of the first
    run (nothing new is kept), differs from it, and equals bit for bit the run of the same scenario with nothing
    kept."""
    if engine == "compiled":
        pytest.importorskip("numba")
    base = _base(name)
    first = blocks.simulate(base, engine=engine)
    kept = _kept()
    assert kept == (1, 1)
    for what, change in _changes(base).items():
        s = base.with_changes(change)
        reused = blocks.simulate(s, engine=engine)
        assert _kept() == kept, f"{what}: a loop of the same structure was wired or planned again"
        clear_reuse()
        fresh = blocks.simulate(s, engine=engine)
        _assert_same_bits(reused, fresh)
        n_t = min(np.size(first.time), np.size(reused.time))
        assert not np.array_equal(np.asarray(first.outputs)[:, :n_t], np.asarray(reused.outputs)[:, :n_t]), \
            f"{what}: the run gave the first scenario's numbers"
        blocks.simulate(base, engine=engine)          # the structure kept again, for the next change
        assert _kept() == kept


def test_reuse_through_python_control_and_the_observer_off():
    """python-control's own solver on a reused interconnection gives a fresh one's numbers, with and without the
    observer (two structures, each reused)."""
    base = blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.1})
    for observer in (True, False):
        blocks.simulate(base, observer=observer, engine="python-control")
    assert _kept() == (2, 0)                   # python-control plans nothing
    s = base.with_changes({"gains.kp": 90.0, "gains.observer": 4.0, "disturbance.f_r[1]": 0.3})
    reused = [blocks.simulate(s, observer=observer, engine="python-control") for observer in (True, False)]
    assert _kept() == (2, 0)
    clear_reuse()
    for observer, resp in zip((True, False), reused):
        _assert_same_bits(resp, blocks.simulate(s, observer=observer, engine="python-control"))


def test_a_reused_interconnection_is_what_interconnect_builds():
    """Every attribute python-control gives an interconnection (matrices, names, offsets, parameters) is that of
    control.interconnect on the same blocks; the blocks are the new loop's own, and its dynamics are theirs."""
    s0 = blocks.load_scenario("paper")
    s1 = s0.with_changes({"gains.kp": 99.0, "disturbance.f_r[0]": 0.5})
    closed_loop(s0)
    reused = closed_loop(s1)
    assert len(WIRINGS) == 1
    fresh = ct.interconnect(list(reused.syslist), inplist=[], outlist=list(reused.output_labels),
                            outputs=list(reused.output_labels), name=reused.name, check_unused=False)
    assert type(reused) is type(fresh)
    for attr in sorted(set(vars(fresh)) | set(vars(reused))):
        if attr in ("updfcn", "outfcn", "scenario", "with_observer"):
            continue
        a, b = getattr(fresh, attr), getattr(reused, attr)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b) and a.shape == b.shape and b.flags.writeable, attr
        else:
            assert a == b, attr
    for m in (reused.connect_map, reused.input_map, reused.output_map):
        assert not any(np.shares_memory(m, kept) for w in WIRINGS._entries.values() for kept in w.maps)
    assert reused.syslist[1].gains["kp"][0, 0] == 99.0      # the controller is s1's
    x0 = loop_module.initial_state(reused, s1)
    for t in (0.0, 0.7):
        assert np.array_equal(reused.dynamics(t, x0, []), fresh.dynamics(t, x0, []))
        assert np.array_equal(reused.output(t, x0, []), fresh.output(t, x0, []))
    first = closed_loop(s0)
    assert not np.array_equal(first.dynamics(0.7, x0, []), reused.dynamics(0.7, x0, []))


def test_a_reused_plan_calls_the_new_blocks_kernels_with_their_parameters():
    """A reused plan is the fresh plan of the new loop: same order, slices and gathers, each step the new block's
    kernels and parameters (the same objects)."""
    s0 = blocks.load_scenario("paper")
    make_plan(closed_loop(s0))
    loop = closed_loop(s0.with_changes({"gains.kd": 20.0, "gains.observer": 7.0}))
    reused = make_plan(loop)
    assert len(PLANS) == 1
    PLANS.clear()
    fresh = make_plan(loop)
    kernels = {b.name: b.contract.kernels for b in loop.syslist}
    for steps in ("steps", "rhs_steps", "updates"):
        for a, b in zip(getattr(reused, steps), getattr(fresh, steps), strict=True):
            assert (a.name, a.x, a.y, a.kernel) == (b.name, b.x, b.y, b.kernel)
            assert np.array_equal(np.asarray(a.gather), np.asarray(b.gather))
            k = kernels[a.name]
            assert a.output is k.output and a.update is k.update and a.output_args is k.params
            assert a.update_args is k.params and a.column_output is k.output
    for attr in ("copy_y", "copy_x", "out_index", "connect_map", "input_map", "output_map"):
        assert np.array_equal(np.asarray(getattr(reused, attr)), np.asarray(getattr(fresh, attr))), attr
    assert (reused.direct, reused.nstates, reused.nsignals, reused.fixed_point) == \
        (fresh.direct, fresh.nstates, fresh.nsignals, fresh.fixed_point)
    x = loop_module.initial_state(loop, loop.scenario)
    from blocks.engines.fastsim import CompiledLoop
    numpy_loop = CompiledLoop(loop)
    assert numpy_loop.plan is not fresh
    assert np.array_equal(numpy_loop.rhs(0.3, x), loop.dynamics(0.3, x, []))


def test_what_is_kept_holds_no_number():
    """The kept plan has no kernel function or parameter; the kept wiring only names and read-only matrices."""
    s = blocks.load_scenario("paper")
    loop = closed_loop(s)
    make_plan(loop)
    (plan,) = PLANS._entries.values()
    for step in plan.steps:
        assert step.output is step.update is step.column_output is None
        assert step.output_args is step.update_args is step.column_args is None
    (wiring,) = WIRINGS._entries.values()
    assert set(vars(wiring)) == {"maps", "outputs", "states", "connection_type"}
    assert all(not m.flags.writeable for m in wiring.maps)
    for array in (plan.out_index, plan.connect_map):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1


def test_a_fresh_process_gives_the_reused_numbers(tmp_path):
    """Runs of changed scenarios through structures kept in this process equal the same runs in a new process."""
    pytest.importorskip("numba")
    names = ["paper"] + (["scope4"] if _has_urdf() else [])
    change = {"gains.kp": 140.0, "disturbance.f_r[0]": 0.2, "simulation.t_final": 0.3}
    mine = {}
    for name in names:
        blocks.simulate(blocks.load_scenario(name).with_changes({"simulation.t_final": 0.3}), engine="compiled")
        mine[name] = blocks.simulate(blocks.load_scenario(name).with_changes(change), engine="compiled")
        assert len(WIRINGS) == names.index(name) + 1
    script = (
        "import json, sys, numpy as np, blocks\n"
        "out = {}\n"
        f"for name in {names!r}:\n"
        f"    r = blocks.simulate(blocks.load_scenario(name).with_changes({change!r}), engine='compiled')\n"
        "    np.save(sys.argv[1] + '/' + name + '_outputs.npy', np.asarray(r.outputs))\n"
        "    np.save(sys.argv[1] + '/' + name + '_states.npy', np.asarray(r.states))\n"
        "    out[name] = list(r.output_labels)\n"
        "print(json.dumps(out))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=600)
    assert done.returncode == 0, done.stderr
    labels = json.loads(done.stdout.strip().splitlines()[-1])
    for name in names:
        assert labels[name] == list(mine[name].output_labels)
        assert np.array_equal(np.load(tmp_path / f"{name}_outputs.npy"), np.asarray(mine[name].outputs))
        assert np.array_equal(np.load(tmp_path / f"{name}_states.npy"), np.asarray(mine[name].states))


# ----------------------------------------------------------------------------------------------------------------
# Other structure: never shared, in either order
# ----------------------------------------------------------------------------------------------------------------
def _user_plant(s):
    """The scenario's plant as a user's own python-control system (no kernels, no contract)."""
    from blocks.diagram.systems import plant, signal_names
    inner = plant(s.robot, s.disturbance)
    arm = s.robot
    return ct.nlsys(inner.updfcn, inner.outfcn, inputs=signal_names("tau", arm),
                    states=signal_names("q", arm) + signal_names("dq", arm),
                    outputs=signal_names("q", arm) + signal_names("dq", arm) + signal_names("tau_dis", arm),
                    name="plant")


def _paper():
    return blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.3})


def _locked_scope4():
    return blocks.load_scenario("scope4").with_changes({
        "simulation.t_final": 0.3, "arm.locked": ["roll"], "trajectory.amplitude": [0.3, 0.2, 0.03],
        "trajectory.omega": [0.8, 1.1, 1.5], "trajectory.offset": [0.0, 0.1, 0.1], "disturbance.f_r": [0.05, 0.1, 0.4]})


PAIRS = {
    "observer on / off": (lambda: (_paper(), True, None), lambda: (_paper(), False, None)),
    "step / tissue disturbance": (lambda: (_paper(), True, None),
                                  lambda: (_paper().with_changes({"disturbance.kind": ["step", "tissue"]}), True, None)),
    "diagonal / full observer gain": (
        lambda: (_paper().with_changes({"gains.observer": [[10.0, 0, 0, 0], [0, 10.0, 0, 0], [0, 0, 10.0, 0],
                                                            [0, 0, 0, 10.0]]}), True, None),
        lambda: (_paper().with_changes({"gains.observer": [[10.0, 1.0, 0, 0], [1.0, 10.0, 0, 0], [0, 0, 10.0, 0],
                                                            [0, 0, 0, 10.0]]}), True, None)),
    "paper / scope4": (lambda: (_paper(), True, None),
                       lambda: (blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.3}), True, None)),
    "scope4 / locked roll": (lambda: (blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.3}), True,
                                      None), lambda: (_locked_scope4(), True, None)),
    "scope4 / heavier nominal model": (
        lambda: (blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.3}), True, None),
        lambda: (blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.3,
                                                              "arm.nominal_mass_scale": 1.2}), True, None)),
    "scope4 / panda": (lambda: (blocks.load_scenario("scope4").with_changes({"simulation.t_final": 0.3}), True, None),
                       lambda: (blocks.load_scenario("panda").with_changes({"simulation.t_final": 0.3}), True, None)),
}
URDF_PAIRS = {"paper / scope4", "scope4 / locked roll", "scope4 / heavier nominal model", "scope4 / panda"}


@pytest.mark.parametrize("pair", [pytest.param(k, marks=needs_urdf) if k in URDF_PAIRS else k for k in PAIRS])
@pytest.mark.parametrize("order", ["forward", "backward"])
def test_other_structure_is_never_shared(pair, order):
    """Loops whose wiring, states, signals or traced code differ get keys of their own: the second is wired and
    planned anew whichever comes first, and its plan is the one planned with nothing kept."""
    makers = PAIRS[pair] if order == "forward" else PAIRS[pair][::-1]
    loops = []
    for k, make in enumerate(makers):
        s, observer, plant = make()
        loop = closed_loop(s, observer=observer, plant=plant)
        make_plan(loop)
        assert _kept() == (k + 1, k + 1), f"{pair}: loop {k + 1} shared a kept structure"
        loops.append(loop)
    first, second = loops
    assert blocks_structure(first.syslist) != blocks_structure(second.syslist)
    kept = make_plan(second)
    clear_reuse()
    fresh = make_plan(second)
    assert [(s.name, s.x, s.y) for s in kept.steps] == [(s.name, s.x, s.y) for s in fresh.steps]


def test_a_user_plant_is_never_kept_nor_given_a_kept_structure():
    """A plant without kernels (a user's python-control system) makes its loop unshared, before or after a loop of
    the Python plant; its run equals the Python plant's run built with nothing kept."""
    s = _paper()
    plant = _user_plant(s)
    assert block_structure(plant) is None
    user = closed_loop(s, plant=plant)
    assert _kept() == (0, 0) and user.syslist[2] is plant
    closed_loop(s)
    assert _kept() == (1, 0)
    again = closed_loop(s, plant=_user_plant(s))
    assert _kept() == (1, 0) and blocks_structure(again.syslist) is None
    make_plan(again)
    assert len(PLANS) == 0
    ours = blocks.simulate(s, engine="fast")
    theirs = blocks.simulate(s, plant=plant, engine="fast")
    np.testing.assert_allclose(np.asarray(theirs.outputs), np.asarray(ours.outputs), rtol=0, atol=1e-12)


def test_a_sampled_controller_has_a_plan_of_its_own():
    """The sampled-data loop (the [controller] section) is planned under its own key, apart from the continuous loop
    of the same scenario; a second sampled scenario with other gains reuses it and gives the numbers of a run with
    nothing kept."""
    digital = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 0.05})
    continuous = _paper()
    make_plan(closed_loop(continuous))
    assert len(PLANS) == 1
    first = blocks.simulate(digital, engine="fast")
    plans = len(PLANS)
    assert plans >= 2
    other = digital.with_changes({"gains.kp": 120.0})
    reused = blocks.simulate(other, engine="fast")
    assert len(PLANS) == plans
    clear_reuse()
    _assert_same_bits(reused, blocks.simulate(other, engine="fast"))
    assert not np.array_equal(np.asarray(first.outputs), np.asarray(reused.outputs))


# ----------------------------------------------------------------------------------------------------------------
# Bounded memory
# ----------------------------------------------------------------------------------------------------------------
def test_kept_structures_are_bounded(monkeypatch):
    """At most the capacity of structures is kept, the least recently used dropped first."""
    monkeypatch.setattr(WIRINGS, "capacity", 2)
    monkeypatch.setattr(PLANS, "capacity", 2)
    base = _paper()
    variants = [(base, True), (base, False), (base.with_changes({"disturbance.kind": ["step", "tissue"]}), True)]
    keys = []
    for s, observer in variants:
        loop = closed_loop(s, observer=observer)
        make_plan(loop)
        keys.append(plan_key(loop.syslist, *connection_maps(loop)))
        assert len(WIRINGS) <= 2 and len(PLANS) <= 2
    assert len(WIRINGS) == len(PLANS) == 2
    assert PLANS.get(keys[0]) is None and PLANS.get(keys[1]) is not None and PLANS.get(keys[2]) is not None
    # used last: kept when the next one comes
    PLANS.get(keys[1])
    loop = closed_loop(base.with_changes({"disturbance.kind": ["step", "friction"]}))
    make_plan(loop)
    assert PLANS.get(keys[1]) is not None and PLANS.get(keys[2]) is None


def test_many_scenarios_of_one_structure_keep_one_entry():
    """A sweep of thirty gains keeps one wiring and one plan."""
    base = _paper()
    for k in range(30):
        make_plan(closed_loop(base.with_changes({"gains.kp": 100.0 + k})))
    assert _kept() == (1, 1)


def test_structure_cache_refuses_a_bad_capacity():
    with pytest.raises(ValueError, match=r"capacity must be a whole number >= 1, got 0"):
        StructureCache(0)
    with pytest.raises(ValueError, match=r"capacity must be a whole number >= 1, got 2.5"):
        StructureCache(2.5)


def test_remembered_layouts_do_not_keep_blocks_alive():
    """The parameter layouts remembered per block go with their blocks (a sweep leaves nothing behind)."""
    import gc

    from blocks.diagram import structure
    base = _paper()
    gc.collect()
    before = len(structure._layouts)
    for k in range(5):
        loop = closed_loop(base.with_changes({"gains.kp": 120.0 + k}))
        make_plan(loop)
    assert len(structure._layouts) >= before + len(loop.syslist)
    del loop
    clear_reuse()
    gc.collect()
    assert len(structure._layouts) == before


def test_threads_building_one_structure_get_their_own_numbers():
    """Scenarios of one structure simulated from several threads at once give each its own numbers (those of a run
    with nothing kept) and keep one structure."""
    from concurrent.futures import ThreadPoolExecutor

    base = _paper().with_changes({"simulation.t_final": 0.2})
    scenarios = [base.with_changes({"gains.kp": 100.0 + 20 * k, "disturbance.f_r[2]": 0.5 + 0.1 * k})
                 for k in range(6)]
    with ThreadPoolExecutor(max_workers=3) as pool:
        together = list(pool.map(lambda s: blocks.simulate(s, engine="fast"), scenarios))
    assert _kept() == (1, 1)
    for s, resp in zip(scenarios, together):
        clear_reuse()
        _assert_same_bits(resp, blocks.simulate(s, engine="fast"))
