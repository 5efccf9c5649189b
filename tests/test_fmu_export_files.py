"""The file ``fmu.export_plant`` writes: an existing file (or one another export wrote while this one compiled)
is kept unless forced, and the plant starts in a regular pose unless the caller gives one.
"""
from __future__ import annotations

import math

import pytest


# --- fmu.export_plant keeps an existing file and starts in a regular pose ---------------------------------------
def test_export_refuses_an_existing_file_before_compiling(tmp_path):
    from fmu import export_plant

    target = tmp_path / "plant.fmu"
    target.write_bytes(b"someone's file")
    with pytest.raises(FileExistsError, match="plant.fmu.*exists; refusing to overwrite it.*force=True"):
        export_plant(target)
    assert target.read_bytes() == b"someone's file"
    with pytest.raises(IsADirectoryError, match="is a folder"):
        export_plant(tmp_path)


@pytest.mark.parametrize("force", [False, True])
def test_a_file_another_export_wrote_while_this_one_compiled_is_kept_unless_forced(tmp_path, force):
    """Two exports to one path at once: the check before compiling passes for both; without force the second to
    finish is refused when it puts its archive in place (a real compiler, run by a script that first writes the
    other export's file)."""
    import zipfile

    from fmu import export_plant
    from fmu.build import find_compiler

    target = tmp_path / "plant.fmu"
    compiler = tmp_path / "cc-after-another-export"
    compiler.write_text(f"#!/bin/sh\nprintf 'the other export' > '{target}'\nexec {find_compiler()[0]} \"$@\"\n")
    compiler.chmod(0o755)
    if force:
        export_plant(target, cc=str(compiler), force=True)
        assert zipfile.is_zipfile(target)                   # replaced, as asked
    else:
        with pytest.raises(FileExistsError, match="plant.fmu.*written by another export.*force=True"):
            export_plant(target, cc=str(compiler))
        assert target.read_bytes() == b"the other export"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []    # no archive left half-named


@pytest.mark.needs_cc
def test_export_replaces_with_force_and_starts_in_a_regular_pose(tmp_path):
    import fmpy

    from fmu import export_plant

    target = tmp_path / "plant.fmu"
    target.write_bytes(b"old")
    assert export_plant(target, force=True) == target and target.stat().st_size > 1000
    start = {v.name: v.start for v in fmpy.read_model_description(str(target)).modelVariables}
    q0 = [float(start[f"q[{i}]"]) for i in range(4)]
    # theta2 = pi/2: |sin(theta2)| = 1, the largest planar Jacobian determinant a1 a2 sin(theta2); d3 = 0.24 m
    assert q0 == pytest.approx([0.0, math.pi / 2, 0.24, 0.0], abs=1e-12)
    assert [float(start[f"dq[{i}]"]) for i in range(4)] == [0.0] * 4
    # a start given by the caller is kept
    again = export_plant(tmp_path / "mine.fmu", q0=[0.1, 1.0, 0.2, 0.0])
    start = {v.name: v.start for v in fmpy.read_model_description(str(again)).modelVariables}
    assert float(start["q[1]"]) == pytest.approx(1.0)
