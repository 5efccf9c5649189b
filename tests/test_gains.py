"""Gains: one check (blocks.diagram.gains.validated_gain) that a scenario file and a batch variant both apply."""
from __future__ import annotations

import doctest

import numpy as np
import pytest

import blocks.diagram.gains
from blocks import RRPR_JOINTS, ScenarioError, load_scenario, scenario_from_dict
from blocks.diagram.gains import GainError, validated_gain
from blocks.figure2.batch import Variants

# An observer gain whose eigenvalues are both 1 (positive) but whose symmetric part [[2, 4], [4, 2]]
# (in the first two joints) has the eigenvalue 2 - 4 = -2: the error energy e^T M e can grow.
SHEARED = [[1.0, 4.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
# Eigenvalues 1 +- 5i, symmetric part 2 I: non-symmetric but convergent.
ROTATING = [[1.0, 5.0, 0.0, 0.0], [-5.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
COUPLED_KP = [[180.0, 5.0, 0.0, 0.0], [0.0, 180.0, 0.0, 0.0], [0.0, 0.0, 180.0, 0.0], [0.0, 0.0, 0.0, 180.0]]

GOOD = [
    ("kp", 100, np.diag([100.0] * 4)),
    ("kd", [30.0, 31.0, 32.0, 33.0], np.diag([30.0, 31.0, 32.0, 33.0])),
    ("kp", np.diag([1.0, 2.0, 3.0, 4.0]).tolist(), np.diag([1.0, 2.0, 3.0, 4.0])),   # a diagonal matrix
    ("observer", 40.0, np.diag([40.0] * 4)),
    ("observer", [5, 6, 7, 8], np.diag([5.0, 6.0, 7.0, 8.0])),
    ("observer", ROTATING, np.array(ROTATING)),
]

BAD = {
    "text": ("kp", "high", ["gains.kp", "'high'", "a number, 4 numbers or a diagonal 4x4 matrix"]),
    "true/false": ("kd", True, ["gains.kd", "True"]),
    "nothing": ("kp", None, ["gains.kp", "None"]),
    "a list holding true": ("kp", [True, 1.0, 1.0, 1.0], ["gains.kp", "True"]),
    "wrong length": ("kd", [1.0, 2.0], ["gains.kd", "[1.0, 2.0]", "shape (2,)"]),
    "ragged matrix": ("observer", [[1.0, 2.0], [3.0]], ["gains.observer", "a 4x4 matrix"]),
    "not finite": ("kp", float("inf"), ["gains.kp", "finite", "inf"]),
    "nan in a list": ("observer", [10.0, float("nan"), 10.0, 10.0], ["gains.observer", "finite"]),
    "zero kp": ("kp", 0.0, ["gains.kp", "> 0 on every joint"]),
    "negative kd on one joint": ("kd", [36.0, 36.0, -1.0, 36.0], ["gains.kd", "> 0 on every joint", "-1.0"]),
    "coupled kp": ("kp", COUPLED_KP, ["gains.kp", "diagonal", "no coupling"]),
    "coupled kd": ("kd", SHEARED, ["gains.kd", "diagonal"]),
    "negative observer": ("observer", -10.0, ["gains.observer", "Y + Y^T > 0", "-10.0"]),
    "zero observer on one joint": ("observer", [10.0, 10.0, 0.0, 10.0], ["gains.observer", "Y + Y^T > 0"]),
    "observer with positive eigenvalues but indefinite Y + Y^T": ("observer", SHEARED,
                                                                  ["gains.observer", "Y + Y^T > 0"]),
}


@pytest.mark.parametrize("key, value, expected", GOOD)
def test_good_gains_become_read_only_matrices(key, value, expected):
    matrix = validated_gain(value, key, RRPR_JOINTS)
    np.testing.assert_array_equal(matrix, expected)
    assert matrix.dtype == float and not matrix.flags.writeable
    with pytest.raises(ValueError):
        matrix[0, 0] = 1.0


def test_the_callers_array_is_copied():
    given = np.diag([1.0, 2.0, 3.0, 4.0])
    matrix = validated_gain(given, "kp", RRPR_JOINTS)
    given[0, 0] = 99.0                            # the caller keeps a writable array ...
    assert matrix[0, 0] == 1.0                    # ... that does not reach the validated gain
    assert given.flags.writeable


@pytest.mark.parametrize("case", list(BAD))
def test_bad_gains_name_the_key_the_value_and_what_is_allowed(case):
    key, value, fragments = BAD[case]
    with pytest.raises(GainError) as err:
        validated_gain(value, key, RRPR_JOINTS)
    assert isinstance(err.value, ValueError)
    for fragment in fragments:
        assert fragment in str(err.value), (fragment, str(err.value))


def test_unknown_gain_name():
    with pytest.raises(GainError, match="gains.ki"):
        validated_gain(1.0, "ki", RRPR_JOINTS)


@pytest.fixture(scope="module")
def paper():
    return load_scenario("paper")


@pytest.mark.parametrize("case", list(BAD))
def test_scenario_and_batch_refuse_exactly_what_validated_gain_refuses(case, paper):
    key, value, _ = BAD[case]
    with pytest.raises(GainError) as direct:
        validated_gain(value, key, RRPR_JOINTS)
    with pytest.raises(ScenarioError) as from_file:
        scenario_from_dict({"gains": {key: value}}, source="g.toml")
    with pytest.raises(ScenarioError) as from_batch:
        Variants(paper, [{"gains.kp": 150.0}, {f"gains.{key}": value}])
    assert str(from_file.value) == f"g.toml: {direct.value}"
    assert str(from_batch.value) == f"variant 1: {direct.value}"
    with pytest.raises(ScenarioError) as changed:
        paper.with_changes({f"gains.{key}": value})
    assert str(changed.value) == f"paper: {direct.value}"


@pytest.mark.parametrize("key, value, expected", GOOD)
def test_scenario_and_batch_accept_the_same_gains_as_validated_gain(key, value, expected, paper):
    field = {"kp": "kp", "kd": "kd", "observer": "observer_gain"}[key]
    from_file = scenario_from_dict({"gains": {key: value}})
    np.testing.assert_array_equal(getattr(from_file, field), expected)
    batch = Variants(paper, [{}, {f"gains.{key}": value}])
    if key == "observer":
        full = batch.y_full[:, :, 1] if batch.y_full is not None else np.diag(batch.y_diag[:, 1])
        np.testing.assert_array_equal(full, expected)
        np.testing.assert_array_equal(batch.y_full[:, :, 0] if batch.y_full is not None
                                      else np.diag(batch.y_diag[:, 0]), 10.0 * np.eye(4))
    else:
        np.testing.assert_array_equal(getattr(batch, key)[:, 1], np.diag(expected))
    np.testing.assert_array_equal(getattr(batch.scenario(1), field), expected)


def test_module_examples_run():
    assert doctest.testmod(blocks.diagram.gains).failed == 0
