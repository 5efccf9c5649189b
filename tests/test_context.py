"""blocks.Context: a run's numbers apart from its diagram, with an optional member axis."""
import numpy as np
import pytest

from blocks.engines.context import Context, finite_bounds
from blocks.engines.divergence import StateBounds


def test_member_takes_its_column_and_its_rows():
    x0 = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])             # 2 states, 3 members
    gains = np.array([[10.0, 11.0], [20.0, 21.0], [30.0, 31.0]])  # a leading member axis
    bounds = StateBounds(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), ["a", "b"], ["", ""], ["", ""])
    ctx = Context(0.0, x0, params={"controller": (gains, 7.0)}, bounds=bounds, members=3)
    one = ctx.member(1)
    np.testing.assert_array_equal(one.x0, [2.0, 5.0])
    np.testing.assert_array_equal(one.params["controller"][0], [20.0, 21.0])
    assert one.params["controller"][1] == 7.0
    np.testing.assert_array_equal(one.bounds.bounds, [2.0, 5.0])
    assert one.members is None
    with pytest.raises(IndexError, match="member 3 is outside 0..2"):
        ctx.member(3)


def test_shapes_are_checked_and_default_bounds_only_ask_for_finite_states():
    with pytest.raises(ValueError, match=r"shape \(nstates, 3\) for 3 members"):
        Context(0.0, np.zeros((2, 2)), members=3)
    with pytest.raises(ValueError, match=r"shape \(nstates,\) for one run"):
        Context(0.0, np.zeros((2, 2)))
    ctx = Context(0.5, [1.0, -2.0], growth=False, labels=("x", "v"))
    b = ctx.state_bounds()
    assert np.all(np.isinf(b.bounds)) and b.names == ["x", "v"]
    assert not b.violated([1e300, -1e300]).any() and b.violated([np.nan, 0.0]).tolist() == [True, False]
    assert finite_bounds(["s"]).reasons == ["finite"]
