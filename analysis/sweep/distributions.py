"""The distributions of a sweep's uncertain values: ``[monte_carlo.distributions]`` and ``[sensitivity.distributions]``.

One module for both tables, so that the sweep file's reader (:mod:`analysis.sweep.spec`) and the sensitivity
designs (:mod:`analysis.sweep.sensitivity`) share the kinds and their draws without importing each other.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

__all__ = ["DISTRIBUTIONS", "Distribution"]

#: Distribution kinds and their parameters (required, optional).
DISTRIBUTIONS = {"uniform": (("low", "high"), ()), "normal": (("mean", "std"), ()),
                 "lognormal": (("mean", "sigma"), ()), "choice": (("values",), ("weights",))}

@dataclass(frozen=True)
class Distribution:
    """A distribution of one uncertain value (see :data:`DISTRIBUTIONS`)."""

    kind: str
    params: dict

    def draw(self, rng: np.random.Generator, n: int) -> list:
        """``n`` draws as plain Python values."""
        p = self.params
        if self.kind == "uniform":
            return rng.uniform(p["low"], p["high"], n).tolist()
        if self.kind == "normal":
            return rng.normal(p["mean"], p["std"], n).tolist()
        if self.kind == "lognormal":
            return rng.lognormal(p["mean"], p["sigma"], n).tolist()
        weights = p.get("weights")
        prob = None if weights is None else np.asarray(weights, dtype=float) / np.sum(weights)
        return [copy.deepcopy(p["values"][i]) for i in rng.choice(len(p["values"]), size=n, p=prob)]
