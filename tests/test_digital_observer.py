"""One update of the sampled observer with a full (non-diagonal) gain ``Y``, against the observer law by hand.

The law (paper-notes, "Control law and observer"): ``d_hat = Y q' + z`` and
``z' = -Y M^-1(q) (tau + d_hat - N(q, q') q' - G(q))``.  Over one sample with
``q``, ``q'`` and ``tau`` held, ``z' = A z + c`` with ``A = -Y M^-1`` and
``c = -Y M^-1 (tau + Y q' - N q' - G)``.  Forward Euler takes one step of it;
``"zoh"`` its exact solution, computed here by a tight ODE integration.
``M`` is Eq. 5 written out in tests/conftest.py; ``N q'`` the Christoffel
vector of paper-notes (``h = k2 sin(theta2) / 2``).
"""
from __future__ import annotations

import numpy as np
import pytest
from conftest import PAPER_G, PAPER_K, reference_inertia
from scipy.integrate import solve_ivp

from blocks import RobotParameters
from blocks.diagram.digital import DigitalController, digital_observer

TS = 0.002
Y_FULL = np.array([[10.0, 2.0, 0.0, 1.0],       # Y + Y^T positive definite, off-diagonal terms on three joints
                   [-1.0, 8.0, 0.5, 0.0],
                   [0.0, 0.5, 12.0, 0.0],
                   [1.0, 0.0, 0.0, 9.0]])
Q, DQ = np.array([0.3, 1.2, 0.1, 0.2]), np.array([0.4, -0.7, 0.05, 1.1])
TAU, Z = np.array([3.0, -1.0, -2.0, 0.5]), np.array([0.2, -0.4, 1.0, 0.3])


def bias_by_hand(q, dq) -> np.ndarray:
    """``N(q, q') q' + G(q)`` from paper-notes: C11 = -h q2', C12 = -h (q1' + q2'), C21 = h q1', G3 = -k4 g."""
    h = PAPER_K["k2"] * np.sin(q[1]) / 2
    return np.array([-h * dq[1] * dq[0] - h * (dq[0] + dq[1]) * dq[1], h * dq[0] ** 2, -PAPER_K["k4"] * PAPER_G, 0.0])


def affine_law(Y=Y_FULL):
    """``(A, c)`` of ``z' = A z + c`` at the held inputs."""
    Minv = np.linalg.inv(reference_inertia(Q[1]))
    return -Y @ Minv, -Y @ Minv @ (TAU + Y @ DQ - bias_by_hand(Q, DQ))


@pytest.mark.parametrize("discretization", ["euler", "zoh"])
def test_one_sample_of_the_observer_with_a_full_gain(discretization):
    block = digital_observer(RobotParameters(), Y_FULL,
                             DigitalController(sample_rate=1 / TS, observer_discretization=discretization))
    u = np.concatenate([TAU, Q, DQ])
    np.testing.assert_allclose(block.output(0.0, Z, u), Y_FULL @ DQ + Z, rtol=1e-14)
    A, c = affine_law()
    if discretization == "euler":
        want = Z + TS * (A @ Z + c)
    else:
        want = solve_ivp(lambda t, z: A @ z + c, (0.0, TS), Z, method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1]
    got = block.dynamics(0.0, Z, u)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-13)
    # the off-diagonal terms matter: an Euler step with the diagonal of Y alone lands far from it
    A_d, c_d = affine_law(np.diag(np.diag(Y_FULL)))
    assert np.abs(got - (Z + TS * (A_d @ Z + c_d))).max() > 1e-3
