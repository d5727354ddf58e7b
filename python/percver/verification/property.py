"""The property a loop must satisfy: safe conditions at every step, a goal at the end or at
some step (``within``), each judged on float runs as the engine judges it on sets."""

from __future__ import annotations

from typing import Optional

import numpy as np

from percver import _core
from percver.errors import InputError
from percver.expr import Condition
from percver.systems import ClosedLoop, all_of


def conditions(value, what: str, states: list) -> list:
    if value is None:
        return []
    items = value if isinstance(value, (list, tuple)) else [value]
    out = []
    for c in items:
        if not isinstance(c, Condition):
            raise InputError(f"{what} must be a condition such as p >= 0.45 (or a list of them), got {c!r}")
        unknown = set(c.margin().variables()) - set(states)
        if unknown:
            raise InputError(f"{what} '{c}' uses {sorted(unknown)}, which are not states of the loop ({', '.join(states)})")
        out.append(c)
    return out


NEGATE = {"<": lambda m: m >= 0, "<=": lambda m: m > 0, ">": lambda m: m <= 0, ">=": lambda m: m < 0}


def holds(op: str, margin: np.ndarray) -> np.ndarray:
    return {"<": margin < 0, "<=": margin <= 0, ">": margin > 0, ">=": margin >= 0}[op]


class Property:
    """safe (every step), goal (last step, or some step if within) over the states."""

    def __init__(self, loop: ClosedLoop, safe, unsafe, goal, within: bool, steps: int):
        self.states = loop.states
        self.safe = conditions(safe, "safe", self.states)
        for u in conditions(unsafe, "unsafe", self.states):
            # One unsafe half-space is the complement of a safe one.
            self.safe.append(NEGATE[u.op](u.margin()))
        goals = conditions(goal, "goal", self.states)
        self.goal = all_of(goals) if goals else None  # a list is a conjunction
        self.within = within
        self.steps = steps
        if not self.safe and self.goal is None:
            raise InputError("nothing to verify: give safe=..., unsafe=... or goal=...")

    def rust(self):
        safe = [(c.margin(), c.op, str(c)) for c in self.safe]
        goal = (self.goal.margin(), self.goal.op, str(self.goal)) if self.goal is not None else None
        return safe, goal

    def _satisfied(self, condition, x: np.ndarray, parameters: Optional[dict]) -> np.ndarray:
        margin = _core.eval_float([condition.margin()], self.states, np.ascontiguousarray(x), parameters)[:, 0]
        return holds(condition.op, margin)

    def parameters(self) -> list:
        """The uncertain parameters the property's conditions read, as ``(id, lo, hi)``."""
        conditions = self.safe + ([self.goal] if self.goal is not None else [])
        return [p for c in conditions for p in c.margin().parameters()]

    def monitor(self, loop: ClosedLoop, x0: np.ndarray, steps: int, parameters: Optional[dict] = None):
        """Runs from the rows of ``x0`` (with ``parameters``: ``{id: value per run}``) judged as
        the engine judges them: the safe conditions at every step and, with ``within``, a run
        ends at its first step at the goal (after it, its states are NaN and need not be
        simulated). Returns the trajectories (N x (steps + 1) x n) and per run its first
        violation ``(step, label)``, or None."""
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
            for c in self.safe:
                bad = going & ~self._satisfied(c, x, values)
                for i in np.nonzero(bad)[0]:
                    found[live[i]] = (t, str(c))
                going &= ~bad
            if self.goal is not None and (self.within or t == steps):
                arrived = self._satisfied(self.goal, x, values)
                if t == steps:
                    for i in np.nonzero(going & ~arrived)[0]:
                        found[live[i]] = (t, f"goal {self.goal}")
                going &= ~arrived
            live, x = live[going], x[going]
            if not len(live):
                break
        return traj, found
