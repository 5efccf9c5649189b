"""A chain arm's row kernels by pinocchio's own algorithms, for the ``fast`` (numpy) engine's generated Python.

The ``fast`` engine runs a loop's generated functions on Python floats
(:mod:`blocks.engines.compiled.scalar`).  Traced with
:data:`blocks.kernels.chain.KERNEL_CALLS`, each chain row kernel the loop
uses -- ``plant_acceleration``, ``mass_solve``, ``mass_times``,
``bias_forces``, ``gravity_forces``, ``inertia_matrix`` -- is one call of a
function of the generated module; :func:`binding` gives, for such a call, a
function computing the same maths with pinocchio's C++ algorithms on a
pinocchio model built from the arm's :class:`~blocks.kernels.chain.ChainParams`
(:func:`model_of`: the same placements, axes, inertias and gravity, whatever
the arm was read from, the nominal model's scaled masses included):

==========================  ==========================================================
``plant_acceleration``      ``aba(q, q', tau)``: ``M^-1 (tau - h)``
``mass_solve(r)``           ``cholesky.solve`` with the factor of ``M(q)``: ``M^-1 r``
``mass_times(v)``           ``M(q) v``, a matrix product
``bias_forces``             ``nonLinearEffects(q, q')``: ``h``
``gravity_forces``          ``computeGeneralizedGravity(q)``: ``G``
``inertia_matrix``          ``crba(q)`` (upper triangle, mirrored)
==========================  ==========================================================

``M(q)`` (``crba``) and its Cholesky factor (``cholesky.decompose``) are made
once per ``q`` and arm and shared by ``mass_times`` and ``mass_solve``: the
controller and the observer act on the nominal arm at the same measured
``q``, so a right-hand side makes one ``M`` (together about half an
``aba``), where an ``rnea`` for ``M v`` and a second ``aba`` for ``M^-1 r``
cost three times as much.  ``q`` and ``q'`` are made arrays once per value
too (every call of a right-hand side passes them again).  What is kept is
the last ``q``'s, compared by value, so any order of calls gets the numbers
of its own ``q``.  The bindings of an arm share its pinocchio ``Data`` (as
before) and these last values: one thread of a process runs them at a time
(parallel runs are processes, :mod:`blocks.plumbing.workers`).

A Python statement costs tens of nanoseconds: the generated dynamics of a
7-joint arm are thousands of them, one of these calls a microsecond or two.
The numbers equal the chain kernels' to rounding (about 1e-15 relative; the
operations are pinocchio's, in its order), not to the last bit as the
generated statements do.
"""
from __future__ import annotations

import weakref

import numpy as np

from blocks.kernels.trace import Callee

__all__ = ["model_of", "binding"]

_models: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _pinocchio():
    try:
        import pinocchio
    except ImportError:
        return None
    return pinocchio


def _joint_model(pin, kind: str, axis: tuple):
    """pinocchio's joint for an axis: the axis-aligned joint where the axis is +x, +y or +z, else unaligned."""
    named = {(1.0, 0.0, 0.0): "X", (0.0, 1.0, 0.0): "Y", (0.0, 0.0, 1.0): "Z"}.get(tuple(float(a) for a in axis))
    if kind == "revolute":
        return getattr(pin, f"JointModelR{named}")() if named else pin.JointModelRevoluteUnaligned(np.array(axis))
    return getattr(pin, f"JointModelP{named}")() if named else pin.JointModelPrismaticUnaligned(np.array(axis))


def model_of(k) -> tuple | None:
    """``(model, data, still, still_data)``: pinocchio models of the arm ``k`` (a ``ChainParams``), with its
    gravity and with none (``still``, for ``M v`` and ``M^-1 r``); None without pinocchio.  Made once per arm."""
    found = _models.get(k)
    if found is not None:
        return found
    pin = _pinocchio()
    if pin is None:
        return None
    model = pin.Model()
    ids = []
    for i in range(k.n):
        parent = 0 if k.parents[i] < 0 else ids[k.parents[i]]
        placement = pin.SE3(np.array(k.rotations[i], dtype=float), np.array(k.translations[i], dtype=float))
        joint = model.addJoint(parent, _joint_model(pin, k.kinds[i], k.axes[i]), placement, k.names[i])
        model.appendBodyToJoint(joint, pin.Inertia(float(k.masses[i]), np.array(k.coms[i], dtype=float),
                                                   np.array(k.com_inertias[i], dtype=float)), pin.SE3.Identity())
        ids.append(joint)
    model.gravity = pin.Motion(np.array(k.gravity, dtype=float), np.zeros(3))
    still = model.copy()
    still.gravity = pin.Motion.Zero()
    found = _models[k] = (model, model.createData(), still, still.createData())
    return found


class _Last:
    """One remembered value and what it was made from (replaced as one tuple, so a reader never sees half of it)."""

    __slots__ = ("entry",)

    def __init__(self) -> None:
        self.entry = (None, None)


#: The array of the last ``q`` and ``q'`` given to a binding.  The calls of one right-hand side pass the same
#: joint positions (and rates) again and again -- to the plant's and the nominal model's algorithms, as tuples of
#: the same floats -- so each is converted to an array once per right-hand side, not once per call.
_last_q, _last_v = _Last(), _Last()


class _Factor:
    """``M(q)`` of a nominal arm and its Cholesky factor, made once per ``q``: :attr:`entry` is ``(q as a tuple, M,
    data holding the factor)`` of the last ``q``; calling it with another ``q`` makes them there."""

    __slots__ = ("entry", "model", "data", "crba", "decompose", "mirror")

    def __init__(self, model, pin) -> None:
        self.model, self.data = model, model.createData()
        self.crba, self.decompose = pin.crba, pin.cholesky.decompose
        self.entry = (None, None, None)
        # pinocchio's Python crba mirrors the upper triangle it computes; older releases returned it alone
        M = self.crba(model, self.data, np.full(model.nq, 0.3))
        self.mirror = not np.array_equal(M, M.T)

    def __call__(self, q: tuple) -> tuple:
        key, qa = _last_q.entry
        if q != key:
            qa = np.array(q)
            _last_q.entry = (q, qa)
        M = self.crba(self.model, self.data, qa)
        if self.mirror:
            M = np.triu(M) + np.triu(M, 1).T
        self.decompose(self.model, self.data)
        self.entry = (q, M, self.data)
        return M, self.data


_factors: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _factors_of(k, still, pin) -> _Factor:
    """The :class:`_Factor` of the arm ``k`` (its model without gravity ``still``), shared by its bindings."""
    found = _factors.get(k)
    if found is None:
        found = _factors[k] = _Factor(still, pin)
    return found


def binding(callee: Callee):
    """A function ``f(x) -> sequence`` computing ``callee`` (a chain row kernel recorded as a call) with pinocchio,
    returning its outputs that are not constants, in order; None when the callee is not such a call or pinocchio
    is not installed.

    ``x`` is the tuple of floats the generated code passes (``q`` first).  ``q`` and ``q'`` become arrays once per
    value (:data:`_last_q`, :data:`_last_v`), and ``M v`` and ``M^-1 r`` use ``M(q)`` and its Cholesky factor made
    once per ``q`` (``crba`` and ``cholesky.decompose``, together about half of an ``aba``; then a matrix product
    and ``cholesky.solve``, a third of an ``rnea`` each): a controller and an observer on the nominal model at the
    measured ``q`` pay for one ``M`` per right-hand side."""
    name, k = getattr(callee, "kernel", (None, None))
    if name is None:
        return None
    models = model_of(k)
    if models is None:
        return None
    model, data, still, _ = models
    pin = _pinocchio()
    n = k.n
    _, outputs = callee.traced
    kept = np.array([i for i, v in enumerate(outputs) if Callee.constant(v) is None], dtype=int)
    array = np.array
    last_q, last_v = _last_q, _last_v
    if len(kept) == len(outputs):
        listed = np.ndarray.tolist
    else:
        def listed(values: np.ndarray) -> list:
            return values[kept].tolist()

    # q and q' memoised inline (a function call per lookup costs about as much as the lookup)
    if name == "plant_acceleration":
        aba = pin.aba

        def values(x):
            q, v = x[:n], x[n:2 * n]
            key, qa = last_q.entry
            if q != key:
                qa = array(q)
                last_q.entry = (q, qa)
            key, va = last_v.entry
            if v != key:
                va = array(v)
                last_v.entry = (v, va)
            return listed(aba(model, data, qa, va, array(x[2 * n:])))
    elif name == "mass_solve":
        solve = pin.cholesky.solve
        factor_at = _factors_of(k, still, pin)

        def values(x):
            q = x[:n]
            key, _, factor = factor_at.entry
            if q != key:
                _, factor = factor_at(q)
            return listed(solve(still, factor, array(x[n:])))
    elif name == "mass_times":
        factor_at = _factors_of(k, still, pin)

        def values(x):
            q = x[:n]
            key, M, _ = factor_at.entry
            if q != key:
                M, _ = factor_at(q)
            return listed(M.dot(array(x[n:])))
    elif name == "bias_forces":
        nle = pin.nonLinearEffects

        def values(x):
            q, v = x[:n], x[n:2 * n]
            key, qa = last_q.entry
            if q != key:
                qa = array(q)
                last_q.entry = (q, qa)
            key, va = last_v.entry
            if v != key:
                va = array(v)
                last_v.entry = (v, va)
            return listed(nle(model, data, qa, va))
    elif name == "gravity_forces":
        gravity = pin.computeGeneralizedGravity

        def values(x):
            return listed(gravity(model, data, array(x)))
    elif name == "inertia_matrix":
        crba = pin.crba
        upper = np.triu_indices(n)

        def values(x):
            M = crba(model, data, array(x))
            M[upper[::-1]] = M[upper]                 # pinocchio fills the upper triangle: mirror it
            return listed(M.ravel())
    else:
        return None
    values.__name__ = callee.name
    return values

