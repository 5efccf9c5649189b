"""The README's examples run exactly as written.

Every ```python block of README.md is run, in order, in one namespace, in a
fresh temporary folder (so files one block writes are there for the next).
A block may be preceded by an HTML comment that says how to treat it:

* ``<!-- readme-test: needs_cc -->``: needs a C compiler (skipped without one);
* ``<!-- readme-test: skip -->``: not run (say why in the README beside it).
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(?:<!--\s*readme-test:\s*(?P<tag>[\w-]+)\s*-->\s*\n)?```(?P<lang>\w*)\n(?P<code>.*?)```",
                    re.DOTALL)


def readme_blocks(language: str) -> list[tuple[int, str | None, str]]:
    """``(line number, tag, code)`` of each fenced block in the given language, in order."""
    text = README.read_text(encoding="utf-8")
    out = []
    for match in _BLOCK.finditer(text):
        if match.group("lang") == language:
            line = text.count("\n", 0, match.start("code"))
            out.append((line, match.group("tag"), match.group("code")))
    return out


def _has_compiler() -> bool:
    import os
    return any(shutil.which(c) for c in filter(None, (os.environ.get("CC"), "cc", "gcc", "clang")))


def test_the_readme_has_python_examples():
    assert len(readme_blocks("python")) >= 2


def test_python_examples_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    ran = 0
    for line, tag, code in readme_blocks("python"):
        if tag == "skip" or (tag == "needs_cc" and not _has_compiler()):
            continue
        try:
            exec(compile(code, f"README.md:{line}", "exec"), namespace)
        except Exception as err:        # name the block in the failure
            pytest.fail(f"README.md python block at line {line} failed: {type(err).__name__}: {err}")
        ran += 1
    assert ran >= 1
