"""Rigid-body dynamics of any serial (or tree) arm as row kernels: CRBA, RNEA, Cholesky, tool point.

The arm is a :class:`ChainParams`: for every moving joint its parent, the
placement of its frame in the parent's frame, its axis and the inertia of
the body it moves (fixed links merged in), all as plain Python floats.
:class:`ChainParams` is a :class:`~blocks.kernels.trace.Frozen` parameter,
so when :mod:`blocks.kernels.trace` runs these kernels on symbols the
geometry stays constants: products with exact zeros (axis-aligned joints,
identity rotations) and sums with them are skipped here, at Python level,
and the traced straight-line code holds only what the arm needs.  Loops run
over joints (structure), branches are on joint kinds, never on ``q``.

The algorithms (Featherstone, *Rigid Body Dynamics Algorithms*, ch. 5 and 6,
with pinocchio's order of a motion: linear part first) work in the joint
frames, where each body's inertia is a constant and each joint's motion
subspace is its fixed axis (one non-zero entry for an axis-aligned joint):

* ``M(q)``: composite-rigid-body algorithm; each composite inertia is
  carried to the parent's frame, each joint's force for a unit motion to
  its ancestors' frames;
* ``h(q, q')`` and ``G(q)``: recursive Newton-Euler with the base
  accelerating at ``-g``, each body's force from Newton's and Euler's
  equations at its centre of mass;
* ``M^-1 r``: Cholesky ``M = L L^T`` and two triangular solves (the generic
  n x n solve);
* the tool point of one frame (in base coordinates: the joints' frames
  composed to the base, ``S_i = (p_i x a_i, a_i)`` about the base origin):
  its position, its linear Jacobian (base axes, as pinocchio's
  ``LOCAL_WORLD_ALIGNED``) and ``J' q'``.

Rows are joint-first: ``q[i]`` is a number, an array of a batch or a traced
symbol.  Units: rad, m, kg, kg m^2, N m, N; gravity in m/s^2.

Traced on a graph that asks for calls (the compiled engine's,
:class:`blocks.kernels.trace.Graph` with ``calls``), ``M(q)``, ``h(q, q')``
and ``G(q)`` are recorded as calls of one generated function per arm and
term (:class:`~blocks.kernels.trace.Callee`) instead of their statements,
so a loop that needs them in several functions compiles them once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blocks.kernels.trace import Callee, Frozen, Sym

__all__ = ["ChainParams", "inertia_matrix", "mass_times", "mass_solve", "bias_forces", "gravity_forces",
           "plant_acceleration", "tool_position", "tool_jacobian", "tool_acceleration_bias"]

Vec = tuple
Mat = tuple


@dataclass(frozen=True, eq=False)
class ChainParams(Frozen):
    """The geometry and inertia of an arm of ``n`` moving joints, in joint order (parents first).

    Every number is a Python float (so a trace keeps them as constants);
    rotations are row-major 3x3 tuples.  Frames follow pinocchio: joint
    ``i``'s frame sits at ``placement_i`` in its parent's joint frame (the
    base for ``parent = -1``) and moves by the joint about or along ``axis``
    (a unit vector in its own frame).

    Attributes
    ----------
    names : tuple of str
        Joint names.
    kinds : tuple of str
        ``"revolute"`` or ``"prismatic"``.
    parents : tuple of int
        Index of each joint's parent joint, ``-1`` for the base; ``parents[i] < i``.
    rotations, translations : tuple
        The joint frames' placements in their parents' frames (3x3, m).
    axes : tuple of 3-tuples
        Joint axes in the joint frames (unit).
    masses : tuple of float
        Mass of each joint's body (kg).
    coms : tuple of 3-tuples
        Centre of mass of each body in its joint frame (m).
    com_inertias : tuple of 3x3 tuples
        Rotational inertia of each body about its centre of mass, in its joint frame (kg m^2).
    gravity : 3-tuple
        Gravitational acceleration in the base frame (m/s^2), ``(0, 0, -9.81)`` for a URDF world.
    tool_joint : int
        The joint the tool frame is fixed to (``-1``: the base).
    tool_rotation, tool_translation : tuple
        The tool frame's placement in that joint's frame (3x3, m).
    """

    names: tuple
    kinds: tuple
    parents: tuple
    rotations: tuple
    translations: tuple
    axes: tuple
    masses: tuple
    coms: tuple
    com_inertias: tuple
    gravity: tuple
    tool_joint: int
    tool_rotation: tuple
    tool_translation: tuple

    @property
    def n(self) -> int:
        """Number of moving joints."""
        return len(self.kinds)

    def support(self, i: int) -> list:
        """Joints from the base to joint ``i`` (inclusive), base first; empty for ``i = -1``."""
        path = []
        while i >= 0:
            path.append(i)
            i = self.parents[i]
        return path[::-1]


# ---------------------------------------------------------------------------------------------------------------
# Arithmetic that skips exact constant zeros and ones (Python floats), so a trace stays lean
# ---------------------------------------------------------------------------------------------------------------
def _const(a, value: float) -> bool:
    return a.__class__ is float and a == value


def _mul(a, b):
    if a.__class__ is float:
        if a == 0.0:
            return 0.0
        if a == 1.0:
            return b
        if a == -1.0:
            return -b
    if b.__class__ is float:
        if b == 0.0:
            return 0.0
        if b == 1.0:
            return a
        if b == -1.0:
            return -a
    return a * b


def _add(a, b):
    if _const(a, 0.0):
        return b
    if _const(b, 0.0):
        return a
    return a + b


def _sub(a, b):
    if _const(b, 0.0):
        return a
    if _const(a, 0.0):
        return -b
    return a - b


def _sum(terms):
    out = 0.0
    for t in terms:
        out = _add(out, t)
    return out


def _dot(u, v):
    return _sum(_mul(a, b) for a, b in zip(u, v))


def _cross(u, v) -> Vec:
    return (_sub(_mul(u[1], v[2]), _mul(u[2], v[1])),
            _sub(_mul(u[2], v[0]), _mul(u[0], v[2])),
            _sub(_mul(u[0], v[1]), _mul(u[1], v[0])))


def _vadd(u, v) -> Vec:
    return tuple(_add(a, b) for a, b in zip(u, v))


def _vscale(u, s) -> Vec:
    return tuple(_mul(a, s) for a in u)


def _matvec(R, v) -> Vec:
    return tuple(_dot(row, v) for row in R)


def _matmul(A, B) -> Mat:
    return tuple(tuple(_dot(A[r], (B[0][c], B[1][c], B[2][c])) for c in range(3)) for r in range(3))


_ZERO3 = (0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------------------------------
# Kinematics: joint frames, motion subspaces and body inertias in the base frame
# ---------------------------------------------------------------------------------------------------------------
def _joint_rotation(axis, c, s) -> Mat:
    """Rotation by the angle of cosine ``c`` and sine ``s`` about the unit ``axis`` (Rodrigues)."""
    nonzero = [j for j in range(3) if axis[j] != 0.0]
    if len(nonzero) == 1:                   # about +-x, +-y or +-z: five non-trivial entries
        k = nonzero[0]
        ss = _mul(axis[k], s)
        a, b = (k + 1) % 3, (k + 2) % 3
        R = [[0.0] * 3 for _ in range(3)]
        R[k][k] = 1.0
        R[a][a] = c
        R[b][b] = c
        R[a][b] = -ss
        R[b][a] = ss
        return tuple(tuple(r) for r in R)
    t = 1.0 - c
    ux = ((0.0, -axis[2], axis[1]), (axis[2], 0.0, -axis[0]), (-axis[1], axis[0], 0.0))
    return tuple(tuple(_add(_add(c if r == col else 0.0, _mul(ux[r][col], s)), _mul(axis[r] * axis[col], t))
                       for col in range(3)) for r in range(3))


def _local_placement(k: ChainParams, q, i: int, given=None) -> tuple:
    """``(E, r)``: rotation and origin of joint ``i``'s frame in its parent's frame at ``q[i]`` (or at what
    ``given`` says: ``(cos q_i, sin q_i)`` of a revolute joint, ``q_i`` of a prismatic one)."""
    Rp, tp, axis = k.rotations[i], k.translations[i], k.axes[i]
    if k.kinds[i] == "revolute":
        c, s = (np.cos(q[i]), np.sin(q[i])) if given is None else given
        return _matmul(Rp, _joint_rotation(axis, c, s)), tp
    return Rp, _vadd(tp, _vscale(_matvec(Rp, axis), q[i] if given is None else given))


def _mtvec(E, x) -> Vec:
    """``E^T x``."""
    return tuple(_dot((E[0][c], E[1][c], E[2][c]), x) for c in range(3))


class _Frames:
    """Joint frames in the base for the joints asked for (and their ancestors): ``R[i]``, ``p[i]`` and the
    motion subspace ``S[i]`` about the base origin (for the tool point)."""

    def __init__(self, k: ChainParams, q, joints=None) -> None:
        wanted = set(range(k.n)) if joints is None else {j for i in joints for j in k.support(i)}
        self.R, self.p, self.S = {}, {}, {}
        for i in sorted(wanted):
            E, r = _local_placement(k, q, i)
            axis_loc = _matvec(k.rotations[i], k.axes[i])         # R_j(q) leaves its own axis unchanged
            parent = k.parents[i]
            if parent < 0:
                R, p, a = E, r, axis_loc
            else:
                Rl = self.R[parent]
                R, p, a = _matmul(Rl, E), _vadd(self.p[parent], _matvec(Rl, r)), _matvec(Rl, axis_loc)
            self.R[i], self.p[i] = R, p
            self.S[i] = _cross(p, a) + a if k.kinds[i] == "revolute" else a + _ZERO3


def _motion_cross(V, W) -> tuple:
    """``V x W`` of two motions ``(v, w)``."""
    v, w = V[:3], V[3:]
    return _vadd(_cross(w, W[:3]), _cross(v, W[3:])) + _cross(w, W[3:])


def _sadd(a, b) -> tuple:
    return tuple(_add(x, y) for x, y in zip(a, b))


def _subspace(k: ChainParams, i: int) -> tuple:
    """Joint ``i``'s motion subspace in its own frame: ``(0, u)`` (revolute) or ``(u, 0)`` (prismatic)."""
    u = k.axes[i]
    return _ZERO3 + u if k.kinds[i] == "revolute" else u + _ZERO3


def _along(k: ChainParams, i: int, f, n):
    """``S_i . (f, n)``: the component of a force ``(f, n)`` in joint ``i``'s frame along its motion."""
    return _dot(k.axes[i], n) if k.kinds[i] == "revolute" else _dot(k.axes[i], f)


# ---------------------------------------------------------------------------------------------------------------
# The algorithms on lists of values, in joint frames
# ---------------------------------------------------------------------------------------------------------------
def _rnea(k: ChainParams, X: list, dq, ddq, gravity) -> list:
    """``tau = M q'' + N q' + G`` (gravity ``gravity``, m/s^2) by recursive Newton-Euler, as a list.

    ``X[i] = (E, r)`` are the joints' placements in their parents (:func:`_local_placement`).
    """
    n = k.n
    V, A, F = {}, {}, {}
    for i in range(n):
        E, r = X[i]
        parent = k.parents[i]
        if parent >= 0:                  # the parent's motion in this frame
            v, w = V[parent][:3], V[parent][3:]
            a, dw = A[parent][:3], A[parent][3:]
            Vx = _mtvec(E, _vadd(v, _cross(w, r))) + _mtvec(E, w)
            Ax = _mtvec(E, _vadd(a, _cross(dw, r))) + _mtvec(E, dw)
        else:                            # the base accelerates at -g: gravity on every body
            Vx = (0.0,) * 6
            Ax = _mtvec(E, tuple(-g for g in gravity)) + _ZERO3
        S = _subspace(k, i)
        Sdq = _vscale(S, dq[i])
        V[i] = _sadd(Vx, Sdq)
        A[i] = _sadd(_sadd(Ax, _vscale(S, ddq[i])), _motion_cross(V[i], Sdq))
        # Newton-Euler about the centre of mass, then the moment about the joint origin
        m, c, Ic = k.masses[i], k.coms[i], k.com_inertias[i]
        v, w = V[i][:3], V[i][3:]
        a, dw = A[i][:3], A[i][3:]
        v_c = _vadd(v, _cross(w, c))
        f = _vscale(_vadd(_vadd(a, _cross(dw, c)), _cross(w, v_c)), m)
        n_c = _vadd(_matvec(Ic, dw), _cross(w, _matvec(Ic, w)))
        F[i] = f + _vadd(n_c, _cross(c, f))
    tau = [0.0] * n
    for i in reversed(range(n)):
        f, nm = F[i][:3], F[i][3:]
        tau[i] = _along(k, i, f, nm)
        parent = k.parents[i]
        if parent >= 0:                  # the force on the parent, in its frame
            E, r = X[i]
            Ef = _matvec(E, f)
            F[parent] = _vadd(F[parent][:3], Ef) + _vadd(F[parent][3:], _vadd(_matvec(E, nm), _cross(r, Ef)))
    return tau


def _body_inertia(k: ChainParams, i: int) -> tuple:
    """Body ``i``'s spatial inertia about its joint origin in its joint frame: ``(m, h = m c, I_O)`` with
    ``I_O = Ic + m (|c|^2 1 - c c^T)`` (parallel axes); constants."""
    m, c, Ic = k.masses[i], k.coms[i], k.com_inertias[i]
    h = _vscale(c, m)
    ch = _dot(h, c)
    I = [[None] * 3 for _ in range(3)]
    for a in range(3):
        for b in range(a, 3):
            v = _sub(Ic[a][b], _mul(h[a], c[b]))
            I[a][b] = I[b][a] = _add(v, ch) if a == b else v
    return m, h, tuple(tuple(row) for row in I)


def _inertia_to_parent(inertia, E, r) -> tuple:
    """A spatial inertia ``(m, h, I_O)`` of a joint frame expressed in its parent's frame at ``(E, r)``:
    ``h' = E h + m r``, ``I' = E I_O E^T + (m |r|^2 + 2 r.Eh) 1 - m r r^T - Eh r^T - r Eh^T``."""
    m, h, I = inertia
    he = _matvec(E, h)
    T = _matmul(E, I)
    diag = _add(_mul(m, _dot(r, r)), _mul(2.0, _dot(r, he)))
    out = [[None] * 3 for _ in range(3)]
    for a in range(3):
        for b in range(a, 3):
            v = _dot(T[a], E[b])
            if a == b:
                v = _add(v, diag)
            v = _sub(v, _add(_mul(_mul(m, r[a]), r[b]), _add(_mul(he[a], r[b]), _mul(r[a], he[b]))))
            out[a][b] = out[b][a] = v
    return m, _vadd(he, _vscale(r, m)), tuple(tuple(row) for row in out)


def _crba(k: ChainParams, X: list) -> list:
    """``M(q)`` by the composite-rigid-body algorithm in joint frames, as nested lists (exact zeros between
    branches of a tree)."""
    n = k.n
    composite = [_body_inertia(k, i) for i in range(n)]
    for i in reversed(range(n)):
        parent = k.parents[i]
        if parent >= 0:
            m2, h2, I2 = _inertia_to_parent(composite[i], *X[i])
            m1, h1, I1 = composite[parent]
            composite[parent] = (_add(m1, m2), _vadd(h1, h2), tuple(_vadd(a, b) for a, b in zip(I1, I2)))
    M = [[0.0] * n for _ in range(n)]
    for i in range(n):
        m, h, I = composite[i]
        u = k.axes[i]
        # the composite's force for a unit motion of joint i: (w x h, I w) or (m v, h x v)
        f, nm = (_cross(u, h), _matvec(I, u)) if k.kinds[i] == "revolute" else (_vscale(u, m), _cross(h, u))
        M[i][i] = _along(k, i, f, nm)
        j = i
        while k.parents[j] >= 0:         # carried to each ancestor's frame
            E, r = X[j]
            f = _matvec(E, f)
            nm = _vadd(_matvec(E, nm), _cross(r, f))
            j = k.parents[j]
            M[i][j] = M[j][i] = _along(k, j, f, nm)
    return M


def _placements(k: ChainParams, q) -> list:
    return [_local_placement(k, q, i) for i in range(k.n)]


def _cholesky_solve(M, r) -> list:
    """``M^-1 r`` for a symmetric positive-definite ``M``: ``M = L L^T``, then ``L y = r`` and ``L^T x = y``."""
    n = len(r)
    L = [[0.0] * n for _ in range(n)]
    inv = [0.0] * n
    for j in range(n):
        d = _sub(M[j][j], _sum(_mul(L[j][c], L[j][c]) for c in range(j)))
        L[j][j] = np.sqrt(d)
        inv[j] = 1.0 / L[j][j]
        for i in range(j + 1, n):
            L[i][j] = _mul(_sub(M[i][j], _sum(_mul(L[i][c], L[j][c]) for c in range(j))), inv[j])
    y = [0.0] * n
    for i in range(n):
        y[i] = _mul(_sub(r[i], _sum(_mul(L[i][c], y[c]) for c in range(i))), inv[i])
    x = [0.0] * n
    for i in reversed(range(n)):
        x[i] = _mul(_sub(y[i], _sum(_mul(L[c][i], x[c]) for c in range(i + 1, n))), inv[i])
    return x


# ---------------------------------------------------------------------------------------------------------------
# Rows in, rows out
# ---------------------------------------------------------------------------------------------------------------
def _is_traced(*rows) -> bool:
    return any(isinstance(r, np.ndarray) and r.dtype == object for r in rows)


def _pack(values, shape: tuple, *rows) -> np.ndarray:
    """Nested lists of values as an array of leading shape ``shape`` (object rows stay objects)."""
    def at(idx):
        v = values
        for i in idx:
            v = v[i]
        return v

    if _is_traced(*rows):
        out = np.empty(shape, dtype=object)
    else:
        out = np.empty(shape + np.broadcast_shapes(*(np.shape(r)[1:] for r in rows)))
    for idx in np.ndindex(*shape):
        out[idx] = at(idx)
    return out


def _zeros(n: int) -> list:
    return [0.0] * n


# ---------------------------------------------------------------------------------------------------------------
# Traced on a graph that asks for calls (blocks.kernels.trace.Graph.calls): M, h and G as functions
# ---------------------------------------------------------------------------------------------------------------
# A loop's generated code needs the same arm's M(q) and h(q, q') in several functions (right-hand side, outputs and
# their row versions); inlined, the Panda's dynamics are written out four times (about 15,000 lines for numba to
# compile).  Traced this way each is one function of the generated module, compiled once and called where needed;
# the caller computes cos q_i and sin q_i once for the true and the nominal arm, and the Cholesky solve stays inline
# (it is small, and it skips the exact zeros of a tree's M as before).  The numbers are the same operations.
def _graph_of(*rows):
    """The trace's graph (None for numbers)."""
    for r in rows:
        if isinstance(r, np.ndarray) and r.dtype == object:
            for v in r.ravel():
                if isinstance(v, Sym):
                    return v.graph
    return None


def _calls_graph(*rows):
    """The trace's graph when it asks for calls, else None (numbers, or a trace that inlines)."""
    graph = _graph_of(*rows)
    return graph if graph is not None and graph.calls else None


#: ``Graph.calls`` of a trace that records each row kernel below as one call (``KERNEL_CALLS``): the ``fast``
#: engine's, whose generated Python then calls pinocchio's algorithms for them (:mod:`blocks.model.urdf.pin_kernels`).
KERNEL_CALLS = "kernels"


def _kernel_call(kernel, k: ChainParams, *rows):
    """Outputs of ``kernel(k, *rows)`` recorded as one call of a :class:`~blocks.kernels.trace.Callee` named for the
    kernel and the arm, when the trace asks for kernel calls (:data:`KERNEL_CALLS`); else None.

    The callee's inputs are the rows as they are (``q`` first); its body is the kernel traced inline, so the
    generated function computes what the kernel computes.  ``callee.kernel = (name, k)`` says which it is, for a
    binding to another implementation of the same maths (pinocchio's).
    """
    graph = _graph_of(*rows)
    if graph is None or graph.calls != KERNEL_CALLS:
        return None
    sizes = [len(r) for r in rows]
    key = (k.frozen_digest(), kernel.__name__, tuple(sizes))
    callee = _callees.get(key)
    if callee is None:
        def body(x):
            parts, at = [], 0
            for size in sizes:
                part = np.empty(size, dtype=object)
                for i in range(size):
                    part[i] = x[at + i]
                parts.append(part)
                at += size
            return list(np.asarray(kernel(k, *parts), dtype=object).ravel())
        callee = _callees[key] = Callee(f"arm_{kernel.__name__}_{key[0].partition('#')[2]}", sum(sizes), body)
        callee.kernel = (kernel.__name__, k)
    return graph.call(callee, [r[i] for r in rows for i in range(len(r))])


def _joint_inputs(k: ChainParams, q) -> list:
    """What the joints' placements need: ``cos q_i, sin q_i`` of a revolute joint, ``q_i`` of a prismatic one."""
    out = []
    for i in range(k.n):
        out += [np.cos(q[i]), np.sin(q[i])] if k.kinds[i] == "revolute" else [q[i]]
    return out


def _placements_of(k: ChainParams, x) -> list:
    """The placements from :func:`_joint_inputs` ``x``."""
    X, j = [], 0
    for i in range(k.n):
        if k.kinds[i] == "revolute":
            X.append(_local_placement(k, None, i, (x[j], x[j + 1])))
            j += 2
        else:
            X.append(_local_placement(k, None, i, x[j]))
            j += 1
    return X


_callees: dict = {}


def _callee(k: ChainParams, kind: str) -> Callee:
    """The generated function ``arm_<kind>_<digest>`` of arm ``k``: ``inertia`` (the lower triangle of ``M`` by
    rows), ``bias`` (``h``; inputs then ``q'``) or ``gravity`` (``G``)."""
    key = (k.frozen_digest(), kind)
    found = _callees.get(key)
    if found is not None:
        return found
    m = sum(2 if kind_i == "revolute" else 1 for kind_i in k.kinds)
    n = k.n
    if kind == "inertia":
        def body(x):
            M = _crba(k, _placements_of(k, x))
            return [M[i][j] for i in range(n) for j in range(i + 1)]
        n_in = m
    elif kind == "bias":
        def body(x):
            return _rnea(k, _placements_of(k, x), list(x[m:]), _zeros(n), k.gravity)
        n_in = m + n
    else:
        def body(x):
            return _rnea(k, _placements_of(k, x), _zeros(n), _zeros(n), k.gravity)
        n_in = m
    found = _callees[key] = Callee(f"arm_{kind}_{key[0].partition('#')[2]}", n_in, body)
    return found


def _inertia(k: ChainParams, q) -> list:
    """``M(q)`` as nested lists: the CRBA, or a call of the arm's ``inertia`` function."""
    graph = _calls_graph(q)
    if graph is None:
        return _crba(k, _placements(k, q))
    values = iter(graph.call(_callee(k, "inertia"), _joint_inputs(k, q)))
    M = [[0.0] * k.n for _ in range(k.n)]
    for i in range(k.n):
        for j in range(i + 1):
            M[i][j] = M[j][i] = next(values)
    return M


def _bias(k: ChainParams, q, dq) -> list:
    """``h(q, q')`` as a list: the RNEA, or a call of the arm's ``bias`` function."""
    graph = _calls_graph(q, dq)
    if graph is None:
        return _rnea(k, _placements(k, q), [dq[i] for i in range(k.n)], _zeros(k.n), k.gravity)
    return graph.call(_callee(k, "bias"), _joint_inputs(k, q) + [dq[i] for i in range(k.n)])


def _gravity(k: ChainParams, q) -> list:
    """``G(q)`` as a list: the RNEA at rest, or a call of the arm's ``gravity`` function."""
    graph = _calls_graph(q)
    if graph is None:
        return _rnea(k, _placements(k, q), _zeros(k.n), _zeros(k.n), k.gravity)
    return graph.call(_callee(k, "gravity"), _joint_inputs(k, q))


def inertia_matrix(k: ChainParams, q) -> np.ndarray:
    """``M(q)`` (kg m^2, kg on prismatic joints), shape ``q.shape[1:] + (n, n)``, by the CRBA."""
    called = _kernel_call(inertia_matrix, k, q)
    M = _inertia(k, q) if called is None else [called[r * k.n:(r + 1) * k.n] for r in range(k.n)]
    out = _pack(M, (k.n, k.n), q)
    return out if out.ndim == 2 else np.moveaxis(out, (0, 1), (-2, -1))


def mass_times(k: ChainParams, q, v) -> np.ndarray:
    """``M(q) v`` (N m, N) for joint rows ``v`` (rad/s^2, m/s^2); rows."""
    called = _kernel_call(mass_times, k, q, v)
    if called is not None:
        return _pack(called, (k.n,), q, v)
    M = _inertia(k, q)
    return _pack([_dot(M[i], [v[j] for j in range(k.n)]) for i in range(k.n)], (k.n,), q, v)


def mass_solve(k: ChainParams, q, r) -> np.ndarray:
    """``M(q)^-1 r`` for a generalised force ``r`` (N m, N): Cholesky of ``M`` and two triangular solves; rows."""
    x = _kernel_call(mass_solve, k, q, r)
    if x is None:
        x = _cholesky_solve(_inertia(k, q), [r[i] for i in range(k.n)])
    return _pack(x, (k.n,), q, r)


def bias_forces(k: ChainParams, q, dq) -> np.ndarray:
    """``h(q, q') = N(q, q') q' + G(q)`` (N m, N) by recursive Newton-Euler; rows."""
    called = _kernel_call(bias_forces, k, q, dq)
    return _pack(_bias(k, q, dq) if called is None else called, (k.n,), q, dq)


def gravity_forces(k: ChainParams, q) -> np.ndarray:
    """``G(q)`` (N m, N): the forces that hold the arm still against gravity; rows."""
    called = _kernel_call(gravity_forces, k, q)
    return _pack(_gravity(k, q) if called is None else called, (k.n,), q)


def plant_acceleration(k: ChainParams, q, dq, force) -> np.ndarray:
    """Joint accelerations ``q'' = M(q)^-1 (force - h(q, q'))`` (rad/s^2, m/s^2); rows.

    Parameters
    ----------
    k : ChainParams
    q, dq : numpy.ndarray
        Joint positions (rad, m) and velocities (rad/s, m/s), rows.
    force : numpy.ndarray
        Total generalised force on the joints (N m, N), rows.
    """
    called = _kernel_call(plant_acceleration, k, q, dq, force)
    if called is not None:
        return _pack(called, (k.n,), q, dq, force)
    if _calls_graph(q, dq, force) is not None:
        h, M = _bias(k, q, dq), _inertia(k, q)
    else:                                       # one set of placements for both
        X = _placements(k, q)
        h = _rnea(k, X, [dq[i] for i in range(k.n)], _zeros(k.n), k.gravity)
        M = _crba(k, X)
    x = _cholesky_solve(M, [_sub(force[i], h[i]) for i in range(k.n)])
    return _pack(x, (k.n,), q, dq, force)


# ---------------------------------------------------------------------------------------------------------------
# The tool point
# ---------------------------------------------------------------------------------------------------------------
def _tool_point(k: ChainParams, fr: _Frames) -> Vec:
    j = k.tool_joint
    if j < 0:
        return k.tool_translation
    return _vadd(fr.p[j], _matvec(fr.R[j], k.tool_translation))


def tool_position(kin: ChainParams, q) -> np.ndarray:
    """Position of the tool frame's origin in the base frame (m); rows ``(3,)``."""
    fr = _Frames(kin, q, [kin.tool_joint] if kin.tool_joint >= 0 else [])
    return _pack(list(_tool_point(kin, fr)), (3,), q)


def tool_jacobian(kin: ChainParams, q) -> np.ndarray:
    """Linear Jacobian ``dp/dq`` of the tool point in base axes (m/rad, m/m); rows ``(3, n)``."""
    support = kin.support(kin.tool_joint)
    fr = _Frames(kin, q, support[-1:])
    p = _tool_point(kin, fr)
    J = [[0.0] * kin.n for _ in range(3)]
    for j in support:
        S = fr.S[j]
        col = _vadd(S[:3], _cross(S[3:], p))               # velocity of the point p: v_O + w x p
        for r in range(3):
            J[r][j] = col[r]
    return _pack(J, (3, kin.n), q)


def tool_acceleration_bias(kin: ChainParams, q, dq) -> np.ndarray:
    """``J'(q, q') q'`` (m/s^2): the tool point's classical acceleration at ``q'' = 0``, no gravity; rows ``(3,)``."""
    support = kin.support(kin.tool_joint)
    fr = _Frames(kin, q, support[-1:])
    p = _tool_point(kin, fr)
    V, A = (0.0,) * 6, (0.0,) * 6
    for j in support:
        Sdq = _vscale(fr.S[j], dq[j])
        A = _sadd(A, _motion_cross(V, Sdq))
        V = _sadd(V, Sdq)
    w = V[3:]
    pdot = _vadd(V[:3], _cross(w, p))
    acc = _vadd(_vadd(A[:3], _cross(A[3:], p)), _cross(w, pdot))
    return _pack(list(acc), (3,), q, dq)
