"""What each constraint of a tuning costs in the objective (``dobkit tune --constraint-costs``).

After the tuning's search, :func:`analysis.tune.runner.run_tune` runs the same
search (same seed, bounds and budget) once more per active constraint of
:data:`COSTED`, with that constraint dropped.  Every search writes to the same
evaluation log, so a candidate an earlier search simulated is taken from there.

The cost of a constraint C is read off every simulated evaluation of these
searches (the base gains' aside), each judged by the tuning's own constraints
(:meth:`analysis.tune.evaluate.Evaluator.judged`)::

    reference = the lowest objective of the evaluations that meet every constraint
    dropped   = the lowest objective of the evaluations that meet every constraint but C
    cost      = reference - dropped        (mm)

The second set holds the first, so the cost is never negative.  It is above
zero only when gains that break C alone beat every evaluation that meets them
all -- C *binds* -- and exactly zero otherwise, whichever path the search
without C took.  These are the best values a finite, seeded search found, not
the true optima: a larger budget can only lower ``dropped`` and ``reference``.
"""
from __future__ import annotations

import dataclasses
import math

from analysis.tune.evaluate import DAMPING_CONSTRAINTS, Evaluation, Evaluator
from analysis.tune.results import ConstraintCost
from analysis.tune.spec import Limits, TuneSpec

__all__ = ["COSTED", "costed_constraints", "without", "search_count", "constraint_costs"]

#: The constraints whose cost can be measured, in the order they are searched without and reported.
COSTED = ("min_damping_ratio", "max_overshoot", "min_observer_bandwidth_ratio", "sampled_margin", "torque_noise_rms")
#: What dropping each one changes in :class:`analysis.tune.spec.Limits`.
_DROPPED = {"min_damping_ratio": {"min_damping_ratio": None, "max_overshoot": None, "damping_from": "off"},
            "max_overshoot": {"min_damping_ratio": None, "max_overshoot": None, "damping_from": "off"},
            "min_observer_bandwidth_ratio": {"min_observer_bandwidth_ratio": None},
            "sampled_margin": {"sampled_margin": None, "sampled_from": "off"},
            "torque_noise_rms": {"torque_noise_rms": None}}
#: The violation keys of each (the damping constraint is a minimum ratio or a maximum overshoot).
_KEYS = {"min_damping_ratio": DAMPING_CONSTRAINTS, "max_overshoot": DAMPING_CONSTRAINTS}


def costed_constraints(limits: Limits) -> list[str]:
    """The constraints of :data:`COSTED` that ``limits`` sets (by default or given), in that order."""
    return [key for key in COSTED if getattr(limits, key) is not None]


def without(limits: Limits, key: str) -> Limits:
    """``limits`` with the constraint ``key`` of :data:`COSTED` dropped.

    Raises
    ------
    ValueError
        Naming the key and the allowed ones, when ``key`` is not one of :data:`COSTED`.
    """
    if key not in _DROPPED:
        raise ValueError(f"constraint {key!r} has no cost to measure; allowed: {', '.join(COSTED)}")
    return dataclasses.replace(limits, **_DROPPED[key])


def search_count(spec: TuneSpec, constraint_costs: bool = False, compare_unconstrained: bool = False) -> int:
    """How many searches a tuning runs: 1, plus one per active costed constraint with ``constraint_costs``, or
    plus one without the damping constraint with ``compare_unconstrained`` (when the tuning has one)."""
    if constraint_costs:
        return 1 + len(costed_constraints(spec.limits))
    damped = spec.limits.min_damping_ratio is not None or spec.limits.max_overshoot is not None
    return 2 if compare_unconstrained and damped else 1


def constraint_costs(evaluator: Evaluator, histories: list[list[Evaluation]], simulated: dict[str, int],
                     margins: dict[str, float]) -> list[ConstraintCost]:
    """What each searched-without constraint costs (module docstring).

    Parameters
    ----------
    evaluator : Evaluator
        The tuning's own evaluator (every constraint on): it judges the evaluations of every search.
    histories : list of list of Evaluation
        The evaluations of the tuning's search and of each search without a constraint.
    simulated : dict of str to int
        Per constraint searched without (in order), the candidates that search simulated.
    margins : dict of str to float
        The tuned gains' margins (:meth:`Evaluator.margins`).
    """
    pool: dict[str, Evaluation] = {}
    for history in histories:
        for ev in history:
            if ev.simulated and ev.phase != "base" and ev.key not in pool:
                judged = evaluator.judged(ev)
                if math.isfinite(judged.objective):
                    pool[ev.key] = judged
    ranked = sorted(pool.values(), key=lambda e: (e.objective, e.key))
    feasible = next((e for e in ranked if e.feasible), None)
    reference = None if feasible is None else feasible.objective
    out = []
    for key, count in simulated.items():
        dropped = _KEYS.get(key, (key,))
        best = next((e for e in ranked if all(v == 0 for k, v in e.violations.items() if k not in dropped)), None)
        binds = best is not None and feasible is not None and best.objective < reference
        cost = None if feasible is None else (reference - best.objective if binds else 0.0)
        out.append(ConstraintCost(
            constraint=key, margin=margins.get(key), binds=bool(binds), cost=cost,
            objective=None if best is None else float(best.objective), reference=reference,
            gains={} if best is None else best.gains,
            margin_there=None if best is None else evaluator.margins(best).get(key), simulated=int(count)))
    return out
