"""Conditions of a translated property: constraint atoms compared, negated and combined.

Atoms are the reader's ``(lhs AST, op, rhs AST, position)``; conditions are percver
``Condition`` objects (or ``True``/``False`` when both sides are constants).
"""

from __future__ import annotations

from typing import Optional

from percver.errors import ParseError
from percver.expr import Condition, Expr
from percver.formats.flowstar_syntax import AutomatonJump
from percver.translation.values import condition_of, evaluate_floats, same_ast


def dedupe(conds: list) -> list:
    out = []
    for c in conds:
        if c is True:
            continue
        if c is False:
            return [False]
        if not any(c is d or repr(c) == repr(d) for d in out):
            out.append(c)
    return out


def dedupe_atoms(atoms: list) -> list:
    out = []
    for a in atoms:
        if not any(same_ast(a[0], b[0]) and a[1] == b[1] and same_ast(a[2], b[2]) for b in out):
            out.append(a)
    return out


def complementary(a, b) -> bool:
    """``x >= c`` and ``x <= c`` (same sides, opposite directions)."""
    flips = {("<=", ">="), (">=", "<="), ("<", ">="), (">=", "<"), (">", "<="), ("<=", ">")}
    return same_ast(a[0], b[0]) and same_ast(a[2], b[2]) and (a[1], b[1]) in flips


def implies(a, b) -> bool:
    """Does atom a (``x <= c1``) imply atom b (``x <= c2``)?  Decided for constant right sides."""
    if not same_ast(a[0], b[0]) or a[1] not in ("<=", "<", ">=", ">") or b[1] not in ("<=", "<", ">=", ">"):
        return False
    if a[1][0] != b[1][0]:
        return False
    ca, cb = const_ast(a[2]), const_ast(b[2])
    if ca is None or cb is None:
        return same_ast(a[2], b[2]) and (a[1] == b[1] or len(a[1]) == 1)
    return ca <= cb if a[1][0] == "<" else ca >= cb


def const_ast(ast) -> Optional[float]:
    if ast[0] == "num":
        return ast[1]
    if ast[0] == "neg" and ast[1][0] == "num":
        return -ast[1][1]
    return None


def atom_text(a) -> str:
    def t(x):
        if x[0] == "num":
            return repr(x[1])
        if x[0] == "var":
            return x[1]
        return "(...)"

    return f"{t(a[0])} {a[1]} {t(a[2])}"


def negate(conds: list, src, jump: Optional[AutomatonJump]) -> Condition:
    """The complement of an unsafe conjunction: one flipped comparison, or min(g_i) < 0."""
    conds = [c for c in conds if c is not True]
    if not conds or any(c is False for c in conds):
        where = f"jump {jump.src} -> {jump.dst} (line {src.line(jump.pos)})" if jump else "an obligation"
        if not conds:
            raise ParseError(f"{src.path}: {where} is unsafe for every state; the property can never hold")
        raise ParseError(f"{src.path}: {where} can never fire; remove it")
    if len(conds) == 1:
        c = conds[0]
        flip = {"<=": ">", "<": ">=", ">=": "<", ">": "<="}[c.op]
        return condition_of(c.lhs, flip, c.rhs)
    gs = []
    for c in conds:
        m = c.margin()
        gs.append(m if c.op in (">=", ">") else -m)
    g = gs[0]
    for other in gs[1:]:
        g = min2(g, other)
    return g < 0.0


def max2(a, b):
    return (a + b + Expr.apply("abs", a - b)) * 0.5


def min2(a, b):
    return (a + b - Expr.apply("abs", a - b)) * 0.5


def all_of(conds: list) -> Condition:
    """One strict condition equivalent to the conjunction of strict comparisons: two bounds on
    one expression become ((e - c) / r)^2 < 1 (polynomial, so its range stays tight), the rest
    are combined by max."""
    bounds: dict = {}
    margins = []
    for c in conds:
        rhs = c.rhs
        if rhs.variables() or c.op not in ("<", ">"):
            margins.append(c.margin() if c.op in ("<", "<=") else -c.margin())
            continue
        value = float(evaluate_floats([rhs], {})[0, 0])
        bounds.setdefault(repr(c.lhs), (c.lhs, [], []))[1 if c.op == "<" else 2].append(value)
    for e, highs, lows in bounds.values():
        if len(highs) == 1 and len(lows) == 1 and lows[0] < highs[0]:
            centre, radius = 0.5 * (lows[0] + highs[0]), 0.5 * (highs[0] - lows[0])
            margins.append(((e - centre) * (1.0 / radius)) ** 2 - 1.0)
        else:
            margins += [e - h for h in highs] + [lo - e for lo in lows]
    m = margins[0]
    for other in margins[1:]:
        m = max2(m, other)
    return m < 0.0
