"""The README runs as written: every block, shell and Python, in the order written, in one folder.

That is what a new user does after the quick start: types each ```bash block
(with ``bash -e``, the installed ``dobkit`` command) and runs each ```python
block (in one namespace, so names one block makes serve the next) in the same
folder, from the top of the file to the bottom.  A file one block writes is
there for every later block, so two blocks that write the same file fail here
as they would for the user.  A block may be preceded by an HTML comment that
says how to treat it:

* ``<!-- readme-test: needs_cc -->``: needs a C compiler (skipped without one);
* ``<!-- readme-test: skip (why) -->``: not run; the reason is required (for
  example the quick-start commands that make a virtual environment and install);
* ``<!-- readme-test: file NAME -->`` before a ```toml block: the block is
  written to the file NAME in the folder, where the README says to save it;
* ``<!-- readme-test: extra NAME -->`` before the ```bash block that installs
  the optional extra NAME (``pip install ".[NAME]"``): not run (the test
  environment is installed already), but the extra must exist in
  ``pyproject.toml`` and every package it lists must be installed here, so a
  section that needs an extra cannot run here without one.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(?:<!--\s*readme-test:\s*(?P<tag>[\w-]+)(?:\s+(?P<arg>[^\s()]+))?\s*(?:\((?P<why>[^)]*)\))?"
                    r"\s*-->\s*\n)?```(?P<lang>\w*)\n(?P<code>.*?)```", re.DOTALL)
_TAGS = {"needs_cc", "skip", "file", "extra"}
# Longest a shell block may run (s); the whole README takes about three minutes on 2 cores.
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
        if block["tag"] == "extra":
            assert block["lang"] == "bash" and block["arg"], f"README.md:{block['line']}: 'extra' needs a name"
            assert f'.[{block["arg"]}]' in block["code"], f"README.md:{block['line']}: installs another extra"


def test_every_toml_block_is_a_file_that_a_command_runs():
    # a fragment a user cannot run is a fragment nobody checked
    blocks = readme_blocks("bash", "toml")
    for i, block in enumerate(blocks):
        if block["lang"] != "toml":
            continue
        assert block["tag"] == "file", f"README.md:{block['line']}: a toml block must be saved as a file and run"
        later = "".join(b["code"] for b in blocks[i + 1:] if b["lang"] == "bash" and not b["tag"] == "skip")
        assert block["arg"] in later, f"README.md:{block['line']}: no later command uses {block['arg']}"


def _extra_installed(name: str) -> None:
    """Fail unless the optional extra ``name`` exists and every distribution it lists is installed."""
    import tomllib
    from importlib import metadata

    from packaging.requirements import Requirement

    pyproject = tomllib.loads((README.parent / "pyproject.toml").read_text(encoding="utf-8"))
    extras = pyproject["project"]["optional-dependencies"]
    assert name in extras, f"the README installs the extra {name!r}, which pyproject.toml does not define"
    for line in extras[name]:
        requirement = Requirement(line)
        try:
            metadata.version(requirement.name)
        except metadata.PackageNotFoundError:
            pytest.skip(f"the extra {name!r} is not installed here ({requirement.name} is missing)")


def _dobkit_on_path() -> dict:
    """The environment for the shell blocks: this interpreter's scripts folder (with ``dobkit``) first."""
    scripts = Path(sys.executable).parent
    if not (scripts / "dobkit").exists():
        pytest.skip(f"the dobkit command is not installed beside {sys.executable} (pip install the project)")
    env = dict(os.environ)
    env["PATH"] = f"{scripts}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    return env


def _run_shell(block: dict, folder: Path, env: dict) -> None:
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", block["code"]], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=_BLOCK_TIMEOUT, stdin=subprocess.DEVNULL)
    if done.returncode != 0:
        pytest.fail(f"README.md shell block at line {block['line']} failed with status {done.returncode}:\n"
                    f"{block['code']}\n--- stderr (end) ---\n{done.stderr[-3000:]}")


def _run_python(block: dict, namespace: dict) -> None:
    try:
        exec(compile(block["code"], f"README.md:{block['line']}", "exec"), namespace)
    except Exception as err:        # name the block in the failure
        pytest.fail(f"README.md python block at line {block['line']} failed: {type(err).__name__}: {err}")


@pytest.mark.slow
def test_the_readme_runs_top_to_bottom_in_one_folder(tmp_path, monkeypatch):
    env = _dobkit_on_path()
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    ran = {"bash": 0, "python": 0}
    for block in readme_blocks("bash", "toml", "python"):
        if block["tag"] == "file":
            target = tmp_path / block["arg"]
            assert not target.exists(), f"README.md:{block['line']}: {block['arg']} was written by an earlier block"
            target.write_text(block["code"], encoding="utf-8")
        elif block["tag"] == "extra":
            _extra_installed(block["arg"])
        elif _skipped(block):
            continue
        elif block["lang"] == "bash":
            _run_shell(block, tmp_path, env)
            ran["bash"] += 1
        elif block["lang"] == "python":
            _run_python(block, namespace)
            ran["python"] += 1
    assert ran["bash"] >= 3 and ran["python"] >= 2
    # what the commands promise is there: the report, the quick preview (and that it says so), the sweep summary
    assert (tmp_path / "report-run" / "report.html").is_file()
    assert "quick preview" in (tmp_path / "preview" / "report.html").read_text(encoding="utf-8")
    assert (tmp_path / "mc-summary" / "summary.json").is_file()


def test_readme_joint1_offset_is_the_rest_pose_the_report_computes():
    """Without the observer, at rest ``Kp e = M(q)^-1 d`` (perfect model, computed torque): the rest pose is
    the fixed point ``q = q0 + M(q)^-1 d / Kp``, solved here by iteration with the arm's inertia alone."""
    from analysis.linear.loop import operating_point_analysis
    from blocks import inertia
    from blocks.scenarios.scenario import load_scenario

    scenario = load_scenario("paper")
    q0 = np.asarray(scenario.trajectory.evaluate(0.0)[0], dtype=float)
    point = operating_point_analysis(scenario, q0)
    d = np.asarray(point.disturbance_at_rest)
    kp = np.diag(scenario.kp)
    q = q0.copy()
    for _ in range(50):
        q = q0 + np.linalg.solve(inertia(q, scenario.robot), d) / kp
    offset = q[0] - q0[0]
    # at the path's start (M(q0)) it would be 1.84e-5: the README's old 1.8e-5 was that other number
    assert abs(np.linalg.solve(inertia(q0, scenario.robot), d)[0] / kp[0] - 1.84e-5) < 0.01e-5
    assert point.q_equilibrium_without_dob[0] - q0[0] == pytest.approx(offset, rel=1e-6)
    readme = re.sub(r"\s+", " ", (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8"))
    stated = re.search(r"rests with joint 1 only ([0-9.e-]+) rad off", readme)
    assert stated is not None
    assert float(stated.group(1)) == pytest.approx(offset, rel=5e-3)
    assert f"{offset:.3g}".replace("e-05", "e-5") == stated.group(1)


def test_every_time_the_readme_states_names_the_load_it_was_measured_at():
    # a time read on a quiet machine is not what a user on a loaded one sees: a stated time comes with its load
    # (the benchmark that printed it, benchmarks/bench_readme_times.py for the commands, prints it)
    text = re.sub(r"```.*?```", "", README.read_text(encoding="utf-8"), flags=re.DOTALL)
    claim = re.compile(r"\b(took|takes|take|runs in|run in|compiles in|in about)\b[^.]{0,60}?\b\d[\d.,]*\s?(s|ms|min)\b")
    unloaded = []
    for paragraph in re.split(r"\n\s*\n", text):
        said = re.sub(r'"[^"]*"', '""', paragraph)          # quoted output ("done, took 3.2 s") is an example
        if claim.search(said) and "load" not in said:
            unloaded.append(" ".join(paragraph.split())[:160])
    assert not unloaded, "times without the load they were measured at:\n" + "\n".join(unloaded)
