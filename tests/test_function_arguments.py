"""The public model functions check their arguments once, in one place (blocks/model/validation.py): every function of
``blocks`` that takes arrays raises TypeError for a wrong type and ValueError for a wrong shape or a non-finite
entry, naming the argument, what it got and what is expected; good batches still give the numbers of
docs/model.md, worked by hand here.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import D1, D4, L1, L2, reference_inertia

import blocks
from blocks import PAPER_PARAMETERS as P

PAPER = blocks.load_scenario("paper")


@pytest.mark.parametrize("call, error, words", [
    (lambda: blocks.forward_kinematics(np.zeros((4, 5)), P), ValueError, r"q must have shape \(\.\.\., 4\).*\(4, 5\)"),
    (lambda: blocks.forward_kinematics(np.zeros(3), P), ValueError, r"q must have shape \(\.\.\., 4\).*\(3,\)"),
    (lambda: blocks.inertia(np.full(4, np.nan), P), ValueError, r"q must be finite.*nan"),
    (lambda: blocks.jacobian(None, P), TypeError, r"q must be an array of real numbers, got NoneType"),
    (lambda: blocks.gravity(np.zeros(4), "x"), TypeError,
     r"params must be an arm model \(blocks.model.arm.ArmModel.*got str 'x'"),
    (lambda: blocks.forward_dynamics(np.zeros(4), np.zeros((2, 4)), np.zeros((3, 4)), P), ValueError,
     r"q, dq, tau must have shapes that broadcast together, got q \(4,\), dq \(2, 4\), tau \(3, 4\)"),
    (lambda: blocks.inverse_kinematics([0.5, 0.0, 0.0], P), ValueError, r"pose must have shape \(\.\.\., 4\)"),
])
def test_public_functions_refuse_bad_arrays_naming_the_argument_and_its_shape(call, error, words):
    with pytest.raises(error, match=words):
        call()


def test_batches_of_good_arrays_still_give_the_hand_computed_numbers():
    q = np.array([[0.3, 1.2, 0.1, 0.2], [0.0, np.pi / 2, 0.2, 0.0]])
    pose = blocks.forward_kinematics(q, P)
    # x = l1 c1 + l2 c12, y = l1 s1 + l2 s12, z = d1 - d3 - d4, phi = theta1 + theta2 - theta4 (docs/model.md)
    expected = [[L1 * math.cos(t1) + L2 * math.cos(t1 + t2), L1 * math.sin(t1) + L2 * math.sin(t1 + t2),
                 D1 - d3 - D4, t1 + t2 - t4] for t1, t2, d3, t4 in q]
    np.testing.assert_allclose(pose, expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(blocks.inertia(q, P), [reference_inertia(t2) for t2 in q[:, 1]], rtol=1e-13)


# Bad values of every kind a user may pass; each public function must answer TypeError or ValueError.
BAD_VALUES = [None, "x", True, {}, object(), 1j, [1.0, 2.0, 3.0], [[1.0, 2.0], [3.0]], [math.nan] * 4,
              [math.inf, 0, 0, 0], [10 ** 400, 0, 0, 0], [1j, 0, 0, 0], np.array(["1", "2", "3", "4"]),
              np.zeros((4, 5)), np.zeros((0, 3))]


# any real array of times is a time grid (it broadcasts against the joints' leading shape)
BAD_TIMES = [None, "x", True, {}, object(), 1j, [math.nan], [10 ** 400], [[1.0, 2.0], [3.0]]]


Q = [0.3, 1.2, 0.1, 0.2]


FUNCTIONS = {
    "inertia": (blocks.inertia, {"q": Q, "params": P}),
    "coriolis_vector": (blocks.coriolis_vector, {"q": Q, "dq": Q, "params": P}),
    "coriolis_matrix": (blocks.coriolis_matrix, {"q": Q, "dq": Q, "params": P}),
    "gravity": (blocks.gravity, {"q": Q, "params": P}),
    "forward_dynamics": (blocks.forward_dynamics, {"q": Q, "dq": Q, "tau": Q, "params": P}),
    "inverse_dynamics": (blocks.inverse_dynamics, {"q": Q, "dq": Q, "ddq": Q, "params": P}),
    "kinetic_energy": (blocks.kinetic_energy, {"q": Q, "dq": Q, "params": P}),
    "forward_kinematics": (blocks.forward_kinematics, {"q": Q, "params": P}),
    "jacobian": (blocks.jacobian, {"q": Q, "params": P}),
    "inverse_kinematics": (blocks.inverse_kinematics, {"pose": [0.45, 0.1, -0.39, 0.0], "params": P}),
    "external_disturbance": (blocks.external_disturbance,
                             {"t": 0.5, "q": Q, "dq": Q, "spec": PAPER.disturbance, "params": P}),
    "lumped_disturbance": (blocks.lumped_disturbance,
                           {"q": Q, "dq": Q, "tau": Q, "tau_dis": Q, "scenario": PAPER}),
}


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_public_functions_answer_any_bad_argument_with_a_type_or_value_error_naming_it(name):
    function, good = FUNCTIONS[name]
    function(**good)                                         # the good call works
    for argument in good:
        for bad in BAD_TIMES if argument == "t" else BAD_VALUES:
            try:
                function(**(good | {argument: bad}))
            except (TypeError, ValueError) as err:
                assert argument in str(err), (name, argument, bad, err)
            else:
                raise AssertionError(f"{name}({argument}={bad!r:.60}) was accepted")
