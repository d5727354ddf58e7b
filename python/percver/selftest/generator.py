"""Random programs for ``percver selftest``: small closed loops aimed at the engine's corners.

Program ``index`` of campaign ``seed`` depends on those two numbers alone, so any program can be
made again. The draws favour what sound set arithmetic gets wrong most easily: conditions that
hold on part of a cell (forks), several conditions whose Taylor models coincide although they
are about different quantities (``sin(1000 x)`` and ``sin(1000 y)`` over wide boxes, uncertain
parameters with equal ranges; the init and parameter boxes are drawn from short lists so that
ranges repeat), saturations (clip, min, max, ReLU), uncertain parameters, network stages (chained
in one stage, or consecutive and fused by the compiler) with output maps, accumulators, and the
verify options that change how a cell is split or enclosed (``state_symbols`` too). The property's thresholds come from
pilot runs of the oracle, so that some programs hold with a wide margin, some barely, and some
not at all.
"""

from __future__ import annotations

import numpy as np

from percver.selftest.oracle import Simulator, evaluate
from percver.selftest.program import (
    COMPARISONS,
    SIMPLEST,
    UNARY,
    Binary,
    Clip,
    Cond,
    Const,
    Net,
    Param,
    Pow,
    Program,
    Stage,
    Unary,
    Var,
    Where,
    names_in,
    params_in,
    walk,
)

STATE_RANGES = [(0.0031, 0.0131), (-0.5, 0.5), (0.0, 1.0), (0.9, 1.1), (-1.0, -0.8), (0.2, 0.25), (0.5, 0.5)]
PARAM_RANGES = [(-1.0, 1.0), (0.0, 1.0), (-0.5, 0.5), (0.9, 1.1)]
FAST = (1000.0, 300.0, 40.0)  # frequencies that wrap sin over a box of width 0.01 or more
PERIODS = (0.1, 0.07, 0.13, 0.3, 0.05)


def _round(v: float, digits: int = 3) -> float:
    return float(f"{float(v):.{digits}g}")


class _Draw:
    """One program's random choices (a numpy Generator and the names in scope)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.ranges: dict = {}  # state -> init range (thresholds of conditions on it)
        self.params: list = []
        # Most of a program's conditions use one comparison: conditions about different quantities
        # then often look alike to the engine (same operator, same threshold, equal models).
        self.comparison = self.pick(COMPARISONS)
        self.made: list = []  # the conditions drawn so far: later ones repeat them or their siblings

    def pick(self, options, weights=None):
        i = self.rng.choice(len(options), p=None if weights is None else np.asarray(weights) / np.sum(weights))
        return options[i]

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def number(self, lo: float, hi: float) -> float:
        return _round(self.rng.uniform(lo, hi))

    # -- expressions ----------------------------------------------------------------------------

    def fast_atom(self, names: list):
        """``sin(K v)``, ``cos(K v)`` or ``tanh(K v)`` with a large K: a model that covers its
        whole range on a wide box, whichever variable it reads."""
        return Unary(self.pick(["sin", "cos", "tanh"]), Binary("*", Const(self.pick(FAST)), Var(self.pick(names))))

    def leaf(self, names: list, prefer: list):
        kinds = ["var", "const", "param", "fast", "scaled"]
        weights = [0.45, 0.15, 0.15 if self.params else 0.0, 0.15, 0.1]
        kind = self.pick(kinds, weights)
        if kind == "var":
            return Var(self.pick(prefer) if prefer and self.chance(0.5) else self.pick(names))
        if kind == "const":
            return Const(self.number(-1.5, 1.5))
        if kind == "param":
            return Param(int(self.rng.integers(len(self.params))))
        if kind == "fast":
            return self.fast_atom(names)
        return Binary("*", Const(self.number(-2, 2)), Var(self.pick(names)))

    def expr(self, depth: int, names: list, prefer: list = (), smooth: bool = False):
        """A random expression over ``names``; ``smooth`` leaves out ``where`` (continuous plants)."""
        prefer = list(prefer)
        if depth <= 0 or self.chance(0.25):
            return self.leaf(names, prefer)
        kinds = ["unary", "arith", "minmax", "div", "pow", "where", "clip"]
        weights = [0.18, 0.27, 0.07, 0.03, 0.04, 0.0 if smooth else 0.3, 0.1]
        kind = self.pick(kinds, weights)
        sub = lambda: self.expr(depth - 1, names, prefer, smooth)
        if kind == "unary":
            fn = self.pick(UNARY)
            arg = sub()
            if fn == "exp":  # of a bounded argument
                arg = Clip(arg, -2.0, 2.0)
            elif fn in ("sqrt", "log"):  # of a positive one
                arg = Binary("+", Const(self.number(0.1, 1)), Pow(arg, 2))
            return Unary(fn, arg)
        if kind == "arith":
            return Binary(self.pick(["+", "-", "*"]), sub(), sub())
        if kind == "minmax":
            return Binary(self.pick(["min", "max"]), sub(), sub())
        if kind == "div":
            return Binary("/", sub(), Binary("+", Const(self.number(0.5, 2)), Pow(sub(), 2)))
        if kind == "pow":
            return Pow(sub(), int(self.pick([2, 3])))
        if kind == "where":
            branch = lambda: Const(float(self.pick([0.0, 1.0, -1.0]))) if self.chance(0.4) else sub()
            return Where(self.condition(depth - 1, names, prefer), branch(), branch())
        lo = self.number(-1.5, 0.5)
        return Clip(sub(), lo, _round(lo + self.rng.uniform(0.1, 2)))

    def condition(self, depth: int, names: list, prefer: list = ()) -> Cond:
        """A condition likely to hold on part of a cell: an earlier condition again or its
        sibling (see :meth:`sibling`), or one on a fast atom or a parameter (against 0 or near the
        middle), on a state (inside its init range), or on any expression (against 0)."""
        known = [c for c in self.made if names_in(c) <= set(names)]  # those this scope can read
        if known and self.chance(0.35):
            earlier = known[int(self.rng.integers(len(known)))]
            return earlier if self.chance(0.3) else self.sibling(earlier, names)
        cond = self.fresh_condition(depth, names, prefer)
        self.made.append(cond)
        return cond

    def sibling(self, cond: Cond, names: list) -> Cond:
        """The same comparison with the same threshold about another quantity of the same kind:
        another parameter with an equal range, the wave of another state (or the other wave of
        the same state), another state."""
        lhs = cond.lhs
        if isinstance(lhs, Param):
            twins = [i for i, r in enumerate(self.params) if r == self.params[lhs.index] and i != lhs.index]
            lhs = Param(int(self.pick(twins))) if twins else lhs
        elif isinstance(lhs, Unary) and isinstance(lhs.arg, Binary) and isinstance(lhs.arg.b, Var):
            others = [n for n in names if n != lhs.arg.b.name]
            if others and self.chance(0.7):
                lhs = Unary(lhs.fn, Binary("*", lhs.arg.a, Var(self.pick(others))))
            else:
                lhs = Unary({"sin": "cos", "cos": "sin"}.get(lhs.fn, "sin"), lhs.arg)
        elif isinstance(lhs, Var):
            lhs = Var(self.pick(names))
        return Cond(lhs, cond.op, cond.rhs)

    def fresh_condition(self, depth: int, names: list, prefer: list) -> Cond:
        op = self.comparison if self.chance(0.7) else self.pick(COMPARISONS)
        kind = self.pick(["fast", "param", "var", "expr"], [0.3, 0.25 if self.params else 0.0, 0.25, 0.2])
        if kind == "fast":
            return Cond(self.fast_atom(names), op, Const(float(self.pick([0.0, 0.0, 0.0, 0.3, -0.5]))))
        if kind == "param":
            i = int(self.rng.integers(len(self.params)))
            lo, hi = self.params[i]
            return Cond(Param(i), op, Const(_round(lo + (hi - lo) * self.pick([0.5, 0.5, 0.5, 0.25, 0.8]))))
        if kind == "var":
            name = self.pick(list(prefer) if prefer and self.chance(0.5) else names)
            lo, hi = self.ranges.get(name, (-0.5, 0.5))
            return Cond(Var(name), op, Const(_round(lo + (hi - lo) * self.rng.uniform(0.2, 0.8))))
        lhs = self.expr(max(depth, 1), names, prefer)
        if not names_in(lhs) and not params_in(lhs):  # a comparison of constants is no condition
            lhs = Binary("+", lhs, Var(self.pick(names)))
        return Cond(lhs, op, Const(0.0))

    # -- networks -------------------------------------------------------------------------------

    def net(self, n_in: int, n_out: int, mapped: bool) -> Net:
        act = self.pick(["sigmoid", "tanh", "relu"])
        widths = [int(self.rng.integers(2, 6)) for _ in range(int(self.rng.integers(1, 3)))] + [n_out]
        layers, fan_in = [], n_in
        for k, width in enumerate(widths):
            last = k == len(widths) - 1
            activation = (
                self.pick(["identity", "identity", "tanh"])
                if last
                else (act if self.chance(0.8) else self.pick(["sigmoid", "tanh", "relu"]))
            )
            weight = np.round(self.rng.normal(0, 1.5 / np.sqrt(fan_in), (width, fan_in)), 3).tolist()
            bias = np.round(self.rng.normal(0, 0.5, width), 3).tolist()
            layers.append((weight, bias, activation))
            fan_in = width
        scale = np.round(self.rng.uniform(0.2, 2, n_out), 3).tolist() if mapped and self.chance(0.5) else None
        offset = np.round(self.rng.uniform(-1, 1, n_out), 3).tolist() if mapped and self.chance(0.5) else None
        return Net(layers, scale, offset, self.pick(["gemm", "matmul"]))

    # -- the program ----------------------------------------------------------------------------

    def stages(self, states: list, continuous: bool) -> list:
        stages, widths = [], {s: 1 for s in states}
        for output in ["u", "w", "h"][: int(self.pick([0, 1, 2, 3], [0.25, 0.35, 0.28, 0.12]))]:
            signals = list(widths)
            inputs = [str(s) for s in self.rng.choice(signals, size=int(self.rng.integers(1, min(3, len(signals)) + 1)), replace=False)]
            names = [n for s in inputs for n in ([s] if widths[s] == 1 else [f"{s}_{i}" for i in range(widths[s])])]
            width = 2 if self.chance(0.2) else 1
            if self.chance(0.6):
                n_in = len(names)
                if self.chance(0.2):  # two files chained with pv.chain
                    middle = int(self.rng.integers(2, 4))
                    nets = [self.net(n_in, middle, True), self.net(middle, width, True)]
                else:
                    nets = [self.net(n_in, width, True)]
                stage = Stage(output, inputs, nets=nets)
            else:
                stage = Stage(output, inputs, exprs=[self.expr(2, names) for _ in range(width)])
            if self.chance(0.3):
                stage.scale = self.number(0.2, 2)
                stage.offset = self.number(-0.5, 0.5) if self.chance(0.5) else None
            stages.append(stage)
            widths[output] = width
        return stages

    def program(self) -> Program:
        continuous = self.chance(0.3)
        states = ["x", "y", "z"][: int(self.rng.integers(1, 3 if continuous else 4))]
        shared = self.pick(STATE_RANGES) if self.chance(0.4) else None
        init = {s: shared or self.pick(STATE_RANGES) for s in states}
        self.ranges = dict(init)
        shared = self.pick(PARAM_RANGES)
        self.params = [shared if self.chance(0.7) else self.pick(PARAM_RANGES) for _ in range(int(self.pick([0, 0, 1, 2, 2])))]
        stages = self.stages(states, continuous)
        outputs = [n for s in stages for n in s.names]
        if continuous:
            scalar = [s.output for s in stages if s.width == 1]
            names = states + scalar
            update = {}
            for s in states:  # a damping term -k s (k = 0: none) keeps most flows bounded
                drift, k = self.expr(2, names, scalar, smooth=True), float(self.pick([0.0, 0.5, 1.0]))
                update[s] = Binary("-", drift, Binary("*", Const(k), Var(s))) if k else drift
            used = set().union(*(names_in(e) for e in update.values()))
            inputs = [u for u in scalar if u in used]
            period = float(self.pick(PERIODS))
            program = Program(
                states, init, update, stages, list(self.params), period=period, step=period / int(self.pick([1, 2, 3, 5])), inputs=inputs
            )
        else:
            names = states + outputs
            update = {}
            for s in states:
                form = self.pick(["increment", "map", "wall"], [0.45, 0.2, 0.35])
                if form == "increment":
                    update[s] = Binary("+", Var(s), Binary("*", Const(float(self.pick([0.1, 0.5, 1.0]))), self.expr(3, names, outputs)))
                elif form == "map":
                    update[s] = self.expr(3, names, outputs)
                else:
                    update[s] = Where(self.condition(2, names, outputs), self.expr(2, names, outputs), self.expr(2, names, outputs))
            program = Program(states, init, update, stages, list(self.params))
            if self.chance(0.25):  # a reward-like sum as a plant state
                program.states = states + ["r"]
                program.init = {**init, "r": (0.0, 0.0)}
                program.update = {**update, "r": Binary("+", Var("r"), self.expr(2, names, outputs))}
        if self.chance(0.2):
            program.reward = {"cost": self.expr(2, program.env_names, outputs, smooth=continuous)}
        program.steps = int(self.rng.integers(1, 4 if continuous else 6))
        self.options(program)
        self.property(program)
        return program

    def options(self, program: Program):
        """How cells are made and enclosed. Every program bounds its cells (a grid, a bisection
        down to a quarter of the initial set, an adaptive splitter with a few runs): the default
        adaptive splitter may run the engine a thousand times on one program."""
        opts = {}
        free = [s for s in program.states if program.init[s][1] > program.init[s][0]]
        cells = self.pick(["split", "refine", "adaptive", "grid"], [0.3, 0.15, 0.3, 0.25] if free else [0, 0, 0.5, 0.5])
        if cells == "split":
            opts["split"] = {self.pick(free): int(self.pick([2, 3]))}
        elif cells == "refine":
            opts["refine"] = True
            opts["min_width"] = {s: _round((program.init[s][1] - program.init[s][0]) / 4) for s in free}
        else:
            opts["splitter"] = (
                ("Adaptive", {"start": int(self.pick([1, 2])), "max_cells": int(self.pick([4, 8]))})
                if cells == "adaptive"
                else SIMPLEST["splitter"]
            )
        if self.chance(0.4):
            opts["max_splits"] = int(self.pick([0, 2, 4]))
        if self.chance(0.3):
            opts["order"] = int(self.pick([2, 3, 4]))
        if self.chance(0.15):
            opts["rebox"] = True
        nets = program.nets()
        if nets and not any("relu" in net.activations for net in nets) and self.chance(0.25):
            opts["method"] = "verisig"
        elif not program.continuous and self.chance(0.1):
            opts["state_symbols"] = True  # Taylor method, discrete plants
        program.options = opts

    def property(self, program: Program):
        """safe / unsafe / goal conditions with thresholds placed against pilot runs."""
        names = program.all_states
        rng = self.rng
        runs = 32
        lo, hi = np.array([program.start[s] for s in names]).T
        x0 = lo + (hi - lo) * rng.random((runs, len(names)))
        params = np.array([[rng.uniform(a, b) for a, b in program.params] for _ in range(runs)]).reshape(runs, len(program.params))
        traj = Simulator(program).simulate(x0, params)
        traj = traj[np.isfinite(traj).all(axis=(1, 2))]
        if not len(traj):
            traj = np.zeros((1, program.steps + 1, len(names)))
            params = np.zeros((1, len(program.params)))

        def quantity():
            if self.chance(0.7):
                return Var(self.pick(names))
            if len(names) > 1 and self.chance(0.5):
                a, b = rng.choice(names, 2, replace=False)
                return Binary(self.pick(["+", "-"]), Var(str(a)), Var(str(b)))
            return Unary(self.pick(["sin", "tanh"]), Var(self.pick(names)))

        def values(q):  # runs x steps
            return np.stack(
                [evaluate(q, {s: traj[:, t, j] for j, s in enumerate(names)}, params[: len(traj)]) for t in range(traj.shape[1])], axis=1
            )

        def bound(v, upper: bool) -> float:
            top, bottom = np.nanmax(v), np.nanmin(v)
            spread = max(top - bottom, 1e-3)
            m = float(self.pick([-0.1, 0.0, 0.005, 0.02, 0.1, 0.5], [1, 1, 2, 2, 2, 1]))
            return _round(top + m * spread if upper else bottom - m * spread, 4)

        form = self.pick(["safe", "unsafe", "goal", "within"], [0.55, 0.15, 0.15, 0.15])
        q = quantity()
        v = values(q)
        upper = self.chance(0.5)
        if form in ("safe", "unsafe"):
            thr = bound(v, upper)
            safe = Cond(q, "<=" if upper else ">=", Const(thr)) if form == "safe" else None
            unsafe = Cond(q, ">" if upper else "<", Const(thr)) if form == "unsafe" else None
            program.safe = [safe] if safe else []
            program.unsafe = [unsafe] if unsafe else []
            if form == "safe" and self.chance(0.2):
                q2 = quantity()
                program.safe.append(Cond(q2, ">=", Const(bound(values(q2), False))))
        else:
            # Final goal: the last step's values; within: each run's best value along the way.
            reach = (
                v[:, -1] if form == "goal" else (v[:, 1:].max(axis=1) if upper else v[:, 1:].min(axis=1)) if v.shape[1] > 1 else v[:, -1]
            )
            thr = _round(np.quantile(reach, self.pick([0.0, 0.05, 0.3])) if upper else np.quantile(reach, self.pick([1.0, 0.95, 0.7])), 4)
            program.goal = [Cond(q, ">=" if upper else "<=", Const(thr))]
            program.within = form == "within"
            if self.chance(0.3):
                q2 = quantity()
                program.safe = [Cond(q2, "<=", Const(bound(values(q2), True)))]


def generate(seed: int, index: int) -> Program:
    """Program ``index`` of the campaign with ``seed``."""
    return _Draw(np.random.default_rng([seed, index])).program()


def _wide_atom(node, program: Program):
    """What the engine's model of ``node`` is on the initial set when it is the same for different
    quantities: an uncertain parameter's range, or the whole [-1, 1] for sin or cos of a fast
    multiple of a state whose initial range spans a period. None for anything else."""
    if isinstance(node, Param):
        return ("param", tuple(program.params[node.index]))
    if (
        isinstance(node, Unary)
        and node.fn in ("sin", "cos")
        and isinstance(node.arg, Binary)
        and node.arg.op == "*"
        and isinstance(node.arg.a, Const)
        and isinstance(node.arg.b, Var)
        and node.arg.b.name in program.init
    ):
        lo, hi = program.init[node.arg.b.name]
        if abs(node.arg.a.value) * (hi - lo) >= 2 * np.pi:
            return ("wave",)
    return None


def aliasing_pairs(program: Program) -> list:
    """Pairs of conditions of one evaluation (the plant's update, or one expression stage) about
    different quantities that the engine's models cannot tell apart on the initial set: the same
    comparison with the same threshold of two distinct parameters of equal range, or of sin/cos
    waves that each cover [-1, 1]. The class of the fork-alias hole (issue 24): a point may take
    different branches at the two, and an engine that reuses one's branch for the other misses it."""
    groups = [list(program.update.values()) + (list(program.reward.values()) if not program.continuous else [])]
    groups += [s.exprs for s in program.stages if s.exprs]
    pairs = []
    for group in groups:
        conds = list(dict.fromkeys(n.cond for e in group for n in walk(e) if isinstance(n, Where)))
        for i, a in enumerate(conds):
            for b in conds[i + 1 :]:
                key = _wide_atom(a.lhs, program)
                if key is not None and key == _wide_atom(b.lhs, program) and a.lhs != b.lhs and a.op == b.op and a.rhs == b.rhs:
                    pairs.append((a, b))
    return pairs
