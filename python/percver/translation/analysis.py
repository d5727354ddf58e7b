"""What each variable and mode of a Verisig automaton is, read once before any run.

Clocks and counters (constant rates, constant or incremental resets) are tracked as numbers;
modes with constant dynamics are discrete updates; the modes that integrate the plant are
the ones with non-constant dynamics and a positive dwell time.
"""

from __future__ import annotations

import math
from typing import Optional

from percver.errors import ParseError
from percver.expr import Expr
from percver.formats.flowstar_syntax import Automaton, AutomatonMode, ast_variables
from percver.translation.values import TOL, NeedAbsolute, Relative, build_value, is_num


class Analysis:
    """The automaton with its variables classified (timers, plant states) and its modes (flowing or not)."""

    def __init__(self, aut: Automaton, networks: list):
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
        self.timers = self.find_timers()
        for m, mode in self.modes.items():
            states = [a for a in mode.inv if not (ast_variables(a[0]) | ast_variables(a[2])) <= set(self.timers)]
            if states and m not in self.terminal:
                self.notes.append(
                    f"mode '{m}' (line {self.src.line(mode.pos)}): state invariants ignored (an over-approximation: "
                    f"runs Verisig would block there are kept)"
                )
        self.sym = {v: Expr.var(v) for v in self.vars if v not in self.timers}
        self.flow_mode = self.find_flow_mode()

    def const(self, ast) -> Optional[float]:
        if ast_variables(ast):
            return None
        try:
            v = build_value(self.src, ast, lambda n, p: 0.0)
        except (ArithmeticError, ValueError):
            return None
        return v if is_num(v) else None

    def find_timers(self) -> dict:
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
                r = self.const(ast)
                if r is None:
                    ok = False
                    break
                rates[name] = r
            if not ok:
                continue
            for j in self.aut.jumps:
                if v in j.reset and self.timer_reset(v, j.reset[v]) is None:
                    ok = False
                    break
            if ok:
                timers[v] = rates
        return timers

    def timer_reset(self, v: str, ast):
        """('set', c) or ('add', c) for a timer reset, else None."""
        c = self.const(ast)
        if c is not None:
            return ("set", c)
        if ast[0] == "var" and ast[1] == v:
            return ("add", 0.0)
        if ast[0] == "bin" and ast[1] in "+-":
            a, b = ast[2], ast[3]
            if a[0] == "var" and a[1] == v and self.const(b) is not None:
                return ("add", self.const(b) * (1 if ast[1] == "+" else -1))
            if ast[1] == "+" and b[0] == "var" and b[1] == v and self.const(a) is not None:
                return ("add", self.const(a))
        return None

    def solvable(self, mode: AutomatonMode) -> bool:
        """Constant dynamics within the mode (rhs reads only variables frozen in it): the flow
        over a dwell time d is exactly x + d * rhs, a discrete update."""
        frozen = {v for v in self.vars if v not in self.timers and self.const(mode.ode.get(v, ("num", 0.0))) == 0.0}
        for v in self.vars:
            if v in self.timers:
                continue
            ast = mode.ode.get(v, ("num", 0.0))
            if self.const(ast) == 0.0:
                continue
            if not ast_variables(ast) <= frozen:
                return False
        return True

    def inv_bound(self, mode: AutomatonMode) -> Optional[float]:
        bounds = [
            self.const(rhs)
            for lhs, op, rhs, _ in mode.inv
            if op in ("<=", "<") and lhs[0] == "var" and lhs[1] in self.timers and self.const(rhs) is not None
        ]
        return min(bounds) if bounds else None

    def find_flow_mode(self) -> Optional[str]:
        """The mode that integrates the plant; with several (a period through plant modes with
        guards), the first of them, the others in ``self.region`` (see :meth:`_hybrid`)."""
        flows = [
            m for m, mode in self.modes.items() if m not in self.terminal and not self.solvable(mode) and (self.inv_bound(mode) or 0.0) > 0
        ]
        self.region = flows
        return flows[0] if flows else None

    def dwell(self, name: str, timers: dict) -> float:
        """How long a run stays in the mode: until its clock invariant runs out."""
        mode = self.modes[name]
        if self.inv_bound(mode) is None:
            raise self.src.error(mode.pos, f"mode '{name}' has no clock invariant ('clock <= c'), so its dwell time is unknown")
        clocks = [lhs[1] for lhs, op, rhs, _ in mode.inv if lhs[0] == "var" and lhs[1] in self.timers and op in ("<=", "<")]
        dwell = math.inf
        for c in clocks:
            t = timers[c]
            if isinstance(t, Relative):
                raise NeedAbsolute(c, mode.pos)
            rate = self.timers[c][name]
            b = self.const([rhs for lhs, op, rhs, _ in mode.inv if lhs[0] == "var" and lhs[1] == c][0])
            if rate > 0:
                dwell = min(dwell, (b - t) / rate)
        if dwell == math.inf or dwell < -TOL:
            raise self.src.error(mode.pos, f"mode '{name}' is entered with its clock past the invariant bound")
        return max(dwell, 0.0)

    def initial_timers(self) -> dict:
        out = {}
        for v in self.timers:
            lo, hi = self.aut.init.get(v, (0.0, 0.0))
            if v not in self.aut.init:
                self.notes.append(f"counter/clock '{v}' has no initial value; 0 assumed")
            if hi - lo > TOL:
                raise self.src.error(self.aut.init_pos, f"init: the clock/counter '{v}' must start at one value, got [{lo}, {hi}]")
            out[v] = lo
        return out

    def init_box(self, states: list) -> dict:
        missing = [v for v in states if v not in self.aut.init]
        if missing:
            raise self.src.error(self.aut.init_pos, f"init gives no interval for {', '.join(missing)}, which the translated loop needs")
        return {v: tuple(self.aut.init[v]) for v in states}
