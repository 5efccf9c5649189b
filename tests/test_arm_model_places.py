"""Each arm model in its own place: nothing outside the RRPR's package names the RRPR (issue 30, item 2).

The paper's RRPR in closed form lives in :mod:`blocks.model.rrpr`; every other layer asks the arm model
(:class:`blocks.model.arm.ArmModel`) what it needs.  The places allowed to name it are the package itself, the
top-level API's re-exports (``blocks.RobotParameters``, ...) and the scenario defaults (the paper scenario is
the default scenario).  The check walks the syntax tree of every module of ``blocks``, ``analysis``, ``fmu`` and
``dobkit``: names, attributes, arguments, definitions and imports (not comments or strings, where prose may speak
of the paper's arm).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("blocks", "analysis", "fmu", "dobkit")

#: The RRPR's own symbols: its parameters and constants, joints, closed-form kernels' inputs and path.
RRPR_SYMBOLS = frozenset({
    "RobotParameters", "PAPER_PARAMETERS", "InertiaConstants", "RRPR_JOINTS", "D3_STROKE", "arm_constants",
    "kinematic_lengths", "LacerationPath", "inertia_derivative_theta2", "is_rrpr", "is_rrpr_kernels",
})

#: Where the RRPR may be named: its package, the top-level API and the scenario defaults (the default arm).
ALLOWED = ("blocks/model/rrpr/", "blocks/__init__.py", "blocks/model/default.py", "blocks/scenarios/scenario.py",
           "blocks/scenarios/scenario_arm.py")

#: Modules allowed to name the RRPR for a while (none now); an entry is a debt: the test fails on one no longer needed.
PENDING: frozenset = frozenset()


def rrpr_mentions(source: str) -> list[tuple[int, str]]:
    """(line, symbol) of every RRPR symbol a module's code names: an RRPR name, an identifier with ``rrpr`` in
    it, or an import from :mod:`blocks.model.rrpr`."""
    found = []

    def named(node, text: str | None) -> None:
        if text and (text in RRPR_SYMBOLS or "rrpr" in text.lower()):
            found.append((node.lineno, text))

    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Name):
            named(node, node.id)
        elif isinstance(node, ast.Attribute):
            named(node, node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            named(node, node.name)
        elif isinstance(node, ast.arg):
            named(node, node.arg)
        elif isinstance(node, ast.keyword) and node.arg is not None:
            named(node.value, node.arg)
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if module.startswith(("blocks.model.rrpr", "model.rrpr")) or (node.level and module.startswith("rrpr")) \
                    or (module in ("blocks.model", "model") and any(a.name == "rrpr" for a in node.names)):
                found.append((node.lineno, f"from {'.' * node.level}{module} import ..."))
            for alias in node.names:
                named(node, alias.name)
                named(node, alias.asname)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if "rrpr" in alias.name.lower():
                    found.append((node.lineno, f"import {alias.name}"))
    return sorted(set(found))


def _offenders() -> dict[str, list[tuple[int, str]]]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith(ALLOWED) or rel in ALLOWED:
                continue
            mentions = rrpr_mentions(path.read_text(encoding="utf-8"))
            if mentions:
                out[rel] = mentions
    return out


def test_the_walk_finds_each_kind_of_mention():
    """The check itself, on code that names the RRPR each way it can, and on code that does not."""
    source = ("from blocks.model.rrpr.parameters import RobotParameters\n"
              "from .model.rrpr import tool_kernels as _rrpr_tool\n"
              "import blocks.model.rrpr\n"
              "def f(joints=RRPR_JOINTS, rrpr=True):\n"
              "    return blocks.PAPER_PARAMETERS, isinstance(joints, InertiaConstants), g(is_rrpr=1)\n")
    symbols = {text for _, text in rrpr_mentions(source)}
    assert {"RobotParameters", "_rrpr_tool", "RRPR_JOINTS", "rrpr", "PAPER_PARAMETERS", "InertiaConstants",
            "is_rrpr", "import blocks.model.rrpr", "from blocks.model.rrpr.parameters import ..."} <= symbols
    clean = ('"""The paper\'s RRPR is the default scenario\'s arm."""\n'
             "# RobotParameters lives in blocks.model.rrpr\n"
             "def f(arm):\n    return arm.paper is not None, arm.joints\n")
    assert rrpr_mentions(clean) == []


def test_nothing_outside_the_rrpr_package_names_the_rrpr():
    offenders = _offenders()
    unexpected = {path: mentions for path, mentions in offenders.items() if path not in PENDING}
    listing = "\n".join(f"  {path}: " + ", ".join(f"line {line} {text}" for line, text in mentions[:6])
                        + (f" (+{len(mentions) - 6} more)" if len(mentions) > 6 else "")
                        for path, mentions in sorted(unexpected.items()))
    assert not unexpected, ("these modules name the RRPR outside blocks/model/rrpr/ (ask the arm model instead, "
                            f"blocks.model.arm.ArmModel):\n{listing}")


def test_every_pending_module_still_needs_its_entry():
    stale = sorted(PENDING - set(_offenders()))
    assert not stale, f"no longer naming the RRPR, remove from PENDING: {stale}"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_signature_defaults_to_the_rrpr(package):
    """No function of any module (the RRPR's package and the pending ones aside) has an RRPR default."""
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("blocks/model/rrpr/") or rel in PENDING:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                for default in node.args.defaults + [d for d in node.args.kw_defaults if d is not None]:
                    if rrpr_mentions(ast.unparse(default)):
                        bad.append(f"{rel}:{default.lineno} {ast.unparse(default)}")
    assert not bad, f"signatures defaulting to the RRPR: {bad}"
