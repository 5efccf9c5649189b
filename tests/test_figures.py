"""The figures a reader sees: what each draws and says, in the formats asked for.
"""
from __future__ import annotations

import pytest

import blocks
from blocks import load_scenario


def test_figure_formats_are_checked(short_toml, tmp_path):
    from analysis.simulation.figures import paper_figures

    resp = blocks.simulate(load_scenario(short_toml), engine="fast")
    with pytest.raises(ValueError, match=r"figure formats must be one or more of \['png', 'svg'\], got \('jpg',\)"):
        paper_figures(resp, resp, tmp_path, formats=("jpg",))
    assert not any(tmp_path.iterdir())
