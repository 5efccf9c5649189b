"""The blocks of the paper's Figure 2 as python-control nonlinear I/O systems.

Every factory returns a :class:`control.NonlinearIOSystem` whose signals use
the names of the design (``q[i]``, ``dq[i]``, ``q_ref[i]``, ``tau[i]``,
``d_hat[i]``, ``tau_dis[i]``, ...), so that :func:`control.interconnect` wires
them by name.  Parameters are bound in closures rather than passed through
python-control's ``params`` because ``interconnect`` merges equal parameter
names of different blocks (the true plant and the nominal model would collide).

Each block also records which of its inputs reach its outputs directly in the
attribute ``feedthrough`` (a frozenset of input names).  The fast simulation
path uses it to order the blocks without iterating to a fixed point.

The output functions here also accept column-stacked signals: ``t`` of
shape (T,), ``x`` of shape (nstates, T) and ``u`` of shape (ninputs, T) give
outputs of shape (noutputs, T).  Such blocks carry ``columnwise = True`` (the
trajectory and sensor blocks when the object they wrap evaluates many times
at once), and the fast path then evaluates a whole time grid in one pass per
block instead of one pass per grid point.

The controller and the observer share one evaluation of the nominal model per
right-hand-side call through :mod:`blocks.model_cache` (values
remembered at their last arguments).  The plant declares in ``state_outputs``
that its outputs ``q[i]``, ``dq[i]`` are its states, so the fast path reads
them from the state and evaluates the disturbance once, in the plant's update.
"""
from __future__ import annotations

import control as ct
import numpy as np

from .disturbances import DisturbanceSpec, external_disturbance
from .dynamics import coriolis_vector, gravity, inertia
from .model_cache import nominal_terms
from .noise import MeasurementNoise
from .joints import RRPR_JOINTS
from .parameters import RobotParameters

__all__ = ["plant", "controller", "observer", "trajectory_block", "sensor", "gain_matrix", "signal_names",
           "OBSERVER_VARIANTS", "JOINTS"]

JOINTS = RRPR_JOINTS.count
OBSERVER_VARIANTS = ("correct", "paper-eq16")


def signal_names(prefix: str) -> list[str]:
    """The four per-joint signal names ``prefix[0]`` .. ``prefix[3]``."""
    return [f"{prefix}[{i}]" for i in range(JOINTS)]


def _declare_feedthrough(sys: ct.NonlinearIOSystem, inputs, columnwise: bool = True) -> ct.NonlinearIOSystem:
    sys.feedthrough = frozenset(inputs)
    sys.columnwise = columnwise     # see the module docstring
    return sys


def gain_matrix(value, name: str, allow_matrix: bool = False) -> np.ndarray:
    """A 4x4 gain from a scalar, a 4-vector (diagonal) or, if allowed, a 4x4 matrix.

    Raises
    ------
    ValueError
        On a wrong shape or a non-finite entry, naming ``name``.
    """
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"gain '{name}' must be finite, got {value!r}")
    if arr.ndim == 0:
        return float(arr) * np.eye(JOINTS)
    if arr.shape == (JOINTS,):
        return np.diag(arr)
    if arr.shape == (JOINTS, JOINTS) and (allow_matrix or np.count_nonzero(arr - np.diag(np.diag(arr))) == 0):
        return arr.copy()
    allowed = "a scalar, 4 numbers" + (" or a 4x4 matrix" if allow_matrix else " or a diagonal 4x4 matrix")
    raise ValueError(f"gain '{name}' must be {allowed}, got shape {arr.shape}")


def plant(params: RobotParameters, disturbance: DisturbanceSpec | None = None,
          name: str = "plant") -> ct.NonlinearIOSystem:
    """The true arm, Eq. 1, with the external disturbance models acting inside it.

    States ``q[i]``, ``dq[i]``; input ``tau[i]`` (N m, N); outputs ``q[i]``,
    ``dq[i]`` and the external disturbance ``tau_dis[i]`` acting at that instant.

    Parameters
    ----------
    params : RobotParameters
        True arm parameters.
    disturbance : DisturbanceSpec, optional
        External disturbance models (default: the paper's Eq. 4).
    """
    spec = DisturbanceSpec() if disturbance is None else disturbance

    def update(t, x, u, _params):
        q, dq = x[:JOINTS], x[JOINTS:]
        rhs = u + external_disturbance(t, q, dq, spec, params) - coriolis_vector(q, dq, params) - gravity(q, params)
        return np.concatenate([dq, np.linalg.solve(inertia(q, params), rhs)])

    def output(t, x, u, _params):
        return np.concatenate([x, external_disturbance(t, x[:JOINTS].T, x[JOINTS:].T, spec, params).T])

    sys = ct.nlsys(update, output, name=name, inputs=signal_names("tau"),
                   states=signal_names("q") + signal_names("dq"),
                   outputs=signal_names("q") + signal_names("dq") + signal_names("tau_dis"))
    sys.robot_parameters = params
    sys.disturbance_spec = spec
    # q and dq are the states themselves: the fast path reads them from x instead of calling output
    sys.state_outputs = {name: name for name in signal_names("q") + signal_names("dq")}
    return _declare_feedthrough(sys, ())


def controller(nominal: RobotParameters, kp, kd, use_observer: bool = True,
               measured: str = "", name: str = "controller") -> ct.NonlinearIOSystem:
    """Computed-torque control, Eq. 11, on the nominal model.

    ``tau = M^(q)(q_ref'' + Kd e' + Kp e) + N^(q, q') q' + G^(q) - d_hat``,
    with ``e = q_ref - q``.  Without the observer ``d_hat = 0`` and the block
    has no ``d_hat`` input.

    Parameters
    ----------
    nominal : RobotParameters
        The model the controller believes in.
    kp, kd : float, 4 floats
        Proportional (1/s^2) and derivative (1/s) gains, scalar or per joint.
    use_observer : bool
        Whether the block takes ``d_hat[i]`` from the observer.
    measured : str
        Suffix of the measured signals it reads, ``""`` for ``q[i]``/``dq[i]``
        or ``"_meas"`` for ``q_meas[i]``/``dq_meas[i]`` from a sensor block.
    """
    Kp = gain_matrix(kp, "kp")
    Kd = gain_matrix(kd, "kd")
    for gain, label in ((Kp, "kp"), (Kd, "kd")):
        if np.any(np.diag(gain) <= 0):
            raise ValueError(f"gain '{label}' must be > 0 on every joint, got {np.diag(gain).tolist()}")
    n = JOINTS
    inputs = [name for prefix in ("q_ref", "dq_ref", "ddq_ref", "q" + measured, "dq" + measured)
              for name in signal_names(prefix)]
    if use_observer:
        inputs += signal_names("d_hat")
    model = nominal_terms(nominal)      # shared with an observer on the same nominal model

    def output(t, x, u, _params):
        q_ref, dq_ref, ddq_ref = u[:n], u[n:2 * n], u[2 * n:3 * n]
        q, dq = u[3 * n:4 * n], u[4 * n:5 * n]
        v = ddq_ref + Kd @ (dq_ref - dq) + Kp @ (q_ref - q)
        if u.ndim == 1:
            M, h = model(q, dq)
            tau = M @ v + h
        else:                                   # columns (T on the last axis) for a grid pass
            M, h = model(q.T, dq.T)
            tau = np.einsum("kij,jk->ik", M, v) + h.T
        return tau - u[5 * n:6 * n] if use_observer else tau

    sys = ct.nlsys(None, output, name=name, inputs=inputs, outputs=signal_names("tau"))
    sys.gains = {"kp": Kp, "kd": Kd}
    return _declare_feedthrough(sys, inputs)


def observer(nominal: RobotParameters, gain, variant: str = "correct", measured: str = "",
             name: str = "observer") -> ct.NonlinearIOSystem:
    """Nonlinear disturbance observer (Chen et al. 2000; Mohammadi et al. 2013).

    ``d_hat = Y q' + z``, ``z' = -Y M^-1(q)(tau + d_hat - N(q, q') q' - G(q))``,
    which gives ``d_hat' = Y M^-1 (d - d_hat)`` on a perfect model.  With
    ``variant="paper-eq16"`` the update carries the extra ``- Y q'`` term of
    the paper's printed Eq. 16, which biases the estimate whenever the arm moves.

    States ``z[i]``; inputs ``tau[i]``, ``q[i]``, ``dq[i]``; output ``d_hat[i]``.

    Parameters
    ----------
    nominal : RobotParameters
        The model the observer believes in.
    gain : float, 4 floats or 4x4
        Observer gain ``Y`` (kg m^2/s and kg/s entries); the paper's "K3 = 10 I".
    variant : {"correct", "paper-eq16"}
    measured : str
        Suffix of the measured signals it reads (see :func:`controller`).
    """
    if variant not in OBSERVER_VARIANTS:
        raise ValueError(f"observer variant {variant!r} is unknown; choose from {list(OBSERVER_VARIANTS)}")
    Y = gain_matrix(gain, "observer", allow_matrix=True)
    n = JOINTS
    printed_eq16 = variant == "paper-eq16"
    q_in, dq_in = signal_names("q" + measured), signal_names("dq" + measured)
    model = nominal_terms(nominal)      # shared with a controller on the same nominal model

    def update(t, z, u, _params):
        tau, q, dq = u[:n], u[n:2 * n], u[2 * n:3 * n]
        M, h = model(q, dq)
        Y_dq = Y @ dq
        dz = -Y @ np.linalg.solve(M, tau + (Y_dq + z) - h)
        return dz - Y_dq if printed_eq16 else dz

    def output(t, z, u, _params):
        return Y @ u[2 * n:3 * n] + z

    sys = ct.nlsys(update, output, name=name, inputs=signal_names("tau") + q_in + dq_in,
                   states=signal_names("z"), outputs=signal_names("d_hat"))
    sys.gain = Y
    sys.variant = variant
    return _declare_feedthrough(sys, dq_in)


def trajectory_block(trajectory, name: str = "trajectory") -> ct.NonlinearIOSystem:
    """A source block with outputs ``q_ref[i]``, ``dq_ref[i]``, ``ddq_ref[i]``.

    Parameters
    ----------
    trajectory : object
        Anything with ``evaluate(t) -> (q, dq, ddq)`` returning three 4-vectors
        for a scalar time ``t`` (s) (see :mod:`blocks.trajectory`).
        When it also has ``evaluate_stacked(t)``, returning the three side by
        side with shape ``np.shape(t) + (12,)`` for a scalar or a (T,) array of
        times, that is used instead and the block is ``columnwise``.
    """
    stacked = getattr(trajectory, "evaluate_stacked", None)

    def output(t, x, u, _params):
        if stacked is not None:
            refs = stacked(t)
            return refs if refs.ndim == 1 else refs.T
        return np.concatenate(trajectory.evaluate(t))

    sys = ct.nlsys(None, output, name=name, inputs=0,
                   outputs=signal_names("q_ref") + signal_names("dq_ref") + signal_names("ddq_ref"))
    sys.trajectory = trajectory
    return _declare_feedthrough(sys, (), columnwise=stacked is not None)


def sensor(noise, name: str = "sensor") -> ct.NonlinearIOSystem:
    """Measurement of ``q``, ``dq`` with additive noise: outputs ``q_meas[i]``, ``dq_meas[i]``.

    Parameters
    ----------
    noise : object
        Anything with ``sample(t) -> (n_q, n_dq)`` returning two 4-vectors
        (see :class:`blocks.noise.MeasurementNoise`, which also takes a
        (T,) array of times and makes the block ``columnwise``).
    """
    n = JOINTS

    def output(t, x, u, _params):
        n_q, n_dq = noise.sample(t)
        return np.concatenate([u[:n] + n_q.T, u[n:] + n_dq.T])

    inputs = signal_names("q") + signal_names("dq")
    sys = ct.nlsys(None, output, name=name, inputs=inputs, outputs=signal_names("q_meas") + signal_names("dq_meas"))
    # a grid of times at once is part of MeasurementNoise.sample's contract, not of any object with sample(t)
    return _declare_feedthrough(sys, inputs, columnwise=getattr(type(noise), "sample", None) is MeasurementNoise.sample)
