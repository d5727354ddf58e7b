"""Shrinking a program that shows a violation, hypothesis-style: try simpler variants (a shorter
horizon, fewer options, conditions, stages, states and parameters, smaller expressions, shorter
numbers) and keep the first that still shows a violation of the same kind, until none does or the
budget is spent."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import fields, is_dataclass, replace
from typing import Callable, Optional

from percver.selftest.program import SIMPLEST, Cond, Const, Param, Program, Var, Where, children, names_in, params_in


def shrink(program: Program, violation, fails: Callable[[Program], Optional[object]], seconds: float):
    """The smallest variant found within ``seconds`` of CPU time and its violation (``fails``
    returns one, or None)."""
    deadline = time.process_time() + seconds  # CPU time: on a busy machine wall time buys little
    improved = True
    while improved and time.process_time() < deadline:
        improved = False
        for candidate in variants(program):
            if time.process_time() >= deadline:
                break
            if candidate == program:  # a substitution that found nothing to substitute
                continue
            found = fails(candidate)
            if found is not None:
                program, violation, improved = candidate, found, True
                break
    return program, violation


def variants(p: Program) -> Iterator[Program]:
    """Simpler programs than ``p``, the biggest simplifications first."""
    for steps in sorted({1, p.steps - 1}):
        if 1 <= steps < p.steps:
            yield replace(p, steps=steps)
    if p.options != SIMPLEST:
        yield replace(p, options=SIMPLEST)
    for key in p.options:
        if key not in ("min_width", "splitter"):
            rest = {k: v for k, v in p.options.items() if k != key and not (key == "refine" and k == "min_width")}
            cells = {"split", "refine", "min_width", "splitter"} & set(rest)
            yield replace(p, options=rest if cells else {**rest, **SIMPLEST})
    yield from _fewer_conditions(p)
    for k in range(len(p.stages)):
        yield from _without_stage(p, k)
    for name in p.reward:
        if not any(name in names_in(c) for c in p.conditions()):
            yield replace(p, reward={n: e for n, e in p.reward.items() if n != name})
    for s in p.states:
        yield from _without_state(p, s)
    for i, (lo, hi) in enumerate(p.params):
        yield _substituted(p, lambda node, i=i, mid=0.5 * (lo + hi): Const(mid) if node == Param(i) else None)
    used = sorted(set().union(*(params_in(e) for e in p.expressions())))
    if len(used) < len(p.params):
        renumber = {i: Param(k) for k, i in enumerate(used)}
        yield replace(
            _substituted(p, lambda node: renumber.get(node.index) if isinstance(node, Param) else None), params=[p.params[i] for i in used]
        )
    for s, (lo, hi) in p.init.items():
        if hi - lo > 1e-3:  # a narrower box would not be simpler to read
            mid = 0.5 * (lo + hi)
            for half in ((lo, mid), (mid, hi)):
                yield replace(p, init={**p.init, s: half})
    yield from _smaller_expressions(p)
    rounded = _substituted(
        p, lambda node: Const(float(f"{node.value:.2g}")) if isinstance(node, Const) and float(f"{node.value:.2g}") != node.value else None
    )
    if rounded != p:
        yield rounded


def _fewer_conditions(p: Program) -> Iterator[Program]:
    if len(p.conditions()) > 1:
        for what in ("safe", "unsafe", "goal"):
            conds = getattr(p, what)
            for i in range(len(conds)):
                rest = conds[:i] + conds[i + 1 :]
                yield replace(p, **{what: rest}, within=p.within and bool(p.goal if what != "goal" else rest))
    if p.within:
        yield replace(p, within=False)


def _without_stage(p: Program, k: int) -> Iterator[Program]:
    """Stage k removed, its outputs read as 0 (not when a later network reads it: its width would change)."""
    stage = p.stages[k]
    if any(s.nets and stage.output in s.inputs for s in p.stages[k + 1 :]):
        return
    zero = {n: Const(0.0) for n in stage.names}
    q = _substituted(p, lambda node: zero.get(node.name) if isinstance(node, Var) else None)
    stages = [replace(s, inputs=[i for i in s.inputs if i != stage.output]) for j, s in enumerate(q.stages) if j != k]
    if all(s.inputs for s in stages):
        yield replace(q, stages=stages, inputs=[u for u in q.inputs if u != stage.output])


def _without_state(p: Program, name: str) -> Iterator[Program]:
    """A state read by nothing but its own update and the property's conditions removed (with them)."""
    others = [e for s, e in p.update.items() if s != name] + list(p.reward.values()) + [e for s in p.stages for e in s.exprs or []]
    if len(p.states) == 1 or any(name in names_in(e) for e in others) or any(name in s.inputs for s in p.stages):
        return
    keep = lambda conds: [c for c in conds if name not in names_in(c)]
    q = replace(
        p,
        states=[s for s in p.states if s != name],
        init={s: b for s, b in p.init.items() if s != name},
        update={s: e for s, e in p.update.items() if s != name},
        safe=keep(p.safe),
        unsafe=keep(p.unsafe),
        goal=keep(p.goal),
        options={k: ({s: v for s, v in o.items() if s != name} if isinstance(o, dict) else o) for k, o in p.options.items()},
    )
    if q.conditions():
        yield replace(q, within=q.within and bool(q.goal))


def _slots(p: Program) -> list:
    """(getter, setter) of every expression of the program and of its property."""
    slots = []
    for s in p.update:
        slots.append((lambda q, s=s: q.update[s], lambda q, e, s=s: replace(q, update={**q.update, s: e})))
    for s in p.reward:
        slots.append((lambda q, s=s: q.reward[s], lambda q, e, s=s: replace(q, reward={**q.reward, s: e})))
    for k, stage in enumerate(p.stages):
        for i in range(len(stage.exprs or [])):

            def put(q, e, k=k, i=i):
                stages = list(q.stages)
                stages[k] = replace(stages[k], exprs=[e if j == i else x for j, x in enumerate(stages[k].exprs)])
                return replace(q, stages=stages)

            slots.append((lambda q, k=k, i=i: q.stages[k].exprs[i], put))
    for what in ("safe", "unsafe", "goal"):
        for i in range(len(getattr(p, what))):

            def put(q, c, what=what, i=i):
                conds = list(getattr(q, what))
                conds[i] = replace(conds[i], lhs=c)
                return replace(q, **{what: conds})

            slots.append((lambda q, what=what, i=i: getattr(q, what)[i].lhs, put))
    return slots


def _smaller_expressions(p: Program) -> Iterator[Program]:
    """Each sub-expression replaced by one of its children, or by 0 or 1."""
    for get, put in _slots(p):
        root = get(p)
        for path, node in _positions(root):
            options = [c for c in children(node) if not isinstance(c, Cond)]
            if isinstance(node, Where):
                options = [node.then, node.otherwise] + [replace(node, cond=replace(node.cond, lhs=c)) for c in children(node.cond.lhs)]
            options += [Const(0.0), Const(1.0)] if not isinstance(node, Const) else []
            for option in options:
                yield put(p, _put(root, path, option))


def _positions(node, path=()):
    """(path, node) of every expression node below and including ``node`` (paths are field names)."""
    yield path, node
    if is_dataclass(node):
        for f in fields(node):
            value = getattr(node, f.name)
            if is_dataclass(value):
                if isinstance(value, Cond):
                    yield from _positions(value.lhs, path + (f.name, "lhs"))
                else:
                    yield from _positions(value, path + (f.name,))


def _put(node, path: tuple, new):
    if not path:
        return new
    return replace(node, **{path[0]: _put(getattr(node, path[0]), path[1:], new)})


def _map(node, f):
    """``node`` with every sub-expression for which ``f`` gives a replacement replaced (top down)."""
    new = f(node)
    if new is not None:
        return new
    if not is_dataclass(node) or isinstance(node, (Const, Var, Param)):
        return node
    return replace(node, **{fl.name: _map(getattr(node, fl.name), f) for fl in fields(node) if is_dataclass(getattr(node, fl.name))})


def _substituted(p: Program, f) -> Program:
    """Every expression of ``p`` (loop and property) mapped with ``f``."""
    stages = [replace(s, exprs=[_map(e, f) for e in s.exprs]) if s.exprs is not None else s for s in p.stages]
    conds = {w: [_map(c, f) for c in getattr(p, w)] for w in ("safe", "unsafe", "goal")}
    return replace(
        p, update={s: _map(e, f) for s, e in p.update.items()}, reward={s: _map(e, f) for s, e in p.reward.items()}, stages=stages, **conds
    )
