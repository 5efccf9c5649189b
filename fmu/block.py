"""Load a Model Exchange FMU (FMI 2 or 3) as a python-control nonlinear I/O system.

The returned system is a drop-in block for :func:`control.interconnect`:

* states: the FMU's continuous states, named after their state variables
  (for the dobkit plant ``q[i]``, ``dq[i]``);
* inputs: its real input variables; outputs: its real output variables,
  in model-description order, with their FMU names;
* ``updfcn(t, x, u)`` sets time, states and inputs and returns the state
  derivatives; ``outfcn(t, x, u)`` sets time, states and *only the inputs
  some output depends on* and returns the outputs.

Which inputs an output needs comes from the model structure (FMI 2
``ModelStructure/Outputs`` dependencies, FMI 3 ``Output`` dependencies; an
output without the attribute needs every input).  Engines -- python-control's
own evaluation of an interconnection and :class:`blocks.engines.fastsim.CompiledLoop`
-- evaluate outputs before every input is known, with zeros or stale values
in its place; an FMU whose equations divide by an input (a mass, a length)
would return an error status if that input were set to zero, although no
output needs it.  Those inputs are set only for the state derivatives.

An FMU with event indicators (state events) or a time event announced at
initialization carries ``event_source`` (:class:`fmu.events.FMUEventSource`):
the numpy engine stops at its events and runs its event iteration
(:mod:`fmu.events`); ``event_source`` is None for an FMU without events.

The system is a :class:`blocks.diagram.contract.Block`: its contract declares
exactly those needed inputs as its feedthrough, and ``close()`` (or a
``with`` statement) releases the FMU.  An FMU without continuous states
(a gain, an adder, a table) is a static block.  Attributes:
``initial_state`` (the states after initialization), ``fmu`` (the
:class:`~fmu.instance.FMUInstance`, which owns the native instance
and the extraction folder; ``sys.fmu.close()`` releases them early) and
``model_description``.
"""
from __future__ import annotations

import numpy as np

from blocks.diagram.contract import Block, BlockContract

from .archive import ExtractionLimits, open_extracted
from .description import described, interface, real_variables, require_variables, state_variables, unsupported_features
from .errors import FMUError, FMUModelDescriptionError, FMUUnsupportedError
from .events import FMUEventSource, has_events
from .instance import FMUInstance

__all__ = ["load", "output_feedthrough", "output_dependencies", "FMUBlock"]


class FMUBlock(Block):
    """A Model Exchange FMU as a block; :meth:`close` (or leaving a ``with`` block) releases the FMU."""

    def close(self) -> None:
        """Free the FMU's native instance and its extraction folder (further calls raise)."""
        fmu = getattr(self, "fmu", None)
        if fmu is not None:
            fmu.close()


def output_dependencies(model_description, input_names: list[str]) -> dict[str, frozenset[str]]:
    """For each output variable, the inputs among ``input_names`` it depends on directly.

    From ``ModelStructure``: FMI 2 ``Outputs/Unknown``, FMI 3 ``Output``
    elements.  An output without a ``dependencies`` attribute, or missing from
    the model structure, depends on every input (the standard's default).

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    input_names : list of str
        Names of the input variables of interest.
    """
    wanted = frozenset(input_names)
    listed = {u.variable.name: u for u in model_description.outputs}
    deps: dict[str, frozenset[str]] = {}
    for v in model_description.modelVariables:
        if v.causality != "output":
            continue
        unknown = listed.get(v.name)
        if unknown is None or unknown.dependencies is None:
            deps[v.name] = wanted
        else:
            deps[v.name] = frozenset(d.name for d in unknown.dependencies) & wanted
    return deps


def output_feedthrough(model_description, input_names: list[str]) -> frozenset[str]:
    """Inputs that reach some output directly, from ``ModelStructure`` (all inputs if unknown).

    Parameters
    ----------
    model_description : fmpy.model_description.ModelDescription
    input_names : list of str
        Names of the input variables of interest.
    """
    deps = output_dependencies(model_description, input_names)
    return frozenset().union(*deps.values()) if deps else frozenset()


def load(path, name: str = "plant", start_values: dict | None = None, start_time: float = 0.0,
         limits: ExtractionLimits | None = None, extract_to=None, scenario=None) -> FMUBlock:
    """A Model Exchange FMU as a :class:`control.NonlinearIOSystem` (an :class:`FMUBlock`).

    Parameters
    ----------
    path : str, pathlib.Path or ExtractedFMU
        The ``.fmu`` file (FMI 2.0 or 3.0, Model Exchange), or an extraction
        to reuse (:func:`~fmu.archive.extract_fmu`; left in place).
    name : str
        Name of the system (the block name in an interconnection).
    start_values : dict, optional
        Variable name -> start value applied before initialization: parameters
        (e.g. ``{"m1": 6.0, "disturbance_friction": True}``) and state start
        values.  They take precedence over the values from ``scenario``.
    start_time : float
        Time (s) at which the FMU is initialized.
    limits : ExtractionLimits, optional
        Archive size limits.
    extract_to : str or pathlib.Path, optional
        Parent folder of the private extraction folder (default: system temp).
    scenario : Scenario or str, optional
        Make the FMU the scenario's *true* plant: set its robot parameters
        (``m1`` ... ``d4``), disturbance switches and disturbance parameters
        to the scenario's values, and its start state to the scenario's
        (as :func:`~fmu.cosimulate` does with ``parameters="scenario"``).
        Without it the FMU keeps its own start values -- those of its
        export -- so ``blocks.simulate(s, plant=load(path))`` simulates the
        exported plant, whatever scenario ``s`` says.  Parameters the FMU does
        not declare are listed in a warning.

    Returns
    -------
    control.NonlinearIOSystem
        With attributes ``feedthrough``, ``initial_state``, ``fmu``, ``model_description``.

    Raises
    ------
    FMUUnsupportedError
        If the FMU is outside the supported subset (see Notes); the message names the feature.
    FMUMissingVariablesError
        With ``scenario``, if the FMU lacks the plant's states ``q[i]``, ``dq[i]`` or inputs ``tau[i]``.
    FMUError
        (other subclasses) if the archive, the model description, the platform
        binary or the instantiation is bad; :class:`~fmu.errors.FMUStepError`
        later if the FMU returns an error status while being evaluated, and
        :class:`~fmu.errors.FMUError` for any evaluation after ``sys.fmu.close()``.

    Notes
    -----
    Supported subset: Model Exchange FMUs (FMI 2.0 or 3.0) with scalar
    Real / Float64 inputs and outputs, with or without continuous states (an
    FMU without states is a static block), with or without events: state
    events (event indicators), time events, event iteration, states the FMU
    re-initialises and ``terminateSimulation`` are handled by the numpy
    engine (:mod:`fmu.events`: ``blocks.simulate(..., engine="fast")``,
    :func:`fmu.simulate_loop`); the other engines refuse a loop with such a
    block.  A block with events runs once, from ``start_time``: its discrete
    states move on with the run, so load it again for another run.  Start values of every type can be set (FMI 3 enumerations as
    Int64), checked against the range of their type first
    (:mod:`fmu.start_values`).  Refused at load, with the feature named
    (:func:`fmu.simulate_fmu` runs the first two on its own):

    * FMI 3 array variables (``Dimension``) among inputs, outputs or states;
    * inputs or outputs of another type (Integer, Boolean, String, Float32, ...);
    * inputs of discrete variability (settable only at events);
    * FMI 3 clocks.

    Not detected, so do not use them: FMUs without event indicators or time
    events that need ``completedIntegratorStep`` to request step events, or
    whose discrete variables change in continuous time.

    The FMU's native code runs in this process: loading runs the shared
    library's constructors, and a crashing FMU ends Python -- load an
    untrusted FMU only in a sandbox.  Each call sets time, states and the
    inputs it needs before evaluating, so the block may be evaluated at any
    time and state, in any order (as solvers do).  An error status raises
    :class:`~fmu.errors.FMUStepError` with the FMU's own log lines of the
    failing call (the FMU is instantiated with logging on).
    Loading is serialised by a lock (fmpy changes the working directory
    while it loads a library); evaluating one instance from several threads
    at once is not supported.

    Examples
    --------
    The plant FMU as the true plant of the paper scenario (exporting it
    needs a C compiler):

    >>> import blocks, fmu
    >>> plant = fmu.load(fmu.export_plant("plant.fmu"), scenario="paper")
    >>> plant.input_labels[:2], plant.state_labels[2]
    (['tau[0]', 'tau[1]'], 'q[2]')
    >>> loop = blocks.closed_loop("paper", plant=plant)
    >>> plant.close()
    """
    extracted, owned = open_extracted(path, limits=limits, parent=extract_to)
    try:
        md = described(extracted)
        interface(md, "ModelExchange", extracted.source)        # no Model Exchange: say what it offers, first
        unsupported = unsupported_features(md, "ModelExchange", state_events=True)
        if unsupported:
            raise FMUUnsupportedError(f"{extracted.source}: uses FMI features that dobkit does not support as "
                                      "ModelExchange: " + "; ".join(unsupported))
        start = dict(start_values or {})
        if scenario is not None:
            start = _scenario_start_values(extracted, scenario) | start
    except BaseException:
        if owned:
            extracted.cleanup()
        raise
    # checked above; events=True keeps a time event announced at initialization
    inst = FMUInstance(extracted, kind="ModelExchange", start_values=start, name=name, start_time=start_time,
                       adopt=owned, check_interface=False, events=True)
    try:
        if inst.terminate_requested:
            raise FMUError(f"{inst.source}: the FMU asked to end the simulation (terminateSimulation) during "
                           f"initialization at t = {start_time:g} s")
        md = inst.model_description
        state_names = [v.name for v in state_variables(md, inst.source)]
        inputs = [v.name for v in real_variables(md, "input")]
        outputs = [v.name for v in real_variables(md, "output")]
        if not outputs:
            raise FMUModelDescriptionError(f"{inst.source}: the FMU has no real output variables to connect")
        in_vr = inst.value_references(inputs)
        out_vr = inst.value_references(outputs)
        deps = output_dependencies(md, inputs)
        needed = [j for j, n in enumerate(inputs) if any(n in deps[o] for o in outputs)]
        needed_vr = inst.value_references([inputs[j] for j in needed])
        initial_state = inst.get_states() if state_names else np.zeros(0)
    except BaseException:
        inst.close()
        raise
    needed_idx = np.array(needed, dtype=int)

    def prepare(t, x) -> None:
        inst.set_time(float(t))
        if state_names:
            inst.set_states(x)

    def update(t, x, u, params):
        prepare(t, x)
        if inputs:
            inst.set_real(in_vr, u)
        return inst.derivatives()

    def output(t, x, u, params):
        prepare(t, x)
        if needed:      # only the inputs the outputs depend on: the others may be zeros or stale here
            inst.set_real(needed_vr, np.asarray(u, dtype=float)[needed_idx])
        return inst.get_real(out_vr)

    signals = dict(name=name, inputs=inputs, outputs=outputs)
    if state_names:     # python-control refuses a state count of 0 without an update function
        signals["states"] = state_names
    sys = FMUBlock(update if state_names else None, output, contract=BlockContract(
        feedthrough=frozenset(inputs[j] for j in needed)), **signals)
    sys.initial_state = initial_state
    sys.event_source = FMUEventSource(inst, name, start_time) if has_events(inst) else None
    sys.fmu = inst
    sys.model_description = md
    return sys


def _scenario_start_values(extracted, scenario) -> dict:
    """The scenario's true-plant parameters and start state, for an FMU with the plant's signals."""
    from blocks.scenarios.scenario import Scenario, load_scenario  # the scenario machinery only when asked for

    from .arm_match import check_scenario_arm
    from .scenario_values import plant_start_values
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    md = described(extracted)
    joints = range(s.robot.joints.count)
    require_variables(md, [f"q[{i}]" for i in joints] + [f"dq[{i}]" for i in joints] + [f"tau[{i}]" for i in joints],
                      source=f"{extracted.source} (as the true plant of scenario {s.name!r})")
    try:
        check_scenario_arm(extracted, md, s)
    except FMUError as err:
        raise type(err)(f"{extracted.source} (as the true plant of scenario {s.name!r}): {err}") from None
    return plant_start_values(s, {v.name for v in md.modelVariables}, "scenario", stacklevel=4)
