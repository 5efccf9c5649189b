"""One tick of a scenario's digital controller as C, traced from the sampled-controller kernels.

The controller FMU (:mod:`fmu.controller_export`) runs the blocks the
monolithic sampled loop runs (:func:`blocks.figure2.digital_loop.sampled_loop`):
``encoder``, ``observer``, ``controller`` and ``actuator``.  Their kernels
(:mod:`blocks.diagram.digital`) are called once on the traced symbols of
:mod:`blocks.kernels.trace` -- the same trace the compiled numba engine
uses -- and :mod:`blocks.engines.compiled.c_backend` writes what they compute as C
statements, one per traced expression.  Four functions are generated:

``ctrl_start(in, theta, x)``
    the controller's state at the first tick from the first inputs, as
    :func:`blocks.figure2.digital_loop.sampled_initial_state` sets it (the encoder's
    previous sample consistent with the start velocity, ``z`` so that
    ``d_hat(0)`` is the scenario's start estimate; the delay buffer is
    filled by the caller with the first command);
``ctrl_outputs(t, x, in, ref, theta, out)``
    ``out = [tau; d_hat; tau_cmd]`` at a tick, as
    :meth:`blocks.engines.hybrid.HybridSystem.tick_outputs` evaluates them
    (encoder, observer, controller, actuator);
``ctrl_zoh_matrix(t, x, in, ref, theta, a)``
    only for ``observer_discretization = "zoh"``: the augmented matrix
    ``[[A, c], [0, 0]] Ts`` of :func:`blocks.diagram.digital.observer_zoh_update`,
    built with the observer law itself; its exponential is taken by the
    runtime routine ``dk_expm`` (``fmu/c/controller_expm.c``, the Pade
    scaling-and-squaring method of :func:`blocks.kernels.expm.expm_small`),
    because that routine branches on values and does not trace;
``ctrl_update(t, x, in, ref, theta, e, xn)``
    the states after the tick (:meth:`~blocks.engines.hybrid.HybridSystem.tick_updates`).

``in`` holds ``[q; dq]`` (the plant's outputs at the tick), ``ref`` the row
``[q_ref; dq_ref; ddq_ref]`` of the tick, ``theta`` every number of the
kernels' parameters (the gains among them, so that they are tunable).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from blocks.diagram.contract import contract_of
from blocks.diagram.digital import observer_zoh_update, quantized
from blocks.engines.compiled.c_backend import C_PRELUDE, emit_c_function
from blocks.kernels import observer_rate
from blocks.kernels.trace import Graph, Sym, symbolic_params

__all__ = ["TickCode", "trace_tick", "is_zoh_update"]

_BLOCKS = ("encoder", "observer", "controller", "actuator")


@dataclass
class TickCode:
    """The generated C of one controller and the layout of its arrays.

    Attributes
    ----------
    source : str
        ``controller_tick.c``: the four functions (see the module docstring).
    n : int
        Joints.
    theta : numpy.ndarray
        Start values of ``theta`` (every number of the kernels' parameters).
    gains : dict of str to list of int
        ``"kp"``, ``"kd"``, ``"Y"``: the positions of the gains' entries in ``theta``
        (``Y`` row by row when it is a full matrix, its diagonal otherwise).
    y_full : bool
        Whether ``Y`` is a full matrix (else only its diagonal is a parameter).
    nx : int
        Controller states: encoder (``2 n`` with a velocity difference), observer ``z`` (n), delay buffer.
    buffer : slice
        The delay buffer's place in ``x`` (empty without a delay).
    zoh : bool
        Whether the observer update needs the exponential of ``ctrl_zoh_matrix``.
    state_labels : list of str
        The names of the entries of ``x`` (``q_prev[i]``, ``v_prev[i]``, ``z[i]``, ``buffer0[i]`` ...).
    """

    source: str
    n: int
    theta: np.ndarray
    gains: dict
    y_full: bool
    nx: int
    buffer: slice
    zoh: bool
    state_labels: list = field(default_factory=list)


def _leaves(graph: Graph, kind: str, count: int, offset: int = 0) -> np.ndarray:
    out = np.empty(count, dtype=object)
    for i in range(count):
        out[i] = graph.leaf(kind, offset + i)
    return out


def _objects(values) -> np.ndarray:
    out = np.empty(len(values), dtype=object)
    for i, v in enumerate(values):
        out[i] = v
    return out


def _flat(value) -> list:
    return list(np.asarray(value, dtype=object).ravel())


class _Tick:
    """The four controller blocks of a sampled loop, traced with symbolic parameters (one graph per C function)."""

    def __init__(self, loop, scenario) -> None:
        names = {b.name: b for b in loop.syslist}
        missing = [b for b in _BLOCKS if b not in names]
        if missing:
            raise ValueError(f"the sampled loop has no block {missing}: the controller FMU needs the observer "
                             "(export the loop with the disturbance observer)")
        self.kernels = {b: contract_of(names[b]).kernels for b in _BLOCKS}
        self.states = {b: list(names[b].state_labels) for b in _BLOCKS}
        self.s = scenario
        self.n = scenario.robot.joints.count
        offset, self.x_slices = 0, {}
        for b in _BLOCKS:
            self.x_slices[b] = slice(offset, offset + len(self.states[b]))
            offset += len(self.states[b])
        self.nx = offset
        # parameters as theta symbols, block by block in a fixed order (the C reads theta by these positions)
        self.theta: list[float] = []
        self.positions: dict[str, list[int]] = {}
        self._layout()

    def _layout(self) -> None:
        self.param_layout = {}
        for b in _BLOCKS:
            params = self.kernels[b].params
            spans = []
            for p in params:
                start = len(self.theta)
                # a trial on a throwaway graph: where each parameter's numbers fall in theta
                symbolic_params(Graph(), p, self.theta)
                spans.append((start, len(self.theta)))
            self.param_layout[b] = spans
        kp_span, kd_span = self.param_layout["controller"][1], self.param_layout["controller"][2]
        y_span = self.param_layout["observer"][1]
        self.positions = {"kp": list(range(*kp_span)), "kd": list(range(*kd_span)), "Y": list(range(*y_span))}
        self.y_full = np.ndim(self.kernels["observer"].params[1]) == 2

    def params(self, graph: Graph, block: str) -> tuple:
        """The block's parameters with each number a ``theta[j]`` leaf of ``graph`` (at its fixed position)."""
        values: list[float] = []
        sym = symbolic_params(graph, self.kernels[block].params, values)
        start = self.param_layout[block][0][0]
        # symbolic_params numbered the leaves from 0; renumber to the block's place in theta
        return _renumber(graph, sym, start)

    # -- the tick's outputs ------------------------------------------------------------------------
    def outputs(self, graph: Graph) -> dict:
        n = self.n
        t = graph.leaf("t", 0)
        x = _leaves(graph, "x", self.nx)
        u = _leaves(graph, "in", 2 * n)
        ref = _leaves(graph, "ref", 3 * n)
        sig = {}
        enc = self.kernels["encoder"]
        xs = x[self.x_slices["encoder"]]
        y = _flat(enc.output(t, xs, u, *self.params(graph, "encoder")))
        sig["q_s"], sig["dq_s"] = y[:n], y[n:]
        obs = self.kernels["observer"]
        obs_in = _objects([graph.const(0.0)] * n + sig["q_s"] + sig["dq_s"])   # tau does not feed through
        sig["d_hat"] = _flat(obs.output(t, x[self.x_slices["observer"]], obs_in, *self.params(graph, "observer")))
        ctl = self.kernels["controller"]
        ctl_in = _objects(list(ref) + sig["q_s"] + sig["dq_s"] + sig["d_hat"])
        sig["tau_cmd"] = _flat(ctl.output(t, x[self.x_slices["controller"]], ctl_in,
                                          *self.params(graph, "controller")))
        act = self.kernels["actuator"]
        sig["tau"] = _flat(act.output(t, x[self.x_slices["actuator"]], _objects(sig["tau_cmd"]),
                                      *self.params(graph, "actuator")))
        sig.update(t=t, x=x, u=u)
        return sig

    def observer_inputs(self, sig: dict) -> np.ndarray:
        return _objects(sig["tau"] + sig["q_s"] + sig["dq_s"])

    def zoh_matrix(self, graph: Graph) -> list:
        """The augmented matrix of :func:`blocks.diagram.digital.observer_zoh_update`, row by row."""
        sig = self.outputs(graph)
        n = self.n
        k, gain, eq16, period = self.params(graph, "observer")
        u = self.observer_inputs(sig)
        tau, q, dq = u[:n], u[n:2 * n], u[2 * n:3 * n]
        rate = _observer_rate(self.kernels["observer"].update)
        c = _flat(rate(k, gain, eq16, q, dq, tau, np.zeros(n)))
        a = [[graph.const(0.0)] * (n + 1) for _ in range(n + 1)]
        for j in range(n):
            basis = np.zeros(n)
            basis[j] = 1.0
            col = _flat(rate(k, gain, eq16, q, dq, tau, basis))
            for i in range(n):
                a[i][j] = (col[i] - c[i]) * period
        for i in range(n):
            a[i][n] = c[i] * period
        return [v for row in a for v in row]

    def update(self, graph: Graph) -> list:
        """Every state after the tick, in ``x`` order."""
        sig = self.outputs(graph)
        n, t, x = self.n, sig["t"], sig["x"]
        nxt = list(x)
        enc = self.kernels["encoder"]
        if enc.update is not None:
            xs = self.x_slices["encoder"]
            nxt[xs] = _flat(enc.update(t, x[xs], sig["u"], *self.params(graph, "encoder")))
        obs = self.kernels["observer"]
        xs = self.x_slices["observer"]
        if is_zoh_update(obs.update):
            e = _leaves(graph, "e", (n + 1) * (n + 1))
            step = e.reshape(n + 1, n + 1)
            z = x[xs]
            # z_{k+1} = e^{A Ts} z_k + (int e^{A s} ds) c, the last line of observer_zoh_update
            nxt[xs] = [sum((step[i, j] * z[j] for j in range(1, n)), step[i, 0] * z[0]) + step[i, n]
                       for i in range(n)]
        else:
            nxt[xs] = _flat(obs.update(t, x[xs], self.observer_inputs(sig), *self.params(graph, "observer")))
        act = self.kernels["actuator"]
        xs = self.x_slices["actuator"]
        if act.update is not None and xs.stop > xs.start:
            nxt[xs] = _flat(act.update(t, x[xs], _objects(sig["tau_cmd"]), *self.params(graph, "actuator")))
        return nxt

    def start(self, graph: Graph) -> list:
        """The first tick's states from the first inputs (the buffer is filled by the caller)."""
        n = self.n
        u = _leaves(graph, "in", 2 * n)
        q0, dq0 = u[:n], u[n:]
        x = [graph.const(0.0)] * self.nx
        xs = self.x_slices["encoder"]
        if xs.stop > xs.start:
            res, steps, period = self.params(graph, "encoder")[:3]
            q_s0 = _flat(quantized(q0, res, steps))
            x[xs] = [q_s0[i] - period * dq0[i] for i in range(n)] + list(dq0)
        _, gain, _, _ = self.params(graph, "observer")
        d_hat0 = self.s.initial["d_hat"]
        d_hat0 = np.zeros(n) if d_hat0 is None else np.asarray(d_hat0, dtype=float)
        gain = np.asarray(gain, dtype=object)
        y_dq = [sum((gain[i, j] * dq0[j] for j in range(1, n)), gain[i, 0] * dq0[0]) for i in range(n)] \
            if gain.ndim == 2 else [gain[i] * dq0[i] for i in range(n)]
        x[self.x_slices["observer"]] = [float(d_hat0[i]) - y_dq[i] for i in range(n)]
        return x


def is_zoh_update(update) -> bool:
    """Whether an observer's update is :func:`blocks.diagram.digital.observer_zoh_update` (called with any arm's kernels:
    :func:`blocks.kernels.model.with_arm`)."""
    return getattr(update, "func", update) is observer_zoh_update


def _observer_rate(update):
    """The observer law as the zoh update calls it: :func:`blocks.kernels.observer_rate` with the update's arm's
    kernels (``update.model``)."""
    return partial(observer_rate, update.model)


def _renumber(graph: Graph, sym, start: int):
    """``sym`` (from :func:`symbolic_params` numbered from 0) with every ``theta[j]`` leaf moved to ``theta[start + j]``."""
    if isinstance(sym, Sym):
        if sym.op == "leaf" and sym.args[0] == "theta":
            return graph.leaf("theta", start + sym.args[1])
        return sym
    if isinstance(sym, np.ndarray) and sym.dtype == object:
        out = np.empty(sym.shape, dtype=object)
        for idx in np.ndindex(sym.shape):
            out[idx] = _renumber(graph, sym[idx], start)
        return out
    if isinstance(sym, tuple):
        items = [_renumber(graph, v, start) for v in sym]
        return type(sym)(*items) if hasattr(sym, "_fields") else tuple(items)
    return sym


#: Leaf kinds of a tick's trace -> their C arguments.
_LEAVES = {"t": "t", "x": "x[{i}]", "in": "in[{i}]", "ref": "ref[{i}]", "theta": "theta[{i}]", "e": "e[{i}]"}


def _function(name: str, args: str, rows: list, out: str) -> str:
    return emit_c_function(name, rows, leaves=_LEAVES, args=args, out=out)


def trace_tick(loop, scenario) -> TickCode:
    """Trace the controller blocks of a sampled loop and generate the C of one tick.

    Parameters
    ----------
    loop : blocks.engines.hybrid.HybridSystem
        :func:`blocks.figure2.digital_loop.sampled_loop` of the scenario, with the observer.
    scenario : blocks.scenarios.scenario.Scenario
        The scenario (its start estimate ``initial.d_hat``).

    Raises
    ------
    blocks.kernels.trace.TraceError
        If a kernel cannot be traced (a branch on a value); its subclass
        :class:`blocks.engines.compiled.c_backend.CodegenError` if the trace holds what C cannot (a table).
    """
    tick = _Tick(loop, scenario)
    n = tick.n
    head = C_PRELUDE + "\n#include \"controller_tick.h\"\n\n"
    const = "const double *"
    parts = []
    g = Graph()
    parts.append(_function("ctrl_start", f"{const}in, {const}theta, double *x",
                           tick.start(g), "x"))
    g = Graph()
    sig = tick.outputs(g)
    outs = sig["tau"] + sig["d_hat"] + sig["tau_cmd"]
    parts.append(_function("ctrl_outputs", f"double t, {const}x, {const}in, {const}ref, {const}theta, double *out",
                           outs, "out"))
    zoh = is_zoh_update(tick.kernels["observer"].update)
    if zoh:
        g = Graph()
        parts.append(_function("ctrl_zoh_matrix",
                               f"double t, {const}x, {const}in, {const}ref, {const}theta, double *a",
                               tick.zoh_matrix(g), "a"))
    g = Graph()
    parts.append(_function("ctrl_update",
                           f"double t, {const}x, {const}in, {const}ref, {const}theta, {const}e, double *xn",
                           tick.update(g), "xn"))
    source = "/* controller_tick.c: traced from the dobkit sampled-controller kernels; do not edit. */\n" + \
        head + "\n".join(parts)
    buf = tick.x_slices["actuator"]
    labels = [label for b in _BLOCKS for label in tick.states[b]]
    return TickCode(source=source, n=n, theta=np.array(tick.theta, dtype=float), gains=tick.positions,
                    y_full=tick.y_full, nx=tick.nx, buffer=buf, zoh=zoh, state_labels=labels)
