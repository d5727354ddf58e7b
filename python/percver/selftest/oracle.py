"""The float oracle of ``percver selftest``: runs of a :class:`~percver.selftest.program.Program`
computed without percver, and the checks of a verification result against them.

Independent of what it checks: expressions are evaluated by walking the program's AST with numpy,
networks by onnxruntime from the ONNX files the loop loaded, continuous plants by scipy's DOP853
with the stage outputs held over each period; percver's simulator (``loop.simulate``,
``pv.evaluate``) is not used. An uncertain parameter gets one value per run, held for the whole
run (corners of the parameter box and uniform draws): a constant in [lo, hi] is one of the
behaviours the engine must cover, whatever it assumes about the parameter between steps.

The checks, per cell of the result:
  1. a verified cell has no sampled run that violates the property;
  2. every sampled state lies in the cell's reach box at every step the box reports (up to the
     run's first step at a ``within`` goal, after which the engine need not track it): exactly
     for discrete plants, up to ``ODE_TOLERANCE`` (relative) for continuous ones, the
     integrator's own error;
  3. a falsified cell's counterexample replays here (with the parameter values it carries): the
     oracle's run from it violates the property too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy.special import expit

from percver.selftest.program import Binary, Clip, Cond, Const, Param, Pow, Program, Unary, Var, Where, source_of

# Relative error allowed for the integrator (rtol 1e-10 per period, a few periods, through networks).
ODE_TOLERANCE = 1e-8
# A replayed counterexample may miss its violation by this much (relative): percver integrates with
# its own tolerances and evaluates in another order, so a margin can differ in the last digits.
REPLAY_SLACK = {"discrete": 1e-12, "continuous": 1e-6}

FUNCTIONS = {
    "sin": np.sin,
    "cos": np.cos,
    "tanh": np.tanh,
    "sigmoid": expit,
    "atan": np.arctan,
    "exp": np.exp,
    "abs": np.abs,
    "sqrt": np.sqrt,
    "log": np.log,
}
OPERATORS = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "min": np.minimum, "max": np.maximum}


def evaluate(node, env: dict, params: np.ndarray) -> np.ndarray:
    """The node on a batch of runs: ``env`` maps names to columns, ``params`` is runs x parameters."""
    n = len(params)
    if isinstance(node, Const):
        return np.full(n, node.value)
    if isinstance(node, Var):
        return env[node.name]
    if isinstance(node, Param):
        return params[:, node.index]
    if isinstance(node, Unary):
        return FUNCTIONS[node.fn](evaluate(node.arg, env, params))
    if isinstance(node, Binary):
        return OPERATORS[node.op](evaluate(node.a, env, params), evaluate(node.b, env, params))
    if isinstance(node, Pow):
        a = evaluate(node.arg, env, params)
        out = a
        for _ in range(node.n - 1):
            out = out * a  # repeated products, as an integer power is computed
        return out
    if isinstance(node, Where):
        return np.where(holds(node.cond, env, params), evaluate(node.then, env, params), evaluate(node.otherwise, env, params))
    if isinstance(node, Clip):
        return np.minimum(np.maximum(evaluate(node.arg, env, params), node.lo), node.hi)
    raise TypeError(f"not a program node: {node!r}")


def holds(cond: Cond, env: dict, params: np.ndarray, slack: float = 0.0) -> np.ndarray:
    """Where the condition holds; ``slack`` > 0 demands it hold by that much (relative to the
    sides' size), ``slack`` < 0 lets it fail by that much."""
    lhs, rhs = evaluate(cond.lhs, env, params), evaluate(cond.rhs, env, params)
    d = lhs - rhs
    if slack:
        d = d + np.sign(slack) * (1 if cond.op in ("<=", "<") else -1) * abs(slack) * (1 + np.abs(lhs) + np.abs(rhs))
    return {"<=": d <= 0, "<": d < 0, ">=": d >= 0, ">": d > 0}[cond.op]


class Simulator:
    """Runs of one program. Networks run in onnxruntime from ``net_files`` (their ONNX files in
    ``program.nets()`` order), or without files in numpy from the program's weights (the
    generator's pilot runs, before any file exists)."""

    def __init__(self, program: Program, net_files: Optional[list] = None):
        self.program = program
        self.run_net = _numpy_net
        if net_files is not None:
            import onnxruntime

            options = onnxruntime.SessionOptions()
            options.intra_op_num_threads = options.inter_op_num_threads = 1
            sessions = {
                id(net): onnxruntime.InferenceSession(str(f), options, providers=["CPUExecutionProvider"])
                for net, f in zip(program.nets(), net_files, strict=True)
            }
            self.run_net = lambda net, x: sessions[id(net)].run(None, {"input": x})[0]

    def _stage(self, k: int, env: dict, params: np.ndarray) -> np.ndarray:
        stage = self.program.stages[k]
        if stage.exprs is not None:
            out = np.column_stack([evaluate(e, env, params) for e in stage.exprs])
        else:
            out = np.column_stack([env[n] for s in stage.inputs for n in self._names(s, env)])
            for net in stage.nets:
                out = self.run_net(net, np.ascontiguousarray(out))
        if stage.scale is not None:
            out = out * stage.scale
        if stage.offset is not None:
            out = out + stage.offset
        return out

    @staticmethod
    def _names(signal: str, env: dict) -> list:
        """The environment names of a signal: itself, or its components ``signal_0``, ..."""
        if signal in env:
            return [signal]
        names = []
        while f"{signal}_{len(names)}" in env:
            names.append(f"{signal}_{len(names)}")
        return names

    def environment(self, x: np.ndarray, params: np.ndarray) -> dict:
        """States (columns of x in ``program.all_states`` order) and every stage output."""
        env = {n: x[:, j] for j, n in enumerate(self.program.all_states)}
        for k, stage in enumerate(self.program.stages):
            out = self._stage(k, env, params)
            env.update({n: out[:, i] for i, n in enumerate(stage.names)})
        return env

    def step(self, x: np.ndarray, params: np.ndarray) -> np.ndarray:
        p = self.program
        env = self.environment(x, params)
        if p.continuous:
            plant = self._flow(x[:, : len(p.states)], {u: env[u] for u in p.inputs}, params)
        else:
            plant = np.column_stack([evaluate(p.update[s], env, params) for s in p.states])
        sums = [env[r] + evaluate(g, env, params) for r, g in p.reward.items()]
        return np.column_stack([plant, *sums]) if sums else plant

    def _flow(self, x: np.ndarray, held: dict, params: np.ndarray) -> np.ndarray:
        from scipy.integrate import solve_ivp

        p, n = self.program, len(x)

        def rhs(_t, flat):
            env = dict(held)
            env.update({s: flat[j * n : (j + 1) * n] for j, s in enumerate(p.states)})
            return np.concatenate([evaluate(p.update[s], env, params) for s in p.states])

        sol = solve_ivp(rhs, (0.0, p.period), x.T.reshape(-1), method="DOP853", rtol=1e-10, atol=1e-12)
        if not sol.success:
            return np.full_like(x, np.nan)
        return sol.y[:, -1].reshape(len(p.states), n).T

    def simulate(self, x0: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Trajectories (runs x (steps + 1) x states)."""
        steps = self.program.steps
        out = np.empty((len(x0), steps + 1, len(self.program.all_states)))
        out[:, 0] = x = np.asarray(x0, dtype=float)
        with np.errstate(all="ignore"):
            for t in range(steps):
                x = self.step(x, params)
                out[:, t + 1] = x
        return out


ACTIVATIONS = {"sigmoid": expit, "tanh": np.tanh, "relu": lambda z: np.maximum(z, 0.0), "identity": lambda z: z}


def _numpy_net(net, x: np.ndarray) -> np.ndarray:
    for weight, bias, activation in net.layers:
        x = ACTIVATIONS[activation](x @ np.asarray(weight).T + np.asarray(bias))
    if net.scale is not None:
        x = x * np.asarray(net.scale)
    if net.offset is not None:
        x = x + np.asarray(net.offset)
    return x


def judge(program: Program, traj: np.ndarray, params: np.ndarray, slack: float = 0.0):
    """Per run: its first violation ``(step, label)`` or None, and the last step the reach boxes
    must hold it (its first step at a ``within`` goal, else the horizon). Safe conditions are
    checked at every step up to and including that one; a final goal at the last step."""
    n, steps = len(traj), program.steps
    found: list = [None] * n
    end = np.full(n, steps)
    done = np.zeros(n, dtype=bool)
    names = program.all_states
    for t in range(steps + 1):
        env = {s: traj[:, t, j] for j, s in enumerate(names)}
        with np.errstate(all="ignore"):
            for label, cond, bad_when in [(f"safe {source_of(c)}", c, False) for c in program.safe] + [
                (f"unsafe {source_of(c)}", c, True) for c in program.unsafe
            ]:
                broken = holds(cond, env, params, -slack if bad_when else slack) == bad_when
                for i in np.nonzero(broken & ~done & np.array([f is None for f in found], dtype=bool))[0]:
                    found[i] = (t, label)
            if program.goal and (program.within or t == steps):
                at_goal = np.all([holds(c, env, params, slack) for c in program.goal], axis=0)
                if program.within:
                    end = np.where(at_goal & ~done, t, end)
                    done |= at_goal
                if t == steps:
                    for i in np.nonzero(~at_goal & ~done & np.array([f is None for f in found], dtype=bool))[0]:
                        found[i] = (t, "goal " + ", ".join(source_of(c) for c in program.goal))
    return found, end


def sample(program: Program, cell: dict, n: int, rng: np.random.Generator):
    """``n`` runs from a cell (``{state: (lo, hi)}``): its corners first (all, or a random half of
    the runs' worth when there are more), then uniform points; each run's parameters are a corner
    of the parameter box or a uniform draw, half and half, and the first run has their midpoints."""
    lo = np.array([cell[s][0] for s in program.all_states], dtype=float)
    hi = np.array([cell[s][1] for s in program.all_states], dtype=float)
    free = np.nonzero(hi > lo)[0]
    count = min(2 ** len(free), max(n // 2, 1))
    bits = rng.integers(0, 2, (count, len(free))) if 2 ** len(free) > count else ((np.arange(count)[:, None] >> np.arange(len(free))) & 1)
    x0 = lo + (hi - lo) * rng.random((n, len(lo)))
    x0[:count] = lo
    x0[:count, free] = np.where(bits, hi[free], lo[free])
    plo = np.array([a for a, _ in program.params], dtype=float).reshape(-1)
    phi = np.array([b for _, b in program.params], dtype=float).reshape(-1)
    corner = rng.random(n) < 0.5
    draws = np.where(corner[:, None], np.where(rng.random((n, len(plo))) < 0.5, plo, phi), plo + (phi - plo) * rng.random((n, len(plo))))
    draws[0] = 0.5 * (plo + phi)
    return x0, draws.reshape(n, len(plo))


@dataclass
class Violation:
    """A check that failed: ``kind`` is "box", "verified-but-violated", "counterexample" or
    "crash"; ``witness`` has what the reproducer shows (cell, run, step, values); ``program`` is
    the program whose verification failed the check."""

    kind: str
    message: str
    witness: dict = field(default_factory=dict)
    program: object = None


@dataclass
class Report:
    """What the checks covered: runs followed to the horizon, values compared with a reach box,
    runs left out because the oracle's run is not finite (a flow that blows up, an overflow)."""

    runs: int = 0
    box_checks: int = 0
    diverged: int = 0
    violations: list = field(default_factory=list)


def check(program: Program, simulator: Simulator, result, runs: int, rng: np.random.Generator, param_ids: list = ()) -> Report:
    """Checks 1-3 of the module doc on ``result`` with ``runs`` sampled runs spread over its cells;
    ``param_ids`` are percver's ids of the program's parameters (a counterexample names its
    parameters' values by them)."""
    if list(result.states) != program.all_states:
        raise ValueError(f"the result's states {result.states} are not the program's {program.all_states}")
    report = Report()
    per_cell = max(4, -(-runs // max(len(result.cells), 1)))
    for k, cell in enumerate(result.cells):
        x0, params = sample(program, cell.box, per_cell, rng)
        traj = simulator.simulate(x0, params)
        finite = np.isfinite(traj).all(axis=(1, 2))
        traj, x0, params = traj[finite], x0[finite], params[finite]
        report.runs += len(traj)
        report.diverged += int(np.count_nonzero(~finite))
        found, end = judge(program, traj, params, -ODE_TOLERANCE if program.continuous else 0.0)
        if cell.boxes:
            _check_boxes(program, k, cell, traj, params, end, report)
        if cell.verdict == "verified":
            bad = [i for i, f in enumerate(found) if f is not None]
            if bad:
                i = bad[0]
                step, label = found[i]
                report.violations.append(
                    Violation(
                        "verified-but-violated",
                        f"cell {k} is verified, but the run from {_point(program, x0[i], params[i])} violates {label} at step {step}",
                        {
                            "cell": k,
                            "initial": x0[i].tolist(),
                            "params": params[i].tolist(),
                            "step": step,
                            "label": label,
                            "trajectory": traj[i, : step + 1].tolist(),
                        },
                    )
                )
        if cell.counterexample is not None:
            _check_counterexample(program, simulator, k, cell, report, list(param_ids))
    return report


def _check_boxes(program, k, cell, traj, params, end, report):
    boxes = np.asarray(cell.boxes, dtype=float)
    part = traj[:, : len(boxes)]
    live = np.arange(len(boxes))[None, :] <= end[:, None]  # runs x steps
    tol = ODE_TOLERANCE * (1 + np.abs(part)) if program.continuous else 0.0
    outside = ((part < boxes[None, :, :, 0] - tol) | (part > boxes[None, :, :, 1] + tol)) & live[:, :, None]
    report.box_checks += int(live.sum()) * part.shape[2]
    if outside.any():
        i, t, j = np.argwhere(outside)[0]
        lo, hi = boxes[t, j]
        value = part[i, t, j]
        gap = lo - value if value < lo else value - hi
        name = program.all_states[j]
        report.violations.append(
            Violation(
                "box",
                f"cell {k} ({cell.verdict}): {np.count_nonzero(outside)} sampled values outside the reach boxes; first "
                f"{name} = {float(value)!r} at step {t}, outside [{float(lo)!r}, {float(hi)!r}] by {gap:.3g}, from {_point(program, traj[i, 0], params[i])}",
                {
                    "cell": k,
                    "initial": traj[i, 0].tolist(),
                    "params": params[i].tolist(),
                    "step": int(t),
                    "state": name,
                    "value": float(value),
                    "box": [float(lo), float(hi)],
                    "trajectory": traj[i, : t + 1].tolist(),
                },
            )
        )


def _check_counterexample(program, simulator, k, cell, report, param_ids):
    cex = cell.counterexample
    x0 = np.array([[cex.initial[s] for s in program.all_states]])
    # A parameter the counterexample does not name is read by nothing: any value does.
    values = {p["id"]: p["value"] for p in cex.parameters}
    params = np.array([[values.get(i, 0.5 * (lo + hi)) for i, (lo, hi) in zip(param_ids, program.params, strict=True)]])
    params = params.reshape(1, len(program.params))
    inside = all(cell.box[s][0] <= cex.initial[s] <= cell.box[s][1] for s in program.all_states)
    found, _ = judge(program, simulator.simulate(x0, params), params, REPLAY_SLACK["continuous" if program.continuous else "discrete"])
    if found[0] is None or not inside:
        why = "starts outside its cell" if not inside else "does not violate the property in the oracle's run"
        report.violations.append(
            Violation(
                "counterexample",
                f"cell {k} is falsified by a counterexample from {_point(program, x0[0], params[0])} "
                f"(percver: {cex.violated} at step {cex.step}) that {why}",
                {"cell": k, "initial": x0[0].tolist(), "params": params[0].tolist(), "step": cex.step, "label": cex.violated},
            )
        )


def _point(program: Program, x: np.ndarray, params: np.ndarray) -> str:
    text = ", ".join(f"{s}={float(v)!r}" for s, v in zip(program.all_states, x))
    if len(params):
        text += " with " + ", ".join(f"p{i + 1}={float(v)!r}" for i, v in enumerate(params))
    return text
