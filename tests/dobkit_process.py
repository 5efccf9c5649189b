"""``dobkit`` as a user runs it: the command line in a fresh Python process, its output captured."""
from __future__ import annotations

import subprocess
import sys


def run_dobkit(*args, cwd=None, env=None, timeout=600) -> subprocess.CompletedProcess:
    """Run ``python -m dobkit ARGS`` (each argument through ``str``) and return the finished process."""
    return subprocess.run([sys.executable, "-m", "dobkit", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=timeout)
