"""The blocks of the paper's Figure 2 as python-control nonlinear I/O systems.

Every factory returns a :class:`~blocks.diagram.contract.Block` (a
:class:`control.NonlinearIOSystem`) whose signals use the names of the design
(``q[i]``, ``dq[i]``, ``q_ref[i]``, ``tau[i]``, ``d_hat[i]``, ``tau_dis[i]``,
...), so that :func:`control.interconnect` wires them by name.  Parameters
are bound when the block is made rather than passed through python-control's
``params``, because ``interconnect`` merges equal parameter names of
different blocks (the true plant and the nominal model would collide).

The plant, controller, observer and sensor are *kernel blocks*: their update
and output functions are the block kernels below, which slice the stacked
input and call the laws of :mod:`blocks.kernels`, and their contract carries
those kernels with their parameters so that an engine can call them
directly, over a time grid or over a batch.  The trajectory block is a
kernel block too when its path has kernels (the paths of
:mod:`blocks.diagram.trajectory` do); it wraps any other path object.

Any arm
-------
The factories take any :class:`~blocks.model.arm.ArmModel`: signal names and sizes come from ``arm.joints``, the numbers from
``arm.kernel_params()``, and the block kernels below take the arm's row
kernels first (``model``, :class:`~blocks.kernels.model.ArmKernels`): a
block calls them with its arm's (:func:`~blocks.kernels.model.with_arm`).
"""
from __future__ import annotations

import numpy as np

from blocks.diagram.contract import Block, BlockContract, Kernels, joint_states, kernel_block
from blocks.diagram.gains import OBSERVER_VARIANTS, validated_gain
from blocks.kernels import (
    computed_torque,
    disturbance_params,
    external_disturbance,
    observer_estimate,
    observer_rate,
)
from blocks.kernels.model import with_arm
from blocks.kernels.noise import sampled_noise
from blocks.model.arm import ArmModel
from blocks.model.disturbances import DisturbanceSpec
from blocks.model.noise import MeasurementNoise

__all__ = ["plant", "controller", "observer", "trajectory_block", "sensor", "signal_names", "OBSERVER_VARIANTS",
           "plant_update", "plant_output", "controller_output", "controller_output_with_estimate",
           "observer_update", "observer_output", "sensor_output"]


def signal_names(prefix: str, params: ArmModel | None = None) -> list[str]:
    """The per-joint signal names ``prefix[0]`` .. ``prefix[n-1]`` of the arm ``params`` (default: the default
    scenario's arm, :func:`blocks.scenarios.scenario.default_arm`)."""
    if params is None:
        from blocks.model.default import default_arm
        params = default_arm()
    return params.joints.signal_names(prefix)


def _arm(value, name: str) -> ArmModel:
    if not isinstance(value, ArmModel):
        raise TypeError(f"{name} must be an arm model (blocks.model.arm.ArmModel, e.g. scenario.robot or "
                        f"blocks.model.default.default_arm()), got {type(value).__name__} {value!r:.80}")
    return value


# --------------------------------------------------------------------------------------------------------------
# Block kernels: (model, t, x, u, *params) -> rows, in the layout of blocks.kernels; a block passes its arm's
# kernels as ``model`` (blocks.kernels.model.with_arm), the engines the rest
# --------------------------------------------------------------------------------------------------------------
def plant_update(model, t, x, u, k, disturbance):
    """Plant states ``[q; dq]`` -> ``[dq; q'']`` under torque ``u`` plus the external disturbance (Eq. 1)."""
    n = x.shape[0] // 2
    q, dq = x[:n], x[n:]
    return np.concatenate((dq, model.plant_acceleration(k, q, dq,
                                                        u + external_disturbance(model, t, q, dq, disturbance))))


def plant_output(model, t, x, u, k, disturbance):
    """Plant outputs ``[q; dq; tau_dis]``: the states and the external disturbance acting now."""
    n = x.shape[0] // 2
    return np.concatenate((x, external_disturbance(model, t, x[:n], x[n:], disturbance)))


def controller_output(model, t, x, u, k, kp, kd):
    """Eq. 11 without an estimate: inputs ``[q_ref; dq_ref; ddq_ref; q; dq]``."""
    n = kp.shape[0]
    return computed_torque(model, k, kp, kd, u[3 * n:4 * n], u[4 * n:5 * n], u[:n], u[n:2 * n], u[2 * n:3 * n],
                           0.0)


def controller_output_with_estimate(model, t, x, u, k, kp, kd):
    """Eq. 11: inputs ``[q_ref; dq_ref; ddq_ref; q; dq; d_hat]``."""
    n = kp.shape[0]
    return computed_torque(model, k, kp, kd, u[3 * n:4 * n], u[4 * n:5 * n], u[:n], u[n:2 * n], u[2 * n:3 * n],
                           u[5 * n:6 * n])


def observer_update(model, t, z, u, k, gain, eq16_weight):
    """Observer state derivative: inputs ``[tau; q; dq]``, state ``z``."""
    n = z.shape[0]
    return observer_rate(model, k, gain, eq16_weight, u[n:2 * n], u[2 * n:3 * n], u[:n], z)


def observer_output(model, t, z, u, k, gain, eq16_weight):
    """The estimate ``d_hat = Y dq + z``."""
    n = z.shape[0]
    return observer_estimate(gain, u[2 * n:3 * n], z)


def sensor_output(t, x, u, table, period):
    """Measured ``[q; dq]``: the true signals plus the sampled noise at ``t``."""
    return u + sampled_noise(t, table, period)


# --------------------------------------------------------------------------------------------------------------
# Factories
# --------------------------------------------------------------------------------------------------------------
def plant(params: ArmModel, disturbance: DisturbanceSpec | None = None, name: str = "plant") -> Block:
    """The true arm, Eq. 1, with the external disturbance models acting inside it.

    States ``q[i]``, ``dq[i]``; input ``tau[i]`` (N m, N); outputs ``q[i]``,
    ``dq[i]`` and the external disturbance ``tau_dis[i]`` acting at that instant.
    The outputs ``q[i]``, ``dq[i]`` are declared copies of the states.

    Parameters
    ----------
    params : ArmModel
        The true arm (any :class:`~blocks.model.arm.ArmModel`).
    disturbance : DisturbanceSpec, optional
        External disturbance models (default: the paper's Eq. 4, for the RRPR only; see
        :class:`~blocks.model.disturbances.DisturbanceSpec` for other arms).

    Raises
    ------
    ValueError
        If the disturbance does not fit the arm (a list of the wrong length, a model of the RRPR only).
    """
    params = _arm(params, "params")
    spec = DisturbanceSpec() if disturbance is None else disturbance
    spec.check_arm(params)
    states = signal_names("q", params) + signal_names("dq", params)
    block = kernel_block(Kernels((params.kernel_params(), disturbance_params(spec, params)),
                                 with_arm(plant_output, params), with_arm(plant_update, params)),
                         name=name, inputs=signal_names("tau", params), states=states,
                         outputs=states + signal_names("tau_dis", params), state_outputs=zip(states, states),
                         state_meanings=joint_states(signal_names("q", params), "position")
                         + joint_states(signal_names("dq", params), "velocity"))
    block.robot_parameters = block.arm = params
    block.disturbance_spec = spec
    return block


def controller(nominal: ArmModel, kp, kd, use_observer: bool = True, measured: str = "",
               name: str = "controller") -> Block:
    """Computed-torque control, Eq. 11, on the nominal model.

    ``tau = M^(q)(q_ref'' + Kd e' + Kp e) + N^(q, q') q' + G^(q) - d_hat``,
    with ``e = q_ref - q``.  Without the observer ``d_hat = 0`` and the block
    has no ``d_hat`` input.

    Parameters
    ----------
    nominal : ArmModel
        The model the controller believes in.
    kp, kd : float, n floats or diagonal n x n
        Proportional (1/s^2) and derivative (1/s) gains, each > 0, scalar or per joint.
    use_observer : bool
        Whether the block takes ``d_hat[i]`` from the observer.
    measured : str
        Suffix of the measured signals it reads, ``""`` for ``q[i]``/``dq[i]``
        or ``"_meas"`` for ``q_meas[i]``/``dq_meas[i]`` from a sensor block.

    Raises
    ------
    blocks.diagram.gains.GainError
        If a gain is not positive, not diagonal or of the wrong shape.
    """
    nominal = _arm(nominal, "nominal")
    Kp, Kd = validated_gain(kp, "kp", nominal.joints), validated_gain(kd, "kd", nominal.joints)
    inputs = [s for prefix in ("q_ref", "dq_ref", "ddq_ref", "q" + measured, "dq" + measured)
              for s in signal_names(prefix, nominal)]
    if use_observer:
        inputs += signal_names("d_hat", nominal)
    law = controller_output_with_estimate if use_observer else controller_output
    block = kernel_block(Kernels((nominal.kernel_params(), np.diag(Kp).copy(), np.diag(Kd).copy()),
                                 with_arm(law, nominal)),
                         name=name, inputs=inputs, outputs=signal_names("tau", nominal), feedthrough=inputs)
    block.gains = {"kp": Kp, "kd": Kd}
    return block


def observer(nominal: ArmModel, gain, variant: str = "correct", measured: str = "",
             name: str = "observer", matrix_gain: bool = False) -> Block:
    """Nonlinear disturbance observer (Chen et al. 2000; Mohammadi et al. 2013).

    ``d_hat = Y q' + z``, ``z' = -Y M^-1(q)(tau + d_hat - N(q, q') q' - G(q))``,
    which gives ``d_hat' = Y M^-1 (d - d_hat)`` on a perfect model.  With
    ``variant="paper-eq16"`` the update carries the extra ``- Y q'`` term of
    the paper's printed Eq. 16, which biases the estimate whenever the arm moves.

    States ``z[i]``; inputs ``tau[i]``, ``q[i]``, ``dq[i]``; output ``d_hat[i]``.

    Parameters
    ----------
    nominal : ArmModel
        The model the observer believes in.
    gain : float, n floats or n x n
        Observer gain ``Y`` (kg m^2/s and kg/s entries); the paper's "K3 = 10 I".
        ``Y + Y^T`` must be positive definite.
    variant : {"correct", "paper-eq16"}
    measured : str
        Suffix of the measured signals it reads (see :func:`controller`).
    matrix_gain : bool
        Give the kernels ``Y`` as an n x n matrix even when it is diagonal (by
        default a diagonal gain is given by its diagonal, which multiplies
        elementwise); for engines that need one parameter layout for every gain.

    Raises
    ------
    blocks.diagram.gains.GainError
        If the gain is of the wrong shape or ``Y + Y^T`` is not positive definite.
    ValueError
        If the variant is unknown.
    """
    if variant not in OBSERVER_VARIANTS:
        raise ValueError(f"observer variant {variant!r} is unknown; choose from {list(OBSERVER_VARIANTS)}")
    nominal = _arm(nominal, "nominal")
    Y = validated_gain(gain, "observer", nominal.joints)
    # a diagonal gain multiplies elementwise (see blocks.kernels.laws.gain_times)
    diagonal = np.count_nonzero(Y - np.diag(np.diag(Y))) == 0 and not matrix_gain
    y_param = np.diag(Y).copy() if diagonal else np.array(Y)
    dq_in = signal_names("dq" + measured, nominal)
    inputs = signal_names("tau", nominal) + signal_names("q" + measured, nominal) + dq_in
    kernels = Kernels((nominal.kernel_params(), y_param, 1.0 if variant == "paper-eq16" else 0.0),
                      with_arm(observer_output, nominal), with_arm(observer_update, nominal))
    block = kernel_block(kernels, name=name, inputs=inputs, states=signal_names("z", nominal),
                         outputs=signal_names("d_hat", nominal), feedthrough=dq_in,
                         state_meanings=joint_states(signal_names("z", nominal), "observer_state"))
    block.gain = Y
    block.variant = variant
    return block


def trajectory_block(trajectory, name: str = "trajectory", arm: ArmModel | None = None) -> Block:
    """A source block with outputs ``q_ref[i]``, ``dq_ref[i]``, ``ddq_ref[i]``.

    Parameters
    ----------
    trajectory : object
        A path of :mod:`blocks.diagram.trajectory` (the block is then a kernel block
        whose output is the path's reference kernel), or anything with
        ``evaluate(t) -> (q, dq, ddq)`` returning three n-vectors for a scalar
        time ``t`` (s).  When such an object also has ``evaluate_stacked(t)``,
        returning the three side by side with shape ``np.shape(t) + (3n,)``
        for a scalar or a (T,) array of times, that is used instead and the
        block takes columns.
    arm : ArmModel, optional
        The arm whose joints the reference drives (names, n); default the default scenario's.
    """
    outputs = signal_names("q_ref", arm) + signal_names("dq_ref", arm) + signal_names("ddq_ref", arm)
    make_kernels = getattr(trajectory, "kernels", None)
    if callable(make_kernels):
        block = kernel_block(make_kernels(), name=name, inputs=[], outputs=outputs)
        block.trajectory = trajectory
        return block
    stacked = getattr(trajectory, "evaluate_stacked", None)

    def output(t, x, u, _params):
        if stacked is not None:
            refs = stacked(t)
            return refs if refs.ndim == 1 else refs.T
        return np.concatenate(trajectory.evaluate(t))

    block = Block(None, output, name=name, inputs=0, outputs=outputs,
                  contract=BlockContract(feedthrough=frozenset(), columnwise=stacked is not None))
    block.trajectory = trajectory
    return block


def sensor(noise, name: str = "sensor", arm: ArmModel | None = None) -> Block:
    """Measurement of ``q``, ``dq`` with additive noise: outputs ``q_meas[i]``, ``dq_meas[i]``.

    Parameters
    ----------
    noise : object
        A :class:`~blocks.model.noise.MeasurementNoise` (the block is then a kernel
        block), or anything with ``sample(t) -> (n_q, n_dq)`` returning two
        n-vectors for a scalar time.
    arm : ArmModel, optional
        The arm whose joints are measured (names, n); default the paper's.
    """
    inputs = signal_names("q", arm) + signal_names("dq", arm)
    outputs = signal_names("q_meas", arm) + signal_names("dq_meas", arm)
    if isinstance(noise, MeasurementNoise):
        params = (noise.table, noise.sample_period)      # the table is indexed by time, not broadcast
        return kernel_block(Kernels(params, sensor_output, column_params=params), name=name, inputs=inputs,
                            outputs=outputs, feedthrough=inputs)

    def output(t, x, u, _params):
        n_q, n_dq = noise.sample(t)
        return u + np.concatenate([n_q, n_dq])

    return Block(None, output, name=name, inputs=inputs, outputs=outputs,
                 contract=BlockContract(feedthrough=frozenset(inputs)))
