"""The Figure-2 loop of any arm model, linearized at a held configuration from the model's own derivatives.

:mod:`analysis.linear.loop` linearizes the interconnected python-control loop a
scenario builds.  This module gives the same linearization straight from an
:class:`~blocks.model.arm.ArmModel` (true plant) and a nominal model, for any joint
count, without a scenario: the computed-torque law and the observer written
as in the paper (Eq. 9-16, correct Eq. 16) and the chain rule on the forward
dynamics ``a(q, q', tau) = M^-1(q) (tau - h(q, q'))``.

With the reference held at ``q0`` (``u = Kp (q0 - q) - Kd q'``), a constant
disturbance ``d`` and an extra input torque ``w`` at the plant:

* controller ``tau = M^(q) u + h^(q, q') - d_hat``, observer ``d_hat = Y q' + z``;
* plant ``q'' = a(q, q', tau + d + w)``;
* observer ``z' = -Y M^-1 (tau + d_hat - h^) = -Y u`` (the law's terms cancel).

The partials of ``tau`` follow from those of the nominal forward dynamics:
``ID^(q, q', a^(q, q', f)) = f`` gives ``dID^/dq = -M^ da^/dq`` at the
acceleration ``u``.  So the state matrix of ``x = [q, q', z]`` is ::

    [ 0                  I                          0      ]
    [ a_q + M^-1 T_q     a_v + M^-1 T_v             -M^-1  ]
    [ Y Kp               Y Kd                       0      ]

with ``T_q = -M^ (a^_q + Kp)`` and ``T_v = -M^ (a^_v + Kd) - Y``; without the
observer the ``z`` block and ``Y`` drop out.  ``a_q, a_v`` are the
derivatives of ``M^-1 h`` that :func:`analysis.linear.arm_terms.acceleration_jacobians`
gives (exact from the model, or central differences).

Equilibrium: with the observer the arm rests at ``q0`` with
``d_hat = d + G^(q0) - G(q0)``; without it at the root of
``M^(q) Kp (q0 - q) + G^(q) - G(q) + d = 0`` (Newton from ``q0``).
"""
from __future__ import annotations

from dataclasses import dataclass

import control as ct
import numpy as np

from analysis.linear.arm_terms import FD_STEP, acceleration_jacobians, arm_model, joint_matrix, joint_vector
from blocks.model.arm import ArmModel

__all__ = ["ArmLoop", "ScaledArm", "arm_equilibrium", "arm_linearization", "arm_analytic_poles"]

# Newton on the resting position without observer stops when the residual (N m, N) is this small, relative to
# the largest force in it.
_REST_TOL = 1e-12


class ScaledArm(ArmModel):
    """An arm with every mass and inertia multiplied by ``factor``: ``M``, ``h`` and ``G`` all scale by it.

    Only the joint-last methods are scaled (what the analyses call); the row
    kernels and their parameters are the base arm's, so engines must not be given it.
    """

    def __init__(self, base: ArmModel, factor: float):
        if not (isinstance(factor, (int, float)) and np.isfinite(factor) and factor > 0):
            raise ValueError(f"inertia scale factor must be a finite number > 0, got {factor!r}")
        self.base, self.factor = arm_model(base, "base"), float(factor)
        self.joints, self.kernels, self.tool_kernels = base.joints, base.kernels, base.tool_kernels
        # what scaling M and h keeps of the base's answers: the joints M depends on, a constant G, the held poses
        self.inertia_depends_on, self.constant_gravity = base.inertia_depends_on, base.constant_gravity
        self.held_values = base.held_values

    def kernel_params(self):
        return self.base.kernel_params()

    def tool_params(self):
        return self.base.tool_params()

    def inertia(self, q):
        return self.factor * self.base.inertia(q)

    def bias(self, q, dq):
        return self.factor * self.base.bias(q, dq)

    def gravity_forces(self, q):
        return self.factor * self.base.gravity_forces(q)

    def forward_dynamics(self, q, dq, tau):
        # (a M)^-1 (tau - a h) = M^-1 (tau / a - h)
        return self.base.forward_dynamics(q, dq, np.asarray(tau, dtype=float) / self.factor)

    def inverse_dynamics(self, q, dq, ddq):
        return self.factor * self.base.inverse_dynamics(q, dq, ddq)


@dataclass(frozen=True, eq=False)
class ArmLoop:
    """Gains and models of a held loop (see the module docstring); gains as ``n x n`` matrices."""

    arm: ArmModel
    nominal: ArmModel
    kp: np.ndarray
    kd: np.ndarray
    Y: np.ndarray
    q0: np.ndarray
    d: np.ndarray

    @classmethod
    def make(cls, arm, kp, kd, Y, q0, d=None, nominal=None) -> ArmLoop:
        """Check and shape the arguments: gains scalar, ``n`` numbers or ``n x n``; ``q0``, ``d`` ``n`` numbers."""
        arm = arm_model(arm)
        nominal = arm if nominal is None else arm_model(nominal, "nominal")
        if nominal.joints != arm.joints:
            raise ValueError(f"nominal joints {nominal.joints.names} differ from the arm's {arm.joints.names}")
        n = arm.n
        d = np.zeros(n) if d is None else joint_vector(d, "d (constant disturbance, N m or N)", arm.joints)
        return cls(arm=arm, nominal=nominal, kp=joint_matrix(kp, "kp", n), kd=joint_matrix(kd, "kd", n),
                   Y=joint_matrix(Y, "Y", n), q0=joint_vector(q0, "q0", arm.joints), d=d)


def arm_equilibrium(loop: ArmLoop, observer: bool = True, max_iter: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Where the held arm rests (rad, m) and the observer state ``z`` there (N m, N; zeros without observer).

    Raises
    ------
    RuntimeError
        When Newton's method does not bring the resting residual below 1e-12 times the largest force in it
        (N m, N) in ``max_iter`` steps, or meets a singular Jacobian: no resting position near ``q0`` (the arm
        sags away).
    """
    arm, nom = loop.arm, loop.nominal
    if observer:
        d_hat = loop.d + nom.gravity_forces(loop.q0) - arm.gravity_forces(loop.q0)
        return loop.q0.copy(), d_hat

    def residual(q):
        # q: (n,) or a batch (k, n) of configurations (one call for all of a Jacobian's columns)
        pd = np.einsum("...ab,...b->...a", nom.inertia(q), (loop.q0 - q) @ loop.kp.T)
        return pd + nom.gravity_forces(q) - arm.gravity_forces(q) + loop.d

    q = loop.q0.copy()
    n = arm.n
    # rounding of the residual's terms: relative to the largest of them
    scale = 1.0 + np.max(np.abs(loop.d)) + np.max(np.abs(arm.gravity_forces(q))) + np.max(np.abs(nom.gravity_forces(q)))
    for _ in range(max_iter):
        r = residual(q)
        if np.max(np.abs(r)) <= _REST_TOL * scale:
            return q, np.zeros(n)
        E = FD_STEP * np.eye(n)
        jac = ((residual(q + E) - residual(q - E)) / (2 * FD_STEP)).T       # column k: along joint k
        try:
            step = np.linalg.solve(jac, r)
        except np.linalg.LinAlgError:       # Newton has wandered where the residual is flat: no rest near q0
            break
        q = q - step
        if np.max(np.abs(step)) <= 1e-14 * (1.0 + np.max(np.abs(q))) and np.max(np.abs(residual(q))) <= 1e-9 * scale:
            return q, np.zeros(n)           # converged to rounding
    raise RuntimeError(f"no resting position found without observer near q0 = {loop.q0.tolist()} "
                       f"(residual {np.max(np.abs(residual(q))):.3g} N m after {max_iter} Newton steps)")


def arm_linearization(arm, kp, kd, Y, q0, d=None, nominal=None, observer: bool = True) -> ct.StateSpace:
    """The held loop of an arm model linearized at its equilibrium (see the module docstring).

    Parameters
    ----------
    arm : ArmModel
        The true plant.
    kp, kd : scalar, n numbers or n x n
        Controller gains (1/s^2, 1/s).
    Y : scalar, n numbers or n x n
        Observer gain (kg m^2/s, kg/s); unused without the observer.
    q0 : array_like, shape (n,)
        Held configuration (rad, m).
    d : array_like, shape (n,), optional
        Constant disturbance (N m, N); default zero.
    nominal : ArmModel, optional
        The model of controller and observer; default the true one (perfect model).
    observer : bool
        With or without the disturbance observer.

    Returns
    -------
    control.StateSpace
        States ``q[i]``, ``dq[i]`` (deviations) and, with the observer, ``z[i]``;
        inputs ``w[i]`` (torque added at the plant, N m or N); outputs the tracking
        error ``e[i] = q0 - q`` and, with the observer, the estimation error
        ``e_d[i] = d + w - d_hat`` (deviations from rest).
    """
    loop = ArmLoop.make(arm, kp, kd, Y, q0, d, nominal)
    arm, nom, n = loop.arm, loop.nominal, loop.arm.n
    q_eq, _ = arm_equilibrium(loop, observer)
    rest = np.zeros(n)
    u_eq = loop.kp @ (loop.q0 - q_eq)
    a_q, a_v, M_inv = acceleration_jacobians(arm, q_eq, rest, arm.gravity_forces(q_eq))
    n_q, n_v, _ = acceleration_jacobians(nom, q_eq, rest, nom.inverse_dynamics(q_eq, rest, u_eq))
    M_nom = nom.inertia(q_eq)
    Y = loop.Y if observer else np.zeros((n, n))
    T_q = -M_nom @ (n_q + loop.kp)
    T_v = -M_nom @ (n_v + loop.kd) - Y
    I, Z = np.eye(n), np.zeros((n, n))
    rows = [[Z, I], [a_q + M_inv @ T_q, a_v + M_inv @ T_v]]
    B = np.vstack([Z, M_inv])
    C = np.hstack([-I, Z])
    D = Z
    states = [f"q[{i}]" for i in range(n)] + [f"dq[{i}]" for i in range(n)]
    outputs = [f"e[{i}]" for i in range(n)]
    if observer:
        rows = [rows[0] + [Z], rows[1] + [-M_inv], [loop.Y @ loop.kp, loop.Y @ loop.kd, Z]]
        B = np.vstack([B, Z])
        C = np.vstack([np.hstack([C, Z]), np.hstack([Z, -loop.Y, -I])])
        D = np.vstack([D, I])
        states += [f"z[{i}]" for i in range(n)]
        outputs += [f"e_d[{i}]" for i in range(n)]
    return ct.ss(np.block(rows), B, C, D, states=states, inputs=[f"w[{i}]" for i in range(n)], outputs=outputs,
                 name="dob_arm_linearized" if observer else "ctc_arm_linearized")


def arm_analytic_poles(kp, kd, Y, M, observer: bool = True) -> dict:
    """The analytic split on a perfect model: roots of ``s^2 + Kd_i s + Kp_i`` and eigenvalues of ``-Y M^-1``.

    Parameters
    ----------
    kp, kd, Y, M : array_like, shape (n, n)
        Diagonal PD gains, observer gain and the nominal inertia at the held configuration.

    Returns
    -------
    dict
        ``"plant"``: the ``2 n`` PD roots; with the observer ``"observer"``: the ``n`` eigenvalues (rad/s).
    """
    M = np.asarray(M, dtype=float)
    n = M.shape[-1]
    kp, kd = np.diag(joint_matrix(kp, "kp", n)), np.diag(joint_matrix(kd, "kd", n))
    out = {"plant": np.concatenate([np.roots([1.0, kd[i], kp[i]]) for i in range(n)]).astype(complex)}
    if observer:
        out["observer"] = np.linalg.eigvals(-joint_matrix(Y, "Y", n) @ np.linalg.inv(M)).astype(complex)
    return out
