"""Budgets: sizes and settings read as documented, estimates that bound what a batch really allocates."""
from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

import blocks
from blocks.engines.budget import (
    DEFAULT_MEMORY,
    DEFAULT_STEPS,
    NOISE_SAMPLE_BYTES_PER_JOINT,
    SIGNAL_POINT_BYTES_PER_JOINT,
    Budget,
    BudgetError,
    estimate_batch,
    format_bytes,
    largest_batch,
    parse_size,
    schedule_steps,
)
from blocks.figure2.batch import Variants, simulate_batch, step_schedule


@pytest.mark.parametrize("text, size", [("4G", 4 * 1024 ** 3), ("4GiB", 4 * 1024 ** 3), ("512M", 512 * 1024 ** 2),
                                        ("512 mb", 512 * 1024 ** 2), ("1.5K", 1536), ("1e9", 10 ** 9),
                                        (2048, 2048), ("3T", 3 * 1024 ** 4)])
def test_sizes_read_as_written(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize("text", ["", "lots", "-1G", "0", "4X", "nan", "inf", True, float("nan")])
def test_sizes_that_are_not_sizes_are_refused(text):
    with pytest.raises(ValueError, match="memory size"):
        parse_size(text)


def test_bytes_are_shown_in_binary_units():
    assert [format_bytes(n) for n in (3, 2048, 5 * 1024 ** 2, 4 * 1024 ** 3)] == ["3 B", "2.0 KiB", "5.0 MiB",
                                                                                   "4.0 GiB"]


def test_flags_override_variables_which_override_defaults():
    assert Budget.from_env({}) == Budget(DEFAULT_MEMORY, DEFAULT_STEPS, None)
    env = {"DOBKIT_MAX_MEMORY": "1G", "DOBKIT_MAX_STEPS": "5e6", "DOBKIT_MAX_SECONDS": "60"}
    assert Budget.from_env(env) == Budget(1024 ** 3, 5_000_000, 60.0)
    assert Budget.from_env(env, memory="2G", steps=10, seconds=1.5) == Budget(2 * 1024 ** 3, 10, 1.5)
    with pytest.raises(ValueError, match="DOBKIT_MAX_STEPS"):
        Budget.from_env({"DOBKIT_MAX_STEPS": "2.5"})
    with pytest.raises(ValueError, match="DOBKIT_MAX_SECONDS"):
        Budget.from_env({"DOBKIT_MAX_SECONDS": "-1"})
    with pytest.raises(ValueError, match="step budget"):
        Budget(steps=0)


def test_over_budget_names_the_estimate_and_the_key():
    need = estimate_batch(1, steps=5_000_000, grid_points=2001, keys={"steps": "gains.observer"},
                          steps_reason="2000 output intervals x 2500 substeps", joints=4)
    with pytest.raises(BudgetError) as err:
        Budget(steps=2_000_000).check(need, "run 3")
    assert err.value.key == "gains.observer" and err.value.limit == "steps"
    assert "run 3" in str(err.value) and "5e+06" in str(err.value) and "2e+06" in str(err.value)
    assert "--max-steps" in str(err.value)
    noisy = estimate_batch(1, steps=1000, grid_points=101, noise=True, noise_samples=10 ** 8,
                           keys={"steps": "x"}, joints=4)
    with pytest.raises(BudgetError) as err:
        Budget().check(noisy, "run 0")
    assert err.value.key == "noise.sample_period" and err.value.limit == "memory" and "--max-memory" in str(err.value)
    Budget().check(estimate_batch(250, steps=12_000, grid_points=2001, noise=True, noise_samples=10_002, joints=4), "a batch")


def test_largest_batch_is_the_largest_that_fits():
    kwargs = dict(steps=20_000, grid_points=2001, noise=True, noise_samples=10_002, joints=4)
    memory = 300 * 1024 ** 2
    n = largest_batch(memory, **kwargs)
    assert n >= 1
    assert estimate_batch(n, **kwargs).memory <= memory < estimate_batch(n + 1, **kwargs).memory
    assert largest_batch(1000, **kwargs) == 0


def _peak(job) -> int:
    gc.collect()
    tracemalloc.start()
    try:
        job()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("members, noise, substeps", [(1, False, 1), (40, False, 1), (1, False, 6), (1, True, 1),
                                                      (40, True, 2)])
def test_the_estimate_bounds_what_a_batch_allocates(members, noise, substeps):
    base = blocks.load_scenario("paper").with_changes({"simulation.t_final": 0.3, "trajectory.duration": 10.0})
    records = [{"gains.kp": 150.0 + i} | ({"noise.q_std": [1e-5] * 4, "noise.seed": i} if noise else {})
               for i in range(members)]
    sim = base.simulation
    samples = int(np.ceil(sim.t_final / base.data["noise"]["sample_period"])) + 2
    steps = schedule_steps(sim.t_final, sim.output_step, substeps, breakpoints=samples if noise else 0)
    need = estimate_batch(members, steps=steps, grid_points=int(round(sim.t_final / sim.output_step)) + 1,
                          noise=noise, noise_samples=samples, joints=4)
    run = lambda: simulate_batch(None, Variants(base, records), substeps=substeps)   # noqa: E731
    run()                       # the compiled engine's first call compiles: code, not the batch's data
    measured = _peak(run)
    assert measured <= need.memory <= 8 * measured + 2 * 1024 ** 2, (measured, need.memory)


def test_a_schedule_with_many_breakpoints_takes_memory_in_proportion():
    """10 s at 5 ms with a noise sample every 0.5 ms: 20000 breakpoints between 2000 grid points."""
    breaks = list(np.arange(1, 20_000) * 5e-4 + 1e-4)
    peak = _peak(lambda: step_schedule(10.0, 0.005, 1, breaks))
    assert peak < 20 * 1024 ** 2          # was a 20000 x 2001 table of distances: 340 MB
    # the points kept are those not within `merge` of a grid point, found here by brute force on a short piece
    short = [b for b in breaks if b < 0.1] + [0.05 + 5e-10, 0.07 - 2e-9]
    times, grid_index = step_schedule(0.1, 0.005, 1, short)
    grid = np.linspace(0.0, 0.1, 21)
    kept = [b for b in short if np.min(np.abs(np.array(grid) - b)) > 1e-9]
    np.testing.assert_array_equal(times, np.union1d(grid, kept))
    assert list(times[grid_index >= 0]) == list(times[np.isin(times, grid)])


def test_a_batch_estimate_scales_its_per_joint_parts_with_the_arm():
    """Noise samples and kept signals hold n (2n) numbers: a 7-joint arm needs 7/4 of the 4-joint parts."""
    four = estimate_batch(10, steps=0, grid_points=1001, signals=3, noise=True, noise_samples=5001, joints=4)
    seven = estimate_batch(10, steps=0, grid_points=1001, signals=3, noise=True, noise_samples=5001, joints=7)
    grow = seven.memory - four.memory
    per_joint_parts = (10 * NOISE_SAMPLE_BYTES_PER_JOINT * 5001 + 10 * SIGNAL_POINT_BYTES_PER_JOINT * 1001 * 3) * 3
    assert abs(grow - per_joint_parts) <= 2
