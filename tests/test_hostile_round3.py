"""Hostile inputs, round 3 (issue 22): what still got through, each held to a refusal or a correct result.

Expected numbers come from docs/model.md and the paper's Table 1 (conftest), worked by hand here: the
prismatic joint's position is ``d3 = d1 - d4 - z``, the PD loop's fastest rate with ``kd^2 < 4 kp`` is
``sqrt(kp)``, an explicit RK45 step is stable for ``h <= 3 / rate``.  docs/hostile-inputs.md, "Round 3",
lists each case with its test.
"""
from __future__ import annotations

import errno
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import D1, D4, L1, L2, SHORT_SCENARIO_TOML, SKIN_DEFAULT, reference_inertia

import blocks
from blocks import PAPER_PARAMETERS as P
from blocks import ScenarioError
from blocks.budget import BudgetError
from blocks.divergence import StateBounds
from blocks.gains import GainError, validated_gain
from blocks.outputs import file_error
from dobkit.signals import INTERRUPTED, TERMINATED, run_with_signals

PAPER = blocks.load_scenario("paper")
D3_STROKE = (0.0, 0.48)            # docs/model.md, "Joint ranges": 0 to twice Table 1's d3 = 0.24 m


def _dobkit(*args, cwd=None, timeout=600):
    return subprocess.run([sys.executable, "-m", "dobkit", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


# --------------------------------------------------------------------------------------------
# Silent wrong answers: every joint's range, argument shapes and finiteness
# --------------------------------------------------------------------------------------------
def test_a_stitch_a_million_metres_deep_is_refused_naming_the_joint_its_reach_and_its_range():
    with pytest.raises(ScenarioError) as err:
        PAPER.with_changes({"trajectory.depth": 1e6})
    text = str(err.value)
    # d3 = d1 - d4 - z at the stitch's bottom z = skin - depth; the paper's skin is at Table 1's d3 = 0.24 m
    deepest = D1 - D4 - (SKIN_DEFAULT - 1e6)
    assert deepest == pytest.approx(1e6 + 0.24)
    assert f"d3 reaches {deepest:.6g} m, outside its range 0 to 0.48 m" in text
    assert "trajectory.depth" in text and "[trajectory]" in text


@pytest.mark.parametrize("key, inside, outside", [
    # d3 at the stitch's bottom is 0.24 + depth (<= 0.48), at the hover height 0.24 - hover (>= 0)
    ("trajectory.depth", 0.235, 0.245),
    ("trajectory.hover", 0.235, 0.245),
])
def test_the_stroke_bounds_the_stitch_where_the_hand_computation_says(key, inside, outside):
    assert PAPER.with_changes({key: inside}).data["trajectory"][key.split(".")[1]] == inside
    with pytest.raises(ScenarioError, match=r"d3 reaches .* outside its range 0 to 0\.48 m"):
        PAPER.with_changes({key: outside})


def test_joint_sines_and_initial_positions_outside_the_stroke_are_refused():
    sine = {"trajectory.kind": "joint_sine", "trajectory.offset": [0.0, 2.0, 0.3, 0.0], "trajectory.omega": 1.0,
            "trajectory.amplitude": [0.1, 0.1, 0.25, 0.1]}
    # 0.3 + 0.25 sin(t) reaches 0.55 m at t = pi/2, within the 10 s run (and 0.05 m, inside, at 3 pi/2)
    with pytest.raises(ScenarioError, match=r"joint sine: d3 reaches 0\.55 m, outside its range 0 to 0\.48 m"):
        PAPER.with_changes(sine)
    # over a 0.5 s run the same sine reaches only 0.3 + 0.25 sin(0.5) = 0.420 m: inside the stroke
    short = PAPER.with_changes(sine | {"simulation.t_final": 0.5, "simulation.output_step": 0.01})
    assert short.trajectory.amplitude[2] == 0.25
    with pytest.raises(ScenarioError, match=r"'initial\.q\[2\]' = -0\.01 m is outside the range of joint d3, 0 to "
                                            r"0\.48 m"):
        PAPER.with_changes({"initial.q": [0.0, 1.0, -0.01, 0.0]})


def test_the_revolute_joints_turn_without_limit():
    assert blocks.RRPR_JOINTS.limits[0] == (-math.inf, math.inf)
    assert blocks.RRPR_JOINTS.limits[2] == D3_STROKE
    assert blocks.RRPR_JOINTS.outside_limits([[50.0, -50.0, 0.1, 1e6]]) is None


@pytest.mark.parametrize("call, error, words", [
    (lambda: blocks.forward_kinematics(np.zeros((4, 5)), P), ValueError, r"q must have shape \(\.\.\., 4\).*\(4, 5\)"),
    (lambda: blocks.forward_kinematics(np.zeros(3), P), ValueError, r"q must have shape \(\.\.\., 4\).*\(3,\)"),
    (lambda: blocks.inertia(np.full(4, np.nan), P), ValueError, r"q must be finite.*nan"),
    (lambda: blocks.jacobian(None, P), TypeError, r"q must be an array of real numbers, got NoneType"),
    (lambda: blocks.gravity(np.zeros(4), "x"), TypeError, r"params must be an arm model \(blocks.arm.ArmModel.*got str 'x'"),
    (lambda: blocks.forward_dynamics(np.zeros(4), np.zeros((2, 4)), np.zeros((3, 4)), P), ValueError,
     r"q, dq, tau must have shapes that broadcast together, got q \(4,\), dq \(2, 4\), tau \(3, 4\)"),
    (lambda: blocks.inverse_kinematics([0.5, 0.0, 0.0], P), ValueError, r"pose must have shape \(\.\.\., 4\)"),
])
def test_public_functions_refuse_bad_arrays_naming_the_argument_and_its_shape(call, error, words):
    with pytest.raises(error, match=words):
        call()


def test_batches_of_good_arrays_still_give_the_hand_computed_numbers():
    q = np.array([[0.3, 1.2, 0.1, 0.2], [0.0, np.pi / 2, 0.2, 0.0]])
    pose = blocks.forward_kinematics(q, P)
    # x = l1 c1 + l2 c12, y = l1 s1 + l2 s12, z = d1 - d3 - d4, phi = theta1 + theta2 - theta4 (docs/model.md)
    expected = [[L1 * math.cos(t1) + L2 * math.cos(t1 + t2), L1 * math.sin(t1) + L2 * math.sin(t1 + t2),
                 D1 - d3 - D4, t1 + t2 - t4] for t1, t2, d3, t4 in q]
    np.testing.assert_allclose(pose, expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(blocks.inertia(q, P), [reference_inertia(t2) for t2 in q[:, 1]], rtol=1e-13)


# Bad values of every kind a user may pass; each public function must answer TypeError or ValueError.
BAD_VALUES = [None, "x", True, {}, object(), 1j, [1.0, 2.0, 3.0], [[1.0, 2.0], [3.0]], [math.nan] * 4,
              [math.inf, 0, 0, 0], [10 ** 400, 0, 0, 0], [1j, 0, 0, 0], np.array(["1", "2", "3", "4"]),
              np.zeros((4, 5)), np.zeros((0, 3))]
# any real array of times is a time grid (it broadcasts against the joints' leading shape)
BAD_TIMES = [None, "x", True, {}, object(), 1j, [math.nan], [10 ** 400], [[1.0, 2.0], [3.0]]]
Q = [0.3, 1.2, 0.1, 0.2]
FUNCTIONS = {
    "inertia": (blocks.inertia, {"q": Q, "params": P}),
    "coriolis_vector": (blocks.coriolis_vector, {"q": Q, "dq": Q, "params": P}),
    "coriolis_matrix": (blocks.coriolis_matrix, {"q": Q, "dq": Q, "params": P}),
    "gravity": (blocks.gravity, {"q": Q, "params": P}),
    "forward_dynamics": (blocks.forward_dynamics, {"q": Q, "dq": Q, "tau": Q, "params": P}),
    "inverse_dynamics": (blocks.inverse_dynamics, {"q": Q, "dq": Q, "ddq": Q, "params": P}),
    "kinetic_energy": (blocks.kinetic_energy, {"q": Q, "dq": Q, "params": P}),
    "forward_kinematics": (blocks.forward_kinematics, {"q": Q, "params": P}),
    "jacobian": (blocks.jacobian, {"q": Q, "params": P}),
    "inverse_kinematics": (blocks.inverse_kinematics, {"pose": [0.45, 0.1, -0.39, 0.0], "params": P}),
    "external_disturbance": (blocks.external_disturbance,
                             {"t": 0.5, "q": Q, "dq": Q, "spec": PAPER.disturbance, "params": P}),
    "lumped_disturbance": (blocks.lumped_disturbance,
                           {"q": Q, "dq": Q, "tau": Q, "tau_dis": Q, "scenario": PAPER}),
}


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_public_functions_answer_any_bad_argument_with_a_type_or_value_error_naming_it(name):
    function, good = FUNCTIONS[name]
    function(**good)                                         # the good call works
    for argument in good:
        for bad in BAD_TIMES if argument == "t" else BAD_VALUES:
            try:
                function(**(good | {argument: bad}))
            except (TypeError, ValueError) as err:
                assert argument in str(err), (name, argument, bad, err)
            else:
                raise AssertionError(f"{name}({argument}={bad!r:.60}) was accepted")


def test_entry_points_answer_bad_input_with_their_documented_errors(tmp_path):
    """A fuzz-like pass over the scenario's entry points: only ScenarioError/ValueError/TypeError escape."""
    deep: list = []
    for _ in range(3000):
        deep = [deep]
    values = [None, "x", True, {}, [], [[1.0]], 10 ** 400, -10 ** 400, [10 ** 400] * 4, math.nan, math.inf,
              -math.inf, 1e308, -1e308, deep, object()]
    keys = ["gains.kp", "gains.kd", "gains.observer", "simulation.t_final", "simulation.output_step",
            "trajectory.depth", "trajectory.start", "trajectory.stitches", "noise.seed", "noise.q_std", "initial.q",
            "disturbance.f_r", "robot.m1", "nominal_scale.I2", "controller.sample_rate", "observer.variant"]
    for key in keys:
        for value in values:
            try:
                PAPER.with_changes({key: value})
            except ScenarioError as err:
                # the key, dotted or as '[section] ... name'
                assert key.split(".")[1] in str(err) or "nested too deeply" in str(err), (key, value, err)
            # a value the scenario takes is fine: it was checked
    for given in [None, 5, 2.5, b"paper", ["paper"], {"gains": {"kp": 100}}, object(), "no-such-scenario"]:
        with pytest.raises((TypeError, ScenarioError)):
            blocks.load_scenario(given)
    for given in [None, 5, "paper", ["paper"], {"gains": 5}, {"gains": {"kp": deep}}, {"nope": 1}, object()]:
        with pytest.raises(ScenarioError):
            blocks.scenario_from_dict(given)
    for given in [None, "x", 5, [1, 2], {"kp": 1}]:
        with pytest.raises(ScenarioError):
            PAPER.with_changes(given)
    for value in [None, "x", 10 ** 400, [math.nan] * 4, deep[:1], {"a": 1}, 0.0, [[1.0] * 4] * 4]:
        with pytest.raises(GainError):
            validated_gain(value, "observer")
    for name, value in [("observer", None), ("observer", 1), ("engine", 5), ("engine", "turbo"), ("progress", 5),
                        ("progress", "x"), ("plant", "x"), ("plant", 5)]:
        with pytest.raises((TypeError, ValueError), match=name):
            blocks.simulate(PAPER, **{name: value})
    for given in [None, 5, {"gains": {"kp": 1}}]:
        with pytest.raises(TypeError):
            blocks.closed_loop(given)


# --------------------------------------------------------------------------------------------
# Tracebacks instead of messages
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", ["kp", "observer"])
def test_gains_too_large_for_a_float_are_not_finite_numbers_in_a_file_and_in_with_changes(tmp_path, key):
    with pytest.raises(ScenarioError, match=rf"'gains\.{key}' must be a finite number, got 1\.000e\+400"):
        PAPER.with_changes({f"gains.{key}": 10 ** 400})
    path = tmp_path / "huge.toml"
    path.write_text(f"[gains]\n{key} = 1{'0' * 400}\n")
    with pytest.raises(ScenarioError, match=rf"'gains\.{key}' must be a finite number, got 1\.000e\+400"):
        blocks.load_scenario(path)
    run = _dobkit("simulate", "--scenario", path, "--out", tmp_path / "out")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.count("\n") == 1 and "must be a finite number, got 1.000e+400" in run.stderr
    assert not (tmp_path / "out").exists()


def test_a_deeply_nested_array_in_a_file_is_a_scenario_error_not_a_recursion_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("[gains]\nkp = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ScenarioError, match="nested too deeply"):
        blocks.load_scenario(path)
    path.write_text("[gains]\nkp = " + "[" * 20 + "1.0" + "]" * 20 + "\n")    # parsed, then refused by shape
    with pytest.raises(ScenarioError, match=r"'gains\.kp' must be a number, 4 numbers or a diagonal 4x4 matrix"):
        blocks.load_scenario(path)


def test_a_nested_mapping_of_variants_asks_for_dotted_keys():
    from blocks.batch import simulate_batch
    with pytest.raises(ScenarioError, match=r"variant column 'gains' must be a list.*write dotted keys, "
                                            r"\{'gains\.kp': \[\.\.\.\]\}"):
        simulate_batch(PAPER, {"gains": {"kp": 100}})
    with pytest.raises(ScenarioError, match=r"variant column 'gains\.kp' must be a list of values, got 100"):
        simulate_batch(PAPER, {"gains.kp": 100})
    with pytest.raises(ScenarioError, match="variants must be a mapping of columns"):
        simulate_batch(PAPER, 5)


def test_a_progress_that_cannot_be_called_is_named():
    with pytest.raises(TypeError, match="progress must be a function \\(or None\\), got int 5"):
        blocks.simulate(PAPER, progress=5)


# --------------------------------------------------------------------------------------------
# Signals and files
# --------------------------------------------------------------------------------------------
# `dobkit simulate ...` (argv[2:]) that holds after drawing its figures into the staging folder, until a signal ends
# it; it says so in the marker file (argv[1]).  Everything else is the real command.
_HELD_AFTER_FIGURES = """
import sys, time
from pathlib import Path
import analysis.simulation.figures as figures
from dobkit.cli import main
marker, draw = Path(sys.argv[1]), figures.paper_figures

def held(*args, **kwargs):
    made = draw(*args, **kwargs)
    marker.write_text("drawn")
    time.sleep(3600)
    return made

figures.paper_figures = held
sys.argv = ["dobkit", *sys.argv[2:]]
sys.exit(main())
"""


def test_sigterm_during_dobkit_simulate_ends_like_ctrl_c_leaving_no_lock_or_partial_folder(tmp_path):
    scenario = tmp_path / "short.toml"
    scenario.write_text(SHORT_SCENARIO_TOML)
    out = tmp_path / "out"
    out.mkdir()                                  # an empty folder given by the user stays, empty
    marker = tmp_path / "figures-drawn"
    proc = subprocess.Popen([sys.executable, "-c", _HELD_AFTER_FIGURES, str(marker), "simulate", "--scenario",
                             str(scenario), "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        # wait until the results are being written (the figures are drawn into the staging folder); the command
        # holds there, so the signal cannot come after the move, however loaded the machine (watching for the
        # staging folder alone left ~0.9 s to send it in)
        deadline = time.monotonic() + 1800              # guards a hung run only
        while not marker.exists():
            assert proc.poll() is None, ("the command ended before it could be signalled", proc.communicate())
            assert time.monotonic() < deadline, "the command drew no figures"
            time.sleep(0.01)
        assert len(list(out.glob(".partial-*"))) == 1 and (out / ".dobkit-writing").exists()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == TERMINATED == 143
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "dobkit simulate: interrupted; nothing partial was written"
    assert list(out.iterdir()) == []


def test_run_with_signals_turns_sigterm_into_the_ctrl_c_path_and_restores_the_handler():
    def command(send: bool) -> int:
        try:
            if send:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)                    # the signal interrupts this
            return 0
        except KeyboardInterrupt:
            return INTERRUPTED

    before = signal.getsignal(signal.SIGTERM)
    assert run_with_signals(command, True) == TERMINATED
    assert run_with_signals(command, False) == 0
    assert signal.getsignal(signal.SIGTERM) is before


def test_devices_and_pipes_are_not_scenario_files(tmp_path):
    with pytest.raises(ScenarioError, match="'/dev/zero' is not a regular file"):
        blocks.load_scenario("/dev/zero")
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    outcome: list = []

    def load():
        try:
            blocks.load_scenario(fifo)
        except ScenarioError as err:
            outcome.append(str(err))
    reader = threading.Thread(target=load, daemon=True)
    reader.start()
    reader.join(60)                              # a FIFO without a writer would block a plain open forever
    assert not reader.is_alive(), "reading the FIFO blocked"
    assert outcome and "is not a regular file" in outcome[0] and str(fifo) in outcome[0]


@pytest.mark.parametrize("code, words", [(errno.EROFS, "the file system is read-only"),
                                         (errno.ENOSPC, "the disk is full"), (errno.EDQUOT, "quota")])
@pytest.mark.parametrize("role", ["output folder", "results file", "cache folder"])
def test_file_errors_name_the_path_and_the_role(code, words, role):
    err = file_error(OSError(code, os.strerror(code)), "/data/run-1", role)
    assert str(err) == f"{role} '/data/run-1' cannot be written: {DISK_WORDS[code]}; choose another --out"
    assert words in str(err) and err.errno == code and "Errno" not in str(err)


DISK_WORDS = {errno.EROFS: "the file system is read-only", errno.ENOSPC: "the disk is full (no space left)",
              errno.EDQUOT: "the disk quota is used up"}


def _can_mount() -> bool:
    if shutil.which("unshare") is None or os.geteuid() != 0:
        return False
    return subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True).returncode == 0


@pytest.mark.skipif(not _can_mount(), reason="needs root and mount namespaces (unshare -m) for a real small tmpfs")
def test_a_read_only_or_full_file_system_is_named_with_the_output_folder(tmp_path):
    mount = tmp_path / "mnt"
    mount.mkdir()
    script = tmp_path / "fill.py"
    script.write_text(
        "import sys\nfrom pathlib import Path\nfrom blocks.outputs import staged_output\n"
        "target = Path(sys.argv[1])\n"
        "try:\n"
        "    with staged_output(target) as stage:\n"
        "        (stage / 'timeseries.csv').write_bytes(b'0' * 200_000)\n"
        "except OSError as err:\n"
        "    print(err)\n"
        "print(sorted(p.name for p in target.parent.rglob('*')))\n")
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    shell = (f"mount -t tmpfs -o size=64k tmpfs {mount} && {sys.executable} {script} {mount}/full; "
             f"mount -o remount,ro {mount} && {sys.executable} -m dobkit simulate --out {mount}/ro")
    run = subprocess.run(["unshare", "-m", "sh", "-c", shell], capture_output=True, text=True, env=env, timeout=600)
    full, left, *_ = run.stdout.splitlines()
    assert full == (f"output folder '{mount}/full' cannot be written: the disk is full (no space left); free space "
                    "or choose another --out; nothing was kept")
    assert left == "[]"                          # no staging folder, lock or folder left on the full disk
    assert run.returncode == 2
    assert run.stderr.strip() == (f"dobkit simulate: error: output folder '{mount}/ro' cannot be written: the file "
                                  "system is read-only; choose another --out")


# --------------------------------------------------------------------------------------------
# Immutability
# --------------------------------------------------------------------------------------------
def test_a_scenarios_arrays_cannot_be_made_writable_again():
    s = blocks.load_scenario("surgical").with_changes({"initial.q": [0.1, 1.0, 0.2, 0.0]})
    arrays = {"kp": s.kp, "kd": s.kd, "observer_gain": s.observer_gain, "initial q": s.initial["q"],
              "noise table": s.noise.table, "a validated gain": validated_gain(180, "kp")}
    for name, arr in arrays.items():
        before = arr.copy()
        for target in (arr, arr.base):
            with pytest.raises(ValueError, match="cannot set WRITEABLE flag"):
                target.setflags(write=True)
        with pytest.raises(ValueError, match="read-only"):
            arr[...] = 0.0
        np.testing.assert_array_equal(arr, before, err_msg=name)
    assert s.kp[0, 0] == 180.0 and s.observer_gain[0, 0] == 40.0


# --------------------------------------------------------------------------------------------
# Wording: numbers in one message agree with each other
# --------------------------------------------------------------------------------------------
NUMBER = r"([0-9.]+(?:e[+-]?\d+)?)"


def test_the_step_refusal_of_kp_1e308_agrees_with_its_own_rate_and_step():
    with pytest.raises(BudgetError) as err:
        blocks.simulate(PAPER.with_changes({"gains.kp": 1e308}))
    text = str(err.value)
    steps, rate, step = (float(re.search(pattern, text).group(1)) for pattern in (
        rf"needs about {NUMBER} integrator steps", rf"fastest rate, about {NUMBER} 1/s",
        rf"step to {NUMBER} s"))
    # kd^2 < 4 kp: the PD poles have modulus sqrt(kp) = 1e154 1/s (perfect model: no mismatch factor)
    assert rate == pytest.approx(1e154, rel=1e-3)
    assert step == pytest.approx(3.0 / 1e154, rel=1e-3)
    assert steps == pytest.approx(10.0 / step, rel=1e-2)
    assert "'gains.kp'" in text


def test_a_value_beyond_its_bound_prints_beyond_it():
    rng = np.random.default_rng(3)
    for bound in list(rng.uniform(1.0, 1e4, 200)) + [100.2, 1000.0, 1e-3]:
        for excess in (1e-15, 1e-12, 1e-9, 3e-5, 1e-3, 0.5):
            value = bound * (1 + excess)
            if value <= bound:
                continue
            bounds = StateBounds(np.array([bound]), ["plant dq[2]"], ["m/s"], ["a reason"])
            text = bounds.describe(np.array([-value]))
            shown, limit = re.fullmatch(r"plant dq\[2\] reached (-?\S+) m/s, beyond its bound (\S+) m/s "
                                        r"\(a reason\)", text).groups()
            assert abs(float(shown)) > float(limit), text
    text = StateBounds(np.array([100.2]), ["plant dq[2]"], ["m/s"], ["r"]).describe(np.array([100.23]))
    assert "reached 100.23 m/s, beyond its bound 100.2 m/s" in text


TUNE_BASE = SHORT_SCENARIO_TOML.replace('name = "short"', 'name = "short-base"')


def _tuning(folder: Path, constraints: str, search: str = "population = 5\nmax_evaluations = 20\n"
            "polish_evaluations = 5\n") -> Path:
    (folder / "base.toml").write_text(TUNE_BASE)
    path = folder / "tune.toml"
    path.write_text('name = "round3"\nscenario = "base.toml"\nobjective = "worst"\n[search]\n"gains.kp" = [20, 2000]\n'
                    f"seed = 3\n{search}[constraints]\n{constraints}\n[monte_carlo]\nruns = 2\nseed = 1\n"
                    '[monte_carlo.distributions]\n"nominal_scale.m1" = {kind = "choice", values = [0.9, 1.1]}\n')
    return path


def test_an_infeasible_tunings_file_stdout_and_result_give_the_same_objective(tmp_path):
    from analysis.tune.results import objective_text
    from analysis.tune.runner import run_tune
    from analysis.tune.spec import load_tuning
    result = run_tune(load_tuning(_tuning(tmp_path, "torque_limit = 1.0")), tmp_path / "out", workers=1,
                      progress=False)
    assert not result.feasible and result.tuned.diverged == 0
    # tune.json keeps the objective; the message (stdout) and the tuned file's description say it alike
    text = objective_text(result.tuned.objective)
    assert text == f"{result.tuned.objective:.4g} mm"
    assert result.tuned.objective == pytest.approx(max(result.tuned.values))
    description = tomllib.loads((tmp_path / "out" / result.scenario_file).read_text())["description"]
    assert description.startswith("INFEASIBLE") and description.endswith(text)
    assert f"is {text} (base gains" in result.message and "not finite" not in description


def test_a_tiny_torque_noise_budget_is_printed_with_significant_digits(tmp_path):
    from analysis.tune.runner import run_tune
    from analysis.tune.spec import TuneError, load_tuning
    with pytest.raises(TuneError) as err:
        run_tune(load_tuning(_tuning(tmp_path, "torque_noise_rms = 1e-9")), tmp_path / "out", workers=1,
                 progress=False)
    text = str(err.value)
    noise = [float(v) for v in re.search(r"torque noise \[([^\]]+)\]", text).group(1).split(", ")]
    budget = re.search(r"against the budget \[([^\]]+)\] N m", text).group(1)
    assert budget == "1e-09, 1e-09, 1e-09, 1e-09"
    joint, factor = re.search(rf"\(joint (\d) {NUMBER} times its budget\)", text).groups()
    # four significant digits each: the printed factor and the printed noise agree to 1e-3
    assert min(noise) > 0 and float(factor) == pytest.approx(noise[int(joint) - 1] / 1e-9, rel=2e-3)
    assert float(factor) == pytest.approx(max(noise) / 1e-9, rel=2e-3)
