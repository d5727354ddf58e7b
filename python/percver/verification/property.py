"""The property a loop must satisfy: sets to stay in (at every step, or in a window of steps),
to avoid, and to reach at the end or at some step (``within``), each judged on float runs as the
engine judges it on sets. The sets themselves are :mod:`percver.properties`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from percver.errors import InputError
from percver.expr import Condition
from percver.properties import Region, Window, all_of, as_region
from percver.systems import ClosedLoop, Continuous


def holds(op: str, margin: np.ndarray) -> np.ndarray:
    return {"<": margin < 0, "<=": margin <= 0, ">": margin > 0, ">=": margin >= 0}[op]


@dataclass
class Requirement:
    """One safety requirement: the states stay in ``region`` at the steps of ``window`` (first,
    last; None: every step). ``condition`` is what the engine decides (never weaker)."""

    region: Region
    window: Optional[tuple]
    condition: Condition
    label: str


def requirements(value, what: str, loop: ClosedLoop, steps: int, avoid: bool) -> list:
    """``safe=`` (each item a requirement) or ``unsafe=`` (one set to avoid: a list is the
    intersection of its conditions) as requirements; an intersection to stay in is one
    requirement per member, which the engine decides separately (tighter than their minimum)."""
    if value is None:
        return []
    items = list(value) if isinstance(value, (list, tuple)) else [value]
    if avoid and len(items) > 1:
        if any(isinstance(i, Window) for i in items):
            raise InputError(
                "unsafe=[...] is one set (the intersection of its conditions); give a window to the whole set, "
                "unsafe=pv.during(pv.all_of(...), steps=...), or several with pv.any_of"
            )
        if sum(not isinstance(i, Condition) for i in items) > 1:
            raise InputError(
                "unsafe=[...] is one set, the intersection of its members; for several sets to avoid write "
                "unsafe=pv.any_of(set1, set2), for their intersection unsafe=pv.all_of(set1, set2)"
            )
        items = [all_of(items)]
    period = loop.plant.period if isinstance(loop.plant, Continuous) else None
    out = []
    for item in items:
        window = item.in_steps(period, steps) if isinstance(item, Window) else None
        given = as_region(item.region if isinstance(item, Window) else item, what)
        _known(given, what, loop.states)
        during = "" if window is None else f" for steps [{window[0]:g}, {window[1]:g}]"
        if avoid:
            region = given.complement()
            out.append(Requirement(region, window, region.condition(), f"unsafe {given}{during}"))
            continue
        for part in _members(given):
            out.append(Requirement(part, window, part.condition(), f"{part}{during}"))
    return out


def _known(region: Region, what: str, states: list):
    for c in region.conditions():
        unknown = set(c.margin().variables()) - set(states)
        if unknown:
            raise InputError(f"{what} '{c}' uses {sorted(unknown)}, which are not states of the loop ({', '.join(states)})")


def _members(region: Region) -> list:
    """An intersection's members as regions of their own (nested intersections flattened)."""
    if region.kind != "all":
        return [region]
    return [m for p in region.parts for m in (_members(p) if isinstance(p, Region) else [Region("all", [p])])]


class Property:
    """safe (every step, or a window of steps), goal (last step, or some step if within) over the states."""

    def __init__(self, loop: ClosedLoop, safe, unsafe, goal, within: bool, steps: int):
        self.states = loop.states
        self.safe = requirements(safe, "safe", loop, steps, avoid=False) + requirements(unsafe, "unsafe", loop, steps, avoid=True)
        if isinstance(goal, Window) or (isinstance(goal, (list, tuple)) and any(isinstance(g, Window) for g in goal)):
            raise InputError("goal= takes no window: it is checked at the last step, or at every step with within=True")
        self.goal_region = None if goal is None or (isinstance(goal, (list, tuple)) and not goal) else as_region(goal, "goal")
        if self.goal_region is not None:
            _known(self.goal_region, "goal", self.states)
        self.goal = self.goal_region.condition() if self.goal_region is not None else None  # a list is a conjunction
        self.within = within
        self.steps = steps
        if not self.safe and self.goal is None:
            raise InputError("nothing to verify: give safe=..., unsafe=... or goal=...")

    def rust(self):
        safe = [(r.condition.margin(), r.condition.op, r.label, r.window) for r in self.safe]
        goal = (self.goal.margin(), self.goal.op, str(self.goal), None) if self.goal is not None else None
        return safe, goal

    def parameters(self) -> list:
        """The uncertain parameters the property's conditions read, as ``(id, lo, hi)``."""
        conditions = [r.condition for r in self.safe] + ([self.goal] if self.goal is not None else [])
        return [p for c in conditions for p in c.margin().parameters()]

    def monitor(self, loop: ClosedLoop, x0: np.ndarray, steps: int, parameters: Optional[dict] = None):
        """Runs from the rows of ``x0`` (with ``parameters``: ``{id: value per run}``) judged as
        the engine judges them: the safe sets at the steps they apply to (member by member) and,
        with ``within``, a run ends at its first step at the goal (after it, its states are NaN
        and need not be simulated). Returns the trajectories (N x (steps + 1) x n) and per run
        its first violation ``(step, label)``, or None."""
        traj = np.full((len(x0), steps + 1, len(self.states)), np.nan)
        found: list = [None] * len(x0)
        live, x = np.arange(len(x0)), np.asarray(x0, dtype=float)
        drawn = {k: np.asarray(v, dtype=float) for k, v in (parameters or {}).items()}
        for t in range(steps + 1):
            values = {k: v[live] for k, v in drawn.items()}
            if t:
                x = loop.step_float(x, values)
            traj[live, t] = x
            going = np.ones(len(live), dtype=bool)
            for r in self.safe:
                if r.window is not None and not r.window[0] - 1e-9 <= t <= r.window[1] + 1e-9:
                    continue
                bad = going & ~r.region.holds(self.states, x, values)
                for i in np.nonzero(bad)[0]:
                    found[live[i]] = (t, r.label)
                going &= ~bad
            if self.goal is not None and (self.within or t == steps):
                arrived = self.goal_region.holds(self.states, x, values)
                if t == steps:
                    for i in np.nonzero(going & ~arrived)[0]:
                        found[live[i]] = (t, f"goal {self.goal_region}")
                going &= ~arrived
            live, x = live[going], x[going]
            if not len(live):
                break
        return traj, found
