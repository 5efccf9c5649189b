"""The README's examples run exactly as written, in the order written.

Every ```python block of README.md is run, in order, in one namespace, in a
fresh temporary folder (so files one block writes are there for the next).
Every ```bash block is run, in order, with ``bash -e`` in another fresh
temporary folder, with the installed ``dobkit`` command: what a new user
following only the README types.  A block may be preceded by an HTML comment
that says how to treat it:

* ``<!-- readme-test: needs_cc -->``: needs a C compiler (skipped without one);
* ``<!-- readme-test: skip (why) -->``: not run; the reason is required (for
  example the quick-start commands that make a virtual environment and install);
* ``<!-- readme-test: file NAME -->`` before a ```toml block: the block is
  written to the file NAME in the shell examples' folder, where the README says
  to save it, before the shell block that follows it runs.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(?:<!--\s*readme-test:\s*(?P<tag>[\w-]+)(?:\s+(?P<arg>[^\s()]+))?\s*(?:\((?P<why>[^)]*)\))?"
                    r"\s*-->\s*\n)?```(?P<lang>\w*)\n(?P<code>.*?)```", re.DOTALL)
_TAGS = {"needs_cc", "skip", "file"}
# Longest a shell block may run (s); the whole set of them takes about two minutes on 2 cores.
_BLOCK_TIMEOUT = 900


def readme_blocks(*languages: str) -> list[dict]:
    """The fenced blocks in the given languages, in order: ``line``, ``lang``, ``tag``, ``arg``, ``why``, ``code``."""
    text = README.read_text(encoding="utf-8")
    out = []
    for match in _BLOCK.finditer(text):
        if match.group("lang") in languages:
            out.append({"line": text.count("\n", 0, match.start("code")), "lang": match.group("lang"),
                        "tag": match.group("tag"), "arg": match.group("arg"), "why": match.group("why"),
                        "code": match.group("code")})
    return out


def _has_compiler() -> bool:
    return any(shutil.which(c) for c in filter(None, (os.environ.get("CC"), "cc", "gcc", "clang")))


def _skipped(block: dict) -> bool:
    return block["tag"] == "skip" or (block["tag"] == "needs_cc" and not _has_compiler())


def test_the_readme_has_python_and_shell_examples():
    assert len(readme_blocks("python")) >= 2
    assert len([b for b in readme_blocks("bash") if b["tag"] != "skip"]) >= 3


def test_every_readme_test_tag_is_known_and_a_skip_says_why():
    text = README.read_text(encoding="utf-8")
    tags = re.findall(r"<!--\s*readme-test:\s*([\w-]+)", text)
    assert tags and set(tags) <= _TAGS
    blocks = readme_blocks("python", "bash", "toml")
    assert sum(1 for b in blocks if b["tag"]) == len(tags)          # every tag sits right before a fence
    for block in blocks:
        if block["tag"] == "skip":
            assert block["why"] and block["why"].strip(), f"README.md:{block['line']}: a skip needs a reason"
        if block["tag"] == "file":
            assert block["lang"] == "toml" and block["arg"], f"README.md:{block['line']}: 'file' needs a name"


def test_python_examples_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    ran = 0
    for block in readme_blocks("python"):
        if _skipped(block):
            continue
        try:
            exec(compile(block["code"], f"README.md:{block['line']}", "exec"), namespace)
        except Exception as err:        # name the block in the failure
            pytest.fail(f"README.md python block at line {block['line']} failed: {type(err).__name__}: {err}")
        ran += 1
    assert ran >= 1


def _dobkit_on_path() -> dict:
    """The environment for the shell examples: this interpreter's scripts folder (with ``dobkit``) first."""
    scripts = Path(sys.executable).parent
    if not (scripts / "dobkit").exists():
        pytest.skip(f"the dobkit command is not installed beside {sys.executable} (pip install the project)")
    env = dict(os.environ)
    env["PATH"] = f"{scripts}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    return env


@pytest.mark.slow
def test_shell_examples_run_as_written_in_order(tmp_path):
    env = _dobkit_on_path()
    ran = 0
    for block in readme_blocks("bash", "toml"):
        if block["tag"] == "file":
            (tmp_path / block["arg"]).write_text(block["code"], encoding="utf-8")
            continue
        if block["lang"] != "bash" or _skipped(block):
            continue
        done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", block["code"]], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=_BLOCK_TIMEOUT, stdin=subprocess.DEVNULL)
        if done.returncode != 0:
            pytest.fail(f"README.md shell block at line {block['line']} failed with status {done.returncode}:\n"
                        f"{block['code']}\n--- stderr (end) ---\n{done.stderr[-3000:]}")
        ran += 1
    assert ran >= 3
    # what the commands promise is there: the report, the quick preview (and that it says so), the sweep summary
    assert (tmp_path / "report-run" / "report.html").is_file()
    assert "quick preview" in (tmp_path / "preview" / "report.html").read_text(encoding="utf-8")
    assert (tmp_path / "mc-summary" / "summary.json").is_file()
