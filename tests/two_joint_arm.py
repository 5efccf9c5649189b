"""The two-joint test arm (tests/small_arms/two_joints.urdf) as text, to write it with one thing changed.

Tests that feed dobkit a URDF file which is the test arm with one element altered (a number that is not a number,
an inverted range, a loop) start from ``TWO``; ``changed`` insists that what it replaces occurs exactly once.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

TWO = (Path(__file__).parent / "small_arms" / "two_joints.urdf").read_text(encoding="utf-8")
ARM_LINK = '<mass value="1.2"/>'

# URDF arms need pinocchio (the "urdf" extra): tests that read a URDF file are skipped without it
needs_pinocchio = pytest.mark.skipif(importlib.util.find_spec("pinocchio") is None,
                                     reason="needs pinocchio: pip install 'dobkit[urdf]'")


def write_urdf(folder: Path, text: str, name: str = "arm.urdf") -> Path:
    """Write ``text`` as ``folder/name`` and return its path."""
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def changed(old: str, new: str) -> str:
    """The test arm with ``old`` (found exactly once) replaced by ``new``."""
    assert TWO.count(old) == 1, old
    return TWO.replace(old, new)
