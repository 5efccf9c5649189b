"""What a tuning writes (``tune.json``) and reading it back.

The result types of :func:`analysis.tune.runner.run_tune`, apart from the
runner (which writes them) and the report (which reads them), so that
neither imports the other.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from analysis.jobs.figures import JobFigure
from analysis.results import JsonResult, omitted_if_none
from analysis.tune.spec import TuneError
from blocks.scenarios.scenario import default_arm

__all__ = ["RESULT_NAME", "PointResult", "TuneHistory", "TuneFigure", "ConstraintCost", "TuneResult", "read_result",
           "objective_text", "numbers_text", "excess_text"]

RESULT_NAME = "tune.json"


@dataclass(frozen=True)
class PointResult(JsonResult):
    """One set of gains evaluated on the set.

    Attributes
    ----------
    gains : dict
        The tuned keys' values as the scenario file holds them (a number, or n for a diagonal).
    objective : float or None
        Worst or mean of the metric over the set (mm); None when a run diverged or the set was not run.
    worst, mean : float or None
        Largest and mean metric over the set (mm).
    values : list of float or None
        The metric of every run of the set (mm; None: diverged), in the set's order.
    nominal : float or None
        The metric of the scenario itself with these gains, without the set's changes (mm).
    torque_noise_rms : list of float
        Linear torque noise per joint (:attr:`TuneResult.force_units`).
    peak_torque : list of float or None
        Peak ``|tau|`` per joint over the set (:attr:`TuneResult.force_units`).
    spectral_abscissa : float
        Largest real part of the linearized loop's poles (1/s).
    violations : dict of str to float
        Per constraint, how far it is missed (0: met; see :mod:`analysis.tune.evaluate`).
    feasible : bool
    diverged : int
        Runs of the set that diverged.
    damping_ratio : list of float
        Of the error dynamics ``e'' + kd e' + kp e = 0`` per joint, ``kd / (2 sqrt(kp))``.
    bandwidth_ratio : float or None
        Slowest observer mode over the tracking bandwidth (:mod:`analysis.tune.spec`).
    margins : dict of str to float
        Per constraint, by how much it is met (< 0: missed; :mod:`analysis.tune.evaluate` says in what unit).
    sampled_loop : dict or None
        With a sampled-loop constraint: ``ts_lambda_max``, ``Ts lambda_max(Y M^-1)`` along the path, and
        ``ts_lambda_limit``, the sampled loop's limit on it for these gains (:mod:`blocks.figure2.digital_stability`).
    """

    gains: dict
    objective: float | None
    worst: float | None
    mean: float | None
    values: list[float | None] | None
    nominal: float | None
    torque_noise_rms: list[float]
    peak_torque: list[float] | None
    spectral_abscissa: float
    violations: dict[str, float]
    feasible: bool
    diverged: int
    damping_ratio: list[float] = field(default_factory=list)
    bandwidth_ratio: float | None = None
    margins: dict[str, float] = field(default_factory=dict)
    sampled_loop: dict | None = omitted_if_none()


@dataclass(frozen=True)
class TuneHistory(JsonResult):
    """Every evaluation of the search in order (linear-only ones included).

    Attributes
    ----------
    phase : list of str
        ``"base"``, ``"search"``, ``"polish"`` or ``"final"``.
    objective : list of float or None
        Objective (mm); None when not simulated or a run diverged.
    feasible, simulated : list of bool
    """

    phase: list[str]
    objective: list[float | None]
    feasible: list[bool]
    simulated: list[bool]


#: A figure of the tuning: its PNG file name (in ``figures/``) and caption (the job figure of both kinds of job).
TuneFigure = JobFigure


@dataclass(frozen=True)
class ConstraintCost(JsonResult):
    """What one constraint costs in the objective: the tuning's search run again with it dropped
    (:mod:`analysis.tune.costs`).

    Attributes
    ----------
    constraint : str
        Its key in ``[constraints]``: ``"min_damping_ratio"`` (or ``"max_overshoot"``),
        ``"min_observer_bandwidth_ratio"``, ``"sampled_margin"`` or ``"torque_noise_rms"``.
    margin : float or None
        The tuned gains' margin on it (:attr:`PointResult.margins`; < 0: missed).
    binds : bool
        Whether gains that break this constraint alone reach a lower objective than every evaluation that meets
        them all (then ``cost > 0``).
    cost : float or None
        ``reference - objective`` (mm; >= 0, exactly 0 when it does not bind); None when no evaluation met every
        constraint.
    objective : float or None
        The lowest objective of the evaluations that meet every other constraint, with it dropped (mm).
    reference : float or None
        The lowest objective of the evaluations that meet every constraint (mm): the tuned gains' own, unless a
        search without one constraint found better gains that meet them all.
    gains : dict
        The gains of ``objective``.
    margin_there : float or None
        Those gains' margin on the dropped constraint (< 0: they break it).
    simulated : int
        Candidates the search without it simulated that no earlier search of the tuning had.
    """

    constraint: str
    margin: float | None
    binds: bool
    cost: float | None
    objective: float | None
    reference: float | None
    gains: dict
    margin_there: float | None
    simulated: int


@dataclass(frozen=True)
class TuneResult(JsonResult):
    """What a tuning found (``tune.json``).

    Attributes
    ----------
    name, source, description, definition : str
        The tuning, its file and its definition (see :mod:`analysis.tune.runner`).
    scenario : str
        The base scenario's name.
    objective, metric : str
        ``"worst"`` or ``"mean"`` of ``metric`` over the set.
    runs : int
        Runs in the set.
    parameters, units : list of str
        The searched values (``gains.kp``, ``gains.observer[2]``) and their units.
    bounds : list of list of float
    limits : dict
        The constraints (:meth:`analysis.tune.spec.Limits.as_dict`).
    base, tuned : PointResult
        The base scenario's gains and the tuned ones.
    feasible : bool
        Whether the tuned gains meet every constraint; False: they are the best infeasible point found.
    message : str
        One sentence on the outcome.
    history : TuneHistory
    evaluations : dict of str to int
        ``search``, ``polish`` (evaluations asked for), ``simulated`` (candidates simulated now), ``from_log``
        (candidates taken from the evaluation log of an earlier run), ``linear_only`` (evaluations refused by the
        linear constraints, not simulated).
    seconds : float
        Wall time of this call (s).
    scenario_file : str
        The tuned scenario's file name (in the output folder).
    figures : list of TuneFigure
    log_problems : list of str
        Lines of the evaluation log that were not usable (their candidates were simulated again).
    unconstrained : PointResult or None
        The best evaluation of the same search that meets every constraint but the damping (or overshoot) one:
        what the search found without it.  None when the tuning has no damping constraint or no such evaluation.
    damping_cost : float or None
        What the damping constraint costs: the tuned objective minus the unconstrained one (mm; >= 0).
    unconstrained_from : str or None
        ``"evaluations"``: the best of the constrained search's own evaluations (the search was steered by the
        constraint, so the optimum without it may be lower and the cost larger); ``"search"``: the answer of the
        same search run without the constraint (``compare_unconstrained``).
    joints : list of str
        The base scenario's arm's joint names, in the order of every per-joint list (the paper's RRPR in a
        ``tune.json`` written before the arm was recorded).
    force_units : list of str
        Unit of each joint's torque or force (``"N m"``, ``"N"``): of the torque noise, the peak torque and
        their limits.
    constraint_costs : list of ConstraintCost or None
        With ``constraint_costs``: what each active constraint of :data:`analysis.tune.costs.COSTED` costs, in
        that order; None (and left out of the file) without.
    """

    name: str
    source: str
    description: str
    definition: str
    scenario: str
    objective: str
    metric: str
    runs: int
    parameters: list[str]
    units: list[str]
    bounds: list[list[float]]
    limits: dict
    base: PointResult
    tuned: PointResult
    feasible: bool
    message: str
    history: TuneHistory
    evaluations: dict[str, int]
    seconds: float
    scenario_file: str
    figures: list[TuneFigure] = field(default_factory=list)
    log_problems: list[str] = field(default_factory=list)
    unconstrained: PointResult | None = None
    damping_cost: float | None = None
    unconstrained_from: str | None = None
    # a result written before the joints were kept is the default scenario's arm's
    joints: list[str] = field(default_factory=lambda: list(default_arm().joints.names))
    force_units: list[str] = field(default_factory=lambda: list(default_arm().joints.force_units))
    constraint_costs: list[ConstraintCost] | None = omitted_if_none()


def read_result(folder):
    """The :class:`TuneResult` of a tuning folder.

    Raises
    ------
    TuneError
        When the folder has no readable ``tune.json`` or a listed figure is missing.
    """
    folder = Path(folder)
    path = folder / RESULT_NAME
    if not path.is_file():
        raise TuneError(f"tuning folder '{folder}' has no {RESULT_NAME} (run 'dobkit tune' first)")
    try:
        result = TuneResult.from_json(path.read_text(encoding="utf-8"))
    except (ValueError, KeyError, TypeError) as err:
        raise TuneError(f"tuning result '{path}' cannot be read ({err}); run 'dobkit tune' again") from None
    for figure in result.figures:
        if Path(figure.file).name != figure.file or not (folder / "figures" / figure.file).is_file():
            raise TuneError(f"tuning folder '{folder}' lists the figure '{figure.file}', which is not in its "
                            "figures/ folder: the folder is incomplete; run 'dobkit tune' again")
    return result


# --------------------------------------------------------------------------------------------
# Numbers in words: the same text wherever a tuning's outcome is written (stdout, tune.json, the tuned file)
# --------------------------------------------------------------------------------------------
def objective_text(objective: float | None, diverged: int = 0, runs: int = 0) -> str:
    """A point's objective (mm) for messages: 4 significant digits, or why it has none.

    Examples
    --------
    >>> objective_text(2.274712)
    '2.275 mm'
    >>> objective_text(None, diverged=2, runs=3)
    'not finite (2 of 3 runs diverged)'
    """
    if objective is not None and math.isfinite(objective):
        return f"{objective:.4g} mm"
    return "not finite" + (f" ({diverged} of {runs} runs diverged)" if diverged else "")


def numbers_text(values, unit: str = "") -> str:
    """Numbers for messages with 4 significant digits, so that small ones stay visible: ``[1e-09, 0.02392]``."""
    return "[" + ", ".join(f"{float(v):.4g}" for v in values) + "]" + (f" {unit}" if unit else "")


def excess_text(value: float, limit: float) -> str:
    """How far ``value`` is over ``limit`` (> 0): a percentage up to ten times, a factor beyond.

    Examples
    --------
    >>> excess_text(1.5, 1.0)
    'over by 50.0 %'
    >>> excess_text(0.02392, 1e-9)
    '2.392e+07 times its budget'
    """
    ratio = value / limit
    return f"over by {100 * (ratio - 1):.1f} %" if ratio < 10 else f"{ratio:.4g} times its budget"
