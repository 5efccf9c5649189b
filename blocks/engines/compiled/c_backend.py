"""C from a traced kernel: the second back end of :mod:`blocks.kernels.trace` (the first writes numba Python).

A kernel block's ``update`` and ``output`` (``f(t, x, u, *params) -> rows``)
are run once on symbols (:func:`trace_block`); :func:`emit_c_function`
writes the recorded graph as one C99 function, every node once as a
``const double``, its operands before it, with the operations
the numba back end performs: the same operands in the same order, ``cos``,
``sin``, ``sqrt``, ``fabs`` ..., a comparison as a 0/1 double.  Compiled
without ``-ffast-math`` and with ``-ffp-contract=off`` it rounds as the
numpy kernel does.

The numbers of the block's parameters are not in the text: like the numba
back end, the code reads them from ``theta`` (:attr:`CProgram.theta` holds
their values, :attr:`CProgram.theta_names` what each one is), so a new gain
or mass needs no new code.  Booleans, integers and shapes are structure: the
code is specialised on them.

The API (used for the plant FMU and by the controller FMU):

``trace_block(kernels, n_x, n_u, which=("update", "output"), param_names=None) -> KernelTrace``
    the rows of a :class:`~blocks.diagram.contract.Kernels`' functions as graph nodes;
``emit_c_function(name, rows, leaves=None, args=C_ARGS, out="out", static=False) -> str``
    one C function writing ``rows`` to ``out[0..]``; ``leaves`` maps a leaf kind
    (``"t"``, ``"x"``, ``"u"``, ``"theta"``, or any other a caller's trace uses) to
    a C expression template with ``{i}`` for its index;
``block_c(kernels, n_x, n_u, names, param_names=None) -> CProgram``
    a C translation unit with one function per traced function, e.g.
    ``void plant_update(double t, const double *x, const double *u, const double *theta, double *out)``;
``system_c(block, prefix) -> CProgram``
    the same for a kernel block made by :mod:`blocks.diagram.systems` (sizes from the block);
``C_PRELUDE``
    the ``#include`` and the numpy-compatible helpers (``dk_sign``, ``dk_maximum`` ...) every unit needs.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from blocks.kernels.trace import Graph, Sym, TraceError, result_rows, symbolic_params

__all__ = ["CodegenError", "KernelTrace", "CProgram", "C_ARGS", "C_PRELUDE", "C_FLAGS", "trace_block",
           "emit_c_function", "block_c", "system_c", "theta_names"]

#: The arguments of a generated block function.
C_ARGS = "double t, const double *x, const double *u, const double *theta, double *out"

#: Flags the generated code needs to round as numpy does (no contraction into fused multiply-adds).
C_FLAGS = ("-std=c99", "-O2", "-ffp-contract=off", "-fno-fast-math")

#: Helpers with numpy's semantics (NaN propagation of maximum/minimum, sign of 0 and NaN).
C_PRELUDE = """#include <math.h>

/* numpy semantics: np.sign(0) = 0, np.sign(nan) = nan; np.maximum/np.minimum propagate NaN */
static inline double dk_sign(double a) { return a > 0.0 ? 1.0 : (a < 0.0 ? -1.0 : (a == 0.0 ? 0.0 : a)); }
static inline double dk_maximum(double a, double b) { return (a != a) ? a : ((b != b) ? b : (a >= b ? a : b)); }
static inline double dk_minimum(double a, double b) { return (a != a) ? a : ((b != b) ? b : (a <= b ? a : b)); }
"""

# trace call name -> C function (numpy's semantics; see C_PRELUDE for the dk_ helpers)
_C_CALLS = {"cos": "cos", "sin": "sin", "tan": "tan", "tanh": "tanh", "sqrt": "sqrt", "exp": "exp",
            "sign": "dk_sign", "floor": "floor", "absolute": "fabs", "maximum": "dk_maximum",
            "minimum": "dk_minimum", "arctan2": "atan2", "rint": "rint"}

_DEFAULT_LEAVES = {"t": "t", "x": "x[{i}]", "u": "u[{i}]", "theta": "theta[{i}]"}


class CodegenError(TraceError):
    """A traced graph holds something the C back end cannot write (a table lookup, an unknown leaf)."""


@dataclass
class KernelTrace:
    """The rows of a block's traced functions.

    Attributes
    ----------
    graph : Graph
        The hash-consed expression graph of every traced function.
    rows : dict of str to list
        ``"update"`` and/or ``"output"`` -> their rows (:class:`~blocks.kernels.trace.Sym` or numbers).
    theta : numpy.ndarray
        The parameter numbers the trace lifted, in the order the code reads them.
    theta_names : list of str
        What each entry of ``theta`` is (``"k[0]"``, ``"disturbance.f_r[2]"`` ...).
    """

    graph: Graph
    rows: dict
    theta: np.ndarray
    theta_names: list


@dataclass
class CProgram:
    """A C translation unit generated from one trace.

    Attributes
    ----------
    source : str
        C99 text: :data:`C_PRELUDE` and the functions.
    functions : dict of str to str
        Traced function (``"update"``, ``"output"``) -> its C name.
    sizes : dict of str to int
        C name -> number of rows it writes.
    theta, theta_names
        As :class:`KernelTrace`.
    n_nodes : int
        Nodes of the graph (each at most one statement per function that uses it).
    """

    source: str
    functions: dict
    sizes: dict
    theta: np.ndarray
    theta_names: list
    n_nodes: int = 0
    n_x: int = 0
    n_u: int = 0
    statements: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------------------
# Tracing a block
# --------------------------------------------------------------------------------------------------------------
def _leaves(graph: Graph, kind: str, n: int) -> np.ndarray:
    out = np.empty(n, dtype=object)
    for i in range(n):
        out[i] = graph.leaf(kind, i)
    return out


def theta_names(params, names=None) -> list[str]:
    """What each number :func:`~blocks.kernels.trace.symbolic_params` lifts from ``params`` is, in its order.

    Named tuples give their field names, arrays their indices; the top-level
    entries are named by ``names`` (default ``p0``, ``p1`` ...).

    Examples
    --------
    >>> theta_names((np.array([1.0, 2.0]), 3.0, True), names=("k", "g", "flag"))
    ['k[0]', 'k[1]', 'g']
    """
    out: list[str] = []

    def walk(value, path: str) -> None:
        if isinstance(value, (bool, np.bool_, str, type(None))) or isinstance(value, numbers.Integral):
            return
        if isinstance(value, numbers.Real):
            out.append(path)
        elif isinstance(value, np.ndarray):
            for idx in np.ndindex(value.shape):
                out.append(path + "[" + ",".join(str(i) for i in idx) + "]")
        elif isinstance(value, tuple):
            fields = getattr(value, "_fields", None)
            for j, v in enumerate(value):
                walk(v, f"{path}.{fields[j]}" if fields else f"{path}[{j}]")

    for j, value in enumerate(params):
        walk(value, names[j] if names is not None and j < len(names) else f"p{j}")
    return out


def trace_block(kernels, n_x: int, n_u: int, which=("update", "output"), param_names=None) -> KernelTrace:
    """Trace a block's kernels on symbols ``t``, ``x[i]``, ``u[i]`` and ``theta[j]``.

    Parameters
    ----------
    kernels : blocks.diagram.contract.Kernels
        The block's kernels and parameters.
    n_x, n_u : int
        Its number of states and inputs.
    which : sequence of {"update", "output"}
        The functions to trace (one graph: their common terms are one node).
    param_names : sequence of str, optional
        Names of the top-level parameters, for :attr:`KernelTrace.theta_names`.

    Raises
    ------
    CodegenError
        If a function is missing, a parameter is a table, or a kernel cannot be
        traced (the message says which and why).
    """
    for w in which:
        if w not in ("update", "output"):
            raise ValueError(f"which must name 'update' or 'output', got {w!r}")
        if getattr(kernels, w) is None:
            raise CodegenError(f"the block has no {w} kernel to generate C from")
    graph = Graph()
    theta: list[float] = []
    try:
        sym = symbolic_params(graph, kernels.params, theta, None)
    except TraceError as err:
        raise CodegenError(f"the block's parameters cannot be written as C numbers: {err}") from None
    t, x, u = graph.leaf("t", 0), _leaves(graph, "x", n_x), _leaves(graph, "u", n_u)
    rows = {}
    for w in which:
        try:
            value = getattr(kernels, w)(t, x, u, *sym)
        except TraceError as err:
            raise CodegenError(f"the block's {w} kernel cannot be traced into C: {err}") from None
        rows[w] = result_rows(value, n_x if w == "update" else None, f"the block's {w}", CodegenError)
    return KernelTrace(graph=graph, rows=rows, theta=np.array(theta, dtype=float),
                       theta_names=theta_names(kernels.params, param_names))


# --------------------------------------------------------------------------------------------------------------
# Emitting C
# --------------------------------------------------------------------------------------------------------------
def c_literal(value: float) -> str:
    """A double literal that reads back as exactly ``value`` (shortest repr; INFINITY and NAN by name)."""
    value = float(value)
    if math.isnan(value):
        return "NAN"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    text = repr(value)
    return f"({text})" if text.startswith("-") else text


def _operands(node: Sym) -> list:
    if node.op in ("bin", "call"):
        return [a for a in node.args[1:] if isinstance(a, Sym)]
    if node.op == "lookup":
        return [node.args[2]]
    return []


class _Writer:
    def __init__(self, leaves: dict) -> None:
        self.leaves = leaves
        self.names: dict[int, str] = {}
        self.lines: list[str] = []

    def value(self, v) -> str:
        if not isinstance(v, Sym):
            return c_literal(float(v))
        if v.op == "const":
            return c_literal(v.args[0])
        if v.op == "leaf":
            return self._leaf(v)
        found = self.names.get(v.id)
        if found is not None:
            return found
        stack = [v]             # operands first, iteratively (expressions can be deep)
        while stack:
            node = stack[-1]
            pending = [a for a in _operands(node) if a.op not in ("const", "leaf") and a.id not in self.names]
            if pending:
                stack.extend(pending)
                continue
            stack.pop()
            if node.id in self.names:
                continue
            name = f"v{node.id}"
            self.lines.append(f"    const double {name} = {self._expr(node)};")
            self.names[node.id] = name
        return self.names[v.id]

    def _leaf(self, node: Sym) -> str:
        kind, index = node.args
        template = self.leaves.get(kind)
        if template is None:
            raise CodegenError(f"the traced code reads {kind!r} {index!r}, which the C function has no argument "
                               f"for (known: {sorted(self.leaves)})")
        return template.format(i=index)

    def _expr(self, node: Sym) -> str:
        if node.op == "lookup":
            raise CodegenError("the traced code reads a table (noise samples); the C back end takes no tables")
        ops = [self.value(a) for a in node.args[1:]]
        if node.op == "bin":
            op = node.args[0]
            if op in ("<", ">", "<=", ">="):
                return f"(({ops[0]} {op} {ops[1]}) ? 1.0 : 0.0)"
            return f"{ops[0]} {op} {ops[1]}"
        name = node.args[0]
        if name == "negative":
            return f"-{ops[0]}"
        if name not in _C_CALLS:
            raise CodegenError(f"the traced code calls {name!r}, which the C back end does not write")
        return f"{_C_CALLS[name]}({', '.join(ops)})"


def emit_c_function(name: str, rows, leaves: dict | None = None, args: str = C_ARGS, out: str = "out",
                    static: bool = False) -> str:
    """One C function that writes ``rows`` (traced expressions or numbers) to ``out[0..len(rows)-1]``.

    Parameters
    ----------
    name : str
        The C function's name.
    rows : sequence of Sym or float
        The expressions, in output order.
    leaves : dict of str to str, optional
        Leaf kind -> C expression, ``{i}`` standing for the leaf's index;
        default ``t``, ``x[{i}]``, ``u[{i}]``, ``theta[{i}]``.
    args : str
        The C parameter list (default :data:`C_ARGS`).
    out : str
        The array the rows are written to.
    static : bool
        Give the function internal linkage.

    Raises
    ------
    CodegenError
        If a row reads a leaf ``leaves`` has no entry for, a table, or an unknown function.
    """
    writer = _Writer(dict(_DEFAULT_LEAVES if leaves is None else leaves))
    assigns = [f"    {out}[{r}] = {writer.value(v)};" for r, v in enumerate(rows)]
    body = writer.lines + assigns
    unused = [a.strip().split()[-1].lstrip("*") for a in args.split(",") if a.strip()]
    used = "\n".join(body)
    voids = [f"    (void){a};" for a in unused if not _mentions(used, a)]
    head = ("static " if static else "") + f"void {name}({args})"
    return head + "\n{\n" + "\n".join(voids + body) + "\n}\n"


def _mentions(text: str, ident: str) -> bool:
    import re
    return re.search(rf"(?<![A-Za-z0-9_]){re.escape(ident)}(?![A-Za-z0-9_])", text) is not None


def block_c(kernels, n_x: int, n_u: int, names: dict, param_names=None, static: bool = False) -> CProgram:
    """A C unit with one function per traced kernel function of a block, all sharing one ``theta``.

    Parameters
    ----------
    kernels : blocks.diagram.contract.Kernels
    n_x, n_u : int
        States and inputs of the block.
    names : dict of str to str
        ``{"update": C name, "output": C name}`` (either or both).
    param_names : sequence of str, optional
        See :func:`trace_block`.
    static : bool
        Internal linkage for the functions (to include the unit in another).

    Examples
    --------
    >>> from blocks.model.default import default_arm
    >>> from blocks.diagram.contract import contract_of
    >>> from blocks.diagram.systems import plant
    >>> block = plant(default_arm())
    >>> prog = block_c(contract_of(block).kernels, 8, 4, {"update": "f"}, ("k", "disturbance"))
    >>> prog.sizes["f"], prog.theta_names[:2]
    (8, ['k[0]', 'k[1]'])
    """
    trace = trace_block(kernels, n_x, n_u, tuple(names), param_names)
    parts, sizes, statements = [C_PRELUDE], {}, {}
    for which, cname in names.items():
        text = emit_c_function(cname, trace.rows[which], static=static)
        parts.append(text)
        sizes[cname] = len(trace.rows[which])
        statements[cname] = text.count(";")
    return CProgram(source="\n".join(parts), functions=dict(names), sizes=sizes, theta=trace.theta,
                    theta_names=trace.theta_names, n_nodes=len(trace.graph.nodes), n_x=n_x, n_u=n_u,
                    statements=statements)


def system_c(block, prefix: str | None = None, param_names=None, static: bool = False) -> CProgram:
    """:func:`block_c` for a kernel block (a :class:`~blocks.diagram.contract.Block` of :mod:`blocks.diagram.systems`).

    Its functions are ``<prefix>_update`` (when it has states) and ``<prefix>_output``;
    ``prefix`` defaults to the block's name.

    Raises
    ------
    CodegenError
        If the block carries no kernels.
    """
    from blocks.diagram.contract import contract_of
    kernels = contract_of(block).kernels
    if kernels is None:
        raise CodegenError(f"block {block.name!r} carries no kernels (a user's own system or an FMU): "
                           "there is nothing to generate C from")
    prefix = block.name if prefix is None else prefix
    names = {}
    if kernels.update is not None and block.nstates > 0:
        names["update"] = f"{prefix}_update"
    if kernels.output is not None:
        names["output"] = f"{prefix}_output"
    return block_c(kernels, block.nstates, block.ninputs, names, param_names, static)
