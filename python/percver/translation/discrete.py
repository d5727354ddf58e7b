"""A period without plant dynamics to integrate: the loop's plant is a ``pv.Discrete`` update."""

from __future__ import annotations

from percver.errors import ParseError
from percver.expr import Expr
from percver.systems import ClosedLoop, Discrete
from percver.translation.execution import RunState
from percver.translation.problem import VerisigProblem, make_problem
from percver.translation.properties import final_goal, jump_properties
from percver.translation.stages import build_stages
from percver.translation.timing import (
    check_assumed,
    discrete_trigger,
    horizon_steps,
    jump_note,
    property_horizon,
    timer_sequence,
)


def discrete_problem(ex, init_timers: dict) -> VerisigProblem:
    aut = ex.aut
    ending = [j for j in aut.jumps if j.dst in ex.terminal]
    others = [j for j in ending if j.src != ending[0].src]
    if others:
        a, b = ending[0], others[0]
        raise ex.src.error(
            b.pos,
            f"jump {b.src} -> {b.dst} ends the run from '{b.src}', but jump {a.src} -> {a.dst} (line {ex.src.line(a.pos)}) "
            f"from '{a.src}'; properties must be read at one step-boundary mode",
        )
    anchor = ending[0].src if ending else aut.init_mode
    if ex.inv_bound(ex.modes[anchor]) not in (0.0,):
        raise ex.src.error(ex.modes[anchor].pos, f"the step boundary mode '{anchor}' must take no time (invariant clock <= 0)")
    # Prefix: from the initial mode to the step boundary (must not change the states).
    if aut.init_mode != anchor:
        pre = RunState(dict(ex.sym), dict(init_timers))
        pre = ex.run(aut.init_mode, pre, anchor, None)
        if ex.calls:
            raise ex.src.error(aut.init_pos, "a network is evaluated before the first step boundary; not supported")
        start_timers, prefix_jumps, start_env = pre.timers, pre.jumps, pre.env
    else:
        start_timers, prefix_jumps, start_env = dict(init_timers), 0, dict(ex.sym)
    end = ex.cycle(anchor, anchor, start_timers, None)
    check_assumed(ex, end.timers, start_timers, anchor)
    H = horizon_steps(ex, end.elapsed, end.max_jumps, prefix_jumps)
    timer_at = timer_sequence(ex, start_timers, end.timers, H, lambda v, n, t: t)
    calls = ex.calls
    # Property from the jumps leaving the boundary mode.
    safe, finals, goals_within = jump_properties(ex, anchor, lambda atoms: discrete_trigger(ex, atoms, timer_at, H), H)
    H = property_horizon(ex, finals, safe, H)
    goal, within = final_goal(ex, finals, goals_within, anchor)
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
        if v not in ex.sym:
            raise ParseError(f"{ex.src.path}: the translated step reads '{v}', which is not a state variable")
        states.add(v)
        e = nxt[v]
        if isinstance(e, Expr):
            todo += [w for w in e.variables() if w not in signals and w not in states]
    if prefix_jumps:
        for v in states:
            if start_env[v] is not ex.sym[v]:
                raise ex.src.error(aut.init_pos, f"the jumps from the initial mode to '{anchor}' change the state '{v}'; not supported")
    order = [v for v in ex.vars if v in states]
    init = ex.init_box(order)
    update = {v: nxt[v] for v in order}
    stages, inputs = build_stages(ex, calls, set(order), {})
    plant = Discrete(update, inputs=inputs)
    loop = ClosedLoop(plant, stages)
    jump_note(ex, H, end.max_jumps, prefix_jumps, bool(finals))
    return make_problem(ex, loop, init, H, goal, safe, within, None)
