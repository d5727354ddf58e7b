"""Verisig 2.0 closed-loop models: Flow* ``hybrid reachability`` files with DNN modes, read.

:func:`read` returns the file as a hybrid automaton (:class:`Automaton`: variables, settings,
modes with their ODEs and invariants, jumps with guards and resets, the initial set, the unsafe
sets) with every expression an AST and every construct's position, so errors name file and line.
It does not interpret the model: :mod:`percver.translation` turns it into a percver closed loop.
"""

from __future__ import annotations

import bisect
import re
import warnings
from dataclasses import dataclass
from pathlib import Path


from percver.errors import MissingFileError, ParseError

__all__ = ["read", "Automaton", "AutomatonMode", "AutomatonJump"]

_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TOKEN = re.compile(rf"\s*(?:(?P<num>{_NUMBER})|(?P<id>[A-Za-z_]\w*)|(?P<op>:=|->|<=|>=|==|[-+*/^()\[\],'=<>{{}}]))")
_FUNCTIONS = {"sin", "cos", "tan", "atan", "exp", "log", "sqrt", "tanh", "sigmoid", "abs"}


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


def _block(text: str, start: int, path: str) -> tuple[str, int]:
    """The text inside the braces opening at or after ``start``, and the index after them."""
    open_at = text.index("{", start)
    depth = 0
    for i in range(open_at, len(text)):
        if text[i] == "{":
            depth += 1
        elif text[i] == "}":
            depth -= 1
            if depth == 0:
                return text[open_at + 1 : i], i + 1
    raise ParseError(f"{path}: unbalanced '{{' at line {text.count(chr(10), 0, open_at) + 1}")


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
class AutomatonMode:
    name: str
    pos: int
    ode: dict  # var -> ast
    inv: list  # atoms


@dataclass
class AutomatonJump:
    src: str
    dst: str
    pos: int
    guard: list
    reset: dict  # var -> ast


@dataclass
class Automaton:
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


def read(path: str) -> Automaton:
    """The model file as a hybrid automaton, untranslated; ``percver.ParseError`` names file
    and line of anything that is not Verisig's Flow* syntax."""
    return _parse(path)


def _parse(path: str) -> Automaton:
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
    return Automaton(src, variables, settings, modes, jumps, init_mode, init, init_pos, unsafe, notes)


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
        modes[name] = AutomatonMode(name, pos, ode, inv)
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
        jumps.append(AutomatonJump(a, b, pos, guard, reset))
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
