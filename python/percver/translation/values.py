"""Symbolic values of a translated run: floats (constants, folded) or percver expressions.

A clock or counter whose value depends on the step number is kept relative to its value at
the start of the period (:class:`Relative`); reading it where an absolute value is needed
raises :class:`NeedAbsolute`, and the period is run again with that counter fixed.
"""

from __future__ import annotations

import math
from typing import Union

import numpy as np

from percver import _core
from percver.errors import ParseError
from percver.expr import Condition, Expr

TOL = 1e-9


class Relative:
    """A counter or timer relative to its (step-dependent) value at the start of the period."""

    __slots__ = ("var", "c")

    def __init__(self, var: str, c: float):
        self.var, self.c = var, c

    def __add__(self, d: float) -> "Relative":
        return Relative(self.var, self.c + d)

    def __eq__(self, other):
        return isinstance(other, Relative) and other.var == self.var and abs(other.c - self.c) <= TOL

    def __repr__(self):
        return f"{self.var}@start + {self.c}"


class NeedAbsolute(Exception):
    """A timer's value is needed where it depends on the step number (retry it as absolute)."""

    def __init__(self, var: str, pos: int):
        self.var, self.pos = var, pos


def is_num(x) -> bool:
    return isinstance(x, float)


def fold(op: str, a, b):
    """a op b with constants folded, so resets like ``0 * y1`` or ``temp := 0; temp + d`` stay small."""
    if is_num(a) and is_num(b):
        try:
            r = {"+": a + b, "-": a - b, "*": a * b}[op] if op != "/" else a / b
        except ZeroDivisionError:
            raise ArithmeticError("division by zero in a constant expression") from None
        return float(r)
    if op == "+":
        return b if is_num(a) and a == 0 else a if is_num(b) and b == 0 else a + b
    if op == "-":
        return a if is_num(b) and b == 0 else -b if is_num(a) and a == 0 else a - b
    if op == "*":
        if (is_num(a) and a == 0) or (is_num(b) and b == 0):
            return 0.0
        return b if is_num(a) and a == 1 else a if is_num(b) and b == 1 else a * b
    return a if is_num(b) and b == 1 else a / b


def call_function(name: str, x):
    if is_num(x):
        f = {
            "sin": math.sin,
            "cos": math.cos,
            "tan": math.tan,
            "atan": math.atan,
            "exp": math.exp,
            "log": math.log,
            "sqrt": math.sqrt,
            "tanh": math.tanh,
            "abs": abs,
            "sigmoid": lambda v: 1 / (1 + math.exp(-v)),
        }[name]
        return float(f(x))
    return Expr.apply(name, x)


def build_value(src, ast, lookup):
    """The value (float or Expr) of an AST; ``lookup(name, pos)`` gives each variable's value."""
    kind = ast[0]
    if kind == "num":
        return ast[1]
    if kind == "var":
        return lookup(ast[1], ast[2])
    if kind == "neg":
        v = build_value(src, ast[1], lookup)
        return -v if is_num(v) else -v
    if kind == "bin":
        return fold(ast[1], build_value(src, ast[2], lookup), build_value(src, ast[3], lookup))
    if kind == "pow":
        base, exp = build_value(src, ast[1], lookup), build_value(src, ast[2], lookup)
        if not is_num(exp):
            raise ParseError(f"{src.path}: exponents must be constants in '^'")
        return float(base**exp) if is_num(base) else base**exp
    if kind == "call":
        return call_function(ast[1], build_value(src, ast[2], lookup))
    if kind == "interval":
        return ast[1] if ast[1] == ast[2] else Expr.uncertain(ast[1], ast[2])
    if kind in ("min", "max"):
        a, b = build_value(src, ast[1], lookup), build_value(src, ast[2], lookup)
        if is_num(a) and is_num(b):
            return float(min(a, b) if kind == "min" else max(a, b))
        return (Expr.minimum if kind == "min" else Expr.maximum)(as_expr(a), as_expr(b))
    if kind == "where":
        holds = condition_of(build_value(src, ast[1], lookup), ast[2], build_value(src, ast[3], lookup))
        then, otherwise = build_value(src, ast[4], lookup), build_value(src, ast[5], lookup)
        if isinstance(holds, bool):
            return then if holds else otherwise
        return Expr.select(holds, as_expr(then), as_expr(otherwise))
    raise AssertionError(kind)


def same_ast(a, b) -> bool:
    """Structural equality ignoring source positions."""
    if a[0] != b[0]:
        return False
    if a[0] == "var":
        return a[1] == b[1]
    if a[0] == "call":
        return a[1] == b[1] and same_ast(a[2], b[2])
    if len(a) != len(b):
        return False
    return all(same_ast(x, y) if isinstance(x, tuple) else x == y for x, y in zip(a[1:], b[1:]))


def as_expr(v) -> Expr:
    return v if isinstance(v, Expr) else Expr.constant(float(v))


def condition_of(lhs, op: str, rhs) -> Union[Condition, bool]:
    """A Condition, or a bool when both sides are constants."""
    if is_num(lhs) and is_num(rhs):
        return {"<=": lhs <= rhs, ">=": lhs >= rhs, "<": lhs < rhs, ">": lhs > rhs}[op]
    lhs = as_expr(lhs)
    return {"<=": lhs <= rhs, ">=": lhs >= rhs, "<": lhs < rhs, ">": lhs > rhs}[op]


def select_where(conds: list, then, otherwise):
    """``then`` where every condition holds, else ``otherwise`` (a conjunction as nested where)."""
    value = then
    for c in reversed(conds):
        if c is True:
            continue
        if c is False:
            return otherwise
        if value is otherwise:
            continue
        value = Expr.select(c, as_expr(value), as_expr(otherwise))
    return value


def compare(lv, op: str, rv) -> bool:
    d = lv - rv
    tol = TOL * max(1.0, abs(lv), abs(rv))
    return {"<=": d <= tol, ">=": d >= -tol, "<": d < tol, ">": d > -tol, "=": abs(d) <= tol}[op]


def timer_equal(a, b) -> bool:
    if isinstance(a, Relative) or isinstance(b, Relative):
        return a == b
    return abs(a - b) <= TOL * max(1.0, abs(a))


def evaluate_floats(values: list, columns: dict) -> np.ndarray:
    exprs = [as_expr(v) for v in values]
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 1
    pts = np.column_stack([np.asarray(columns[k], float) for k in names]) if names else np.zeros((n, 0))
    return _core.eval_float(exprs, names, np.ascontiguousarray(pts))


def order_key(variables: list):
    index = {v: i for i, v in enumerate(variables)}
    return lambda n: (index.get(n, len(index)), n)
