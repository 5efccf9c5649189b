"""Budgets for memory, integration steps and wall time, and the estimates checked against them before a job starts.

A job (a batch of runs, a sweep, later a single run) estimates what it will
need from the numbers it is given -- members, steps, grid points, noise
samples, runs -- *before* it allocates anything, and refuses when the estimate
exceeds the budget, naming the estimate, the budget and the scenario or sweep
key that drives it::

    from blocks.engines.budget import Budget, estimate_batch
    budget = Budget.from_env(memory="8G")           # flags > DOBKIT_MAX_* variables > defaults
    need = estimate_batch(members=250, steps=12_000, grid_points=2_001, noise=True, noise_samples=10_001, joints=4)
    budget.check(need, "a batch of 250 runs")       # BudgetError (a ValueError) when over

Memory is what the job allocates for its data (arrays, tables, rows), on top
of the few hundred MB the Python process and its libraries take; the
constants below are upper bounds of allocations measured with ``tracemalloc``
on :func:`blocks.figure2.batch.simulate_batch` (the tests check them against a fresh
measurement).
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

__all__ = ["Budget", "BudgetError", "Estimate", "estimate_batch", "largest_batch", "schedule_steps", "parse_size",
           "format_bytes", "DEFAULT_MEMORY", "DEFAULT_STEPS", "ENVIRONMENT", "STEP_BYTES", "MEMBER_BYTES",
           "NOISE_STEP_BYTES", "NOISE_SAMPLE_BYTES_PER_JOINT", "NOISE_BASE_BYTES", "SIGNAL_POINT_BYTES_PER_JOINT", "BASE_BYTES"]

#: Default memory budget (bytes): 4 GiB.
DEFAULT_MEMORY = 4 * 2 ** 30
#: Default step budget: integrator steps per run (2e6 fixed RK4 steps of one member take about half an hour).
DEFAULT_STEPS = 2_000_000
#: Environment variables that set the budget when no flag does.
ENVIRONMENT = {"memory": "DOBKIT_MAX_MEMORY", "steps": "DOBKIT_MAX_STEPS", "seconds": "DOBKIT_MAX_SECONDS"}

#: Bytes per step of a batch's schedule, shared by its members: step times, the reference at step
#: ends and mid points, and their temporaries (measured: about 850).
STEP_BYTES = 1024
#: Bytes per member that do not grow with the run: states, RK4 stages, model constants (measured: about 16 kB).
MEMBER_BYTES = 32 * 1024
#: Bytes per member and step with measurement noise: the noise at step ends and mid points (measured: about 200).
NOISE_STEP_BYTES = 256
#: Bytes per member, noise sample and joint: the drawn samples (2 numbers a joint) and their temporaries
#: (measured on the paper's arm: 192 for its joints).
NOISE_SAMPLE_BYTES_PER_JOINT = 48
#: Bytes per member, grid point, kept signal and joint (one number).
SIGNAL_POINT_BYTES_PER_JOINT = 8
#: Bytes a batch needs whatever its size (scenario, kernels' small tables).
BASE_BYTES = 1024 * 1024
#: Bytes a batch with measurement noise needs whatever its size (the compiled batch's noise tables and driver
#: buffers: measured about 2.6 MB).
NOISE_BASE_BYTES = 3 * 1024 * 1024

_UNITS = {"": 1, "K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}


class BudgetError(ValueError):
    """A job's estimate exceeds its budget.

    Attributes
    ----------
    estimate : Estimate or None
        What the job would need.
    key : str
        The scenario or sweep key that drives the estimate.
    limit : str
        Which budget is exceeded: ``"memory"``, ``"steps"`` or ``"seconds"``.
    """

    def __init__(self, message: str, estimate: Estimate | None = None, key: str = "", limit: str = "") -> None:
        super().__init__(message)
        self.estimate, self.key, self.limit = estimate, key, limit


def parse_size(value) -> int:
    """Bytes from ``4G``, ``512M``, ``2.5GiB``, ``1e9`` or a number (K, M, G, T are powers of 1024).

    Examples
    --------
    >>> parse_size("4G"), parse_size("512 MiB"), parse_size(1000)
    (4294967296, 536870912, 1000)
    """
    if isinstance(value, bool):
        raise ValueError(f"a memory size must be a number of bytes or like '4G', got {value!r}")
    if isinstance(value, (int, float)):
        number, unit = float(value), ""
    else:
        found = re.fullmatch(r"\s*([0-9.]+(?:[eE][+-]?[0-9]+)?)\s*([KMGT]?)(?:i?B)?\s*", str(value), re.I)
        if not found:
            raise ValueError(f"a memory size must be a number of bytes or like '4G', '512M', got {value!r}")
        number, unit = float(found.group(1)), found.group(2).upper()
    size = number * _UNITS[unit]
    if not math.isfinite(size) or size <= 0:
        raise ValueError(f"a memory size must be positive and finite, got {value!r}")
    return int(size)


def format_bytes(size: float) -> str:
    """``4.0 GiB``, ``512 MiB``, ``3.2 TiB``: for messages.

    Examples
    --------
    >>> format_bytes(4 * 2 ** 30), format_bytes(1536), format_bytes(12)
    ('4.0 GiB', '1.5 KiB', '12 B')
    """
    for unit, scale in (("PiB", 2 ** 50), ("TiB", 2 ** 40), ("GiB", 2 ** 30), ("MiB", 2 ** 20), ("KiB", 2 ** 10)):
        if size >= scale:
            return f"{size / scale:.1f} {unit}"
    return f"{size:.0f} B"


def _count(value, what: str) -> int:
    """A whole count >= 1 from an int, a float such as 2e6, or text such as '2e6'."""
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number) or number < 1 or number != int(number):
        raise ValueError(f"{what} must be a whole number >= 1, got {value!r}")
    return int(number)


def _seconds(value) -> float | None:
    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "none", "unlimited")):
        return None
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"a wall-time budget must be a positive number of seconds, got {value!r}")
    return number


@dataclass(frozen=True)
class Budget:
    """What a job may use.

    Attributes
    ----------
    memory : int
        Bytes the job may allocate for its data (default :data:`DEFAULT_MEMORY`, 4 GiB).
    steps : int
        Integrator steps one run may take (default :data:`DEFAULT_STEPS`).
    seconds : float or None
        Wall-clock seconds a job may run; None (the default): no limit.
    """

    memory: int = DEFAULT_MEMORY
    steps: int = DEFAULT_STEPS
    seconds: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "memory", parse_size(self.memory))
        object.__setattr__(self, "steps", _count(self.steps, "the step budget"))
        object.__setattr__(self, "seconds", _seconds(self.seconds))

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, *, memory=None, steps=None,
                 seconds=None) -> Budget:
        """The budget from explicit values (flags), else the :data:`ENVIRONMENT` variables, else the defaults.

        Raises
        ------
        ValueError
            On a value that is not a size, a count or a number of seconds; the message names the variable.
        """
        env = os.environ if environ is None else environ
        given = {"memory": memory, "steps": steps, "seconds": seconds}
        values = {}
        for name, variable in ENVIRONMENT.items():
            if given[name] is not None:
                values[name] = given[name]
            elif env.get(variable, "").strip():
                values[name] = env[variable]
            else:
                continue
            try:
                cls(**{name: values[name]})
            except ValueError as err:
                source = "" if given[name] is not None else f"{variable}: "
                raise ValueError(f"{source}{err}") from None
        return cls(**values)

    def share(self, parts: int) -> Budget:
        """The budget of one of ``parts`` jobs that run at the same time (memory divided)."""
        return replace(self, memory=max(1, self.memory // max(1, int(parts))))

    def check_steps(self, steps: float, what: str, cause: str, key: str = "") -> None:
        """Refuse a fixed-step run of ``steps`` steps beyond :attr:`steps` (a co-simulation, a check's run).

        Parameters
        ----------
        steps : float
            The estimate (may be huge or infinite).
        what : str
            The run, e.g. ``"co-simulation of plant.fmu"``.
        cause : str
            The values that give the estimate, e.g. ``"t_final = 10 s / step = 1e-09 s"``.
        key : str
            The argument or scenario key that drives it (``"step"``), for :attr:`BudgetError.key`.
        """
        if not steps <= self.steps:
            raise BudgetError(f"{what}: {cause} gives {steps:.3g} steps, more than the step budget of "
                              f"{self.steps:.3g}; choose a larger step or a shorter time, or raise the budget with "
                              f"--max-steps or {ENVIRONMENT['steps']}", None, key, "steps")

    def check(self, estimate: Estimate, what: str) -> None:
        """Raise :class:`BudgetError` when ``estimate`` exceeds this budget; ``what`` names the job in the message."""
        if estimate.steps > self.steps:
            key = f"; set by '{estimate.steps_key}'" if estimate.steps_key else ""
            raise BudgetError(
                f"{what} needs about {estimate.steps:.3g} integrator steps per run ({estimate.steps_reason}{key}), "
                f"over the step budget of {self.steps:.3g}; raise it with --max-steps or {ENVIRONMENT['steps']}",
                estimate, estimate.steps_key, "steps")
        if estimate.memory > self.memory:
            key = f"; set by '{estimate.memory_key}'" if estimate.memory_key else ""
            raise BudgetError(
                f"{what} needs about {format_bytes(estimate.memory)} of memory (mostly {estimate.memory_reason}{key}), "
                f"over the memory budget of {format_bytes(self.memory)}; raise it with --max-memory or "
                f"{ENVIRONMENT['memory']}", estimate, estimate.memory_key, "memory")
        if self.seconds is not None and estimate.seconds > self.seconds:
            key = f"; set by '{estimate.seconds_key}'" if estimate.seconds_key else ""
            raise BudgetError(
                f"{what} needs about {estimate.seconds:.3g} s of wall time before its run ({estimate.seconds_reason}"
                f"{key}), over the wall-time budget of {self.seconds:g} s; raise it with --max-seconds or "
                f"{ENVIRONMENT['seconds']}", estimate, estimate.seconds_key, "seconds")


@dataclass(frozen=True)
class Estimate:
    """What a job would need.

    Attributes
    ----------
    memory : int
        Peak bytes of the job's data.
    steps : int
        Integrator steps per run (0 when not applicable).
    parts : dict of str to int
        Memory by part (bytes), for the message.
    keys : dict of str to str
        The key that drives each part, and ``"steps"`` for the step count.
    reasons : dict of str to str
        How each part and the step count come about, in words.
    seconds : float
        Wall time (s) the job spends before its runs can start, known beforehand: a redundant arm's task-space
        path solved by IK (:attr:`blocks.scenarios.tool_path.ToolPath.solve_seconds`); 0 when there is none.  Its key and
        reason are ``keys["seconds"]`` and ``reasons["seconds"]``.
    """

    memory: int
    steps: int = 0
    parts: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def memory_part(self) -> str:
        """The largest part of the memory."""
        return max(self.parts, key=self.parts.get) if self.parts else ""

    @property
    def memory_key(self) -> str:
        """The key that drives the largest part of the memory."""
        return self.keys.get(self.memory_part, "")

    @property
    def memory_reason(self) -> str:
        part = self.memory_part
        return f"{part}: {self.reasons.get(part, format_bytes(self.parts.get(part, 0)))}" if part else "?"

    @property
    def steps_key(self) -> str:
        return self.keys.get("steps", "")

    @property
    def steps_reason(self) -> str:
        return self.reasons.get("steps", "")

    @property
    def seconds_key(self) -> str:
        return self.keys.get("seconds", "")

    @property
    def seconds_reason(self) -> str:
        return self.reasons.get("seconds", "")


def schedule_steps(t_final: float, output_step: float, substeps: int, breakpoints: int = 0) -> int:
    """Fixed steps of a run: ``substeps`` per output interval plus one per breakpoint between grid points (an
    upper bound: a breakpoint on a step end adds none)."""
    return int(round(t_final / output_step)) * int(substeps) + int(breakpoints)


def estimate_batch(members: int, steps: int, grid_points: int, signals: int = 0, noise: bool = False,
                   noise_samples: int = 0, keys: Mapping[str, str] | None = None,
                   steps_reason: str = "", *, joints: int) -> Estimate:
    """Peak memory and steps of a fixed-step batch (:func:`blocks.figure2.batch.simulate_batch`).

    Parameters
    ----------
    members : int
        Runs in the batch.
    steps : int
        Integrator steps of the shared schedule.
    grid_points : int
        Points of the output grid.
    signals : int
        Signals kept on the grid for every member (the metrics alone need none).
    noise : bool
        Whether the members have measurement noise (stored at every step).
    noise_samples : int
        Noise samples per member (``t_final / sample_period + 1``).
    keys : mapping, optional
        The key that drives each part: ``"steps"``, ``"members"``, ``"noise"`` (samples) and ``"signals"``.
    steps_reason : str
        How the step count comes about, for the message.
    joints : int
        The arm's joint count n: noise samples and kept signals hold n (2n) numbers.

    Returns
    -------
    Estimate
    """
    joints = max(1, int(joints))
    keys = {"steps": "", "members": "batch.size", "noise": "noise.sample_period",
            "signals": "simulation.output_step"} | dict(keys or {})
    members, steps = int(members), int(steps)
    parts = {
        "the step schedule": BASE_BYTES + STEP_BYTES * steps + members * NOISE_STEP_BYTES * steps * bool(noise),
        "the members' states": members * MEMBER_BYTES,
        "the noise samples": (NOISE_BASE_BYTES + members * NOISE_SAMPLE_BYTES_PER_JOINT * joints * int(noise_samples))
        * bool(noise),
        "the kept signals": members * SIGNAL_POINT_BYTES_PER_JOINT * joints * int(grid_points) * int(signals),
    }
    reasons = {"the step schedule": f"{steps:.3g} steps" + (f" with noise for {members} runs" if noise else ""),
               "the members' states": f"{members} runs",
               "the noise samples": f"{int(noise_samples):.3g} samples for each of {members} runs",
               "the kept signals": f"{signals} signals at {grid_points:.3g} points for {members} runs",
               "steps": steps_reason or f"{steps:.3g} steps"}
    part_keys = {"the step schedule": keys["steps"], "the members' states": keys["members"],
                 "the noise samples": keys["noise"], "the kept signals": keys["signals"], "steps": keys["steps"]}
    return Estimate(memory=int(sum(parts.values())), steps=steps, parts=parts, keys=part_keys, reasons=reasons)


def largest_batch(memory: int, **kwargs) -> int:
    """The most members a batch may have within ``memory`` bytes (0 if not even one fits); ``kwargs`` as
    :func:`estimate_batch` takes them (without ``members``)."""
    one, two = estimate_batch(1, **kwargs).memory, estimate_batch(2, **kwargs).memory
    per_member = max(1, two - one)
    fixed = one - per_member
    return max(0, int((memory - fixed) // per_member))
