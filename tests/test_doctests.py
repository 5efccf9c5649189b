"""The examples in the packages' docstrings run and print what they show.

Every module of ``blocks``, ``analysis``, ``fmu`` and ``dobkit`` is searched
for doctest examples; each module with examples is one test, run in a fresh
working folder (examples may write files such as ``plant.fmu``).  Examples
that export an FMU need a C compiler and are marked ``needs_cc``.
"""
from __future__ import annotations

import doctest
import importlib
import io
import pkgutil

import pytest

PACKAGES = ("blocks", "analysis", "fmu", "dobkit")
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _module_names() -> list[str]:
    names = []
    for package in PACKAGES:
        module = importlib.import_module(package)
        names.append(package)
        names += [info.name for info in pkgutil.walk_packages(module.__path__, prefix=f"{package}.")
                  if not info.name.endswith("__main__")]            # running __main__ would start the CLI
    return names


def _examples(name: str) -> list[doctest.DocTest]:
    module = importlib.import_module(name)
    return [t for t in doctest.DocTestFinder(exclude_empty=True).find(module, name) if t.examples]


def _cases() -> list:
    cases = []
    for name in _module_names():
        tests = _examples(name)
        if not tests:
            continue
        builds = any(word in ex.source for t in tests for ex in t.examples
                     for word in ("export_plant", "export_controller"))
        cases.append(pytest.param(name, id=name, marks=[pytest.mark.needs_cc] if builds else []))
    return cases


CASES = _cases()


def test_modules_with_examples_are_found():
    found = {case.values[0] for case in CASES}
    assert {"blocks.model.rrpr.parameters", "fmu.export", "fmu.block", "fmu.variables"} <= found, sorted(found)


@pytest.mark.parametrize("name", CASES)
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    report = io.StringIO()
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in _examples(name):
        runner.run(test, out=report.write)
    result = runner.summarize(verbose=False)
    assert result.attempted > 0
    assert result.failed == 0, report.getvalue()
