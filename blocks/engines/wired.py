"""Any wired diagram as blocks with kernels: what lets a user's own blocks run on the compiled engine.

:func:`lower` takes a python-control system -- an interconnection a user
wired with :func:`control.interconnect`, or one ``NonlinearIOSystem`` /
``StateSpace`` -- and returns the same dynamics as a *direct* diagram
(every block input one signal with gain 1, no external inputs), the form
the plan's generated code runs (:mod:`blocks.engines.compiled.codegen`):

* a block that carries kernels (every Figure-2 block) stays as it is;
* a linear block (``ct.ss``, ``ct.tf`` once interconnected) gets kernels
  ``A x + B u`` and ``C x + D u``, which the trace follows;
* a nonlinear block ``ct.nlsys(updfcn, outfcn, params=...)`` gets kernels
  that call its functions with its parameters (python-control's merge of
  block, interconnection and call-time ``params``): *traced* when they run
  on symbols (numpy arithmetic, ``np.sin`` ..., ``params.get``), else
  *compiled as they stand* with ``numba.njit`` (the parameters then a typed
  dict of floats), else *refused* with the reason; a refused block keeps
  its python-control functions and the diagram runs on the numpy engine;
* a sum or a scaled signal on a block's input becomes a junction block
  ``G v`` ahead of it, the interconnection's external inputs a source block
  that interpolates ``U`` over ``T`` as :func:`control.input_output_response`
  does (linearly, extrapolating past the ends), and outputs that are not one
  signal a junction of their own.

The blocks keep their order, so the lowered diagram's state is the
original's, state for state.

A traced function runs once, on symbols: what it reads from outside its
arguments (a module constant, an object's attribute) is taken as a constant
of the generated code, as with any tracing compiler; numbers that change
between runs belong in ``params``.  The generated code is kept per content
of the function (its code, the values it closes over, the module values it
reads), so an edited function is traced again.
"""
from __future__ import annotations

import hashlib
import numbers
import types
from dataclasses import dataclass, field

import control as ct
import numpy as np

from blocks.diagram.contract import Block, BlockContract, Kernels, contract_of
from blocks.diagram.control_compat import connection_maps, merged_params, subsystems

__all__ = ["Lowered", "lower", "input_table", "junction", "linear_output", "linear_update"]


# -- kernels of the lowered blocks ---------------------------------------------------------------------------
def input_table(t, x, u, T, U):
    """The external inputs at ``t`` (s): ``U`` (m, len(T)) linearly interpolated over ``T`` as python-control's
    ``input_output_response`` does (clipped index, so extrapolated past the ends); ``t`` a float or (K,)."""
    idx = np.searchsorted(T, t)
    idx = np.minimum(np.maximum(idx, 1), T.shape[0] - 1)
    dt = (t - T[idx - 1]) / (T[idx] - T[idx - 1])
    return U[:, idx - 1] * (1.0 - dt) + U[:, idx] * dt


def junction(t, x, u, G):
    """A static sum of signals: ``G u`` (a block input that is a sum or a scaled signal)."""
    return G @ u


def linear_update(t, x, u, A, B, C, D, through):
    """A linear block's state derivative ``A x + B u``."""
    return A @ x + B @ u


def linear_output(t, x, u, A, B, C, D, through):
    """A linear block's outputs ``C x + D u``, ``D`` given by its columns ``through`` (a tuple of input indices,
    those with a nonzero column): the outputs read no other input, so the plan may evaluate the block before
    the blocks that feed those (the trace sees D's numbers only as symbols)."""
    return C @ x + D @ u[list(through)]


# Exceptions a trial trace of a user function may raise when the trace cannot follow it (as the code generator's)
_NOT_TRACED = (TypeError, AttributeError, IndexError, ValueError, KeyError, NotImplementedError)


def _digest(*parts) -> str:
    return hashlib.sha256("\x00".join(parts).encode()).hexdigest()[:16]


def _code_text(code: types.CodeType) -> str:
    """What a code object computes, for a key: its bytecode, constants (nested code too) and names."""
    consts = [(_code_text(c) if isinstance(c, types.CodeType) else repr(c)) for c in code.co_consts]
    return repr((code.co_code, consts, code.co_names, code.co_varnames))


def function_key(fn) -> str:
    """A digest of what a user function computes: its code, the values it closes over and the module numbers it
    reads (the in-process program cache and the on-disk module name depend on it)."""
    if not isinstance(fn, types.FunctionType):
        return f"{type(fn).__module__}.{type(fn).__qualname__}#{id(fn)}"
    cells = [repr(c.cell_contents) if c.cell_contents is not None else "None" for c in (fn.__closure__ or ())]
    names = []
    for name in fn.__code__.co_names:
        value = fn.__globals__.get(name)
        if isinstance(value, (numbers.Number, np.ndarray, str, tuple)):
            names.append(f"{name}={value!r}")
        elif isinstance(value, types.FunctionType):
            names.append(f"{name}={value.__module__}.{value.__qualname__}:{_digest(_code_text(value.__code__))}")
        elif value is not None and not isinstance(value, (types.ModuleType, type)) and not callable(value):
            # an object the function reads (a traced function takes its numbers as constants): its contents
            names.append(f"{name}={getattr(value, '__dict__', value)!r}")
    return _digest(fn.__module__ or "", fn.__qualname__, _code_text(fn.__code__), *cells, *names,
                   repr(fn.__defaults__))


def _is_number_param(value) -> bool:
    """A parameter the trace reads as numbers (``theta``): a real number or a small array of them."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, numbers.Real):
        return True
    return isinstance(value, np.ndarray) and value.dtype.kind in "fiu" and value.size <= 64


def _traced_kernel(fn, keys: tuple, fixed: dict, key: str, what: str):
    """``kernel(t, x, u, *values)`` calling ``fn(t, x, u, params)`` with ``params`` the fixed entries and ``keys``
    bound to ``values``; column-stacked signals are evaluated one column at a time (a user's function takes
    one point)."""
    def kernel(t, x, u, *values):
        params = dict(fixed)
        params.update(zip(keys, values))
        if getattr(x, "ndim", 1) == 2 or getattr(u, "ndim", 1) == 2:      # columns (a grid of outputs)
            K = x.shape[1] if getattr(x, "ndim", 1) == 2 else u.shape[1]
            ts = np.broadcast_to(np.asarray(t, dtype=float), (K,))
            cols = [np.ravel(np.asarray(fn(ts[k], x[:, k], u[:, k], params), dtype=float)) for k in range(K)]
            return np.stack(cols, axis=1) if cols else np.zeros((0, 0))
        return np.ravel(np.asarray(fn(t, x, u, params), dtype=object if _symbolic(x, u) else float))
    kernel.__qualname__ = f"user_{what}[{key}]"
    return kernel


def _symbolic(x, u) -> bool:
    return getattr(x, "dtype", None) == np.dtype(object) or getattr(u, "dtype", None) == np.dtype(object)


def _njit_kernel(jitted, key: str, what: str):
    """``kernel(t, x, u, params)`` calling the numba-compiled user function (the parameters a typed dict);
    the compiled engine calls ``jitted`` itself (its ``numba_kernel``), the numpy engine this function, which
    takes column-stacked signals one column at a time."""
    def kernel(t, x, u, params):
        if x.ndim == 2 or u.ndim == 2:
            K = x.shape[1] if x.ndim == 2 else u.shape[1]
            ts = np.broadcast_to(np.asarray(t, dtype=float), (K,))
            cols = [np.ravel(jitted(float(ts[k]), np.ascontiguousarray(x[:, k]), np.ascontiguousarray(u[:, k]),
                                    params)) for k in range(K)]
            return np.stack(cols, axis=1)
        return jitted(t, np.ascontiguousarray(x), np.ascontiguousarray(u), params)
    kernel.__qualname__ = f"user_njit_{what}[{key}]"
    kernel.numba_kernel = jitted
    return kernel


# -- a user's block ----------------------------------------------------------------------------------------------
@dataclass
class Lowered:
    """A diagram lowered to blocks with kernels (see the module docstring).

    Attributes
    ----------
    system : control.InterconnectedSystem
        The direct diagram; its states are the original's, in order.
    how : dict of str to str
        For each of the user's blocks without kernels: ``"linear"``, ``"traced"``, ``"compiled"`` (numba as it
        stands) or ``"refused"``.
    refused : dict of str to str
        Why each refused block could be neither traced nor compiled.
    """

    system: object
    how: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)

    @property
    def reason(self) -> str | None:
        """Why the compiled engine cannot run the diagram (None: it can)."""
        if not self.refused:
            return None
        return "; ".join(f"block '{name}' {why}" for name, why in self.refused.items())


def _linear_kernels(block) -> tuple[Kernels, tuple]:
    """The kernels of a linear block and the indices of the inputs that reach its outputs (nonzero columns of D)."""
    A, B, C, D = (np.array(m, dtype=float) for m in (block.A, block.B, block.C, block.D))
    through = tuple(int(j) for j in np.flatnonzero(np.any(D != 0, axis=0)))
    params = (A, B, C, np.ascontiguousarray(D[:, list(through)]), through)
    return Kernels(params=params, output=linear_output, update=linear_update if block.nstates else None,
                   column_params=params), through


def _inputs_read(rows) -> set:
    """The input indices (leaves ``u``) that the traced expressions ``rows`` depend on."""
    from blocks.kernels.trace import Sym
    seen, found, stack = set(), set(), [r for r in rows if isinstance(r, Sym)]
    while stack:
        node = stack.pop()
        if node.id in seen:
            continue
        seen.add(node.id)
        if node.op == "leaf":
            kind, index = node.args
            if kind == "u":
                found.add(int(index))
            continue
        for a in node.args:
            if isinstance(a, Sym):
                stack.append(a)
            elif isinstance(a, tuple):
                stack.extend(v for v in a if isinstance(v, Sym))
    return found


def _trial(kernels: Kernels, nstates: int, ninputs: int, noutputs: int) -> set:
    """Run ``kernels`` on symbols as the code generator will (raises when the trace cannot follow them); the
    inputs the outputs read (the block's feedthrough)."""
    from blocks.kernels.trace import Graph, result_rows, symbolic_params
    graph = Graph()
    sym = symbolic_params(graph, kernels.params, [], [])
    x = np.empty(nstates, dtype=object)
    for i in range(nstates):
        x[i] = graph.leaf("x", i)
    u = np.empty(ninputs, dtype=object)
    for i in range(ninputs):
        u[i] = graph.leaf("u", i)
    t = graph.leaf("t", 0)
    through = set()
    if kernels.output is not None:
        through = _inputs_read(result_rows(kernels.output(t, x, u, *sym), noutputs))
    if kernels.update is not None and nstates:
        result_rows(kernels.update(t, x, u, *sym), nstates)
    return through


def _nonlinear_kernels(block, params: dict) -> tuple[Kernels | None, str, str, frozenset | None]:
    """Kernels for a user's ``NonlinearIOSystem`` with its merged ``params``: ``(kernels, how, why refused,
    feedthrough)``, the feedthrough the inputs the traced outputs read (None: every input, untraced)."""
    upd, out = block.updfcn, block.outfcn
    if block.isdtime(strict=True):
        return None, "refused", "is discrete-time (dt > 0), which the continuous engines do not step", None
    if out is None:
        out = _state_output(block.nstates, block.noutputs)
    keys = tuple(k for k in sorted(params) if _is_number_param(params[k]))
    fixed = {k: v for k, v in params.items() if k not in keys}
    key = _digest(function_key(out), function_key(upd) if upd is not None else "",
                  repr(sorted((k, repr(v)) for k, v in fixed.items())), repr(keys))
    values = tuple(params[k] if isinstance(params[k], np.ndarray) else float(params[k]) for k in keys)
    traced = Kernels(params=values, column_params=values, output=_traced_kernel(out, keys, fixed, key, "output"),
                     update=None if upd is None or not block.nstates else _traced_kernel(upd, keys, fixed, key,
                                                                                           "update"))
    try:
        through = _trial(traced, block.nstates, block.ninputs, block.noutputs)
        labels = list(block.input_labels)
        return traced, "traced", "", frozenset(labels[i] for i in through)
    except _NOT_TRACED as err:
        why_trace = f"{type(err).__name__}: {err}"
    except Exception as err:            # a user's function may raise anything on symbols  # noqa: BLE001
        why_trace = f"{type(err).__name__}: {err}"
    compiled, why_jit = _njit_kernels(block, out, upd, params, key)
    if compiled is not None:
        return compiled, "compiled", "", None
    _check_sizes(block, out, upd, params)
    return None, "refused", (f"cannot be traced ({why_trace}) nor compiled by numba as it stands ({why_jit}), "
                             "so the compiled engine cannot run it"), None


def _check_sizes(block, out, upd, params: dict) -> None:
    """Refuse, by the block's name, a function that gives the wrong number of values at the zero state and input
    (every engine would fail on it mid-run with numpy's broadcast error); one that raises there is left to run."""
    x, u = np.zeros(block.nstates), np.zeros(block.ninputs)
    for fn, rows, what in ((out, block.noutputs, "output"), (upd, block.nstates, "update")):
        if fn is None or (what == "update" and not block.nstates):
            continue
        try:
            with np.errstate(all="ignore"):
                got = np.size(fn(0.0, x, u, params))
        except Exception:               # a function may divide by its state; its run will say  # noqa: BLE001
            continue
        if got != rows:
            raise ValueError(f"block '{block.name}': its {what} function returns {got} values at the zero state and "
                             f"input, where it has {rows} {what}s ({what} functions return one value per {what})")


def _state_output(nstates: int, noutputs: int):
    n = nstates if noutputs is None else noutputs

    def state_output(t, x, u, params):
        return x[:n]
    state_output.__qualname__ = f"state_output[{n}]"
    return state_output


# The user functions compiled by numba, by function and content (a function is compiled once per process)
_JITTED: dict = {}


def _jitted_user(numba, fn):
    key = (fn, function_key(fn))
    found = _JITTED.get(key)
    if found is None:
        found = _JITTED[key] = numba.njit(error_model="numpy")(fn)
    return found


def _njit_kernels(block, out, upd, params: dict, key: str) -> tuple[Kernels | None, str]:
    """The user's functions compiled by numba as they are, tried once on zeros; ``(kernels or None, why not)``."""
    from blocks.engines.compiled.jit import numba_or_none
    numba = numba_or_none()
    if numba is None:
        return None, "numba is not installed"
    plain = [fn for fn in (out, upd) if fn is not None and not isinstance(fn, types.FunctionType)]
    if plain:
        return None, f"its function {plain[0]!r:.60} is not a plain Python function"
    if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in params.values()):
        return None, "its parameters are not all numbers (numba gets them as a dict of floats)"
    try:
        typed = numba.typed.Dict.empty(key_type=numba.types.unicode_type, value_type=numba.types.float64)
        for k, v in params.items():
            typed[str(k)] = float(v)
        x, u = np.zeros(block.nstates), np.zeros(block.ninputs)
        fns = []
        for fn, rows, what in ((out, block.noutputs, "output"), (upd, block.nstates, "update")):
            if fn is None or (what == "update" and not block.nstates):
                fns.append(None)
                continue
            jitted = _jitted_user(numba, fn)
            raw = jitted(0.0, x, u, typed)
            if np.ndim(raw) == 0:           # python-control takes a number; the compiled loop stores an array
                return None, f"its {what} function returns a number, not an array (numba's loop needs np.array([...]))"
            got = np.asarray(raw)
            if got.size != rows:
                return None, f"its {what} function gave {got.size} values where {rows} were expected"
            fns.append(_njit_kernel(jitted, key, what))
    except Exception as err:            # numba's typing errors and whatever the function raises  # noqa: BLE001
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        return None, f"{type(err).__name__}: {first}"
    return Kernels(params=(typed,), output=fns[0], update=fns[1], column_params=(typed,)), ""


def _kernel_block(block, kernels: Kernels, feedthrough: frozenset | None = None) -> Block:
    """A :class:`Block` with ``block``'s signals and ``kernels`` (its python-control functions call them) and the
    inputs that reach its outputs (None: every one)."""
    params = kernels.params
    outfcn = (lambda t, x, u, _p: kernels.output(t, x, u, *params)) if kernels.output is not None else None
    updfcn = (lambda t, x, u, _p: kernels.update(t, x, u, *params)) if kernels.update is not None else None
    signals = dict(name=block.name, inputs=list(block.input_labels), outputs=list(block.output_labels))
    if block.nstates:
        signals["states"] = list(block.state_labels)
    return Block(updfcn, outfcn, contract=BlockContract(feedthrough=feedthrough, kernels=kernels), **signals)


def _static_block(name: str, kernels: Kernels, ninputs: int, noutputs: int) -> Block:
    return Block(None, lambda t, x, u, _p: kernels.output(t, x, u, *kernels.params),
                 contract=BlockContract(feedthrough=frozenset(f"v[{i}]" for i in range(ninputs)), kernels=kernels),
                 name=name, inputs=[f"v[{i}]" for i in range(ninputs)], outputs=[f"w[{i}]" for i in range(noutputs)])


# -- the diagram ---------------------------------------------------------------------------------------------
def lower(system, T=None, U=None, params: dict | None = None) -> Lowered:
    """The direct diagram of ``system`` with kernels for every block that allows it (see the module docstring).

    Parameters
    ----------
    system : control.InterconnectedSystem or control.NonlinearIOSystem
    T, U : numpy.ndarray, optional
        Times (s) and external inputs (ninputs, len(T)) of a run; needed when ``system`` has inputs.
    params : dict, optional
        Call-time parameters, merged as python-control merges them.
    """
    if isinstance(system, ct.InterconnectedSystem):
        blocks = subsystems(system)
        C, B, O = connection_maps(system)
        outer = system
    else:
        blocks = [system]
        C = np.zeros((system.ninputs, system.noutputs))
        B = np.eye(system.ninputs)
        O = np.hstack([np.eye(system.noutputs), np.zeros((system.noutputs, system.ninputs))])
        outer = None
    lowered = Lowered(None)
    new_blocks = []
    for block in blocks:
        if contract_of(block).kernels is not None:
            new_blocks.append(block)
            continue
        if isinstance(block, ct.InterconnectedSystem):
            lowered.how[block.name], lowered.refused[block.name] = "refused", (
                "is an interconnection inside the interconnection (flatten it: interconnect its blocks directly)")
            new_blocks.append(block)
            continue
        if isinstance(block, ct.StateSpace):
            if block.isdtime(strict=True):
                lowered.how[block.name] = "refused"
                lowered.refused[block.name] = "is discrete-time (dt > 0), which the continuous engines do not step"
                new_blocks.append(block)
                continue
            kernels, through = _linear_kernels(block)
            labels = list(block.input_labels)
            new_blocks.append(_kernel_block(block, kernels, frozenset(labels[j] for j in through)))
            lowered.how[block.name] = "linear"
            continue
        if getattr(block, "event_source", None) is not None:
            lowered.how[block.name], lowered.refused[block.name] = "refused", (
                "has events (an FMU's event indicators or time events), which only the numpy engine stops at")
            new_blocks.append(block)
            continue
        merged = merged_params(outer, block, params) if outer is not None else {**block.params, **(params or {})}
        kernels, how, why, through = _nonlinear_kernels(block, merged)
        lowered.how[block.name] = how
        if kernels is None:
            lowered.refused[block.name] = why
            new_blocks.append(block)
        else:
            new_blocks.append(_kernel_block(block, kernels, through))
    lowered.system = _direct(system, new_blocks, C, B, O, T, U)
    return lowered


def _unique(name: str, taken: set) -> str:
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def _direct(system, blocks: list, C, B, O, T, U):
    """The direct interconnection of ``blocks`` (the user's, lowered) with an input source and junctions."""
    n_in = B.shape[1]
    taken = {b.name for b in blocks}
    y_off = np.cumsum([0] + [b.noutputs for b in blocks])
    u_off = np.cumsum([0] + [b.ninputs for b in blocks])
    n_y = int(y_off[-1])
    front = []                     # source and junction blocks, ahead of the user's blocks
    # a column of [C | B] is a signal: the blocks' outputs, then the external inputs
    signal_of_column: list = [("y", j) for j in range(n_y)]
    if n_in:
        if T is None or U is None:
            raise ValueError("the system has external inputs: give T and U")
        TU = (np.asarray(T, dtype=float), np.ascontiguousarray(U, dtype=float))
        source = _static_block(_unique("u_ext", taken), Kernels(params=TU, column_params=TU,
                                                                 output=input_table),
                               0, n_in)
        front.append(source)
        signal_of_column += [("u", i) for i in range(n_in)]
    CB = np.hstack([C, B])
    # per block input row: the column it copies, or None (a junction makes it)
    feeds: list = []
    for k, block in enumerate(blocks):
        rows = CB[u_off[k]:u_off[k + 1]]
        direct = rows.shape[0] == 0 or (np.all(np.count_nonzero(rows, axis=1) == 1) and np.all(rows[rows != 0] == 1))
        if direct:
            feeds.append(("copy", [int(np.argmax(r != 0)) for r in rows]))
        else:
            used = sorted(set(np.nonzero(np.any(rows != 0, axis=0))[0].tolist()))
            G = rows[:, used]
            j = _static_block(_unique(f"sum_{block.name}", taken), Kernels(params=(G,), output=junction, column_params=(G,)),
                              len(used), rows.shape[0])
            front.append(j)
            feeds.append(("junction", (j, used)))
    # outputs: columns of O over [y, block inputs]
    n_out = O.shape[0]
    out_direct = np.all(np.count_nonzero(O, axis=1) == 1) and np.all(O[O != 0] == 1)
    tail = []
    if not out_direct:
        used = sorted(set(np.nonzero(np.any(O != 0, axis=0))[0].tolist()))
        jo = _static_block(_unique("outputs", taken), Kernels(params=(O[:, used],), output=junction,
                                                             column_params=(O[:, used],)), len(used),
                           n_out)
        tail.append((jo, used))
    every = front + blocks + [b for b, _ in tail]
    # signal index of each new block's outputs
    new_y = np.cumsum([0] + [b.noutputs for b in every])
    index = {id(b): int(new_y[i]) for i, b in enumerate(every)}
    src_start = index[id(front[0])] if n_in else None

    def signal(column: int) -> int:
        kind, j = signal_of_column[column]
        if kind == "u":
            return src_start + j
        k = int(np.searchsorted(y_off, j, side="right") - 1)
        return index[id(blocks[k])] + j - int(y_off[k])

    input_signal: dict = {}                # original block-input row -> new signal index
    new_rows: list[list[int]] = [[] for _ in every]      # per new block, the signal each input copies
    pos = {id(b): i for i, b in enumerate(every)}
    for k, (kind, what) in enumerate(feeds):
        if kind == "copy":
            sig = [signal(c) for c in what]
        else:
            jb, used = what
            new_rows[pos[id(jb)]] = [signal(c) for c in used]
            sig = [index[id(jb)] + r for r in range(blocks[k].ninputs)]
        new_rows[pos[id(blocks[k])]] = sig
        for r, s in enumerate(sig):
            input_signal[int(u_off[k]) + r] = s

    def o_signal(column: int) -> int:
        return signal(column) if column < n_y else input_signal[column - n_y]
    for jb, used in tail:
        new_rows[pos[id(jb)]] = [o_signal(c) for c in used]
    n_signals = int(new_y[-1])
    n_inputs = sum(b.ninputs for b in every)
    C_new = np.zeros((n_inputs, n_signals))
    r = 0
    for rows in new_rows:
        for s in rows:
            C_new[r, s] = 1.0
            r += 1
    O_new = np.zeros((n_out, n_signals + n_inputs))
    if tail:
        jb = tail[0][0]
        for i in range(n_out):
            O_new[i, index[id(jb)] + i] = 1.0
    else:
        for i in range(n_out):
            O_new[i, o_signal(int(np.argmax(O[i] != 0)))] = 1.0
    outputs = [f"y[{i}]" for i in range(n_out)]
    states = [f"x[{i}]" for i in range(sum(b.nstates for b in every))]
    flat = ct.InterconnectedSystem(every, connections=[], inplist=[], outlist=[], inputs=[], outputs=outputs,
                                   states=states, name=f"{system.name}_direct")
    flat.set_connect_map(C_new)
    flat.set_input_map(np.zeros((n_inputs, 0)))
    flat.set_output_map(O_new)
    return flat
