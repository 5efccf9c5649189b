"""Ctrl-C and SIGTERM to ``dobkit`` commands: one line, exit 130 or 143, no traceback, nothing partial left.

SIGTERM is handled by dobkit/signals.py, hooked where the commands start (``dobkit.cli.main``);
tests/test_output_interrupts.py hits each moment of writing an output folder on purpose.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import SHORT_SCENARIO_TOML
from two_joint_arm import needs_pinocchio

from dobkit.signals import INTERRUPTED, TERMINATED, run_with_signals

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


def _processes_mentioning(text: str) -> list[str]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                line = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
            except OSError:
                continue
            if text in line:
                found.append(line[:120])
    return found


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="needs /proc to see the compiler's processes")
@needs_pinocchio
def test_sigterm_while_the_fmu_is_compiled_leaves_no_compiler_process_or_temporary_file(tmp_path):
    # the compiler's driver was killed, its cc1 ran on and left /tmp/cc*.s and cc*.o behind after "interrupted;
    # nothing partial was written"
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = dict(os.environ, TMPDIR=str(temp))
    proc = subprocess.Popen([sys.executable, "-m", "dobkit", "fmu", "export", "--arm", "scope4", "--out", "x.fmu"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not any("cc1" in p for p in _processes_mentioning(str(temp))):
        assert proc.poll() is None and time.monotonic() < deadline, "the compiler never ran"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "dobkit fmu: interrupted; nothing partial was written"
    time.sleep(1.0)                                    # what outlived the command has had time to write
    assert _processes_mentioning(str(temp)) == []
    assert sorted(p.name for p in temp.iterdir()) == []
    assert not (tmp_path / "x.fmu").exists()


def test_an_interrupt_while_a_module_makes_its_classes_is_not_reported_as_an_error(monkeypatch, capsys):
    # SIGTERM during `import scipy...` ended `dobkit fmu export` with "error: Error calling __set_name__ on
    # 'cached_property' instance 'nodes_and_weights' in 'GaussLegendreQuadrature'" and exit 2 (Python 3.11 wraps
    # an exception of __set_name__ in RuntimeError)
    import dobkit.cli

    class Descriptor:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt("received signal SIGTERM")

    def command(args):
        type("Quadrature", (), {"nodes_and_weights": Descriptor()})     # what an import does when it makes a class
        return 0
    monkeypatch.setattr(dobkit.cli, "_cmd_simulate", command)
    assert dobkit.cli.main(["simulate"]) == 130
    assert capsys.readouterr().err.strip() == "dobkit simulate: interrupted; nothing partial was written"


def test_an_interrupted_job_says_nothing_was_written_when_its_log_was_not_made(tmp_path, capsys):
    # "every finished run is kept in s-results.jsonl, and the same command resumes" with no such file
    import argparse

    from dobkit.job_commands import run_job
    args = argparse.Namespace(max_memory=None, max_steps=None, max_seconds=None)
    results = tmp_path / "s-results.jsonl"

    def body(args, budget, state):
        state["results"] = results
        raise KeyboardInterrupt
    assert run_job("sweep", args, body, (), "run", "results") == 130
    assert capsys.readouterr().err.strip() == "dobkit sweep: interrupted before any run finished; nothing was written"
    results.write_text("{}\n")
    assert run_job("sweep", args, body, (), "run", "results") == 130
    assert f"every finished run is kept in {results}" in capsys.readouterr().err
