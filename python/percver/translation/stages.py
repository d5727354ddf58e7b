"""The closed loop's stages: one per network call of a period, with expression stages for
their inputs and for plant inputs computed from the networks' outputs."""

from __future__ import annotations

import numpy as np

from percver.errors import ParseError
from percver.expr import Expr
from percver.systems import Stage
from percver.translation.values import as_expr, evaluate_floats, is_num, order_key


def build_stages(ex, calls: list, states: set, computed_inputs: dict) -> tuple:
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
                    b = float(evaluate_floats([e], {vs[0]: np.array([0.0])})[0, 0])
                    a = float(evaluate_floats([e], {vs[0]: np.array([1.0])})[0, 0]) - b
                    check = float(evaluate_floats([e], {vs[0]: np.array([-1.5])})[0, 0])
                    if abs(check - (b - 1.5 * a)) <= 1e-12 * max(1.0, abs(a), abs(b)):
                        renamed[vs[0]] = (u, a, b)
    for c in calls:
        # Plain states and signals, and constants (a set speed), wire the network directly.
        plain = [v.name() if isinstance(v, Expr) else v if is_num(v) else None for v in c.inputs]
        names = [p for p in plain if isinstance(p, str)]
        if all(p is not None and (p in known or is_num(p)) for p in plain) and len(set(names)) == len(names):
            wired = plain
        else:
            in_name = ex.fresh(f"{c.output}_in")
            exprs = [as_expr(v) for v in c.inputs]
            what = f"the inputs of the network in '{c.mode}'"
            used = _inputs(
                ex, exprs, known, f"{what} read {{}}, which are neither plant states nor earlier signals", f"{what} are constants"
            )
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
        e = as_expr(e)
        unknown = f"the plant input '{u}' reads {{}} from the previous period; only plant states carry over between periods"
        used = _inputs(ex, [e], known, unknown, f"the plant input '{u}' is a constant; make it a parameter instead")
        stages.append(Stage([e], inputs=used, output=u))
        known.add(u)
        signals.append(u)
    return stages, signals


def _inputs(ex, exprs: list, known: set, unknown: str, constant: str) -> list:
    """The variables ``exprs`` read, in the model's order; refused when one is not ``known`` yet
    (``unknown`` names them at its ``{}``) or when there is none (``constant``)."""
    used = sorted({n for e in exprs for n in e.variables()}, key=order_key(ex.vars))
    missing = [n for n in used if n not in known]
    if missing:
        raise ParseError(f"{ex.src.path}: {unknown.format(missing)}")
    if not used:
        raise ParseError(f"{ex.src.path}: {constant}")
    return used


def same_controller(ex, pre_calls, pre_env, calls, env, plant):
    """The jumps before the first flow must compute what each period computes: compare the
    network inputs and plant-mode inputs on random states."""
    if len(pre_calls) != len(calls) or any(a.net is not b.net for a, b in zip(pre_calls, calls)):
        raise ParseError(f"{ex.src.path}: the jumps before the first flow evaluate the networks differently from a period; not supported")
    box = {v: ex.aut.init.get(v, (0.0, 0.0)) for v in ex.vars}
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
        x, y = evaluate_floats(a.inputs, values), evaluate_floats(b.inputs, values)
        if not np.allclose(x, y, equal_nan=True, rtol=1e-9, atol=1e-12):
            raise ParseError(
                f"{ex.src.path}: the network inputs computed before the first flow differ from those of a period; not supported"
            )
