"""The mutation probe's list stays applicable: each wrong change names a snippet found exactly once in its file.

Code moves (a function to another module, a line rewritten) would otherwise leave mutants that the probe can no
longer apply, and its table would quietly shrink.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _probe():
    spec = importlib.util.spec_from_file_location("mutation_probe", ROOT / "tests" / "mutation_probe.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("mutation_probe", module)
    spec.loader.exec_module(module)
    return module


def test_every_mutant_names_a_snippet_found_once_and_a_real_change():
    probe = _probe()
    assert len(probe.MUTANTS) >= 198
    ids = [m.id for m in probe.MUTANTS]
    assert len(ids) == len(set(ids)), "mutant ids are unique"
    wrong = {m.id: (ROOT / m.file).read_text().count(m.old) for m in probe.MUTANTS
             if (ROOT / m.file).read_text().count(m.old) != 1}
    assert wrong == {}, "snippets not found exactly once (id: count)"
    assert all(m.old != m.new for m in probe.MUTANTS)
    for m in probe.MUTANTS:
        for test in m.tests:
            path = test.split("::")[0]
            if path.startswith("tests/"):
                assert (ROOT / path).is_file(), f"{m.id}: {path} does not exist"
    # every killer test is where the probe says, and kills mutants of the list
    ids = set(ids)
    for node, killed in probe.KILLED_BY.items():
        path, name = node.split("::")
        assert f"\ndef {name}(" in (ROOT / path).read_text(), f"{node} does not exist"
        assert killed and set(killed) <= ids, f"{node}: {set(killed) - ids} are not mutants"
