"""A loop's generated right-hand side as C, compiled by the system's C compiler and called through ctypes.

:func:`blocks.engines.compiled.codegen.loop_program` writes a loop's functions as
straight-line Python (one ``vN = ...`` statement per traced operation, an arm's
``M(q)`` and ``h(q, q')`` as functions of the module).  numba compiles that text
for the compiled engine; without numba the ``fast`` engine runs it on Python
floats (:mod:`blocks.engines.compiled.scalar`), where a chain arm's loop costs
about 13 us per right-hand side -- as much as a lean pinocchio loop written by
hand.  Here the same functions are written as C99 (:func:`loop_c_source`: every
statement the same operation on the same operands, comparisons as 0/1, numpy's
``sign``/``maximum``/``minimum`` as :data:`~blocks.engines.compiled.c_backend.C_PRELUDE`
defines them) and compiled with ``-ffp-contract=off`` and without fast-math, so
a C call returns the floats the Python text returns, bit for bit (tested).  ``tanh`` and
``exp`` are the C library's, as in numba's code (the Python text calls numpy's,
which may differ in the last bit); the example arms' loops use neither.

What cannot be C is refused (:class:`CUnavailable`, with the reason): a block
whose kernels are called rather than traced (the laceration path, a noise
table), a table lookup, anything else the text reads from ``ext`` or ``work``.
The engine then keeps the Python text.

The shared library is kept in the compiled-code cache folder
(:func:`blocks.engines.compiled.cache.cache_dir`) under a name hashing its C
text, the compiler and the flags; it is written to a temporary name and
renamed into place, so a second process or a killed compile never leaves a
half-written library under the real name; its SHA-256 is written beside it and
checked before it is loaded.  Compiling takes 0.2-0.4 s for the UR5's and the
Panda's loops (:func:`estimate_c_compile_seconds`); a loop estimated over
:data:`C_COMPILE_LIMIT` is not compiled, and a compiler that does not finish
within :data:`COMPILE_TIMEOUT` is stopped (with its whole process group); the
Python text runs then.
"""
from __future__ import annotations

import ast
import ctypes
import hashlib
import os
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np

from blocks.engines.compiled.c_backend import C_PRELUDE
from blocks.engines.compiled.cache import CompiledCacheWarning, _sha256, _write_atomic, cache_dir
from blocks.engines.compiled.codegen import CompiledUnavailable, LoopProgram
from blocks.plumbing.compiler import CompilerTimeout, compiler_command, run_compiler

__all__ = ["CUnavailable", "CTooLong", "loop_c_source", "c_compiler", "loop_library", "CLoop", "c_rhs", "C_LOOP_FLAGS",
           "COMPILE_TIMEOUT", "C_COMPILE_LIMIT", "estimate_c_compile_seconds"]

#: Flags of the loop's library: the generated maths must round as the Python text does (no fused multiply-adds,
#: no fast-math); -O1 compiles the Panda's loop in two thirds of -O2's time (0.32 against 0.47 s) and runs within 10 %.
C_LOOP_FLAGS = ("-std=c99", "-O1", "-ffp-contract=off", "-fno-fast-math", "-shared", "-fPIC")
#: Seconds a compile may take before it is stopped (the Python text is used then).
COMPILE_TIMEOUT = 120.0
#: A loop whose C is estimated to compile longer than this (s, :func:`estimate_c_compile_seconds`) is not compiled:
#: the fast engine's promise is no compile to wait for, and the largest example arm's loop takes about 0.3 s.
C_COMPILE_LIMIT = 10.0
# The generated functions the fast engine calls, by their Python name -> their C arguments.
_ARGS = {"loop_sources": "double t, const double *theta, double *src",
         "loop_rhs": "double t, const double *x, const double *theta, const double *src, double *dx",
         "loop_outputs": "double t, const double *x, const double *theta, const double *src, double *y",
         "loop_outputs_rows": "double t, const double *x, const double *theta, const double *src, const double *aux, "
                              "const double *flags, double *y, double *rows"}
# The Python text's arguments each C function keeps (the others, ext and work, are what C cannot read).
_KEPT = {"t", "x", "theta", "src", "dx", "y", "aux", "flags", "rows"}
# np.<name> -> C (numpy's semantics for sign, maximum, minimum: C_PRELUDE)
_C_MATH = {"cos": "cos", "sin": "sin", "tan": "tan", "tanh": "tanh", "sqrt": "sqrt", "exp": "exp",
           "sign": "dk_sign", "floor": "floor", "abs": "fabs", "maximum": "dk_maximum", "minimum": "dk_minimum",
           "arctan2": "atan2", "rint": "rint"}
_C_OPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}

_C_COMPARE = {ast.Gt: ">", ast.Lt: "<", ast.GtE: ">=", ast.LtE: "<="}


class CUnavailable(CompiledUnavailable):
    """The loop's functions cannot be C (a called kernel, a table), or no C compiler could build them."""


class CTooLong(CUnavailable):
    """The loop's C would take longer to compile than the caller allows."""


# --------------------------------------------------------------------------------------------------------------
# Python text -> C text
# --------------------------------------------------------------------------------------------------------------
class _Writer:
    """One generated function as C: each ``vN = ...`` a ``const double`` (or, for a call of a module function,
    an array of its outputs)."""

    def __init__(self, outputs_of: dict) -> None:
        self.outputs_of = outputs_of          # module function -> how many outputs it returns
        self.arrays: set[str] = set()
        self.reads_aux = False
        self.aux_flags: set[int] = set()       # the row groups (flag indices) whose statements read aux

    def expr(self, node) -> str:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                and not isinstance(node.value, bool):
            return repr(float(node.value))
        if isinstance(node, ast.Name):
            if node.id == "t" or node.id.startswith("v"):
                return node.id
            raise CUnavailable(f"the generated code reads {node.id!r} as a value")
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "np":
            if node.attr == "nan":
                return "NAN"
            if node.attr == "inf":
                return "INFINITY"
            raise CUnavailable(f"the generated code reads np.{node.attr}")
        if isinstance(node, ast.Subscript):
            return self.subscript(node)
        if isinstance(node, ast.BinOp) and type(node.op) in _C_OPS:
            return f"({self.expr(node.left)} {_C_OPS[type(node.op)]} {self.expr(node.right)})"
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return f"(-{self.expr(node.operand)})"
        if isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in _C_COMPARE:
            # a comparison is a 0/1 number in the Python text (True * 2.0 == 2.0): the same in C
            return (f"(double)({self.expr(node.left)} {_C_COMPARE[type(node.ops[0])]} "
                    f"{self.expr(node.comparators[0])})")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and isinstance(node.func.value, ast.Name) and node.func.value.id == "np" \
                and node.func.attr in _C_MATH and not node.keywords:
            return f"{_C_MATH[node.func.attr]}({', '.join(self.expr(a) for a in node.args)})"
        raise CUnavailable(f"the generated code has {ast.unparse(node)!r}, which has no C translation here")

    def subscript(self, node: ast.Subscript) -> str:
        if not (isinstance(node.value, ast.Name) and isinstance(node.slice, ast.Constant)
                and isinstance(node.slice.value, int)):
            raise CUnavailable(f"the generated code reads {ast.unparse(node)!r} (a called kernel's rows or a table)")
        name = node.value.id
        if name == "aux":
            self.reads_aux = True
        if name in ("x", "theta", "src", "aux") or name in self.arrays:
            return f"{name}[{node.slice.value}]"
        raise CUnavailable(f"the generated code reads {ast.unparse(node)!r} (a called kernel's rows or a table)")

    def statement(self, node) -> str:
        if isinstance(node, ast.Pass):
            return ""
        if isinstance(node, ast.If) and not node.orelse and _is_flag_test(node.test):
            # a row group's statements, run when its flag is set; what they name stays inside (as in the text)
            flag, outside = node.test.left.slice.value, self.reads_aux
            self.reads_aux = False
            inner = "".join(f"        {line}\n" for line in (self.statement(s) for s in node.body) if line)
            if self.reads_aux:
                self.aux_flags.add(flag)
            self.reads_aux = outside or self.reads_aux
            return f"if (flags[{flag}] != 0.0) {{\n{inner}    }}"
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1):
            raise CUnavailable(f"the generated code has the statement {ast.unparse(node)!r}")
        target, value = node.targets[0], node.value
        if isinstance(target, ast.Name) and target.id.startswith("v"):
            if isinstance(value, ast.Call) and isinstance(value.func, ast.Name):
                return self.module_call(target.id, value)
            return f"const double {target.id} = {self.expr(value)};"
        if isinstance(target, ast.Subscript) and isinstance(target.value, ast.Name) \
                and target.value.id in ("dx", "src", "y", "rows") and isinstance(target.slice, ast.Constant):
            return f"{target.value.id}[{target.slice.value}] = {self.expr(value)};"
        raise CUnavailable(f"the generated code assigns {ast.unparse(target)!r}")

    def module_call(self, name: str, call: ast.Call) -> str:
        """``vK = f((a, b, ...,))``: a module function (an arm's M or h) writing its outputs to the array vK."""
        fname = call.func.id
        if fname not in self.outputs_of or len(call.args) != 1 or not isinstance(call.args[0], ast.Tuple):
            raise CUnavailable(f"the generated code calls {fname!r} (a kernel, not a function of the module)")
        args = ", ".join(self.expr(a) for a in call.args[0].elts)
        self.arrays.add(name)
        size = max(self.outputs_of[fname], 1)
        return f"double {name}[{size}]; {fname}((const double[]){{{args}}}, {name});"


def _is_flag_test(test) -> bool:
    """Whether ``test`` is ``flags[g] != 0`` (how the text guards a row group)."""
    return isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.NotEq) \
        and isinstance(test.left, ast.Subscript) and isinstance(test.left.value, ast.Name) \
        and test.left.value.id == "flags" and isinstance(test.left.slice, ast.Constant) \
        and isinstance(test.comparators[0], ast.Constant) and test.comparators[0].value == 0


def _functions(source: str) -> dict:
    """The generated module's functions by name (their syntax trees)."""
    return {node.name: node for node in ast.parse(source).body if isinstance(node, ast.FunctionDef)}


# program key -> (its C text, the flags of the row groups that read aux), or why it has none
_c_texts: dict[str, tuple[str, frozenset] | CUnavailable] = {}


def _written(program: LoopProgram) -> tuple[str, frozenset]:
    """``(C text, flags of the row groups that read aux)`` of ``program``, written once per program and process
    (parsing the text costs tens of ms).

    Raises
    ------
    CUnavailable
        As :func:`_loop_c_text`.
    """
    found = _c_texts.get(program.key)
    if found is None:
        try:
            found = _loop_c_text(program)
        except CUnavailable as err:
            found = err
        _c_texts[program.key] = found
    if isinstance(found, CUnavailable):
        raise found
    return found


def loop_c_source(program: LoopProgram) -> str:
    """The C text of ``program`` (see :func:`_loop_c_text`).

    Raises
    ------
    CUnavailable
        If the program calls a kernel (a block that is not traced) or reads a table.
    """
    return _written(program)[0]


def _loop_c_text(program: LoopProgram) -> tuple[str, frozenset]:
    """The C text of a loop program's module functions (an arm's M and h, ``loop_sources``, ``loop_rhs``,
    ``loop_outputs``, ``loop_outputs_rows``) and three entry points: ``dk_rhs(t, x, theta, dx)``,
    ``dk_outputs(t, x, theta, y)`` (the sources evaluated first) and ``dk_outputs_grid`` (the outputs and the flagged
    row groups at every time of a grid, in one call); beside it the flags of the row groups whose statements read
    ``aux`` (which the grid pass does not have).

    Raises
    ------
    CUnavailable
        If the program calls a kernel (a block that is not traced) or reads a table.
    """
    if program.called:
        raise CUnavailable(f"block(s) {', '.join(repr(b) for b in program.called)} are called as kernels, not traced "
                           "into statements, so the loop's right-hand side cannot be C")
    fns = _functions(program.source)
    outputs_of, parts = {}, [C_PRELUDE]
    for name in program.callees:                          # an arm's M and h: name(const double *x, double *r)
        fn = fns[name]
        *body, ret = fn.body
        if [a.arg for a in fn.args.args] != ["x"] or not isinstance(ret, ast.Return) \
                or not isinstance(ret.value, ast.Tuple):
            raise CUnavailable(f"the module function {name!r} is not f(x) -> tuple")
        w = _Writer(outputs_of)
        text = [w.statement(stmt) for stmt in body]
        text += [f"r[{r}] = {w.expr(v)};" for r, v in enumerate(ret.value.elts)]
        outputs_of[name] = len(ret.value.elts)
        parts.append(f"static void {name}(const double *x, double *r)\n{{\n" + _body(text) + "}\n")
    for name, args in _ARGS.items():
        fn = fns[name]
        unknown = {a.arg for a in fn.args.args} - _KEPT - {"ext", "work"}
        if unknown:
            raise CUnavailable(f"{name} takes {sorted(unknown)}")
        w = _Writer(outputs_of)
        text = [w.statement(stmt) for stmt in fn.body]
        parts.append(f"static void {name}({args})\n{{\n" + _body(text) + "}\n")
        if name == "loop_outputs_rows":
            aux_flags = frozenset(w.aux_flags)
    n_src, n_aux, n_y = max(program.n_src, 1), max(program.n_aux, 1), max(program.n_out, 1)
    n_out, n_rows_used = program.n_out, program.n_rows
    n_rows = max(n_rows_used, 1)
    parts.append(f"""void dk_rhs(double t, const double *x, const double *theta, double *dx)
{{
    double src[{n_src}];
    loop_sources(t, theta, src);
    loop_rhs(t, x, theta, src, dx);
}}

void dk_outputs(double t, const double *x, const double *theta, double *y)
{{
    double src[{n_src}];
    loop_sources(t, theta, src);
    loop_outputs(t, x, theta, src, y);
}}

/* The outputs and the flagged row groups' rows at every grid time: X is (n_x, T), out (n_y + n_rows, T), both
   C-ordered; aux is zeros (CLoop.row_groups offers no group that reads it). */
void dk_outputs_grid(long T, const double *ts, long n_x, const double *X, const double *theta, const double *flags,
                     double *out)
{{
    double src[{n_src}], aux[{n_aux}] = {{0.0}}, y[{n_y}] = {{0.0}}, rows[{n_rows}] = {{0.0}};
    double x[n_x];
    for (long k = 0; k < T; k++) {{
        for (long i = 0; i < n_x; i++) x[i] = X[i * T + k];
        loop_sources(ts[k], theta, src);
        loop_outputs_rows(ts[k], x, theta, src, aux, flags, y, rows);
        for (long r = 0; r < {n_out}; r++) out[r * T + k] = y[r];
        for (long r = 0; r < {n_rows_used}; r++) out[({n_out} + r) * T + k] = rows[r];
    }}
}}
""")
    return "\n".join(parts), aux_flags


def _body(lines: list) -> str:
    return "".join(f"    {line}\n" for line in lines if line)


# --------------------------------------------------------------------------------------------------------------
# Building and loading the library
# --------------------------------------------------------------------------------------------------------------
def c_compiler() -> list[str] | None:
    """The C compiler's command (``$CC``, else ``cc``, ``gcc`` or ``clang`` on PATH, as the FMU export finds it), or
    None when there is none (or ``DOBKIT_FAST_C=0`` turns the C right-hand side off)."""
    if os.environ.get("DOBKIT_FAST_C", "1").strip() == "0":
        return None
    return compiler_command(os.environ.get("CC"))


def estimate_c_compile_seconds(c_lines: int) -> float:
    """Seconds the compiler takes on a loop's C text of ``c_lines`` lines (-O1; fitted to the UR5's 2,981 lines,
    0.19 s, and the Panda's 4,828, 0.32 s, on this project's 2-core machine, with a margin of 2 for a loaded one)."""
    return 2.0 * (0.02 + 6.5e-5 * c_lines)


_versions: dict[str, str] = {}


def _compiler_version(argv: list[str]) -> str:
    """The compiler's ``--version`` text (part of the library's name: another compiler, another library)."""
    key = " ".join(argv)
    if key not in _versions:
        try:
            said = subprocess.run(argv + ["--version"], capture_output=True, text=True, timeout=30)
            _versions[key] = said.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            _versions[key] = "unknown"
    return _versions[key]


def _compile(argv: list[str], c_text: str, output: Path) -> None:
    """Compile ``c_text`` into the shared library ``output`` (written under a temporary name, renamed into place)."""
    with tempfile.TemporaryDirectory(prefix="dobkit_cloop_") as tmp:
        source = Path(tmp) / "loop.c"
        source.write_text(c_text, encoding="utf-8")
        built = Path(tmp) / "loop.so"
        cmd = argv + list(C_LOOP_FLAGS) + [str(source), "-o", str(built), "-lm"]
        try:       # in its own process group: a time-out or an interrupt ends the whole compiler
            returncode, said = run_compiler(cmd, COMPILE_TIMEOUT, tmp)
        except CompilerTimeout as err:
            raise CUnavailable(str(err)) from None
        except OSError as err:
            raise CUnavailable(f"could not run the C compiler {argv[0]!r}: {err}") from None
        if returncode != 0 or not built.is_file():
            raise CUnavailable(f"compiling the loop's C failed (exit code {returncode}): {said.strip()[:400]}")
        data = built.read_bytes()
    _write_atomic(output, data)
    # the library's digest beside it: a library changed or cut short after it was written is not loaded
    _write_atomic(output.with_name(output.name + ".sha256"), hashlib.sha256(data).hexdigest().encode())


def _checked(path: Path) -> bool:
    """Whether ``path`` is a library whose bytes match the digest written beside it."""
    found = _sha256(path)
    try:
        digest = path.with_name(path.name + ".sha256").read_text().strip()
    except OSError:
        return False
    return found is not None and found[1] == digest


_libraries: dict[tuple, ctypes.CDLL] = {}


def loop_library(program: LoopProgram, max_compile_seconds: float = C_COMPILE_LIMIT) -> ctypes.CDLL:
    """The compiled library of ``program``'s C text: loaded from the cache folder when a checked copy is there,
    else compiled (into the cache folder, or a temporary one when that cannot be written).

    Parameters
    ----------
    program : LoopProgram
    max_compile_seconds : float
        A library not in the cache is compiled only when :func:`estimate_c_compile_seconds` says it takes at most
        this long (s).

    Raises
    ------
    CUnavailable
        No compiler, a text that cannot be C, or a failed compile (the message says which).
    CTooLong
        The compile would take longer than ``max_compile_seconds``.
    """
    argv = c_compiler()
    if argv is None:
        raise CUnavailable("no C compiler found (CC, cc, gcc, clang), or DOBKIT_FAST_C=0")
    c_text = loop_c_source(program)
    found = _libraries.get((program.key, tuple(argv)))
    if found is not None:
        return found
    key = hashlib.sha256("\n".join([c_text, " ".join(argv), _compiler_version(argv), " ".join(C_LOOP_FLAGS)])
                         .encode()).hexdigest()[:20]
    folder = cache_dir()
    path = folder / f"dobkit_cloop_{key}.so"
    if not _checked(path):
        seconds = estimate_c_compile_seconds(c_text.count("\n"))
        if seconds > max_compile_seconds:
            raise CTooLong(f"the loop's C ({c_text.count(chr(10)):,} lines) would take about {seconds:.3g} s to "
                           f"compile, over {max_compile_seconds:g} s")
        try:
            folder.mkdir(parents=True, exist_ok=True)
            _compile(argv, c_text, path)
        except OSError as err:          # the folder cannot be written: a library for this process only
            warnings.warn(f"compiled-code cache {folder}: the loop's C library cannot be kept there ({err}); it is "
                          "compiled for this process only", CompiledCacheWarning, stacklevel=2)
            path = Path(tempfile.mkdtemp(prefix="dobkit_cloop_")) / f"dobkit_cloop_{key}.so"
            _compile(argv, c_text, path)
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as err:
        raise CUnavailable(f"the loop's C library {path} could not be loaded: {err}") from None
    for name in ("dk_rhs", "dk_outputs"):
        fn = getattr(lib, name)
        fn.restype = None
        fn.argtypes = [ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    lib.dk_outputs_grid.restype = None
    lib.dk_outputs_grid.argtypes = [ctypes.c_long, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                                    ctypes.c_void_p, ctypes.c_void_p]
    _libraries[(program.key, tuple(argv))] = lib
    return lib


class CLoop:
    """A loop's right-hand side and outputs through its C library, with the loop's numbers ``theta``.

    Parameters
    ----------
    program : LoopProgram
    theta : numpy.ndarray
        The numbers of the loop's traced blocks (``program.numbers(kernels)[0]``).
    n_states : int
    """

    def __init__(self, program: LoopProgram, theta: np.ndarray, n_states: int) -> None:
        lib = loop_library(program)
        self._rhs_c, self._outputs_c, self._grid_c = lib.dk_rhs, lib.dk_outputs, lib.dk_outputs_grid
        self.program = program
        self.theta = np.array(theta, dtype=float)          # kept: the library reads it through its address
        self._x, self._dx, self._y = np.empty(n_states), np.empty(n_states), np.empty(max(program.n_out, 1))
        self._n_out = program.n_out
        self._addresses = (self._x.ctypes.data, self.theta.ctypes.data, self._dx.ctypes.data, self._y.ctypes.data)

    def rhs(self, t, x) -> np.ndarray:
        """The loop's state derivative at ``(t, x)``: a new array (a solver keeps what it is given)."""
        xa, tha, dxa, _ = self._addresses
        self._x[:] = x
        self._rhs_c(t, xa, tha, dxa)
        return self._dx.copy()

    def outputs(self, t, x) -> np.ndarray:
        """The interconnection's outputs at ``(t, x)`` (a new array)."""
        xa, tha, _, ya = self._addresses
        self._x[:] = x
        self._outputs_c(t, xa, tha, ya)
        return self._y[:self._n_out].copy()

    @property
    def row_groups(self) -> dict:
        """The row groups the grid pass offers (name -> (flag, rows)): those that read no shared values
        (``aux``: the reference's tool pose, which this pass does not have)."""
        reading = _written(self.program)[1]
        return {name: spec for name, spec in self.program.row_groups.items() if spec[0] not in reading}

    def outputs_on_grid(self, t_grid, X, rows: tuple = ()) -> tuple[np.ndarray, dict]:
        """The outputs (n_out, T) at the grid times ``t_grid`` (s) of the states ``X`` (n_x, T), and the rows of
        the row groups named in ``rows`` by name, in one C call."""
        groups = self.row_groups
        unknown = [name for name in rows if name not in groups]
        if unknown:
            raise ValueError(f"row group(s) {unknown} are not computed on the C grid pass; it has {sorted(groups)}")
        flags = np.zeros(max(len(self.program.row_groups), 1))
        for name in rows:
            flags[groups[name][0]] = 1.0
        t_grid = np.ascontiguousarray(t_grid, dtype=float)
        X = np.ascontiguousarray(X, dtype=float)
        out = np.zeros((self._n_out + self.program.n_rows, t_grid.size))
        self._grid_c(t_grid.size, t_grid.ctypes.data, X.shape[0], X.ctypes.data, self.theta.ctypes.data,
                     flags.ctypes.data, out.ctypes.data)
        n = self._n_out
        return out[:n], {name: out[n + groups[name][1].start:n + groups[name][1].stop] for name in rows}


_failures: set[str] = set()


def c_rhs(plan, system):
    """``f(t, x) -> dx`` of a loop through its C library, or None when the loop's text cannot be C or no compiler
    builds it (a compiler that fails says why once per process, as a warning).

    Parameters
    ----------
    plan : LoopPlan
    system : control.InterconnectedSystem
    """
    from blocks.engines.compiled.codegen import program_for
    from blocks.engines.compiled.rows import loop_rows_of
    if c_compiler() is None:
        return None
    try:
        program, kernels = program_for(plan, system, loop_rows_of(system))
        loop_c_source(program)                       # refuses what cannot be C before a compiler is run
    except CompiledUnavailable:
        return None
    try:
        theta, _ = program.numbers(kernels)
        return CLoop(program, theta, plan.nstates).rhs
    except CTooLong:
        return None
    except CUnavailable as err:
        if str(err) not in _failures:
            _failures.add(str(err))
            warnings.warn(f"the fast engine runs this loop's right-hand side in Python: {err}", RuntimeWarning,
                          stacklevel=2)
        return None
