"""Joint references of a redundant arm's tool-point path: the resolved-rate law, integrated, with its exact rates.

For an arm with more joints moving the tool point than the point's three coordinates (the UR5, the Panda),
the joint positions along a path ``p(t)`` (m) are the solution of

    q' = F(t, q) = J^+ (p' + K_p (p - f(q))) + (I - J^+ J) z(q),      z(q) = K_n (q_rest - q) (+ limits)

from the first sample's IK solution, with ``J = df/dq`` the tool point's Jacobian and
``J^+ = J^T (J J^T)^-1``:

* ``J^+ (p' + K_p e)`` moves the tool point along the path; the feedback ``K_p e`` on the task-space
  error ``e = p - f(q)`` (``K_p``, 1/s: ``task_gain``) makes ``e' = -K_p e``, so rounding and integration
  errors decay instead of adding up;
* ``(I - J^+ J) z`` moves only in the null space of ``J`` (the tool point does not feel
  it) and pulls the posture toward ``q_rest`` (default: the first sample's solution) with the rate
  ``K_n`` (1/s: ``posture_gain``).  Without it the minimum-norm motion of a closed path does not close:
  the posture drifts by a fixed amount on every loop.  With it the null-space motion stays bounded
  (the UR5 on a 5 cm circle, ten loops: 1.2e-3 rad from the start, settled within five loops, against
  1.0e-2 rad and growing without it and 9.6e-3 rad by per-sample least squares).  Within the last
  tenth of a joint's range (``LIMIT_MARGIN``) ``z`` also pushes the joint back, by ``K_l m d^2`` with
  ``d`` the depth into that margin ``m`` as a fraction of it (``K_l``, 1/s: ``limit_gain``): a term that
  is continuous with its first derivative, so ``q''`` stays exact.  A Panda carrying its hand 5.5 rad
  around its base needs it: without it joint 1 leaves its range (+-2.897 rad) after 5.2 rad; with it
  joint 3 takes over and joint 1 stays below 2.89 rad.

:func:`blocks.model.urdf.ik.joint_path` takes ``K_p = 10``, ``K_n = 1`` and ``K_l = 10`` per s by default: fast
enough to correct the start's residual within the first samples and to turn a joint back within its
margin, slow enough (against samples 0.05 s apart) to keep the law non-stiff for the explicit integrator.

``q`` comes from an 8th-order Runge-Kutta integrator with error control (``scipy``'s DOP853, ``rtol``,
``atol``) run sample interval by sample interval; between two samples ``p, p'`` are the quintic Hermite
polynomial of the samples' ``p, p', p''`` (exact for a quintic path such as the ``tool_path`` kind's
smoothstep segments when samples fall on the segment ends).  Each interval starts with the step the error
control last proposed, so a smooth path takes one DOP853 step (13 evaluations of ``f`` and ``J``) per sample
0.01 to 0.05 s apart, two where it bends harder: some three to five times the cost of per-sample least
squares.  The default tolerances (``rtol = 1e-9``, ``atol = 1e-11`` rad) leave the task-space residual near
1e-11 m, far below the quintic interpolation between samples (1e-6 rad at 0.05 s).  At
each sample ``q' = F(t, q)`` exactly and ``q''`` is its exact time derivative along the motion,

    q'' = dJ^+ v + J^+ v' + dP z + P z',      v = p' + K_p e,  z = z(q),  P = I - J^+ J,
    dJ^+ = P J'^T (J J^T)^-1 - J^+ J' J^+,    dP = -(dJ^+ J + J^+ J'),
    v' = p'' + K_p (p' - J q'),               z' = (dz/dq) q'  (= -K_n q' away from the joints' ends),

with ``J' = J'(q, q')`` (:func:`jacobian_rate`).  So ``q``, ``q'`` and ``q''`` are one
curve to the integrator's accuracy, and ``J q' = p'``, ``J q'' + J' q' = p''`` hold up to terms in ``e``.

Joint positions (rad, m), velocities (rad/s, m/s), accelerations (rad/s^2, m/s^2); points in the arm's
base frame (m).
"""
from __future__ import annotations

import numpy as np

from blocks.kernels.splines import quintic_hermite
from blocks.model.arm import ArmModel

__all__ = ["ResolvedRate", "moving_joints", "integrate_path", "jacobian_rate", "LIMIT_MARGIN"]

#: The part of a joint's range at either end (a fraction of the range) where the null-space term pushes back.
LIMIT_MARGIN = 0.1


def jacobian_rate(arm: ArmModel, q, dq) -> np.ndarray:
    """``J'(q, q')`` (3, n) by polarisation of ``c(v) = J'(q, v) v`` (exact: ``J'`` is symmetric in its directions)."""
    n = arm.n
    eye = np.eye(n)
    plus = arm.tool_acceleration_bias(np.broadcast_to(q, (n, n)), dq + eye)
    minus = arm.tool_acceleration_bias(np.broadcast_to(q, (n, n)), dq - eye)
    return ((plus - minus) / 4.0).T


class SingularJacobian(ArithmeticError):
    """``J J^T`` of the tool point is (near) singular: the path's velocity has no joint velocity."""


def moving_joints(arm: ArmModel, q) -> np.ndarray:
    """Which joints move the tool point at ``q``: the columns of ``J`` not zero (beyond rounding), shape (n,).

    A roll about an axis through the tool point (scope4's roll, the UR5's last wrist joint, the Panda's
    seventh joint for its hand's origin) never moves the point: its column is zero.
    """
    norms = np.linalg.norm(arm.tool_jacobian(np.asarray(q, dtype=float)), axis=0)
    return norms > 1e-9 * max(float(norms.max()), 1e-300)


def hermite5(h: float, s: float, y0, y1) -> tuple[np.ndarray, np.ndarray]:
    """Value and rate at ``s`` in [0, 1] of the quintic through ``y0 = (y, y', y'')`` and ``y1`` on ``h`` s.

    ``y0`` and ``y1`` are triples of arrays (the value, its rate per s and per s^2 at each end); the quintic is
    the tool path's own (:func:`blocks.kernels.splines.quintic_hermite`).
    """
    (a0, b0, c0), (a1, b1, c1) = y0, y1
    value, rate, _ = quintic_hermite(s, h, a0, b0 * h, c0 * (h * h), a1, b1 * h, c1 * (h * h))
    return value, rate


class ResolvedRate:
    """The right-hand side ``F(t, q)`` of the resolved-rate law and its time derivative (module docstring).

    Parameters
    ----------
    arm : ArmModel
    task_gain : float
        ``K_p`` (1/s), the rate at which a task-space error ``p - f(q)`` decays.
    posture_gain : float
        ``K_n`` (1/s), the rate of the null-space pull toward ``rest``; 0 gives the minimum-norm motion.
    rest : array_like, shape (n,)
        The posture ``q_rest`` the null-space term pulls toward (rad, m).
    min_sigma : float
        Smallest singular value of ``J`` (m/rad) accepted; below it :class:`SingularJacobian` is raised.
    """

    def __init__(self, arm: ArmModel, task_gain: float, posture_gain: float, rest, min_sigma: float,
                 limit_gain: float = 0.0) -> None:
        self.arm = arm
        self.kp = float(task_gain)
        self.kn = float(posture_gain)
        self.kl = float(limit_gain)
        self.rest = np.asarray(rest, dtype=float)
        self.min_sigma = float(min_sigma)
        lo, hi = np.array(arm.joints.limits, dtype=float).T
        bounded = np.isfinite(lo) & np.isfinite(hi)
        width = LIMIT_MARGIN * (np.where(bounded, hi, 1.0) - np.where(bounded, lo, 0.0))
        self.margin = np.where(bounded, width, np.inf)            # inf: an unbounded joint is never near an end
        self.inner_lo = np.where(bounded, np.where(bounded, lo, 0.0) + width, -np.inf)
        self.inner_hi = np.where(bounded, np.where(bounded, hi, 0.0) - width, np.inf)

    def posture(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The null-space term's ``z(q)`` (rad/s, m/s) and the diagonal of ``dz/dq`` (1/s).

        ``z = K_n (q_rest - q)`` plus, within ``LIMIT_MARGIN`` of a joint's range from either end, a push
        back ``K_l m (d_lo^2 - d_hi^2)`` with ``d`` the depth into the margin ``m`` as a fraction of it
        (continuous with its derivative, so ``q''`` stays exact and continuous).
        """
        into_hi = np.maximum(q - self.inner_hi, 0.0) / self.margin
        into_lo = np.maximum(self.inner_lo - q, 0.0) / self.margin
        m = np.where(np.isfinite(self.margin), self.margin, 0.0)
        z = self.kn * (self.rest - q) + self.kl * m * (into_lo ** 2 - into_hi ** 2)
        slope = -self.kn - 2.0 * self.kl * (into_lo + into_hi)
        return z, slope

    def _terms(self, q):
        J = self.arm.tool_jacobian(q)
        JJt = J @ J.T
        sigma2 = np.linalg.eigvalsh(JJt)[0]
        if not sigma2 >= self.min_sigma ** 2:
            raise SingularJacobian(f"smallest singular value of J {np.sqrt(max(sigma2, 0.0)):.3g}, below "
                                   f"{self.min_sigma:.3g}")
        pinv = np.linalg.solve(JJt, J).T          # J^T (J J^T)^-1 (J J^T is symmetric)
        return J, JJt, pinv

    def rate(self, q, p, dp) -> np.ndarray:
        """``q' = F`` (rad/s, m/s) at joint positions ``q`` on the path point ``p`` (m) moving at ``dp`` (m/s)."""
        J, _, pinv = self._terms(q)
        v = dp + self.kp * (p - self.arm.tool_position(q))
        z = self.posture(q)[0]
        return pinv @ v + z - pinv @ (J @ z)

    def rates(self, q, p, dp, ddp) -> tuple[np.ndarray, np.ndarray]:
        """``q'`` and its exact time derivative ``q''`` (rad/s^2, m/s^2) along the motion, at one sample."""
        J, JJt, pinv = self._terms(q)
        P = np.eye(self.arm.n) - pinv @ J
        e = p - self.arm.tool_position(q)
        v = dp + self.kp * e
        z, slope = self.posture(q)
        dq = pinv @ v + P @ z
        Jd = jacobian_rate(self.arm, q, dq)
        dpinv = P @ np.linalg.solve(JJt, Jd).T - pinv @ Jd @ pinv   # d/dt J^T (J J^T)^-1
        dP = -(dpinv @ J + pinv @ Jd)
        dv = ddp + self.kp * (dp - J @ dq)
        dz = slope * dq
        ddq = dpinv @ v + pinv @ dv + dP @ z + P @ dz
        return dq, ddq


def integrate_path(law: ResolvedRate, t, p, dp, ddp, q_start, *, rtol: float, atol: float, check):
    """``q, q', q''`` at the samples ``t`` (s) of the path ``p, p', p''`` from ``q_start`` by the law ``law``.

    Parameters
    ----------
    law : ResolvedRate
    t : numpy.ndarray, shape (N,)
    p, dp, ddp : numpy.ndarray, shape (N, 3)
    q_start : numpy.ndarray, shape (n,)
        Joint positions at ``t[0]`` (on the path).
    rtol, atol : float
        Tolerances of the DOP853 integrator (relative; absolute in rad, m).
    check : callable
        ``check(k, q)`` refuses sample ``k`` reached at ``q`` (residual, joint ranges) by raising.

    Returns
    -------
    q, dq, ddq : numpy.ndarray, shape (N, n)

    Raises
    ------
    SingularJacobian
        Carrying the sample index ``k`` (``err.sample``) where ``J`` became singular (in the interval up to it,
        or at it) and the last joint positions reached (``err.q``).
    """
    from scipy.integrate import DOP853

    N, n = t.size, law.arm.n
    q, dq, ddq = np.empty((N, n)), np.empty((N, n)), np.empty((N, n))
    q[0] = q_start
    step = np.inf               # the controller's last proposal starts the next interval: no step search per sample
    for k in range(N):
        if k > 0:
            h = t[k] - t[k - 1]
            ends = ((p[k - 1], dp[k - 1], ddp[k - 1]), (p[k], dp[k], ddp[k]))

            def rhs(tk, qk, t0=t[k - 1], h=h, ends=ends):
                point, velocity = hermite5(h, (tk - t0) / h, *ends)
                return law.rate(qk, point, velocity)

            try:
                solver = DOP853(rhs, t[k - 1], q[k - 1], t[k], rtol=rtol, atol=atol, first_step=min(step, h))
                while solver.status == "running":
                    solver.step()
                if solver.status != "finished":
                    raise SingularJacobian(f"the integrator stopped: {solver.message}")
            except SingularJacobian as err:
                err.sample, err.q = k, q[k - 1].copy()
                raise
            q[k] = solver.y
            step = solver.h_abs
        check(k, q[k])
        try:
            dq[k], ddq[k] = law.rates(q[k], p[k], dp[k], ddp[k])
        except SingularJacobian as err:
            err.sample, err.q = k, q[k].copy()
            raise
    return q, dq, ddq
