"""Flow* model files: parse them and run them with their own settings.

``continuous reachability``: ``state var``, the settings block (fixed/adaptive steps and orders,
time, remainder estimation as a number or per variable, QR/identity precondition, cutoff;
plotting, output, precision and print lines are read and ignored), ``poly ode N`` / ``nonpoly
ode`` / ``nonpoly ode { N }`` (all integrated by the same Taylor-model Picard engine), and
``init``. Anything else is refused with the file name, line and what is supported.

``hybrid reachability`` (read with the Verisig model parser, :mod:`percver.formats.verisig`):
time-triggered automata, as Verisig 1.0 and :func:`percver.formats.to_flowstar` write them. Every
mode dwells a fixed time set by a clock (``clock' = 1``, ``inv { clock <= c }``); jumps fire at
the end of the dwell when their guard can hold, all of them (branching), and reset variables
simultaneously. :meth:`HybridModel.run` computes the reach set with boxes: each mode's flow by
the flowpipe engine, one flowpipe per group of variables whose equations couple them (a layer of
neuron ODEs is one small flowpipe per neuron), resets and guards by interval evaluation. Boxing
at every jump loses the correlations Flow* keeps in its Taylor models, so the sets are sound but
wider (for a network, like interval propagation with exact activations).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

from percver import _core
from percver.errors import BlowUpError, InputError, MissingFileError, ParseError
from percver.formats.verisig import _block


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


def load_flowstar(path: str) -> Union[FlowstarModel, "HybridModel"]:
    """Parses a Flow* model file: a :class:`FlowstarModel` (continuous) or a :class:`HybridModel`."""
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


# Bisections of a flowpipe's initial box before a flow counts as not enclosable (2^6 pieces).
MAX_SPLITS = 6


@dataclass
class HybridMode:
    name: str
    ode: dict  # variable -> Expr (variables not listed stay constant)
    dwell_atoms: list  # (clock, c): the mode is left when clock reaches c


@dataclass
class HybridJump:
    source: str
    target: str
    guard: list  # (variable or None, margin Expr, op, constant or None): margin op 0
    reset: dict  # variable -> Expr, applied simultaneously


@dataclass
class HybridVisit:
    """One stay in a mode: the box on entry, the box at the end of the dwell, the time span."""

    mode: str
    start: float
    end: float
    entry: dict
    exit: dict


@dataclass
class HybridRun:
    """Reach set of a hybrid model: every stay, and the stays no jump leaves (``finals``)."""

    visits: list
    finals: list
    notes: list

    def final_box(self, mode: Optional[str] = None) -> dict:
        """Hull of the final boxes (of those in ``mode``, if given): ``{variable: (lo, hi)}``."""
        boxes = [v.exit for v in self.finals if mode is None or v.mode == mode]
        if not boxes:
            raise InputError(f"no run ends in mode '{mode}' (final modes: {sorted({v.mode for v in self.finals})})")
        return {k: (min(b[k][0] for b in boxes), max(b[k][1] for b in boxes)) for k in boxes[0]}


@dataclass
class HybridModel:
    """A time-triggered Flow* hybrid model; :meth:`run` computes its reach set (see the module doc)."""

    path: str
    variables: list
    modes: dict  # name -> HybridMode
    jumps: list
    init_mode: str
    init: dict
    t_end: float
    max_jumps: int
    step: object
    order: int
    remainder: list
    cutoff: float
    ignored: list = field(default_factory=list)

    def run(self, *, max_stays: int = 100_000) -> HybridRun:
        """Follows every run from the initial box until no jump fires, up to the file's time
        horizon and jump count; a flow that cannot be enclosed raises :class:`BlowUpError`."""
        notes: list = []
        box = {v: self.init.get(v, (0.0, 0.0)) for v in self.variables}
        pending = [(self.init_mode, box, 0.0, 0)]
        visits, finals = [], []
        while pending:
            mode, box, time, jumps = pending.pop()
            dwell = self._dwell(self.modes[mode], box)
            end = self._flow(self.modes[mode], box, dwell)
            visit = HybridVisit(mode, time, time + dwell, box, end)
            visits.append(visit)
            if len(visits) > max_stays:
                raise BlowUpError(f"{self.path}: more than {max_stays} mode stays (branching jumps); give run(max_stays=...)")
            fired = False
            for jump in self.jumps:
                if jump.source != mode or (guarded := self._guard(jump, end)) is None:
                    continue
                if jumps >= self.max_jumps or time + dwell > self.t_end:
                    notes.append(f"stopped in {mode} at t = {time + dwell:g} after {jumps} jumps (the file's limits)")
                    break
                pending.append((jump.target, self._reset(jump, guarded), time + dwell, jumps + 1))
                fired = True
            if not fired:
                finals.append(visit)
        return HybridRun(visits, finals, notes)

    def _dwell(self, mode: HybridMode, box: dict) -> float:
        dwells = []
        for clock, c in mode.dwell_atoms:
            lo, hi = box[clock]
            if lo != hi:
                raise ParseError(
                    f"{self.path}: mode {mode.name} is entered with {clock} in [{lo}, {hi}]; the runner needs a clock reset to one value"
                )
            dwells.append(max(0.0, c - lo))
        return min(dwells)

    def _flow(self, mode: HybridMode, box: dict, dwell: float) -> dict:
        """The box after `dwell` time units: each group of coupled variables by its own flowpipe
        from the box (the groups are independent, so nothing is lost by splitting a box)."""
        end = dict(box)
        if dwell == 0.0:
            return end
        moving = dict(mode.ode)
        group = {v: v for v in moving}

        def root(v):
            while group[v] != v:
                group[v] = group[group[v]]
                v = group[v]
            return v

        for v, e in moving.items():
            for w in e.variables():
                if w in moving:
                    group[root(v)] = root(w)
        members: dict = {}
        for v in moving:
            members.setdefault(root(v), []).append(v)
        for names in members.values():
            parameters = sorted({w for v in names for w in moving[v].variables()} - set(names))
            if not parameters and all(not moving[v].variables() for v in names):
                # Constant rates (clocks, counters): x + rate * dwell in interval arithmetic.
                for v in names:
                    rate = _core.eval_interval([moving[v]], [], [])[0]
                    moved = _core.Interval(*box[v]) + _core.Interval(*rate) * _core.Interval(dwell, dwell)
                    end[v] = (moved.lo, moved.hi)
                continue
            ode = {v: moving[v] for v in names}
            ode.update({w: _core.Expr.constant(0.0) for w in parameters})
            final = self._integrate(ode, {v: box[v] for v in ode}, dwell, MAX_SPLITS)
            end.update({v: final[v] for v in names})
        return end

    def _integrate(self, ode: dict, box: dict, dwell: float, splits: int) -> dict:
        """The final box of a flowpipe from `box`; if it cannot be enclosed, the hull of those of
        the two halves of the widest side (a neuron whose pre-activation spans [-5, 5] needs a
        few: tanh(a t) over such a range is too steep for one Taylor model at moderate order)."""
        from percver.flowpipe import flowpipe

        adaptive = self.step if isinstance(self.step, tuple) else None
        remainder = {v: self.remainder[self.variables.index(v)] for v in ode}
        try:
            fp = flowpipe(
                ode,
                box,
                dwell,
                order=self.order,
                step=0.0 if adaptive else self.step,
                adaptive=adaptive,
                cutoff=self.cutoff,
                remainder=remainder,
            )
            return fp.final_box()
        except BlowUpError:
            widest = max(box, key=lambda v: box[v][1] - box[v][0])
            lo, hi = box[widest]
            if splits == 0 or not lo < hi:
                raise
        mid = 0.5 * (lo + hi)
        halves = [self._integrate(ode, {**box, widest: side}, dwell, splits - 1) for side in ((lo, mid), (mid, hi))]
        return {v: (min(h[v][0] for h in halves), max(h[v][1] for h in halves)) for v in halves[0]}

    def _guard(self, jump: HybridJump, box: dict) -> Optional[dict]:
        """The box where the guard can hold (bounds of single variables applied), or None."""
        box = dict(box)
        for variable, margin, op, constant in jump.guard:
            if op == "=" and variable is not None and constant is not None:
                lo, hi = box[variable]
                tol = 1e-9 * max(1.0, abs(constant))
                if not lo - tol <= constant <= hi + tol:
                    return None
                continue
            lo, hi = _core.eval_interval([margin], self.variables, [box[v] for v in self.variables])[0]
            if (op in ("<=", "<") and lo > 0) or (op in (">=", ">") and hi < 0) or (op == "=" and (lo > 0 or hi < 0)):
                return None
            if variable is not None and constant is not None:
                vlo, vhi = box[variable]
                vlo, vhi = (
                    (vlo, min(vhi, constant)) if op in ("<=", "<") else (max(vlo, constant), vhi) if op in (">=", ">") else (vlo, vhi)
                )
                if vlo > vhi:
                    return None
                box[variable] = (vlo, vhi)
        return box

    def _reset(self, jump: HybridJump, box: dict) -> dict:
        if not jump.reset:
            return dict(box)
        names = list(jump.reset)
        values = _core.eval_interval([jump.reset[v] for v in names], self.variables, [box[v] for v in self.variables])
        return {**box, **dict(zip(names, (tuple(v) for v in values)))}


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


def _atom(src, atom, variables: set) -> tuple:
    """(variable, margin, op, constant) of `lhs op rhs`: variable and constant when the atom
    bounds a single variable by a constant (so a guard can cut the box)."""
    lhs, op, rhs, pos = atom
    variable = lhs[1] if lhs[0] == "var" else None
    constant = None
    if rhs[0] == "num" or (rhs[0] == "neg" and rhs[1][0] == "num"):
        constant = rhs[1] if rhs[0] == "num" else -rhs[1][1]
    margin = _expr(("bin", "-", lhs, rhs))
    unknown = sorted(set(margin.variables()) - variables)
    if unknown:
        raise src.error(pos, f"undeclared variables {unknown} in a constraint")
    return variable, margin, op, constant


def _load_hybrid(path: str) -> HybridModel:
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
    order = found["order"] if isinstance(found["order"], int) else max(found["order"])
    modes = {}
    for name, mode in aut.modes.items():
        ode = {v: _expr(ast) for v, ast in mode.ode.items() if not (ast[0] == "num" and ast[1] == 0.0)}
        atoms = []
        for lhs, op, rhs, _ in mode.inv:
            clock, rate = (lhs[1], ode.get(lhs[1])) if lhs[0] == "var" else (None, None)
            if clock and op in ("<=", "<") and rhs[0] == "num" and rate is not None and not rate.variables():
                if _core.eval_interval([rate], [], [])[0] == (1.0, 1.0):
                    atoms.append((clock, rhs[1]))
        if not atoms:
            raise src.error(
                mode.pos,
                f"mode {name} has no invariant 'clock <= c' with clock' = 1: the runner reads time-triggered models (each mode dwells a fixed time), as Verisig writes them",
            )
        modes[name] = HybridMode(name, ode, atoms)
    jumps = []
    for j in aut.jumps:
        guard = [_atom(src, a, set(variables)) for a in j.guard]
        # The runner fires jumps at the end of the dwell only: out of a flowing mode, a jump must
        # say so (guard clock = c), or it could fire earlier, from states the runner never sees.
        for clock, c in modes[j.src].dwell_atoms:
            if c > 0 and not any(g[0] == clock and g[2] == "=" and g[3] == c for g in guard):
                raise src.error(
                    j.pos,
                    f"jump {j.src} -> {j.dst} can fire during the flow of {j.src}; the runner reads jumps at the end of a mode's dwell: add '{clock} = {c:g}' to the guard",
                )
        jumps.append(HybridJump(j.src, j.dst, guard, {v: _expr(ast) for v, ast in j.reset.items()}))
    ignored = found["ignored"] + ([f"unsafe sets of {sorted(aut.unsafe)} (run() computes reach sets only)"] if aut.unsafe else [])
    return HybridModel(
        path,
        variables,
        modes,
        jumps,
        aut.init_mode,
        dict(aut.init),
        aut.settings["time"],
        aut.settings.get("max_jumps", 10**9),
        found["step"],
        order,
        found["remainder"],
        found["cutoff"],
        ignored,
    )
