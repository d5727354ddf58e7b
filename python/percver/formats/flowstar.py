"""Flow* ``continuous reachability`` model files: parse them and run them with their own settings.

Supported: ``state var``, the settings block (fixed/adaptive steps and orders, time, remainder
estimation as a number or per variable, QR/identity precondition, cutoff; plotting, output,
precision and print lines are read and ignored), ``poly ode N`` / ``nonpoly ode`` /
``nonpoly ode { N }`` (all integrated by the same Taylor-model Picard engine), and ``init``.
Anything else is refused with the file name, line and what is supported.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from percver import _core
from percver.errors import ParseError


@dataclass
class FlowstarModel:
    path: str
    variables: list
    odes: dict  # name -> expression text
    init: dict  # name -> (lo, hi)
    t_end: float
    step: object  # float or (min, max)
    order: object  # int or (min, max)
    remainder: list
    precondition: str = "identity"
    cutoff: float = 1e-10
    ode_kind: str = "nonpoly ode"
    symbolic_queue: int = 100
    ignored: list = field(default_factory=list)

    def run(self, *, progress: bool = False, on_failure: str = "raise", refinements: int = 30):
        """Integrate with the file's settings; returns a :class:`percver.flowpipe.Flowpipe`."""
        from percver.flowpipe import flowpipe

        ode = {v: _core.Expr.parse(self.odes[v]) for v in self.variables}
        adaptive = self.step if isinstance(self.step, tuple) else None
        step = self.step if not isinstance(self.step, tuple) else 0.0
        return flowpipe(
            ode,
            {v: self.init[v] for v in self.variables},
            self.t_end,
            order=self.order,
            step=step,
            adaptive=adaptive,
            precondition=self.precondition,
            cutoff=self.cutoff,
            remainder=dict(zip(self.variables, self.remainder)),
            refinements=refinements,
            symbolic_queue=self.symbolic_queue,
            progress=progress,
            on_failure=on_failure,
        )


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


def _line_of(text: str, needle: str) -> int:
    i = text.find(needle)
    return text.count("\n", 0, i) + 1 if i >= 0 else 0


def load_flowstar(path: str) -> FlowstarModel:
    """Parses a Flow* continuous model file."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"Flow* model '{path}' does not exist")
    text = re.sub(r"#[^\n]*", "", p.read_text())
    name = str(p)
    m = re.search(r"continuous\s+reachability", text)
    if not m:
        if "hybrid reachability" in text:
            raise ParseError(f"{name}: hybrid models are read by percver.formats.load_verisig (closed-loop verification), not load_flowstar")
        raise ParseError(f"{name}: expected 'continuous reachability {{ ... }}' at the top")
    body, _ = _block(text, m.end(), name)
    sv = re.search(r"state\s+var\s+([^\n]+)", body)
    if not sv:
        raise ParseError(f"{name}: missing 'state var x, y, ...' line")
    variables = [v.strip() for v in sv.group(1).split(",") if v.strip()]
    s = re.search(r"\bsetting\b", body)
    if not s:
        raise ParseError(f"{name}: missing 'setting {{ ... }}' block")
    settings, _ = _block(body, s.end(), name)
    step: object = None
    order: object = None
    t_end: Optional[float] = None
    remainder = [1e-4] * len(variables)
    precondition = "identity"
    cutoff = 1e-10
    ignored = []
    number = r"([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"
    for raw in re.split(r"\n", settings):
        line = raw.strip()
        if not line:
            continue
        if mm := re.fullmatch(rf"fixed\s+steps\s+{number}", line):
            step = float(mm.group(1))
        elif mm := re.fullmatch(rf"adaptive\s+steps\s*\{{\s*min\s+{number}\s*,\s*max\s+{number}\s*\}}", line):
            step = (float(mm.group(1)), float(mm.group(2)))
        elif mm := re.fullmatch(rf"time\s+{number}", line):
            t_end = float(mm.group(1))
        elif mm := re.fullmatch(rf"remainder\s+estimation\s+{number}", line):
            remainder = [float(mm.group(1))] * len(variables)
        elif mm := re.fullmatch(r"remainder\s+estimation\s*\{(.*)\}", line):
            pairs = re.findall(rf"(\w+)\s*:\s*\[\s*{number}\s*,\s*{number}\s*\]", mm.group(1))
            per = {v: max(abs(float(a)), abs(float(b))) for v, a, b in pairs}
            remainder = [per.get(v, 1e-4) for v in variables]
        elif re.fullmatch(r"QR\s+precondition", line):
            # Flow* 2.1.0 parses this keyword but never calls its QR code (FLOWSTAR-NOTES §4):
            # both keywords run translate-and-scale, which is our "identity".
            precondition = "identity"
        elif re.fullmatch(r"identity\s+precondition", line):
            precondition = "identity"
        elif mm := re.fullmatch(r"fixed\s+orders?\s+(\d+)", line):
            order = int(mm.group(1))
        elif mm := re.fullmatch(r"adaptive\s+orders\s*\{\s*min\s+(\d+)\s*,\s*max\s+(\d+)\s*\}", line):
            order = (int(mm.group(1)), int(mm.group(2)))
        elif mm := re.fullmatch(r"adaptive\s+orders\s*\{\s*min\s*\{([^}]*)\}\s*,\s*max\s*\{([^}]*)\}\s*\}", line):
            # Per-variable orders: one order for all variables (the largest given).
            lows = [int(v) for v in re.findall(r":\s*(\d+)", mm.group(1))]
            highs = [int(v) for v in re.findall(r":\s*(\d+)", mm.group(2))]
            order = (max(lows), max(highs))
        elif mm := re.fullmatch(r"fixed\s+orders?\s*\{([^}]*)\}", line):
            order = max(int(v) for v in re.findall(r":\s*(\d+)", mm.group(1)))
        elif mm := re.fullmatch(rf"cutoff\s+{number}", line):
            cutoff = float(mm.group(1))
        elif re.match(r"(gnuplot|matlab|output|print|precision|max\s+jumps|no\s+output|tm\s+output)", line):
            ignored.append(line)
        else:
            raise ParseError(f"{name}, line {_line_of(text, line)}: unsupported setting '{line}'")
    for what, value in (("a step size", step), ("an order", order), ("a time horizon", t_end)):
        if value is None:
            raise ParseError(f"{name}: the setting block gives no {what}")
    o = re.search(r"\b(poly\s+ode\s+\d|nonpoly\s+ode|linear\s+ode|lti\s+ode|ltv\s+ode)\b", body)
    if not o:
        raise ParseError(f"{name}: no ODE block ('poly ode N {{...}}' or 'nonpoly ode {{...}}')")
    kind = re.sub(r"\s+", " ", o.group(1))
    if kind in ("lti ode", "ltv ode"):
        raise ParseError(f"{name}: '{kind}' models are not supported yet; rewrite them as 'nonpoly ode'")
    rest = body[o.end() :]
    after = rest.lstrip()
    symbolic_queue = 100  # percver always keeps remainders symbolically; the file may size the queue
    if queue := re.match(r"\{\s*(\d+)\s*\}", after):
        symbolic_queue = max(1, int(queue.group(1)))
        rest = after[queue.end() :]
    ode_text, end = _block(rest, 0, name)
    odes = {}
    for raw in ode_text.split("\n"):
        line = raw.strip()
        if not line:
            continue
        mm = re.fullmatch(r"(\w+)\s*'\s*=\s*(.+)", line)
        if not mm:
            raise ParseError(f"{name}, line {_line_of(text, line)}: expected \"x' = expression\", got '{line}'")
        v, rhs = mm.group(1), mm.group(2)
        if v not in variables:
            raise ParseError(f"{name}, line {_line_of(text, line)}: equation for undeclared variable '{v}' (state var: {', '.join(variables)})")
        try:
            _core.Expr.parse(rhs)
        except ParseError as e:
            raise ParseError(f"{name}, line {_line_of(text, line)}: {e}") from None
        odes[v] = rhs
    missing = [v for v in variables if v not in odes]
    if missing:
        raise ParseError(f"{name}: no equation for {', '.join(missing)}; add \"{missing[0]}' = ...\" to the ODE block")
    i = re.search(r"\binit\b", rest[end:])
    if not i:
        raise ParseError(f"{name}: missing 'init {{ ... }}' block")
    init_text, _ = _block(rest[end:], i.end(), name)
    init = {}
    for v, a, b in re.findall(rf"(\w+)\s+in\s+\[\s*{number}\s*,\s*{number}\s*\]", init_text):
        init[v] = (float(a), float(b))
    missing = [v for v in variables if v not in init]
    if missing:
        raise ParseError(f"{name}: the init block gives no interval for {', '.join(missing)}")
    return FlowstarModel(name, variables, odes, init, t_end, step, order, remainder, precondition, cutoff, kind, symbolic_queue, ignored)
