"""The sampled loop's stability rule (blocks.figure2.digital_stability) against independent derivations.

* the one-sample map built here another way -- the tick applied to each unit state, the plant, the held torque
  and the zoh observer propagated together by scipy.linalg.expm of one block matrix -- has the package's
  spectral radius, and a bisection on it gives the package's limits;
* the limits of issue 17 for the paper's gains (Kp = 180, Kd = 36): Ts lambda_max(Y M^-1) = 1.9795 / 1.9174 /
  1.7899 for zoh at 1 kHz / 250 Hz / 100 Hz; forward Euler with measured velocity exactly 2 (docs/model.md,
  "Digital observer": its estimate's error obeys e+ = (I - Ts Y M^-1) e whatever the torque), and docs/model.md's
  table is the computation's;
* the nonlinear sampled loop (held arm, past the pre-run check) decays at 0.99 of the computed limit and grows at
  1.01 of it;
* at 0.99 of the limit ``blocks.simulate`` runs and stays bounded; at 1.01 it is refused before the run (no
  progress reported), naming the keys and the computed limit; the issue's zoh scenario through ``dobkit simulate``
  exits 2.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from conftest import reference_inertia

import blocks
from blocks.diagram.digital import DigitalController
from blocks.figure2.digital_stability import held_exponential, sampled_stability, scenario_stability, spectral_radius
from blocks.figure2.metrics import signal
from blocks.figure2.sampled_blocks import sampled_initial_state, sampled_loop
from blocks.model.rrpr.parameters import RobotParameters
from blocks.scenarios.scenario import ScenarioError
from dobkit.cli import main

Q0 = np.array([0.3, 1.2, 0.1, 0.2])
HELD = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.0] * 4, "trajectory.offset": Q0.tolist()}
# a smooth moving path that the sampled PD at 100 Hz tracks to a few mm (the laceration's needle roll it cannot)
SINE = {"trajectory.kind": "joint_sine", "trajectory.amplitude": [0.2, 0.3, 0.02, 0.5],
        "trajectory.omega": [1.0, 1.5, 2.0, 2.5], "trajectory.offset": Q0.tolist()}
KP, KD, Y10 = 180.0 * np.eye(4), 36.0 * np.eye(4), 10.0 * np.eye(4)
K4 = 0.25                                     # lambda_min(M): the prismatic joint, lambda_max(10 M^-1) = 40 1/s
DOCS = Path(__file__).resolve().parents[1] / "docs" / "model.md"

# (discretization, velocity, low-pass cut-off Hz, delay): the settings the rule must cover
CASES = [("euler", "measured", None, 0), ("zoh", "measured", None, 0), ("euler", "difference", 40.0, 0),
         ("zoh", "difference", 40.0, 0), ("zoh", "measured", None, 1)]


def _settings(rate, method="euler", velocity="measured", cutoff=None, delay=0) -> DigitalController:
    return DigitalController(sample_rate=rate, observer_discretization=method, velocity=velocity,
                             velocity_cutoff=cutoff, delay=delay)


def _by_columns(M, kp, kd, Y, Ts, method, velocity="measured", pole=0.0, delay=0) -> np.ndarray:
    """The linearized loop's one-sample map, written here from the [controller] section's definition.

    State (another order than the package's): ``[z, q, v, w_prev, p, newest command .. oldest command]``.
    Between samples the plant under the held torque and the observer with its held inputs are one linear
    system ``[q, v, z, tau, w]' = F [q, v, z, tau, w]`` (tau and w constant), propagated by ``expm(F Ts)``.
    """
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    A = -Y @ Minv
    F = np.zeros((5 * n, 5 * n))
    F[:n, n:2 * n] = np.eye(n)                                  # q' = v
    F[n:2 * n, 3 * n:4 * n] = Minv                              # v' = M^-1 tau
    F[2 * n:3 * n, 2 * n:3 * n] = A                             # z' = -Y M^-1 (tau + Y w + z)
    F[2 * n:3 * n, 3 * n:4 * n] = A
    F[2 * n:3 * n, 4 * n:5 * n] = A @ Y
    E = scipy.linalg.expm(F * Ts)
    diff = velocity == "difference"
    m = n * (3 + 2 * diff + delay)

    def tick(x):
        z, q, v = x[:n], x[n:2 * n], x[2 * n:3 * n]
        rest = x[3 * n:]
        if diff:
            w_prev, p, rest = rest[:n], rest[n:2 * n], rest[2 * n:]
            w = pole * w_prev + (1 - pole) * (q - p) / Ts
        else:
            w = v
        buffer = [rest[j * n:(j + 1) * n] for j in range(delay)]          # newest first
        command = M @ (-kp * q - kd * w) - (Y @ w + z)
        tau = buffer[-1] if delay else command
        moved = E @ np.concatenate([q, v, z, tau, w])
        z_next = moved[2 * n:3 * n] if method == "zoh" else z + Ts * (A @ (tau + Y @ w + z))
        out = [z_next, moved[:n], moved[n:2 * n]]
        if diff:
            out += [w, q]
        if delay:
            out += [command] + buffer[:-1]
        return np.concatenate(out)
    return np.column_stack([tick(e) for e in np.eye(m)])


def _radius(*args, **kwargs) -> float:
    return float(np.abs(np.linalg.eigvals(_by_columns(*args, **kwargs))).max())


def _limit_by_bisection(M, kp, kd, Y, Ts, method, velocity="measured", pole=0.0, delay=0, rtol=1e-6) -> float:
    """The largest c with radius(c Y) < 1, bracketed from below by a stable c (geometric bisection)."""
    lo, hi = 0.5, 0.5
    while _radius(M, kp, kd, hi * Y, Ts, method, velocity, pole, delay) < 1:
        lo, hi = hi, 2 * hi
    while hi / lo > 1 + rtol:
        mid = np.sqrt(lo * hi)
        stable = _radius(M, kp, kd, mid * Y, Ts, method, velocity, pole, delay) < 1
        lo, hi = (mid, hi) if stable else (lo, mid)
    return lo


# --------------------------------------------------------------------------------------------------------------
# The map and its limits against an independent construction and the issue's numbers
# --------------------------------------------------------------------------------------------------------------
def test_held_exponential_equals_scipy_expm_of_the_augmented_matrix():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 4, 4)) * 40
    for Ts in (1e-4, 1e-2, 0.2):
        held, integral = held_exponential(A, Ts)
        for i in range(len(A)):
            aug = np.zeros((8, 8))
            aug[:4, :4], aug[:4, 4:] = A[i] * Ts, np.eye(4) * Ts
            E = scipy.linalg.expm(aug)
            np.testing.assert_allclose(held[i], E[:4, :4], rtol=1e-11, atol=1e-13 * np.abs(E[:4, :4]).max())
            np.testing.assert_allclose(integral[i], E[:4, 4:], rtol=1e-11, atol=1e-13 * np.abs(E[:4, 4:]).max())


@pytest.mark.parametrize("method, velocity, cutoff, delay", CASES + [("euler", "difference", None, 2)])
def test_the_spectral_radius_equals_an_independently_built_map(method, velocity, cutoff, delay):
    M = blocks.inertia(Q0, blocks.PAPER_PARAMETERS)
    settings = _settings(100.0, method, velocity, cutoff, delay)
    Y = np.array([[40.0, 3.0, 0.0, -1.0], [2.0, 30.0, 0.0, 0.0], [0.0, 0.0, 15.0, 0.0], [0.5, 0.0, 0.0, 20.0]])
    for gain in (Y10, 4.0 * Y10, Y):
        want = _radius(M, 180.0, 36.0, gain, 0.01, method, velocity, settings.filter_pole, delay)
        got = spectral_radius(M, KP, KD, gain, settings)
        assert got == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("rate, want", [(1000.0, 1.9795), (250.0, 1.9174), (100.0, 1.7899)])
def test_zoh_limits_are_the_issues(rate, want):
    """zoh, measured velocity, Kp 180, Kd 36, paper arm: the issue's Ts lambda_max at the limit, and the same
    limit from a bisection on the map built here."""
    got = sampled_stability(blocks.PAPER_PARAMETERS, [Q0], KP, KD, Y10, _settings(rate, "zoh"))
    assert got.ts_lambda_max == pytest.approx(40.0 / rate, rel=1e-9)            # Y / k4
    assert got.ts_lambda_limit == pytest.approx(want, abs=1e-4)
    assert got.ts_lambda_limit < 2.0
    M = blocks.inertia(Q0, blocks.PAPER_PARAMETERS)
    independent = _limit_by_bisection(M, 180.0, 36.0, Y10, 1 / rate, "zoh")
    assert got.largest_stable_scale == pytest.approx(independent, rel=1e-5)


@pytest.mark.parametrize("delay", [0, 1])
def test_euler_with_measured_velocity_reaches_two(delay):
    """Euler's estimate error obeys e+ = (I - Ts Y M^-1) e whatever the torque: limit 2 / (Ts lambda_max)
    = 2 f / 40, with or without a delay."""
    for rate in (100.0, 1000.0):
        got = sampled_stability(blocks.PAPER_PARAMETERS, [Q0], KP, KD, Y10, _settings(rate, delay=delay))
        assert got.largest_stable_scale == pytest.approx(2 * rate / 40.0, rel=1e-6)
        assert got.ts_lambda_limit == pytest.approx(2.0, rel=1e-6)


def test_difference_velocity_and_a_delay_limits_match_the_independent_map():
    """Euler with difference velocity and a 40 Hz low-pass at 100 Hz: below Ts lambda = 1.5 (the issue's
    diverging case); zoh with a delay of one sample below zoh without."""
    M = blocks.inertia(Q0, blocks.PAPER_PARAMETERS)
    settings = _settings(100.0, "euler", "difference", 40.0)
    got = sampled_stability(blocks.PAPER_PARAMETERS, [Q0], KP, KD, Y10, settings)
    assert got.ts_lambda_limit < 1.5
    independent = _limit_by_bisection(M, 180.0, 36.0, Y10, 0.01, "euler", "difference", settings.filter_pole)
    assert got.largest_stable_scale == pytest.approx(independent, rel=1e-5)
    delayed = sampled_stability(blocks.PAPER_PARAMETERS, [Q0], KP, KD, Y10, _settings(100.0, "zoh", delay=1))
    assert delayed.largest_stable_scale == pytest.approx(_limit_by_bisection(M, 180.0, 36.0, Y10, 0.01, "zoh",
                                                                              delay=1), rel=1e-5)
    assert delayed.ts_lambda_limit < 1.7899


def test_the_worst_configuration_over_a_path_binds():
    """The limit over several configurations is the smallest of theirs, found at the binding one."""
    qs = np.array([[0.0, t2, 0.1, 0.0] for t2 in (0.3, 1.2, 2.8)])
    settings = _settings(100.0, "zoh", "difference", 20.0)
    Y = np.diag([40.0, 10.0, 2.0, 10.0])                          # the prismatic mode no longer dominates
    each = [sampled_stability(blocks.PAPER_PARAMETERS, [q], KP, KD, Y, settings).largest_stable_scale for q in qs]
    together = sampled_stability(blocks.PAPER_PARAMETERS, qs, KP, KD, Y, settings)
    assert together.largest_stable_scale == pytest.approx(min(each), rel=1e-6)
    assert len(set(np.round(each, 6))) == 3                        # the configurations do differ


def test_the_table_in_docs_is_the_computation():
    """docs/model.md, "Digital observer": every number of its limits table is the computation's (4 decimals)."""
    text = DOCS.read_text(encoding="utf-8")
    header = next(line for line in text.splitlines() if line.startswith("| rate | euler, measured"))
    columns = [c.strip() for c in header.strip("|").split("|")][1:]
    rows = [line for line in text.splitlines() if re.match(r"\| [0-9.]+ k?Hz \|", line)]
    assert len(rows) == 3
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rate = float(cells[0].split()[0]) * (1000.0 if "kHz" in cells[0] else 1.0)
        for name, shown in zip(columns, cells[1:]):
            method = name.split(",")[0]
            delay = 1 if "delay 1" in name else 0
            cutoff = 40.0 if "difference 40 Hz" in name else None
            velocity = "difference" if cutoff else "measured"
            got = sampled_stability(blocks.PAPER_PARAMETERS, [Q0], KP, KD, Y10,
                                    _settings(rate, method, velocity, cutoff, delay))
            assert f"{got.ts_lambda_limit:.4f}" == shown, (rate, name)


# --------------------------------------------------------------------------------------------------------------
# The computed limit against the nonlinear sampled loop, and the pre-run check
# --------------------------------------------------------------------------------------------------------------
def _paper(changes: dict) -> blocks.Scenario:
    return blocks.load_scenario("paper").with_changes(changes)


def _case(method, velocity, cutoff, delay) -> dict:
    changes = {"controller.sample_rate": 100.0, "controller.observer_discretization": method,
               "controller.velocity": velocity, "controller.delay": delay}
    return changes | ({"controller.velocity_cutoff": cutoff} if cutoff else {})


@pytest.mark.parametrize("method, velocity, cutoff, delay", [CASES[1], CASES[2]])
def test_the_nonlinear_loop_decays_inside_the_limit_and_grows_outside(method, velocity, cutoff, delay):
    """Held arm, the observer started at 0 against the paper's step: the estimate's sample-to-sample swing
    shrinks at 0.99 of the computed limit and grows at 1.01 (the run bypasses the pre-run check)."""
    s = _paper(HELD | _case(method, velocity, cutoff, delay) | {"simulation.t_final": 1.0,
                                                                "simulation.output_step": 0.01})
    scale = scenario_stability(s).largest_stable_scale
    for factor, grows in ((0.99, False), (1.01, True)):
        g = s.with_changes({"gains.observer": 10.0 * scale * factor})
        loop = sampled_loop(g)
        _, out = loop.simulate(sampled_initial_state(loop, g), g.simulation.time_grid)
        swing = np.abs(np.diff(out[loop.output_labels.index("d_hat[2]")]))
        early, late = swing[10:30].max(), swing[-20:].max()
        assert bool(late > early) == grows, (factor, early, late)


@pytest.mark.parametrize("method, velocity, cutoff, delay", CASES)
def test_just_inside_runs_bounded_and_just_outside_is_refused_before_the_run(method, velocity, cutoff, delay):
    s = _paper(SINE | _case(method, velocity, cutoff, delay) | {"simulation.t_final": 0.5,
                                                                "simulation.output_step": 0.01})
    verdict = scenario_stability(s)
    scale = verdict.largest_stable_scale
    inside = blocks.simulate(s.with_changes({"gains.observer": 10.0 * scale * 0.99}))
    error = signal(inside, "q_ref") - signal(inside, "q")
    assert np.all(np.isfinite(error)) and np.abs(error).max() < 0.01          # rad, m: tracking, not diverging
    assert np.abs(signal(inside, "d_hat")).max() < 20.0                        # N m, N; the step is 1.2-1.6

    reported = []
    with pytest.raises(ScenarioError) as refused:
        blocks.simulate(s.with_changes({"gains.observer": 10.0 * scale * 1.01}), progress=reported.append)
    assert reported == []                                                      # nothing was simulated
    message = str(refused.value)
    for key in ("'controller.sample_rate' = 100 Hz", "'gains.observer'", f"observer_discretization = \"{method}\"",
                f"controller.velocity = \"{velocity}\"", f"controller.delay = {delay}"):
        assert key in message, key
    limit = float(re.search(r"Ts lambda_max\(Y M\^-1\) < ([0-9.]+)", message).group(1))
    assert limit == pytest.approx(verdict.ts_lambda_limit, rel=1e-3)
    shown_scale = float(re.search(r"at most ([0-9.]+) x gains.observer", message).group(1))
    assert shown_scale == pytest.approx(1 / 1.01, rel=1e-3)                   # of the refused gain


def test_a_controller_unstable_at_the_rate_names_its_gains():
    """Kd = 300 1/s at 100 Hz: the sampled PD loop alone has Ts kd = 3 > 2 (unstable for any observer gain)."""
    s = _paper(HELD | {"controller.sample_rate": 100.0, "gains.kd": 300.0, "simulation.t_final": 0.1})
    assert scenario_stability(s).largest_stable_scale == 0.0
    with pytest.raises(ScenarioError, match=r"for any 'gains.observer'.*'gains.kp' / 'gains.kd'"):
        blocks.simulate(s)


def test_the_issues_zoh_scenario_is_refused_by_dobkit_simulate(tmp_path, capsys):
    path = tmp_path / "zoh.toml"
    path.write_text("name = \"zoh-100\"\n[gains]\nkp = 180.0\nkd = 36.0\nobserver = 48.75\n"
                    "[controller]\nsample_rate = 100\nobserver_discretization = \"zoh\"\nvelocity = \"measured\"\n"
                    "[simulation]\nt_final = 1.0\noutput_step = 0.01\n")
    out = tmp_path / "out"
    assert main(["simulate", "--scenario", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'controller.sample_rate' = 100 Hz" in err and "'gains.observer'" in err
    assert "observer_discretization = \"zoh\"" in err
    # Ts lambda_max = 48.75 / 0.25 / 100 = 1.95 against the computed 1.7899; 44.74 = 1.7899 / 1.95 x 48.75
    assert "Ts lambda_max(Y M^-1) = 1.95" in err and "< 1.789" in err and "scalar gain: 44.7" in err
    assert not out.exists() or not any(out.iterdir())


PAPER = RobotParameters()


Q = np.array([0.4, 1.1, 0.2, 0.3])            # a pose away from every singularity (rad, rad, m, rad)


def _euler_map(M, kp, kd, Y, Ts, eq16_weight):
    """One sample of the held loop, forward Euler, measured velocity, no delay, built column by column from the
    [controller] definitions: tau = -M (Kp q + Kd v) - (Y v + z); the plant under held tau exactly (a double
    integrator); z+ = z + Ts (-Y M^-1 (tau + Y v + z) - w16 Y v)."""
    n = M.shape[0]
    Minv = np.linalg.inv(M)

    def tick(x):
        q, v, z = x[:n], x[n:2 * n], x[2 * n:]
        tau = -M @ (kp * q + kd * v) - (Y @ v + z)
        a = Minv @ tau
        z_next = z + Ts * (-Y @ Minv @ (tau + Y @ v + z) - eq16_weight * (Y @ v))
        return np.concatenate([q + Ts * v + 0.5 * Ts ** 2 * a, v + Ts * a, z_next])
    return np.column_stack([tick(e) for e in np.eye(3 * n)])


def _variant_radius(*args) -> float:
    return float(np.abs(np.linalg.eigvals(_euler_map(*args))).max())


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
@pytest.mark.parametrize("variant, weight", [("correct", 0.0), ("paper-eq16", 1.0)])
def test_the_sampled_map_of_each_observer_variant_and_its_stable_limit(variant, weight):
    """ds-variant-swap, ds-eq16-sign, ds-return-hi: the spectral radius of each variant equals that of the map
    built here; the largest stable scale is stable (radius at most 1, to rounding: for the correct law the limit
    is exactly 2 / (Ts lambda_max), where the error mode sits at -1) and a hair above it is not."""
    from blocks.diagram.digital import DigitalController
    from blocks.figure2.digital_stability import sampled_stability
    Ts = 0.01
    M = reference_inertia(Q[1])
    Y = np.diag([40.0, 30.0, 15.0, 20.0])
    s = sampled_stability(PAPER, [Q], 180.0 * np.eye(4), 36.0 * np.eye(4), Y,
                          DigitalController(sample_rate=1.0 / Ts), variant=variant)
    assert s.spectral_radius == pytest.approx(_variant_radius(M, 180.0, 36.0, Y, Ts, weight), rel=1e-9)
    c = s.largest_stable_scale
    assert 0.0 < c < math.inf
    assert _variant_radius(M, 180.0, 36.0, c * Y, Ts, weight) < 1.0 + 1e-12
    assert _variant_radius(M, 180.0, 36.0, c * (1 + 1e-5) * Y, Ts, weight) >= 1.0
