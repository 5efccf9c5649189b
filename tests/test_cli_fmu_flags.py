"""``dobkit fmu``'s flags: a flag that would be ignored is refused in one line, and ``--locked NAME=VALUE`` holds a
joint where the command line says (docs/hostile-inputs.md, "Round 7").
"""
from __future__ import annotations

import numpy as np
import pytest
from two_joint_arm import changed as _changed
from two_joint_arm import write_urdf as _urdf

pin = pytest.importorskip("pinocchio")

from blocks.model.urdf.urdf import load_urdf_arm  # noqa: E402


@pytest.mark.parametrize("argv, says", [
    (["fmu", "export", "--tool-frame", "tip", "--out", "x.fmu"], "--tool-frame goes with --arm X.urdf"),
    (["fmu", "export", "--locked", "a,b", "--out", "x.fmu"], "--locked goes with --arm X.urdf"),
    (["fmu", "export", "--arm", "scope4", "--scenario", "paper", "--out", "x.fmu"],
     "--arm scope4 and --scenario paper both name the plant to export; give one"),
    (["fmu", "check", "x.fmu", "--arm", "rrpr", "--tool-frame", "tip"], "--tool-frame goes with --arm X.urdf"),
])
def test_fmu_flags_that_would_be_ignored_are_refused(tmp_path, monkeypatch, capsys, argv, says):
    # `fmu export --tool-frame tip` exported the paper's plant, the flag ignored; `--arm X --scenario Y` exported X
    from dobkit.cli import main
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dobkit fmu: error: ") and says in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.fmu").exists()


def test_fmu_export_locks_a_joint_at_a_position_given_on_the_command_line(tmp_path, capsys):
    # --locked took names only: a joint whose range excludes 0 could not be locked from the command line
    from dobkit.cli import main
    path = _urdf(tmp_path, _changed('lower="-0.1" upper="0.2"', 'lower="0.05" upper="0.2"'))
    out = tmp_path / "x.fmu"
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide", "--out",
                 str(out)]) == 2
    assert "--locked NAME=VALUE" in capsys.readouterr().err and not out.exists()
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide=x", "--out",
                 str(out)]) == 2
    assert "--locked 'slide=x': the position after '=' must be a number" in capsys.readouterr().err
    assert main(["fmu", "export", "--arm", str(path), "--tool-frame", "arm", "--locked", "slide=0.1", "--out",
                 str(out)]) == 0
    assert "arm 1 joints ['pitch']" in capsys.readouterr().out
    # the record in the FMU is the arm with the slide held at 0.1 m: the rod's centre of mass then sits 0.1 m
    # further along the slide's axis (0.8, 0, -0.6) in the arm's frame, so the pitch inertia is pinocchio's
    import zipfile

    from fmu.arm_record import ARM_RECORD, arm_from_record
    recorded = arm_from_record(zipfile.ZipFile(out).read(ARM_RECORD).decode("utf-8"))
    reference = load_urdf_arm(path, "arm", locked=["slide"], locked_values={"slide": 0.1})
    model = reference.pin_model
    data = model.createData()
    q = np.array([0.3])
    np.testing.assert_allclose(recorded.inertia(q), pin.crba(model, data, q), rtol=1e-12)
