"""Where the branches of a control period join again: immediate post-dominators of its modes."""

from __future__ import annotations


def post_dominators(ex, start: str, first_edges: list, stop: str) -> dict:
    """Immediate post-dominators of the modes between ``start`` and ``stop`` (where
    branches of the period join again)."""
    succ: dict = {start: sorted({j.dst for j in first_edges})}
    todo = [j.dst for j in first_edges]
    while todo:
        m = todo.pop()
        if m in succ or m == stop:
            continue
        succ[m] = sorted({j.dst for j in ex.continuing(m)})
        if not succ[m]:
            raise ex.src.error(ex.pos(m), f"mode '{m}' has no way back to '{stop}' (no continuing jumps)")
        todo += succ[m]
    succ[stop] = []
    # A cycle that avoids the period's start/end cannot be one control period.
    colour: dict = {}
    for root in succ:
        if colour.get(root):
            continue
        stack = [(root, iter(succ[root]))]
        colour[root] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
            elif colour.get(nxt) == 1:
                raise ex.src.error(
                    ex.pos(nxt),
                    f"mode '{nxt}' lies on a cycle that does not pass '{stop}': a loop inside one control period is not supported",
                )
            elif not colour.get(nxt):
                colour[nxt] = 1
                stack.append((nxt, iter(succ[nxt])))
    # Post-dominators: dominators of the reversed graph rooted at ``stop``.
    pred: dict = {m: [] for m in succ}
    for m, ss in succ.items():
        for s in ss:
            pred[s].append(m)
    order, seen = [], {stop}
    stack = [(stop, iter(pred[stop]))]
    while stack:
        node, it = stack[-1]
        nxt = next(it, None)
        if nxt is None:
            order.append(node)
            stack.pop()
        elif nxt not in seen:
            seen.add(nxt)
            stack.append((nxt, iter(pred[nxt])))
    rpo = order[::-1]
    index = {m: i for i, m in enumerate(rpo)}
    ipdom = {stop: stop}
    changed = True
    while changed:
        changed = False
        for m in rpo[1:]:
            cands = [s for s in succ[m] if s in ipdom]
            new = cands[0]
            for s in cands[1:]:
                a, b = new, s
                while a != b:
                    while index[a] > index[b]:
                        a = ipdom[a]
                    while index[b] > index[a]:
                        b = ipdom[b]
                new = a
            if ipdom.get(m) != new:
                ipdom[m] = new
                changed = True
    return ipdom
