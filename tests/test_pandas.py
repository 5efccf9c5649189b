"""pandas comes with the package: a run's ``to_pandas`` gives every signal by name.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import blocks
from blocks import load_scenario


# --- pandas comes with the package ------------------------------------------------------------------------------
def test_to_pandas_gives_every_signal_by_name(short_toml):
    resp = blocks.simulate(load_scenario(short_toml), engine="fast")
    frame = resp.to_pandas()
    assert list(frame.columns[:1 + len(resp.output_labels)]) == ["time", *resp.output_labels]   # then the states
    assert len(frame) == 101 and frame["time"].iloc[-1] == pytest.approx(1.0)
    # the joint-sine reference of the short scenario: q_ref[1] = 2 + 0.05 sin(2 t) (rad)
    t = frame["time"].to_numpy()
    np.testing.assert_allclose(frame["q_ref[1]"].to_numpy(), 2.0 + 0.05 * np.sin(2.0 * t), atol=1e-12)


def test_pandas_is_a_dependency_of_the_package():
    import tomllib

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    assert any(r.replace(" ", "").startswith("pandas>=") for r in project["dependencies"])     # not an extra
