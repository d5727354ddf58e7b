"""Flow* model syntax: the one tokenizer and parser behind every Flow* reader and writer.

:mod:`percver.formats.flowstar` (continuous and hybrid models), :mod:`percver.formats.verisig`
(Verisig 2.0 models) and :mod:`percver.formats.flowstar_export` (which prints with :func:`text`
what :meth:`Parser.expression` reads back) share it, so a file means one thing to all of them.
Expressions are the grammar of the Rust core's ``taylor::parser`` (``pv.parse``); the tests
check the two agree. Loosest first::

    expression := term (('+' | '-') term)*
    term       := unary (('*' | '/') unary)*
    unary      := ('-' | '+') unary | power          # -x^2 is -(x^2), as in Flow*
    power      := atom ['^' signed-number]            # no chains: x^2^3 is refused
    atom       := number | name | name '(' arguments ')' | '(' expression ')'
                | '[' signed-number ',' signed-number ']'
    number     := digits ['.' digits] [('e'|'E') ['+'|'-'] digits] | '.' digits

Functions: those of :data:`FUNCTIONS`, ``min(a, b)``, ``max(a, b)``, ``clip(x, lo, hi)`` (read
as ``min(max(x, lo), hi)``) and ``where(lhs cmp rhs, then, otherwise)`` (percver's printed
piecewise form). Expressions are ASTs of tuples, with file positions where errors point::

    ("num", value) ("var", name, pos) ("neg", a) ("bin", op, a, b) ("pow", base, ("num", k))
    ("call", function, a, pos) ("min", a, b) ("max", a, b) ("where", lhs, cmp, rhs, then, otherwise)
    ("interval", lo, hi)

A model file is ``continuous reachability { state var ...  setting { ... }  <ode> { x' = ... }
init { x in [lo, hi] ... } }`` or ``hybrid reachability { state var ...  setting { ... }  modes
{ ... }  jumps { ... }  init { mode { ... } } }``, either followed by an optional ``unsafe``
block; :func:`parse` gives a :class:`ContinuousModel` or an :class:`Automaton`. Every error is a
:class:`percver.ParseError` naming file, line and column.
"""

from __future__ import annotations

import bisect
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

from percver.errors import MissingFileError, ParseError

__all__ = [
    "FUNCTIONS",
    "Source",
    "Parser",
    "Settings",
    "ast_variables",
    "position_of",
    "AutomatonMode",
    "AutomatonJump",
    "Automaton",
    "ContinuousModel",
    "model_kind",
    "parse",
    "parse_expression",
    "text",
    "to_expr",
]

# Function names (aliases included) -> the core's names (taylor::functions::Func::from_name).
FUNCTIONS = {
    "exp": "exp",
    "log": "log",
    "ln": "log",
    "sqrt": "sqrt",
    "sin": "sin",
    "cos": "cos",
    "tan": "tan",
    "atan": "atan",
    "arctan": "atan",
    "tanh": "tanh",
    "sigmoid": "sigmoid",
    "abs": "abs",
}
_COMPARISONS = ("<=", ">=", "<", ">")
_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TOKEN = re.compile(rf"\s*(?:(?P<num>{_NUMBER})|(?P<id>[A-Za-z_][A-Za-z0-9_]*)|(?P<op>:=|->|<=|>=|==|[-+*/^()\[\],:'=<>{{}}]))", re.ASCII)
_END = "the end of the block"
_SPACE = re.compile(r"\s*")


class Source:
    """A file's text, comments blanked (positions stay the file's), and its line starts."""

    def __init__(self, path: str, text: str):
        self.path = path
        self.text = re.sub(r"#[^\n]*", lambda m: " " * len(m.group(0)), text)
        self._starts = [0] + [m.end() for m in re.finditer("\n", self.text)]

    @classmethod
    def read(cls, path, what: str) -> "Source":
        """The file at ``path``; ``what`` names it in the error when it does not exist."""
        p = Path(path)
        if not p.exists():
            raise MissingFileError(f"{what} '{path}' does not exist")
        return cls(str(p), p.read_text())

    def line(self, pos: int) -> int:
        return bisect.bisect_right(self._starts, pos)

    def column(self, pos: int) -> int:
        return pos - self._starts[self.line(pos) - 1] + 1

    def where(self, pos: int) -> str:
        return f"{self.path}, line {self.line(pos)}, column {self.column(pos)}"

    def error(self, pos: int, message: str) -> ParseError:
        return ParseError(f"{self.where(pos)}: {message}")


# ----------------------------------------------------------------------------- tokens and expressions


class Parser:
    """The tokens of ``src.text`` from ``start``, read on demand (text after a model's end is
    never tokenized, so a stray brace there warns instead of failing), and the grammar."""

    def __init__(self, src: Source, start: int = 0):
        self.src = src
        self._scan = start
        self._ahead: list = []  # (kind, text, position) read but not consumed
        self.consumed = self.before = start  # where the last token read ends, and the one before it

    def _fill(self, n: int) -> bool:
        text = self.src.text
        while len(self._ahead) < n:
            m = _TOKEN.match(text, self._scan)
            if m is None:
                bad = _SPACE.match(text, self._scan).end()
                if bad == len(text):
                    return False
                raise self.src.error(bad, f"unexpected character '{text[bad]}'")
            kind = m.lastgroup
            self._ahead.append((kind, m.group(kind), m.start(kind)))
            self._scan = m.end()
        return True

    def peek(self, k: int = 0) -> tuple:
        return self._ahead[k] if self._fill(k + 1) else ("end", "", self._scan)

    def next(self) -> tuple:
        tok = self.peek()
        if self._ahead:
            self._ahead.pop(0)
            self.before, self.consumed = self.consumed, tok[2] + len(tok[1])
        return tok

    def at_end(self) -> bool:
        return not self._fill(1)

    def at(self, *words: str) -> bool:
        """Whether the next tokens are ``words`` (keywords or symbols, not numbers)."""
        return all(self.peek(k)[1] == w and self.peek(k)[0] != "num" for k, w in enumerate(words))

    def accept(self, *words: str) -> bool:
        if not self.at(*words):
            return False
        for _ in words:
            self.next()
        return True

    def offset(self) -> int:
        """Where the next token starts (the end of the text at its end)."""
        return self.peek()[2]

    def fail(self, tok: tuple, expected: str) -> ParseError:
        """``expected ..., found ...`` at ``tok``, or where the line before it ends when ``tok``
        starts a later line (``x' = -x +`` is wrong at its end, not at the next line's brace)."""
        prior = self.before if tok[2] < self.consumed else self.consumed
        pos = prior if self.src.line(tok[2]) > self.src.line(prior) else tok[2]
        return self.src.error(pos, f"expected {expected}, found '{tok[1] or _END}'")

    def expect(self, value: str, what: str = "") -> tuple:
        tok = self.next()
        if tok[1] != value or tok[0] == "num":
            raise self.fail(tok, f"'{value}'{' ' + what if what else ''}")
        return tok

    def ident(self, what: str) -> tuple:
        tok = self.next()
        if tok[0] != "id":
            raise self.fail(tok, what)
        return tok

    def number(self, what: str) -> float:
        """A number with an optional sign."""
        negative = self.accept("-")
        if not negative:
            self.accept("+")
        tok = self.next()
        if tok[0] != "num":
            raise self.fail(tok, f"a number for {what}")
        return -self._float(tok) if negative else self._float(tok)

    def integer(self, what: str) -> int:
        tok = self.next()
        if tok[0] != "num" or not tok[1].isdigit():
            raise self.fail(tok, f"a whole number for {what}")
        return int(tok[1])

    def bounds(self, what: str) -> tuple:
        """``[lo, hi]`` with lo <= hi."""
        at = self.expect("[", f"opening {what} [lo, hi]")[2]
        lo = self.number("an interval bound")
        self.expect(",", "in an interval [lo, hi]")
        hi = self.number("an interval bound")
        self.expect("]", "closing an interval [lo, hi]")
        if not lo <= hi:
            raise self.src.error(at, f"empty interval [{lo}, {hi}] for {what}: write the smaller bound first")
        return lo, hi

    def rest_of_line(self) -> str:
        """The text from the next token to the end of its line or a closing brace, skipped
        (settings Flow* reads and percver does not need are kept as text)."""
        text = self.src.text
        start = self._ahead[0][2] if self._ahead else _SPACE.match(text, self._scan).end()
        end = min(i for i in (text.find("\n", start), text.find("}", start), len(text)) if i >= 0)
        self._ahead, self._scan = [], end
        return text[start:end].strip()

    def _float(self, tok: tuple) -> float:
        value = float(tok[1])
        if not math.isfinite(value):
            raise self.src.error(tok[2], f"number '{tok[1]}' overflows to infinity; expressions take finite numbers only")
        return value

    def expression(self) -> tuple:
        return self._left(("+", "-"), self._term)

    def _term(self) -> tuple:
        return self._left(("*", "/"), self._unary)

    def _left(self, ops: tuple, operand) -> tuple:
        """``operand (op operand)*`` for ``ops``, nested to the left (``x - y - 1`` is ``(x - y) - 1``)."""
        node = operand()
        while self.peek()[0] == "op" and self.peek()[1] in ops:
            op = self.next()[1]
            node = ("bin", op, node, operand())
        return node

    def _unary(self) -> tuple:
        if self.peek()[0] == "op" and self.peek()[1] in ("-", "+"):
            op = self.next()[1]
            inner = self._unary()
            return ("neg", inner) if op == "-" else inner
        return self._power()

    def _power(self) -> tuple:
        base = self._atom()
        if not self.accept("^"):
            return base
        exponent = self.number("the exponent after '^' (exponents are constant numbers)")
        if self.at("^"):
            raise self.src.error(self.offset(), "chained '^' is ambiguous; add parentheses")
        return ("pow", base, ("num", exponent))

    def _atom(self) -> tuple:
        if self.at("["):
            return ("interval", *self.bounds("an interval constant"))
        tok = self.next()
        kind, name, pos = tok
        if kind == "num":
            return ("num", self._float(tok))
        if kind == "id":
            return self._call(name, pos) if self.accept("(") else ("var", name, pos)
        if name == "(" and kind == "op":
            inner = self.expression()
            self.expect(")", "closing '('")
            return inner
        raise self.fail(tok, "an expression")

    def _call(self, name: str, pos: int) -> tuple:
        if name == "where":  # where(lhs cmp rhs, then, otherwise)
            lhs = self.expression()
            cmp = self.next()
            if cmp[1] not in _COMPARISONS or cmp[0] != "op":
                raise self.fail(cmp, "a comparison (<=, >=, <, >) in where(lhs cmp rhs, then, otherwise)")
            rhs = self.expression()
            self.expect(",", "after the condition of where(...)")
            then = self.expression()
            self.expect(",", "after the first value of where(...)")
            otherwise = self.expression()
            self.expect(")", "closing where(")
            return ("where", lhs, cmp[1], rhs, then, otherwise)
        arity = {"min": 2, "max": 2, "clip": 3}.get(name, 1)
        if arity == 1 and name not in FUNCTIONS:
            known = ", ".join([*sorted(set(FUNCTIONS)), "min", "max", "clip", "where"])
            raise self.src.error(pos, f"unknown function '{name}' (known: {known})")
        args = [self.expression()]
        while self.accept(","):
            args.append(self.expression())
        self.expect(")", f"closing {name}(")
        if len(args) != arity:
            raise self.src.error(pos, f"{name} takes {arity} argument(s), got {len(args)}")
        if name == "clip":
            return ("min", ("max", args[0], args[1]), args[2])
        if name in ("min", "max"):
            return (name, *args)
        return ("call", FUNCTIONS[name], args[0], pos)

    def constraints(self) -> list:
        """``e1 <= e2``, ``e1 >= e2``, ``e1 < e2``, ``e1 > e2``, ``e1 = e2`` or ``e in [a, b]`` up to
        '}' (not consumed), as (lhs, op, rhs, position) atoms."""
        out = []
        while not self.at_end() and not self.at("}"):
            pos = self.offset()
            lhs = self.expression()
            kind, op, opos = self.next()
            if op == "in" and kind == "id":
                lo, hi = self.bounds("'in'")
                out += [(lhs, ">=", ("num", lo), pos), (lhs, "<=", ("num", hi), pos)]
                continue
            if op not in (*_COMPARISONS, "=", "==") or kind != "op":
                raise self.src.error(opos, f"expected a comparison (<=, >=, =) in a constraint, found '{op or _END}'")
            out.append((lhs, "=" if op == "==" else op, self.expression(), pos))
        return out

    def block(self, what: str) -> None:
        """Opens a ``{ ... }`` block; :meth:`close` ends it."""
        self.expect("{", f"opening {what}")

    def close(self, what: str) -> None:
        self.expect("}", f"closing {what}")


def parse_expression(text: str, what: str = "expression") -> tuple:
    """The AST of one expression; ``what`` names it in errors."""
    parser = Parser(Source(what, text))
    if parser.at_end():
        raise parser.src.error(0, "empty expression")
    ast = parser.expression()
    if not parser.at_end():
        raise parser.src.error(parser.offset(), f"unexpected '{parser.peek()[1]}' after the expression")
    return ast


def _num(x: float) -> str:
    """A float that reads back exactly."""
    return repr(float(x))


def text(ast: tuple) -> str:
    """Flow* text of an AST, fully parenthesised: :func:`parse_expression` reads it back."""
    kind = ast[0]
    if kind == "num":
        return _num(ast[1]) if ast[1] >= 0 else f"({_num(ast[1])})"
    if kind == "var":
        return ast[1]
    if kind == "neg":
        return f"(-{text(ast[1])})"
    if kind == "bin":
        return f"({text(ast[2])} {ast[1]} {text(ast[3])})"
    if kind == "pow":
        k = ast[2][1]
        return f"({text(ast[1])}^{int(k) if k == int(k) else _num(k)})"
    if kind == "call":
        return f"{ast[1]}({text(ast[2])})"
    if kind in ("min", "max"):
        return f"{kind}({text(ast[1])}, {text(ast[2])})"
    if kind == "where":
        return f"where({text(ast[1])} {ast[2]} {text(ast[3])}, {text(ast[4])}, {text(ast[5])})"
    if kind == "interval":
        return f"[{_num(ast[1])}, {_num(ast[2])}]"
    raise ValueError(f"not an expression AST: {ast!r}")


def to_expr(ast: tuple):
    """The :class:`percver.Expr` of an AST. Long sums are left-nested: their left spine is walked
    in a loop (one recursion per term would exceed Python's limit on a 600-input layer)."""
    from percver.expr import Expr

    spine = []
    while ast[0] == "bin":
        spine.append(ast)
        ast = ast[2]
    kind = ast[0]
    if kind == "num":
        value = Expr.constant(ast[1])
    elif kind == "var":
        value = Expr.var(ast[1])
    elif kind == "neg":
        value = -to_expr(ast[1])
    elif kind == "pow":
        value = to_expr(ast[1]) ** ast[2][1]
    elif kind == "call":
        value = Expr.apply(ast[1], to_expr(ast[2]))
    elif kind in ("min", "max"):
        value = (Expr.minimum if kind == "min" else Expr.maximum)(to_expr(ast[1]), to_expr(ast[2]))
    elif kind == "where":
        lhs, rhs = to_expr(ast[1]), to_expr(ast[3])
        condition = {"<=": lhs <= rhs, ">=": lhs >= rhs, "<": lhs < rhs, ">": lhs > rhs}[ast[2]]
        value = Expr.select(condition, to_expr(ast[4]), to_expr(ast[5]))
    elif kind == "interval":
        value = Expr.uncertain(ast[1], ast[2])
    else:
        raise ValueError(f"not an expression AST: {ast!r}")
    for node in reversed(spine):
        right = to_expr(node[3])
        value = {"+": value.__add__, "-": value.__sub__, "*": value.__mul__, "/": value.__truediv__}[node[1]](right)
    return value


# ----------------------------------------------------------------------------- settings


@dataclass
class Settings:
    """A setting block: what percver uses, and every line as (key, text, position), ``key``
    naming what it sets, ``"display"`` for output and plotting lines, None when unsupported."""

    time: Optional[float] = None
    max_jumps: Optional[int] = None
    step: object = None  # float, or (min, max) for adaptive steps
    order: object = None  # int, or (min, max) for adaptive orders
    remainder: object = None  # one estimate, or {variable: estimate}
    precondition: str = "identity"
    cutoff: float = 1e-10
    lines: list = field(default_factory=list)
    pos: int = 0  # where the block starts

    def remainders(self, variables: list) -> list:
        """The remainder estimate of each variable (1e-4 where the file gives none)."""
        if isinstance(self.remainder, dict):
            return [self.remainder.get(v, 1e-4) for v in variables]
        return [1e-4 if self.remainder is None else self.remainder] * len(variables)

    def unused(self, *keys: str) -> list:
        """The text of every line except those setting ``keys``."""
        return [t for k, t, _ in self.lines if k not in keys]


_DISPLAY = {"gnuplot", "matlab", "output", "print", "precision"}


def _orders(p: Parser) -> int:
    """``N`` or ``{ x: N, y: M }`` (one order for all variables: the largest)."""
    if not p.accept("{"):
        return p.integer("an order")
    found = []
    while not p.accept("}"):
        if found:
            p.expect(",", "between orders")
        p.ident("a variable name")
        p.expect(":")
        found.append(p.integer("an order"))
    return max(found)


def _setting(p: Parser, s: Settings) -> Optional[str]:
    """Reads one setting into ``s``; returns its key."""
    if p.accept("fixed", "steps"):
        s.step = p.number("the step")
        return "step"
    if p.accept("adaptive", "steps"):
        p.expect("{"), p.expect("min")
        lo = p.number("the smallest step")
        p.expect(","), p.expect("max")
        s.step = (lo, p.number("the largest step"))
        p.expect("}", "closing the adaptive steps")
        return "step"
    if p.accept("time"):
        s.time = p.number("the time horizon")
        return "time"
    if p.accept("max", "jumps"):
        s.max_jumps = p.integer("max jumps")
        return "max_jumps"
    if p.accept("remainder", "estimation"):
        if not p.accept("{"):
            s.remainder = p.number("the remainder estimate")
            return "remainder"
        s.remainder = {}
        while not p.accept("}"):
            if s.remainder:
                p.expect(",", "between remainder estimates")
            v = p.ident("a variable name")[1]
            p.expect(":")
            lo, hi = p.bounds(f"the remainder estimate of '{v}'")
            s.remainder[v] = max(abs(lo), abs(hi))
        return "remainder"
    if p.accept("QR", "precondition") or p.accept("identity", "precondition"):
        # Flow* 2.1.0 parses 'QR' but never calls its QR code (FLOWSTAR-NOTES §4): both
        # keywords run translate-and-scale, which is our "identity".
        s.precondition = "identity"
        return "precondition"
    if p.accept("fixed", "orders") or p.accept("fixed", "order"):
        s.order = _orders(p)
        return "order"
    if p.accept("adaptive", "orders"):
        p.expect("{"), p.expect("min")
        lo = _orders(p)
        p.expect(","), p.expect("max")
        s.order = (lo, _orders(p))
        p.expect("}", "closing the adaptive orders")
        return "order"
    if p.accept("cutoff"):
        s.cutoff = p.number("the cutoff")
        return "cutoff"
    return "display" if p.peek()[1] in _DISPLAY or p.at("no", "output") or p.at("tm", "output") else None


def _settings(p: Parser) -> Settings:
    s = Settings()
    while not p.at("}") and not p.at_end():
        start = p.offset()
        key = _setting(p, s)
        if key in ("display", None):
            line = p.rest_of_line()
        else:
            line = p.src.text[start : p.consumed]
        s.lines.append((key, line, start))
    return s


# ----------------------------------------------------------------------------- models


@dataclass
class AutomatonMode:
    name: str
    pos: int
    ode: dict  # variable -> AST
    inv: list  # constraints


@dataclass
class AutomatonJump:
    src: str
    dst: str
    pos: int
    guard: list  # constraints
    reset: dict  # variable -> AST


@dataclass
class Automaton:
    """A ``hybrid reachability`` file as written: nothing interpreted."""

    src: Source
    variables: list
    settings: Settings
    modes: dict
    jumps: list
    init_mode: str
    init: dict  # variable -> (lo, hi)
    init_pos: int
    unsafe: dict  # mode -> (constraints, position)
    notes: list


@dataclass
class ContinuousModel:
    """A ``continuous reachability`` file as written."""

    src: Source
    variables: list
    settings: Settings
    ode_kind: str  # "nonpoly ode", "poly ode N", "linear ode"
    ode_pos: int
    symbolic_queue: Optional[int]  # the N of 'nonpoly ode { N }'
    odes: dict  # variable -> (AST, its text)
    init: dict  # variable -> (lo, hi)
    init_pos: int
    unsafe: list  # constraints
    notes: list


_ODES = ("nonpoly", "poly", "linear")


def _ode_kind(p: Parser, where: str) -> tuple:
    """``nonpoly ode``, ``poly ode N`` or ``linear ode``, and ``{ N }`` (a queue size) if given."""
    kind, word, pos = p.next()
    if word in ("lti", "ltv") and p.at("ode"):
        raise p.src.error(pos, f"{where}'{word} ode' dynamics are not supported; write them as 'nonpoly ode'")
    if word not in _ODES or kind != "id":
        raise p.fail((kind, word, pos), "'nonpoly ode { ... }', 'poly ode N { ... }' or 'linear ode { ... }'")
    p.expect("ode", f"after '{word}'")
    name = f"{word} ode"
    if word == "poly" and p.peek()[0] == "num":
        name += f" {p.next()[1]}"
    queue = None
    if p.at("{") and p.peek(1)[0] == "num" and p.peek(2)[1] == "}":
        p.next()
        queue = p.integer("the symbolic remainder queue")
        p.next()
    return name, queue


def _assignments(p: Parser, variables: list, op: str, what: str) -> dict:
    """``x' <op> expression`` up to the closing brace: ODEs (``=``) or resets (``:=``), each as
    (AST, text); ``what`` starts the message for an undeclared variable."""
    out = {}
    while not p.at("}") and not p.at_end():
        v, vpos = p.ident(f'"x\' {op} expression"')[1:]
        if v not in variables:
            raise p.src.error(vpos, f"{what} undeclared variable '{v}' (state var: {', '.join(variables)})")
        p.expect("'", f"after '{v}' in \"{v}' {op} ...\"")
        p.expect(op, f'in "{v}\' {op} ..."')
        start = p.offset()
        ast = p.expression()
        out[v] = (ast, p.src.text[start : p.consumed])
    return out


def _state_var(p: Parser) -> list:
    if not p.accept("state", "var"):
        raise p.fail(p.peek(), "'state var x, y, ...' first in the model")
    names = [p.ident("a variable name after 'state var'")[1]]
    while p.accept(","):
        names.append(p.ident("a variable name after ','")[1])
    return names


def _section(p: Parser, keyword: str) -> None:
    if not p.accept(keyword):
        raise p.fail(p.peek(), f"'{keyword} {{ ... }}'")
    p.block(f"the {keyword} block")


def _setting_block(p: Parser) -> Settings:
    pos = p.offset()
    _section(p, "setting")
    settings = _settings(p)
    settings.pos = pos
    p.close("the setting block")
    return settings


def _modes(p: Parser, variables: list) -> dict:
    _section(p, "modes")
    modes: dict = {}
    while not p.at("}") and not p.at_end():
        name, pos = p.ident("a mode name")[1:]
        if name in modes:
            raise p.src.error(pos, f"mode '{name}' is defined twice")
        p.block(f"mode '{name}'")
        ode: dict = {}
        inv: list = []
        while not p.at("}") and not p.at_end():
            if p.accept("inv"):
                p.block("the invariant")
                inv += p.constraints()
                p.close("the invariant")
                continue
            if p.peek()[1] not in (*_ODES, "lti", "ltv"):
                raise p.fail(p.peek(), f"'nonpoly ode {{...}}' or 'inv {{...}}' in mode '{name}'")
            _ode_kind(p, f"mode '{name}': ")
            p.block("the ODE block")
            ode.update({v: ast for v, (ast, _) in _assignments(p, variables, "=", f"mode '{name}': equation for").items()})
            p.close("the ODE block")
        p.close(f"mode '{name}'")
        modes[name] = AutomatonMode(name, pos, ode, inv)
    if not modes:
        raise p.src.error(p.offset(), "the modes block is empty")
    p.close("the modes block")
    return modes


def _jumps(p: Parser, modes: dict, variables: list) -> list:
    _section(p, "jumps")
    jumps = []
    while not p.at("}") and not p.at_end():
        a, pos = p.ident("a jump 'A -> B'")[1:]
        p.expect("->", f"after '{a}' in a jump")
        b, bpos = p.ident("the target mode of a jump")[1:]
        for name, at in ((a, pos), (b, bpos)):
            if name not in modes:
                raise p.src.error(at, f"jump {a} -> {b}: no mode named '{name}'")
        guard: list = []
        reset: dict = {}
        if p.accept("guard"):
            p.block("the guard")
            guard = p.constraints()
            p.close("the guard")
        if p.accept("reset"):
            p.block("the reset")
            reset = {v: ast for v, (ast, _) in _assignments(p, variables, ":=", f"jump {a} -> {b}: reset of").items()}
            p.close("the reset")
        kind, word, wpos = p.next()
        if word not in ("interval", "parallelotope", "octagon") or kind != "id":
            raise p.src.error(wpos, f"jump {a} -> {b}: expected 'interval aggregation' after the reset, found '{word or _END}'")
        p.expect("aggregation", f"after '{word}'")
        if p.at("{"):  # the aggregation's template directions: not used
            depth = 0
            while True:
                tok = p.next()
                depth += {"{": 1, "}": -1}.get(tok[1], 0)
                if depth == 0 or tok[0] == "end":
                    break
        jumps.append(AutomatonJump(a, b, pos, guard, reset))
    p.close("the jumps block")
    return jumps


def _box(p: Parser, variables: list, where: str) -> dict:
    """``x in [lo, hi]`` up to the closing brace."""
    box: dict = {}
    while not p.at("}") and not p.at_end():
        v, vpos = p.ident("'x in [lo, hi]'")[1:]
        if v not in variables:
            raise p.src.error(vpos, f"{where}: undeclared variable '{v}' (state var: {', '.join(variables)})")
        p.expect("in", f"in '{v} in [lo, hi]'")
        box[v] = p.bounds(f"'{v}'")
    return box


def _unsafe(p: Parser, modes: Optional[dict]) -> object:
    """The optional ``unsafe [set] { ... }`` after a model: per mode for a hybrid one."""
    if not p.accept("unsafe"):
        return {} if modes is not None else []
    p.accept("set")
    p.block("the unsafe block")
    if modes is None:
        found = p.constraints()
    else:
        found = {}
        while not p.at("}") and not p.at_end():
            mode, pos = p.ident("a mode name in the unsafe block")[1:]
            if mode not in modes:
                raise p.src.error(pos, f"unsafe: no mode named '{mode}'")
            p.block(f"the unsafe set of '{mode}'")
            found[mode] = (p.constraints(), pos)
            p.close(f"the unsafe set of '{mode}'")
    p.close("the unsafe block")
    return found


def _trailing(p: Parser) -> list:
    """Flow* runs the analysis when it has read the model and ignores what follows; so do we,
    loudly, so a misplaced brace cannot silently drop a property."""
    if p.at_end():
        return []
    at = p.offset()
    rest = " ".join(p.src.text[at:].split())
    msg = (
        f"{p.src.where(at)}: ignoring '{rest[:40]}...' after the model (Flow* ignores it too: a stray '}}' closed the unsafe block early?)"
    )
    warnings.warn(msg, stacklevel=4)
    return [msg]


def model_kind(src: Source) -> tuple:
    """``"continuous"``, ``"hybrid"`` or None, from the first words of the file, and where."""
    p = Parser(src)
    pos = p.offset()
    for kind in ("continuous", "hybrid"):
        if p.at(kind, "reachability"):
            return kind, pos
    return None, pos


def parse(src: Source) -> Union[ContinuousModel, Automaton]:
    """The model in ``src``: a :class:`ContinuousModel` or an :class:`Automaton`."""
    kind, pos = model_kind(src)
    if kind is None:
        raise src.error(pos, "expected 'continuous reachability { ... }' or 'hybrid reachability { ... }' at the top")
    p = Parser(src)
    p.next(), p.next()
    p.block(f"the {kind} model")
    variables = _state_var(p)
    settings = _setting_block(p)
    if kind == "continuous":
        ode_pos = p.offset()
        if p.peek()[1] not in (*_ODES, "lti", "ltv"):
            raise p.fail(p.peek(), "an ODE block ('poly ode N {...}' or 'nonpoly ode {...}')")
        ode_kind, queue = _ode_kind(p, "")
        p.block("the ODE block")
        odes = _assignments(p, variables, "=", "equation for")
        p.close("the ODE block")
        _section(p, "init")
        init_pos = p.offset()
        init = _box(p, variables, "init")
        p.close("the init block")
        p.close("the continuous model")
        unsafe = _unsafe(p, None)
        return ContinuousModel(src, variables, settings, ode_kind, ode_pos, queue, odes, init, init_pos, unsafe, _trailing(p))
    modes = _modes(p, variables)
    jumps = _jumps(p, modes, variables)
    _section(p, "init")
    init_mode, init_pos = p.ident("the initial mode")[1:]
    if init_mode not in modes:
        raise p.src.error(init_pos, f"init: no mode named '{init_mode}'")
    p.block(f"the initial set of '{init_mode}'")
    init = _box(p, variables, "init")
    p.close(f"the initial set of '{init_mode}'")
    if not p.at("}"):
        raise p.src.error(p.offset(), "init: several initial modes are not supported (give one mode)")
    p.close("the init block")
    if not p.at("}"):
        raise p.src.error(p.offset(), f"unexpected '{p.peek()[1]}' after the init block of the hybrid model")
    p.close("the hybrid model")
    unsafe = _unsafe(p, modes)
    return Automaton(src, variables, settings, modes, jumps, init_mode, init, init_pos, unsafe, _trailing(p))


def ast_variables(ast: tuple) -> set:
    """The variable names an AST reads."""
    if ast[0] == "var":
        return {ast[1]}
    return set().union(*(ast_variables(a) for a in ast[1:] if isinstance(a, tuple)))


def position_of(ast: tuple, name: str) -> Optional[int]:
    """Where the AST first reads the variable ``name`` (None if it does not)."""
    if ast[0] == "var":
        return ast[2] if ast[1] == name else None
    return next((p for a in ast[1:] if isinstance(a, tuple) and (p := position_of(a, name)) is not None), None)
