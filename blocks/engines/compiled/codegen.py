"""Generate one loop's module from its evaluation plan and its blocks' kernels.

:func:`loop_program` reads a :class:`~blocks.diagram.plan.LoopPlan` -- blocks in
evaluation order, input gathers, outputs read from states -- and writes the
source of these functions:

``loop_sources(t, theta, ext, work, src)``
    the outputs of the source blocks (no inputs, no states: the reference);
``loop_rhs(t, x, theta, src, ext, work, dx)``
    the loop's state derivative, the blocks in plan order;
``loop_outputs(t, x, theta, src, ext, work, y)``
    the interconnection's outputs;
``loop_rhs_rows(t, x, theta, src, ext, work, aux, flags, dx, rows)`` and ``loop_outputs_rows(..., y, rows)``
    the same, and beside them the rows of the asked-for row groups
    (:mod:`blocks.engines.compiled.rows`: the lumped disturbance, tracking-error
    rows), traced from the kernels in the same function so that they share
    its terms; ``flags[g] != 0`` asks for group ``g``, ``aux`` holds values
    shared by every run at that time (the reference's tool pose);
``member_ext(ext, tables, j)``
    the called kernels' parameters with every table (a noise table) taken
    from row ``j`` of ``tables``, for a batch whose members have their own.

With :data:`ARM_CALLS` set (the default), an arm's ``M(q)`` and ``h(q, q')`` (a chain
arm's: :mod:`blocks.kernels.chain`) are functions of the module,
``arm_inertia_<arm>(x)`` and ``arm_bias_<arm>(x)`` returning tuples, called
by the functions below where they need them
(:class:`~blocks.kernels.trace.Callee`): numba compiles each once instead
of four inlined copies (about half the compile time, runs 10-20 % slower).

A block's kernels are traced (:mod:`blocks.kernels.trace`) into scalar
statements when they can be: then the generated code has no array
temporaries, and a term two blocks compute alike is computed once.  A
kernel that cannot be traced (a table lookup, a branch on the time) is
called as its compiled copy (:func:`blocks.engines.compiled.jit.jit_kernel`); a
kernel that returns its rows as a tuple of numbers (the laceration path's)
is called without allocating.  The numbers of traced blocks are read from
one vector ``theta``, so a new gain or mass needs no new code; the
parameters of called kernels travel in the tuple ``ext``.

The text is plain Python.  numba compiles it together with the integrators
of :mod:`blocks.engines.compiled.dopri` (:func:`load_module`), and
:mod:`blocks.engines.compiled.scalar` runs it as it is, on Python floats, for the
``fast`` engine.  Programs are kept per loop structure for the process
(:func:`program_for`).

Each compiled module is written once to the cache folder under a name that
hashes its text and the source of every kernel it calls; numba caches its
machine code beside it, so a second process neither traces into new code
nor recompiles.  The folder is ``$DOBKIT_CACHE_DIR`` or ``~/.cache/dobkit``
(``$XDG_CACHE_HOME/dobkit``); :mod:`blocks.engines.compiled.cache` checks its files
before numba reads them, and when it cannot be written the compiled code
stays in memory for the process (one note says so).
"""
from __future__ import annotations

import contextlib
import hashlib
import platform
import sys
import types
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from blocks.diagram.contract import contract_of
from blocks.diagram.control_compat import subsystems
from blocks.engines.compiled.cache import ModuleCache, cache_dir, guard_dispatcher
from blocks.engines.compiled.jit import jit_kernel, kernel_sources, numba_or_none
from blocks.kernels.trace import (
    Callee,
    Graph,
    Sym,
    TraceError,
    is_table,
    param_structure,
    param_tables,
    param_values,
    result_rows,
    symbolic_params,
)

__all__ = ["CompiledUnavailable", "LoopProgram", "loop_program", "program_for", "cache_dir", "load_module"]


#: Generate a chain arm's ``M(q)`` and ``h(q, q')`` as functions of the module, called where needed, instead of
#: inlining them in every function (see :class:`~blocks.kernels.trace.Callee`).  Measured on the 2-core machine
#: (CPU s of a cold compile; best cached run): the Panda's loop 14,250 -> 7,670 lines, compile 23.1 -> 12.6 s,
#: run 6.5 -> 7.6 ms (+15-20 %, in the Dormand-Prince steps and the grid pass); the UR5's 8,064 -> 5,114 lines,
#: 13.6 -> 9.0 s; scope4 3,023 -> 1,981 lines, 7.1 -> 5.3 s, run +10-15 %; the numbers are the same to the last bit.
#: On: a first run of a big arm is dominated by its compile (every example arm compiles within
#: :data:`~blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS`).  The paper's RRPR has no chain kernels: its
#: code is the same either way.  Set it False before a loop is first traced to inline them again.
ARM_CALLS = True


class CompiledUnavailable(RuntimeError):
    """The compiled engine cannot run this loop; the message says which block or setting stops it."""


# --------------------------------------------------------------------------------------------------------------
# The program of one loop: which blocks are traced, where their numbers are, the generated text
# --------------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class LoopProgram:
    """A loop's generated functions and how to call them.

    Attributes
    ----------
    source : str
        The generated functions (without the integrators' text).
    theta : numpy.ndarray
        The numbers of the traced blocks' parameters, in the order the code
        reads them, for the loop the program was traced from (see :meth:`numbers`).
    theta_slices : dict of str to slice
        Each traced block's part of ``theta``.
    ext : tuple
        Parameters the generated code reads as they are: the called kernels'
        parameters and the traced blocks' tables, in order.
    ext_slices : dict of str to tuple
        Each block's ``(first, stop)`` in ``ext``.
    traced, called : list of str
        Blocks traced into statements, and blocks whose kernels are called.
    sources : list of str
        Source blocks (evaluated by ``loop_sources``).
    n_src, n_work, n_out : int
        Sizes of the source vector, the work buffer and the output vector.
    kernels : dict of str to function
        The kernels the generated code calls (by their name there).
    structure : str
        What the text depends on (blocks, kernels, parameter layouts, plan, row groups).
    row_groups : dict of str to (int, slice)
        For each row group the loop has: its flag index and its rows.
    n_rows, n_aux : int
        Rows of all groups, and shared values (``aux``) they read.
    tables : tuple of int
        Positions in ``ext`` of table parameters (see ``member_ext``).
    order : list of str
        Every block, in the order its numbers were read (see :meth:`numbers`).
    callees : dict of str to Callee
        The functions of the module the loop's functions call (an arm's M and h), by name.
    """

    source: str
    theta: np.ndarray
    theta_slices: dict
    ext: tuple
    ext_slices: dict
    traced: list
    called: list
    sources: list
    n_src: int
    n_work: int
    n_out: int
    kernels: dict
    structure: str
    row_groups: dict = field(default_factory=dict)
    n_rows: int = 0
    n_aux: int = 0
    tables: tuple = ()
    order: list = field(default_factory=list)
    callees: dict = field(default_factory=dict)

    @cached_property
    def key(self) -> str:
        """Hash of the module's text, the kernels it calls and the compiler's versions: its name in the cache."""
        numba = numba_or_none()
        key_text = "\n".join([self.source, _template_text(), kernel_sources(self.kernels.values()), self.structure,
                              f"numba {getattr(numba, '__version__', None)}", f"numpy {np.__version__}",
                              f"python {platform.python_version()} {sys.platform}"])
        return hashlib.sha256(key_text.encode()).hexdigest()[:20]

    def numbers(self, kernels_by_block: dict) -> tuple[np.ndarray, tuple]:
        """``(theta, ext)`` of a loop with this program's structure and its own numbers.

        Parameters
        ----------
        kernels_by_block : dict of str to Kernels
            The loop's kernels by block name.
        """
        values: list[float] = []
        ext: list = []
        for name in self.order:
            params = kernels_by_block[name].params
            if name in self.theta_slices:
                param_values(params, values)
                param_tables(params, ext)
            else:
                ext.extend(params)
        return np.array(values, dtype=float), tuple(ext)


def block_kernels(plan, system) -> dict:
    """The kernels of every block of ``plan`` by name.

    Raises
    ------
    CompiledUnavailable
        If a block has none (its name is in the message).
    """
    blocks = {b.name: b for b in subsystems(system)}
    out = {}
    for step in plan.steps:
        kernels = contract_of(blocks[step.name]).kernels
        if not step.kernel or kernels is None:
            raise CompiledUnavailable(
                f"block '{step.name}' has no kernels (its contract carries none, as for a user's own "
                f"python-control system or an FMU), so the compiled engine cannot run this loop")
        out[step.name] = kernels
    return out


class _Builder:
    """Traces the blocks of a plan and emits the statements of one generated function at a time."""

    def __init__(self, plan, kernels: dict, calls=None) -> None:
        self.plan, self.kernels = plan, kernels
        # an arm's M and h as functions called where needed (chain arms; ``calls`` overrides ARM_CALLS: the fast
        # engine asks for each chain row kernel as a call, KERNEL_CALLS, to bind pinocchio's algorithms to them)
        self.graph = Graph(calls=ARM_CALLS if calls is None else calls)
        self.theta: list[float] = []
        self.theta_slices: dict[str, slice] = {}
        self.sym_params: dict[str, tuple] = {}
        self.ext: list = []
        self.ext_slices: dict[str, tuple] = {}
        self.kernel_names: dict[str, object] = {}
        self.traced, self.called = [], []
        self.source_steps = [s for s in plan.steps if _is_source(s)]
        self.src_offset, n = {}, 0
        for s in self.source_steps:
            self.src_offset[s.name] = n
            n += s.y.stop - s.y.start
        self.n_src = n
        self.work = 0
        for step in plan.steps:
            self._classify(step)

    # -- which blocks are traced -----------------------------------------------------------------------
    def _classify(self, step) -> None:
        k = self.kernels[step.name]
        start, e0 = len(self.theta), len(self.ext)
        try:
            sym = symbolic_params(self.graph, k.params, self.theta, self.ext)      # tables go to ext
            # a trial trace of every function the block has, on fresh symbols
            x = self._leaves("x", range(step.x.start, step.x.stop))
            u = self._leaves("trial", range(_gather_size(step)))
            t = self.graph.leaf("t", 0)
            if k.output is not None:
                result_rows(k.output(t, x, u, *sym), step.y.stop - step.y.start)
            if k.update is not None and step.x.stop > step.x.start:
                result_rows(k.update(t, x, u, *sym), step.x.stop - step.x.start)
        except (TraceError, TypeError, AttributeError, IndexError, ValueError):
            del self.theta[start:]
            del self.ext[e0:]
            self.ext.extend(k.params)
            self.ext_slices[step.name] = (e0, len(self.ext))
            self.called.append(step.name)
            return
        self.sym_params[step.name] = sym
        self.theta_slices[step.name] = slice(start, len(self.theta))
        self.ext_slices[step.name] = (e0, len(self.ext))
        self.traced.append(step.name)

    def _leaves(self, kind: str, indices) -> np.ndarray:
        out = np.empty(len(indices), dtype=object)
        for n, i in enumerate(indices):
            out[n] = self.graph.leaf(kind, i)
        return out

    # -- one block in a function -----------------------------------------------------------------------
    def block_rows(self, fn_out: _Function, step, which: str, signals: dict) -> list:
        """Expressions of the block's outputs (``which="output"``) or derivative (``"update"``)."""
        k = self.kernels[step.name]
        fn = k.output if which == "output" else k.update
        # an input not evaluated yet does not feed through (the plan's order guarantees it): a placeholder
        # that fails if an expression uses it, and 0 where a called kernel receives it
        u_syms = [signals.get(j, self.graph.leaf("unset", j)) for j in _gather_list(step)]
        n_rows = (step.y.stop - step.y.start) if which == "output" else (step.x.stop - step.x.start)
        if step.name in self.sym_params:
            x = self._leaves("x", range(step.x.start, step.x.stop))
            u = np.empty(len(u_syms), dtype=object)
            for i, s in enumerate(u_syms):
                u[i] = s
            return result_rows(fn(self.graph.leaf("t", 0), x, u, *self.sym_params[step.name]), n_rows)
        # a called kernel: inputs into the work buffer, the kernel, its rows read back
        name = f"K_{step.name}_{which}"
        self.kernel_names[name] = fn
        w0 = self.work
        self.work += len(u_syms)
        call = fn_out.call(name, step, w0, u_syms, self.ext_slices[step.name])
        return [self.graph.leaf("call", (call, i)) for i in range(n_rows)]


def _is_source(step) -> bool:
    return _gather_size(step) == 0 and step.x.stop == step.x.start


def _gather_list(step) -> list:
    g = step.gather
    if isinstance(g, slice):
        return list(range(g.start, g.stop))
    return [int(i) for i in np.asarray(g).ravel()]


def _gather_size(step) -> int:
    return len(_gather_list(step))


# --------------------------------------------------------------------------------------------------------------
# Emitting one function
# --------------------------------------------------------------------------------------------------------------
_CALL_NAMES = {"cos": "np.cos", "sin": "np.sin", "tan": "np.tan", "tanh": "np.tanh", "sqrt": "np.sqrt",
               "exp": "np.exp", "sign": "np.sign", "floor": "np.floor", "absolute": "np.abs",
               "maximum": "np.maximum", "minimum": "np.minimum", "arctan2": "np.arctan2"}
_CALL_NAMES["rint"] = "np.rint"          # the encoder's rounding (round half to even, as np.round)


def _literal(value: float) -> str:
    if np.isnan(value):
        return "np.nan"
    if np.isinf(value):
        return "np.inf" if value > 0 else "(-np.inf)"
    text = repr(float(value))
    return f"({text})" if value < 0 else text


class _Function:
    """The statements of one generated function, each expression emitted once, before its first use."""

    def __init__(self, builder: _Builder, name: str, args: str) -> None:
        self.builder, self.name, self.args = builder, name, args
        self.lines: list[str] = []
        self.names: dict[int, str] = {}
        self.calls = 0
        self.indent = ""

    def emit(self, line: str) -> None:
        self.lines.append(self.indent + line)

    @contextlib.contextmanager
    def guarded(self, condition: str):
        """Statements emitted inside run only when ``condition`` holds; what they name is forgotten after."""
        names, start = dict(self.names), len(self.lines)
        self.emit(f"if {condition}:")
        self.indent += "    "
        yield
        if len(self.lines) == start + 1:
            self.emit("pass")
        self.indent = self.indent[:-4]
        self.names = names

    def value(self, v) -> str:
        if not isinstance(v, Sym):
            return _literal(float(v))
        if v.op == "const":
            return _literal(v.args[0])
        found = self.names.get(v.id)
        if found is not None:
            return found
        # operands first, iteratively (expressions can be deep)
        stack = [v]
        while stack:
            node = stack[-1]
            pending = [a for a in _operands(node) if a.op != "const" and a.id not in self.names]
            if pending:
                stack.extend(pending)
                continue
            stack.pop()
            if node.id in self.names:
                continue
            self.names[node.id] = name = f"v{node.id}"
            self.emit(f"{name} = {self._expr(node)}")
        return self.names[v.id]

    def _expr(self, node: Sym) -> str:
        if node.op == "leaf":
            kind, index = node.args
            if kind == "t":
                return "t"
            if kind in ("x", "theta", "src", "aux"):
                return f"{kind}[{index}]"
            if kind == "call":
                call, row = index
                return f"r{call}[{row}]"
            if kind == "tablen":
                return f"ext[{index}].shape[1]"
            raise CompiledUnavailable(f"the generated code would read {kind!r} {index!r}: a block uses an input "
                                      "its contract says does not feed through")
        if node.op == "fcall":                  # a function of the module (an arm's M or h): a tuple of outputs
            return f"{node.args[0]}(({', '.join(self.value(a) for a in node.args[1:])},))"
        if node.op == "fout":
            call, j = node.args
            return f"{self.value(call)}[{j}]"
        if node.op == "lookup":                 # a table read at a whole-valued float index
            slot, row, at = node.args
            return f"ext[{slot}][{row}, int({self.value(at)})]"
        ops = [self.value(a) for a in node.args[1:]]
        if node.op == "bin":
            return f"{ops[0]} {node.args[0]} {ops[1]}"
        name = node.args[0]
        if name == "negative":
            return f"-{ops[0]}"
        return f"{_CALL_NAMES[name]}({', '.join(ops)})"

    def call(self, kernel: str, step, w0: int, inputs: list, ext_slice: tuple) -> int:
        """Emit a call of a kernel on its gathered inputs; return the call's number."""
        for i, s in enumerate(inputs):
            unset = isinstance(s, Sym) and s.op == "leaf" and s.args[0] == "unset"
            self.emit(f"work[{w0 + i}] = {'0.0' if unset else self.value(s)}")
        self.calls += 1
        c = self.calls
        stateful = step.x.stop > step.x.start and "x" in self.args.split(", ")
        # no states or no inputs: the module's one empty array (a slice made at each call costs two atomic
        # reference counts, about a tenth of a laceration path's call)
        x = f"x[{step.x.start}:{step.x.stop}]" if stateful else "NO_ARRAY"
        u = f"work[{w0}:{w0 + len(inputs)}]" if inputs else "NO_ARRAY"
        params = "".join(f", ext[{e}]" for e in range(*ext_slice))
        self.emit(f"r{c} = {kernel}(t, {x}, {u}{params})")
        return c

    def assign(self, target: str, v) -> None:
        self.emit(f"{target} = {self.value(v)}")

    def text(self) -> str:
        body = self.lines or ["pass"]
        return f"def {self.name}({self.args}):\n" + "".join(f"    {line}\n" for line in body) + "\n"


def _operands(node: Sym) -> list:
    if node.op in ("bin", "call", "fcall"):
        return [a for a in node.args[1:] if isinstance(a, Sym)]
    if node.op == "fout":
        return [node.args[0]]
    if node.op == "lookup":
        return [node.args[2]]
    return []


# --------------------------------------------------------------------------------------------------------------
# The program of a plan
# --------------------------------------------------------------------------------------------------------------
def _by_signal(labels: list, plan, signals: dict) -> dict:
    """The interconnection's outputs as rows by signal name: ``{"q": [q[0], q[1], ...], ...}`` (object arrays)."""
    rows: dict[str, dict] = {}
    for r, j in enumerate(plan.out_index):
        name, _, index = labels[r].partition("[")
        rows.setdefault(name, {})[int(index.rstrip("]")) if index else 0] = signals[int(j)]
    out = {}
    for name, by_index in rows.items():
        arr = np.empty(len(by_index), dtype=object)
        for i, v in enumerate(by_index[k] for k in sorted(by_index)):
            arr[i] = v
        out[name] = arr
    return out


def _emit_row_groups(fn: _Function, b: _Builder, groups: tuple, by_signal: dict, aux) -> list:
    """Each group's rows into ``rows``, guarded by its flag; the groups' row counts."""
    offset, sizes = 0, []
    for gi, group in enumerate(groups):
        rows = result_rows(group.rows(by_signal, aux, b.sym_params), None)
        with fn.guarded(f"flags[{gi}] != 0"):
            for r, v in enumerate(rows):
                fn.assign(f"rows[{offset + r}]", v)
        offset += len(rows)
        sizes.append(len(rows))
    return sizes


_GATHER_TEXTS: dict = {}
# The repr of a gather index array by its dtype, shape and bytes: numpy's repr costs most of a new scenario's cache
# lookup (0.7 of 0.9 ms for the Panda) and the same gathers come back run after run; bounded by _GATHER_TEXTS_KEPT
_GATHER_TEXTS_KEPT = 1024


def _gather_text(gather) -> str:
    """``repr(gather)``, the same text (it is part of the on-disk cache keys), remembered for index arrays."""
    if not isinstance(gather, np.ndarray):
        return repr(gather)
    key = (gather.dtype.str, gather.shape, gather.tobytes())
    text = _GATHER_TEXTS.get(key)
    if text is None:
        if len(_GATHER_TEXTS) >= _GATHER_TEXTS_KEPT:
            _GATHER_TEXTS.clear()
        text = _GATHER_TEXTS[key] = repr(gather)
    return text


def structure_of(plan, kernels: dict, labels: list, groups: tuple = (), calls=None) -> str:
    """What a loop's generated text depends on: its blocks, their kernels and parameter layouts, the plan,
    the output names, the row groups asked for and what the trace calls instead of inlining (``calls``: see
    :class:`_Builder`)."""
    parts = []
    for s in plan.steps:
        k = kernels[s.name]
        parts.append(f"{s.name}|{k.output.__module__}.{k.output.__qualname__}|"
                     f"{getattr(k.update, '__qualname__', None)}|{param_structure(k.params)}|{s.x}|{s.y}|"
                     f"{_gather_text(s.gather)}")
    parts.append(f"{plan.copy_y!r}|{plan.copy_x!r}|{plan.out_index.tolist()}|{plan.direct}")
    parts.append(",".join(labels))
    parts.append(",".join(f"{g.name}:{g.rows.__module__}.{g.rows.__qualname__}" for g in groups))
    if not ARM_CALLS and calls is None:     # another text for the same loop (absent by default: the RRPR's keys stay)
        parts.append("arm M and h inlined")
    if calls is not None:
        parts.append(f"calls {calls!r}")
    return "\n".join(parts)


def _sources_function(b: _Builder) -> _Function:
    """``loop_sources``: the source blocks' outputs into ``src``."""
    fn = _Function(b, "loop_sources", "t, theta, ext, work, src")
    for step in b.source_steps:
        for r, v in enumerate(b.block_rows(fn, step, "output", {})):
            fn.assign(f"src[{b.src_offset[step.name] + r}]", v)
    return fn


def _with_sources(b: _Builder, signals: dict) -> dict:
    """``signals`` with the source blocks' outputs read from ``src``."""
    for step in b.source_steps:
        for r in range(step.y.stop - step.y.start):
            signals[step.y.start + r] = b.graph.leaf("src", b.src_offset[step.name] + r)
    return signals


def _output_pass(b: _Builder, fn: _Function, signals: dict, skip=()) -> dict:
    """Every block's outputs in plan order into ``fn``, but the sources' and those of the blocks in ``skip``
    (evaluated already, or held): the signals."""
    for step in b.plan.steps:
        if _is_source(step) or step.name in skip:
            continue
        for r, v in enumerate(b.block_rows(fn, step, "output", signals)):
            signals[step.y.start + r] = v
    return signals


def _assign_outputs(fn: _Function, plan, signals: dict) -> None:
    """The interconnection's outputs ``y[r]`` from the signals."""
    for r, j in enumerate(plan.out_index):
        fn.assign(f"y[{r}]", signals[int(j)])


def _callee_functions(b: _Builder) -> str:
    """The text of the functions the generated code calls (:class:`~blocks.kernels.trace.Callee`: an arm's M, h),
    each ``name(x) -> tuple`` of its outputs that are not constants."""
    texts = []
    for callee in b.graph.callees.values():
        _, outputs = callee.traced
        fn = _Function(None, callee.name, "x")
        values = [fn.value(v) for v in outputs if Callee.constant(v) is None]
        # every output a constant (a one-joint arm's gravity about a vertical axis): an empty tuple, never read
        fn.emit(f"return ({', '.join(values)},)" if values else "return ()")
        texts.append(fn.text())
    return "".join(t + "\n" for t in texts)


def _member_ext(b: _Builder) -> tuple[tuple, str]:
    """Which ``ext`` entries are tables, and the text of ``member_ext``, which puts member ``j``'s tables in
    their place (for a batch whose members have their own)."""
    tables = tuple(e for e, p in enumerate(b.ext) if is_table(p))
    if not tables:
        return tables, "def member_ext(ext, tables, j):\n    return ext\n\n\n"
    parts = [f"tables[{tables.index(e)}][j]" if e in tables else f"ext[{e}]" for e in range(len(b.ext))]
    return tables, f"def member_ext(ext, tables, j):\n    return ({', '.join(parts)},)\n\n\n"


def loop_program(plan, system, groups: tuple = (), calls=None) -> LoopProgram:
    """Trace the blocks of ``plan`` (of the interconnection ``system``) and generate the loop's functions.

    Parameters
    ----------
    plan : LoopPlan
    system : control.InterconnectedSystem
    groups : tuple of RowGroup
        Row groups (:mod:`blocks.engines.compiled.rows`) to generate where the loop
        has what they need.
    calls : optional
        What the trace records as calls of functions of the module instead of inlining: default
        :data:`ARM_CALLS` (a chain arm's M and h); ``blocks.kernels.chain.KERNEL_CALLS``: every chain row kernel.

    Raises
    ------
    CompiledUnavailable
        If the plan is not direct (connections other than one signal with
        gain 1, external inputs) or a block has no kernels.
    """
    if not plan.direct:
        raise CompiledUnavailable("the interconnection is not direct (an input is a sum or a scaled signal, or the "
                                  "loop has external inputs), so the compiled engine cannot run it")
    kernels = block_kernels(plan, system)
    labels = list(system.output_labels)
    b = _Builder(plan, kernels, calls)
    g = b.graph
    groups = tuple(gr for gr in groups if gr.available(labels, b.traced))
    n_aux = max((gr.aux for gr in groups), default=0)
    aux = b._leaves("aux", range(n_aux))

    fn_src = _sources_function(b)

    def signals_with_sources() -> dict:
        return _with_sources(b, {})

    def rhs(fn: _Function) -> dict:
        """The right-hand side into ``fn``: outputs it needs, then every update; the signals it evaluated."""
        signals = signals_with_sources()
        for j, i in zip(_indices(plan.copy_y), _indices(plan.copy_x)):
            signals[j] = g.leaf("x", i)
        for step in plan.rhs_steps:
            if _is_source(step):
                continue
            for r, v in enumerate(b.block_rows(fn, step, "output", signals)):
                signals[step.y.start + r] = v
        for step in plan.updates:
            for r, v in enumerate(b.block_rows(fn, step, "update", signals)):
                fn.assign(f"dx[{step.x.start + r}]", v)
        return signals

    def outputs(fn: _Function, signals: dict, skip=()) -> dict:
        return _output_pass(b, fn, signals, skip)

    fn_rhs = _Function(b, "loop_rhs", "t, x, theta, src, ext, work, dx")
    rhs(fn_rhs)

    fn_out = _Function(b, "loop_outputs", "t, x, theta, src, ext, work, y")
    _assign_outputs(fn_out, plan, outputs(fn_out, signals_with_sources()))

    # the same with the row groups beside them, which share their terms
    fn_rhs_rows = _Function(b, "loop_rhs_rows", "t, x, theta, src, ext, work, aux, flags, dx, rows")
    signals = rhs(fn_rhs_rows)
    sizes = []
    if groups:
        # the other blocks' outputs as expressions (traced blocks add no statements until a row uses them)
        signals = outputs(fn_rhs_rows, signals, skip={s.name for s in plan.rhs_steps})
        sizes = _emit_row_groups(fn_rhs_rows, b, groups, _by_signal(labels, plan, signals), aux)

    fn_out_rows = _Function(b, "loop_outputs_rows", "t, x, theta, src, ext, work, aux, flags, y, rows")
    signals = outputs(fn_out_rows, signals_with_sources())
    _assign_outputs(fn_out_rows, plan, signals)
    if groups and _emit_row_groups(fn_out_rows, b, groups, _by_signal(labels, plan, signals), aux) != sizes:
        raise TraceError("a row group gave different row counts beside the right-hand side and the outputs")

    tables, member_ext = _member_ext(b)

    n_out = len(plan.out_index)
    row_groups, offset = {}, 0
    for gi, (group, size) in enumerate(zip(groups, sizes)):
        row_groups[group.name] = (gi, slice(offset, offset + size))
        offset += size
    sizes = (f"def loop_source_count():\n    return {b.n_src}\n\n\n"
             f"def loop_work_size():\n    return {max(b.work, 1)}\n\n\n"
             f"def loop_output_count():\n    return {n_out}\n\n\n"
             f"def loop_row_count():\n    return {max(offset, 1)}\n\n\n")
    source = _callee_functions(b) + "\n".join(f.text() for f in (fn_src, fn_rhs, fn_out, fn_rhs_rows, fn_out_rows)) \
        + "\n" + member_ext + sizes
    return LoopProgram(source=source, theta=np.array(b.theta, dtype=float), theta_slices=b.theta_slices,
                       ext=tuple(b.ext), ext_slices=b.ext_slices, traced=b.traced, called=b.called,
                       sources=[s.name for s in b.source_steps], n_src=b.n_src, n_work=max(b.work, 1), n_out=n_out,
                       kernels=dict(b.kernel_names), structure=structure_of(plan, kernels, labels, groups, calls),
                       row_groups=row_groups, n_rows=offset, n_aux=n_aux, tables=tables,
                       order=[s.name for s in plan.steps], callees=dict(g.callees))


_programs: dict[str, LoopProgram] = {}


def program_for(plan, system, groups: tuple = (), calls=None) -> tuple[LoopProgram, dict]:
    """The program of a loop's structure (traced once per process) and the loop's kernels by block.

    Raises
    ------
    CompiledUnavailable
        As :func:`loop_program`.
    """
    if not plan.direct:
        loop_program(plan, system, groups, calls)   # raises with the reason
    kernels = block_kernels(plan, system)
    structure = structure_of(plan, kernels, list(system.output_labels), groups, calls)
    program = _programs.get(structure)
    if program is None:
        program = loop_program(plan, system, groups, calls)
        _programs[structure] = program
    return program, kernels


def _indices(idx) -> list:
    if isinstance(idx, slice):
        return list(range(idx.start or 0, idx.stop))
    return [int(i) for i in np.asarray(idx).ravel()]


# --------------------------------------------------------------------------------------------------------------
# The module on disk
# --------------------------------------------------------------------------------------------------------------
def _template_text() -> str:
    return (Path(__file__).parent / "dopri.py").read_text(encoding="utf-8")


#: A program of more generated lines than this keeps ``INLINE_WHEN_SMALL`` (its sources and outputs) as calls: inlined
#: into the drivers they pay in the paper's short run (1,132 lines; dopri.INLINE) and cost compile time in proportion
#: to their size: the Panda's first run 15.6 s of CPU with them inlined, 12.9 s without (7,670 lines), its cached
#: run 5.8 and 5.6 ms (benchmarks/bench_urdf_compile.py, load 1.0).
SMALL_PROGRAM_LINES = 2_000

_modules: dict[str, tuple[types.ModuleType, bool]] = {}
_stores: dict[str, ModuleCache] = {}


def module_path(program: LoopProgram) -> Path:
    """Where the program's module text is kept in the cache folder."""
    return cache_dir() / f"dobkit_loop_{program.key}.py"


def _module_text(program: LoopProgram) -> str:
    return ("# Generated by blocks.engines.compiled.codegen for one loop structure; the cache may delete it.\n"
            + _template_text() + "\n\n# ---- the loop's functions, generated from its plan ----\n\n" + program.source)


def load_module(program: LoopProgram) -> tuple[types.ModuleType, bool]:
    """The program's compiled module (made once per process); whether its machine code is cached complete.

    The functions are numba dispatchers whose cache is checked against the
    module's manifest (:mod:`blocks.engines.compiled.cache`): they load machine code
    that checks out, else compile on first call and save it.  Corrupt or
    unwritable cache files are reported once (:class:`~blocks.engines.compiled.cache.CompiledCacheWarning`)
    and never stop a run.
    """
    found = _modules.get(program.key)
    if found is not None:
        return found
    numba = numba_or_none()
    name = f"dobkit_loop_{program.key}"
    text = _module_text(program)
    store = ModuleCache(name, text, cache_dir())     # checks the cached files; notes what it cannot use
    # the module from its text (not through Python's import, whose bytecode cache would be another file to trust)
    module = types.ModuleType(name)
    module.__file__ = str(module_path(program))
    sys.modules[name] = module          # numba's cache finds a function's module by name when it loads it
    exec(compile(text, module.__file__, "exec"), module.__dict__)
    # the reference (a source: called at every right-hand side and grid point) with its helpers inlined
    sources = {f"K_{name}_output" for name in program.sources}
    for kname, fn in program.kernels.items():
        setattr(module, kname, jit_kernel(fn, inline_callees=kname in sources))
    parallel = set(getattr(module, "PARALLEL", ()))
    nogil = set(getattr(module, "NOGIL", ()))
    inline = set(getattr(module, "INLINE", ()))
    if program.source.count("\n") > SMALL_PROGRAM_LINES:   # a big loop: its sources and outputs stay calls
        inline -= set(getattr(module, "INLINE_WHEN_SMALL", ()))
    for attr, value in list(vars(module).items()):
        if isinstance(value, types.FunctionType) and value.__module__ == name:
            options = dict(error_model="numpy")
            if attr in parallel:
                options["parallel"] = True
            if attr in nogil:
                options["nogil"] = True
            if attr in inline:
                options["inline"] = "always"
            dispatcher = numba.njit(**options)(value)
            guard_dispatcher(dispatcher, store)
            setattr(module, attr, dispatcher)
    module.CACHE_NOTE = f"cached in {store.folder}" if store.writable else "not cached: kept in memory"
    _stores[program.key] = store
    _modules[program.key] = (module, store.complete)
    return module, store.complete


def mark_compiled(program: LoopProgram) -> None:
    """Record that the program's machine code is cached complete (no compile message next time)."""
    store = _stores.get(program.key)
    if store is not None:
        store.mark_compiled()
    found = _modules.get(program.key)
    if found is not None:
        _modules[program.key] = (found[0], True)


# --------------------------------------------------------------------------------------------------------------
# The program of a sampled-data loop (a blocks.engines.hybrid.HybridSystem): the tick, the plant between ticks, outputs
# --------------------------------------------------------------------------------------------------------------
def sampled_program(hybrid) -> LoopProgram:
    """Trace the blocks of a hybrid diagram (continuous and sampled blocks) and generate its functions.

    The functions mirror :class:`blocks.engines.hybrid.HybridSystem`'s steps, with
    ``aux`` holding the block outputs held since the last tick (all
    ``nsignals`` of them; only the sampled blocks' entries are read):

    ``loop_sources(t, theta, ext, work, src)``
        the source blocks' outputs (as for a continuous loop);
    ``sampled_tick(t, x, theta, src, ext, work, aux, held, xn)``
        :meth:`~blocks.engines.hybrid.HybridSystem.tick_outputs` and
        :meth:`~blocks.engines.hybrid.HybridSystem.tick_updates`: every block's
        output in plan order (a sampled block's input not evaluated yet reads
        its held value), the sampled blocks' outputs into ``held`` and their
        next states into ``xn`` (the caller fills both with ``aux`` and ``x``
        first);
    ``sampled_rhs(t, x, theta, src, ext, work, aux, dx)``
        :meth:`~blocks.engines.hybrid.HybridSystem.continuous_rhs`: the continuous
        states' derivative with the sampled outputs held, zero for the
        sampled blocks' states (it evaluates the sources itself when a
        continuous update needs them);
    ``sampled_outputs(t, x, theta, src, ext, work, aux, y)``
        :meth:`~blocks.engines.hybrid.HybridSystem.outputs_between_ticks` at one
        time: the continuous blocks evaluated, the sampled ones held (the
        caller evaluates the sources at ``t`` first);

    and ``member_ext`` and the size functions of :func:`loop_program`.

    Raises
    ------
    CompiledUnavailable
        If a block has no kernels, the plan is not a single pass, or a
        sampled block runs at a multiple of the base period (one rate only).
    """
    plan, system = hybrid.plan, hybrid.system
    if plan.fixed_point:
        raise CompiledUnavailable("the diagram's blocks declare no order (a fixed-point plan), so the compiled "
                                  "sampled engine cannot run it")
    slow = {name: m for name, m in hybrid.multiples.items() if m != 1}
    if slow:
        raise CompiledUnavailable(f"blocks {sorted(slow)} are sampled at multiples {sorted(set(slow.values()))} of "
                                  "the base period; the compiled sampled engine runs one sample rate")
    kernels = block_kernels(plan, system)
    discrete = set(hybrid.multiples)
    b = _Builder(plan, kernels)
    g = b.graph
    held = lambda: {j: g.leaf("aux", j) for j in range(plan.nsignals)}      # noqa: E731

    def with_sources(signals: dict) -> dict:
        return _with_sources(b, signals)

    fn_src = _sources_function(b)

    # the tick: every output in plan order, then the sampled blocks' updates
    fn_tick = _Function(b, "sampled_tick", "t, x, theta, src, ext, work, aux, held, xn")
    signals = with_sources(held())
    for j, i in zip(_indices(plan.copy_y), _indices(plan.copy_x)):
        signals[j] = g.leaf("x", i)
    for step in plan.steps:
        if _is_source(step):
            continue
        for r, v in enumerate(b.block_rows(fn_tick, step, "output", signals)):
            signals[step.y.start + r] = v
    for step in plan.updates:
        if step.name in discrete:
            for r, v in enumerate(b.block_rows(fn_tick, step, "update", signals)):
                fn_tick.assign(f"xn[{step.x.start + r}]", v)
    for step in plan.steps:
        if step.name in discrete:
            for j in range(step.y.start, step.y.stop):
                fn_tick.assign(f"held[{j}]", signals[j])

    # between ticks: the continuous blocks a continuous update needs, then those updates
    between = {s.name for s in hybrid._steps_between_ticks}
    fn_rhs = _Function(b, "sampled_rhs", "t, x, theta, src, ext, work, aux, dx")
    signals = held()
    if any(_is_source(s) for s in plan.steps if s.name in between):
        fn_rhs.emit("loop_sources(t, theta, ext, work, src)")
        signals = with_sources(signals)
    for j, i in zip(_indices(plan.copy_y), _indices(plan.copy_x)):
        signals[j] = g.leaf("x", i)
    for step in plan.rhs_steps:
        if step.name in between and not _is_source(step):
            for r, v in enumerate(b.block_rows(fn_rhs, step, "output", signals)):
                signals[step.y.start + r] = v
    for step in plan.updates:
        if step.name in discrete:
            for i in range(step.x.start, step.x.stop):
                fn_rhs.emit(f"dx[{i}] = 0.0")
        else:
            for r, v in enumerate(b.block_rows(fn_rhs, step, "update", signals)):
                fn_rhs.assign(f"dx[{step.x.start + r}]", v)

    # outputs at a time between ticks
    fn_out = _Function(b, "sampled_outputs", "t, x, theta, src, ext, work, aux, y")
    _assign_outputs(fn_out, plan, _output_pass(b, fn_out, with_sources(held()), skip=discrete))

    tables, member_ext = _member_ext(b)
    n_out = len(plan.out_index)
    sizes = (f"def loop_source_count():\n    return {max(b.n_src, 1)}\n\n\n"
             f"def loop_work_size():\n    return {max(b.work, 1)}\n\n\n"
             f"def loop_output_count():\n    return {n_out}\n\n\n"
             f"def loop_signal_count():\n    return {plan.nsignals}\n\n\n"
             f"def loop_row_count():\n    return 1\n\n\n")
    # the derivative dp_step integrates (blocks/engines/compiled/dopri.py): this one replaces the template's
    step_rhs = ("def step_rhs(t, x, theta, ext, src, work, aux, out):\n"
                "    sampled_rhs(t, x, theta, src, ext, work, aux, out)\n\n\n")
    source = _callee_functions(b) + "\n".join(f.text() for f in (fn_src, fn_tick, fn_rhs, fn_out)) + "\n" + step_rhs \
        + member_ext + sizes
    structure = "sampled\n" + structure_of(plan, kernels, list(system.output_labels)) + \
        "\n" + ",".join(sorted(discrete)) + "|" + ",".join(sorted(between))
    return LoopProgram(source=source, theta=np.array(b.theta, dtype=float), theta_slices=b.theta_slices,
                       ext=tuple(b.ext), ext_slices=b.ext_slices, traced=b.traced, called=b.called,
                       sources=[s.name for s in b.source_steps], n_src=max(b.n_src, 1), n_work=max(b.work, 1),
                       n_out=n_out, kernels=dict(b.kernel_names), structure=structure, tables=tables,
                       order=[s.name for s in plan.steps])


def sampled_program_for(hybrid) -> tuple[LoopProgram, dict]:
    """The sampled program of a hybrid diagram's structure (traced once per process) and its kernels by block.

    Raises
    ------
    CompiledUnavailable
        As :func:`sampled_program`.
    """
    kernels = block_kernels(hybrid.plan, hybrid.system)
    key = "sampled\n" + structure_of(hybrid.plan, kernels, list(hybrid.system.output_labels)) + \
        "\n" + repr(sorted(hybrid.multiples.items()))
    program = _programs.get(key)
    if program is None:
        program = sampled_program(hybrid)
        _programs[key] = program
    return program, kernels
