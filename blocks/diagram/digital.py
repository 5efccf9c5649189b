"""The digital controller: computed torque and observer sampled at a fixed rate, with encoders and torque limits.

A joint controller is a program that runs every ``Ts = 1 / sample_rate``
seconds.  At ``t_k = k Ts`` it reads the encoders, forms the velocity
estimate, the disturbance estimate ``d_hat_k = Y dq_k + z_k`` and the
torque ``tau_k`` of Eq. 11 on the nominal model, and writes the torque,
which the motor drives hold until the next sample.  With ``delay = d`` the
torque computed at ``t_k`` is applied from ``t_{k+d}``; the applied torque
is saturated at ``torque_limit``.  The observer updates ``z_{k+1}`` from
``q_k``, ``dq_k``, ``z_k`` and the torque applied over the sample (so it sees
the saturated torque and does not wind up), either by forward Euler or by the
exact solution of its equation with ``M^(q_k)`` and its inputs frozen over
the sample (``"zoh"``).

Velocity: ``"measured"`` samples the velocity signal (a tachometer or the
drive's own estimate); ``"difference"`` takes the backward difference of
the sampled (quantized) positions, ``(q_k - q_{k-1}) / Ts``, through a
first-order low-pass ``v_k = a v_{k-1} + (1 - a) diff_k`` with
``a = exp(-2 pi f_c Ts)`` when ``velocity_cutoff = f_c`` is given (the
raw difference otherwise).  Positions are quantized to ``position_resolution``
per joint (``res * round(q / res)``; 0 = exact).

Stability: alone (the estimate not fed back) the ``"zoh"`` update is stable
at any rate and forward Euler while ``Ts lambda_max(Y M^-1) < 2``.  In the
loop (the controller subtracts ``d_hat``, the plant integrates the held
torque) only forward Euler with measured velocity keeps that limit exactly:
its estimate's error follows ``e_{k+1} = (I - Ts Y M^-1) e_k`` whatever the
torque (with or without a delay).  With ``"zoh"`` or a velocity difference
the estimate and the tracking couple and the limit is lower, and a delay
lowers it further (zoh, measured, Kp = 180,
Kd = 36: ``Ts lambda_max < 1.7899`` at 100 Hz, ``1.9795`` at 1 kHz); it is
computed from the loop's linearized one-sample map by
:mod:`blocks.figure2.digital_stability`, which the pre-run check uses.  See
``docs/model.md``, "Digital observer".

Any arm: the settings carry the arm's joints (``DigitalController(...,
joints=arm.joints)``; a scenario's ``[controller]`` takes them from its arm),
so the per-joint settings are one number for every joint or one per joint,
in the joints' units; the controller and observer blocks take the nominal
arm and pass its row kernels to the laws as a value (the kernels below take
``model`` first: :func:`blocks.kernels.model.with_arm`).

The blocks are python-control discrete-time systems (``dt = Ts``) and run
in a :class:`~blocks.engines.hybrid.HybridSystem` with the continuous plant::

    trajectory --> controller --(tau_cmd)--> actuator --(tau)--> plant --(q, dq)--> [sensor] --> encoder
                      ^    ^                                 |                                      |
                      |    +---(d_hat)--- observer <---(tau)-+----------------(q_s, dq_s)-----------+
                      +-----------------------------(q_s, dq_s)-------------------------------------+
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from blocks.diagram.bound_kernels import Kernels
from blocks.diagram.gains import OBSERVER_VARIANTS, validated_gain
from blocks.kernels import observer_estimate, observer_rate
from blocks.kernels.expm import expm_small
from blocks.kernels.model import with_arm

# The block factories import python-control's side (contract, systems) when called, so that a scenario
# holding a DigitalController loads without python-control.
from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace

__all__ = ["DigitalController", "DISCRETIZATIONS", "VELOCITY_SOURCES", "encoder", "digital_controller", "actuator",
           "digital_observer"]

DISCRETIZATIONS = ("euler", "zoh")
VELOCITY_SOURCES = ("measured", "difference")


@dataclass(frozen=True)
class DigitalController:
    """How the controller is implemented: its rate, delay, encoders, velocity estimate and torque limits.

    Parameters
    ----------
    sample_rate : float
        Samples per second (Hz), finite and > 0.
    delay : int
        Whole samples between reading the sensors and applying the torque, >= 0.
    observer_discretization : {"euler", "zoh"}
        The observer's update: forward Euler, or the exact solution with its inputs held over the sample.
    velocity : {"measured", "difference"}
        Sampled velocity signal, or backward difference of the sampled positions.
    velocity_cutoff : float, optional
        Cut-off (Hz) of the first-order low-pass on the difference, below the
        Nyquist frequency ``sample_rate / 2``; only with ``"difference"``.
    position_resolution : float or n floats
        Encoder quantization step (rad; m on a prismatic joint), >= 0; 0 = exact.
        One number for every joint or one per joint; stored as n numbers.
    torque_limit : float or n floats
        Saturation (N m; N on a prismatic joint), >= 0; 0 = none.  One number or one per joint.
    joints : JointSpace
        The joints of the arm the controller runs (n, names, units); default those of the default scenario's arm
        (:func:`blocks.scenarios.scenario.default_arm`).
        Take it from the arm: ``DigitalController(1000.0, joints=arm.joints)``.
    """

    sample_rate: float
    delay: int = 0
    observer_discretization: str = "euler"
    velocity: str = "measured"
    velocity_cutoff: float | None = None
    position_resolution: tuple | float = 0.0
    torque_limit: tuple | float = 0.0
    joints: JointSpace | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.joints is None:             # the default scenario's arm's joints
            from blocks.model.default import default_arm
            object.__setattr__(self, "joints", default_arm().joints)
        if not isinstance(self.joints, JointSpace):
            raise TypeError(f"'joints' must be a blocks.model.joints.JointSpace (an arm's .joints), got {self.joints!r:.80}")
        rate = self.sample_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise ValueError(f"'controller.sample_rate' must be a finite number of Hz > 0, got {rate!r}")
        object.__setattr__(self, "sample_rate", float(rate))
        d = self.delay
        if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d < 0:
            raise ValueError(f"'controller.delay' must be a whole number of samples >= 0, got {d!r}")
        object.__setattr__(self, "delay", int(d))
        if self.observer_discretization not in DISCRETIZATIONS:
            raise ValueError(f"'controller.observer_discretization' must be one of {list(DISCRETIZATIONS)}, "
                             f"got {self.observer_discretization!r}")
        if self.velocity not in VELOCITY_SOURCES:
            raise ValueError(f"'controller.velocity' must be one of {list(VELOCITY_SOURCES)}, got {self.velocity!r}")
        fc = self.velocity_cutoff
        if fc is not None:
            if self.velocity != "difference":
                raise ValueError("'controller.velocity_cutoff' filters the position difference: it needs "
                                 f"velocity = \"difference\" (velocity is {self.velocity!r})")
            if isinstance(fc, bool) or not isinstance(fc, (int, float)) or not math.isfinite(fc) or fc <= 0:
                raise ValueError(f"'controller.velocity_cutoff' must be a finite number of Hz > 0, got {fc!r}")
            if fc >= rate / 2:
                raise ValueError(f"'controller.velocity_cutoff' ({fc:g} Hz) must be below the Nyquist frequency "
                                 f"sample_rate / 2 = {rate / 2:g} Hz")
            object.__setattr__(self, "velocity_cutoff", float(fc))
        for name, units in (("position_resolution", self.joints.position_units),
                            ("torque_limit", self.joints.force_units)):
            object.__setattr__(self, name, _per_joint(getattr(self, name), name, self.joints, units))

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.joints.count

    def check_arm(self, arm: ArmModel) -> None:
        """Refuse an arm whose joints are not the ones these settings were made for.

        Raises
        ------
        ValueError
            Naming the two joint lists.
        """
        if arm.joints.names != self.joints.names or arm.joints.kinds != self.joints.kinds:
            raise ValueError(f"the controller settings are for the {self.n} joints {list(self.joints.names)}, but "
                             f"the arm has the {arm.n} joints {list(arm.joints.names)}: make them with "
                             "DigitalController(..., joints=arm.joints)")

    @property
    def period(self) -> float:
        """The sample period ``Ts`` (s)."""
        return 1.0 / self.sample_rate

    @property
    def filter_pole(self) -> float:
        """``a = exp(-2 pi f_c Ts)`` of the velocity low-pass (0: no filter)."""
        return 0.0 if self.velocity_cutoff is None else math.exp(-2 * math.pi * self.velocity_cutoff * self.period)


def _per_joint(value, name: str, joints: JointSpace, units) -> tuple[float, ...]:
    """``value`` (a number or one per joint) as n floats >= 0, or a ValueError naming the key, n and the joints."""
    n = joints.count
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    flags = np.ravel(np.asarray(value, dtype=object)) if arr.ndim <= 1 else ()
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or np.any(arr < 0) or \
            any(isinstance(v, (bool, np.bool_)) for v in flags):
        joint_list = f", one per joint of {list(joints.names)} or one for all"
        raise ValueError(f"'controller.{name}' must be {n} finite numbers >= 0 ({', '.join(units)}){joint_list}, "
                         f"got {value!r}")
    return tuple(float(v) for v in arr)


# --------------------------------------------------------------------------------------------------------------
# Discrete block kernels: outputs y_k = g(x_k, u_k), updates x_{k+1} = f(x_k, u_k)
# --------------------------------------------------------------------------------------------------------------
def quantized(q, resolution, steps=None):
    """``res * round(q / res)`` per joint (to even at a tie), ``q`` itself where the resolution is 0.

    ``steps`` says per joint whether its resolution is > 0 (a tuple of bools,
    so that the compiled engine specialises on it instead of branching on a value).
    """
    steps = np.asarray(resolution > 0 if steps is None else steps)
    return np.where(steps, np.rint(q / np.where(steps, resolution, 1.0)) * resolution, q)


def encoder_measured_output(t, x, u, resolution, steps):
    """Sampled ``[q_s; dq_s]``: quantized positions and the velocity signal as measured."""
    n = resolution.shape[0]
    return np.concatenate((quantized(u[:n], resolution, steps), u[n:]))


def encoder_difference_output(t, x, u, resolution, steps, period, pole):
    """Sampled ``[q_s; dq_s]`` with ``dq_s`` the low-passed backward difference; state ``[q_s(k-1); dq_s(k-1)]``."""
    n = resolution.shape[0]
    q_s = quantized(u[:n], resolution, steps)
    return np.concatenate((q_s, pole * x[n:] + (1.0 - pole) * (q_s - x[:n]) / period))


def encoder_difference_update(t, x, u, resolution, steps, period, pole):
    """The encoder's next state: this sample's position and velocity estimate."""
    return encoder_difference_output(t, x, u, resolution, steps, period, pole)


def actuator_output(t, x, u, limit, n):
    """The applied torque: the command (delay 0) or the oldest buffered one, saturated at ``limit``.

    Joint by joint ``min(max(command, -limit), limit)``, as ``np.clip``, in a
    form the compiled engine traces into scalar statements.
    """
    command = u if x.shape[0] == 0 else x[:n]
    return np.array([np.minimum(np.maximum(command[i], -limit[i]), limit[i]) for i in range(n)])


def actuator_update(t, x, u, limit, n):
    """The buffer of commands not yet applied, oldest first."""
    return np.concatenate((x[n:], u))


def observer_euler_update(model, t, z, u, k, gain, eq16_weight, period):
    """``z_{k+1} = z_k + Ts z'(q_k, dq_k, tau_k, z_k)``: inputs ``[tau; q_s; dq_s]``."""
    n = z.shape[0]
    return z + period * observer_rate(model, k, gain, eq16_weight, u[n:2 * n], u[2 * n:3 * n], u[:n], z)


def observer_zoh_update(model, t, z, u, k, gain, eq16_weight, period):
    """The exact solution of ``z' = A z + c`` over the sample, ``A = -Y M^(q_k)^-1`` and ``c`` frozen at ``t_k``.

    The observer's law (:func:`blocks.kernels.observer_rate`) is affine in
    ``z`` with the other inputs held, so ``c = z'(0)`` and the columns of
    ``A`` are ``z'(e_j) - c``, evaluated with the law itself; the exponential
    (:func:`blocks.kernels.expm.expm_small`) of the
    augmented matrix ``[[A, c], [0, 0]] Ts`` then gives
    ``z_{k+1} = e^{A Ts} z_k + (int_0^Ts e^{A s} ds) c``.
    """
    n = z.shape[0]
    tau, q, dq = u[:n], u[n:2 * n], u[2 * n:3 * n]
    # written with loops and no closures so that the compiled sampled engine calls this same kernel
    c = observer_rate(model, k, gain, eq16_weight, q, dq, tau, np.zeros(n))
    augmented = np.zeros((n + 1, n + 1))
    basis = np.zeros(n)
    for j in range(n):
        basis[:] = 0.0
        basis[j] = 1.0
        augmented[:n, j] = (observer_rate(model, k, gain, eq16_weight, q, dq, tau, basis) - c) * period
    augmented[:n, n] = c * period
    step = expm_small(augmented)
    return np.ascontiguousarray(step[:n, :n]) @ z + step[:n, n]


def observer_zoh_matrix(model, t, x, u, k, gain, eq16_weight, period):
    """The first ``n`` rows of :func:`observer_zoh_update`'s augmented matrix ``[[A, c], [0, 0]] Ts``, row by row
    (``n (n + 1)`` numbers): inputs ``[tau; q_s; dq_s]``.

    The zoh update of a URDF arm split in two for the compiled sampled engine (:func:`zoh_split`): this part
    evaluates the observer law on the arm's model, which the engine traces into its code; :func:`observer_zoh_step`
    takes the exponential, which it calls.  The numbers are those of :func:`observer_zoh_update`.
    """
    n = u.shape[0] // 3
    tau, q, dq = u[:n], u[n:2 * n], u[2 * n:3 * n]
    c = observer_rate(model, k, gain, eq16_weight, q, dq, tau, np.zeros(n))
    columns = []
    for j in range(n):
        basis = np.zeros(n)
        basis[j] = 1.0
        columns.append((observer_rate(model, k, gain, eq16_weight, q, dq, tau, basis) - c) * period)
    columns.append(c * period)
    return np.stack(columns, axis=1).ravel()


def observer_zoh_step(t, z, u, gain, period):
    """``z_{k+1} = e^{A Ts} z_k + (int_0^Ts e^{A s} ds) c`` from the augmented matrix's rows (:func:`observer_zoh_matrix`)
    in the inputs ``[tau; q_s; dq_s; rows]``: the last lines of :func:`observer_zoh_update`."""
    n = z.shape[0]
    augmented = np.zeros((n + 1, n + 1))
    for i in range(n):
        for j in range(n + 1):
            augmented[i, j] = u[3 * n + i * (n + 1) + j]
    step = expm_small(augmented)
    return np.ascontiguousarray(step[:n, :n]) @ z + step[:n, n]


def observer_held_output(t, z, u, gain, period):
    """``d_hat_k = Y dq_k + z_k`` (:func:`observer_sampled_output` without the model it does not read)."""
    n = z.shape[0]
    dq = u[2 * n:3 * n]
    return observer_estimate(gain, dq, z)


def observer_sampled_output(model, t, z, u, k, gain, eq16_weight, period):
    """``d_hat_k = Y dq_k + z_k``."""
    n = z.shape[0]
    return observer_estimate(gain, u[2 * n:3 * n], z)


# --------------------------------------------------------------------------------------------------------------
# Factories
# --------------------------------------------------------------------------------------------------------------
def encoder(settings: DigitalController, measured: str = "", name: str = "encoder"):
    """Sampled positions ``q_s[i]`` and velocity estimate ``dq_s[i]`` from ``q[i]``, ``dq[i]`` (or ``*_meas``).

    The joints (n, names) are those of ``settings.joints``.
    """
    from blocks.diagram.contract import joint_states, kernel_block
    names = settings.joints.signal_names
    res = np.array(settings.position_resolution)
    steps = tuple(bool(r > 0) for r in res)         # which joints quantize: structure, not numbers
    inputs = names("q" + measured) + names("dq" + measured)
    outputs = names("q_s") + names("dq_s")
    if settings.velocity == "measured":
        return kernel_block(Kernels((res, steps), encoder_measured_output, column_params=(res, steps)), name=name,
                            inputs=inputs, outputs=outputs, feedthrough=inputs, dt=settings.period)
    params = (res, steps, settings.period, settings.filter_pole)
    return kernel_block(Kernels(params, encoder_difference_output, encoder_difference_update, column_params=params),
                        name=name, inputs=inputs, outputs=outputs, dt=settings.period,
                        states=names("q_prev") + names("v_prev"), feedthrough=names("q" + measured),
                        state_meanings=joint_states(names("q_prev"), "position")
                        + joint_states(names("v_prev"), "velocity"))


def _nominal_arm(nominal, settings: DigitalController) -> ArmModel:
    if not isinstance(nominal, ArmModel):
        raise TypeError(f"nominal must be an arm model (blocks.model.arm.ArmModel, e.g. scenario.robot or "
                        f"blocks.model.default.default_arm()), got {type(nominal).__name__} {nominal!r:.80}")
    settings.check_arm(nominal)
    return nominal


def digital_controller(nominal: ArmModel, kp, kd, settings: DigitalController, use_observer: bool = True,
                       name: str = "controller"):
    """Eq. 11 at each sample, from the sampled signals; output the command ``tau_cmd[i]``.

    Parameters
    ----------
    nominal : ArmModel
        The model the controller believes in (any arm; its joints must be ``settings.joints``).
    kp, kd : float, n floats or diagonal n x n
        Proportional (1/s^2) and derivative (1/s) gains.
    settings : DigitalController
    use_observer : bool
        Whether the block takes ``d_hat[i]``.

    Raises
    ------
    ValueError
        If ``settings`` were made for other joints than the arm's.
    """
    from blocks.diagram.contract import kernel_block
    from blocks.diagram.systems import controller_output, controller_output_with_estimate
    nominal = _nominal_arm(nominal, settings)
    names = nominal.joints.signal_names
    Kp, Kd = validated_gain(kp, "kp", nominal.joints), validated_gain(kd, "kd", nominal.joints)
    inputs = [s for prefix in ("q_ref", "dq_ref", "ddq_ref", "q_s", "dq_s") for s in names(prefix)]
    if use_observer:
        inputs += names("d_hat")
    law = controller_output_with_estimate if use_observer else controller_output
    block = kernel_block(Kernels((nominal.kernel_params(), np.diag(Kp).copy(), np.diag(Kd).copy()),
                                 with_arm(law, nominal)), name=name,
                         inputs=inputs, outputs=names("tau_cmd"), feedthrough=inputs, dt=settings.period)
    block.gains = {"kp": Kp, "kd": Kd}
    return block


def actuator(settings: DigitalController, name: str = "actuator"):
    """Delay by ``settings.delay`` samples and saturate: ``tau_cmd[i]`` -> applied ``tau[i]`` (joints of
    ``settings.joints``)."""
    from blocks.diagram.contract import kernel_block
    names = settings.joints.signal_names
    limit = np.array([v if v > 0 else np.inf for v in settings.torque_limit])
    n, d = limit.size, settings.delay
    params = (limit, n)
    inputs = names("tau_cmd")
    states = [f"buffer{j}[{i}]" for j in range(d) for i in range(n)]
    return kernel_block(Kernels(params, actuator_output, actuator_update if d else None, column_params=params),
                        name=name, inputs=inputs, outputs=names("tau"), states=states,
                        feedthrough=() if d else inputs, dt=settings.period)


def digital_observer(nominal: ArmModel, gain, settings: DigitalController, variant: str = "correct",
                     name: str = "observer"):
    """The observer sampled at ``settings.period``: inputs ``tau[i]`` (applied), ``q_s[i]``, ``dq_s[i]``.

    Parameters
    ----------
    nominal : ArmModel
        The model the observer believes in (its joints must be ``settings.joints``).
    gain : float, n floats or n x n
        Observer gain ``Y`` (kg m^2/s; kg/s on a prismatic joint).
    settings : DigitalController
    variant : {"correct", "paper-eq16"}

    Raises
    ------
    ValueError
        If the variant is unknown or ``settings`` were made for other joints than the arm's.
    """
    from blocks.diagram.contract import joint_states, kernel_block
    if variant not in OBSERVER_VARIANTS:
        raise ValueError(f"observer variant {variant!r} is unknown; choose from {list(OBSERVER_VARIANTS)}")
    nominal = _nominal_arm(nominal, settings)
    names = nominal.joints.signal_names
    Y = validated_gain(gain, "observer", nominal.joints)
    y_param = np.diag(Y).copy() if np.count_nonzero(Y - np.diag(np.diag(Y))) == 0 else np.array(Y)
    update = observer_zoh_update if settings.observer_discretization == "zoh" else observer_euler_update
    params = (nominal.kernel_params(), y_param, 1.0 if variant == "paper-eq16" else 0.0, settings.period)
    inputs = names("tau") + names("q_s") + names("dq_s")
    block = kernel_block(Kernels(params, with_arm(observer_sampled_output, nominal), with_arm(update, nominal)), name=name,
                         inputs=inputs, states=names("z"), outputs=names("d_hat"), feedthrough=names("dq_s"),
                         dt=settings.period, state_meanings=joint_states(names("z"), "observer_state"))
    block.gain = Y
    if settings.observer_discretization == "zoh":
        block.zoh_split = partial(zoh_split, nominal, params, settings, name)
    return block


def zoh_split(nominal: ArmModel, params: tuple, settings: DigitalController, name: str = "observer") -> list:
    """The zoh observer as two sampled blocks with its numbers: the augmented matrix, then the update and estimate.

    ``<name>_zoh`` (inputs ``tau``, ``q_s``, ``dq_s``; outputs ``<name>_a[i]``, the ``n (n + 1)`` entries of
    :func:`observer_zoh_matrix`) evaluates the observer law on the nominal model; ``<name>`` (inputs ``tau``,
    ``q_s``, ``dq_s`` and those entries, state ``z``, output ``d_hat``) takes the exponential
    (:func:`observer_zoh_step`) and reads no model.  The compiled sampled engine runs this pair for an arm whose
    model it must trace (a URDF arm's, which compiled code cannot take as a parameter): the first block is traced,
    the second called with numbers only.  The states, outputs and numbers are those of the one block.

    Parameters
    ----------
    nominal : ArmModel
    params : tuple
        The observer block's parameters ``(model, gain, eq16_weight, period)``.
    settings : DigitalController
    name : str
        The observer block's name.
    """
    from blocks.diagram.contract import joint_states, kernel_block
    names = nominal.joints.signal_names
    n = nominal.joints.count
    _, gain, _, period = params
    inputs = names("tau") + names("q_s") + names("dq_s")
    rows = [f"{name}_a[{i}]" for i in range(n * (n + 1))]
    matrix = kernel_block(Kernels(params, with_arm(observer_zoh_matrix, nominal)), name=f"{name}_zoh", inputs=inputs,
                          outputs=rows, feedthrough=inputs, dt=settings.period)
    observer = kernel_block(Kernels((gain, period), observer_held_output, observer_zoh_step), name=name,
                            inputs=inputs + rows, states=names("z"), outputs=names("d_hat"),
                            feedthrough=names("dq_s"), dt=settings.period,
                            state_meanings=joint_states(names("z"), "observer_state"))
    return [observer, matrix]
