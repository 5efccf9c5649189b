"""A task-space path of the tool point turned into joint references ``q, q', q''`` for any arm.

The first sample's ``q`` comes from damped least-squares iterations
``q <- q + J^T (J J^T + lambda^2 I)^-1 (p - f(q))`` (:func:`solve_ik`), each projected onto the joints'
ranges, from ``q0`` until the residual ``|p - f(q)|`` stops falling; a residual above ``tol`` refuses the
point (time, point, residual).  The rest of the path depends on how many joints move the tool point
(:func:`~blocks.model.urdf.resolved_rate.moving_joints`: a roll about an axis through the point does not):

**At most three (a square** ``J`` **: scope4's yaw, pitch and insertion), method** ``"dls"``.  Every sample
is solved the same way, warm-started from the previous one, and

* ``q' = J^+ p'`` with ``J^+ = J^T (J J^T)^-1`` (``J^-1`` on the joints that move the point);
* ``q'' = d/dt (J^+ p') = J^+ (p'' - J' q') + (I - J^+ J) J'^T (J J^T)^-1 p'``, its exact derivative
  along the motion (the second term lies in the null space of ``J`` and vanishes here).

``q``, ``q'`` and ``q''`` are one curve exactly: the inverse is unique.

**More than three (a redundant arm: the UR5, the Panda), method** ``"resolved_rate"``.  Solving each sample
on its own would not give one curve: the fibre ``f(q) = p`` has a null-space direction, the iterations move
along ``J``'s row space and agree with ``J^+ p'`` only to first order in the sample spacing, and the posture
drifts a fixed amount on every round of a closed path.  Instead ``q(t)`` integrates the resolved-rate law
``q' = J^+ (p' + K_p (p - f(q))) + (I - J^+ J) K_n (q_rest - q)`` (8th-order Runge-Kutta with error
control), ``q'`` is that right-hand side and ``q''`` its exact time derivative; the task-space feedback
``K_p`` (``task_gain``, 1/s) holds the tool point on the path, the null-space term ``K_n``
(``posture_gain``, 1/s) pulls toward ``rest`` (default: the first sample's solution) so the null-space
motion stays bounded.  See :mod:`blocks.model.urdf.resolved_rate`.  A sample whose residual exceeds ``tol`` is
refused by time, point and residual, one beyond a joint's range by time, point and joint.  Within the
last tenth of a joint's range the null-space term also pushes the joint back (``limit_gain``, 1/s), which
does what the projected iterations' sliding along a joint's end does, without breaking the curve.

``J'`` is assembled from the arm's ``J'(q, v) v`` by polarisation: ``J'`` is symmetric in its two
directions (second derivatives of the tool position), so column ``i`` of ``J'(q, q')`` is
``(c(q' + e_i) - c(q' - e_i)) / 4`` with ``c(v) = J'(q, v) v``, exact up to rounding.

Joint positions (rad, m), velocities (rad/s, m/s), accelerations (rad/s^2, m/s^2); points in the
arm's base frame (m).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blocks.model.arm import ArmModel, UnreachableError
from blocks.model.urdf.resolved_rate import ResolvedRate, SingularJacobian, integrate_path, jacobian_rate, moving_joints

__all__ = ["IKUnreachableError", "JointPath", "solve_ik", "joint_path", "jacobian_rate"]


class IKUnreachableError(UnreachableError):
    """A point of a task-space path is out of reach (or at a singularity, or beyond a joint's range)."""


@dataclass(frozen=True)
class JointPath:
    """Joint references of a task-space path.

    Attributes
    ----------
    t : numpy.ndarray
        Sample times (s), shape (N,).
    q, dq, ddq : numpy.ndarray
        Joint positions, velocities and accelerations, shape (N, n).
    residual : numpy.ndarray
        ``|p - f(q)|`` at each sample (m), shape (N,).
    method : str
        How ``q`` was found: ``"dls"`` (damped least squares per sample) or ``"resolved_rate"`` (the
        integrated resolved-rate law).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    residual: np.ndarray
    method: str = "dls"


#: Halvings of a damped least-squares step that does not lower the residual, before the point is taken as the closest.
_HALVINGS = 20


def _start(arm: ArmModel, q0) -> np.ndarray:
    if q0 is None:          # the middle of each finite range, else 0
        return np.array([0.5 * (lo + hi) if np.isfinite(lo) and np.isfinite(hi) else 0.0
                         for lo, hi in arm.joints.limits])
    q0 = np.asarray(q0, dtype=float)
    if q0.shape != (arm.n,) or not np.all(np.isfinite(q0)):
        raise ValueError(f"q0 must be {arm.n} finite joint positions ({', '.join(arm.joints.names)}), got {q0!r}")
    return q0


def solve_ik(arm: ArmModel, point, q0=None, *, damping: float = 1e-3, tol: float = 1e-9,
             max_iter: int = 200, t: float | None = None) -> tuple[np.ndarray, float]:
    """Joint positions that put the tool point at ``point`` (m), by damped least squares from ``q0``.

    Parameters
    ----------
    arm : ArmModel
    point : array_like, shape (3,)
        Target in the base frame (m).
    q0 : array_like, shape (n,), optional
        Starting joint positions (default: the middle of each joint's range, 0 where unbounded).
    damping : float
        ``lambda`` of the damped least-squares step (m); larger is more robust near singularities.
    tol : float
        The largest residual accepted (m).
    max_iter : int
        Iterations at most.
    t : float, optional
        Time of the point on a path, for the error message.

    Returns
    -------
    q : numpy.ndarray, shape (n,)
    residual : float
        ``|point - f(q)|`` (m).

    Raises
    ------
    IKUnreachableError
        If the residual stays above ``tol`` (the message gives the time, the point and the residual), or the
        solution leaves a joint's range (the message names the joint).
    """
    for name, value in (("damping", damping), ("tol", tol)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0 (m), got {value!r}")
    point = np.asarray(point, dtype=float)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise ValueError(f"point must be 3 finite coordinates (m), got {point!r}")
    lo, hi = np.array(arm.joints.limits).T
    q = np.clip(_start(arm, q0), lo, hi)
    lam2 = damping * damping
    err = point - arm.tool_position(q)
    res = float(np.linalg.norm(err))
    for _ in range(max_iter):
        if res <= 1e-3 * tol:
            break
        J = arm.tool_jacobian(q)
        step = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(3), err)
        q_new = np.clip(q + step, lo, hi)        # projected onto the joints' ranges
        err_new = point - arm.tool_position(q_new)
        res_new = float(np.linalg.norm(err_new))
        halvings = 0
        # a step that overshoots far from the point (a large move, a curved reach) is halved until it helps; on
        # the point (res <= tol) no progress means the rounding is reached
        while not res_new < res and res > tol and halvings < _HALVINGS:
            step, halvings = 0.5 * step, halvings + 1
            q_new = np.clip(q + step, lo, hi)
            err_new = point - arm.tool_position(q_new)
            res_new = float(np.linalg.norm(err_new))
        if not res_new < res:      # no more progress: the closest point (or rounding) is reached
            break
        q, err, res = q_new, err_new, res_new
    when = "" if t is None else f" at t = {t:.6g} s"
    where = f"({point[0]:.6g}, {point[1]:.6g}, {point[2]:.6g}) m"
    if res > tol:
        ends = [name for name, v, a, b in zip(arm.joints.names, q, lo, hi) if v == a or v == b]
        why = f"; at the end of their ranges: {', '.join(ends)}" if ends else ""
        raise IKUnreachableError(f"task-space point {where}{when} is not reachable by the tool point: the closest "
                                 f"solution found misses it by {res:.3g} m (tolerance {tol:.3g} m){why}")
    outside = arm.joints.outside_limits(q)
    if outside:
        raise IKUnreachableError(f"task-space point {where}{when} needs joint positions outside the arm's ranges: "
                                 f"{outside}")
    return q, res


def _derivatives(arm: ArmModel, q, dp, ddp, t, min_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    J = arm.tool_jacobian(q)
    JJt = J @ J.T
    sigma = float(np.sqrt(max(np.linalg.eigvalsh(JJt)[0], 0.0)))
    if sigma < min_sigma:
        raise IKUnreachableError(f"at t = {t:.6g} s the arm is at a singularity for the tool point (smallest "
                                 f"singular value of J {sigma:.3g}, below {min_sigma:.3g}); the path's velocity has "
                                 "no joint velocity")
    pinv = J.T @ np.linalg.inv(JJt)
    dq = pinv @ dp
    Jdot = jacobian_rate(arm, q, dq)
    ddq = pinv @ (ddp - Jdot @ dq) + (np.eye(arm.n) - pinv @ J) @ (Jdot.T @ np.linalg.solve(JJt, dp))
    return dq, ddq


_METHODS = ("auto", "dls", "resolved_rate")


def _check_options(arm: ArmModel, method, task_gain, posture_gain, limit_gain, rest, rtol, atol):
    if method not in _METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, _METHODS))}, got {method!r}")
    for name, value, unit, low in (("task_gain", task_gain, "1/s", 0.0), ("posture_gain", posture_gain, "1/s", 0.0),
                                   ("limit_gain", limit_gain, "1/s", 0.0), ("rtol", rtol, "", None),
                                   ("atol", atol, "rad, m", None)):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and \
            (value >= low if low is not None else value > 0)
        if not ok:
            allowed = f">= {low:g}" if low is not None else "> 0"
            units = f" ({unit})" if unit else ""
            raise ValueError(f"{name} must be a finite number {allowed}{units}, got {value!r}")
    if rest is not None:
        rest = np.asarray(rest, dtype=float)
        if rest.shape != (arm.n,) or not np.all(np.isfinite(rest)):
            raise ValueError(f"rest must be {arm.n} finite joint positions ({', '.join(arm.joints.names)}), "
                             f"got {rest!r}")
    return rest


def _where(point) -> str:
    return f"({point[0]:.6g}, {point[1]:.6g}, {point[2]:.6g}) m"


def joint_path(arm: ArmModel, t, p, dp, ddp, q0=None, *, damping: float = 1e-3, tol: float = 1e-9,
               max_iter: int = 200, min_sigma: float = 1e-6, method: str = "auto", task_gain: float = 10.0,
               posture_gain: float = 1.0, rest=None, limit_gain: float = 10.0, rtol: float = 1e-9,
               atol: float = 1e-11, on_sample=None) -> JointPath:
    """Joint references ``q, q', q''`` of a sampled task-space path of the tool point.

    Parameters
    ----------
    arm : ArmModel
    t : array_like, shape (N,)
        Sample times (s), increasing.
    p, dp, ddp : array_like, shape (N, 3)
        Tool-point positions (m), velocities (m/s) and accelerations (m/s^2) in the base frame.
    q0 : array_like, shape (n,), optional
        Start of the first sample's iterations (default: the middle of the joints' ranges).
    damping, tol, max_iter
        See :func:`solve_ik`; ``tol`` (m) also bounds the residual of every sample of ``"resolved_rate"``.
    min_sigma : float
        Smallest singular value of ``J`` (m/rad) accepted for the velocity and acceleration.
    method : {"auto", "dls", "resolved_rate"}
        ``"dls"``: damped least squares at every sample, ``q' = J^+ p'`` (one curve exactly when at most
        three joints move the tool point; for more, the null space drifts).  ``"resolved_rate"``: the
        integrated resolved-rate law of :mod:`blocks.model.urdf.resolved_rate` (one curve to the integrator's
        accuracy, bounded null-space motion).  ``"auto"`` (default): ``"resolved_rate"`` when more than
        three joints move the tool point at the first sample (:func:`~blocks.model.urdf.resolved_rate.moving_joints`),
        else ``"dls"``.
    task_gain : float
        ``K_p`` (1/s) of ``"resolved_rate"``: a task-space error decays as ``exp(-K_p t)``.
    posture_gain : float
        ``K_n`` (1/s) of ``"resolved_rate"``: the null-space pull toward ``rest``; 0 gives the minimum-norm
        motion (which drifts on closed paths).
    rest : array_like, shape (n,), optional
        Posture (rad, m) the null-space term pulls toward (default: the first sample's solution).
    limit_gain : float
        ``K_l`` (1/s) of ``"resolved_rate"``: within the last tenth of a joint's range
        (:data:`~blocks.model.urdf.resolved_rate.LIMIT_MARGIN`) the null-space term pushes the joint back, at up to
        ``K_l`` times a tenth of the range per s at the end itself; 0 turns it off.
    rtol, atol : float
        Relative and absolute (rad, m) tolerances of the ``"resolved_rate"`` integrator (DOP853).
    on_sample : callable, optional
        ``on_sample(k)`` after sample ``k`` is solved (progress, a wall-time budget: an exception it raises
        stops the solve).

    Returns
    -------
    JointPath

    Raises
    ------
    IKUnreachableError
        At the first sample out of reach, beyond a joint's range or at a singularity (time, point, residual).
    """
    t = np.asarray(t, dtype=float)
    arrays = {}
    for name, value in (("p", p), ("dp", dp), ("ddp", ddp)):
        arr = np.asarray(value, dtype=float)
        if arr.shape != t.shape + (3,) or not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite with shape {t.shape + (3,)} (one point per time), "
                             f"got shape {arr.shape}")
        arrays[name] = arr
    if t.ndim != 1 or t.size == 0 or np.any(np.diff(t) <= 0):
        raise ValueError(f"t must be a non-empty increasing 1-D array of times (s), got shape {t.shape}")
    rest = _check_options(arm, method, task_gain, posture_gain, limit_gain, rest, rtol, atol)
    N, n = t.size, arm.n
    first = solve_ik(arm, arrays["p"][0], q0, damping=damping, tol=tol, max_iter=max_iter, t=t[0])
    if method == "auto":
        method = "resolved_rate" if int(np.count_nonzero(moving_joints(arm, first[0]))) > 3 else "dls"
    if method == "resolved_rate":
        return _integrated(arm, t, arrays, first, damping=damping, tol=tol, max_iter=max_iter, min_sigma=min_sigma,
                           task_gain=task_gain, posture_gain=posture_gain, limit_gain=limit_gain, rest=rest,
                           rtol=rtol, atol=atol, on_sample=on_sample)
    q, dq, ddq, res = np.empty((N, n)), np.empty((N, n)), np.empty((N, n)), np.empty(N)
    guess = q0
    for k in range(N):
        q[k], res[k] = first if k == 0 else solve_ik(arm, arrays["p"][k], guess, damping=damping, tol=tol,
                                                     max_iter=max_iter, t=t[k])
        dq[k], ddq[k] = _derivatives(arm, q[k], arrays["dp"][k], arrays["ddp"][k], t[k], min_sigma)
        guess = q[k]
        if on_sample is not None:
            on_sample(k)
    return JointPath(t=t, q=q, dq=dq, ddq=ddq, residual=res, method="dls")


def _integrated(arm: ArmModel, t, arrays, first, *, damping, tol, max_iter, min_sigma, task_gain, posture_gain,
                limit_gain, rest, rtol, atol, on_sample=None) -> JointPath:
    """``method="resolved_rate"`` of :func:`joint_path`: the integrated law, refusals by time, point and joint."""
    p, dp, ddp = arrays["p"], arrays["dp"], arrays["ddp"]
    law = ResolvedRate(arm, task_gain, posture_gain, first[0] if rest is None else rest, min_sigma, limit_gain)
    res = np.empty(t.size)

    def check(k, q):
        res[k] = float(np.linalg.norm(p[k] - arm.tool_position(q)))
        if res[k] > tol:
            # an unreachable point is refused as solve_ik refuses it; a reachable one the integration lost
            solve_ik(arm, p[k], q, damping=damping, tol=tol, max_iter=max_iter, t=t[k])
            raise IKUnreachableError(f"task-space point {_where(p[k])} at t = {t[k]:.6g} s: the resolved-rate "
                                     f"integration misses it by {res[k]:.3g} m (tolerance {tol:.3g} m); a smaller "
                                     "rtol or a larger task_gain keeps it on the path")
        outside = arm.joints.outside_limits(q)
        if outside:
            raise IKUnreachableError(f"task-space point {_where(p[k])} at t = {t[k]:.6g} s needs joint positions "
                                     f"outside the arm's ranges: {outside} (the null-space push back from the "
                                     "ends, limit_gain, could not hold it: another q0 or rest, or method='dls', "
                                     "may keep the joints in range)")
        if on_sample is not None:
            on_sample(k)

    try:
        q, dq, ddq = integrate_path(law, t, p, dp, ddp, first[0], rtol=rtol, atol=atol, check=check)
    except SingularJacobian as err:
        k = err.sample
        solve_ik(arm, p[k], err.q, damping=damping, tol=tol, max_iter=max_iter, t=t[k])
        when = f"at t = {t[k]:.6g} s" if k == 0 else f"between t = {t[k - 1]:.6g} s and {t[k]:.6g} s"
        raise IKUnreachableError(f"{when} (point {_where(p[k])}) the arm is at a singularity for the tool point "
                                 f"({err}); the path's velocity has no joint velocity") from None
    return JointPath(t=t, q=q, dq=dq, ddq=ddq, residual=res, method="resolved_rate")
