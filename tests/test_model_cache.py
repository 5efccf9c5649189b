"""NominalTerms: the nominal-model terms the controller and the observer share, remembered at their last arguments."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks.dynamics import coriolis_vector, gravity, inertia
from blocks.model_cache import NominalTerms, nominal_terms


def test_terms_equal_the_model_functions_and_change_with_the_arguments():
    params = blocks.load_scenario("paper").nominal
    terms = NominalTerms(params)
    rng = np.random.default_rng(2)
    for _ in range(3):
        q, dq = rng.standard_normal(4), rng.standard_normal(4)
        M, h = terms(q, dq)
        np.testing.assert_array_equal(M, inertia(q, params))
        np.testing.assert_array_equal(h, coriolis_vector(q, dq, params) + gravity(q, params))


def test_a_repeated_call_returns_the_remembered_read_only_arrays():
    terms = NominalTerms(blocks.load_scenario("paper").nominal)
    q, dq = np.array([0.1, 1.9, 0.25, 0.3]), np.array([0.2, -0.1, 0.01, 0.0])
    M1, h1 = terms(q, dq)
    M2, h2 = terms(q.copy(), dq.copy())
    assert M1 is M2 and h1 is h2
    with pytest.raises(ValueError, match="read-only"):
        M1[0, 0] = 0.0
    M3, _ = terms(q, dq + 1e-12)            # any change in a bit is a new evaluation
    assert M3 is not M1


def test_columns_are_evaluated_not_remembered():
    params = blocks.load_scenario("paper").nominal
    terms = NominalTerms(params)
    q = np.tile([0.1, 1.9, 0.25, 0.3], (5, 1)) + 0.01 * np.arange(5)[:, None]
    M, h = terms(q, np.zeros_like(q))
    assert M.shape == (5, 4, 4) and h.shape == (5, 4) and M.flags.writeable
    np.testing.assert_array_equal(M, inertia(q, params))


def test_blocks_on_equal_parameters_share_one_instance():
    s = blocks.load_scenario("paper")
    assert nominal_terms(s.nominal) is nominal_terms(s.replace(gains={"kp": 100.0}).nominal)
    other = s.replace(nominal_scale={"m1": 1.1}).nominal
    assert nominal_terms(other) is not nominal_terms(s.nominal)


def test_arguments_with_equal_bytes_but_other_meaning_are_not_confused():
    params = blocks.load_scenario("paper").nominal
    terms = NominalTerms(params)
    q = np.array([0.0, 1.0, 0.25, 0.0])
    dq = np.array([0.1, 0.2, 0.3, 0.4])
    terms(q, dq)
    joined = np.concatenate([q, dq])
    with pytest.raises(ValueError, match="last axis of length 4"):
        terms(joined[:3], joined[3:])       # the same 64 bytes split 3 + 5: evaluated (and refused), not recalled
    # integers with the bytes of remembered floats are evaluated as the integers they are
    as_int = q.view(np.int64)
    M_int, _ = terms(as_int, np.zeros(4, dtype=np.int64))
    np.testing.assert_array_equal(M_int, inertia(as_int.astype(float), params))
