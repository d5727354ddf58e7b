"""Verisig 2.0 closed-loop models: Flow* ``hybrid reachability`` files with DNN modes.

Verisig encodes one control period as a chain of zero-time modes and jumps: resets compute
helper variables, modes named ``DNN...`` evaluate a network on ``_f1.._fN`` (outputs come back
in ``_f1..``), modes named ``_op_i_j...`` apply ``var_i := op(var_j)`` (op: cos, sin, tan, div
= 1/x, arc = atan, sqrt, sec), ``_reset_`` modes flow for a fixed time with constant dynamics
(a discrete update written as an ODE), and a ``clock`` plus counters (``k``, ``worldtime``)
drive the step structure. :func:`load_verisig` executes that chain symbolically once, so one
period becomes expressions over the true plant states: a ``pv.Discrete`` update when no mode
integrates real dynamics, else a ``pv.Continuous`` plant (the one flowing mode) whose inputs
are computed by the stages. Branching jumps become ``where`` chains, so the step is the same
function Verisig explores branch by branch.

Properties come from the ``unsafe`` block and the jumps into its modes: a guard without
counters is checked at every step (and along the flowpipe for continuous plants); a guard that
fires only at the horizon (``k >= 150``, ``worldtime = 7``) becomes a goal at the final step; an
absorbing mode that ends the run early (Mountain Car's goal mode) becomes a ``within`` goal.
Like Flow*, no flow starts at the time horizon, so guards holding only from then on never fire.

Assumptions (true of Verisig's generated models; anything else is refused or noted):
- jumps leaving one mode have exclusive guards up to their boundaries; on a boundary the
  ``where`` takes the branch tested first (Verisig takes both: a measure-zero difference), and
  two jumps without state guards leaving one mode together are refused;
- a guard on a single path is not tested and state invariants are ignored: both keep runs
  Verisig would block, an over-approximation;
- jumps out of a flowing mode fire at the end of its dwell (``clock = c``);
- a continuous plant cannot jump: a branch resetting plant states is dropped and "its guard
  never holds" becomes a safety obligation (F1/10's corridor rotation at ``y1 >= 20``).
"""

from __future__ import annotations

import bisect
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import MissingFileError, ParseError
from percver.expr import Condition, Expr
from percver.formats.flowstar import _block
from percver.systems import ClosedLoop, Continuous, Discrete, Hybrid, Jump, Mode, Stage

__all__ = ["load_verisig", "VerisigProblem"]

_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TOKEN = re.compile(rf"\s*(?:(?P<num>{_NUMBER})|(?P<id>[A-Za-z_]\w*)|(?P<op>:=|->|<=|>=|==|[-+*/^()\[\],'=<>{{}}]))")
_FUNCTIONS = {"sin", "cos", "tan", "atan", "exp", "log", "sqrt", "tanh", "sigmoid", "abs"}
# Verisig's function modes: ``_op_i_j...`` sets state var i to op(state var j) on entry.
_SPECIAL = re.compile(r"_(cos|sin|tan|div|arc|sqrt|sec)_(\d+)_(\d+)(?:_|$)")
_TOL = 1e-9
_START = "<start>"  # the period's first mode, distinct from the same mode as its end


# ----------------------------------------------------------------------------- source text


class _Source:
    """The file's text and its line starts, so every message names file and line."""

    def __init__(self, path: str, text: str):
        self.path = path
        self.text = text
        self.newlines = [m.start() for m in re.finditer("\n", text)]

    def line(self, pos: int) -> int:
        return bisect.bisect_left(self.newlines, pos) + 1

    def error(self, pos: int, message: str) -> ParseError:
        return ParseError(f"{self.path}, line {self.line(pos)}: {message}")


class _Tokens:
    """Tokens of one section (offset ``base`` in the file) with a cursor."""

    def __init__(self, src: _Source, text: str, base: int):
        self.src = src
        self.items: list = []  # (kind, text, absolute position)
        pos = 0
        n = len(text)
        while pos < n:
            m = _TOKEN.match(text, pos)
            if m is None or m.end() == pos:
                if text[pos:].strip() == "":
                    break
                bad = pos + len(text[pos:]) - len(text[pos:].lstrip())
                raise src.error(base + bad, f"unexpected character '{text[bad]}'")
            kind = m.lastgroup
            if kind is None:  # trailing whitespace only
                break
            self.items.append((kind, m.group(kind), base + m.start(kind)))
            pos = m.end()
        self.i = 0
        self.end_pos = base + len(text)

    def peek(self, k: int = 0):
        j = self.i + k
        return self.items[j] if j < len(self.items) else ("end", "", self.end_pos)

    def next(self):
        tok = self.peek()
        self.i += 1
        return tok

    def at_end(self) -> bool:
        return self.i >= len(self.items)

    def expect(self, value: str, what: str = ""):
        tok = self.next()
        if tok[1] != value:
            found = tok[1] or "the end of the block"
            raise self.src.error(tok[2], f"expected '{value}'{' ' + what if what else ''}, found '{found}'")
        return tok

    def ident(self, what: str):
        tok = self.next()
        if tok[0] != "id":
            raise self.src.error(tok[2], f"expected {what}, found '{tok[1] or 'the end of the block'}'")
        return tok

    def number(self, what: str) -> float:
        tok = self.next()
        sign = 1.0
        if tok[1] in "+-" and tok[0] == "op":
            sign = -1.0 if tok[1] == "-" else 1.0
            tok = self.next()
        if tok[0] != "num":
            raise self.src.error(tok[2], f"expected a number for {what}, found '{tok[1]}'")
        return sign * float(tok[1])

    # Expressions: Flow* precedence (^ binds tighter than unary minus, right-associative).
    def expr(self):
        node = self.term()
        while self.peek()[0] == "op" and self.peek()[1] in "+-" and self.peek()[1]:
            op = self.next()[1]
            node = ("bin", op, node, self.term())
        return node

    def term(self):
        node = self.unary()
        while self.peek()[0] == "op" and self.peek()[1] in ("*", "/"):
            op = self.next()[1]
            node = ("bin", op, node, self.unary())
        return node

    def unary(self):
        if self.peek()[0] == "op" and self.peek()[1] in ("-", "+"):
            op = self.next()[1]
            inner = self.unary()
            return ("neg", inner) if op == "-" else inner
        return self.power()

    def power(self):
        base = self.atom()
        if self.peek()[0] == "op" and self.peek()[1] == "^":
            self.next()
            return ("pow", base, self.unary())
        return base

    def atom(self):
        kind, text, pos = self.next()
        if kind == "num":
            return ("num", float(text))
        if kind == "id":
            if self.peek()[1] == "(" and text in _FUNCTIONS:
                self.next()
                inner = self.expr()
                self.expect(")", f"closing {text}(")
                return ("call", text, inner, pos)
            if self.peek()[1] == "(":
                raise self.src.error(pos, f"unknown function '{text}' (supported: {', '.join(sorted(_FUNCTIONS))})")
            return ("var", text, pos)
        if text == "(":
            inner = self.expr()
            self.expect(")")
            return inner
        if text == "[":
            lo = self.number("an interval bound")
            self.expect(",", "in an interval [lo, hi]")
            hi = self.number("an interval bound")
            self.expect("]")
            return ("interval", lo, hi)
        raise self.src.error(pos, f"expected an expression, found '{text or 'the end of the block'}'")

    def atoms(self) -> list:
        """Constraints ``e1 <= e2``, ``e1 >= e2``, ``e1 = e2`` or ``e in [a, b]`` up to '}' (not consumed)."""
        out = []
        while not self.at_end() and self.peek()[1] != "}":
            pos = self.peek()[2]
            lhs = self.expr()
            kind, op, opos = self.next()
            if op == "in" and kind == "id":
                self.expect("[")
                lo = self.number("an interval bound")
                self.expect(",")
                hi = self.number("an interval bound")
                self.expect("]")
                out += [(lhs, ">=", ("num", lo), pos), (lhs, "<=", ("num", hi), pos)]
                continue
            if op not in ("<=", ">=", "=", "==", "<", ">"):
                raise self.src.error(opos, f"expected a comparison (<=, >=, =) in a constraint, found '{op}'")
            out.append((lhs, "=" if op == "==" else op, self.expr(), pos))
        return out


# ----------------------------------------------------------------------------- model structure


@dataclass
class _Mode:
    name: str
    pos: int
    ode: dict  # var -> ast
    inv: list  # atoms


@dataclass
class _Jump:
    src: str
    dst: str
    pos: int
    guard: list
    reset: dict  # var -> ast


@dataclass
class _Automaton:
    src: _Source
    variables: list
    settings: dict
    modes: dict
    jumps: list
    init_mode: str
    init: dict  # var -> (lo, hi)
    init_pos: int
    unsafe: dict  # mode -> (atoms, pos)
    notes: list


def _match_at(pattern: str, text: str, pos: int):
    return re.compile(r"\s*" + pattern).match(text, pos)


def _section(src: _Source, text: str, pos: int, keyword: str):
    """``keyword { ... }`` at ``pos``: (inner text, absolute start of inner text, index after)."""
    m = _match_at(keyword, text, pos)
    if not m:
        found = text[pos:].strip().split("\n", 1)[0][:40] or "the end of the file"
        raise src.error(
            pos + len(text[pos:]) - len(text[pos:].lstrip()),
            f"expected '{keyword.replace(chr(92) + 's+', ' ')} {{ ... }}', found '{found}'",
        )
    inner, end = _block(text, m.end(), src.path)
    return inner, text.index("{", m.end()) + 1, end


def _parse(path: str) -> _Automaton:
    p = Path(path)
    if not p.exists():
        raise MissingFileError(f"Verisig model '{path}' does not exist")
    raw = p.read_text()
    # Comments become spaces so positions (and line numbers) stay those of the file.
    text = re.sub(r"#[^\n]*", lambda m: " " * len(m.group(0)), raw)
    src = _Source(str(p), text)
    notes: list = []
    m = _match_at(r"hybrid\s+reachability", text, 0)
    if not m:
        if re.match(r"\s*continuous\s+reachability", text):
            raise src.error(
                0, "a continuous model: read it with percver.formats.load_flowstar; load_verisig needs 'hybrid reachability' with DNN modes"
            )
        raise src.error(0, "expected 'hybrid reachability { ... }' at the top (a Verisig/Flow* hybrid model)")
    body_at = text.index("{", m.end()) + 1
    _, after = _block(text, m.end(), src.path)
    sv = _match_at(r"state\s+var\s+([^\n]+)", text, body_at)
    if not sv:
        raise src.error(body_at, "expected 'state var x, y, ...' first in the hybrid model")
    variables = [v.strip() for v in sv.group(1).split(",") if v.strip()]
    for v in variables:
        if not re.fullmatch(r"[A-Za-z_]\w*", v):
            raise src.error(sv.start(1), f"'{v}' is not a variable name")
    settings_text, settings_at, pos = _section(src, text, sv.end(), r"setting")
    settings = _parse_settings(src, settings_text, settings_at)
    modes_text, modes_at, pos = _section(src, text, pos, r"modes")
    modes = _parse_modes(src, modes_text, modes_at, set(variables))
    jumps_text, jumps_at, pos = _section(src, text, pos, r"jumps")
    jumps = _parse_jumps(src, jumps_text, jumps_at, modes, set(variables))
    init_text, init_at, pos = _section(src, text, pos, r"init")
    init_mode, init, init_pos = _parse_init(src, init_text, init_at, modes, set(variables))
    rest = text[pos : after - 1]
    if rest.strip():
        at = pos + len(rest) - len(rest.lstrip())
        raise src.error(at, f"unexpected '{rest.strip()[:30]}' after the init block of the hybrid model")
    unsafe: dict = {}
    u = _match_at(r"unsafe(\s+set)?", text, after)
    end = after
    if u:
        unsafe_text, unsafe_at, end = _section(src, text, after, r"unsafe(\s+set)?")
        unsafe = _parse_unsafe(src, unsafe_text, unsafe_at, modes, set(variables))
    trailing = text[end:]
    if trailing.strip():
        at = end + len(trailing) - len(trailing.lstrip())
        # Flow* runs the analysis when it has read the unsafe block and ignores what follows;
        # do the same, loudly, so a misplaced brace cannot silently drop a property.
        msg = (
            f"{src.path}, line {src.line(at)}: ignoring '{' '.join(trailing.split())[:40]}...' after the model "
            f"(Flow* ignores it too: a stray '}}' closed the unsafe block early?)"
        )
        warnings.warn(msg, stacklevel=3)
        notes.append(msg)
    return _Automaton(src, variables, settings, modes, jumps, init_mode, init, init_pos, unsafe, notes)


def _parse_settings(src: _Source, text: str, base: int) -> dict:
    out: dict = {"ignored": []}
    for raw in text.split("\n"):
        line = raw.strip()
        if not line:
            continue
        if mm := re.fullmatch(rf"time\s+({_NUMBER})", line):
            out["time"] = float(mm.group(1))
        elif mm := re.fullmatch(r"max\s+jumps\s+(\d+)", line):
            out["max_jumps"] = int(mm.group(1))
        else:
            # Integration knobs of Verisig's Flow* (steps, orders, remainder, output): percver
            # chooses its own, so they are kept for reference only.
            out["ignored"].append(line)
    if "time" not in out:
        raise src.error(base, "the setting block gives no 'time' horizon")
    return out


def _parse_modes(src: _Source, text: str, base: int, variables: set) -> dict:
    t = _Tokens(src, text, base)
    modes: dict = {}
    while not t.at_end():
        _, name, pos = t.ident("a mode name")
        if name in modes:
            raise src.error(pos, f"mode '{name}' is defined twice")
        t.expect("{", f"after mode name '{name}'")
        ode: dict = {}
        inv: list = []
        while t.peek()[1] != "}":
            kind, word, wpos = t.next()
            if word in ("nonpoly", "poly", "linear"):
                t.expect("ode", f"after '{word}'")
                if word == "poly" and t.peek()[0] == "num":
                    t.next()
                if t.peek()[1] == "{" and t.peek(1)[0] == "num" and t.peek(2)[1] == "}":
                    t.next(), t.next(), t.next()  # nonpoly ode { N }: a queue size, not used
                t.expect("{", "opening the ODE block")
                ode.update(_assignments(t, src, variables, "=", f"mode '{name}': equation for"))
                t.expect("}")
            elif word in ("lti", "ltv"):
                raise src.error(wpos, f"mode '{name}': '{word} ode' dynamics are not supported; write them as 'nonpoly ode'")
            elif word == "inv":
                t.expect("{", "opening the invariant")
                inv += t.atoms()
                t.expect("}")
            else:
                raise src.error(wpos, f"mode '{name}': expected 'nonpoly ode {{...}}' or 'inv {{...}}', found '{word or 'the end'}'")
        t.expect("}", f"closing mode '{name}'")
        modes[name] = _Mode(name, pos, ode, inv)
    if not modes:
        raise src.error(base, "the modes block is empty")
    return modes


def _parse_jumps(src: _Source, text: str, base: int, modes: dict, variables: set) -> list:
    t = _Tokens(src, text, base)
    jumps = []
    while not t.at_end():
        _, a, pos = t.ident("a jump 'A -> B'")
        t.expect("->", f"after '{a}' in a jump")
        _, b, bpos = t.ident("the target mode of a jump")
        for name, at in ((a, pos), (b, bpos)):
            if name not in modes:
                raise src.error(at, f"jump {a} -> {b}: no mode named '{name}'")
        guard: list = []
        reset: dict = {}
        if t.peek()[1] == "guard":
            t.next()
            t.expect("{", "opening the guard")
            guard = t.atoms()
            t.expect("}")
        if t.peek()[1] == "reset":
            t.next()
            t.expect("{", "opening the reset")
            reset.update(_assignments(t, src, variables, ":=", f"jump {a} -> {b}: reset of"))
            t.expect("}")
        kind, word, wpos = t.next()
        if word in ("interval", "parallelotope", "octagon"):
            t.expect("aggregation", f"after '{word}'")
            if t.peek()[1] == "{":
                depth = 0
                while True:
                    tok = t.next()
                    depth += {"{": 1, "}": -1}.get(tok[1], 0)
                    if depth == 0 or tok[0] == "end":
                        break
        else:
            raise src.error(wpos, f"jump {a} -> {b}: expected 'interval aggregation' after the reset, found '{word or 'the end'}'")
        jumps.append(_Jump(a, b, pos, guard, reset))
    return jumps


def _parse_init(src: _Source, text: str, base: int, modes: dict, variables: set):
    t = _Tokens(src, text, base)
    _, mode, pos = t.ident("the initial mode")
    if mode not in modes:
        raise src.error(pos, f"init: no mode named '{mode}'")
    t.expect("{")
    box: dict = {}
    while t.peek()[1] != "}":
        _, v, vpos = t.ident("'x in [lo, hi]'")
        if v not in variables:
            raise src.error(vpos, f"init: undeclared variable '{v}'")
        t.expect("in", f"in 'init {v} in [lo, hi]'")
        t.expect("[")
        lo = t.number("an interval bound")
        t.expect(",")
        hi = t.number("an interval bound")
        t.expect("]")
        if lo > hi:
            raise src.error(vpos, f"init: empty interval for '{v}': [{lo}, {hi}]")
        box[v] = (lo, hi)
    t.expect("}")
    if not t.at_end():
        raise src.error(t.peek()[2], "init: several initial modes are not supported (give one mode)")
    return mode, box, pos


def _parse_unsafe(src: _Source, text: str, base: int, modes: dict, variables: set) -> dict:
    t = _Tokens(src, text, base)
    out: dict = {}
    while not t.at_end():
        _, mode, pos = t.ident("a mode name in the unsafe block")
        if mode not in modes:
            raise src.error(pos, f"unsafe: no mode named '{mode}'")
        t.expect("{")
        out[mode] = (t.atoms(), pos)
        t.expect("}")
    return out


# ----------------------------------------------------------------------------- symbolic values


class _Rel:
    """A counter or timer relative to its (step-dependent) value at the start of the period."""

    __slots__ = ("var", "c")

    def __init__(self, var: str, c: float):
        self.var, self.c = var, c

    def __add__(self, d: float) -> "_Rel":
        return _Rel(self.var, self.c + d)

    def __eq__(self, other):
        return isinstance(other, _Rel) and other.var == self.var and abs(other.c - self.c) <= _TOL

    def __repr__(self):
        return f"{self.var}@start + {self.c}"


class _NeedAbsolute(Exception):
    """A timer's value is needed where it depends on the step number (retry it as absolute)."""

    def __init__(self, var: str, pos: int):
        self.var, self.pos = var, pos


def _is_num(x) -> bool:
    return isinstance(x, float)


def _fold(op: str, a, b):
    """a op b with constants folded, so resets like ``0 * y1`` or ``temp := 0; temp + d`` stay small."""
    if _is_num(a) and _is_num(b):
        try:
            r = {"+": a + b, "-": a - b, "*": a * b}[op] if op != "/" else a / b
        except ZeroDivisionError:
            raise ArithmeticError("division by zero in a constant expression") from None
        return float(r)
    if op == "+":
        return b if _is_num(a) and a == 0 else a if _is_num(b) and b == 0 else a + b
    if op == "-":
        return a if _is_num(b) and b == 0 else -b if _is_num(a) and a == 0 else a - b
    if op == "*":
        if (_is_num(a) and a == 0) or (_is_num(b) and b == 0):
            return 0.0
        return b if _is_num(a) and a == 1 else a if _is_num(b) and b == 1 else a * b
    return a if _is_num(b) and b == 1 else a / b


def _call(name: str, x):
    if _is_num(x):
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


def _build(src: _Source, ast, lookup):
    """The value (float or Expr) of an AST; ``lookup(name, pos)`` gives each variable's value."""
    kind = ast[0]
    if kind == "num":
        return ast[1]
    if kind == "var":
        return lookup(ast[1], ast[2])
    if kind == "neg":
        v = _build(src, ast[1], lookup)
        return -v if _is_num(v) else -v
    if kind == "bin":
        return _fold(ast[1], _build(src, ast[2], lookup), _build(src, ast[3], lookup))
    if kind == "pow":
        base, exp = _build(src, ast[1], lookup), _build(src, ast[2], lookup)
        if not _is_num(exp):
            raise ParseError(f"{src.path}: exponents must be constants in '^'")
        return float(base**exp) if _is_num(base) else base**exp
    if kind == "call":
        return _call(ast[1], _build(src, ast[2], lookup))
    if kind == "interval":
        return ast[1] if ast[1] == ast[2] else Expr.uncertain(ast[1], ast[2])
    raise AssertionError(kind)


def _ast_vars(ast, out: set) -> set:
    if ast[0] == "var":
        out.add(ast[1])
    for part in ast[1:]:
        if isinstance(part, tuple):
            _ast_vars(part, out)
    return out


def _same_ast(a, b) -> bool:
    """Structural equality ignoring source positions."""
    if a[0] != b[0]:
        return False
    if a[0] == "var":
        return a[1] == b[1]
    if a[0] == "call":
        return a[1] == b[1] and _same_ast(a[2], b[2])
    if len(a) != len(b):
        return False
    return all(_same_ast(x, y) if isinstance(x, tuple) else x == y for x, y in zip(a[1:], b[1:]))


def _as_expr(v) -> Expr:
    return v if isinstance(v, Expr) else Expr.constant(float(v))


def _condition(lhs, op: str, rhs) -> Union[Condition, bool]:
    """A Condition, or a bool when both sides are constants."""
    if _is_num(lhs) and _is_num(rhs):
        return {"<=": lhs <= rhs, ">=": lhs >= rhs, "<": lhs < rhs, ">": lhs > rhs}[op]
    lhs = _as_expr(lhs)
    return {"<=": lhs <= rhs, ">=": lhs >= rhs, "<": lhs < rhs, ">": lhs > rhs}[op]


def _where(conds: list, then, otherwise):
    """``then`` where every condition holds, else ``otherwise`` (a conjunction as nested where)."""
    value = then
    for c in reversed(conds):
        if c is True:
            continue
        if c is False:
            return otherwise
        if value is otherwise:
            continue
        value = Expr.select(c, _as_expr(value), _as_expr(otherwise))
    return value


# ----------------------------------------------------------------------------- the problem


@dataclass
class VerisigProblem:
    """A Verisig benchmark as a percver closed loop with the file's initial set and property.

    ``pv.verify(problem, ...)`` and ``problem.verify(...)`` use ``defaults`` (init, steps, goal,
    safe, within) for whatever is not given. ``notes`` records every liberty the translation
    took (ignored settings, dropped jumps, added obligations), ``summary()`` prints the result.
    """

    path: str
    loop: ClosedLoop
    init: dict
    steps: int
    goal: Optional[Condition] = None
    safe: list = field(default_factory=list)
    within: bool = False
    period: Optional[float] = None  # control period of a continuous plant
    networks: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "continuous" if isinstance(self.loop.plant, Continuous) else "hybrid" if isinstance(self.loop.plant, Hybrid) else "discrete"

    @property
    def states(self) -> list:
        return self.loop.states

    @property
    def defaults(self) -> dict:
        return {"init": dict(self.init), "steps": self.steps, "goal": self.goal, "safe": list(self.safe) or None, "within": self.within}

    def verify(self, **kwargs):
        """``pv.verify`` with this file's initial set, horizon and property as defaults."""
        from percver.verification import verify

        return verify(self, **kwargs)

    def simulate(self, x0, steps: Optional[int] = None) -> np.ndarray:
        return self.loop.simulate(x0, self.steps if steps is None else steps)

    def summary(self) -> str:
        """What the file became: plant, stages, property (long expressions shortened)."""

        def short(e, n=110):
            s = str(e)
            return s if len(s) <= n else s[: n - 3] + "..."

        def opaque(e):
            # Composed updates share subexpressions; printing expands them (exponentially).
            return f"<composed expression over {', '.join(e.variables())}>" if isinstance(e, Expr) else repr(e)

        plant = self.loop.plant
        lines = [f"{Path(self.path).name}: {self.kind} plant, states {', '.join(self.states)}"]
        if isinstance(plant, Discrete):
            lines += [f"  {s}+ = {opaque(e)}" for s, e in zip(plant.states, plant.update)]
        elif isinstance(plant, Hybrid):
            for name in plant.modes:
                lines.append(f"  mode {name}: " + "; ".join(f"{s}' = {short(e, 60)}" for s, e in zip(plant.states, plant.rhs_of(name))))
            lines += [
                f"  jump {j.source} -> {j.target or 'the networks'} when {' and '.join(map(str, j.guard)) or 'always'}" for j in plant.jumps
            ]
            lines.append(f"  inputs {', '.join(plant.inputs)} held for {self.period} s")
        else:
            lines += [f"  {s}' = {short(e)}" for s, e in zip(plant.states, plant.rhs)]
            lines.append(f"  inputs {', '.join(plant.inputs)} held for {self.period} s")
        for st in self.loop.stages:
            if st.is_network:
                net = st.component
                lines.append(
                    f"  stage {st.output} = network {net.name or ''} ({net.n_in} -> {net.n_out}) of {', '.join(st.input_labels)}"
                    + (
                        f", scale {np.asarray(net.scale).tolist()} offset {np.asarray(net.offset).tolist()}"
                        if net.scale is not None
                        else ""
                    )
                )
            elif st.input_names:
                lines.append(f"  stage {st.output} = {len(st.component)} expression(s) of {', '.join(st.input_names)}")
            else:
                lines.append(f"  stage {st.output} = constants {', '.join(map(str, st.component))}")
        lines.append(f"  init {self.init}, {self.steps} steps")
        for c in self.safe:
            lines.append(f"  safe at every step: {short(c)}")
        if self.goal is not None:
            lines.append(f"  goal {'within' if self.within else 'at'} step {self.steps}: {short(self.goal)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def __repr__(self):
        return f"<VerisigProblem {Path(self.path).name}: {self.kind}, {len(self.states)} states, {self.steps} steps>"


# ----------------------------------------------------------------------------- translation


def load_verisig(model_path: str, networks: Sequence = ()) -> VerisigProblem:
    """Reads a Verisig 2.0 model (``*_tmp.model`` / ``*_verisig.model``) and its networks.

    ``networks``: the ``.yml`` files (or loaded ``pv.Network`` objects) in the order the
    Verisig command line gives them; the k-th distinct ``DNN`` mode of the file uses the k-th.
    Raises ``percver.ParseError`` naming file, line and construct for anything it cannot
    translate faithfully.
    """
    from percver.networks import Network, load_network

    aut = _parse(str(model_path))
    nets = [n if isinstance(n, Network) else load_network(str(n)) for n in networks]
    return _Translator(aut, nets).problem()


@dataclass
class _Call:
    net: object
    inputs: list  # values (float or Expr) of _f1.._fN
    output: str  # signal name
    mode: str


@dataclass
class _Path:
    """The state of a symbolic run: values of the ordinary variables, timers, and bookkeeping."""

    env: dict
    timers: dict  # var -> float (absolute) or _Rel
    jumps: int = 0
    max_jumps: int = 0
    elapsed: float = 0.0
    dwell: float = 0.0  # time spent in the current mode before its jumps

    def copy(self) -> "_Path":
        return _Path(dict(self.env), dict(self.timers), self.jumps, self.max_jumps, self.elapsed, self.dwell)


class _Translator:
    def __init__(self, aut: _Automaton, networks: list):
        self.aut = aut
        self.src = aut.src
        self.notes = list(aut.notes)
        self.networks = networks
        self.vars = aut.variables
        self.modes = aut.modes
        self.out = {m: [] for m in self.modes}
        for j in aut.jumps:
            self.out[j.src].append(j)
        self.terminal = {m for m in self.modes if not self.out[m]}
        for m in aut.unsafe:
            if self.out[m]:
                raise self.src.error(
                    aut.unsafe[m][1],
                    f"unsafe mode '{m}' has outgoing jumps; only terminal unsafe modes (entered by a jump, never left) are supported",
                )
        if aut.init_mode in self.terminal:
            raise self.src.error(aut.init_pos, f"the initial mode '{aut.init_mode}' has no outgoing jumps")
        self.dnn_modes = [m for m in self.modes if m.startswith("DNN")]
        if len(self.dnn_modes) != len(networks):
            raise ParseError(
                f"{self.src.path}: {len(self.dnn_modes)} DNN mode(s) ({', '.join(self.dnn_modes) or 'none'}) but {len(networks)} network(s) given; "
                f"pass networks=[...] with one .yml per DNN mode, in order"
            )
        self.timers = self._find_timers()
        for m, mode in self.modes.items():
            states = [a for a in mode.inv if not (_ast_vars(a[0], set()) | _ast_vars(a[2], set())) <= set(self.timers)]
            if states and m not in self.terminal:
                self.notes.append(
                    f"mode '{m}' (line {self.src.line(mode.pos)}): state invariants ignored (an over-approximation: "
                    f"runs Verisig would block there are kept)"
                )
        self.sym = {v: Expr.var(v) for v in self.vars if v not in self.timers}
        self.flow_mode = self._find_flow_mode()
        self.calls: list = []
        self.obligations: list = []  # (atoms as conditions, text)
        self.assumed_absolute: set = set()
        self._start_mode = aut.init_mode

    # --- classification ---------------------------------------------------------------

    def _const(self, ast) -> Optional[float]:
        if _ast_vars(ast, set()):
            return None
        try:
            v = _build(self.src, ast, lambda n, p: 0.0)
        except (ArithmeticError, ValueError):
            return None
        return v if _is_num(v) else None

    def _find_timers(self) -> dict:
        """Variables with constant rates everywhere and resets ``v := c`` or ``v := v + c``:
        clocks and step counters, tracked as numbers instead of states. The networks' inputs
        and outputs ``_f1.._fN`` are never timers: a constant reset (``_f1' := 30.0``, a set
        speed) is a network input like any other, and the DNN mode writes them without a reset."""
        width = max((max(net.n_in, net.n_out) for net in self.networks), default=0)
        io = {f"_f{i + 1}" for i in range(width)}
        timers = {}
        for v in self.vars:
            if v in io:
                continue
            rates = {}
            ok = True
            for name, mode in self.modes.items():
                ast = mode.ode.get(v, ("num", 0.0))
                r = self._const(ast)
                if r is None:
                    ok = False
                    break
                rates[name] = r
            if not ok:
                continue
            for j in self.aut.jumps:
                if v in j.reset and self._timer_reset(v, j.reset[v]) is None:
                    ok = False
                    break
            if ok:
                timers[v] = rates
        return timers

    def _timer_reset(self, v: str, ast):
        """('set', c) or ('add', c) for a timer reset, else None."""
        c = self._const(ast)
        if c is not None:
            return ("set", c)
        if ast[0] == "var" and ast[1] == v:
            return ("add", 0.0)
        if ast[0] == "bin" and ast[1] in "+-":
            a, b = ast[2], ast[3]
            if a[0] == "var" and a[1] == v and self._const(b) is not None:
                return ("add", self._const(b) * (1 if ast[1] == "+" else -1))
            if ast[1] == "+" and b[0] == "var" and b[1] == v and self._const(a) is not None:
                return ("add", self._const(a))
        return None

    def _solvable(self, mode: _Mode) -> bool:
        """Constant dynamics within the mode (rhs reads only variables frozen in it): the flow
        over a dwell time d is exactly x + d * rhs, a discrete update."""
        frozen = {v for v in self.vars if v not in self.timers and self._const(mode.ode.get(v, ("num", 0.0))) == 0.0}
        for v in self.vars:
            if v in self.timers:
                continue
            ast = mode.ode.get(v, ("num", 0.0))
            if self._const(ast) == 0.0:
                continue
            if not _ast_vars(ast, set()) <= frozen:
                return False
        return True

    def _inv_bound(self, mode: _Mode) -> Optional[float]:
        bounds = [
            self._const(rhs)
            for lhs, op, rhs, _ in mode.inv
            if op in ("<=", "<") and lhs[0] == "var" and lhs[1] in self.timers and self._const(rhs) is not None
        ]
        return min(bounds) if bounds else None

    def _find_flow_mode(self) -> Optional[str]:
        """The mode that integrates the plant; with several (a period through plant modes with
        guards), the first of them, the others in ``self.region`` (see :meth:`_hybrid`)."""
        flows = [
            m
            for m, mode in self.modes.items()
            if m not in self.terminal and not self._solvable(mode) and (self._inv_bound(mode) or 0.0) > 0
        ]
        self.region = flows
        return flows[0] if flows else None

    # --- symbolic execution ---------------------------------------------------------------

    def _lookup(self, state: _Path):
        def get(name, pos):
            if name in self.timers:
                t = state.timers[name]
                if isinstance(t, _Rel):
                    raise _NeedAbsolute(name, pos)
                return t
            if name not in state.env:
                raise self.src.error(pos, f"unknown variable '{name}'")
            return state.env[name]

        return get

    def _value(self, ast, state: _Path):
        return _build(self.src, ast, self._lookup(state))

    def _split_atoms(self, atoms: list, state: _Path, where: str):
        """(timer atoms as ASTs, state conditions as values); mixed atoms are refused."""
        timer_atoms, conds = [], []
        for lhs, op, rhs, pos in atoms:
            used = _ast_vars(lhs, set()) | _ast_vars(rhs, set())
            if used and used <= set(self.timers):
                timer_atoms.append((lhs, op, rhs, pos))
                continue
            if used & set(self.timers):
                raise self.src.error(
                    pos,
                    f"{where}: a constraint mixing clocks/counters ({', '.join(sorted(used & set(self.timers)))}) with states is not supported",
                )
            lv, rv = self._value(lhs, state), self._value(rhs, state)
            if op == "=":
                conds += [_condition(lv, "<=", rv), _condition(lv, ">=", rv)]
            else:
                conds.append(_condition(lv, op, rv))
        return timer_atoms, conds

    def _timer_holds(self, atoms: list, state: _Path) -> bool:
        for lhs, op, rhs, pos in atoms:
            lv, rv = self._value(lhs, state), self._value(rhs, state)
            if not _compare(lv, op, rv):
                return False
        return True

    def _apply_reset(self, jump: _Jump, state: _Path) -> _Path:
        new = state.copy()
        values = {}
        for v, ast in jump.reset.items():
            if v in self.timers:
                kind, c = self._timer_reset(v, ast)
                old = state.timers[v]
                values[v] = ("t", c if kind == "set" else old + c)
            else:
                try:
                    values[v] = ("e", self._value(ast, state))
                except _NeedAbsolute as e:
                    raise self.src.error(
                        e.pos,
                        f"jump {jump.src} -> {jump.dst}: '{v}' is computed from the counter '{e.var}', "
                        f"whose value depends on the step; not supported",
                    ) from None
                except ArithmeticError as e:
                    raise self.src.error(jump.pos, f"jump {jump.src} -> {jump.dst}: {e}") from None
        for v, (kind, val) in values.items():
            (new.timers if kind == "t" else new.env)[v] = val
        new.jumps += 1
        new.max_jumps += 1
        return new

    def _arrive(self, name: str, state: _Path, depth: int, initial: bool = False) -> _Path:
        """What happens in a mode before its jumps: a function mode's operation, a network
        evaluation, or a flow with constant dynamics."""
        mode = self.modes[name]
        special = _SPECIAL.match(name)
        if special and not initial:
            op, i, j = special.group(1), int(special.group(2)), int(special.group(3))
            if i >= len(self.vars) or j >= len(self.vars):
                raise self.src.error(mode.pos, f"function mode '{name}' names state variable {max(i, j)}, but there are {len(self.vars)}")
            dst, arg = self.vars[i], self.vars[j]
            if dst in self.timers or arg in self.timers:
                raise self.src.error(mode.pos, f"function mode '{name}' applies {op} to a clock/counter")
            x = state.env[arg]
            f = {
                "cos": lambda a: _call("cos", a),
                "sin": lambda a: _call("sin", a),
                "tan": lambda a: _call("tan", a),
                "arc": lambda a: _call("atan", a),
                "sqrt": lambda a: _call("sqrt", a),
                "div": lambda a: _fold("/", 1.0, a),
                "sec": lambda a: _fold("/", 1.0, _call("cos", a)),
            }[op]
            state.env[dst] = f(x)
        elif special and initial:
            raise self.src.error(mode.pos, f"the initial mode '{name}' is a function mode; start in an ordinary mode")
        if name in self.dnn_modes:
            if initial:
                raise self.src.error(mode.pos, f"the initial mode '{name}' is a DNN mode; start in a plant mode")
            if depth > 0:
                raise self.src.error(
                    mode.pos,
                    f"DNN mode '{name}' is reached on only some branches of a period; every period must evaluate each network once",
                )
            self._call_network(name, state)
        dwell = state.dwell = self._dwell(name, state.timers)
        if dwell > _TOL:
            if name == self.flow_mode:
                raise AssertionError("the plant mode is handled by the caller")
            if not self._solvable(mode):
                raise self.src.error(
                    mode.pos,
                    f"mode '{name}' flows for {dwell} with non-constant dynamics between the networks of a period; "
                    f"the plant modes ({', '.join(self.region)}) must follow one another",
                )
            lookup = self._lookup(state)
            updates = {}
            for v in self.vars:
                ast = mode.ode.get(v, ("num", 0.0))
                if v in self.timers:
                    continue
                if self._const(ast) == 0.0:
                    continue
                try:
                    rate = _build(self.src, ast, lookup)
                except _NeedAbsolute as e:
                    raise self.src.error(e.pos, f"mode '{name}': the dynamics of '{v}' read the counter '{e.var}'; not supported") from None
                updates[v] = _fold("+", state.env[v], _fold("*", dwell, rate))
            state.env.update(updates)
            for v, rates in self.timers.items():
                t = state.timers[v]
                state.timers[v] = t + rates[name] * dwell
            state.elapsed += dwell
        return state

    def _dwell(self, name: str, timers: dict) -> float:
        """How long a run stays in the mode: until its clock invariant runs out."""
        mode = self.modes[name]
        if self._inv_bound(mode) is None:
            raise self.src.error(mode.pos, f"mode '{name}' has no clock invariant ('clock <= c'), so its dwell time is unknown")
        clocks = [lhs[1] for lhs, op, rhs, _ in mode.inv if lhs[0] == "var" and lhs[1] in self.timers and op in ("<=", "<")]
        dwell = math.inf
        for c in clocks:
            t = timers[c]
            if isinstance(t, _Rel):
                raise _NeedAbsolute(c, mode.pos)
            rate = self.timers[c][name]
            b = self._const([rhs for lhs, op, rhs, _ in mode.inv if lhs[0] == "var" and lhs[1] == c][0])
            if rate > 0:
                dwell = min(dwell, (b - t) / rate)
        if dwell == math.inf or dwell < -_TOL:
            raise self.src.error(mode.pos, f"mode '{name}' is entered with its clock past the invariant bound")
        return max(dwell, 0.0)

    def _call_network(self, mode: str, state: _Path):
        k = self.dnn_modes.index(mode)
        net = self.networks[k]
        ins = []
        for i in range(net.n_in):
            v = f"_f{i + 1}"
            if v not in state.env:
                raise self.src.error(
                    self.modes[mode].pos, f"network {k + 1} takes {net.n_in} inputs but '{v}' is not a state variable of the model"
                )
            ins.append(state.env[v])
        name = self._fresh(f"dnn{len(self.calls) + 1}")
        outs = [name] if net.n_out == 1 else [f"{name}_{i}" for i in range(net.n_out)]
        for i, o in enumerate(outs):
            v = f"_f{i + 1}"
            if v not in state.env:
                raise self.src.error(self.modes[mode].pos, f"network {k + 1} has {net.n_out} outputs but '{v}' is not a state variable")
            state.env[v] = Expr.var(o)
        self.calls.append(_Call(net, ins, name, mode))

    def _fresh(self, base: str) -> str:
        name = base
        while name in self.vars:
            name = "_" + name
        return name

    def _continuing(self, name: str) -> list:
        name = self._start_mode if name == _START else name
        return [j for j in self.out[name] if j.dst not in self.terminal]

    def _pos(self, name: str) -> int:
        return self.modes[self._start_mode if name == _START else name].pos

    def _region(self, start: str, first_edges: list, stop: str) -> dict:
        """Immediate post-dominators of the modes between ``start`` and ``stop`` (where
        branches of the period join again)."""
        succ: dict = {start: sorted({j.dst for j in first_edges})}
        todo = [j.dst for j in first_edges]
        while todo:
            m = todo.pop()
            if m in succ or m == stop:
                continue
            succ[m] = sorted({j.dst for j in self._continuing(m)})
            if not succ[m]:
                raise self.src.error(self._pos(m), f"mode '{m}' has no way back to '{stop}' (no continuing jumps)")
            todo += succ[m]
        succ[stop] = []
        # A cycle that avoids the period's start/end cannot be one control period.
        colour: dict = {}
        for root in succ:
            if colour.get(root):
                continue
            stack = [(root, iter(succ[root]))]
            colour[root] = 1
            while stack:
                node, it = stack[-1]
                nxt = next(it, None)
                if nxt is None:
                    colour[node] = 2
                    stack.pop()
                elif colour.get(nxt) == 1:
                    raise self.src.error(
                        self._pos(nxt),
                        f"mode '{nxt}' lies on a cycle that does not pass '{stop}': a loop inside one control period is not supported",
                    )
                elif not colour.get(nxt):
                    colour[nxt] = 1
                    stack.append((nxt, iter(succ[nxt])))
        # Post-dominators: dominators of the reversed graph rooted at ``stop``.
        pred: dict = {m: [] for m in succ}
        for m, ss in succ.items():
            for s in ss:
                pred[s].append(m)
        order, seen = [], {stop}
        stack = [(stop, iter(pred[stop]))]
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                order.append(node)
                stack.pop()
            elif nxt not in seen:
                seen.add(nxt)
                stack.append((nxt, iter(pred[nxt])))
        rpo = order[::-1]
        index = {m: i for i, m in enumerate(rpo)}
        ipdom = {stop: stop}
        changed = True
        while changed:
            changed = False
            for m in rpo[1:]:
                cands = [s for s in succ[m] if s in ipdom]
                new = cands[0]
                for s in cands[1:]:
                    a, b = new, s
                    while a != b:
                        while index[a] > index[b]:
                            a = ipdom[a]
                        while index[b] > index[a]:
                            b = ipdom[b]
                    new = a
                if ipdom.get(m) != new:
                    ipdom[m] = new
                    changed = True
        return ipdom

    def _run(self, start: str, state: _Path, stop: str, plant_states: Optional[set]) -> _Path:
        """From the initial mode (the run starts inside it) to ``stop``."""
        ipdom = self._region(start, self._continuing(start), stop)
        state = self._arrive(start, state, 0, initial=True)
        return self._walk(start, state, stop, ipdom, 0, plant_states)

    def _walk(self, node: str, state: _Path, stop: str, ipdom: dict, depth: int, plant_states) -> _Path:
        while True:
            edges = []
            for j in self._continuing(node):
                if state.dwell > _TOL and not any(
                    op == "=" and _ast_vars(l, set()) <= set(self.timers) and _ast_vars(l, set()) for l, op, r, _ in j.guard
                ):
                    # Without 'clock = c' the jump may fire at any time of the flow, not just at its end.
                    raise self.src.error(
                        j.pos,
                        f"jump {j.src} -> {j.dst} leaves the flowing mode '{j.src}' without a 'clock = c' guard, "
                        f"so it can fire during the flow; only jumps at the end of a flow are supported",
                    )
                timer_atoms, conds = self._split_atoms(j.guard, state, f"jump {j.src} -> {j.dst}")
                if (timer_atoms and not self._timer_holds(timer_atoms, state)) or any(c is False for c in conds):
                    continue
                edges.append((j, [c for c in conds if c is not True]))
            if not edges:
                raise self.src.error(self._pos(node), f"no jump out of mode '{node}' can fire when its clock runs out")
            if len(edges) == 1:
                j, _ = edges[0]
                state = self._apply_reset(j, state)
                node = j.dst
                if node == stop:
                    return state
                state = self._arrive(node, state, depth)
                continue
            join = ipdom[node]
            branches = []
            for j, conds in edges:
                s = self._apply_reset(j, state)
                if j.dst != join:
                    s = self._arrive(j.dst, s, depth + 1)
                    s = self._walk(j.dst, s, join, ipdom, depth + 1, plant_states)
                branches.append((j, conds, s))
            if plant_states is not None:
                branches = self._drop_plant_jumps(node, state, branches, plant_states)
            state = self._merge(node, branches)
            node = join
            if node == stop:
                return state
            state = self._arrive(node, state, depth)

    def _drop_plant_jumps(self, node: str, before: _Path, branches: list, plant_states: set) -> list:
        """A continuous plant cannot jump: branches that reset plant states are dropped, and
        'their guard never holds' becomes a safety obligation, so a verified result is exact."""
        keep, dropped = [], []
        for j, conds, s in branches:
            changed = [x for x in plant_states if s.env.get(x) is not before.env.get(x)]
            (dropped if changed else keep).append((j, conds, s, changed))
        if not dropped:
            return branches
        if not keep:
            raise self.src.error(self._pos(node), f"every jump out of '{node}' resets plant states; a continuous plant cannot jump")
        for j, conds, s, changed in dropped:
            if not conds:
                raise self.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} resets {', '.join(changed)} unconditionally; a continuous plant cannot jump"
                )
            line = self.src.line(j.pos)
            self.obligations.append((conds, f"jump {j.src} -> {j.dst} (line {line}) resets {', '.join(sorted(changed))}"))
            self.notes.append(
                f"jump {j.src} -> {j.dst} (line {line}) resets plant states {', '.join(sorted(changed))}; "
                f"translated as the obligation that its guard never holds (checked at every step)"
            )
        return [(j, c, s) for j, c, s, _ in keep]

    def _merge(self, node: str, branches: list) -> _Path:
        """One state for the join: each variable a where-chain over the branches' guards; the
        branch with the most guard atoms is the default, so the common case is not tested."""
        if len(branches) == 1:
            return branches[0][2]
        for j, conds, _ in branches:
            if not conds:
                others = ", ".join(f"{b[0].src} -> {b[0].dst} (line {self.src.line(b[0].pos)})" for b in branches if b[0] is not j)
                raise self.src.error(
                    j.pos,
                    f"jump {j.src} -> {j.dst} has no state guard but other jumps leave '{node}' at the same time ({others}); "
                    f"Verisig takes all of them, percver needs exclusive guards",
                )
        order = sorted(range(len(branches)), key=lambda i: len(branches[i][1]))
        default = branches[order[-1]][2]
        merged = _Path({}, {}, min(b[2].jumps for b in branches), max(b[2].max_jumps for b in branches), default.elapsed)
        for _, _, s in branches:
            if abs(s.elapsed - default.elapsed) > _TOL:
                raise self.src.error(self._pos(node), f"branches from '{node}' take different times; not one control period")
        for v in default.timers:
            values = [b[2].timers[v] for b in branches]
            if any(not _timer_equal(x, values[0]) for x in values):
                raise self.src.error(
                    self._pos(node), f"branches from '{node}' leave the counter '{v}' at different values ({values}); not supported"
                )
            merged.timers[v] = values[0]
        for v in default.env:
            value = default.env[v]
            for i in reversed(order[:-1]):
                j, conds, s = branches[i]
                other = s.env[v]
                if other is value or (_is_num(other) and _is_num(value) and other == value):
                    continue
                value = _where(conds, other, value)
            merged.env[v] = value
        return merged

    # --- the period, the prefix and the property ----------------------------------------------

    def _initial_timers(self) -> dict:
        out = {}
        for v in self.timers:
            lo, hi = self.aut.init.get(v, (0.0, 0.0))
            if v not in self.aut.init:
                self.notes.append(f"counter/clock '{v}' has no initial value; 0 assumed")
            if hi - lo > _TOL:
                raise self.src.error(self.aut.init_pos, f"init: the clock/counter '{v}' must start at one value, got [{lo}, {hi}]")
            out[v] = lo
        return out

    def _symbolic_timers(self, anchor: dict) -> dict:
        return {v: (anchor[v] if v in self.assumed_absolute else _Rel(v, 0.0)) for v in self.timers}

    def _cycle(self, start: str, stop: str, anchor_timers: dict, plant_states: Optional[set]) -> _Path:
        """One period with counters relative to their step-dependent start values; a counter
        that a guard needs is retried as a constant and checked to return to that constant."""
        while True:
            self.calls, self.obligations = [], []
            try:
                # The period starts and ends in the same mode: the start is a separate node.
                self._start_mode = start
                state = _Path(dict(self.sym), self._symbolic_timers(anchor_timers))
                if start == self.flow_mode:
                    state.dwell = self._inv_bound(self.modes[start])
                return self._walk(_START, state, stop, self._region(_START, self._continuing(_START), stop), 0, plant_states)
            except _NeedAbsolute as e:
                if e.var in self.assumed_absolute:
                    raise
                self.assumed_absolute.add(e.var)

    def problem(self) -> VerisigProblem:
        aut = self.aut
        init_timers = self._initial_timers()
        if "max_jumps" not in aut.settings:
            self.notes.append("no 'max jumps' setting; the horizon comes from 'time' alone")
        if self.flow_mode is None:
            return self._discrete(init_timers)
        if len(self.region) > 1:
            return self._hybrid(init_timers)
        return self._continuous(init_timers)

    def _property_edges(self, source: str) -> tuple:
        """Jumps into terminal modes: (unsafe ones, absorbing ones) leaving ``source``; such
        jumps elsewhere are refused."""
        unsafe, absorbing = [], []
        for j in self.aut.jumps:
            if j.dst not in self.terminal:
                continue
            if j.src != source:
                raise self.src.error(
                    j.pos,
                    f"jump {j.src} -> {j.dst} ends the run from '{j.src}'; properties are read from jumps leaving '{source}' (the step boundary) only",
                )
            (unsafe if j.dst in self.aut.unsafe else absorbing).append(j)
        return unsafe, absorbing

    def _edge_conditions(self, j: _Jump, state: _Path) -> tuple:
        """(timer atoms, state conditions) of a property jump: its guard, then the unsafe
        block of the target evaluated after the jump's reset."""
        timer_atoms, conds = self._split_atoms(j.guard, state, f"jump {j.src} -> {j.dst}")
        if j.dst in self.aut.unsafe:
            after = self._apply_reset(j, state)
            more_t, more_c = self._split_atoms(self.aut.unsafe[j.dst][0], after, f"unsafe set of '{j.dst}'")
            if more_t:
                raise self.src.error(
                    self.aut.unsafe[j.dst][1], f"unsafe set of '{j.dst}' constrains clocks/counters; put those in the jump guard"
                )
            conds = conds + more_c
        return timer_atoms, _dedupe(conds)

    def _steps(self, elapsed: float, per_period_jumps: int, prefix_jumps: int) -> int:
        T = self.aut.settings["time"]
        if elapsed > _TOL:
            H = int(math.floor(T / elapsed + _TOL))
        else:
            mj = self.aut.settings.get("max_jumps")
            if not mj:
                raise ParseError(f"{self.src.path}: a period takes no time and there is no 'max jumps': the horizon is undefined")
            H = (mj - prefix_jumps) // max(per_period_jumps, 1)
        if H < 1:
            raise ParseError(f"{self.src.path}: the time horizon {T} is shorter than one control period ({elapsed})")
        return H

    def _jump_note(self, H: int, per_period: int, prefix: int, property_jump: bool):
        mj = self.aut.settings.get("max_jumps")
        if mj is None:
            return
        need = prefix + H * per_period + (1 if property_jump else 0)
        if need > mj:
            self.notes.append(
                f"'max jumps {mj}' stops Flow* after {mj} jumps, but {H} periods of {per_period} jumps"
                f"{' plus the jump into the unsafe mode' if property_jump else ''} need {need}: Flow* never checks the final-step property. "
                f"percver checks the intended one ({H} steps)"
            )

    def _classify(self, trig, what: str, pos: int, H: int):
        """'always', ('final', step), or None (never within the horizon); else refused."""
        if trig == "always":
            return "always"
        steps = sorted(trig)
        if not steps:
            self.notes.append(
                f"{what} (line {self.src.line(pos)}) cannot fire before the time horizon ends ({H} steps; Flow* computes no flow past 'time'); dropped"
            )
            return None
        if steps == list(range(H + 1)):
            return "always"
        if len(steps) == 1:
            return ("final", steps[0])
        raise self.src.error(
            pos,
            f"{what} fires at steps {steps[:5]}{'...' if len(steps) > 5 else ''} only; percver checks a property at every step or at one final step",
        )

    def _horizon(self, finals: list, safe: list, H: int) -> int:
        """The final-step properties set the horizon (ex2 checks at 1.4 s of a 1.8 s run)."""
        steps = {s for _, _, s in finals}
        if len(steps) > 1:
            raise ParseError(f"{self.src.path}: final-step properties at different steps {sorted(steps)}; not supported")
        if not steps:
            return H
        s = steps.pop()
        if s < H and safe:
            raise ParseError(
                f"{self.src.path}: a property at step {s} and properties at every step up to {H}; not expressible as one verification"
            )
        return s

    def _discrete(self, init_timers: dict) -> VerisigProblem:
        aut = self.aut
        ending = [j for j in aut.jumps if j.dst in self.terminal]
        others = [j for j in ending if j.src != ending[0].src]
        if others:
            a, b = ending[0], others[0]
            raise self.src.error(
                b.pos,
                f"jump {b.src} -> {b.dst} ends the run from '{b.src}', but jump {a.src} -> {a.dst} (line {self.src.line(a.pos)}) "
                f"from '{a.src}'; properties must be read at one step-boundary mode",
            )
        anchor = ending[0].src if ending else aut.init_mode
        if self._inv_bound(self.modes[anchor]) not in (0.0,):
            raise self.src.error(self.modes[anchor].pos, f"the step boundary mode '{anchor}' must take no time (invariant clock <= 0)")
        # Prefix: from the initial mode to the step boundary (must not change the states).
        if aut.init_mode != anchor:
            pre = _Path(dict(self.sym), dict(init_timers))
            pre = self._run(aut.init_mode, pre, anchor, None)
            if self.calls:
                raise self.src.error(aut.init_pos, "a network is evaluated before the first step boundary; not supported")
            start_timers, prefix_jumps, start_env = pre.timers, pre.jumps, pre.env
        else:
            start_timers, prefix_jumps, start_env = dict(init_timers), 0, dict(self.sym)
        end = self._cycle(anchor, anchor, start_timers, None)
        self._check_assumed(end.timers, start_timers, anchor)
        H = self._steps(end.elapsed, end.max_jumps, prefix_jumps)
        timer_at = self._timer_sequence(start_timers, end.timers, H, lambda v, n, t: t)
        calls = self.calls
        # Property from the jumps leaving the boundary mode.
        unsafe, absorbing = self._property_edges(anchor)
        at = _Path(dict(self.sym), {v: 0.0 for v in self.timers})
        safe, finals, goals_within = [], [], []
        for j in unsafe + absorbing:
            timer_atoms, conds = self._edge_conditions(j, at)
            trig = self._discrete_trigger(timer_atoms, timer_at, H)
            kind = self._classify(trig, f"jump {j.src} -> {j.dst}", j.pos, H)
            if kind is None:
                continue
            if j in absorbing:
                if kind != "always":
                    self.notes.append(f"jump {j.src} -> {j.dst} (line {self.src.line(j.pos)}) ends the run at step {kind[1]} only; ignored")
                    continue
                goals_within.append((j, conds))
            elif kind == "always":
                safe.append(_negate(conds, self.src, j))
            else:
                finals.append((j, conds, kind[1]))
        H = self._horizon(finals, safe, H)
        goal, within = self._final_goal(finals, goals_within, anchor)
        # States: what the property and the controller read, closed under the update.
        nxt = end.env
        signals = {c.output for c in calls} | {f"{c.output}_{i}" for c in calls for i in range(c.net.n_out)}
        need = set()
        for c in safe + ([goal] if goal is not None else []):
            need |= set(c.margin().variables())
        for c in calls:
            for v in c.inputs:
                if isinstance(v, Expr):
                    need |= set(v.variables())
        need -= signals
        states: set = set()
        todo = list(need)
        while todo:
            v = todo.pop()
            if v in states:
                continue
            if v not in self.sym:
                raise ParseError(f"{self.src.path}: the translated step reads '{v}', which is not a state variable")
            states.add(v)
            e = nxt[v]
            if isinstance(e, Expr):
                todo += [w for w in e.variables() if w not in signals and w not in states]
        if prefix_jumps:
            for v in states:
                if start_env[v] is not self.sym[v]:
                    raise self.src.error(
                        aut.init_pos, f"the jumps from the initial mode to '{anchor}' change the state '{v}'; not supported"
                    )
        order = [v for v in self.vars if v in states]
        init = self._init_box(order)
        update = {v: nxt[v] for v in order}
        stages, inputs = self._stages(calls, set(order), {})
        plant = Discrete(update, inputs=inputs)
        loop = ClosedLoop(plant, stages)
        self._jump_note(H, end.max_jumps, prefix_jumps, bool(finals))
        return self._problem(loop, init, H, goal, safe, within, None)

    def _check_assumed(self, end_timers: dict, start_timers: dict, anchor: str):
        for v in self.assumed_absolute:
            e = end_timers[v]
            if isinstance(e, _Rel) or abs(e - start_timers[v]) > _TOL:
                raise ParseError(
                    f"{self.src.path}: a jump guard inside the period reads the counter '{v}', which changes from step to step "
                    f"(start {start_timers[v]}, after one period {e}); step-dependent control flow is not supported"
                )

    def _timer_sequence(self, start: dict, end: dict, H: int, advance) -> list:
        """Counter values at the boundary of each step 0..H (``advance`` adds the flow)."""
        seq = [dict(start)]
        for n in range(H):
            cur = seq[-1]
            nxt = {}
            for v in self.timers:
                e = end[v]
                nxt[v] = advance(v, n, cur[v] + e.c if isinstance(e, _Rel) else e)
            seq.append(nxt)
        return seq

    def _discrete_trigger(self, atoms: list, timer_at: list, H: int):
        if not atoms:
            return "always"
        steps = set()
        for n in range(H + 1):
            st = _Path({}, timer_at[n])
            if self._timer_holds(atoms, st):
                steps.add(n)
        return steps

    def _final_goal(self, finals: list, within_goals: list, anchor: str):
        """The goal: every final-step unsafe set avoided, or (absorbing goal mode) the goal
        region reached at some step, which also ends the run."""
        if within_goals:
            if len(within_goals) != 1 or len(finals) != 1:
                j = within_goals[0][0]
                raise self.src.error(
                    j.pos,
                    "an absorbing goal mode is supported with exactly one goal jump and one final-step unsafe jump (the Mountain Car pattern)",
                )
            (gj, _), (uj, uconds, _) = within_goals[0], finals[0]
            g_atoms = [a for a in gj.guard if not (_ast_vars(a[0], set()) | _ast_vars(a[2], set())) <= set(self.timers)]
            u_atoms = _dedupe_atoms(
                [a for a in uj.guard if not (_ast_vars(a[0], set()) | _ast_vars(a[2], set())) <= set(self.timers)]
                + (self.aut.unsafe[uj.dst][0] if uj.dst in self.aut.unsafe else [])
            )
            if len(g_atoms) != 1 or len(u_atoms) != 1 or not _complementary(g_atoms[0], u_atoms[0]):
                raise self.src.error(
                    gj.pos,
                    f"goal jump {gj.src} -> {gj.dst} and unsafe jump {uj.src} -> {uj.dst} must test one constraint in opposite directions "
                    f"(e.g. x >= c and x <= c) for a 'reach the goal within the horizon' property",
                )
            # Runs continue only while the goal is not reached; else Verisig's runs could go on
            # from the goal region and the within-goal would be unsound.
            for j in self._continuing(anchor):
                if not any(_implies(a, u_atoms[0]) for a in j.guard):
                    raise self.src.error(
                        j.pos,
                        f"jump {j.src} -> {j.dst} continues the run without requiring {_atom_text(u_atoms[0])}; "
                        f"the goal mode would not end every run that reaches the goal",
                    )
            return _negate(uconds, self.src, uj), True
        if not finals:
            return None, False
        negs = [_negate(conds, self.src, j) for j, conds, _ in finals]
        if len(negs) == 1:
            return negs[0], False
        return _all_of(negs), False

    def _continuous(self, init_timers: dict) -> VerisigProblem:
        aut = self.aut
        F = self.flow_mode
        fmode = self.modes[F]
        P = self._inv_bound(fmode)
        plant = [v for v in self.vars if v not in self.timers and self._const(fmode.ode.get(v, ("num", 0.0))) != 0.0]
        plant_set = set(plant)
        # Prefix: from the initial mode to the first entry into the plant mode.
        if aut.init_mode == F:
            raise self.src.error(
                aut.init_pos,
                f"the run starts in the plant mode '{F}' with its input from the init block; "
                f"start before the controller (as Verisig's generated files do)",
            )
        pre = self._run(aut.init_mode, _Path(dict(self.sym), dict(init_timers)), F, plant_set)
        pre_calls = self.calls  # its obligations are the cycle's own (the same jumps)
        for v in plant:
            if pre.env[v] is not self.sym[v]:
                raise self.src.error(aut.init_pos, f"the jumps before the first flow change the plant state '{v}'; not supported")
        self._check_entry_clock(pre.timers, F)
        entry0 = pre.timers
        anchor1 = {v: entry0[v] + self.timers[v][F] * P for v in self.timers}
        end = self._cycle(F, F, anchor1, plant_set)
        self._check_entry_clock(end.timers, F)
        for v in self.assumed_absolute:
            e = end.timers[v]
            if isinstance(e, _Rel) or abs(e + self.timers[v][F] * P - anchor1[v]) > _TOL:
                raise ParseError(
                    f"{self.src.path}: a jump guard inside the period reads the counter '{v}', which changes from step to step; not supported"
                )
        for v in plant:
            if end.env[v] is not self.sym[v]:
                raise self.src.error(
                    fmode.pos,
                    f"the jumps of one period change the plant state '{v}' of the continuous mode '{F}'; a continuous plant cannot jump",
                )
        self._same_controller(pre_calls, pre.env, self.calls, end.env, plant)
        calls = self.calls
        H = self._steps(end.elapsed + P, end.max_jumps, pre.jumps)
        # Counters at the entry into the plant mode, for each period 0..H.
        entries = [dict(entry0)]
        for n in range(H):
            nxt = {}
            for v in self.timers:
                e = end.timers[v]
                anchor = entries[-1][v] + self.timers[v][F] * P
                nxt[v] = anchor + e.c if isinstance(e, _Rel) else e
            entries.append(nxt)
        # The plant: the flowing mode's ODE; frozen variables it reads are inputs (computed
        # by the period's jumps) or constant parameters (never assigned).
        rhs_vars = set()
        for v in plant:
            rhs_vars |= _ast_vars(fmode.ode[v], set())
        if rhs_vars & set(self.timers):
            clocks = ", ".join(sorted(rhs_vars & set(self.timers)))
            raise self.src.error(fmode.pos, f"the dynamics of '{F}' read the clock/counter(s) {clocks} (time-varying ODE); not supported")
        inputs, params = [], []
        for v in self.vars:
            if v in rhs_vars and v not in plant_set:
                (params if end.env[v] is self.sym[v] else inputs).append(v)
        states = plant + params
        state_set = set(states)
        rhs = {v: _build(self.src, fmode.ode[v], lambda n, p: Expr.var(n)) for v in plant}
        rhs.update({v: 0.0 for v in params})
        ordered = [v for v in self.vars if v in state_set]
        # The property.
        unsafe, absorbing = self._property_edges(F)
        at = _Path(dict(self.sym), {v: 0.0 for v in self.timers})
        safe, finals = [], []
        for conds, text in self.obligations:
            safe.append(_negate(conds, self.src, None))
        for j in unsafe + absorbing:
            timer_atoms, conds = self._edge_conditions(j, at)
            trig = self._flow_trigger(timer_atoms, entries, F, P, H)
            kind = self._classify(trig, f"jump {j.src} -> {j.dst}", j.pos, H)
            if kind is None:
                continue
            if j in absorbing:
                if kind != "always":
                    self.notes.append(f"jump {j.src} -> {j.dst} (line {self.src.line(j.pos)}) ends the run at step {kind[1]} only; ignored")
                    continue
                raise self.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} ends the run early (an absorbing goal) in a continuous model; not supported"
                )
            if kind == "always":
                safe.append(_negate(conds, self.src, j))
            else:
                finals.append((j, conds, kind[1]))
        H = self._horizon(finals, safe, H)
        goal, within = self._final_goal(finals, [], F)
        for c in safe + ([goal] if goal is not None else []):
            extra = set(c.margin().variables()) - state_set
            if extra:
                raise ParseError(f"{self.src.path}: the property reads {sorted(extra)}, which are not plant states of '{F}'")
        stages, _ = self._stages(calls, state_set, {u: end.env[u] for u in inputs})
        init = self._init_box(ordered)
        plant_obj = Continuous({v: rhs[v] for v in ordered}, inputs=inputs, period=P)
        loop = ClosedLoop(plant_obj, stages)
        self._jump_note(H - 1, end.max_jumps, pre.jumps, bool(finals))  # the prefix already enters the first flow
        return self._problem(loop, init, H, goal, safe, within, P)

    def _through(self, R: set, first: str, last: str, timers: dict) -> tuple:
        """The plant modes' time-triggered sequence from ``first`` (entered with ``timers``) to
        ``last``: (timers on leaving ``last``, [(mode, timers on entry, dwell)])."""
        node, t, seq = first, dict(timers), []
        for _ in range(4 * len(R)):
            dwell = self._dwell(node, t)
            seq.append((node, dict(t), dwell))
            t = {v: t[v] + self.timers[v][node] * dwell for v in t}
            if node == last:
                return t, seq
            inner = [j for j in self.out[node] if j.dst in R]
            fire = []
            for j in inner:
                if any(not (_ast_vars(l, set()) | _ast_vars(r, set())) <= set(self.timers) for l, _, r, _ in j.guard):
                    raise self.src.error(
                        j.pos,
                        f"jump {j.src} -> {j.dst} between plant modes has a state guard; only clock-triggered jumps between plant modes are supported",
                    )
                if self._timer_holds(j.guard, _Path({}, t)):
                    fire.append(j)
            if len(fire) != 1:
                raise self.src.error(
                    self.modes[node].pos,
                    f"plant mode '{node}' must leave by exactly one jump into the next plant mode when its clock runs out, found {len(fire)}",
                )
            j = fire[0]
            for v, ast in j.reset.items():
                if v in self.timers:
                    kind, c = self._timer_reset(v, ast)
                    t[v] = c if kind == "set" else t[v] + c
            node = j.dst
        raise self.src.error(self.modes[first].pos, f"the plant modes from '{first}' never reach '{last}'")

    def _conditions(self, atoms: list, where: str) -> list:
        """Constraint atoms as conditions over the variables ('=' as two)."""
        out = []
        for lhs, op, rhs, pos in atoms:
            lv, rv = (_build(self.src, a, lambda n, p: Expr.var(n)) for a in (lhs, rhs))
            for o in ["<=", ">="] if op == "=" else [op]:
                c = _condition(lv, o, rv)
                if c is False:
                    raise self.src.error(pos, f"{where}: the constraint never holds")
                if c is not True:
                    out.append(c)
        return out

    def _hybrid(self, init_timers: dict) -> VerisigProblem:
        """A period through several plant modes (Verisig 2.0's quadrotor MPC: one mode per
        segment), as a :class:`Hybrid` plant: the plant modes with their invariants, the clocked
        jumps between them and the jumps back to the networks (which end the period)."""
        aut = self.aut
        R = set(self.region)
        entering = {j.dst for j in aut.jumps if j.dst in R and j.src not in R}
        leaving = [j for j in aut.jumps if j.src in R and j.dst not in R and j.dst not in self.terminal]
        if len(entering) != 1 or len({j.src for j in leaving}) != 1:
            raise self.src.error(
                self.modes[self.region[0]].pos,
                f"the plant modes {', '.join(self.region)} must be entered through one mode and left (back to the networks) from one mode",
            )
        first, last = entering.pop(), leaving[0].src
        if any(j.dst in R for j in self.out[last]):
            raise self.src.error(self.modes[last].pos, f"plant mode '{last}' leaves to the networks and to plant modes; not supported")
        plant = [
            v for v in self.vars if v not in self.timers and any(self._const(self.modes[m].ode.get(v, ("num", 0.0))) != 0.0 for m in R)
        ]
        plant_set = set(plant)
        if aut.init_mode in R:
            raise self.src.error(
                aut.init_pos,
                f"the run starts in the plant mode '{aut.init_mode}'; start before the controller (as Verisig's generated files do)",
            )
        pre = self._run(aut.init_mode, _Path(dict(self.sym), dict(init_timers)), first, plant_set)
        pre_calls = self.calls
        for v in plant:
            if pre.env[v] is not self.sym[v]:
                raise self.src.error(aut.init_pos, f"the jumps before the first flow change the plant state '{v}'; not supported")
        self._check_entry_clock(pre.timers, first)
        entry0 = pre.timers
        exit0, seq = self._through(R, first, last, entry0)
        period = sum(d for _, _, d in seq)
        self.flow_mode = last  # the networks' part of the period starts where the plant modes end
        end = self._cycle(last, first, exit0, plant_set)
        self._check_entry_clock(end.timers, first)
        for v in plant:
            if end.env[v] is not self.sym[v]:
                raise self.src.error(
                    self.modes[first].pos, f"the jumps between the plant modes' visits change the plant state '{v}'; not supported"
                )
        self._same_controller(pre_calls, pre.env, self.calls, end.env, plant)
        calls = self.calls
        H = self._steps(end.elapsed + period, end.max_jumps + len(seq) - 1, pre.jumps)
        entries = [dict(entry0)]
        for _ in range(H):
            out_t, _ = self._through(R, first, last, entries[-1])
            entries.append({v: out_t[v] + e.c if isinstance(e := end.timers[v], _Rel) else e for v in self.timers})
        inner = [j for j in aut.jumps if j.src in R and j.dst in R]
        # Clocks the plant modes test become states of the plant; each period must enter them at the same values.
        tested = set()
        for m in R:
            for lhs, _, rhs, _ in self.modes[m].inv:
                tested |= _ast_vars(lhs, set()) | _ast_vars(rhs, set())
        for j in inner + leaving:
            for lhs, _, rhs, _ in j.guard:
                tested |= _ast_vars(lhs, set()) | _ast_vars(rhs, set())
        clocks = [v for v in self.vars if v in self.timers and v in tested]
        for v in clocks:
            if any(abs(e[v] - entry0[v]) > _TOL for e in entries):
                raise ParseError(
                    f"{self.src.path}: the clock '{v}' enters the plant mode '{first}' at different values in different periods; not supported"
                )
        read = set()
        for m in R:
            for v in plant:
                read |= _ast_vars(self.modes[m].ode.get(v, ("num", 0.0)), set())
        read |= tested
        for j in inner:
            for ast in j.reset.values():
                read |= _ast_vars(ast, set())
        if read & set(self.timers) - set(clocks):
            raise self.src.error(
                self.modes[first].pos, f"the plant modes read the counters {sorted(read & set(self.timers) - set(clocks))}; not supported"
            )
        inputs, params = [], []
        for v in self.vars:
            if v in read and v not in plant_set and v not in self.timers:
                (params if end.env[v] is self.sym[v] else inputs).append(v)
        states = plant + params + clocks
        state_set = set(states)
        build = lambda ast: _build(self.src, ast, lambda n, p: Expr.var(n))  # noqa: E731
        modes = {}
        for m in self.region:
            mode = self.modes[m]
            rhs = {v: build(mode.ode.get(v, ("num", 0.0))) for v in plant + clocks}
            modes[m] = Mode(rhs, invariant=self._conditions(mode.inv, f"invariant of '{m}'"))
        jumps = []
        for j in inner + leaving:
            resets = {}
            for v, ast in j.reset.items():
                if v in state_set:
                    resets[v] = build(ast)
                elif j in inner:
                    raise self.src.error(
                        j.pos, f"jump {j.src} -> {j.dst} between plant modes assigns '{v}', which is not a plant state; not supported"
                    )
            jumps.append(
                Jump(j.src, j.dst if j in inner else None, guard=self._conditions(j.guard, f"jump {j.src} -> {j.dst}"), reset=resets)
            )
        # The property: jumps into unsafe modes leave the last plant mode at the end of a period, or at any time.
        unsafe, absorbing = self._property_edges(last)
        at = _Path(dict(self.sym), {v: 0.0 for v in self.timers})
        safe = [_negate(conds, self.src, None) for conds, _ in self.obligations]
        finals = []
        last_entries = [self._through(R, first, last, e)[1][-1][1] for e in entries[:H]] + [None]
        for j in unsafe + absorbing:
            if j in absorbing:
                raise self.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} ends the run early (an absorbing goal) in a hybrid model; not supported"
                )
            timer_atoms, conds = self._edge_conditions(j, at)
            dwell = seq[-1][2]
            trig = self._flow_trigger(timer_atoms, last_entries, last, dwell, H)
            ends = {n + 1 for n in range(H) if self._timer_holds(timer_atoms, _Path({}, self._through(R, first, last, entries[n])[0]))}
            if trig != "always" and set(trig) != ends:
                raise self.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} fires inside a period; only at the ends of periods or at all times is supported"
                )
            kind = self._classify(trig, f"jump {j.src} -> {j.dst}", j.pos, H)
            if kind == "always":
                safe.append(_negate(conds, self.src, j))
            elif kind is not None:
                finals.append((j, conds, kind[1]))
        H = self._horizon(finals, safe, H)
        goal, within = self._final_goal(finals, [], last)
        for c in safe + ([goal] if goal is not None else []):
            extra = set(c.margin().variables()) - state_set
            if extra:
                raise ParseError(f"{self.src.path}: the property reads {sorted(extra)}, which are not plant states")
        stages, _ = self._stages(calls, state_set, {u: end.env[u] for u in inputs})
        ordered = [v for v in self.vars if v in state_set]
        init = {**self._init_box([v for v in ordered if v not in clocks]), **{v: (entry0[v], entry0[v]) for v in clocks}}
        init = {v: init[v] for v in ordered}
        step = min(d for _, _, d in seq if d > _TOL) / 10
        hybrid = Hybrid(modes, jumps, inputs=inputs, start=first, max_time=2 * period, step=step, max_jumps=4 * len(seq))
        loop = ClosedLoop(hybrid, stages)
        self.notes.append(
            f"plant modes {' -> '.join(m for m, _, _ in seq)} per period, verified as a hybrid plant (Taylor models through the jumps)"
        )
        self._jump_note(H - 1, end.max_jumps + len(seq) - 1, pre.jumps, bool(finals))
        return self._problem(loop, init, H, goal, safe, within, period)

    def _check_entry_clock(self, timers: dict, F: str):
        for lhs, op, rhs, pos in self.modes[F].inv:
            if lhs[0] == "var" and lhs[1] in self.timers:
                t = timers[lhs[1]]
                if isinstance(t, _Rel) or abs(t) > _TOL:
                    raise self.src.error(pos, f"the plant mode '{F}' is entered with '{lhs[1]}' = {t}, not 0: its dwell time would vary")

    def _flow_trigger(self, atoms: list, entries: list, F: str, P: float, H: int):
        """When a jump leaving the flowing mode can fire, as step indices: flow time 0 of
        period n is step n, time P is step n + 1. Like Flow*, no flow starts at the time
        horizon, so a guard that holds only from then on (f1tenth's ``k = 50``) never fires."""
        if not atoms:
            return "always"
        always, any_full, steps = True, False, set()
        for n in range(H):
            span = P
            lo, hi = 0.0, span
            for lhs, op, rhs, pos in atoms:

                def margin(tau):
                    st = _Path({}, {v: entries[n][v] + self.timers[v][F] * tau for v in self.timers})
                    return _fold("-", self._value(lhs, st), self._value(rhs, st))

                m0, m1 = margin(0.0), margin(span)
                if span > 0 and abs(margin(span / 2) - (m0 + m1) / 2) > _TOL * max(1.0, abs(m0), abs(m1)):
                    raise self.src.error(pos, "a clock/counter constraint that is not linear in time")
                a, b = _solve(m0, (m1 - m0) / span if span > 0 else 0.0, op, span)
                lo, hi = max(lo, a), min(hi, b)
            empty = lo > hi + _TOL
            full = not empty and lo <= _TOL and hi >= span - _TOL
            if not full:
                always = False
            if empty:
                continue
            if full:
                any_full = True
                steps |= {n, n + 1}
            elif hi - lo > _TOL:
                raise ParseError(f"{self.src.path}: a property jump out of '{F}' fires during part of period {n} only; not supported")
            elif abs(lo) <= _TOL:
                steps.add(n)
            elif abs(lo - span) <= _TOL:
                steps.add(n + 1)
            else:
                raise ParseError(
                    f"{self.src.path}: a property jump out of '{F}' fires inside period {n} (t = {lo} of {span}); only step boundaries are supported"
                )
        if always:
            return "always"
        if any_full:
            raise ParseError(f"{self.src.path}: a property jump out of '{F}' fires during some periods only; not supported")
        return steps

    def _same_controller(self, pre_calls, pre_env, calls, env, plant):
        """The jumps before the first flow must compute what each period computes: compare the
        network inputs and plant-mode inputs on random states."""
        if len(pre_calls) != len(calls) or any(a.net is not b.net for a, b in zip(pre_calls, calls)):
            raise ParseError(
                f"{self.src.path}: the jumps before the first flow evaluate the networks differently from a period; not supported"
            )
        box = {v: self.aut.init.get(v, (0.0, 0.0)) for v in self.vars}
        rng = np.random.default_rng(0)
        names = sorted(
            {n for c in calls for v in c.inputs if isinstance(v, Expr) for n in v.variables()}
            | {n for c in pre_calls for v in c.inputs if isinstance(v, Expr) for n in v.variables()}
        )
        values = {}
        for n in names:
            lo, hi = box.get(n, (-1.0, 1.0))
            values[n] = lo + (hi - lo) * rng.random(32)
        for a, b in zip(pre_calls, calls):
            x, y = _evaluate(a.inputs, values), _evaluate(b.inputs, values)
            if not np.allclose(x, y, equal_nan=True, rtol=1e-9, atol=1e-12):
                raise ParseError(
                    f"{self.src.path}: the network inputs computed before the first flow differ from those of a period; not supported"
                )

    def _stages(self, calls: list, states: set, computed_inputs: dict) -> tuple:
        """Stages for the network calls (with an expression stage for their inputs unless they
        are plain states), then for plant inputs that are not plain network outputs."""
        stages, signals = [], []
        known = set(states)
        renamed: dict = {}
        # A plant input that is an affine map of one width-1 network output becomes that
        # network's own output, scaled (ex1: u := 4 * _f1).
        for u, e in computed_inputs.items():
            if isinstance(e, Expr):
                vs = e.variables()
                if len(vs) == 1 and any(vs[0] == c.output and c.net.n_out == 1 for c in calls):
                    others = [x for w, x in computed_inputs.items() if w != u and isinstance(x, Expr) and vs[0] in x.variables()]
                    if not others and vs[0] not in renamed:
                        b = float(_evaluate([e], {vs[0]: np.array([0.0])})[0, 0])
                        a = float(_evaluate([e], {vs[0]: np.array([1.0])})[0, 0]) - b
                        check = float(_evaluate([e], {vs[0]: np.array([-1.5])})[0, 0])
                        if abs(check - (b - 1.5 * a)) <= 1e-12 * max(1.0, abs(a), abs(b)):
                            renamed[vs[0]] = (u, a, b)
        for c in calls:
            # Plain states and signals, and constants (a set speed), wire the network directly.
            plain = [v.name() if isinstance(v, Expr) else v if _is_num(v) else None for v in c.inputs]
            names = [p for p in plain if isinstance(p, str)]
            if all(p is not None and (p in known or _is_num(p)) for p in plain) and len(set(names)) == len(names):
                wired = plain
            else:
                in_name = self._fresh(f"{c.output}_in")
                exprs = [_as_expr(v) for v in c.inputs]
                used = sorted({n for e in exprs for n in e.variables()}, key=_order_key(self.vars))
                missing = [n for n in used if n not in known]
                if missing:
                    raise ParseError(
                        f"{self.src.path}: the inputs of the network in '{c.mode}' read {missing}, which are neither plant states nor earlier signals"
                    )
                if not used:
                    raise ParseError(f"{self.src.path}: the inputs of the network in '{c.mode}' are constants")
                stages.append(Stage(exprs, inputs=used, output=in_name))
                known.add(in_name)
                wired = [in_name]
            if c.output in renamed:
                u, a, b = renamed[c.output]
                stages.append(Stage(c.net, inputs=wired, output=u, scale=a, offset=b))
                known.add(u)
                signals.append(u)
            else:
                stages.append(Stage(c.net, inputs=wired, output=c.output))
                names = [c.output] if c.net.n_out == 1 else [f"{c.output}_{i}" for i in range(c.net.n_out)]
                known.update(names)
                known.add(c.output)
                signals.append(c.output)
        done = {r[0] for r in renamed.values()}
        for u, e in computed_inputs.items():
            if u in done:
                continue
            e = _as_expr(e)
            used = sorted(set(e.variables()), key=_order_key(self.vars))
            missing = [n for n in used if n not in known]
            if missing:
                raise ParseError(
                    f"{self.src.path}: the plant input '{u}' reads {missing} from the previous period; only plant states carry over between periods"
                )
            if not used:
                raise ParseError(f"{self.src.path}: the plant input '{u}' is a constant; make it a parameter instead")
            stages.append(Stage([e], inputs=used, output=u))
            known.add(u)
            signals.append(u)
        return stages, signals

    def _init_box(self, states: list) -> dict:
        missing = [v for v in states if v not in self.aut.init]
        if missing:
            raise self.src.error(self.aut.init_pos, f"init gives no interval for {', '.join(missing)}, which the translated loop needs")
        return {v: tuple(self.aut.init[v]) for v in states}

    def _problem(self, loop, init, H, goal, safe, within, period) -> VerisigProblem:
        ignored = self.aut.settings.get("ignored", [])
        if ignored:
            self.notes.append(f"Flow* integration settings not used by percver: {'; '.join(ignored)}")
        return VerisigProblem(
            self.src.path,
            loop,
            init,
            H,
            goal,
            safe,
            within,
            period,
            list(self.networks),
            self.notes,
            {k: v for k, v in self.aut.settings.items() if k != "ignored"},
        )


# ----------------------------------------------------------------------------- small helpers


def _compare(lv, op: str, rv) -> bool:
    d = lv - rv
    tol = _TOL * max(1.0, abs(lv), abs(rv))
    return {"<=": d <= tol, ">=": d >= -tol, "<": d < tol, ">": d > -tol, "=": abs(d) <= tol}[op]


def _timer_equal(a, b) -> bool:
    if isinstance(a, _Rel) or isinstance(b, _Rel):
        return a == b
    return abs(a - b) <= _TOL * max(1.0, abs(a))


def _solve(m0: float, slope: float, op: str, span: float) -> tuple:
    """The times tau in [0, span] where m0 + slope * tau satisfies ``op`` against 0."""
    tol = _TOL * max(1.0, abs(m0))
    if abs(slope) <= _TOL:
        return (0.0, span) if _compare(m0, op, 0.0) else (1.0, 0.0)
    root = -m0 / slope
    if op == "=":
        return (min(max(root, 0.0), span),) * 2 if -tol <= root <= span + tol else (1.0, 0.0)
    holds_after = (slope > 0) == (op in (">=", ">"))
    return (max(root, 0.0), span) if holds_after else (0.0, min(root, span))


def _dedupe(conds: list) -> list:
    out = []
    for c in conds:
        if c is True:
            continue
        if c is False:
            return [False]
        if not any(c is d or repr(c) == repr(d) for d in out):
            out.append(c)
    return out


def _dedupe_atoms(atoms: list) -> list:
    out = []
    for a in atoms:
        if not any(_same_ast(a[0], b[0]) and a[1] == b[1] and _same_ast(a[2], b[2]) for b in out):
            out.append(a)
    return out


def _complementary(a, b) -> bool:
    """``x >= c`` and ``x <= c`` (same sides, opposite directions)."""
    flips = {("<=", ">="), (">=", "<="), ("<", ">="), (">=", "<"), (">", "<="), ("<=", ">")}
    return _same_ast(a[0], b[0]) and _same_ast(a[2], b[2]) and (a[1], b[1]) in flips


def _implies(a, b) -> bool:
    """Does atom a (``x <= c1``) imply atom b (``x <= c2``)?  Decided for constant right sides."""
    if not _same_ast(a[0], b[0]) or a[1] not in ("<=", "<", ">=", ">") or b[1] not in ("<=", "<", ">=", ">"):
        return False
    if a[1][0] != b[1][0]:
        return False
    ca, cb = _const_ast(a[2]), _const_ast(b[2])
    if ca is None or cb is None:
        return _same_ast(a[2], b[2]) and (a[1] == b[1] or len(a[1]) == 1)
    return ca <= cb if a[1][0] == "<" else ca >= cb


def _const_ast(ast) -> Optional[float]:
    if ast[0] == "num":
        return ast[1]
    if ast[0] == "neg" and ast[1][0] == "num":
        return -ast[1][1]
    return None


def _atom_text(a) -> str:
    def t(x):
        if x[0] == "num":
            return repr(x[1])
        if x[0] == "var":
            return x[1]
        return "(...)"

    return f"{t(a[0])} {a[1]} {t(a[2])}"


def _negate(conds: list, src: _Source, jump: Optional[_Jump]) -> Condition:
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
        return _condition(c.lhs, flip, c.rhs)
    gs = []
    for c in conds:
        m = c.margin()
        gs.append(m if c.op in (">=", ">") else -m)
    g = gs[0]
    for other in gs[1:]:
        g = _min2(g, other)
    return g < 0.0


# The engine decides one goal condition, so a conjunction becomes one margin. Taylor-model
# min/max take a hull when the order is undecided, losing the dependency; these forms are exact
# where the order is decided and symmetric where it is not (ex1's goal needs the difference).
def _max2(a, b):
    return (a + b + Expr.apply("abs", a - b)) * 0.5


def _min2(a, b):
    return (a + b - Expr.apply("abs", a - b)) * 0.5


def _all_of(conds: list) -> Condition:
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
        value = float(_evaluate([rhs], {})[0, 0])
        bounds.setdefault(repr(c.lhs), (c.lhs, [], []))[1 if c.op == "<" else 2].append(value)
    for e, highs, lows in bounds.values():
        if len(highs) == 1 and len(lows) == 1 and lows[0] < highs[0]:
            centre, radius = 0.5 * (lows[0] + highs[0]), 0.5 * (highs[0] - lows[0])
            margins.append(((e - centre) * (1.0 / radius)) ** 2 - 1.0)
        else:
            margins += [e - h for h in highs] + [lo - e for lo in lows]
    m = margins[0]
    for other in margins[1:]:
        m = _max2(m, other)
    return m < 0.0


def _evaluate(values: list, columns: dict) -> np.ndarray:
    exprs = [_as_expr(v) for v in values]
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 1
    pts = np.column_stack([np.asarray(columns[k], float) for k in names]) if names else np.zeros((n, 0))
    return _core.eval_float(exprs, names, np.ascontiguousarray(pts))


def _order_key(variables: list):
    index = {v: i for i, v in enumerate(variables)}
    return lambda n: (index.get(n, len(index)), n)


def _assignments(t, src, variables, op: str, what: str) -> dict:
    """``x' <op> expression`` lines up to the closing brace: ODE equations (``=``) or resets
    (``:=``); ``what`` starts the error message for an undeclared variable."""
    out = {}
    while t.peek()[1] != "}":
        _, v, vpos = t.ident(f'"x\' {op} expression"')
        if v not in variables:
            raise src.error(vpos, f"{what} undeclared variable '{v}'")
        t.expect("'", f"after '{v}' in \"{v}' {op} ...\"")
        t.expect(op, f'in "{v}\' {op} ..."')
        out[v] = t.expr()
    return out
