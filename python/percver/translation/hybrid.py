"""A period through several plant modes with clocked jumps between them: the loop's plant is
a ``pv.Hybrid`` automaton (Verisig 2.0's quadrotor MPC, one mode per segment)."""

from __future__ import annotations

from percver.errors import ParseError
from percver.expr import Expr
from percver.systems import ClosedLoop, Hybrid, Jump, Mode
from percver.translation.conditions import negate
from percver.translation.execution import RunState
from percver.translation.problem import VerisigProblem, make_problem
from percver.translation.properties import check_plant_states, constraint_conditions, edge_conditions, final_goal, property_edges
from percver.translation.stages import build_stages, same_controller
from percver.translation.timing import check_entry_clock, classify_trigger, flow_trigger, horizon_steps, jump_note, property_horizon
from percver.formats.flowstar_syntax import ast_variables
from percver.translation.values import TOL, Relative, build_value


def hybrid_problem(ex, init_timers: dict) -> VerisigProblem:
    """A period through several plant modes (Verisig 2.0's quadrotor MPC: one mode per
    segment), as a :class:`Hybrid` plant: the plant modes with their invariants, the clocked
    jumps between them and the jumps back to the networks (which end the period)."""
    aut = ex.aut
    R = set(ex.region)
    entering = {j.dst for j in aut.jumps if j.dst in R and j.src not in R}
    leaving = [j for j in aut.jumps if j.src in R and j.dst not in R and j.dst not in ex.terminal]
    if len(entering) != 1 or len({j.src for j in leaving}) != 1:
        raise ex.src.error(
            ex.modes[ex.region[0]].pos,
            f"the plant modes {', '.join(ex.region)} must be entered through one mode and left (back to the networks) from one mode",
        )
    first, last = entering.pop(), leaving[0].src
    if any(j.dst in R for j in ex.out[last]):
        raise ex.src.error(ex.modes[last].pos, f"plant mode '{last}' leaves to the networks and to plant modes; not supported")
    plant = [v for v in ex.vars if v not in ex.timers and any(ex.const(ex.modes[m].ode.get(v, ("num", 0.0))) != 0.0 for m in R)]
    plant_set = set(plant)
    if aut.init_mode in R:
        raise ex.src.error(
            aut.init_pos,
            f"the run starts in the plant mode '{aut.init_mode}'; start before the controller (as Verisig's generated files do)",
        )
    pre = ex.run(aut.init_mode, RunState(dict(ex.sym), dict(init_timers)), first, plant_set)
    pre_calls = ex.calls
    for v in plant:
        if pre.env[v] is not ex.sym[v]:
            raise ex.src.error(aut.init_pos, f"the jumps before the first flow change the plant state '{v}'; not supported")
    check_entry_clock(ex, pre.timers, first)
    entry0 = pre.timers
    exit0, seq = through_plant_modes(ex, R, first, last, entry0)
    period = sum(d for _, _, d in seq)
    ex.flow_mode = last  # the networks' part of the period starts where the plant modes end
    end = ex.cycle(last, first, exit0, plant_set)
    check_entry_clock(ex, end.timers, first)
    for v in plant:
        if end.env[v] is not ex.sym[v]:
            raise ex.src.error(
                ex.modes[first].pos, f"the jumps between the plant modes' visits change the plant state '{v}'; not supported"
            )
    same_controller(ex, pre_calls, pre.env, ex.calls, end.env, plant)
    calls = ex.calls
    H = horizon_steps(ex, end.elapsed + period, end.max_jumps + len(seq) - 1, pre.jumps)
    entries = [dict(entry0)]
    for _ in range(H):
        out_t, _ = through_plant_modes(ex, R, first, last, entries[-1])
        entries.append({v: out_t[v] + e.c if isinstance(e := end.timers[v], Relative) else e for v in ex.timers})
    inner = [j for j in aut.jumps if j.src in R and j.dst in R]
    # Clocks the plant modes test become states of the plant; each period must enter them at the same values.
    tested = set()
    for m in R:
        for lhs, _, rhs, _ in ex.modes[m].inv:
            tested |= ast_variables(lhs) | ast_variables(rhs)
    for j in inner + leaving:
        for lhs, _, rhs, _ in j.guard:
            tested |= ast_variables(lhs) | ast_variables(rhs)
    clocks = [v for v in ex.vars if v in ex.timers and v in tested]
    for v in clocks:
        if any(abs(e[v] - entry0[v]) > TOL for e in entries):
            raise ParseError(
                f"{ex.src.path}: the clock '{v}' enters the plant mode '{first}' at different values in different periods; not supported"
            )
    read = set()
    for m in R:
        for v in plant:
            read |= ast_variables(ex.modes[m].ode.get(v, ("num", 0.0)))
    read |= tested
    for j in inner:
        for ast in j.reset.values():
            read |= ast_variables(ast)
    if read & set(ex.timers) - set(clocks):
        raise ex.src.error(
            ex.modes[first].pos, f"the plant modes read the counters {sorted(read & set(ex.timers) - set(clocks))}; not supported"
        )
    inputs, params = [], []
    for v in ex.vars:
        if v in read and v not in plant_set and v not in ex.timers:
            (params if end.env[v] is ex.sym[v] else inputs).append(v)
    states = plant + params + clocks
    state_set = set(states)
    build = lambda ast: build_value(ex.src, ast, lambda n, p: Expr.var(n))  # noqa: E731
    modes = {}
    for m in ex.region:
        mode = ex.modes[m]
        rhs = {v: build(mode.ode.get(v, ("num", 0.0))) for v in plant + clocks}
        modes[m] = Mode(rhs, invariant=constraint_conditions(ex, mode.inv, f"invariant of '{m}'"))
    jumps = []
    for j in inner + leaving:
        resets = {}
        for v, ast in j.reset.items():
            if v in state_set:
                resets[v] = build(ast)
            elif j in inner:
                raise ex.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} between plant modes assigns '{v}', which is not a plant state; not supported"
                )
        jumps.append(
            Jump(j.src, j.dst if j in inner else None, guard=constraint_conditions(ex, j.guard, f"jump {j.src} -> {j.dst}"), reset=resets)
        )
    # The property: jumps into unsafe modes leave the last plant mode at the end of a period, or at any time.
    unsafe, absorbing = property_edges(ex, last)
    at = RunState(dict(ex.sym), {v: 0.0 for v in ex.timers})
    safe = [negate(conds, ex.src, None) for conds, _ in ex.obligations]
    finals = []
    last_entries = [through_plant_modes(ex, R, first, last, e)[1][-1][1] for e in entries[:H]] + [None]
    for j in unsafe + absorbing:
        if j in absorbing:
            raise ex.src.error(j.pos, f"jump {j.src} -> {j.dst} ends the run early (an absorbing goal) in a hybrid model; not supported")
        timer_atoms, conds = edge_conditions(ex, j, at)
        dwell = seq[-1][2]
        trig = flow_trigger(ex, timer_atoms, last_entries, last, dwell, H)
        ends = {
            n + 1 for n in range(H) if ex.timer_holds(timer_atoms, RunState({}, through_plant_modes(ex, R, first, last, entries[n])[0]))
        }
        if trig != "always" and set(trig) != ends:
            raise ex.src.error(
                j.pos, f"jump {j.src} -> {j.dst} fires inside a period; only at the ends of periods or at all times is supported"
            )
        kind = classify_trigger(ex, trig, f"jump {j.src} -> {j.dst}", j.pos, H)
        if kind == "always":
            safe.append(negate(conds, ex.src, j))
        elif kind is not None:
            finals.append((j, conds, kind[1]))
    H = property_horizon(ex, finals, safe, H)
    goal, within = final_goal(ex, finals, [], last)
    check_plant_states(ex, safe, goal, state_set, "")
    stages, _ = build_stages(ex, calls, state_set, {u: end.env[u] for u in inputs})
    ordered = [v for v in ex.vars if v in state_set]
    init = {**ex.init_box([v for v in ordered if v not in clocks]), **{v: (entry0[v], entry0[v]) for v in clocks}}
    init = {v: init[v] for v in ordered}
    step = min(d for _, _, d in seq if d > TOL) / 10
    hybrid = Hybrid(modes, jumps, inputs=inputs, start=first, max_time=2 * period, step=step, max_jumps=4 * len(seq))
    loop = ClosedLoop(hybrid, stages)
    ex.notes.append(
        f"plant modes {' -> '.join(m for m, _, _ in seq)} per period, verified as a hybrid plant (Taylor models through the jumps)"
    )
    jump_note(ex, H - 1, end.max_jumps + len(seq) - 1, pre.jumps, bool(finals))
    return make_problem(ex, loop, init, H, goal, safe, within, period)


def through_plant_modes(ex, R: set, first: str, last: str, timers: dict) -> tuple:
    """The plant modes' time-triggered sequence from ``first`` (entered with ``timers``) to
    ``last``: (timers on leaving ``last``, [(mode, timers on entry, dwell)])."""
    node, t, seq = first, dict(timers), []
    for _ in range(4 * len(R)):
        dwell = ex.dwell(node, t)
        seq.append((node, dict(t), dwell))
        t = {v: t[v] + ex.timers[v][node] * dwell for v in t}
        if node == last:
            return t, seq
        inner = [j for j in ex.out[node] if j.dst in R]
        fire = []
        for j in inner:
            if any(not (ast_variables(l) | ast_variables(r)) <= set(ex.timers) for l, _, r, _ in j.guard):
                raise ex.src.error(
                    j.pos,
                    f"jump {j.src} -> {j.dst} between plant modes has a state guard; only clock-triggered jumps between plant modes are supported",
                )
            if ex.timer_holds(j.guard, RunState({}, t)):
                fire.append(j)
        if len(fire) != 1:
            raise ex.src.error(
                ex.modes[node].pos,
                f"plant mode '{node}' must leave by exactly one jump into the next plant mode when its clock runs out, found {len(fire)}",
            )
        j = fire[0]
        for v, ast in j.reset.items():
            if v in ex.timers:
                kind, c = ex.timer_reset(v, ast)
                t[v] = c if kind == "set" else t[v] + c
        node = j.dst
    raise ex.src.error(ex.modes[first].pos, f"the plant modes from '{first}' never reach '{last}'")
