"""Symbolic execution of one control period: from a mode to a mode, branches merged.

A run walks the jumps from mode to mode, applying resets, network calls, function modes and
constant-rate flows to symbolic values; where the jumps branch, each branch runs to the
branches' join (their immediate post-dominator) and the values merge into ``where`` chains.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional

from percver.expr import Expr
from percver.formats.flowstar_syntax import AutomatonJump, ast_variables
from percver.translation.analysis import Analysis
from percver.translation.branches import post_dominators
from percver.translation.values import (
    TOL,
    NeedAbsolute,
    Relative,
    build_value,
    call_function,
    compare,
    condition_of,
    fold,
    is_num,
    select_where,
    timer_equal,
)

# Verisig's function modes: ``_op_i_j...`` sets state var i to op(state var j) on entry.
SPECIAL = re.compile(r"_(cos|sin|tan|div|arc|sqrt|sec)_(\d+)_(\d+)(?:_|$)")
START = "<start>"  # the period's first mode, distinct from the same mode as its end


@dataclass
class Call:
    """A network evaluated in the period: its inputs' values and the signal its outputs become."""

    net: object
    inputs: list  # values (float or Expr) of _f1.._fN
    output: str  # signal name
    mode: str


@dataclass
class RunState:
    """The state of a symbolic run: values of the ordinary variables, timers, and bookkeeping."""

    env: dict
    timers: dict  # var -> float (absolute) or Relative
    jumps: int = 0
    max_jumps: int = 0
    elapsed: float = 0.0
    dwell: float = 0.0  # time spent in the current mode before its jumps

    def copy(self) -> "RunState":
        return RunState(dict(self.env), dict(self.timers), self.jumps, self.max_jumps, self.elapsed, self.dwell)


class Execution(Analysis):
    """The analysed automaton with the state of the current period's run: its network calls,
    the obligations of dropped plant jumps, and the counters that guards need as constants."""

    def __init__(self, aut, networks: list):
        super().__init__(aut, networks)
        self.calls: list = []
        self.obligations: list = []  # (atoms as conditions, text)
        self.assumed_absolute: set = set()
        self.start_mode = aut.init_mode

    def lookup(self, state: RunState):
        def get(name, pos):
            if name in self.timers:
                t = state.timers[name]
                if isinstance(t, Relative):
                    raise NeedAbsolute(name, pos)
                return t
            if name not in state.env:
                raise self.src.error(pos, f"unknown variable '{name}'")
            return state.env[name]

        return get

    def value(self, ast, state: RunState):
        return build_value(self.src, ast, self.lookup(state))

    def split_atoms(self, atoms: list, state: RunState, where: str):
        """(timer atoms as ASTs, state conditions as values); mixed atoms are refused."""
        timer_atoms, conds = [], []
        for lhs, op, rhs, pos in atoms:
            used = ast_variables(lhs) | ast_variables(rhs)
            if used and used <= set(self.timers):
                timer_atoms.append((lhs, op, rhs, pos))
                continue
            if used & set(self.timers):
                raise self.src.error(
                    pos,
                    f"{where}: a constraint mixing clocks/counters ({', '.join(sorted(used & set(self.timers)))}) with states is not supported",
                )
            lv, rv = self.value(lhs, state), self.value(rhs, state)
            if op == "=":
                conds += [condition_of(lv, "<=", rv), condition_of(lv, ">=", rv)]
            else:
                conds.append(condition_of(lv, op, rv))
        return timer_atoms, conds

    def timer_holds(self, atoms: list, state: RunState) -> bool:
        for lhs, op, rhs, pos in atoms:
            lv, rv = self.value(lhs, state), self.value(rhs, state)
            if not compare(lv, op, rv):
                return False
        return True

    def apply_reset(self, jump: AutomatonJump, state: RunState) -> RunState:
        new = state.copy()
        values = {}
        for v, ast in jump.reset.items():
            if v in self.timers:
                kind, c = self.timer_reset(v, ast)
                old = state.timers[v]
                values[v] = ("t", c if kind == "set" else old + c)
            else:
                try:
                    values[v] = ("e", self.value(ast, state))
                except NeedAbsolute as e:
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

    def arrive(self, name: str, state: RunState, depth: int, initial: bool = False) -> RunState:
        """What happens in a mode before its jumps: a function mode's operation, a network
        evaluation, or a flow with constant dynamics."""
        mode = self.modes[name]
        special = SPECIAL.match(name)
        if special and not initial:
            op, i, j = special.group(1), int(special.group(2)), int(special.group(3))
            if i >= len(self.vars) or j >= len(self.vars):
                raise self.src.error(mode.pos, f"function mode '{name}' names state variable {max(i, j)}, but there are {len(self.vars)}")
            dst, arg = self.vars[i], self.vars[j]
            if dst in self.timers or arg in self.timers:
                raise self.src.error(mode.pos, f"function mode '{name}' applies {op} to a clock/counter")
            x = state.env[arg]
            f = {
                "cos": lambda a: call_function("cos", a),
                "sin": lambda a: call_function("sin", a),
                "tan": lambda a: call_function("tan", a),
                "arc": lambda a: call_function("atan", a),
                "sqrt": lambda a: call_function("sqrt", a),
                "div": lambda a: fold("/", 1.0, a),
                "sec": lambda a: fold("/", 1.0, call_function("cos", a)),
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
            self.call_network(name, state)
        dwell = state.dwell = self.dwell(name, state.timers)
        if dwell > TOL:
            if name == self.flow_mode:
                raise AssertionError("the plant mode is handled by the caller")
            if not self.solvable(mode):
                raise self.src.error(
                    mode.pos,
                    f"mode '{name}' flows for {dwell} with non-constant dynamics between the networks of a period; "
                    f"the plant modes ({', '.join(self.region)}) must follow one another",
                )
            lookup = self.lookup(state)
            updates = {}
            for v in self.vars:
                ast = mode.ode.get(v, ("num", 0.0))
                if v in self.timers:
                    continue
                if self.const(ast) == 0.0:
                    continue
                try:
                    rate = build_value(self.src, ast, lookup)
                except NeedAbsolute as e:
                    raise self.src.error(e.pos, f"mode '{name}': the dynamics of '{v}' read the counter '{e.var}'; not supported") from None
                updates[v] = fold("+", state.env[v], fold("*", dwell, rate))
            state.env.update(updates)
            for v, rates in self.timers.items():
                t = state.timers[v]
                state.timers[v] = t + rates[name] * dwell
            state.elapsed += dwell
        return state

    def call_network(self, mode: str, state: RunState):
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
        name = self.fresh(f"dnn{len(self.calls) + 1}")
        outs = [name] if net.n_out == 1 else [f"{name}_{i}" for i in range(net.n_out)]
        for i, o in enumerate(outs):
            v = f"_f{i + 1}"
            if v not in state.env:
                raise self.src.error(self.modes[mode].pos, f"network {k + 1} has {net.n_out} outputs but '{v}' is not a state variable")
            state.env[v] = Expr.var(o)
        self.calls.append(Call(net, ins, name, mode))

    def fresh(self, base: str) -> str:
        name = base
        while name in self.vars:
            name = "_" + name
        return name

    def continuing(self, name: str) -> list:
        name = self.start_mode if name == START else name
        return [j for j in self.out[name] if j.dst not in self.terminal]

    def pos(self, name: str) -> int:
        return self.modes[self.start_mode if name == START else name].pos

    def run(self, start: str, state: RunState, stop: str, plant_states: Optional[set]) -> RunState:
        """From the initial mode (the run starts inside it) to ``stop``."""
        ipdom = post_dominators(self, start, self.continuing(start), stop)
        state = self.arrive(start, state, 0, initial=True)
        return self.walk(start, state, stop, ipdom, 0, plant_states)

    def walk(self, node: str, state: RunState, stop: str, ipdom: dict, depth: int, plant_states) -> RunState:
        while True:
            edges = []
            for j in self.continuing(node):
                if state.dwell > TOL and not any(
                    op == "=" and ast_variables(l) <= set(self.timers) and ast_variables(l) for l, op, r, _ in j.guard
                ):
                    # Without 'clock = c' the jump may fire at any time of the flow, not just at its end.
                    raise self.src.error(
                        j.pos,
                        f"jump {j.src} -> {j.dst} leaves the flowing mode '{j.src}' without a 'clock = c' guard, "
                        f"so it can fire during the flow; only jumps at the end of a flow are supported",
                    )
                timer_atoms, conds = self.split_atoms(j.guard, state, f"jump {j.src} -> {j.dst}")
                if (timer_atoms and not self.timer_holds(timer_atoms, state)) or any(c is False for c in conds):
                    continue
                edges.append((j, [c for c in conds if c is not True]))
            if not edges:
                raise self.src.error(self.pos(node), f"no jump out of mode '{node}' can fire when its clock runs out")
            if len(edges) == 1:
                j, _ = edges[0]
                state = self.apply_reset(j, state)
                node = j.dst
                if node == stop:
                    return state
                state = self.arrive(node, state, depth)
                continue
            join = ipdom[node]
            branches = []
            for j, conds in edges:
                s = self.apply_reset(j, state)
                if j.dst != join:
                    s = self.arrive(j.dst, s, depth + 1)
                    s = self.walk(j.dst, s, join, ipdom, depth + 1, plant_states)
                branches.append((j, conds, s))
            if plant_states is not None:
                branches = self.drop_plant_jumps(node, state, branches, plant_states)
            state = self.merge(node, branches)
            node = join
            if node == stop:
                return state
            state = self.arrive(node, state, depth)

    def drop_plant_jumps(self, node: str, before: RunState, branches: list, plant_states: set) -> list:
        """A continuous plant cannot jump: branches that reset plant states are dropped, and
        'their guard never holds' becomes a safety obligation, so a verified result is exact."""
        keep, dropped = [], []
        for j, conds, s in branches:
            changed = [x for x in plant_states if s.env.get(x) is not before.env.get(x)]
            (dropped if changed else keep).append((j, conds, s, changed))
        if not dropped:
            return branches
        if not keep:
            raise self.src.error(self.pos(node), f"every jump out of '{node}' resets plant states; a continuous plant cannot jump")
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

    def merge(self, node: str, branches: list) -> RunState:
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
        merged = RunState({}, {}, min(b[2].jumps for b in branches), max(b[2].max_jumps for b in branches), default.elapsed)
        for _, _, s in branches:
            if abs(s.elapsed - default.elapsed) > TOL:
                raise self.src.error(self.pos(node), f"branches from '{node}' take different times; not one control period")
        for v in default.timers:
            values = [b[2].timers[v] for b in branches]
            if any(not timer_equal(x, values[0]) for x in values):
                raise self.src.error(
                    self.pos(node), f"branches from '{node}' leave the counter '{v}' at different values ({values}); not supported"
                )
            merged.timers[v] = values[0]
        for v in default.env:
            value = default.env[v]
            for i in reversed(order[:-1]):
                j, conds, s = branches[i]
                other = s.env[v]
                if other is value or (is_num(other) and is_num(value) and other == value):
                    continue
                value = select_where(conds, other, value)
            merged.env[v] = value
        return merged

    def symbolic_timers(self, anchor: dict) -> dict:
        return {v: (anchor[v] if v in self.assumed_absolute else Relative(v, 0.0)) for v in self.timers}

    def cycle(self, start: str, stop: str, anchor_timers: dict, plant_states: Optional[set]) -> RunState:
        """One period with counters relative to their step-dependent start values; a counter
        that a guard needs is retried as a constant and checked to return to that constant."""
        while True:
            self.calls, self.obligations = [], []
            try:
                # The period starts and ends in the same mode: the start is a separate node.
                self.start_mode = start
                state = RunState(dict(self.sym), self.symbolic_timers(anchor_timers))
                if start == self.flow_mode:
                    state.dwell = self.inv_bound(self.modes[start])
                return self.walk(START, state, stop, post_dominators(self, START, self.continuing(START), stop), 0, plant_states)
            except NeedAbsolute as e:
                if e.var in self.assumed_absolute:
                    raise
                self.assumed_absolute.add(e.var)
