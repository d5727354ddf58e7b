"""Steps and horizons: how many periods fit the file's time horizon, and at which steps
a counter- or clock-guarded property jump can fire."""

from __future__ import annotations

import math

from percver.errors import ParseError
from percver.translation.execution import RunState
from percver.translation.values import TOL, Relative, compare, fold


def horizon_steps(ex, elapsed: float, per_period_jumps: int, prefix_jumps: int) -> int:
    T = ex.aut.settings.time
    if elapsed > TOL:
        H = int(math.floor(T / elapsed + TOL))
    else:
        mj = ex.aut.settings.max_jumps
        if not mj:
            raise ParseError(f"{ex.src.path}: a period takes no time and there is no 'max jumps': the horizon is undefined")
        H = (mj - prefix_jumps) // max(per_period_jumps, 1)
    if H < 1:
        raise ParseError(f"{ex.src.path}: the time horizon {T} is shorter than one control period ({elapsed})")
    return H


def jump_note(ex, H: int, per_period: int, prefix: int, property_jump: bool):
    mj = ex.aut.settings.max_jumps
    if mj is None:
        return
    need = prefix + H * per_period + (1 if property_jump else 0)
    if need > mj:
        ex.notes.append(
            f"'max jumps {mj}' stops Flow* after {mj} jumps, but {H} periods of {per_period} jumps"
            f"{' plus the jump into the unsafe mode' if property_jump else ''} need {need}: Flow* never checks the final-step property. "
            f"percver checks the intended one ({H} steps)"
        )


def classify_trigger(ex, trig, what: str, pos: int, H: int):
    """'always', ('final', step), or None (never within the horizon); else refused."""
    if trig == "always":
        return "always"
    steps = sorted(trig)
    if not steps:
        ex.notes.append(
            f"{what} (line {ex.src.line(pos)}) cannot fire before the time horizon ends ({H} steps; Flow* computes no flow past 'time'); dropped"
        )
        return None
    if steps == list(range(H + 1)):
        return "always"
    if len(steps) == 1:
        return ("final", steps[0])
    raise ex.src.error(
        pos,
        f"{what} fires at steps {steps[:5]}{'...' if len(steps) > 5 else ''} only; percver checks a property at every step or at one final step",
    )


def property_horizon(ex, finals: list, safe: list, H: int) -> int:
    """The final-step properties set the horizon (ex2 checks at 1.4 s of a 1.8 s run)."""
    steps = {s for _, _, s in finals}
    if len(steps) > 1:
        raise ParseError(f"{ex.src.path}: final-step properties at different steps {sorted(steps)}; not supported")
    if not steps:
        return H
    s = steps.pop()
    if s < H and safe:
        raise ParseError(
            f"{ex.src.path}: a property at step {s} and properties at every step up to {H}; not expressible as one verification"
        )
    return s


def check_assumed(ex, end_timers: dict, start_timers: dict, anchor: str):
    for v in ex.assumed_absolute:
        e = end_timers[v]
        if isinstance(e, Relative) or abs(e - start_timers[v]) > TOL:
            raise ParseError(
                f"{ex.src.path}: a jump guard inside the period reads the counter '{v}', which changes from step to step "
                f"(start {start_timers[v]}, after one period {e}); step-dependent control flow is not supported"
            )


def timer_sequence(ex, start: dict, end: dict, H: int, advance) -> list:
    """Counter values at the boundary of each step 0..H (``advance`` adds the flow)."""
    seq = [dict(start)]
    for n in range(H):
        cur = seq[-1]
        nxt = {}
        for v in ex.timers:
            e = end[v]
            nxt[v] = advance(v, n, cur[v] + e.c if isinstance(e, Relative) else e)
        seq.append(nxt)
    return seq


def discrete_trigger(ex, atoms: list, timer_at: list, H: int):
    if not atoms:
        return "always"
    steps = set()
    for n in range(H + 1):
        st = RunState({}, timer_at[n])
        if ex.timer_holds(atoms, st):
            steps.add(n)
    return steps


def check_entry_clock(ex, timers: dict, F: str):
    for lhs, op, rhs, pos in ex.modes[F].inv:
        if lhs[0] == "var" and lhs[1] in ex.timers:
            t = timers[lhs[1]]
            if isinstance(t, Relative) or abs(t) > TOL:
                raise ex.src.error(pos, f"the plant mode '{F}' is entered with '{lhs[1]}' = {t}, not 0: its dwell time would vary")


def flow_trigger(ex, atoms: list, entries: list, F: str, P: float, H: int):
    """When a jump leaving the flowing mode can fire, as step indices: flow time 0 of
    period n is step n, time P is step n + 1. Like Flow*, no flow starts at the time
    horizon, so a guard that holds only from then on (f1tenth's ``k = 50``) never fires."""
    if not atoms:
        return "always"
    always, any_full, steps = True, False, set()
    for n in range(H):
        span = P
        lo, hi = 0.0, span
        for lhs, op, rhs, pos in atoms:

            def margin(tau):
                st = RunState({}, {v: entries[n][v] + ex.timers[v][F] * tau for v in ex.timers})
                return fold("-", ex.value(lhs, st), ex.value(rhs, st))

            m0, m1 = margin(0.0), margin(span)
            if span > 0 and abs(margin(span / 2) - (m0 + m1) / 2) > TOL * max(1.0, abs(m0), abs(m1)):
                raise ex.src.error(pos, "a clock/counter constraint that is not linear in time")
            a, b = solve_linear(m0, (m1 - m0) / span if span > 0 else 0.0, op, span)
            lo, hi = max(lo, a), min(hi, b)
        empty = lo > hi + TOL
        full = not empty and lo <= TOL and hi >= span - TOL
        if not full:
            always = False
        if empty:
            continue
        if full:
            any_full = True
            steps |= {n, n + 1}
        elif hi - lo > TOL:
            raise ParseError(f"{ex.src.path}: a property jump out of '{F}' fires during part of period {n} only; not supported")
        elif abs(lo) <= TOL:
            steps.add(n)
        elif abs(lo - span) <= TOL:
            steps.add(n + 1)
        else:
            raise ParseError(
                f"{ex.src.path}: a property jump out of '{F}' fires inside period {n} (t = {lo} of {span}); only step boundaries are supported"
            )
    if always:
        return "always"
    if any_full:
        raise ParseError(f"{ex.src.path}: a property jump out of '{F}' fires during some periods only; not supported")
    return steps


def solve_linear(m0: float, slope: float, op: str, span: float) -> tuple:
    """The times tau in [0, span] where m0 + slope * tau satisfies ``op`` against 0."""
    tol = TOL * max(1.0, abs(m0))
    if abs(slope) <= TOL:
        return (0.0, span) if compare(m0, op, 0.0) else (1.0, 0.0)
    root = -m0 / slope
    if op == "=":
        return (min(max(root, 0.0), span),) * 2 if -tol <= root <= span + tol else (1.0, 0.0)
    holds_after = (slope > 0) == (op in (">=", ">"))
    return (max(root, 0.0), span) if holds_after else (0.0, min(root, span))
