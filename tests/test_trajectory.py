"""Reference trajectories: C2 smoothness, geometry of the laceration path, exact joint_sine derivatives."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import SKIN_DEFAULT, reference_fk

import blocks
from blocks import JointSine, LacerationPath, RobotParameters, UnreachableError

PAPER = RobotParameters()
# The paper scenario's path (scenarios/paper.toml), with a bulge so the curve term is exercised.
PATH = LacerationPath(params=PAPER, start=(0.36, -0.05), end=(0.46, 0.05), bulge=0.01, stitches=5, hover=0.003,
                      depth=0.004, needle_roll=1.0, duration=10.0)
STRAIGHT = LacerationPath(params=PAPER, start=(0.42, -0.04), end=(0.42, 0.04), stitches=4, duration=6.0,
                          elbow="negative", roll_offset=0.3)


def _interior_times(path, n=157):
    """Times strictly inside phases (avoid the boundaries where the third derivative jumps)."""
    T = path.phase_duration
    t = np.linspace(0.0, path.duration, n)
    t = t[np.abs(t / T - np.round(t / T)) > 1e-3]
    return t


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_derivatives_equal_finite_differences(path):
    h = 1e-5
    for t in _interior_times(path):
        q_p, dq_p, _ = path.evaluate(t + h)
        q_m, dq_m, _ = path.evaluate(t - h)
        _, dq, ddq = path.evaluate(t)
        np.testing.assert_allclose(dq, (q_p - q_m) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(ddq, (dq_p - dq_m) / (2 * h), atol=1e-6)


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_continuous_across_phase_boundaries(path):
    T = path.phase_duration
    eps = 1e-9
    for k in range(1, 2 * path.stitches):
        tb = k * T
        before = path.evaluate(tb - eps)
        after = path.evaluate(tb + eps)
        for a, b, tol in zip(before, after, (1e-8, 1e-7, 1e-6)):
            np.testing.assert_allclose(a, b, atol=tol)
        # at a boundary the motion is at rest (every phase starts and ends at rest)
        np.testing.assert_allclose(path.evaluate(tb)[1], 0.0, atol=1e-12)
        np.testing.assert_allclose(path.evaluate(tb)[2], 0.0, atol=1e-10)


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_starts_and_ends_at_rest_and_holds(path):
    for t in (0.0, path.duration, path.duration + 2.5):
        _, dq, ddq = path.evaluate(t)
        np.testing.assert_allclose(dq, 0.0, atol=1e-12)
        np.testing.assert_allclose(ddq, 0.0, atol=1e-12)
    np.testing.assert_allclose(path.evaluate(path.duration + 2.5)[0], path.evaluate(path.duration)[0], atol=1e-14)
    # first and last poses: hovering over the laceration's end points at the rest roll
    for t, xy in ((0.0, path.start), (path.duration, path.end)):
        p = reference_fk(path.evaluate(t)[0])
        np.testing.assert_allclose(p[:2], xy, atol=1e-12)
        assert p[2] == pytest.approx(path.skin_height + path.hover, abs=1e-12)
        assert np.cos(p[3] - path.roll_offset) == pytest.approx(1.0)


def _curve_coordinates(path, xy):
    """Arc parameter s and normal offset w of points xy relative to the start->end chord."""
    p0, p1 = np.array(path.start), np.array(path.end)
    d = p1 - p0
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    rel = xy - p0
    return rel @ d / (d @ d), rel @ n


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_fk_of_reference_stays_on_documented_path(path):
    t = np.linspace(0.0, path.duration, 801)
    q, _, _ = path.evaluate(t)
    p = reference_fk(q)
    # height between the stitch bottom and the hover height, reaching both
    assert p[:, 2].min() == pytest.approx(path.skin_height - path.depth, abs=1e-6)   # sampled near the bottom
    assert p[:, 2].max() == pytest.approx(path.skin_height + path.hover, abs=1e-12)
    assert np.all(p[:, 2] >= path.skin_height - path.depth - 1e-12)
    assert np.all(p[:, 2] <= path.skin_height + path.hover + 1e-12)
    # x, y on the laceration: the parabola start + s d + 4 bulge s (1 - s) n, s in [0, 1]
    s, w = _curve_coordinates(path, p[:, :2])
    assert s.min() == pytest.approx(0.0, abs=1e-12) and s.max() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(w, 4 * path.bulge * s * (1 - s), atol=1e-12)
    # the arc parameter never goes back
    assert np.all(np.diff(s) >= -1e-12)
    # roll between the rest angle and rest + needle_roll
    phi = np.angle(np.exp(1j * (p[:, 3] - path.roll_offset)))
    assert phi.min() >= -1e-12 and phi.max() <= path.needle_roll + 1e-12
    assert phi.max() == pytest.approx(path.needle_roll, abs=1e-4)        # sampled near the peak
    # elbow branch kept
    assert np.all(np.sign(q[:, 1]) == (1 if path.elbow == "positive" else -1))


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_stitches_at_equal_spacing_reach_full_depth(path):
    T = path.phase_duration
    for k in range(path.stitches):
        q, dq, _ = path.evaluate((2 * k + 0.5) * T)          # middle of stitch k
        p = reference_fk(q)
        s, _ = _curve_coordinates(path, p[:2])
        assert s == pytest.approx(k / (path.stitches - 1), abs=1e-12)
        assert p[2] == pytest.approx(path.skin_height - path.depth, abs=1e-12)
        assert np.cos(p[3] - path.roll_offset - path.needle_roll) == pytest.approx(1.0)
        np.testing.assert_allclose(dq, 0.0, atol=1e-10)      # bottom of the dip, roll at its peak


@pytest.mark.parametrize("path", [PATH, STRAIGHT], ids=["paper", "straight"])
def test_scalar_and_array_evaluation_agree(path):
    t = np.concatenate([np.linspace(0.0, path.duration + 1.0, 97), [path.phase_duration * 3]])
    q, dq, ddq = path.evaluate(t)
    assert q.shape == dq.shape == ddq.shape == (t.size, 4)
    for k, tk in enumerate(t):
        qs, dqs, ddqs = path.evaluate(float(tk))
        assert qs.shape == (4,)
        np.testing.assert_allclose(qs, q[k], atol=1e-12)
        np.testing.assert_allclose(dqs, dq[k], atol=1e-10)
        np.testing.assert_allclose(ddqs, ddq[k], atol=1e-9)


def test_default_skin_height_is_table1_d3():
    assert LacerationPath().skin_height == pytest.approx(SKIN_DEFAULT)


@pytest.mark.parametrize("kwargs, fragment", [
    ({"start": (0.8, 0.0), "end": (0.6, 0.0)}, "x=0.8 m"),
    # a cut through the inner hole of the annulus: the middle point is unreachable
    ({"start": (0.35, 0.2), "end": (-0.35, 0.2)}, "y=0.2 m"),
    # reachable everywhere, but passes almost stretched (sin theta2 < sin 0.2)
    ({"start": (0.698, -0.02), "end": (0.698, 0.02)}, "singularity"),
])
def test_unreachable_laceration_raises_naming_the_point(kwargs, fragment):
    with pytest.raises(UnreachableError) as info:
        LacerationPath(params=PAPER, **kwargs)
    message = str(info.value)
    assert "not reachable" in message and fragment in message


@pytest.mark.parametrize("kwargs, name", [
    ({"stitches": 1}, "stitches"),
    ({"stitches": 2.5}, "stitches"),
    ({"depth": 0.0}, "depth"),
    ({"hover": -0.001}, "hover"),
    ({"duration": -1.0}, "duration"),
    ({"elbow": "up"}, "elbow"),
    ({"start": (0.4, 0.0), "end": (0.4, 0.0)}, "start"),
    ({"start": (0.4,)}, "start"),
    ({"bulge": float("nan")}, "bulge"),
])
def test_bad_laceration_values_are_named(kwargs, name):
    with pytest.raises(ValueError, match=f"trajectory.{name}"):
        LacerationPath(params=PAPER, **kwargs)


def test_joint_sine_is_exact():
    a, w, c = np.array([0.1, -0.2, 0.01, 0.3]), np.array([1.0, 2.5, 0.5, 3.0]), np.array([0.2, 1.5, 0.24, -0.1])
    js = JointSine(amplitude=tuple(a), omega=tuple(w), offset=tuple(c))
    t = np.linspace(0.0, 4.0, 41)
    q, dq, ddq = js.evaluate(t)
    np.testing.assert_allclose(q, c + a * np.sin(np.outer(t, w)), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(dq, a * w * np.cos(np.outer(t, w)), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(ddq, -a * w ** 2 * np.sin(np.outer(t, w)), rtol=1e-14, atol=1e-15)
    h = 1e-5
    for tk in t[1:-1]:
        np.testing.assert_allclose(js.evaluate(tk)[1], (js.evaluate(tk + h)[0] - js.evaluate(tk - h)[0]) / (2 * h),
                                   atol=1e-8)
        np.testing.assert_allclose(js.evaluate(tk)[2], (js.evaluate(tk + h)[1] - js.evaluate(tk - h)[1]) / (2 * h),
                                   atol=1e-7)
    for k, tk in enumerate(t):
        for scalar, batch in zip(js.evaluate(float(tk)), (q, dq, ddq)):
            np.testing.assert_allclose(scalar, batch[k], atol=1e-15)


def test_joint_sine_scalar_omega_and_bad_shapes():
    js = JointSine(omega=2.0)
    assert js.omega == (2.0, 2.0, 2.0, 2.0)
    with pytest.raises(ValueError, match="trajectory.amplitude"):
        JointSine(amplitude=(0.1, 0.2))
    with pytest.raises(ValueError, match="trajectory.offset"):
        JointSine(offset=(0.0, np.inf, 0.0, 0.0))


def test_stacked_references_equal_the_three_parts():
    path = blocks.load_scenario("paper").trajectory
    for t in (0.0, 1.234, 9.99):
        np.testing.assert_array_equal(path.evaluate_stacked(t), np.concatenate(path.evaluate(t)))
    t = np.linspace(0.0, 10.0, 7)
    stacked = path.evaluate_stacked(t)
    assert stacked.shape == (7, 12)
    np.testing.assert_array_equal(stacked, np.concatenate(path.evaluate(t), axis=-1))
