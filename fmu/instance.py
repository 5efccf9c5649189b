"""One running FMU instance (FMI 2 or 3, Model Exchange or Co-Simulation).

:class:`FMUInstance` extracts the archive safely, checks the model
description and the platform binary, instantiates, applies start values and
initializes, so that it is ready to simulate.  It hides the differences
between FMI 2 and FMI 3 behind a few numpy-level calls (``get_real``,
``set_real``, ``set_time``, ``set_states``, ``derivatives``, ``do_step``) and
turns every error status into an :class:`~fmu.errors.FMUStepError`
that names the FMI function, the simulation time, the status and the FMU's
own log messages.

Instances are made with logging on, so that an FMU explains its errors to
the importer rather than to standard output; log messages reach the
instance that logged them (:mod:`fmu.logger`), which keeps the most recent
ones.  An error names the messages logged during the failing call.  Every
call on a closed instance raises :class:`~fmu.errors.FMUError` instead
of reaching freed native memory.

Loading runs the FMU's native code in this process, and fmpy changes the
working directory while it loads a library; loading is serialised by a lock.
"""
from __future__ import annotations

import contextlib
import ctypes
import math
import os
import threading
import weakref
from pathlib import Path

import numpy as np

from . import logger
from .archive import ExtractedFMU, ExtractionLimits, open_extracted
from .description import (
    array_shape,
    binary_path,
    described,
    event_indicator_count,
    fmi_major,
    interface,
    intermediate_update_names,
    state_count,
    unsupported_features,
)
from .errors import FMUError, FMUInstantiationError, FMUModelDescriptionError, FMUStepError, FMUUnsupportedError
from .logger import STATUS_NAMES, status_name
from .start_values import checked_start_value

__all__ = ["FMUInstance", "STATUS_NAMES"]

_LOAD_LOCK = threading.Lock()
_MAX_MESSAGES = 200
_FMI3_INTEGER_SETTERS = {"Int8": "setInt8", "UInt8": "setUInt8", "Int16": "setInt16", "UInt16": "setUInt16",
                         "Int32": "setInt32", "UInt32": "setUInt32", "Int64": "setInt64", "UInt64": "setUInt64",
                         "Enumeration": "setInt64"}
_FMI3_GETTERS = {"Float64": "getFloat64", "Float32": "getFloat32", "Boolean": "getBoolean", "String": "getString",
                 "Enumeration": "getInt64", **{t: "g" + s[1:] for t, s in _FMI3_INTEGER_SETTERS.items() if t != "Enumeration"}}
_FMI2_GETTERS = {"Real": "getReal", "Integer": "getInteger", "Enumeration": "getInteger", "Boolean": "getBoolean",
                 "String": "getString"}


def _intermediate_callback(holder: dict):
    """The FMI 3 intermediate-update callback: sets the inputs the provider gives for the asked time.

    ``holder`` (shared with the instance, never the instance itself, so no
    reference cycle keeps it alive) has ``provider`` -- None, or
    ``(value_references, f)`` with ``f(t) -> values`` -- ``set`` (the
    low-level setter) and ``error`` (the first exception raised here, which
    cannot cross back into C; the master raises it after the step).
    """

    def callback(env, time, set_requested, get_allowed, step_finished, can_return_early, early_return_requested,
                 early_return_time):
        provider = holder["provider"]
        if not set_requested or provider is None or holder["error"] is not None:
            return
        try:
            vrs, values_at = provider
            values = np.ascontiguousarray(values_at(float(time)), dtype=float)
            holder["set"](vrs, len(vrs), values.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
        except BaseException as err:  # noqa: BLE001 - nothing may propagate into the FMU's code
            holder["error"] = err

    return callback


def _release(fmu, extracted, owned: bool, state: dict) -> None:
    """Free the instance and its library, then delete an owned extraction folder (finalizer: no self)."""
    state["closed"] = True
    try:
        if fmu is not None and state.get("instantiated"):
            # after an error or fatal status the standard allows only freeing (no terminate)
            if state.get("initialized") and not state.get("terminated") and not state.get("failed"):
                with contextlib.suppress(Exception):
                    fmu.terminate()
            with contextlib.suppress(Exception):
                fmu.freeInstance()  # also unloads the library
        elif fmu is not None:
            with contextlib.suppress(Exception):
                fmu.freeLibrary()
    finally:
        if state.get("log_key") is not None:
            logger.unregister(state["log_key"])
        if owned:
            extracted.cleanup()


class FMUInstance:
    """An instantiated and initialized FMU, ready to simulate.

    Parameters
    ----------
    path : str, pathlib.Path or ExtractedFMU
        The ``.fmu`` file, or an extraction to reuse (from
        :func:`~fmu.archive.extract_fmu`; it is then left in place at
        :meth:`close`, its owner removes it).
    kind : {"ModelExchange", "CoSimulation"}
        Interface to instantiate.
    start_values : dict, optional
        Variable name -> start value, applied before initialization
        (parameters, state start values, inputs).
    name : str, optional
        Instance name (default: the model identifier).
    start_time : float
        Simulation start time (s).
    limits : ExtractionLimits, optional
        Archive size limits.
    extract_to : str or pathlib.Path, optional
        Parent folder for the private extraction folder (default: system temp).
    adopt : bool
        With an ``ExtractedFMU`` as ``path``: take it over and remove it at
        :meth:`close` as if it had been extracted here.
    check_interface : bool
        Refuse an FMU outside the supported subset (default).  False lets a
        check run an FMU whose signals dobkit cannot couple.
    events : bool
        Model Exchange with event handling (:func:`fmu.simulate_fmu`): state
        events, time events, arrays and non-real outputs are accepted, and
        the time of the next time event announced at initialization is kept
        in ``next_event_time`` instead of being refused.

    Raises
    ------
    FMUUnsupportedError
        If the FMU uses a feature outside the supported subset
        (:func:`~fmu.description.unsupported_features`; for Model
        Exchange also a time event announced at initialization).
    FMUError
        (other subclasses) for a bad archive, model description, binary or
        instantiation, and from any call after :meth:`close`.

    Attributes
    ----------
    model_description : fmpy.model_description.ModelDescription
    fmi_version : int
        2 or 3.
    variables : dict
        Variable name -> fmpy ``ModelVariable``.
    messages : list of str
        Log messages received from the FMU (most recent last).
    time : float
        Current simulation time (s) as known to this wrapper.
    """

    def __init__(self, path, kind: str = "ModelExchange", start_values: dict | None = None, name: str | None = None,
                 start_time: float = 0.0, limits: ExtractionLimits | None = None, extract_to=None,
                 adopt: bool = False, check_interface: bool = True, events: bool = False):
        self.path = Path(path.source) if isinstance(path, ExtractedFMU) else Path(path)
        self.source = self.path.name
        self.kind = kind
        self._log = logger.MessageLog(_MAX_MESSAGES)
        self.messages: list[str] = self._log.entries
        self._state = {"instantiated": False, "initialized": False, "terminated": False, "failed": False,
                       "closed": False, "log_key": None}
        self._fmu = None
        self._check_interface = check_interface
        self._events = events
        self.next_event_time: float | None = None     # time event announced by the last event iteration (s)
        self.terminate_requested = False               # the FMU asked to end the simulation
        # the provider of intermediate inputs during an FMI 3 step (see set_input_provider)
        self._intermediate = {"provider": None, "error": None, "set": None}
        self._marked_intermediate = None
        self.extracted, owned = open_extracted(path, limits=limits, parent=extract_to)
        self._owned = owned or adopt
        self._finalizer = weakref.finalize(self, _release, None, self.extracted, self._owned, self._state)
        try:
            self._open(name, start_values or {}, float(start_time))
        except BaseException:
            self.close()
            raise

    # ---- construction -----------------------------------------------------------------------------------------

    def _open(self, name, start_values, start_time) -> None:
        root = self.extracted.root
        md = described(self.extracted)
        self.model_description = md
        self.fmi_version = fmi_major(md)
        element = interface(md, self.kind, self.source)
        unsupported = unsupported_features(md, self.kind, events=self._events) if self._check_interface else []
        if unsupported:
            raise FMUUnsupportedError(f"{self.source}: uses FMI features that dobkit does not support as "
                                      f"{self.kind}: " + "; ".join(unsupported))
        binary_path(root, md, self.kind, self.source)
        self.model_identifier = element.modelIdentifier
        self.variables = {v.name: v for v in md.modelVariables}
        self.n_states = state_count(md, self.source)
        self.n_event_indicators = event_indicator_count(md, self.source)
        self.time = start_time
        unknown = sorted(set(start_values) - set(self.variables))
        if unknown:
            raise FMUModelDescriptionError(f"{self.source}: start values given for unknown variable(s) {unknown}")

        self._fmu = self._load_library(md, name)
        self._finalizer.detach()
        self._finalizer = weakref.finalize(self, _release, self._fmu, self.extracted, self._owned, self._state)
        self._instantiate()
        self._bind_low_level()
        self._apply_start_values(start_values)
        self._initialize(start_time)

    def _load_library(self, md, name):
        from fmpy.fmi2 import FMU2Model, FMU2Slave
        from fmpy.fmi3 import FMU3Model, FMU3Slave
        classes = {(2, "ModelExchange"): FMU2Model, (2, "CoSimulation"): FMU2Slave,
                   (3, "ModelExchange"): FMU3Model, (3, "CoSimulation"): FMU3Slave}
        cls = classes[(self.fmi_version, self.kind)]
        kwargs = dict(guid=md.guid, unzipDirectory=str(self.extracted.root), modelIdentifier=self.model_identifier,
                      instanceName=name or self.model_identifier)
        with _LOAD_LOCK:
            # fmpy changes into the library folder and does not change back if loading fails
            cwd = os.getcwd()
            try:
                return cls(**kwargs)
            except AttributeError as err:  # a missing FMI function in the library
                raise FMUError(f"{self.source}: the binary lacks an FMI {self.fmi_version} function: {err}") from None
            except Exception as err:
                raise FMUError(f"{self.source}: cannot load the binary: {err}") from None
            finally:
                os.chdir(cwd)

    def _instantiate(self) -> None:
        fmu = self._fmu
        try:
            if self.fmi_version == 2:
                # one process-wide logger; this instance's key comes back as componentEnvironment
                self._state["log_key"] = logger.register(self._log, fmu.instanceName)
                fmu.instantiate(callbacks=logger.fmi2_callbacks(self._state["log_key"]), loggingOn=True)
            elif self.kind == "CoSimulation" and self.provides_intermediate_update:
                fmu.instantiate(logMessage=logger.fmi3_log_function(self._log), loggingOn=True,
                                intermediateUpdate=_intermediate_callback(self._intermediate))
            else:
                fmu.instantiate(logMessage=logger.fmi3_log_function(self._log), loggingOn=True)
        except Exception as err:
            detail = " ".join(self.messages[-3:]) or str(err)
            token = "GUID" if self.fmi_version == 2 else "instantiationToken"
            hint = (f" (no message from the FMU; a {token} in modelDescription.xml "
                    f"({self.model_description.guid}) that does not match the binary is a common cause)"
                    if not self.messages else "")
            raise FMUInstantiationError(f"{self.source}: the FMU refused to instantiate as {self.kind}: {detail}"
                                        f"{hint}") from None
        self._state["instantiated"] = True

    def _bind_low_level(self) -> None:
        f, c = self._fmu, self._fmu.component
        if self.fmi_version == 2:
            self._get_real = lambda vr, n, out, count: f.fmi2GetReal(c, vr, n, out)
            self._set_real = lambda vr, n, val, count: f.fmi2SetReal(c, vr, n, val)
            self._vr_type = ctypes.c_uint
        else:
            self._get_real = lambda vr, n, out, count: f.fmi3GetFloat64(c, vr, n, out, count)
            self._set_real = lambda vr, n, val, count: f.fmi3SetFloat64(c, vr, n, val, count)
            self._vr_type = ctypes.c_uint32
        self._intermediate["set"] = lambda vr, n, val: self._set_real(vr, n, val, getattr(vr, "count", n))
        if self.kind == "ModelExchange":
            get_der = "fmi2GetDerivatives" if self.fmi_version == 2 else "fmi3GetContinuousStateDerivatives"
            prefix = f"fmi{self.fmi_version}"
            self._set_time = getattr(f, f"{prefix}SetTime")
            self._set_states = getattr(f, f"{prefix}SetContinuousStates")
            self._get_states = getattr(f, f"{prefix}GetContinuousStates")
            self._get_der = getattr(f, get_der)

    # ---- error translation ------------------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._state["closed"]:
            raise FMUError(f"{self.source}: the FMU instance is closed; load the FMU again to use it")

    @contextlib.contextmanager
    def _calling(self, what: str, t: float):
        from fmpy.fmi1 import FMICallException
        self._check_open()
        mark = self._log.count
        try:
            yield
        except FMICallException as err:
            status = status_name(err.status)
            if status in ("error", "fatal"):
                self._state["failed"] = True
            new = self._log.since(mark)  # only what this call logged, never older messages
            detail = (": " + " ".join(new)) if new else " (the FMU logged no message)"
            raise FMUStepError(f"{self.source}: {err.function} returned status '{status}' at t = {t:.9g} s "
                               f"during {what}{detail}", time=t, status=status, function=err.function,
                               messages=new) from None

    # ---- values -----------------------------------------------------------------------------------------------

    def value_references(self, names) -> ctypes.Array:
        """A ctypes array of value references for variable names (raises on unknown names)."""
        self._check_open()
        unknown = [n for n in names if n not in self.variables]
        if unknown:
            raise FMUModelDescriptionError(f"{self.source}: unknown variable(s) {unknown}")
        refs = (self._vr_type * len(names))(*[self.variables[n].valueReference for n in names])
        # FMI 3 arrays: one value reference carries all elements (nValues in the calls)
        refs.count = sum(self.size(n) for n in names)
        return refs

    def size(self, name: str) -> int:
        """Number of values of a variable: 1 for a scalar, the element count of an FMI 3 array."""
        return math.prod(array_shape(self.variables[name], self.source))

    def get_real(self, vrs: ctypes.Array, out: np.ndarray | None = None) -> np.ndarray:
        """Values of real variables (value references from :meth:`value_references`)."""
        self._check_open()
        n = len(vrs)
        count = getattr(vrs, "count", n)
        out = np.empty(count) if out is None else out
        if n:
            with self._calling("reading outputs", self.time):
                self._get_real(vrs, n, out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), count)
        return out

    def set_real(self, vrs: ctypes.Array, values) -> None:
        """Set real variables (value references from :meth:`value_references`)."""
        self._check_open()
        n = len(vrs)
        if n:
            arr = np.ascontiguousarray(values, dtype=float)
            count = getattr(vrs, "count", n)
            if arr.size != count:
                raise FMUError(f"{self.source}: {count} values are needed for these variables, got {arr.size}")
            with self._calling("setting inputs", self.time):
                self._set_real(vrs, n, arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), count)

    def get_integer(self, name: str) -> int:
        """Value of one integer variable (FMI 2 Integer, FMI 3 Int32) by name."""
        vr = [self.variables[name].valueReference]
        with self._calling(f"reading {name}", self.time):
            values = self._fmu.getInteger(vr) if self.fmi_version == 2 else self._fmu.getInt32(vr)
        return int(values[0])

    def _apply_start_values(self, start_values: dict) -> None:
        for name, value in start_values.items():
            v = self.variables[name]
            if v.causality == "structuralParameter":
                raise FMUUnsupportedError(f"{self.source}: start value {name} = {value!r}: structural parameters stay "
                                          "at their start values in dobkit (array sizes are read from them)")
            count = math.prod(array_shape(v, self.source))
            values = checked_start_value(v, value, self.fmi_version, count, self.source)
            vr = [v.valueReference]
            with self._calling(f"setting the start value of {name}", self.time):
                if v.type in ("Real", "Float64"):
                    self.set_real(self.value_references([name]), values)
                elif v.type == "Float32":
                    self._fmu.setFloat32(vr, values)
                elif v.type == "String":
                    self._fmu.setString(vr, values)
                elif v.type == "Boolean":
                    self._fmu.setBoolean(vr, values)
                elif v.type in ("Integer", "Enumeration") and self.fmi_version == 2:
                    self._fmu.setInteger(vr, values)
                elif v.type in _FMI3_INTEGER_SETTERS:
                    # FMI 3 enumerations are Int64; each integer type has its own setter
                    getattr(self._fmu, _FMI3_INTEGER_SETTERS[v.type])(vr, values)
                else:
                    raise FMUModelDescriptionError(f"{self.source}: cannot set a start value for {name} of type "
                                                   f"{v.type}")

    def read(self, names: list[str]) -> np.ndarray:
        """Values of variables of any type but String and Binary, as floats, arrays flattened (row-major).

        Booleans read as 0 and 1; integers exactly up to 2**53.
        """
        self._check_open()
        out = []
        for name in names:
            v = self.variables[name]
            if v.type in ("Real", "Float64"):
                out.append(self.get_real(self.value_references([name])))
                continue
            getter = (_FMI2_GETTERS if self.fmi_version == 2 else _FMI3_GETTERS).get(v.type)
            if getter is None or v.type == "String":
                raise FMUUnsupportedError(f"{self.source}: cannot read {name} of type {v.type} as a number")
            with self._calling(f"reading {name}", self.time):
                args = ([v.valueReference],) if self.fmi_version == 2 else ([v.valueReference], self.size(name))
                out.append(np.asarray(getattr(self._fmu, getter)(*args), dtype=float))
        return np.concatenate(out) if out else np.zeros(0)

    def _initialize(self, start_time: float) -> None:
        f = self._fmu
        with self._calling("initialization", start_time):
            if self.fmi_version == 2:
                f.setupExperiment(startTime=start_time)
                f.enterInitializationMode()
                f.exitInitializationMode()
            else:
                f.enterInitializationMode(startTime=start_time)
                f.exitInitializationMode()
            self._state["initialized"] = True
            if self.kind == "ModelExchange":
                self._leave_event_mode()

    def _leave_event_mode(self) -> None:
        self.update_discrete_states()
        if self.terminate_requested and not self._events:
            raise FMUError(f"{self.source}: the FMU asked to terminate during initialization")
        if self.next_event_time is not None and not self._events:
            raise FMUUnsupportedError(f"{self.source}: the FMU announces a time event at t = {self.next_event_time:.9g} "
                                      "s; time events are not supported by a block (dobkit integrates Model Exchange "
                                      "blocks as continuous systems; fmu.simulate_fmu handles events)")
        if not self.terminate_requested:
            self.enter_continuous_time_mode()

    # ---- events (Model Exchange) ----------------------------------------------------------------------------

    def update_discrete_states(self, max_iterations: int = 1000) -> bool:
        """Event iteration: ``fmi2NewDiscreteStates`` / ``fmi3UpdateDiscreteStates`` until no update is needed.

        Sets :attr:`next_event_time` (None if the FMU announces none) and
        :attr:`terminate_requested`.

        Returns
        -------
        bool
            Whether the FMU changed the values of its continuous states (re-initialisation).
        """
        f = self._fmu
        changed = False
        for _ in range(max_iterations):
            # (discrete states need update, terminate, nominals changed, values changed, time event?, its time)
            with self._calling("the event iteration", self.time):
                info = f.newDiscreteStates() if self.fmi_version == 2 else f.updateDiscreteStates()
            changed = changed or bool(info[3])
            if info[1]:
                self.terminate_requested = True
                break
            if not info[0]:
                break
        else:
            raise FMUError(f"{self.source}: the event iteration at t = {self.time:.9g} s did not converge in "
                           f"{max_iterations} iterations")
        self.next_event_time = float(info[5]) if info[4] else None
        return changed

    def enter_event_mode(self) -> None:
        """Model Exchange: enter Event Mode at the time and states last set."""
        with self._calling("entering event mode", self.time):
            self._fmu.enterEventMode()

    def enter_continuous_time_mode(self) -> None:
        """Model Exchange: leave Event Mode."""
        with self._calling("entering continuous-time mode", self.time):
            self._fmu.enterContinuousTimeMode()

    def completed_integrator_step(self) -> tuple[bool, bool]:
        """Tell the FMU an integrator step is accepted; ``(enter event mode?, terminate?)``."""
        with self._calling("completing an integrator step", self.time):
            step_event, terminate = self._fmu.completedIntegratorStep()
        return bool(step_event), bool(terminate)

    def event_indicators(self) -> np.ndarray:
        """The event indicators at the time, states and inputs last set."""
        out = np.empty(self.n_event_indicators)
        if out.size:
            with self._calling("evaluating the event indicators", self.time):
                self._fmu.getEventIndicators(out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), out.size)
        return out

    # ---- Model Exchange ---------------------------------------------------------------------------------------

    def set_time(self, t: float) -> None:
        """Set the Model Exchange time ``t`` (s)."""
        with self._calling("setting the time", t):
            self._set_time(self._fmu.component, t)
        self.time = t

    def set_states(self, x) -> None:
        """Set the continuous states (in the order of ``ModelStructure/Derivatives``)."""
        arr = np.ascontiguousarray(x, dtype=float)
        with self._calling("setting the states", self.time):
            self._set_states(self._fmu.component, arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), arr.size)

    def get_states(self) -> np.ndarray:
        """The continuous states."""
        out = np.empty(self.n_states)
        with self._calling("reading the states", self.time):
            self._get_states(self._fmu.component, out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), out.size)
        return out

    def derivatives(self) -> np.ndarray:
        """The state derivatives at the time, states and inputs last set."""
        out = np.empty(self.n_states)
        with self._calling("evaluating the state derivatives", self.time):
            self._get_der(self._fmu.component, out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), out.size)
        return out

    # ---- Co-Simulation ----------------------------------------------------------------------------------------

    @property
    def max_output_derivative_order(self) -> int:
        """``maxOutputDerivativeOrder`` of the Co-Simulation interface (0 if none or not Co-Simulation)."""
        cs = self.model_description.coSimulation
        return int(getattr(cs, "maxOutputDerivativeOrder", 0) or 0) if cs is not None else 0

    @property
    def can_interpolate_inputs(self) -> bool:
        """FMI 2 ``canInterpolateInputs``: inputs may follow slopes set by :meth:`set_input_derivatives`."""
        cs = self.model_description.coSimulation
        return self.fmi_version == 2 and cs is not None and bool(getattr(cs, "canInterpolateInputs", False))

    @property
    def provides_intermediate_update(self) -> bool:
        """FMI 3 ``providesIntermediateUpdate``: the FMU asks for inputs during a step (:meth:`set_input_provider`)."""
        cs = self.model_description.coSimulation
        return self.fmi_version == 3 and cs is not None and bool(getattr(cs, "providesIntermediateUpdate", False))

    def intermediate_inputs(self) -> set[str]:
        """Names of the FMI 3 inputs that may be set during a step (``intermediateUpdate="true"``)."""
        if self._marked_intermediate is None:
            self._marked_intermediate = intermediate_update_names(self.extracted.root)
        marked = self._marked_intermediate
        return {v.name for v in self.model_description.modelVariables if v.causality == "input" and v.name in marked}

    def get_output_derivatives(self, vrs: ctypes.Array, out: np.ndarray | None = None) -> np.ndarray:
        """First time derivatives of outputs at the current communication point (needs ``maxOutputDerivativeOrder``)."""
        self._check_open()
        n = len(vrs)
        out = np.empty(n) if out is None else out
        if n:
            f, c = self._fmu, self._fmu.component
            with self._calling("reading output derivatives", self.time):
                if self.fmi_version == 2:
                    f.fmi2GetRealOutputDerivatives(c, vrs, n, (ctypes.c_int * n)(*([1] * n)),
                                                   out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
                else:
                    f.fmi3GetOutputDerivatives(c, vrs, n, (ctypes.c_int32 * n)(*([1] * n)),
                                               out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n)
        return out

    def set_input_derivatives(self, vrs: ctypes.Array, values) -> None:
        """FMI 2: the slopes (per s) of inputs over the coming step; set the inputs' values first."""
        self._check_open()
        n = len(vrs)
        if n:
            arr = np.ascontiguousarray(values, dtype=float)
            with self._calling("setting input derivatives", self.time):
                self._fmu.fmi2SetRealInputDerivatives(self._fmu.component, vrs, n, (ctypes.c_int * n)(*([1] * n)),
                                                      arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    def set_input_provider(self, vrs: ctypes.Array | None, values_at=None) -> None:
        """FMI 3: inputs the FMU gets when it asks during a step; ``values_at(t)`` gives them at time ``t`` (s).

        ``None`` stops providing (the inputs are then held over a step).
        """
        self._intermediate["provider"] = None if vrs is None else (vrs, values_at)

    def do_step(self, t: float, h: float) -> None:
        """Advance a Co-Simulation FMU from ``t`` by ``h`` (s)."""
        self._intermediate["error"] = None
        with self._calling(f"the communication step from t = {t:.9g} s by h = {h:.9g} s", t):
            result = self._fmu.doStep(t, h)
        error = self._intermediate["error"]
        if error is not None:
            self._intermediate["error"] = None
            raise FMUStepError(f"{self.source}: providing intermediate inputs during the step from t = {t:.9g} s "
                               f"failed: {error}", time=t, status="error", function="intermediateUpdate")
        if self.fmi_version == 3 and result and (result[1] or result[2]):
            raise FMUStepError(f"{self.source}: doStep from t = {t:.9g} s stopped early (terminate="
                               f"{result[1]}, earlyReturn={result[2]}) at t = {result[3]:.9g} s",
                               time=t, status="ok", function="fmi3DoStep")
        self.time = t + h

    # ---- life cycle -------------------------------------------------------------------------------------------

    def close(self) -> None:
        """Terminate and free the instance, unload the library and delete an owned extraction folder.

        Idempotent.  Any later call on this instance raises :class:`~fmu.errors.FMUError`.
        """
        self._finalizer()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return not self._finalizer.alive

    def __enter__(self) -> FMUInstance:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __deepcopy__(self, memo):
        # an instance of native code cannot be copied; copies of a system share it
        return self

    def __copy__(self):
        return self

    def __repr__(self) -> str:
        return f"FMUInstance({self.source!r}, {self.kind}, FMI {getattr(self, 'fmi_version', '?')})"
