"""Sets of states for ``pv.verify``'s ``safe=``, ``unsafe=`` and ``goal=``: conditions, boxes,
their intersections (:func:`all_of`) and unions (:func:`any_of`), and time windows
(:func:`during`).

The engine decides one condition ``margin op 0`` per requirement, so a set made of several
conditions becomes one: the smallest margin for an intersection, the largest for a union, each
member's margin turned to "g >= 0" or "g > 0". Where strict and non-strict comparisons mix, the
combined comparison is strict, which is never weaker than the set it stands for (it differs only
on the boundary of a non-strict member). A set to avoid is first complemented member by member
(``x <= 0`` becomes ``x > 0``, an intersection a union), which is exact, and then combined: so
"avoid B" is also never weaker than avoiding B. Simulation (falsification) judges each member
exactly.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError
from percver.expr import Condition, Expr, maximum, minimum
from percver.sets import Box

_NEGATE = {"<": lambda m: m >= 0, "<=": lambda m: m > 0, ">": lambda m: m <= 0, ">=": lambda m: m < 0}
_HOLDS = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}


class Region:
    """A set of states: conditions (and nested regions) joined by intersection (``"all"``) or
    union (``"any"``). Made by :func:`all_of`, :func:`any_of` or from a :class:`~percver.Box`."""

    def __init__(self, kind: str, parts: Sequence[Union[Condition, "Region"]]):
        self.kind = kind
        self.parts = tuple(parts)

    def complement(self) -> "Region":
        """The states outside, exactly: De Morgan down to the conditions, each negated."""
        flip = {"all": "any", "any": "all"}[self.kind]
        return Region(flip, [p.complement() if isinstance(p, Region) else _NEGATE[p.op](p.margin()) for p in self.parts])

    def conditions(self) -> list:
        """Every condition of the region, nested ones included."""
        return [c for p in self.parts for c in (p.conditions() if isinstance(p, Region) else [p])]

    def condition(self) -> Condition:
        """One condition for the engine, never weaker than the region (module doc)."""
        if len(self.parts) == 1:
            p = self.parts[0]
            return p.condition() if isinstance(p, Region) else p
        members = [p.condition() if isinstance(p, Region) else p for p in self.parts]
        margins = [-c.margin() if c.op in ("<", "<=") else c.margin() for c in members]
        joined = functools.reduce(minimum if self.kind == "all" else maximum, margins)
        return joined > 0.0 if any(c.op in ("<", ">") for c in members) else joined >= 0.0

    def holds(self, names: Sequence[str], x: np.ndarray, parameters: Optional[dict] = None) -> np.ndarray:
        """Row-wise membership of float states (N x n, columns in ``names`` order), member by
        member; ``parameters`` gives the uncertain parameters' values per row (``{id: values}``)."""
        inside = [
            p.holds(names, x, parameters)
            if isinstance(p, Region)
            else _HOLDS[p.op](_core.eval_float([p.margin()], list(names), np.ascontiguousarray(x), parameters)[:, 0], 0.0)
            for p in self.parts
        ]
        return np.logical_and.reduce(inside) if self.kind == "all" else np.logical_or.reduce(inside)

    def __str__(self) -> str:
        inner = f" {'and' if self.kind == 'all' else 'or'} ".join(str(p) for p in self.parts)
        return inner if len(self.parts) == 1 else f"({inner})"

    __repr__ = __str__


SetLike = Union[Condition, Region, Box, Mapping, Sequence]


def as_region(value, what: str) -> Region:
    """A condition, region or box (or a list of them: their intersection) as a region. A
    ``{name: (lo, hi)}`` mapping is a box."""
    if isinstance(value, Region):
        return value
    if isinstance(value, Condition):
        return Region("all", [value])
    if isinstance(value, Mapping):
        value = Box(value)
    if isinstance(value, Box):
        v = [Expr.var(n) for n in value.names]
        return Region("all", [c for x, (lo, hi) in zip(v, value.bounds) for c in (x >= lo, x <= hi)])
    if isinstance(value, (list, tuple)) and value:
        return Region("all", [as_region(p, what) for p in value]) if len(value) > 1 else as_region(value[0], what)
    raise InputError(
        f"{what} must be a condition such as p >= 0.45, a pv.Box, pv.all_of(...) or pv.any_of(...) (or a list of them), got {value!r}"
    )


def all_of(*sets: SetLike) -> Region:
    """The states in every one of ``sets`` (conditions, boxes, regions): their intersection."""
    return Region("all", [as_region(s, "all_of()") for s in _flat(sets, "all_of")])


def any_of(*sets: SetLike) -> Region:
    """The states in at least one of ``sets``: their union (e.g. several obstacles to avoid)."""
    return Region("any", [as_region(s, "any_of()") for s in _flat(sets, "any_of")])


def _flat(sets: tuple, name: str) -> list:
    items = list(sets[0]) if len(sets) == 1 and isinstance(sets[0], (list, tuple)) else list(sets)
    if not items:
        raise InputError(f"{name}() needs at least one condition or box")
    return items


@dataclass(frozen=True)
class Window:
    """A safety requirement that applies only for part of the run: see :func:`during`."""

    region: Region
    steps: Optional[tuple] = None
    time: Optional[tuple] = None

    def in_steps(self, period: Optional[float], horizon: int) -> tuple:
        """The window as (first, last) step, fractional for times between steps; a time within
        1e-9 steps of a step is that step (t / period is rounded: 0.3 / 0.1 is 2.9999999999999996)."""
        if self.time is None:
            lo, hi = self.steps
            return (lo, float(horizon) if hi is None else hi)
        if period is None:
            raise InputError(
                f"during({self.region}, time=...) needs a continuous plant (pv.Continuous) to turn times "
                f"into steps; for a discrete plant give steps=(first, last)"
            )
        snap = lambda s: float(round(s)) if abs(s - round(s)) <= 1e-9 else s  # noqa: E731
        lo, hi = self.time
        return (snap(lo / period), float(horizon) if hi is None else snap(hi / period))


def during(region: SetLike, *, steps: Optional[tuple] = None, time: Optional[tuple] = None) -> Window:
    """``region`` required (with ``safe=``) or avoided (with ``unsafe=``) only in a window of the
    run: ``steps=(first, last)`` control steps, or ``time=(t0, t1)`` seconds of a continuous plant
    (step k is time k * period); ``last`` None means up to the horizon. Both ends are included.
    A continuous plant's flowpipe segments are checked wherever their time span meets the window,
    so ARCH-COMP's "x1 in [0, 1] for t in [0.5, 1]" is
    ``safe=pv.during(pv.Box({"x1": (0, 1)}), time=(0.5, 1))`` and "for t > 8" is
    ``time=(8, None)``."""
    if (steps is None) == (time is None):
        raise InputError("during() needs exactly one of steps=(first, last) or time=(t0, t1)")
    window = steps if steps is not None else time
    try:
        lo, hi = window
        lo, hi = float(lo), None if hi is None else float(hi)
    except (TypeError, ValueError):
        raise InputError(f"during(): the window must be a pair (first, last), last None for the horizon; got {window!r}") from None
    if not (lo >= 0 and (hi is None or hi >= lo)):
        raise InputError(f"during(): the window ({lo}, {hi}) must start at 0 or later and not end before it starts")
    if steps is not None and not (lo.is_integer() and (hi is None or hi.is_integer())):
        raise InputError(f"during(): steps=({lo}, {hi}) must be whole steps; give time=(t0, t1) for times between steps")
    pair = (lo, hi)
    return Window(as_region(region, "during()"), steps=pair if steps is not None else None, time=pair if time is not None else None)
