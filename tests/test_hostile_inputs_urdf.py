"""Hostile URDF files: numbers read as urdfdom reads them, ``<limit>`` attributes not given read as URDF says,
and the file's size, link count and depth bounded before pinocchio reads it.

docs/hostile-inputs.md, "Round 8", lists each case with its test.  The files are the two-joint test arm
(tests/small_arms/two_joints.urdf) with one thing changed, or chains made here; pinocchio (urdfdom) is the
reference for what a file means.
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from blocks.model.urdf import urdf as urdf_module  # noqa: E402
from blocks.model.urdf.urdf import MAX_URDF_BYTES, MAX_URDF_DEPTH, MAX_URDF_LINKS, UrdfFileError, UrdfParseError, load_urdf_arm  # noqa: E402

TWO = (Path(__file__).parent / "small_arms" / "two_joints.urdf").read_text(encoding="utf-8")
ARM_MASS = '<mass value="1.2"/>'


def _urdf(folder: Path, text: str, name: str = "arm.urdf") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def _changed(old: str, new: str, text: str = TWO) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def _pinocchio_mass(path: Path) -> float:
    with urdf_module._stderr_kept():            # urdfdom's complaint is the point, not noise for the test log
        return float(pin.buildModelFromUrdf(str(path)).inertias[1].mass)


# ---------------------------------------------------------------------------------------------------------------
# numbers: what Python's float() reads and urdfdom does not (it drops the whole <inertial>, saying so on stderr)
# ---------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [" 0.35 ", "0.35 ", "0_35", "\u0661.\u0662", "0x1p0", "1.2\u00a0"])
def test_a_mass_python_reads_and_urdfdom_drops_is_refused_naming_the_link(tmp_path, value):
    # before: dobkit's check passed (float() reads these), urdfdom dropped the <inertial>: a massless link, "written"
    path = _urdf(tmp_path, _changed(ARM_MASS, f'<mass value="{value}"/>'))
    assert _pinocchio_mass(path) == 0.0                   # what pinocchio makes of it: the 1.2 kg are gone
    with pytest.raises(UrdfParseError, match=r"link 'arm' <inertial> <mass> value=.*; it must be 1 finite number "
                                             r".*ASCII digits"):
        load_urdf_arm(path, "rod")


def test_a_mass_given_by_an_xml_entity_is_refused_with_urdfdoms_own_reason(tmp_path):
    # Python's XML parser expands the internal entity to "1.2"; urdfdom's does not and drops the <inertial>
    text = _changed('<?xml version="1.0"?>', '<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY m "1.2">]>')
    path = _urdf(tmp_path, _changed(ARM_MASS, '<mass value="&m;"/>', text))
    assert _pinocchio_mass(path) == 0.0
    with pytest.raises(UrdfParseError, match=r"urdfdom \(pinocchio's URDF reader\) could not read all of it .*"
                                             r"mass \[&m;\] is not a float.*Link \[arm\]"):
        load_urdf_arm(path, "rod")


def test_an_inertial_origin_separated_by_tabs_is_refused_not_dropped(tmp_path):
    # the XML parser turns the tabs into spaces; urdfdom splits on spaces only and drops the <inertial>
    path = _urdf(tmp_path, _changed('<origin xyz="0.1 0 0.02"/>', '<origin xyz="0.1\t0\t0.02"/>'))
    assert _pinocchio_mass(path) == 0.0
    with pytest.raises(UrdfParseError, match=r"could not read all of it .*Unable to parse component"):
        load_urdf_arm(path, "rod")


@pytest.mark.parametrize("value, mass", [(" 1.2", 1.2), ("+1.2", 1.2), (".5", 0.5), ("5.", 5.0), ("1E0", 1.0),
                                         ("12e-1", 1.2)])
def test_every_mass_urdfdom_reads_loads_with_the_mass_it_reads(tmp_path, value, mass):
    path = _urdf(tmp_path, _changed(ARM_MASS, f'<mass value="{value}"/>'))
    assert _pinocchio_mass(path) == pytest.approx(mass, rel=1e-15)
    arm = load_urdf_arm(path, "rod")
    assert arm.chain.masses[0] == pytest.approx(mass, rel=1e-15)


# ---------------------------------------------------------------------------------------------------------------
# <limit> without lower or upper: 0, as URDF, urdfdom and pinocchio read it
# ---------------------------------------------------------------------------------------------------------------
def _pinocchio_range(path: Path, joint: int) -> tuple[float, float]:
    model = pin.buildModelFromUrdf(str(path))
    return float(model.lowerPositionLimit[joint]), float(model.upperPositionLimit[joint])


@pytest.mark.parametrize("old, new, joint, expected", [
    ('lower="-2" upper="2"', 'upper="2"', 0, (0.0, 2.0)),
    ('lower="-0.1" upper="0.2"', 'lower="-0.1"', 1, (-0.1, 0.0)),
])
def test_a_limit_without_lower_or_upper_reads_it_as_zero_as_pinocchio_does(tmp_path, old, new, joint, expected):
    # before: a missing bound was no bound (the range, the start checks and the FMU's end stops differed)
    path = _urdf(tmp_path, _changed(old, new))
    assert _pinocchio_range(path, joint) == expected
    arm = load_urdf_arm(path, "rod")
    assert arm.joints.limits[joint] == expected


def test_a_limit_whose_missing_lower_is_above_its_upper_is_refused_saying_it_reads_as_zero(tmp_path):
    path = _urdf(tmp_path, _changed('lower="-2" upper="2"', 'upper="-1"'))
    with pytest.raises(UrdfParseError, match=r"joint 'pitch' <limit> lower=0 is above upper=-1 \(lower is not given, "
                                             r"which URDF reads as 0\); give lower <= upper"):
        load_urdf_arm(path, "rod")


# ---------------------------------------------------------------------------------------------------------------
# size, link count, depth: bounded before pinocchio reads the file
# ---------------------------------------------------------------------------------------------------------------
def _chain(links: int, fan: bool = False, bare: bool = False) -> str:
    """A URDF of ``links`` links: one revolute joint at the base, the rest fixed (one after another, or each on
    the first moving link when ``fan``; without inertials when ``bare``)."""
    inertial = ('<inertial><mass value="0.1"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" '
                'izz="0.001"/></inertial>')
    parts = ['<robot name="deep"><link name="l0"/>',
             '<joint name="j1" type="revolute"><parent link="l0"/><child link="l1"/><axis xyz="0 1 0"/>'
             '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>', f'<link name="l1">{inertial}</link>']
    for i in range(2, links):
        parent = 1 if fan else i - 1
        parts.append(f'<joint name="j{i}" type="fixed"><parent link="l{parent}"/><child link="l{i}"/>'
                     f'<origin xyz="0 0 0.01"/></joint><link name="l{i}">{"" if bare else inertial}</link>')
    parts.append("</robot>")
    return "\n".join(parts)


def test_the_depth_bound_at_both_sides(tmp_path):
    arm = load_urdf_arm(_urdf(tmp_path, _chain(MAX_URDF_DEPTH)), f"l{MAX_URDF_DEPTH - 1}")
    # every fixed link merged into the one moving body: (depth - 1) links of 0.1 kg
    assert arm.n == 1 and arm.chain.masses[0] == pytest.approx(0.1 * (MAX_URDF_DEPTH - 1), rel=1e-12)
    with pytest.raises(UrdfParseError, match=rf"link 'l{MAX_URDF_DEPTH}' is {MAX_URDF_DEPTH + 1} links deep .* at "
                                             rf"most {MAX_URDF_DEPTH} deep"):
        load_urdf_arm(_urdf(tmp_path, _chain(MAX_URDF_DEPTH + 1), "deeper.urdf"), "l1")


def test_a_urdf_5000_links_deep_is_refused_not_a_segmentation_fault(tmp_path):
    # before: pinocchio's recursive walk ran out of C stack: exit 139, no message (in a child process: a crash
    # fails the test instead of ending pytest)
    path = _urdf(tmp_path, _chain(5000))
    script = textwrap.dedent("""
        import sys
        from blocks.model.urdf.urdf import UrdfParseError, load_urdf_arm
        try:
            load_urdf_arm(sys.argv[1], "l1")
        except UrdfParseError as err:
            print("refused:", err)
    """)
    done = subprocess.run([sys.executable, "-c", script, str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    assert "refused:" in done.stdout and "has 5000 links; dobkit reads at most" in done.stdout


def test_the_link_count_bound_at_both_sides_and_a_large_file_is_checked_in_linear_time(tmp_path):
    arm = load_urdf_arm(_urdf(tmp_path, _chain(MAX_URDF_LINKS, fan=True)), "l1")
    assert arm.chain.masses[0] == pytest.approx(0.1 * (MAX_URDF_LINKS - 1), rel=1e-12)
    with pytest.raises(UrdfParseError, match=rf"has {MAX_URDF_LINKS + 1} links; dobkit reads at most "
                                             rf"{MAX_URDF_LINKS}"):
        load_urdf_arm(_urdf(tmp_path, _chain(MAX_URDF_LINKS + 1, fan=True), "more.urdf"), "l1")
    # 20,000 links (before: a minute counting names one by one; now refused by the count)
    with pytest.raises(UrdfParseError, match=r"has 20000 links"):
        load_urdf_arm(_urdf(tmp_path, _chain(20_000, fan=True, bare=True), "many.urdf"), "l1")
    # the name checks themselves are linear: 1,999 links named twice over are listed, not counted pairwise
    twice = _chain(MAX_URDF_LINKS // 2, fan=True).replace('name="l', 'name="m').replace('link="l', 'link="m')
    both = _chain(MAX_URDF_LINKS // 2, fan=True).replace("</robot>", twice.split(">", 1)[1])
    with pytest.raises(UrdfParseError, match=r"joint name\(s\) \['j1', 'j10', "):
        load_urdf_arm(_urdf(tmp_path, both, "twice.urdf"), "l1")


def test_the_file_size_bound_at_both_sides(tmp_path):
    head, tail = TWO.rsplit("</robot>", 1)
    pad = MAX_URDF_BYTES - len((head + "</robot>" + tail).encode())
    exact = _urdf(tmp_path, head + " " * pad + "</robot>" + tail)
    assert exact.stat().st_size == MAX_URDF_BYTES
    assert load_urdf_arm(exact, "rod").n == 2
    over = _urdf(tmp_path, head + " " * (pad + 1) + "</robot>" + tail, "over.urdf")
    with pytest.raises(UrdfParseError, match=rf"has more than {MAX_URDF_BYTES:,} bytes; dobkit reads URDF files of at "
                                             rf"most {MAX_URDF_BYTES:,}"):
        load_urdf_arm(over, "rod")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_or_a_device_as_urdf_is_refused_without_waiting(tmp_path):
    fifo = tmp_path / "arm.urdf"
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        with pytest.raises(UrdfFileError, match=r"is not a regular file"):
            load_urdf_arm(path, "rod")


def test_good_files_load_as_before(tmp_path):
    arm = load_urdf_arm(_urdf(tmp_path, TWO), "rod")
    model = pin.buildModelFromUrdf(str(tmp_path / "arm.urdf"))
    assert arm.joints.limits == ((-2.0, 2.0), (-0.1, 0.2))
    q = np.array([0.3, 0.1])
    M = pin.crba(model, model.createData(), q)
    assert np.allclose(arm.inertia(q), np.triu(M) + np.triu(M, 1).T, atol=1e-12, rtol=0)


@pytest.mark.parametrize("axis", ["0 1e-200 0", "0 1e200 1e200"])
def test_an_axis_too_short_or_too_long_to_normalise_is_refused_naming_its_joint(tmp_path, axis):
    # before: 0 1e-200 0 on the pitch joint was refused as "joint 'pitch'"'s neighbour: "joint 'yaw' ... moves no
    # mass or inertia" (pinocchio's normalisation divided by a length whose square is 0)
    path = _urdf(tmp_path, _changed('<axis xyz="0 1 0"/>', f'<axis xyz="{axis}"/>'))
    with pytest.raises(UrdfParseError, match=rf"joint 'pitch' <axis> xyz='{axis}' cannot be normalised in double "
                                             r"precision"):
        load_urdf_arm(path, "rod")
    for short in ("0 1e-150 0", "0 1e150 0"):        # still normalisable: the same arm as the unit axis
        arm = load_urdf_arm(_urdf(tmp_path, _changed('<axis xyz="0 1 0"/>', f'<axis xyz="{short}"/>'), "ok.urdf"),
                            "rod")
        assert arm.chain.axes[0] == (0.0, 1.0, 0.0)


# ---------------------------------------------------------------------------------------------------------------
# the nominal model and the observer bandwidth of a URDF arm: refused by the key the file sets
# ---------------------------------------------------------------------------------------------------------------
def test_a_nominal_scale_that_underflows_is_refused_by_its_key_not_as_a_singular_matrix():
    # before: "dobkit simulate: error: Singular matrix" (numpy's words, no key) once the run began
    import blocks
    from blocks.scenarios.scenario import ScenarioError
    scope4 = blocks.load_scenario("scope4")
    with pytest.raises(ScenarioError, match=r"the nominal model's inertia M\^\(q0\) at the start q0 = \[0.0, 0.1, 0.1, "
                                            r"0.0\] .* cannot be inverted in double precision; it is set by "
                                            r"'arm.nominal_mass_scale' = 1e-320"):
        scope4.with_changes({"arm.nominal_mass_scale": 1e-320, "gains.observer_bandwidth": 1e-3})
    # the smallest scale whose nominal inertia is still normal doubles loads (the roll's 4e-7 kg m^2 the smallest)
    assert scope4.with_changes({"arm.nominal_mass_scale": 1e-290}).kp.shape == (4, 4)


def test_an_observer_bandwidth_that_underflows_is_refused_naming_the_bandwidth():
    # before: refused as a bad 'gains.observer', a key the file does not set
    import blocks
    from blocks.scenarios.scenario import ScenarioError
    with pytest.raises(ScenarioError, match=r"'gains.observer_bandwidth' = 5e-324 rad/s gives the observer gain Y = "
                                            r"omega M\^\(q0\) that is not a usable gain \(Y must have a positive "
                                            r"definite"):
        blocks.load_scenario("scope4").with_changes({"gains.observer_bandwidth": 5e-324})


# ---------------------------------------------------------------------------------------------------------------
# metrics that are not finite numbers: strict JSON, the same way in every writer
# ---------------------------------------------------------------------------------------------------------------
def _strict(text: str):
    import json

    def refuse(token):
        raise ValueError(f"not JSON: {token}")
    return json.loads(text, parse_constant=refuse)


def test_non_finite_metrics_are_written_as_null_with_their_places_listed():
    # before: dobkit simulate's metrics.json held the bare token Infinity (report: null, unlisted)
    from blocks.plumbing.outputs import NON_FINITE_MEANING, metrics_json
    text, paths = metrics_json({"with_dob": {"rms_disturbance_error": [0.1, float("inf"), np.float64("nan")]},
                                "table": np.array([[1.0, -np.inf]]), "engine": "fast"})
    data = _strict(text)
    assert data["with_dob"]["rms_disturbance_error"] == [0.1, None, None] and data["table"] == [[1.0, None]]
    assert paths == ["with_dob/rms_disturbance_error/1", "with_dob/rms_disturbance_error/2", "table/0/1"]
    assert data["non_finite_values"] == {"meaning": NON_FINITE_MEANING, "paths": paths}
    finite, none = metrics_json({"a": [1.0, 2.5]})
    assert none == [] and "non_finite_values" not in _strict(finite)


def test_every_metrics_writer_is_the_strict_one(tmp_path):
    # dobkit simulate (run_experiment), dobkit report and fmu cosim write metrics.json through metrics_json
    import inspect

    import analysis.report.build as report
    import analysis.simulation.experiment as experiment
    from analysis.simulation.experiment import run_experiment
    from blocks.plumbing.outputs import metrics_json
    from dobkit.fmu_commands import strict_json
    short = __import__("blocks").load_scenario("paper").replace(simulation={"t_final": 0.05})
    result = run_experiment(short, tmp_path / "o", figures=False, engine="fast")
    assert (tmp_path / "o" / "metrics.json").read_text() == metrics_json(result.metrics)[0]
    assert strict_json({"x": float("nan")}) == metrics_json({"x": float("nan")})[0]
    for module in (report, experiment):
        assert "metrics_json(metrics)" in inspect.getsource(module)
