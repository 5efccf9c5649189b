"""The system's C compiler, run in a process group of its own so that a time-out or an interrupt ends all of it.

The plant and controller FMUs (:mod:`fmu.build`) and the fast engine's C loop
(:mod:`blocks.engines.compiled.c_loop`) compile with it.  The compiler driver starts
``cc1``, ``as`` and ``ld``; killing the driver alone would leave them writing, so
the whole group is killed and waited for.
"""
from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import time

__all__ = ["CANDIDATES", "CompilerTimeout", "compiler_command", "run_compiler", "end_process_group"]

#: The compilers looked for on PATH, in order, when none is named.
CANDIDATES = ("cc", "gcc", "clang")


def compiler_command(spec: str | None) -> list[str] | None:
    """The compiler's command as an argument list: ``spec`` (a command line, as ``$CC`` holds one) when its program
    is on PATH, else -- with no ``spec`` -- the first of :data:`CANDIDATES` found; None when there is none."""
    if spec:
        argv = shlex.split(spec)
        return argv if argv and shutil.which(argv[0]) is not None else None
    for name in CANDIDATES:
        if shutil.which(name):
            return [name]
    return None


class CompilerTimeout(RuntimeError):
    """The compiler did not finish within its time-out (s); it was stopped with everything it started."""


def end_process_group(proc: subprocess.Popen, wait: float = 5.0) -> None:
    """Kill ``proc``'s process group and wait (at most ``wait`` s) until none of it is left."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError, AttributeError):     # gone, or no process groups (Windows)
        proc.kill()
    proc.wait()
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except (ProcessLookupError, PermissionError, AttributeError):
            return
        time.sleep(0.01)


def run_compiler(cmd: list[str], timeout: float, tmpdir: str) -> tuple[int, str]:
    """Run a compiler command; ``(exit code, what it wrote to stderr)``.

    Parameters
    ----------
    cmd : list of str
    timeout : float
        Seconds before the compiler is stopped.
    tmpdir : str
        Its ``TMPDIR`` (where ``cc*.s``, ``cc*.o`` go: a folder removed with them).

    Raises
    ------
    OSError
        The compiler could not be started.
    CompilerTimeout
        It ran past ``timeout``.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, TMPDIR=tmpdir), start_new_session=True)
    try:
        _, said = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        end_process_group(proc)
        raise CompilerTimeout(f"the C compiler did not finish within {timeout:g} s") from None
    except BaseException:               # Ctrl-C or SIGTERM: no compiler process outlives the caller
        end_process_group(proc)
        raise
    return proc.returncode, said
