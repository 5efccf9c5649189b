"""How signals cross between a Co-Simulation FMU and the Python side over one communication step.

Two couplings, for the master of :mod:`fmu.master`:

``"zoh"``
    Zero-order hold both ways: the FMU gets the Python side's outputs of
    ``t_k`` held over ``[t_k, t_k + h]``, the Python side the FMU's outputs
    of ``t_k`` held.  First order in ``h``.

``"linear"``
    First-order hold from the Python side to the FMU: its outputs ``c_k``
    and their time derivative ``c'_k`` at ``t_k`` (a one-sided difference
    along the solution), handed over as ``c_k + (t - t_k) c'_k`` -- through
    ``fmi2SetRealInputDerivatives`` (FMI 2, ``canInterpolateInputs``) or
    the intermediate-update callback (FMI 3, ``providesIntermediateUpdate``
    with the inputs marked ``intermediateUpdate``).  The FMU steps first;
    then the Python side integrates with the FMU's outputs interpolated
    between ``t_k`` and ``t_k + h``: a cubic Hermite curve through the values
    and the output derivatives at both ends (``maxOutputDerivativeOrder`` >=
    1), else the straight line between the two values.  For an FMU without
    direct feedthrough every signal is then exact to ``O(h^2)`` over a step,
    so the coupling is second order.  An algebraic path through both sides
    keeps the one-step break of the zero-order hold.  The slope assumes the
    Python outputs are continuous in time; for a side whose outputs jump (a
    sampled controller) use the zero-order hold.

In both, a Python-side input named like an FMU *input* receives exactly the
signal that FMU input receives (held, or the same straight line), so that,
for example, an observer fed the torque sees the torque the plant got.
"""
from __future__ import annotations

import numpy as np

from .errors import CoSimulationError

__all__ = ["COUPLINGS", "interpolates_inputs", "choose_coupling", "hermite", "describe", "CouplingFallbackWarning"]

COUPLINGS = ("zoh", "linear")


class CouplingFallbackWarning(UserWarning):
    """The ``linear`` coupling fell back to ``zoh``: the FMU's output derivatives were not finite numbers."""


def interpolates_inputs(fmu) -> tuple[bool, str]:
    """Whether an :class:`~fmu.instance.FMUInstance` can take inputs that change within a step, and why not.

    Returns
    -------
    (bool, str)
        The answer and, when False, the reason in the FMU's own terms.
    """
    if fmu.fmi_version == 2:
        if fmu.can_interpolate_inputs:
            return True, ""
        return False, "its Co-Simulation interface does not declare canInterpolateInputs"
    if not fmu.provides_intermediate_update:
        return False, ("FMI 3 has no input derivatives and the FMU does not declare providesIntermediateUpdate (the "
                       "only way to pass inputs during a step)")
    inputs = {v.name for v in fmu.model_description.modelVariables if v.causality == "input"}
    held = sorted(inputs - fmu.intermediate_inputs())
    if held:
        return False, f"its inputs {held} are not marked intermediateUpdate"
    return True, ""


def choose_coupling(fmu, coupling: str | None, has_inputs: bool) -> str:
    """The coupling to use: the one asked for, or the best the FMU supports.

    Raises
    ------
    CoSimulationError
        For an unknown coupling, or ``"linear"`` with an FMU that holds its inputs over a step.
    """
    if coupling is not None and coupling not in COUPLINGS:
        raise CoSimulationError(f"coupling must be one of {list(COUPLINGS)}, got {coupling!r}")
    able, why = interpolates_inputs(fmu) if has_inputs else (True, "")
    if coupling is None:
        return "linear" if able else "zoh"
    if coupling == "linear" and not able:
        raise CoSimulationError(f"{fmu.source}: coupling 'linear' needs inputs that follow a slope over the step, but "
                         f"{why}; use coupling 'zoh'")
    return coupling


def hermite(s: float, h: float, y0: np.ndarray, d0: np.ndarray, y1: np.ndarray, d1: np.ndarray) -> np.ndarray:
    """The cubic Hermite curve through ``(0, y0, d0)`` and ``(h, y1, d1)`` at ``s`` in ``[0, h]``.

    Examples
    --------
    >>> import numpy as np
    >>> f = lambda s: s ** 3 - 2 * s                     # a cubic is reproduced exactly
    >>> df = lambda s: 3 * s ** 2 - 2
    >>> round(float(hermite(0.3, 0.5, f(0.0), df(0.0), f(0.5), df(0.5))), 12), f(0.3)
    (-0.573, -0.573)
    """
    r = s / h
    r2, r3 = r * r, r * r * r
    return ((2 * r3 - 3 * r2 + 1) * y0 + (r3 - 2 * r2 + r) * h * d0 + (-2 * r3 + 3 * r2) * y1
            + (r3 - r2) * h * d1)


def describe(coupling: str, fmu_derivatives: bool, fmi_version: int) -> str:
    """One sentence for results: what crossed between the sides, and the order it gives."""
    if coupling == "zoh":
        return ("zero-order hold both ways (first order in h); Python-side inputs named like FMU inputs get the "
                "held value the FMU gets")
    how = "fmi2SetRealInputDerivatives" if fmi_version == 2 else "the FMI 3 intermediate-update callback"
    back = ("cubic Hermite interpolation of the FMU outputs from their values and first derivatives at both ends"
            if fmu_derivatives else "linear interpolation of the FMU outputs between communication points")
    return (f"first-order hold of the Python outputs into the FMU (through {how}), the FMU stepping first, then "
            f"{back} for the Python side (second order in h without feedthrough through both sides)")
