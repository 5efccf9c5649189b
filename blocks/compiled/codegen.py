"""Generate one loop's compiled module from its evaluation plan and its blocks' kernels.

:func:`loop_program` reads a :class:`~blocks.plan.LoopPlan` -- blocks in
evaluation order, input gathers, outputs read from states -- and writes the
source of three functions:

``loop_sources(t, theta, ext, work, src)``
    the outputs of the source blocks (no inputs, no states: the reference);
``loop_rhs(t, x, theta, src, ext, work, dx)``
    the loop's state derivative, the blocks in plan order;
``loop_outputs(t, x, theta, src, ext, work, y)``
    the interconnection's outputs.

A block's kernels are traced (:mod:`blocks.compiled.trace`) into scalar
statements when they can be: then the generated code has no array
temporaries, and a term two blocks compute alike is computed once.  A
kernel that cannot be traced (a table lookup, a branch on the time) is
called as its numba-compiled copy (:func:`blocks.compiled.jit.jit_kernel`).
The numbers of traced blocks are read from one vector ``theta``, so a new
gain or mass needs no new code; the parameters of called kernels travel in
the tuple ``ext``.  The module's text also holds the integrators of
:mod:`blocks.compiled.dopri`.

Each module is written once to the cache folder under a name that hashes
its text and the source of every kernel it calls; numba caches its machine
code beside it, so a second process neither traces into new code nor
recompiles.  The folder is ``$DOBKIT_CACHE_DIR`` or ``~/.cache/dobkit``
(``$XDG_CACHE_HOME/dobkit``), with a temporary folder as the fallback.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import platform
import sys
import tempfile
import time
import types
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..contract import contract_of
from ..control_compat import subsystems
from .jit import jit_kernel, kernel_sources, numba_or_none
from .trace import Graph, Sym, TraceError, param_structure, param_values, symbolic_params

__all__ = ["CompiledUnavailable", "LoopProgram", "loop_program", "cache_dir", "load_module"]

# A parameter array larger than this is a table (noise samples), not numbers to trace.
_TABLE_SIZE = 64


class CompiledUnavailable(RuntimeError):
    """The compiled engine cannot run this loop; the message says which block or setting stops it."""


# --------------------------------------------------------------------------------------------------------------
# The program of one loop: which blocks are traced, where their numbers are, the generated text
# --------------------------------------------------------------------------------------------------------------
@dataclass
class LoopProgram:
    """A loop's generated module and how to call it.

    Attributes
    ----------
    key : str
        Hash of the module's text and of the kernels it calls: its name in the cache.
    source : str
        The generated functions (without the integrators' text).
    theta : numpy.ndarray
        The numbers of the traced blocks' parameters, in the order the code reads them.
    theta_slices : dict of str to slice
        Each traced block's part of ``theta``.
    ext : tuple
        Parameters of the kernels called as compiled functions, in order.
    traced, called : list of str
        Blocks traced into statements, and blocks whose kernels are called.
    sources : list of str
        Source blocks (evaluated by ``loop_sources``).
    n_src, n_work, n_out : int
        Sizes of the source vector, the work buffer and the output vector.
    kernels : dict of str to function
        The numpy kernels the generated code calls (by their name there).
    """

    key: str
    source: str
    theta: np.ndarray
    theta_slices: dict
    ext: tuple
    traced: list
    called: list
    sources: list
    n_src: int
    n_work: int
    n_out: int
    kernels: dict = field(default_factory=dict)


def _block_kernels_or_fail(plan, system) -> dict:
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


def _has_table(params) -> bool:
    if isinstance(params, np.ndarray):
        return params.size > _TABLE_SIZE or params.dtype.kind not in "fiu"
    if isinstance(params, tuple):
        return any(_has_table(p) for p in params)
    return False


class _Builder:
    """Traces the blocks of a plan and emits the statements of one generated function at a time."""

    def __init__(self, plan, kernels: dict) -> None:
        self.plan, self.kernels = plan, kernels
        self.graph = Graph()
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
        self.structure: list[str] = []
        for step in plan.steps:
            self._classify(step)

    # -- which blocks are traced -----------------------------------------------------------------------
    def _classify(self, step) -> None:
        k = self.kernels[step.name]
        self.structure.append(f"{step.name}:{k.output.__module__}.{k.output.__qualname__}:"
                              f"{getattr(k.update, '__qualname__', None)}:{param_structure(k.params)}")
        if not _has_table(k.params):
            start = len(self.theta)
            try:
                sym = symbolic_params(self.graph, k.params, self.theta)
                # a trial trace of every function the block has, on fresh symbols
                x = self._leaves("x", range(step.x.start, step.x.stop))
                u = self._leaves("trial", range(_gather_size(step)))
                t = self.graph.leaf("t", 0)
                if k.output is not None:
                    _rows(k.output(t, x, u, *sym), step.y.stop - step.y.start)
                if k.update is not None and step.x.stop > step.x.start:
                    _rows(k.update(t, x, u, *sym), step.x.stop - step.x.start)
                self.sym_params[step.name] = sym
                self.theta_slices[step.name] = slice(start, len(self.theta))
                self.traced.append(step.name)
                return
            except (TraceError, TypeError, AttributeError, IndexError, ValueError):
                del self.theta[start:]
        e0 = len(self.ext)
        self.ext.extend(k.params)
        self.ext_slices[step.name] = (e0, len(self.ext))
        self.called.append(step.name)

    def _leaves(self, kind: str, indices) -> np.ndarray:
        out = np.empty(len(indices), dtype=object)
        for n, i in enumerate(indices):
            out[n] = self.graph.leaf(kind, i)
        return out

    # -- one block in a function -----------------------------------------------------------------------
    def block_rows(self, fn_out: "_Function", step, which: str, signals: dict) -> list:
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
            return _rows(fn(self.graph.leaf("t", 0), x, u, *self.sym_params[step.name]), n_rows)
        # a called kernel: inputs into the work buffer, the compiled copy, its rows read back
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


def _rows(value, n: int) -> list:
    """A kernel's result as ``n`` expressions (numbers become constants)."""
    arr = np.asarray(value, dtype=object).ravel()
    if arr.size != n:
        raise TraceError(f"a kernel returned {arr.size} rows where {n} were expected")
    out = []
    for v in arr:
        if v is None:
            raise TraceError("a kernel left a row unset")
        out.append(v)
    return out


# --------------------------------------------------------------------------------------------------------------
# Emitting one function
# --------------------------------------------------------------------------------------------------------------
_CALL_NAMES = {"cos": "np.cos", "sin": "np.sin", "tan": "np.tan", "tanh": "np.tanh", "sqrt": "np.sqrt",
               "exp": "np.exp", "sign": "np.sign", "floor": "np.floor", "absolute": "np.abs",
               "maximum": "np.maximum", "minimum": "np.minimum", "arctan2": "np.arctan2"}


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
            self.lines.append(f"{name} = {self._expr(node)}")
        return self.names[v.id]

    def _expr(self, node: Sym) -> str:
        if node.op == "leaf":
            kind, index = node.args
            if kind == "t":
                return "t"
            if kind in ("x", "theta", "src"):
                return f"{kind}[{index}]"
            if kind == "call":
                call, row = index
                return f"r{call}[{row}]"
            raise CompiledUnavailable(f"the generated code would read {kind!r} {index!r}: a block uses an input "
                                      "its contract says does not feed through")
        ops = [self.value(a) for a in node.args[1:]]
        if node.op == "bin":
            return f"{ops[0]} {node.args[0]} {ops[1]}"
        name = node.args[0]
        if name == "negative":
            return f"-{ops[0]}"
        return f"{_CALL_NAMES[name]}({', '.join(ops)})"

    def call(self, kernel: str, step, w0: int, inputs: list, ext_slice: tuple) -> int:
        """Emit a call of a compiled kernel on its gathered inputs; return the call's number."""
        for i, s in enumerate(inputs):
            unset = isinstance(s, Sym) and s.op == "leaf" and s.args[0] == "unset"
            self.lines.append(f"work[{w0 + i}] = {'0.0' if unset else self.value(s)}")
        self.calls += 1
        c = self.calls
        x = f"x[{step.x.start}:{step.x.stop}]" if "x" in self.args.split(", ") else "work[0:0]"
        params = "".join(f", ext[{e}]" for e in range(*ext_slice))
        self.lines.append(f"r{c} = {kernel}(t, {x}, work[{w0}:{w0 + len(inputs)}]{params})")
        return c

    def assign(self, target: str, v) -> None:
        self.lines.append(f"{target} = {self.value(v)}")

    def text(self) -> str:
        body = self.lines or ["pass"]
        return f"def {self.name}({self.args}):\n" + "".join(f"    {line}\n" for line in body) + "\n"


def _operands(node: Sym) -> list:
    if node.op in ("bin", "call"):
        return [a for a in node.args[1:] if isinstance(a, Sym)]
    return []


# --------------------------------------------------------------------------------------------------------------
# The program of a plan
# --------------------------------------------------------------------------------------------------------------
def loop_program(plan, system) -> LoopProgram:
    """Trace the blocks of ``plan`` (of the interconnection ``system``) and generate the loop's functions.

    Raises
    ------
    CompiledUnavailable
        If the plan is not direct (connections other than one signal with
        gain 1, external inputs) or a block has no kernels.
    """
    if not plan.direct:
        raise CompiledUnavailable("the interconnection is not direct (an input is a sum or a scaled signal, or the "
                                  "loop has external inputs), so the compiled engine cannot run it")
    kernels = _block_kernels_or_fail(plan, system)
    b = _Builder(plan, kernels)
    g = b.graph

    # loop_sources: the source blocks' outputs into src
    fn_src = _Function(b, "loop_sources", "t, theta, ext, work, src")
    for step in b.source_steps:
        rows = b.block_rows(fn_src, step, "output", {})
        for r, v in enumerate(rows):
            fn_src.assign(f"src[{b.src_offset[step.name] + r}]", v)

    def signals_with_sources() -> dict:
        signals = {}
        for step in b.source_steps:
            for r in range(step.y.stop - step.y.start):
                signals[step.y.start + r] = g.leaf("src", b.src_offset[step.name] + r)
        return signals

    # loop_rhs: outputs the right-hand side needs, then every update
    fn_rhs = _Function(b, "loop_rhs", "t, x, theta, src, ext, work, dx")
    signals = signals_with_sources()
    copy_y, copy_x = _indices(plan.copy_y), _indices(plan.copy_x)
    for j, i in zip(copy_y, copy_x):
        signals[j] = g.leaf("x", i)
    for step in plan.rhs_steps:
        if _is_source(step):
            continue
        for r, v in enumerate(b.block_rows(fn_rhs, step, "output", signals)):
            signals[step.y.start + r] = v
    for step in plan.updates:
        for r, v in enumerate(b.block_rows(fn_rhs, step, "update", signals)):
            fn_rhs.assign(f"dx[{step.x.start + r}]", v)

    # loop_outputs: every block's outputs, the interconnection's selection of them
    fn_out = _Function(b, "loop_outputs", "t, x, theta, src, ext, work, y")
    signals = signals_with_sources()
    for step in plan.steps:
        if _is_source(step):
            continue
        for r, v in enumerate(b.block_rows(fn_out, step, "output", signals)):
            signals[step.y.start + r] = v
    for r, j in enumerate(plan.out_index):
        fn_out.assign(f"y[{r}]", signals[int(j)])

    n_out = len(plan.out_index)
    sizes = (f"def loop_source_count():\n    return {b.n_src}\n\n\n"
             f"def loop_work_size():\n    return {max(b.work, 1)}\n\n\n"
             f"def loop_output_count():\n    return {n_out}\n\n\n")
    source = fn_src.text() + "\n" + fn_rhs.text() + "\n" + fn_out.text() + "\n" + sizes
    numba = numba_or_none()
    key_text = "\n".join([source, _template_text(), kernel_sources(b.kernel_names.values()),
                          "\n".join(b.structure), f"numba {getattr(numba, '__version__', None)}",
                          f"numpy {np.__version__}", f"python {platform.python_version()} {sys.platform}"])
    key = hashlib.sha256(key_text.encode()).hexdigest()[:20]
    return LoopProgram(key=key, source=source, theta=np.array(b.theta, dtype=float), theta_slices=b.theta_slices,
                       ext=tuple(b.ext), traced=b.traced, called=b.called, sources=[s.name for s in b.source_steps],
                       n_src=b.n_src, n_work=max(b.work, 1), n_out=n_out, kernels=dict(b.kernel_names))


def _indices(idx) -> list:
    if isinstance(idx, slice):
        return list(range(idx.start or 0, idx.stop))
    return [int(i) for i in np.asarray(idx).ravel()]


def theta_of(program: LoopProgram, plan, kernels_by_block: dict) -> np.ndarray:
    """The ``theta`` vector of a loop with the program's structure but other numbers."""
    out: list[float] = []
    for name in program.traced:
        param_values(kernels_by_block[name].params, out)
    return np.array(out, dtype=float)


# --------------------------------------------------------------------------------------------------------------
# The module on disk
# --------------------------------------------------------------------------------------------------------------
def _template_text() -> str:
    return (Path(__file__).parent / "dopri.py").read_text(encoding="utf-8")


def cache_dir() -> Path:
    """Where generated modules and numba's machine code for them are kept (see the module docstring)."""
    root = os.environ.get("DOBKIT_CACHE_DIR")
    if root:
        return Path(root) / "compiled"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "dobkit" / "compiled"


def _writable_dir() -> Path:
    for folder in (cache_dir(), Path(tempfile.gettempdir()) / f"dobkit-compiled-{os.getuid()}"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            probe = folder / f".probe-{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            return folder
        except OSError:
            continue
    raise CompiledUnavailable(f"no writable folder for compiled code (tried {cache_dir()} and the temporary folder)")


_modules: dict[str, types.ModuleType] = {}


def module_path(program: LoopProgram) -> Path:
    return _writable_dir() / f"dobkit_loop_{program.key}.py"


def load_module(program: LoopProgram) -> tuple[types.ModuleType, bool]:
    """The program's compiled module (written and imported once per process); whether it was compiled before.

    The functions are numba dispatchers with ``cache=True``; they compile on
    first call, or load the machine code numba cached beside the file.
    """
    module = _modules.get(program.key)
    if module is not None:
        return module, module_path(program).with_suffix(".compiled").exists()
    numba = numba_or_none()
    path = module_path(program)
    text = ("# Generated by blocks.compiled.codegen for one loop structure; the cache may delete it.\n"
            + _template_text() + "\n\n# ---- the loop's functions, generated from its plan ----\n\n" + program.source)
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)          # atomic: another process reads the old file or the new, never half
    name = path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module          # numba's cache imports a function's module by name when it loads it
    spec.loader.exec_module(module)
    for kname, fn in program.kernels.items():
        setattr(module, kname, jit_kernel(fn))
    parallel = set(getattr(module, "PARALLEL", ()))
    for attr, value in list(vars(module).items()):
        if isinstance(value, types.FunctionType) and value.__module__ == name:
            options = dict(cache=True, error_model="numpy")
            if attr in parallel:
                options["parallel"] = True
            setattr(module, attr, numba.njit(**options)(value))
    _modules[program.key] = module
    marker = path.with_suffix(".compiled")
    return module, marker.exists()


def mark_compiled(program: LoopProgram) -> None:
    """Record that the program's machine code is in numba's cache (no compile message next time)."""
    try:
        module_path(program).with_suffix(".compiled").write_text(time.strftime("%Y-%m-%d %H:%M:%S"))
    except OSError:
        pass
