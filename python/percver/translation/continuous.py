"""A period with one flowing mode: the loop's plant is a ``pv.Continuous`` ODE whose inputs
the networks compute and hold for the period."""

from __future__ import annotations

from percver.errors import ParseError
from percver.expr import Expr
from percver.systems import ClosedLoop, Continuous
from percver.translation.conditions import negate
from percver.translation.execution import RunState
from percver.translation.problem import VerisigProblem, make_problem
from percver.translation.properties import check_plant_states, final_goal, jump_properties
from percver.translation.stages import build_stages, same_controller
from percver.translation.timing import check_entry_clock, flow_trigger, horizon_steps, jump_note, property_horizon
from percver.formats.flowstar_syntax import ast_variables
from percver.translation.values import TOL, Relative, build_value


def continuous_problem(ex, init_timers: dict) -> VerisigProblem:
    aut = ex.aut
    F = ex.flow_mode
    fmode = ex.modes[F]
    P = ex.inv_bound(fmode)
    plant = [v for v in ex.vars if v not in ex.timers and ex.const(fmode.ode.get(v, ("num", 0.0))) != 0.0]
    plant_set = set(plant)
    # Prefix: from the initial mode to the first entry into the plant mode.
    if aut.init_mode == F:
        raise ex.src.error(
            aut.init_pos,
            f"the run starts in the plant mode '{F}' with its input from the init block; "
            f"start before the controller (as Verisig's generated files do)",
        )
    pre = ex.run(aut.init_mode, RunState(dict(ex.sym), dict(init_timers)), F, plant_set)
    pre_calls = ex.calls  # its obligations are the cycle's own (the same jumps)
    for v in plant:
        if pre.env[v] is not ex.sym[v]:
            raise ex.src.error(aut.init_pos, f"the jumps before the first flow change the plant state '{v}'; not supported")
    check_entry_clock(ex, pre.timers, F)
    entry0 = pre.timers
    anchor1 = {v: entry0[v] + ex.timers[v][F] * P for v in ex.timers}
    end = ex.cycle(F, F, anchor1, plant_set)
    check_entry_clock(ex, end.timers, F)
    for v in ex.assumed_absolute:
        e = end.timers[v]
        if isinstance(e, Relative) or abs(e + ex.timers[v][F] * P - anchor1[v]) > TOL:
            raise ParseError(
                f"{ex.src.path}: a jump guard inside the period reads the counter '{v}', which changes from step to step; not supported"
            )
    for v in plant:
        if end.env[v] is not ex.sym[v]:
            raise ex.src.error(
                fmode.pos,
                f"the jumps of one period change the plant state '{v}' of the continuous mode '{F}'; a continuous plant cannot jump",
            )
    same_controller(ex, pre_calls, pre.env, ex.calls, end.env, plant)
    calls = ex.calls
    H = horizon_steps(ex, end.elapsed + P, end.max_jumps, pre.jumps)
    # Counters at the entry into the plant mode, for each period 0..H.
    entries = [dict(entry0)]
    for n in range(H):
        nxt = {}
        for v in ex.timers:
            e = end.timers[v]
            anchor = entries[-1][v] + ex.timers[v][F] * P
            nxt[v] = anchor + e.c if isinstance(e, Relative) else e
        entries.append(nxt)
    # The plant: the flowing mode's ODE; frozen variables it reads are inputs (computed
    # by the period's jumps) or constant parameters (never assigned).
    rhs_vars = set()
    for v in plant:
        rhs_vars |= ast_variables(fmode.ode[v])
    if rhs_vars & set(ex.timers):
        clocks = ", ".join(sorted(rhs_vars & set(ex.timers)))
        raise ex.src.error(fmode.pos, f"the dynamics of '{F}' read the clock/counter(s) {clocks} (time-varying ODE); not supported")
    inputs, params = [], []
    for v in ex.vars:
        if v in rhs_vars and v not in plant_set:
            (params if end.env[v] is ex.sym[v] else inputs).append(v)
    states = plant + params
    state_set = set(states)
    rhs = {v: build_value(ex.src, fmode.ode[v], lambda n, p: Expr.var(n)) for v in plant}
    rhs.update({v: 0.0 for v in params})
    ordered = [v for v in ex.vars if v in state_set]
    # The property.
    obligations = [negate(conds, ex.src, None) for conds, _ in ex.obligations]
    safe, finals, _ = jump_properties(ex, F, lambda atoms: flow_trigger(ex, atoms, entries, F, P, H), H, "continuous")
    safe = obligations + safe
    H = property_horizon(ex, finals, safe, H)
    goal, within = final_goal(ex, finals, [], F)
    check_plant_states(ex, safe, goal, state_set, f" of '{F}'")
    stages, _ = build_stages(ex, calls, state_set, {u: end.env[u] for u in inputs})
    init = ex.init_box(ordered)
    plant_obj = Continuous({v: rhs[v] for v in ordered}, inputs=inputs, period=P)
    loop = ClosedLoop(plant_obj, stages)
    jump_note(ex, H - 1, end.max_jumps, pre.jumps, bool(finals))  # the prefix already enters the first flow
    return make_problem(ex, loop, init, H, goal, safe, within, P)
