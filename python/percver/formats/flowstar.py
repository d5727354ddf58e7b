"""Flow* model files: parse them and run them with their own settings.

``continuous reachability``: ``state var``, the settings block (fixed/adaptive steps and orders,
time, remainder estimation as a number or per variable, QR/identity precondition, cutoff;
plotting, output, precision and print lines are read and ignored), ``poly ode N`` / ``nonpoly
ode`` / ``nonpoly ode { N }`` (all integrated by the same Taylor-model Picard engine), and
``init``. Anything else is refused with the file name, line and what is supported.

``hybrid reachability`` (read with the Verisig model parser, :mod:`percver.formats.verisig`):
modes with ODEs and invariants, jumps with guards and resets, the initial mode and box, the
horizon ``time`` and ``max jumps``. The reader gives a :class:`FlowstarHybrid`: the automaton as a
:class:`percver.Hybrid`, whose reach set :func:`percver.flowpipe.hybrid_flowpipe` computes with
Taylor models carried through the jumps (Flow*'s way; ``run(jumps="box")`` boxes them instead).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

from percver import _core
from percver.errors import MissingFileError, ParseError
from percver.flowpipe import HybridFlowpipe, hybrid_flowpipe
from percver.formats.verisig import _block
from percver.systems import Hybrid, Jump, Mode


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


def _line_of(text: str, needle: str) -> int:
    i = text.find(needle)
    return text.count("\n", 0, i) + 1 if i >= 0 else 0


_NUMBER = r"([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"


def _integration_settings(lines: list, variables: list, name: str, text: str) -> dict:
    """Step, order, horizon, remainder estimates, precondition and cutoff of a setting block."""
    step: object = None
    order: object = None
    t_end: Optional[float] = None
    remainder = [1e-4] * len(variables)
    precondition = "identity"
    cutoff = 1e-10
    ignored = []
    for raw in lines:
        line = raw.strip()
        if not line:
            continue
        if mm := re.fullmatch(rf"fixed\s+steps\s+{_NUMBER}", line):
            step = float(mm.group(1))
        elif mm := re.fullmatch(rf"adaptive\s+steps\s*\{{\s*min\s+{_NUMBER}\s*,\s*max\s+{_NUMBER}\s*\}}", line):
            step = (float(mm.group(1)), float(mm.group(2)))
        elif mm := re.fullmatch(rf"time\s+{_NUMBER}", line):
            t_end = float(mm.group(1))
        elif mm := re.fullmatch(rf"remainder\s+estimation\s+{_NUMBER}", line):
            remainder = [float(mm.group(1))] * len(variables)
        elif mm := re.fullmatch(r"remainder\s+estimation\s*\{(.*)\}", line):
            pairs = re.findall(rf"(\w+)\s*:\s*\[\s*{_NUMBER}\s*,\s*{_NUMBER}\s*\]", mm.group(1))
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
        elif mm := re.fullmatch(rf"cutoff\s+{_NUMBER}", line):
            cutoff = float(mm.group(1))
        elif re.match(r"(gnuplot|matlab|output|print|precision|max\s+jumps|no\s+output|tm\s+output)", line):
            ignored.append(line)
        else:
            raise ParseError(f"{name}, line {_line_of(text, line)}: unsupported setting '{line}'")
    return dict(step=step, order=order, t_end=t_end, remainder=remainder, precondition=precondition, cutoff=cutoff, ignored=ignored)


def load_flowstar(path: str) -> Union[FlowstarModel, FlowstarHybrid]:
    """Parses a Flow* model file: a :class:`FlowstarModel` (continuous) or a :class:`FlowstarHybrid`."""
    p = Path(path)
    if not p.exists():
        raise MissingFileError(f"Flow* model '{path}' does not exist")
    text = re.sub(r"#[^\n]*", "", p.read_text())
    name = str(p)
    if re.match(r"\s*hybrid\s+reachability", text):
        return _load_hybrid(name)
    m = re.search(r"continuous\s+reachability", text)
    if not m:
        raise ParseError(f"{name}: expected 'continuous reachability {{ ... }}' or 'hybrid reachability {{ ... }}' at the top")
    body, _ = _block(text, m.end(), name)
    sv = re.search(r"state\s+var\s+([^\n]+)", body)
    if not sv:
        raise ParseError(f"{name}: missing 'state var x, y, ...' line")
    variables = [v.strip() for v in sv.group(1).split(",") if v.strip()]
    s = re.search(r"\bsetting\b", body)
    if not s:
        raise ParseError(f"{name}: missing 'setting {{ ... }}' block")
    settings, _ = _block(body, s.end(), name)
    found = _integration_settings(settings.split("\n"), variables, name, text)
    step, order, t_end = found["step"], found["order"], found["t_end"]
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
            raise ParseError(
                f"{name}, line {_line_of(text, line)}: equation for undeclared variable '{v}' (state var: {', '.join(variables)})"
            )
        try:
            unknown = sorted(set(_core.Expr.parse(rhs).variables()) - set(variables))
        except ParseError as e:
            raise ParseError(f"{name}, line {_line_of(text, line)}: {e}") from None
        if unknown:
            raise ParseError(
                f'{name}, line {_line_of(text, line)}: the ODE "{v}\' = {rhs}" uses {", ".join(map(repr, unknown))}, '
                f"which is not a state variable (state var: {', '.join(variables)}); declare it or fix the name"
            )
        odes[v] = rhs
    missing = [v for v in variables if v not in odes]
    if missing:
        raise ParseError(f'{name}: no equation for {", ".join(missing)}; add "{missing[0]}\' = ..." to the ODE block')
    i = re.search(r"\binit\b", rest[end:])
    if not i:
        raise ParseError(f"{name}: missing 'init {{ ... }}' block")
    init_text, _ = _block(rest[end:], i.end(), name)
    init = {}
    for v, a, b in re.findall(rf"(\w+)\s+in\s+\[\s*{_NUMBER}\s*,\s*{_NUMBER}\s*\]", init_text):
        init[v] = (float(a), float(b))
    missing = [v for v in variables if v not in init]
    if missing:
        raise ParseError(f"{name}: the init block gives no interval for {', '.join(missing)}")
    return FlowstarModel(
        name,
        variables,
        odes,
        init,
        t_end,
        step,
        order,
        found["remainder"],
        found["precondition"],
        found["cutoff"],
        kind,
        symbolic_queue,
        found["ignored"],
    )


# ----------------------------------------------------------------------------- hybrid models


@dataclass
class FlowstarHybrid:
    """A Flow* ``hybrid reachability`` model as read: the automaton (``plant``, a
    :class:`percver.Hybrid` starting in the file's initial mode), the initial box and the file's
    settings. :meth:`run` hands them to :func:`percver.flowpipe.hybrid_flowpipe`."""

    path: str
    plant: Hybrid
    init: dict
    t_end: float
    max_jumps: int
    step: object  # float or (min, max)
    order: object  # int or (min, max)
    remainder: list
    cutoff: float
    ignored: list = field(default_factory=list)

    @property
    def variables(self) -> list:
        return self.plant.states

    @property
    def modes(self) -> dict:
        return self.plant.modes

    @property
    def jumps(self) -> list:
        return self.plant.jumps

    def run(self, *, jumps: str = "taylor", max_branches: int = 64) -> HybridFlowpipe:
        """The reach set with the file's settings (see :func:`percver.flowpipe.hybrid_flowpipe`)."""
        return hybrid_flowpipe(
            self.plant,
            self.init,
            self.t_end,
            order=self.order,
            step=self.step,
            cutoff=self.cutoff,
            remainder=self.remainder,
            max_jumps=self.max_jumps,
            max_branches=max_branches,
            jumps=jumps,
        )


def _expr(ast) -> "_core.Expr":
    """An Expr from a Verisig-parser AST. Long sums are left-nested: their left spine is walked
    in a loop (one recursion per term would exceed Python's limit on a 600-input layer)."""
    spine = []
    while ast[0] == "bin":
        spine.append(ast)
        ast = ast[2]
    kind = ast[0]
    if kind == "num":
        value = _core.Expr.constant(ast[1])
    elif kind == "var":
        value = _core.Expr.var(ast[1])
    elif kind == "neg":
        value = -_expr(ast[1])
    elif kind == "pow":
        value = _expr(ast[1]) ** _core.eval_interval([_expr(ast[2])], [], [])[0][0]
    elif kind == "call":
        value = _core.Expr.apply(ast[1], _expr(ast[2]))
    else:  # interval
        value = _core.Expr.uncertain(ast[1], ast[2])
    for node in reversed(spine):
        right = _expr(node[3])
        value = {"+": value.__add__, "-": value.__sub__, "*": value.__mul__, "/": value.__truediv__}[node[1]](right)
    return value


def _conditions(src, atoms: list, variables: set, where: str) -> list:
    """Conditions of ``lhs op rhs`` atoms (``=`` as both ``<=`` and ``>=``)."""
    out = []
    for lhs, op, rhs, pos in atoms:
        margin = _expr(("bin", "-", lhs, rhs))
        unknown = sorted(set(margin.variables()) - variables)
        if unknown:
            raise src.error(pos, f"{where}: {', '.join(map(repr, unknown))} not declared in 'state var'")
        out += [margin <= 0] if op in ("<=", "<", "=") else []
        out += [margin >= 0] if op in (">=", ">", "=") else []
    return out


def _load_hybrid(path: str) -> FlowstarHybrid:
    from percver.formats.verisig import _parse

    aut = _parse(path)
    src, variables = aut.src, aut.variables
    dnn = [name for name in aut.modes if name.startswith("DNN")]
    if dnn:
        raise src.error(
            aut.modes[dnn[0]].pos,
            f"mode {dnn[0]} is a Verisig 2.0 network mode (evaluated by the tool from a network file): read the model with pv.load_verisig(model, networks=[...])",
        )
    found = _integration_settings(aut.settings["ignored"], variables, path, src.text)
    for what, value in (("a step size", found["step"]), ("an order", found["order"])):
        if value is None:
            raise ParseError(f"{path}: the setting block gives no {what}")
    known = set(variables)
    modes = {}
    for name, mode in aut.modes.items():
        rhs = {v: _expr(mode.ode[v]) if v in mode.ode else 0.0 for v in variables}
        modes[name] = Mode(rhs, invariant=_conditions(src, mode.inv, known, f"invariant of mode {name}"))
    jumps = [
        Jump(
            j.src,
            j.dst,
            guard=_conditions(src, j.guard, known, f"guard of jump {j.src} -> {j.dst}"),
            reset={v: _expr(ast) for v, ast in j.reset.items()},
        )
        for j in aut.jumps
    ]
    t_end = aut.settings["time"]
    step = found["step"]
    first = step[1] if isinstance(step, tuple) else step
    plant = Hybrid(
        modes, jumps, start=aut.init_mode, max_time=t_end, step=min(first, t_end), max_jumps=aut.settings.get("max_jumps", 10**6)
    )
    ignored = found["ignored"] + ([f"unsafe sets of {sorted(aut.unsafe)} (run() computes reach sets only)"] if aut.unsafe else [])
    return FlowstarHybrid(
        path,
        plant,
        {v: aut.init.get(v, (0.0, 0.0)) for v in variables},
        t_end,
        plant.max_jumps,
        step,
        found["order"],
        found["remainder"],
        found["cutoff"],
        ignored,
    )
