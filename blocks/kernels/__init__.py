"""The loop's maths, written once: model terms, disturbances and control laws as plain array functions.

Every formula of the Figure-2 loop lives here and nowhere else in Python: the
python-control blocks (:mod:`blocks.diagram.systems`), the public model functions
(each arm model's package, :mod:`blocks.model.disturbances`),
the batch engine (:mod:`blocks.figure2.batch`) and any later engine call these
functions.  The exported C plant (:mod:`fmu`) is the one other implementation,
and the tests check it against an independent reference, as they check these.

Layout
------
Signals are *rows*: a joint vector is an array whose first axis is the joint,
shape ``(n,)`` for one point or ``(n, K)`` for ``K`` columns (grid times or
batch members); n is the arm's.  A row ``q[1]`` is then a scalar or a ``(K,)`` array and the
same formula serves both.

Parameters follow the signals: an array parameter is indexed by its first
axes (``k[1]``, ``kp[i]``, ``Y[i, j]``) and, for column signals, carries a
trailing axis of length 1 (shared by every column) or ``K`` (one value per
column, as in a batch).  :func:`column_params` adds the shared trailing axis.
An arm gives its numbers as ``k = arm.kernel_params()`` and ``kin =
arm.tool_params()`` and its row kernels (``mass_times``, ``bias_forces``,
``tool_position``, ...) (the paper's RRPR in
its own package under :mod:`blocks.model`, a URDF chain's in :mod:`blocks.kernels.chain`);
nothing here is any one arm's.  The laws and block kernels take the arm's row
kernels as a value, their first argument ``model``
(:class:`blocks.kernels.model.ArmKernels`, ``arm.arm_kernels``), so one
source serves every arm.

The functions use only the part of numpy that numba compiles: no ``einsum``,
no ellipsis indexing, no keyword-heavy calls.
"""
from __future__ import annotations

import numpy as np

from blocks.kernels.disturbance import (
    DisturbanceParams,
    disturbance_params,
    external_disturbance,
    friction_disturbance,
    paper_disturbance,
    tissue_disturbance,
)
from blocks.kernels.laws import computed_torque, gain_times, lumped_disturbance, observer_estimate, observer_rate

__all__ = [
    "DisturbanceParams", "disturbance_params", "paper_disturbance", "friction_disturbance", "tissue_disturbance",
    "external_disturbance", "computed_torque", "observer_estimate", "observer_rate", "gain_times",
    "lumped_disturbance", "column_params",
]


def column_params(params: tuple) -> tuple:
    """Parameters of the one-point layout made ready for column signals.

    Every numpy array gets a trailing axis of length 1, so that it is shared
    by all columns; scalars and other values pass unchanged; named tuples are
    converted field by field.
    """
    out = []
    for value in params:
        if isinstance(value, np.ndarray):
            out.append(value[..., None])
        elif isinstance(value, tuple) and hasattr(value, "_fields"):
            out.append(type(value)(*column_params(tuple(value))))
        else:
            out.append(value)
    return tuple(out)
