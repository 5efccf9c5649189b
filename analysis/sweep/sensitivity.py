"""Global sensitivity of a sweep: Sobol indices and Morris screening, with SALib's designs and estimators.

A sweep file's ``[sensitivity]`` table replaces ``[grid]`` and ``[monte_carlo]``::

    [sensitivity]
    method = "sobol"              # or "morris"
    samples = 4096                # Sobol: N, a power of 2 (N x (k + 2) runs); Morris: r trajectories (r x (k + 1))
    seed = 1
    levels = 4                    # Morris only: grid levels of each value (even, 2..1000; default 4)
    [sensitivity.distributions]   # as in [monte_carlo]: uniform, normal, lognormal (Morris: uniform only)
    "disturbance.f_r[0]" = {kind = "uniform", low = 0.7, high = 2.1}

The design (Saltelli's scheme on a scrambled Sobol sequence without second-order
terms, :func:`SALib.sample.sobol.sample`; Morris trajectories,
:func:`SALib.sample.morris.sample`) becomes the sweep's runs, in design order,
and runs on the sweep's engine like any other sweep.  From the finished rows
the summary estimates, per kept metric column, with
:func:`SALib.analyze.sobol.analyze` the first-order index S1 (the share of the
column's variance a value explains alone) and the total index ST (its share
with all its interactions), or with :func:`SALib.analyze.morris.analyze` mu*
(the mean absolute elementary effect, in the metric's unit, of moving a value
across its whole range) and sigma (their spread: interactions and
nonlinearity), each with a 95 % bootstrap confidence half-width.  The
estimators need every run of the design: a sweep with unfinished or diverged
runs gets no indices, with the reason.

SALib is an optional dependency (``pip install "dobkit[sensitivity]"``); it is
imported only when a sweep has a ``[sensitivity]`` table.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["Sensitivity", "METHODS", "KINDS", "DEFAULT_LEVELS", "CONFIDENCE", "RESAMPLES", "run_count",
           "samples_problem", "indices", "from_runs", "salib"]

#: The methods of a ``[sensitivity]`` table.
METHODS = ("sobol", "morris")
#: Distribution kinds each method takes.  A Morris trajectory moves each value over levels that include both
#: ends of its range, so its values need a bounded range (the inverse CDF of a normal is infinite at 0 and 1);
#: neither method has a meaning for an unordered choice.
KINDS = {"sobol": ("uniform", "normal", "lognormal"), "morris": ("uniform",)}
#: Morris grid levels when the file gives none (SALib's default).
DEFAULT_LEVELS = 4
#: The most Morris grid levels a file may ask for: SALib lays out levels / 2 grid values per design (a billion
#: levels is 4 GB before a run starts), and past a few dozen levels the grid is as good as continuous.
MAX_LEVELS = 1000
#: Confidence level of the bootstrap intervals, and the number of bootstrap resamples.
CONFIDENCE = 0.95
RESAMPLES = 100


def salib():
    """The SALib package, or an error that says how to install it.

    Raises
    ------
    ImportError
        When SALib is not installed.
    """
    try:
        import SALib  # noqa: F401
    except ImportError:
        raise ImportError("a [sensitivity] sweep needs SALib: pip install 'dobkit[sensitivity]' (or SALib>=1.4)") \
            from None
    import SALib.analyze.morris
    import SALib.analyze.sobol
    import SALib.sample.morris
    import SALib.sample.sobol
    return SALib


def run_count(method: str, samples: int, k: int) -> int:
    """Runs of a design: Sobol N x (k + 2) (the base matrices A and B and one A_B matrix per value), Morris
    r x (k + 1) (each trajectory moves the k values one at a time from a start point).

    Examples
    --------
    >>> run_count("sobol", 4096, 3), run_count("morris", 10, 3)
    (20480, 40)
    """
    return samples * (k + 2) if method == "sobol" else samples * (k + 1)


def samples_problem(method: str, samples, levels) -> str:
    """What is wrong with a method's sample count and levels ('' when nothing): Sobol's N must be a power of 2
    (the balance of the Sobol sequence, which the estimators' convergence rests on), at least 2 (a bootstrap
    interval needs two samples); Morris needs r >= 2 trajectories (sigma is a spread) and an even number of
    levels >= 2 (SALib's trajectories step by levels / (2 (levels - 1)))."""
    if method == "sobol":
        if samples < 2 or samples & (samples - 1):
            below = 1 << max(1, samples.bit_length() - 1)
            return (f"'sensitivity.samples' must be a power of 2 >= 2 for the Sobol method (N of the Saltelli "
                    f"design, which balances the Sobol sequence only at powers of 2), got {samples}; "
                    f"use {below} or {2 * below}")
        if levels is not None:
            return "'sensitivity.levels' is a Morris setting; the Sobol method takes none"
        return ""
    if samples < 2:
        return f"'sensitivity.samples' must be >= 2 Morris trajectories (sigma is their spread), got {samples}"
    if levels is not None and (levels < 2 or levels % 2):
        return f"'sensitivity.levels' must be an even whole number >= 2 (Morris grid levels), got {levels}"
    if levels is not None and levels > MAX_LEVELS:
        return (f"'sensitivity.levels' must be at most {MAX_LEVELS} (MAX_LEVELS: SALib lays out levels / 2 grid "
                f"values, and past a few dozen levels the grid is as good as continuous), got {levels}")
    return ""


@dataclass(frozen=True)
class Sensitivity:
    """A validated ``[sensitivity]`` table: the method, its sample count, seed, levels and distributions.

    Attributes
    ----------
    method : str
        ``"sobol"`` or ``"morris"``.
    samples : int
        Sobol: N (a power of 2); Morris: r, the number of trajectories.
    seed : int
        Seed of the design (the scrambling of the Sobol sequence, the Morris start points) and of the bootstrap.
    distributions : dict of str to Distribution
        The uncertain values by scenario key, in the file's order (the design's columns).
    levels : int
        Morris grid levels (0 for Sobol).
    """

    method: str
    samples: int
    seed: int
    distributions: dict
    levels: int = 0

    @property
    def keys(self) -> list[str]:
        """The uncertain values' keys, in design column order."""
        return list(self.distributions)

    @property
    def runs(self) -> int:
        """Runs of the design (see :func:`run_count`)."""
        return run_count(self.method, self.samples, len(self.distributions))

    def problem(self) -> dict:
        """SALib's problem: names, and per value its bounds and distribution (uniform: low, high; normal: mean,
        std; lognormal: mean and sigma of the logarithm)."""
        bounds, dists = [], []
        for d in self.distributions.values():
            p = d.params
            if d.kind == "uniform":
                bounds.append([p["low"], p["high"]])
                dists.append("unif")
            elif d.kind == "normal":
                bounds.append([p["mean"], p["std"]])
                dists.append("norm")
            else:
                bounds.append([p["mean"], p["sigma"]])
                dists.append("lognorm")
        return {"num_vars": len(bounds), "names": self.keys, "bounds": [list(map(float, b)) for b in bounds],
                "dists": dists}

    def design(self) -> np.ndarray:
        """The design's values, one row per run and one column per key (:attr:`runs` x k)."""
        sa = salib()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            if self.method == "sobol":
                x = sa.sample.sobol.sample(self.problem(), self.samples, calc_second_order=False, scramble=True,
                                           seed=self.seed)
            else:
                x = sa.sample.morris.sample(self.problem(), self.samples, num_levels=self.levels, seed=self.seed)
        if x.shape != (self.runs, len(self.distributions)):           # the run count checked is the one run
            raise RuntimeError(f"SALib made a {self.method} design of shape {x.shape}, not ({self.runs}, "
                               f"{len(self.distributions)})")
        return x

    def record(self) -> dict:
        """The table as the results header keeps it (reads back with :meth:`from_record`)."""
        out = {"method": self.method, "samples": self.samples, "seed": self.seed, "runs": self.runs,
               "distributions": {k: {"kind": d.kind} | d.params for k, d in self.distributions.items()}}
        if self.method == "morris":
            out["levels"] = self.levels
        return out

    @classmethod
    def from_record(cls, record: dict) -> Sensitivity:
        """The settings kept in a results header (see :meth:`record`)."""
        from analysis.sweep.distributions import Distribution
        distributions = {k: Distribution(kind=d["kind"], params={p: v for p, v in d.items() if p != "kind"})
                         for k, d in record["distributions"].items()}
        return cls(method=record["method"], samples=int(record["samples"]), seed=int(record["seed"]),
                   distributions=distributions, levels=int(record.get("levels", 0) or 0))


# --------------------------------------------------------------------------------------------
# Indices from the finished runs
# --------------------------------------------------------------------------------------------
def _column_indices(settings: Sensitivity, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """One metric column's indices by name, one number per key (SALib's estimators)."""
    sa = salib()
    k = len(settings.distributions)
    # SALib's bootstrap treats seed 0 as "no seed"; seed + 1 keeps the intervals reproducible for every seed
    seed = settings.seed + 1
    if settings.method == "sobol":
        if np.ptp(y) == 0.0:
            # no variance to apportion (SALib would divide by a zero std): no value moves the column, index 0
            zero = np.zeros(k)
            return {"first": zero, "total": zero, "first_conf": zero, "total_conf": zero}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            s = sa.analyze.sobol.analyze(settings.problem(), y, calc_second_order=False, num_resamples=RESAMPLES,
                                         conf_level=CONFIDENCE, seed=seed)
        return {"first": s["S1"], "total": s["ST"], "first_conf": s["S1_conf"], "total_conf": s["ST_conf"]}
    s = sa.analyze.morris.analyze(settings.problem(), x, y, num_resamples=RESAMPLES, conf_level=CONFIDENCE,
                                  num_levels=settings.levels, seed=seed)
    return {"mu_star": np.asarray(s["mu_star"], dtype=float), "sigma": np.asarray(s["sigma"], dtype=float),
            "mu_star_conf": np.asarray(s["mu_star_conf"], dtype=float)}


def indices(settings: Sensitivity, x: np.ndarray, columns: dict[str, np.ndarray]) -> dict:
    """The sensitivity indices of every metric column, in the form ``summary.json`` keeps them.

    Parameters
    ----------
    settings : Sensitivity
    x : numpy.ndarray
        The design's values as run, one row per run in design order (``settings.runs`` x k).
    columns : dict of str to numpy.ndarray
        Per metric column (``rms_position_error[2]``, ``max_tool_position_error_mm``) its value of every run in
        design order; all finite.

    Returns
    -------
    dict
        Sobol: ``{"first": {METRIC: {KEY: value}}, "total": ..., "first_conf": ..., "total_conf": ...}``;
        Morris: ``{"mu_star": ..., "sigma": ..., "mu_star_conf": ...}``.  A per-joint metric has a list of
        per-joint values where a one-number metric (the tool tip's) has the number.  The ``_conf`` entries are
        half-widths of 95 % bootstrap intervals.  Sobol indices are fractions of the column's variance (no
        unit); Morris's are in the metric's unit (the effect of moving a value over its whole range).
    """
    names = ("first", "total", "first_conf", "total_conf") if settings.method == "sobol" else \
        ("mu_star", "sigma", "mu_star_conf")
    out: dict = {name: {} for name in names}
    for column, y in columns.items():
        metric, joint = _split(column)
        values = _column_indices(settings, x, np.asarray(y, dtype=float))
        for name in names:
            per_key = out[name].setdefault(metric, {})
            for j, key in enumerate(settings.keys):
                v = float(values[name][j])
                v = v if math.isfinite(v) else None
                if joint is None:
                    per_key[key] = v
                else:
                    entry = per_key.setdefault(key, [])
                    entry.extend([None] * (joint + 1 - len(entry)))
                    entry[joint] = v
    return out


def _split(column: str) -> tuple[str, int | None]:
    """``rms_position_error[2]`` -> (``rms_position_error``, 2); ``max_tool_position_error_mm`` -> (it, None)."""
    if column.endswith("]") and "[" in column:
        metric, _, joint = column[:-1].rpartition("[")
        if joint.isdigit():
            return metric, int(joint)
    return column, None


def from_runs(record, index: np.ndarray, columns: dict[str, np.ndarray], values: dict[str, np.ndarray],
              diverged: int) -> tuple[dict | None, str]:
    """A sweep's indices from its finished runs, or why there are none.

    Parameters
    ----------
    record : dict
        The ``sensitivity`` entry of the results header (:meth:`Sensitivity.record`).
    index : numpy.ndarray of int
        The run index of each finished ok run.
    columns : dict of str to numpy.ndarray
        Per metric column, its value in each of those runs (NaN: not finite).
    values : dict of str to numpy.ndarray
        Per swept key, its value in each of those runs.
    diverged : int
        Runs of the design that diverged.

    Returns
    -------
    (dict or None, str)
        The indices (:func:`indices`, under the method's name) and '' when every run of the design finished ok;
        else None and the reason.  A metric column with a value that is not finite gets no indices (named in the
        note).
    """
    try:
        settings = Sensitivity.from_record(record)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        return None, f"the results header's [sensitivity] entry cannot be read ({err!r})"
    n = settings.runs
    if diverged:
        return None, (f"no {settings.method} indices: {diverged} of the {n:,} runs of the design diverged, and the "
                      "estimators need every run (narrow the distributions that make runs diverge)")
    order = np.argsort(index, kind="stable")
    if index.size != n or not np.array_equal(index[order], np.arange(n)):
        return None, (f"no {settings.method} indices: {index.size:,} of the {n:,} runs of the design finished, and "
                      "the estimators need every run (run the sweep again to finish it)")
    missing = [k for k in settings.keys if k not in values]
    if missing:
        return None, f"no {settings.method} indices: the rows do not hold the values of {missing}"
    x = np.column_stack([np.asarray(values[k], dtype=float)[order] for k in settings.keys])
    kept, left = {}, []
    for column, y in columns.items():
        y = np.asarray(y, dtype=float)[order]
        if np.all(np.isfinite(y)):
            kept[column] = y
        else:
            left.append(column)
    try:
        out = {settings.method: indices(settings, x, kept)}
    except ImportError as err:
        return None, f"no {settings.method} indices: {err}"
    note = f"no indices for {', '.join(left)}: a run's value is not finite" if left else ""
    return out, note
