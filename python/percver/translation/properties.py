"""The property of a translated model: jumps into the ``unsafe`` modes and absorbing goal
modes, read as conditions at every step, at the final step, or as a goal reached within."""

from __future__ import annotations

from typing import Optional

from percver.errors import ParseError
from percver.expr import Expr
from percver.formats.flowstar_syntax import AutomatonJump, ast_variables
from percver.translation.conditions import all_of, atom_text, complementary, dedupe, dedupe_atoms, implies, negate
from percver.translation.execution import RunState
from percver.translation.timing import classify_trigger
from percver.translation.values import build_value, condition_of


def property_edges(ex, source: str) -> tuple:
    """Jumps into terminal modes: (unsafe ones, absorbing ones) leaving ``source``; such
    jumps elsewhere are refused."""
    unsafe, absorbing = [], []
    for j in ex.aut.jumps:
        if j.dst not in ex.terminal:
            continue
        if j.src != source:
            raise ex.src.error(
                j.pos,
                f"jump {j.src} -> {j.dst} ends the run from '{j.src}'; properties are read from jumps leaving '{source}' (the step boundary) only",
            )
        (unsafe if j.dst in ex.aut.unsafe else absorbing).append(j)
    return unsafe, absorbing


def edge_conditions(ex, j: AutomatonJump, state: RunState) -> tuple:
    """(timer atoms, state conditions) of a property jump: its guard, then the unsafe
    block of the target evaluated after the jump's reset."""
    timer_atoms, conds = ex.split_atoms(j.guard, state, f"jump {j.src} -> {j.dst}")
    if j.dst in ex.aut.unsafe:
        after = ex.apply_reset(j, state)
        more_t, more_c = ex.split_atoms(ex.aut.unsafe[j.dst][0], after, f"unsafe set of '{j.dst}'")
        if more_t:
            raise ex.src.error(ex.aut.unsafe[j.dst][1], f"unsafe set of '{j.dst}' constrains clocks/counters; put those in the jump guard")
        conds = conds + more_c
    return timer_atoms, dedupe(conds)


def final_goal(ex, finals: list, within_goals: list, anchor: str):
    """The goal: every final-step unsafe set avoided, or (absorbing goal mode) the goal
    region reached at some step, which also ends the run."""
    if within_goals:
        if len(within_goals) != 1 or len(finals) != 1:
            j = within_goals[0][0]
            raise ex.src.error(
                j.pos,
                "an absorbing goal mode is supported with exactly one goal jump and one final-step unsafe jump (the Mountain Car pattern)",
            )
        (gj, _), (uj, uconds, _) = within_goals[0], finals[0]
        g_atoms = [a for a in gj.guard if not (ast_variables(a[0]) | ast_variables(a[2])) <= set(ex.timers)]
        u_atoms = dedupe_atoms(
            [a for a in uj.guard if not (ast_variables(a[0]) | ast_variables(a[2])) <= set(ex.timers)]
            + (ex.aut.unsafe[uj.dst][0] if uj.dst in ex.aut.unsafe else [])
        )
        if len(g_atoms) != 1 or len(u_atoms) != 1 or not complementary(g_atoms[0], u_atoms[0]):
            raise ex.src.error(
                gj.pos,
                f"goal jump {gj.src} -> {gj.dst} and unsafe jump {uj.src} -> {uj.dst} must test one constraint in opposite directions "
                f"(e.g. x >= c and x <= c) for a 'reach the goal within the horizon' property",
            )
        # Runs continue only while the goal is not reached; else Verisig's runs could go on
        # from the goal region and the within-goal would be unsound.
        for j in ex.continuing(anchor):
            if not any(implies(a, u_atoms[0]) for a in j.guard):
                raise ex.src.error(
                    j.pos,
                    f"jump {j.src} -> {j.dst} continues the run without requiring {atom_text(u_atoms[0])}; "
                    f"the goal mode would not end every run that reaches the goal",
                )
        return negate(uconds, ex.src, uj), True
    if not finals:
        return None, False
    negs = [negate(conds, ex.src, j) for j, conds, _ in finals]
    if len(negs) == 1:
        return negs[0], False
    return all_of(negs), False


def constraint_conditions(ex, atoms: list, where: str) -> list:
    """Constraint atoms as conditions over the variables ('=' as two)."""
    out = []
    for lhs, op, rhs, pos in atoms:
        lv, rv = (build_value(ex.src, a, lambda n, p: Expr.var(n)) for a in (lhs, rhs))
        for o in ["<=", ">="] if op == "=" else [op]:
            c = condition_of(lv, o, rv)
            if c is False:
                raise ex.src.error(pos, f"{where}: the constraint never holds")
            if c is not True:
                out.append(c)
    return out


def check_plant_states(ex, safe: list, goal, states: set, plant: str):
    """A property of a flowing plant reads only its states (``plant`` names it in the message)."""
    for c in safe + ([goal] if goal is not None else []):
        extra = set(c.margin().variables()) - states
        if extra:
            raise ParseError(f"{ex.src.path}: the property reads {sorted(extra)}, which are not plant states{plant}")


def jump_properties(ex, source: str, trigger, H: int, model: Optional[str] = None) -> tuple:
    """The property jumps out of ``source`` by when they fire (``trigger`` maps a jump's counter
    atoms to its steps): (conditions safe at every step, [(jump, conditions, step)] checked at one
    final step, [(jump, conditions)] of absorbing goals that end the run at any step). An
    absorbing goal is refused in a ``model`` (a flowing plant's kind); None accepts it."""
    unsafe, absorbing = property_edges(ex, source)
    at = RunState(dict(ex.sym), {v: 0.0 for v in ex.timers})
    safe, finals, goals_within = [], [], []
    for j in unsafe + absorbing:
        timer_atoms, conds = edge_conditions(ex, j, at)
        kind = classify_trigger(ex, trigger(timer_atoms), f"jump {j.src} -> {j.dst}", j.pos, H)
        if kind is None:
            continue
        if j in absorbing:
            if kind != "always":
                ex.notes.append(f"jump {j.src} -> {j.dst} (line {ex.src.line(j.pos)}) ends the run at step {kind[1]} only; ignored")
                continue
            if model is not None:
                raise ex.src.error(
                    j.pos, f"jump {j.src} -> {j.dst} ends the run early (an absorbing goal) in a {model} model; not supported"
                )
            goals_within.append((j, conds))
        elif kind == "always":
            safe.append(negate(conds, ex.src, j))
        else:
            finals.append((j, conds, kind[1]))
    return safe, finals, goals_within
