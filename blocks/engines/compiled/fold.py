"""Fold a generated function's single-use temporaries into the expression that uses them, for CPython.

The traced code is one statement per operation (``v3 = v1 * v2``), which
suits numba and a C compiler.  CPython pays for every statement: storing the
float, loading it back, and keeping it alive until the function ends.  For
the ``fast`` engine (:mod:`blocks.engines.compiled.scalar`) a temporary assigned an
arithmetic expression and read exactly once is substituted into the
expression that reads it, so ``v3 = v1 * v2; v4 = v3 + v0`` becomes
``v4 = v1 * v2 + v0``: the same operations on the same operands in the same
order and grouping (the expression tree is the trace's; :func:`ast.unparse`
writes the parentheses it needs), so the same floats to the last bit, in
fewer statements.  About a fifth of a URDF arm's right-hand side.

Only straight-line functions are folded (no block, every name assigned
once); only arithmetic is moved (``+ - * / **``, unary minus, numbers and
names, no call or subscript, so no evaluation moves past another call); a
folded expression is at most :data:`MAX_DEPTH` operations deep (CPython's
compiler recurses on nesting).  Anything else is left as it is.
"""
from __future__ import annotations

import ast
import re

__all__ = ["fold_single_use", "MAX_DEPTH"]

#: Deepest expression a fold makes (operations from the root to a leaf).
MAX_DEPTH = 40

_ARITHMETIC = (ast.BinOp, ast.UnaryOp)


def _depth(node: ast.AST) -> int:
    if isinstance(node, ast.BinOp):
        return 1 + max(_depth(node.left), _depth(node.right))
    if isinstance(node, ast.UnaryOp):
        return 1 + _depth(node.operand)
    return 0


def _arithmetic(node: ast.AST) -> bool:
    """Whether ``node`` is arithmetic on names and numbers only (nothing that calls, indexes or looks up)."""
    if isinstance(node, ast.BinOp):
        return _arithmetic(node.left) and _arithmetic(node.right)
    if isinstance(node, ast.UnaryOp):
        return isinstance(node.op, (ast.USub, ast.UAdd)) and _arithmetic(node.operand)
    return isinstance(node, ast.Name) or (isinstance(node, ast.Constant) and isinstance(node.value, (int, float)))


class _Substitute(ast.NodeTransformer):
    def __init__(self, pending: dict) -> None:
        self.pending = pending

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if isinstance(node.ctx, ast.Load) and node.id in self.pending:
            return self.pending.pop(node.id)
        return node


def _straight_line(fn: ast.FunctionDef) -> bool:
    """Every statement an expression, a return, or an assignment to a new name or to an item of an argument."""
    arguments = {a.arg for a in fn.args.args}
    assigned = set(arguments)
    for statement in fn.body:
        if isinstance(statement, (ast.Expr, ast.Return)):
            continue
        if not isinstance(statement, ast.Assign) or len(statement.targets) != 1:
            return False
        target = statement.targets[0]
        if isinstance(target, ast.Name):
            if target.id in assigned:
                return False
            assigned.add(target.id)
        elif not (isinstance(target, ast.Subscript) and isinstance(target.value, ast.Name)
                  and target.value.id in arguments):
            return False
    return True


def _folded(fn: ast.FunctionDef) -> bool:
    """Fold ``fn``'s body in place; False where it is not straight-line code (``fn`` is then to be dropped)."""
    if not _straight_line(fn):
        return False
    reads: dict[str, int] = {}
    for node in ast.walk(fn):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load):
            reads[node.id] = reads.get(node.id, 0) + 1
    pending: dict[str, ast.AST] = {}
    substitute = _Substitute(pending)
    body = []
    for statement in fn.body:
        statement = substitute.visit(statement)
        if isinstance(statement, ast.Assign) and isinstance(statement.targets[0], ast.Name) \
                and isinstance(statement.value, _ARITHMETIC) and _arithmetic(statement.value) \
                and reads.get(statement.targets[0].id) == 1 and _depth(statement.value) < MAX_DEPTH:
            pending[statement.targets[0].id] = statement.value
            continue
        body.append(statement)
    if pending:                       # a read before its assignment: not the code this expects
        return False
    fn.body = body
    return True


def fold_single_use(source: str, names) -> str:
    """``source`` (a module of generated functions) with the functions ``names`` folded (see the module docstring).

    Parameters
    ----------
    source : str
        Python source.
    names : iterable of str
        The functions to fold; those absent or not straight-line code are left as they are.

    Returns
    -------
    str
        The source with those functions' text replaced by their folded text (the rest as it was).  A function
        is found by its ``def`` at the start of a line and ends before the next line that starts with no
        indentation.
    """
    for name in names:
        found = re.search(rf"^def {re.escape(name)}\(.*?(?=^\S|\Z)", source, re.S | re.M)
        if found is None:
            continue
        try:
            (fn,) = ast.parse(found.group(0)).body   # the function's text alone: parsing the module costs more
        except (SyntaxError, ValueError):            # not one function by itself: leave it
            continue
        if isinstance(fn, ast.FunctionDef) and _folded(fn):
            text = ast.unparse(ast.fix_missing_locations(fn)) + "\n\n\n"
            source = source[:found.start()] + text + source[found.end():]
    return source
