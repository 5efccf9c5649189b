"""The Figure-2 loop: blocks from a scenario, their interconnection, and its simulation.

::

    trajectory --(q_ref, dq_ref, ddq_ref)--> controller --(tau)--> plant --(q, dq)--+--> outputs
                                               ^      ^               ^             |
                                               |      +--(d_hat)-- observer <-------+ (tau, q, dq)
                                               +----------------------(q, dq)-------+

The interconnected system returned by :func:`closed_loop` is the single
description of the loop.  :func:`simulate` is the Figure-2 layer over the one
simulator (:func:`blocks.engines.simulator.advance`): it fills the run's
:class:`~blocks.engines.context.Context` from the scenario (start state, the states'
physical bounds, the budget checked by :func:`blocks.figure2.run_limits.check_run`)
and steps the loop with one of three engines, which give the same numbers to
solver tolerance:

``compiled``
    the loop's plan and kernels generated into one numba-compiled module
    (:mod:`blocks.engines.compiled`; needs the extra ``dobkit[fast]``);
``fast``
    the numpy engine, :class:`~blocks.engines.fastsim.CompiledLoop`, with
    ``solve_ivp``'s solvers: the plan's generated right-hand side run by
    Python on floats when every block has kernels, else each block evaluated
    once per call, in dependency order;
``python-control``
    :func:`control.input_output_response` on the interconnection.

``engine="auto"`` (the default) takes ``compiled`` when numba is installed,
every block has kernels and the solver is RK45, and ``fast`` otherwise; the
first fallback for each reason is reported once per process with an
:class:`EngineFallbackWarning` that says why.

A loop whose structure was built before in this process (same arm model,
blocks, signal names, kernels and parameter layouts; other numbers: gains,
disturbance size, noise, ``t_final``) is not wired again: :func:`closed_loop`
makes its interconnection from the kept wiring (:data:`WIRINGS`) and
:func:`blocks.diagram.plan.make_plan` its plan from the kept plan, each with the new
loop's own blocks, so only the numbers are new (see :mod:`blocks.diagram.structure`).
:func:`clear_reuse` forgets what is kept.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable

import control as ct
import numpy as np

from blocks.diagram.structure import StructureCache, blocks_structure
from blocks.diagram.systems import controller, plant, sensor, signal_names, trajectory_block
from blocks.diagram.systems import observer as observer_block
from blocks.engines.budget import Budget
from blocks.engines.context import Context
from blocks.engines.engine_choice import ENGINES, EngineFallbackWarning, select_engine
from blocks.engines.integrate import refuse_hybrid
from blocks.engines.monitor import SimulationError
from blocks.engines.simulator import NumpyEngine, PythonControlEngine, Solver, advance
from blocks.figure2.derived import loop_response
from blocks.figure2.physical_bounds import state_bounds
from blocks.figure2.run_limits import check_run, estimate_run, prepare_reference
from blocks.kernels import lumped_disturbance as lumped_disturbance_rows
from blocks.model.validation import callable_or_none, joint_arrays
from blocks.scenarios.scenario import Scenario, load_scenario

__all__ = ["build_blocks", "closed_loop", "initial_state", "simulate", "SimulationError", "lumped_disturbance",
           "LOOP_SIGNALS", "ENGINES", "EngineFallbackWarning", "select_engine", "clear_reuse", "WIRINGS"]


LOOP_SIGNALS = ("q", "dq", "q_ref", "dq_ref", "ddq_ref", "tau", "d_hat", "tau_dis")


def _as_scenario(scenario) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def build_blocks(scenario: Scenario | str = "paper", observer: bool = True, plant_system=None) -> dict:
    """The blocks of Figure 2 for a scenario, as python-control systems.

    Parameters
    ----------
    scenario : Scenario or str
        A scenario or the name/path of one.
    observer : bool
        Include the disturbance observer (otherwise the controller uses ``d_hat = 0``).
    plant_system : control.NonlinearIOSystem, optional
        A replacement for the Python plant (for example an FMU loaded with
        :func:`fmu.load`); it must take ``tau[i]`` and give ``q[i]``,
        ``dq[i]`` and ``tau_dis[i]``.

    Returns
    -------
    dict
        ``trajectory``, ``controller``, ``plant``, and ``observer`` and ``sensor``
        when present, keyed by block name.
    """
    s = _as_scenario(scenario)
    if plant_system is not None and not isinstance(plant_system, ct.NonlinearIOSystem):
        raise TypeError(f"plant must be a python-control NonlinearIOSystem (for example from fmu.load), got "
                        f"{type(plant_system).__name__} {plant_system!r}")
    measured = "_meas" if s.noise is not None else ""
    blocks = {
        "trajectory": trajectory_block(s.trajectory, arm=s.robot),
        "controller": controller(s.nominal, s.kp, s.kd, use_observer=observer, measured=measured),
        "plant": plant(s.robot, s.disturbance) if plant_system is None else plant_system,
    }
    if observer:
        blocks["observer"] = observer_block(s.nominal, s.observer_gain, s.observer_variant, measured=measured)
    if s.noise is not None:
        blocks["sensor"] = sensor(s.noise, arm=s.robot)
    return blocks


def closed_loop(scenario: Scenario | str = "paper", observer: bool = True, plant=None) -> ct.InterconnectedSystem:
    """The Figure-2 interconnection, wired by signal name with :func:`control.interconnect`.

    Parameters
    ----------
    scenario : Scenario or str
    observer : bool
        With or without the disturbance observer.
    plant : control.NonlinearIOSystem, optional
        A replacement for the Python plant (see :func:`build_blocks`).

    Returns
    -------
    control.InterconnectedSystem
        No external inputs; outputs ``q, dq, q_ref, dq_ref, ddq_ref, tau, tau_dis``
        (``[i]`` per joint), ``d_hat`` with the observer, and ``q_meas``, ``dq_meas``
        with measurement noise.
    """
    s = _as_scenario(scenario)
    blocks = build_blocks(s, observer=observer, plant_system=plant)
    signals = [sig for sig in LOOP_SIGNALS if observer or sig != "d_hat"]
    if "sensor" in blocks:
        signals += ["q_meas", "dq_meas"]
    arm = s.robot
    outputs = [name for sig in signals for name in signal_names(sig, arm)]
    plant_sys = blocks["plant"]
    needed_outputs = signal_names("q", arm) + signal_names("dq", arm) + signal_names("tau_dis", arm)
    plant_outputs, plant_inputs = set(plant_sys.output_labels), set(plant_sys.input_labels)
    missing = [n for n in needed_outputs if n not in plant_outputs]
    missing += [n for n in signal_names("tau", arm) if n not in plant_inputs]
    if missing:
        last = arm.joints.count - 1
        raise ValueError(f"plant block '{plant_sys.name}' lacks signals the loop needs: {missing} "
                         f"(it must take tau[0..{last}] and give q, dq and tau_dis[0..{last}])")
    loop = _interconnect(list(blocks.values()), outputs, "dob_loop" if observer else "ctc_loop")
    loop.scenario = s
    loop.with_observer = observer
    return loop


class _Wiring:
    """What :func:`control.interconnect` derived for one loop structure: its connection matrices (read-only) and
    signal names.  No block, function or number: the loops made from it take those from their own blocks."""

    def __init__(self, loop: ct.InterconnectedSystem) -> None:
        self.maps = []
        for m in (loop.connect_map, loop.input_map, loop.output_map):
            m = np.array(m, dtype=float)
            m.setflags(write=False)
            self.maps.append(m)
        self.outputs, self.states = tuple(loop.output_labels), tuple(loop.state_labels)
        self.connection_type = loop.connection_type

    def loop(self, blocks: list, name: str) -> ct.InterconnectedSystem:
        """The interconnection of ``blocks`` (a loop of this structure) made without matching signal names again:
        python-control's constructor with the names and matrices ``interconnect`` found."""
        loop = ct.InterconnectedSystem(blocks, connections=[], inplist=[], outlist=[], inputs=[],
                                       outputs=list(self.outputs), states=list(self.states), name=name,
                                       connection_type=self.connection_type)
        connect_map, input_map, output_map = (m.copy() for m in self.maps)   # the loop's own, as interconnect's are
        loop.set_connect_map(connect_map)
        loop.set_input_map(input_map)
        loop.set_output_map(output_map)
        return loop


#: Wirings kept for reuse: distinct loop structures (observer on/off, noise, arm, disturbance kind, path kind...),
#: each its three connection matrices, about 90 kB for the Panda's loop, 30 kB for the paper's.
WIRINGS_KEPT = 32
#: The kept wirings by loop structure (see :func:`_interconnect`).
WIRINGS = StructureCache(WIRINGS_KEPT)


def _interconnect(blocks: list, outputs: list, name: str) -> ct.InterconnectedSystem:
    """``control.interconnect`` of ``blocks`` by signal name with outputs ``outputs``, or the same interconnection
    made from the wiring of a loop of the same structure built before in this process (see
    :mod:`blocks.diagram.structure`): only numbers differ, and those are in ``blocks``."""
    parts = blocks_structure(blocks)
    key = None if parts is None else (parts, tuple(outputs), name)
    wiring = WIRINGS.get(key) if key is not None else None
    if wiring is not None:
        return wiring.loop(blocks, name)
    loop = ct.interconnect(blocks, inplist=[], outlist=outputs, outputs=outputs, name=name, check_unused=False)
    if key is not None:
        WIRINGS.put(key, _Wiring(loop))
    return loop


def clear_reuse() -> None:
    """Forget the loop structures and prepared runs this process keeps (:data:`WIRINGS`,
    :data:`blocks.diagram.plan.PLANS`, the latest scenarios' prepared runs): the next loop of each structure is built
    afresh.  Compiled code (kept per structure by :mod:`blocks.engines.compiled`) stays."""
    from blocks.diagram.plan import PLANS
    WIRINGS.clear()
    PLANS.clear()
    _prepared_runs.clear()
    _last_prepared[0] = None


def initial_state(loop: ct.InterconnectedSystem, scenario: Scenario | None = None) -> np.ndarray:
    """Start state: the arm on its reference and ``d_hat(0) = 0``, unless the scenario sets other values.

    Plant states are found by name (``q[i]``, ``dq[i]``), so a substituted plant
    (an FMU) with those state names starts in the same place; its other states
    keep their own start values (attribute ``initial_state`` when present).
    """
    s = scenario if scenario is not None else loop.scenario
    q_ref0, dq_ref0, _ = s.trajectory.evaluate(0.0)
    q0 = s.initial["q"] if s.initial["q"] is not None else q_ref0
    dq0 = s.initial["dq"] if s.initial["dq"] is not None else dq_ref0
    n = s.robot.joints.count
    d_hat0 = s.initial["d_hat"] if s.initial["d_hat"] is not None else np.zeros(n)
    x0, offset = np.zeros(loop.nstates), 0
    for block in loop.syslist:
        xs = slice(offset, offset + block.nstates)
        if block.name == "observer":
            dq_meas0 = dq0 + (s.noise.sample(0.0)[1] if s.noise is not None else 0.0)
            x0[xs] = d_hat0 - s.observer_gain @ dq_meas0          # d_hat = Y dq + z
        elif block.name == "plant":
            x0[xs] = np.asarray(getattr(block, "initial_state", np.zeros(block.nstates)), dtype=float)
            labels = list(block.state_labels)
            for name, values in (("q", q0), ("dq", dq0)):
                for i in range(n):
                    label = f"{name}[{i}]"
                    if label not in labels:
                        raise ValueError(f"plant block has no state '{label}' to start the arm on its reference")
                    x0[offset + labels.index(label)] = values[i]
        offset += block.nstates
    return x0


def lumped_disturbance(q, dq, tau, tau_dis, scenario: Scenario) -> np.ndarray:
    """The total disturbance ``d`` the observer estimates, relative to the nominal model (Eq. 2-3).

    ``M^ q'' + N^ q' + G^ = tau + d`` with ``d = tau_dis + (M^ - M) q'' + (N^ - N) q' + (G^ - G)``,
    where ``q''`` is the true acceleration.  With a perfect model ``d = tau_dis``.
    Arrays of shape (..., n).  The true model is the scenario's ``robot``: with a
    substituted plant (an FMU) whose parameters differ from the scenario's, ``d``
    is relative to the scenario's robot, not to that plant.
    """
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__} {scenario!r:.80}")
    arrays = joint_arrays({"q": q, "dq": dq, "tau": tau, "tau_dis": tau_dis}, scenario.robot.joints)
    rows = [np.moveaxis(a, -1, 0) for a in arrays]
    arm = scenario.robot
    d = lumped_disturbance_rows(arm.arm_kernels, arm.kernel_params(), scenario.nominal.kernel_params(), *rows)
    return np.moveaxis(d, 0, -1)


def simulate(scenario: Scenario | str = "paper", observer: bool = True, plant=None, engine: str = "auto",
             progress: Callable[[float], None] | None = None) -> ct.TimeResponseData:
    """Simulate the Figure-2 loop of a scenario on its uniform output grid.

    Parameters
    ----------
    scenario : Scenario or str
        A scenario or the name/path of one (default: the built-in ``paper``).
    observer : bool
        With or without the disturbance observer.
    plant : control.NonlinearIOSystem, optional
        A replacement plant (for example an FMU loaded with :func:`fmu.load`).
    engine : {"auto", "compiled", "fast", "python-control"}
        ``compiled`` runs the loop's generated, numba-compiled module
        (:mod:`blocks.engines.compiled`: Dormand-Prince 5(4) with ``solve_ivp``'s RK45
        step control); ``fast`` the numpy engine (:class:`~blocks.engines.fastsim.CompiledLoop`,
        ``solve_ivp``'s solvers); ``python-control`` calls
        :func:`control.input_output_response` on the same interconnected
        system.  ``auto`` takes ``compiled`` when it can run the loop and
        ``fast`` otherwise (see :func:`select_engine`).
    progress : callable, optional
        Called with the fraction of simulated time done (0..1) as the solver
        advances, at most every 0.2 s of wall time, and with 1.0 at the end.

    Returns
    -------
    control.TimeResponseData
        Outputs by name: ``q[i]``, ``dq[i]``, ``q_ref[i]``, ``dq_ref[i]``,
        ``ddq_ref[i]``, ``tau[i]``, ``tau_dis[i]``, ``d_hat[i]`` (with the
        observer), ``d[i]`` (the lumped disturbance the observer estimates, see
        :func:`lumped_disturbance`) and ``q_meas[i]``, ``dq_meas[i]`` with noise.
        States are the loop's states.  Time in s.

    Raises
    ------
    SimulationError
        If the solver fails or the state diverges; the message says when and why.
    ValueError
        If ``engine`` is unknown.
    blocks.engines.compiled.CompiledUnavailable
        If ``engine="compiled"`` cannot run: numba is not installed (the
        message names the extra), a block has no kernels (it names the
        block) or the scenario's solver is not RK45.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    s = _as_scenario(scenario)
    if not isinstance(observer, bool):
        raise TypeError(f"observer must be True or False, got {observer!r}")
    callable_or_none(progress, "progress")
    if plant is not None and (s.controller is not None or engine == "python-control"):
        refuse_hybrid(plant, "python-control" if s.controller is None else "sampled")    # it would skip events
    if s.controller is not None:            # the digital controller: a sampled-data loop
        from blocks.figure2.digital_loop import simulate_sampled
        return simulate_sampled(s, observer=observer, plant=plant, progress=progress, engine=engine)
    sim = s.simulation
    t_grid = sim.time_grid
    budget = Budget.from_env()
    budget = prepare_reference(s, budget)   # a task-space path's IK, within the budget, before the loop needs it
    run = _prepared(s, observer) if plant is None and engine != "python-control" else _Prepared(s, observer, plant)
    loop = run.loop
    budget = check_run(s, observer, budget, estimate=run.estimate())
    if engine in ("auto", "compiled"):
        engine = select_engine(engine, run.auto_reason(sim.method) if engine == "auto"
                               else run.compiled_reason(sim.method))
    # the run's numbers: the scenario's start state, and the bounds of its states from the scenario (not from names)
    context = Context(float(t_grid[0]), run.x0, bounds=run.bounds(), budget=budget)
    if engine == "compiled":
        stepper = run.compiled_engine()
    elif engine == "fast":
        stepper = NumpyEngine(loop, sim.method)
    else:
        stepper = PythonControlEngine(loop, sim.method)
    states, outputs, d_rows = advance(stepper, context, t_grid, Solver.of(sim), what=f"scenario '{s.name}'",
                                      progress=progress, rows=("d",))
    with_d = d_rows > 0                      # the compiled engine's grid pass gave d already, as the last rows
    resp = loop_response(t_grid, outputs, states, run.labels, run.state_labels, s, observer, run.title, loop.name,
                         with_d=with_d)
    resp.engine = engine                # the engine that ran ("auto" resolved)
    return resp


class _Prepared:
    """What every run of one (scenario, observer, plant) needs before integrating: the interconnection, its start
    state, the response's labels, and the compiled engine when one is made.  Kept per scenario (see
    :func:`_prepared`) so that repeated runs do no Python work twice."""

    def __init__(self, s: Scenario, observer: bool, plant=None) -> None:
        self.scenario, self.observer = s, observer
        self.loop = loop = closed_loop(s, observer=observer, plant=plant)
        self.x0 = initial_state(loop, s)
        self.x0.setflags(write=False)
        self.labels = list(loop.output_labels)
        self.state_labels = list(loop.state_labels)
        self.title = f"{s.name}: {'with' if observer else 'without'} disturbance observer"
        self._reasons: dict[str, str | None] = {}
        self._compiled = self._estimate = self._bounds = None

    def estimate(self):
        """What a run needs (:func:`blocks.figure2.run_limits.estimate_run`), for the budget check."""
        if self._estimate is None:
            self._estimate = estimate_run(self.scenario, self.observer)
        return self._estimate

    def bounds(self):
        """The divergence bounds of the loop's states (:func:`blocks.figure2.physical_bounds.state_bounds`)."""
        if self._bounds is None:
            self._bounds = state_bounds(self.loop, self.scenario)
        return self._bounds

    def compiled_reason(self, method: str) -> str | None:
        """Why the compiled engine cannot run this loop with ``method`` (None: it can)."""
        if method not in self._reasons:
            from blocks.engines.compiled import unavailable_reason
            self._reasons[method] = unavailable_reason(self.loop, method)
        return self._reasons[method]

    def auto_reason(self, method: str) -> str | None:
        """Why ``engine="auto"`` runs numpy (None: compiled): the compiled engine cannot run the loop, or its
        generated code would take too long to compile now
        (:data:`blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS`)."""
        reason = self.compiled_reason(method)
        return reason if reason is not None else self.compiled_engine().auto_reason()

    def compiled_engine(self):
        if self._compiled is None:
            from blocks.engines.compiled import CompiledLoopEngine
            self._compiled = CompiledLoopEngine(self.loop)
        return self._compiled


# Prepared runs of the latest scenarios (scenarios are immutable and hashable; equal ones share an entry)
_PREPARED_KEPT = 16
_prepared_runs: OrderedDict = OrderedDict()
_last_prepared: list = [None]


class _RunKey:
    """``(scenario, observer)`` as a key whose hash is computed once (a scenario's hash serialises its data, and a
    new scenario's key is hashed to look it up and again to keep it)."""

    __slots__ = ("scenario", "observer", "_hash")

    def __init__(self, s: Scenario, observer: bool) -> None:
        self.scenario, self.observer, self._hash = s, observer, hash((s, observer))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other) -> bool:
        return isinstance(other, _RunKey) and self.observer == other.observer and \
            (self.scenario is other.scenario or self.scenario == other.scenario)


def _prepared(s: Scenario, observer: bool) -> _Prepared:
    """The :class:`_Prepared` run of ``s`` with the Python plant, made once and kept for the latest scenarios."""
    last = _last_prepared[0]
    if last is not None and last.scenario is s and last.observer == observer:
        return last
    key = _RunKey(s, observer)
    run = _prepared_runs.get(key)
    if run is None:
        run = _Prepared(s, observer)
        _prepared_runs[key] = run
        while len(_prepared_runs) > _PREPARED_KEPT:
            _prepared_runs.popitem(last=False)
    else:
        _prepared_runs.move_to_end(key)
    _last_prepared[0] = run
    return run

