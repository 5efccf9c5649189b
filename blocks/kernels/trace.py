"""Trace a kernel into scalar expressions: the kernels run once on symbols, and what they compute is recorded.

A block kernel of :mod:`blocks.kernels` is a plain numpy function of rows.
Called with object arrays whose elements are :class:`Sym` (symbols for the
states, inputs, time and numeric parameters), it runs unchanged and returns
rows of expressions: every ``+``, ``*``, ``np.cos`` ... it performed, in its
order, with structural choices (which disturbance models act, a diagonal or
full gain) taken at trace time.  Equal sub-expressions are one node
(hash-consing), so a term the controller and the observer both compute, such
as ``cos(theta2)`` of the nominal model, is computed once in the generated
code.

A table parameter (a large array, such as the samples of measurement
noise) is not turned into symbols: it becomes a :class:`SymTable`, read by
the generated code from the called kernels' parameters, and indexing it
with a traced value (``table[:, i]``) records a lookup; its length is read
at run time, so the code does not depend on it.

What cannot be traced -- a branch on a value (``if x > 0``), ``math``
functions on a symbol -- raises :class:`TraceError`; the engine then calls
that block's kernel as a compiled function instead (see
:mod:`blocks.engines.compiled.codegen`).
"""
from __future__ import annotations

import hashlib
import numbers
import weakref

import numpy as np

__all__ = ["Sym", "SymTable", "TraceError", "Graph", "Callee", "Frozen", "result_rows", "symbolic_params",
           "param_structure", "param_values", "param_tables", "is_table", "TABLE_SIZE"]

#: A parameter array larger than this is a table (noise samples), not numbers to trace.
TABLE_SIZE = 64


def is_table(value) -> bool:
    """Whether a parameter is a table: an array of more than :data:`TABLE_SIZE` numbers, or not of numbers."""
    return isinstance(value, np.ndarray) and (value.size > TABLE_SIZE or value.dtype.kind not in "fiu")


class Frozen:
    """A parameter that is structure, not numbers: the trace specialises on it and reads no symbol from it.

    A model's geometry (an arm's joint placements, axes and inertias) is
    kept as plain Python floats in a subclass of this marker, so a traced
    kernel sees constants: products with exact zeros are skipped at trace
    time and the generated code carries the numbers as literals.
    :func:`symbolic_params` returns it unchanged, :func:`param_values` reads
    no number from it and :func:`param_structure` gives a digest of
    :meth:`frozen_key`, so two models of different numbers get different
    code.
    """

    __slots__ = ()

    def frozen_key(self) -> str:
        """A text that determines the object exactly (default: its ``repr``, exact for floats)."""
        return repr(self)

    def frozen_digest(self) -> str:
        """``TypeName#`` and a hash of :meth:`frozen_key`: what the generated code is specialised on (kept per
        object: the ``repr`` of a 7-joint arm takes milliseconds, and every run's structure key asks for it)."""
        try:
            found = _digests.get(self)
        except TypeError:               # not weakly referenceable: computed each time
            found = None
        if found is None:
            found = f"{type(self).__name__}#{hashlib.sha256(self.frozen_key().encode()).hexdigest()[:20]}"
            try:
                _digests[self] = found
            except TypeError:
                pass
        return found


# Digests of Frozen parameters (immutable by contract), by object
_digests: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class TraceError(TypeError):
    """A kernel did something with a symbol that has no scalar expression (a branch on its value, say)."""


# Ufuncs a symbol takes part in, by numpy name -> the operator or function name of the generated code.
_BINARY = {"add": "+", "subtract": "-", "multiply": "*", "true_divide": "/", "divide": "/",
           "greater": ">", "less": "<", "greater_equal": ">=", "less_equal": "<="}
_CALLS = {"cos", "sin", "tan", "tanh", "sqrt", "exp", "sign", "floor", "absolute", "negative", "maximum", "minimum",
          "arctan2", "square", "rint"}


class Callee:
    """A function the generated code calls instead of inlining its statements (an arm's ``M(q)`` or ``h(q, q')``).

    Parameters
    ----------
    name : str
        Its name in the generated module (unique for what it computes: the arm's digest is part of it).
    n_in : int
        Number of scalar inputs (the generated function takes them as one tuple ``x``).
    body : callable
        ``body(x) -> list``: its outputs as expressions of the symbols ``x`` (a list of ``n_in``), or numbers.

    Its body is traced once, on its own graph (:attr:`traced`).  Outputs that
    are constants there (exact zeros of a tree's inertia matrix, say) are not
    returned by the generated function: a call gives them to the caller as
    Python floats, so the caller's trace still skips them.
    """

    def __init__(self, name: str, n_in: int, body) -> None:
        self.name, self.n_in, self.body = name, n_in, body
        self._traced = None

    @property
    def traced(self) -> tuple:
        """``(graph, outputs)``: the body traced on ``x[0] ... x[n_in - 1]``."""
        if self._traced is None:
            graph = Graph()
            x = [graph.leaf("x", i) for i in range(self.n_in)]
            self._traced = graph, list(self.body(x))
        return self._traced

    @staticmethod
    def constant(value):
        """The number an output is when it is a constant, else None."""
        if isinstance(value, Sym):
            return value.args[0] if value.op == "const" else None
        return float(value)


class Graph:
    """The nodes of one trace: every expression once, in creation order (which is a dependency order).

    With ``calls`` set, model kernels that offer it (:mod:`blocks.kernels.chain`) record a call of a
    :class:`Callee` (:meth:`call`) instead of their statements; the callees used are in :attr:`callees`.
    """

    def __init__(self, calls: bool = False) -> None:
        self.nodes: dict[tuple, Sym] = {}
        self.calls = calls
        self.callees: dict[str, Callee] = {}

    def call(self, callee: Callee, args) -> list:
        """The outputs of ``callee`` on ``args`` (numbers or symbols of this graph): a symbol per output it
        returns, a Python float per constant output.  Equal calls are one node (computed once)."""
        if len(args) != callee.n_in:
            raise TraceError(f"{callee.name} takes {callee.n_in} inputs, not {len(args)}")
        known = self.callees.setdefault(callee.name, callee)
        if known is not callee and known.n_in != callee.n_in:
            raise TraceError(f"two different functions are named {callee.name}")
        wrapped = tuple(a if isinstance(a, Sym) else self.const(float(a)) for a in args)
        node = self.node("fcall", (callee.name,) + wrapped)
        out, j = [], 0
        for value in callee.traced[1]:
            c = Callee.constant(value)
            if c is not None:
                out.append(float(c))
            else:
                out.append(self.node("fout", (node, j)))
                j += 1
        return out

    def node(self, op: str, args: tuple) -> Sym:
        key = (op,) + tuple(a if isinstance(a, Sym) else ("c", a) for a in args)
        found = self.nodes.get(key)
        if found is None:
            found = Sym(self, op, args, len(self.nodes))
            self.nodes[key] = found
        return found

    def leaf(self, kind: str, index) -> Sym:
        """A value the generated code reads: ``t``, ``x[i]``, ``theta[j]``, ``src[j]``, an opaque result, ..."""
        return self.node("leaf", (kind, index))

    def const(self, value: float) -> Sym:
        return self.node("const", (float(value),))


def _is_const(v, value: float) -> bool:
    return isinstance(v, Sym) and v.op == "const" and v.args[0] == value


class Sym:
    """A scalar expression of a trace.  Arithmetic with numbers, symbols and numpy builds new expressions."""

    __slots__ = ("graph", "op", "args", "id")
    __array_priority__ = 1000

    def __init__(self, graph: Graph, op: str, args: tuple, ident: int) -> None:
        self.graph, self.op, self.args, self.id = graph, op, args, ident

    def __repr__(self) -> str:
        return f"Sym#{self.id}({self.op})"

    # -- building ------------------------------------------------------------------------------------
    def _wrap(self, v) -> Sym:
        if isinstance(v, Sym):
            return v
        if isinstance(v, (bool, np.bool_)):
            return self.graph.const(1.0 if v else 0.0)
        if isinstance(v, numbers.Real):
            return self.graph.const(float(v))
        raise TraceError(f"cannot combine a traced value with {type(v).__name__}")

    def _binary(self, op: str, a, b) -> Sym:
        a, b = self._wrap(a), self._wrap(b)
        if a.op == "const" and b.op == "const" and op in "+-*/":
            x, y = np.float64(a.args[0]), np.float64(b.args[0])
            with np.errstate(all="ignore"):
                return self.graph.const({"+": x + y, "-": x - y, "*": x * y, "/": x / y}[op])
        # exact identities only (x + 0, x * 1, ...): the generated code must round as the kernel does
        if op == "+" and _is_const(b, 0.0):
            return a
        if op == "+" and _is_const(a, 0.0):
            return b
        if op == "-" and _is_const(b, 0.0):
            return a
        if op == "-" and _is_const(a, 0.0):
            return self.graph.node("call", ("negative", b))
        if op == "*" and _is_const(b, 1.0):
            return a
        if op == "*" and _is_const(a, 1.0):
            return b
        if op == "/" and _is_const(b, 1.0):
            return a
        return self.graph.node("bin", (op, a, b))

    def _call(self, name: str, *args) -> Sym:
        return self.graph.node("call", (name,) + tuple(self._wrap(a) for a in args))

    def __add__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("+", a, b))

    def __radd__(self, o):
        return _elementwise(o, self, lambda a, b: self._binary("+", a, b))

    def __sub__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("-", a, b))

    def __rsub__(self, o):
        return _elementwise(o, self, lambda a, b: self._binary("-", a, b))

    def __mul__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("*", a, b))

    def __rmul__(self, o):
        return _elementwise(o, self, lambda a, b: self._binary("*", a, b))

    def __truediv__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("/", a, b))

    def __rtruediv__(self, o):
        return _elementwise(o, self, lambda a, b: self._binary("/", a, b))

    def __gt__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary(">", a, b))

    def __lt__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("<", a, b))

    def __ge__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary(">=", a, b))

    def __le__(self, o):
        return _elementwise(self, o, lambda a, b: self._binary("<=", a, b))

    def __neg__(self):
        if self.op == "const":
            return self.graph.const(-self.args[0])
        return self._call("negative", self)

    def __pos__(self):
        return self

    def __abs__(self):
        return self._call("absolute", self)

    def __pow__(self, o):
        if isinstance(o, numbers.Integral) and o == 2:      # numpy squares exactly, as x * x
            return self._binary("*", self, self)
        raise TraceError(f"power {o!r} of a traced value is not supported")

    def __bool__(self):
        raise TraceError("a kernel branches on a traced value")

    def __float__(self):
        raise TraceError("a kernel converts a traced value to a Python number")

    def __int__(self):
        raise TraceError("a kernel converts a traced value to an integer")

    def __index__(self):
        raise TraceError("a kernel indexes with a traced value")

    def astype(self, dtype):
        """An index made of a traced value stays the (whole-valued) float expression; a :class:`SymTable`
        converts it where it indexes."""
        if np.dtype(dtype).kind not in "iu":
            raise TraceError(f"a kernel converts a traced value to {dtype}")
        return self

    # methods numpy's object-array loops call, by ufunc name
    def cos(self):
        return self._call("cos", self)

    def sin(self):
        return self._call("sin", self)

    def tan(self):
        return self._call("tan", self)

    def tanh(self):
        return self._call("tanh", self)

    def sqrt(self):
        return self._call("sqrt", self)

    def exp(self):
        return self._call("exp", self)

    def rint(self):
        return self._call("rint", self)

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            raise TraceError(f"numpy {ufunc.__name__}.{method} on a traced value is not supported")
        name = ufunc.__name__
        if name in _BINARY and len(inputs) == 2:
            op = _BINARY[name]
            return _elementwise(inputs[0], inputs[1], lambda a, b: self._binary(op, a, b))
        if name in _CALLS:
            if name == "negative":
                return _elementwise_unary(inputs[0], lambda a: -self._wrap(a))
            if name == "square":
                return _elementwise_unary(inputs[0], lambda a: self._wrap(a) ** 2)
            if len(inputs) == 1:
                return _elementwise_unary(inputs[0], lambda a: self._call(name, a))
            return _elementwise(inputs[0], inputs[1], lambda a, b: self._call(name, a, b))
        raise TraceError(f"numpy {name} on a traced value is not supported")


class SymTable:
    """A table parameter during a trace: read by the generated code as ``ext[slot]``, indexed by traced values.

    ``table.shape`` gives the row count and, for the length, a symbol read at
    run time; ``table[:, i]`` with ``i`` a whole-valued expression gives one
    lookup per row.
    """

    def __init__(self, graph: Graph, slot: int, rows: int) -> None:
        self.graph, self.slot, self.rows = graph, slot, rows

    @property
    def shape(self) -> tuple:
        return (self.rows, self.graph.leaf("tablen", self.slot))

    def __getitem__(self, key):
        if not (isinstance(key, tuple) and len(key) == 2 and key[0] == slice(None)):
            raise TraceError("a traced table is read as table[:, i]")
        index = key[1] if isinstance(key[1], Sym) else self.graph.const(float(key[1]))
        out = np.empty(self.rows, dtype=object)
        for r in range(self.rows):
            out[r] = self.graph.node("lookup", (self.slot, r, index))
        return out


def _elementwise(a, b, fn):
    """``fn`` on scalars, or element by element with numpy broadcasting when an operand is an array."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.frompyfunc(fn, 2, 1)(_as_objects(a), _as_objects(b))
    return fn(a, b)


def _elementwise_unary(a, fn):
    if isinstance(a, np.ndarray):
        return np.frompyfunc(fn, 1, 1)(_as_objects(a))
    return fn(a)


def _as_objects(a):
    if isinstance(a, np.ndarray):
        return a.astype(object)
    box = np.empty((), dtype=object)
    box[()] = a
    return box


# ----------------------------------------------------------------------------------------------------------
# Parameters: numbers become symbols read from one flat vector; flags and shapes stay as they are
# ----------------------------------------------------------------------------------------------------------
def result_rows(value, n: int | None, what: str = "a kernel", error: type = TraceError) -> list:
    """A traced result as a list of ``n`` expressions (any count when ``n`` is None), for either back end.

    Raises ``error`` naming ``what`` when the count differs or a row was left unset (``None``).
    """
    arr = np.asarray(value, dtype=object).ravel()
    if n is not None and arr.size != n:
        raise error(f"{what} returned {arr.size} rows where {n} were expected")
    out = []
    for v in arr:
        if v is None:
            raise error(f"{what} left a row unset")
        out.append(v)
    return out


def symbolic_params(graph: Graph, params, values: list, tables: list | None = None):
    """``params`` with every number replaced by a symbol ``theta[j]`` and its value appended to ``values``.

    Floats and float arrays become symbols (an array becomes an object array
    of symbols of the same shape); booleans, integers, strings and None are
    structure and stay (the generated code is specialised on them); named
    tuples and tuples are converted element by element.  A table (see
    :func:`is_table`) is appended to ``tables`` and becomes a
    :class:`SymTable` of that slot (a 2-D table only); without ``tables`` it
    cannot be traced.  A :class:`Frozen` parameter is structure and stays.
    """
    if isinstance(params, (bool, np.bool_, str, type(None), Frozen)) or isinstance(params, numbers.Integral):
        return params
    if isinstance(params, numbers.Real):
        values.append(float(params))
        return graph.leaf("theta", len(values) - 1)
    if is_table(params):
        if tables is None or params.ndim != 2 or params.dtype.kind != "f":
            raise TraceError("a table parameter cannot be traced here")
        tables.append(params)
        return SymTable(graph, len(tables) - 1, params.shape[0])
    if isinstance(params, np.ndarray):
        if params.dtype.kind not in "fiu":
            raise TraceError(f"a parameter array of dtype {params.dtype} cannot be traced")
        flat = np.empty(params.size, dtype=object)
        for i, v in enumerate(np.asarray(params, dtype=float).ravel()):
            values.append(float(v))
            flat[i] = graph.leaf("theta", len(values) - 1)
        return flat.reshape(params.shape)
    if isinstance(params, tuple):
        items = [symbolic_params(graph, v, values, tables) for v in params]
        return type(params)(*items) if hasattr(params, "_fields") else tuple(items)
    raise TraceError(f"a parameter of type {type(params).__name__} cannot be traced")


def param_structure(params) -> str:
    """What the generated code is specialised on: types, shapes and structural values (not the numbers)."""
    if isinstance(params, Frozen):
        return params.frozen_digest()
    if isinstance(params, (bool, np.bool_, str, type(None))) or isinstance(params, numbers.Integral):
        return repr(params)
    if isinstance(params, numbers.Real):
        return "f"
    if is_table(params):                # its length is read at run time
        return f"table{params.dtype.kind}{params.shape[:-1]}"
    if isinstance(params, np.ndarray):
        return f"a{params.dtype.kind}{params.shape}"
    if isinstance(params, tuple):
        name = type(params).__name__ if hasattr(params, "_fields") else ""
        return name + "(" + ",".join(param_structure(v) for v in params) + ")"
    return type(params).__name__


def param_values(params, out: list) -> list:
    """The numbers of ``params`` in the order :func:`symbolic_params` reads them (for a new set of values);
    tables are not numbers."""
    if isinstance(params, (bool, np.bool_, str, type(None), Frozen)) or isinstance(params, numbers.Integral) \
            or is_table(params):
        return out
    if isinstance(params, numbers.Real):
        out.append(float(params))
    elif isinstance(params, np.ndarray):
        out.extend(np.asarray(params, dtype=float).ravel().tolist())
    elif isinstance(params, tuple):
        for v in params:
            param_values(v, out)
    return out


def param_tables(params, out: list) -> list:
    """The tables of ``params`` in the order :func:`symbolic_params` reads them."""
    if is_table(params):
        out.append(params)
    elif isinstance(params, tuple):
        for v in params:
            param_tables(v, out)
    return out
