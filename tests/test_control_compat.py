"""python-control still keeps what dobkit's engines read (blocks.diagram.control_compat)."""
from __future__ import annotations

import control as ct
import numpy as np
import pytest

from blocks.diagram.control_compat import PythonControlChanged, check_python_control, connection_maps, merged_params


def test_the_installed_python_control_keeps_what_the_engines_read():
    check_python_control()


def test_a_changed_release_is_reported_by_name(monkeypatch):
    """Simulate a release whose interconnections drop ``connect_map``: the check names what changed."""
    real = ct.interconnect

    def changed(*args, **kwargs):
        system = real(*args, **kwargs)
        del system.connect_map
        return system
    monkeypatch.setattr(ct, "interconnect", changed)
    with pytest.raises(PythonControlChanged, match=r"python-control .*connect_map.*blocks.diagram.control_compat"):
        check_python_control()


def test_merged_params_follow_python_controls_rule():
    block = ct.nlsys(None, lambda t, x, u, p: u, inputs="u", outputs="y", name="b", params={"a": 1, "b": 2})
    loop = ct.interconnect([block], inplist=["u"], outlist=["y"], params={"b": 3})
    assert merged_params(loop, loop.syslist[0]) == {"a": 1, "b": 3}
    assert merged_params(loop, loop.syslist[0], {"a": 7}) == {"a": 7, "b": 3}
    C, B, O = connection_maps(loop)
    assert B.shape == (1, 1) and np.all(O[:, :1] == 1)
