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

from conftest import SHORT_SCENARIO_TOML

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
