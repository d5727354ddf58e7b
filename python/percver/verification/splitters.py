"""Splitters: how the initial set is cut into cells, and how a cell the engine leaves unknown is
cut again. A splitter is a parameter of :func:`percver.verify` (``splitter=``), not code inside it.

- :class:`Grid`: a uniform grid (``split={state: pieces}``); a cell's verdict is final.
- :class:`Bisection`: a grid whose unknown cells are halved (along the state the engine wanted
  to split, else the widest relative to the initial set) down to ``min_width``.
- :class:`Adaptive` (the default): no layout to give. It starts from a coarse grid, halves what
  stays unknown, and learns from the cells settled so far how small cells must be where: a cell
  about to run next to smaller cells that were needed (they verified after their parents did
  not) is cut to their size first, so the engine does not spend a run on a cell that is too big.

Timed-out cells (``timeout_per_cell``) are halved by every splitter that can.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from percver.errors import InputError
from percver.sets import Box


def grid(box: Box, split: dict):
    """The cells of ``box.split(split)`` as a lazy iterator, and their count: a campaign of 10^4
    cells never holds them all at once."""
    unknown = set(split) - set(box.names)
    if unknown:
        raise InputError(f"split names {sorted(unknown)}, which are not states ({', '.join(box.names)})")
    axes = [[c.bounds[j] for c in box.split({name: split[name]})] if name in split else [box.bounds[j]] for j, name in enumerate(box.names)]
    return (Box(box.names, bounds) for bounds in itertools.product(*axes)), int(np.prod([len(a) for a in axes]))


def bisect(box: Box, init: Box, min_width: dict, hint: Optional[str] = None) -> list:
    """Halves the cell along ``hint`` (the state the engine wanted to split) while it is above
    its min_width, else along the widest dimension relative to the initial set among those
    above theirs."""
    above = above_min_width(box, init, min_width)
    if hint in box.names and above[box.names.index(hint)]:
        j = box.names.index(hint)
    else:
        rel = [(hi - lo) / (ihi - ilo) if ok else -1.0 for ok, (lo, hi), (ilo, ihi) in zip(above, box.bounds, init.bounds)]
        j = int(np.argmax(rel))
    return _halves(box, j)


def _halves(box: Box, j: int) -> list:
    lo, hi = box.bounds[j]
    mid = 0.5 * (lo + hi)
    left = list(box.bounds)
    right = list(box.bounds)
    left[j] = (lo, mid)
    right[j] = (mid, hi)
    return [Box(box.names, tuple(left)), Box(box.names, tuple(right))]


def above_min_width(cell: Box, init: Box, min_width: dict, default: float = 1 / 64) -> list:
    """Per dimension: whether halving the cell keeps it at least min_width (default ``default``
    of the initial set) wide."""
    return [
        hi - lo > 2 * min_width.get(name, (ihi - ilo) * default) and ihi > ilo
        for name, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds)
    ]


def splittable(cell: Box, init: Box, min_width: dict, default: float = 1 / 64) -> bool:
    return any(above_min_width(cell, init, min_width, default))


def _checked_widths(min_width: Optional[dict]) -> dict:
    out = {}
    for name, w in (min_width or {}).items():
        if not (isinstance(w, (int, float)) and w > 0 and np.isfinite(w)):
            raise InputError(f"min_width['{name}'] must be a positive number, got {w!r}")
        out[name] = float(w)
    return out


@dataclass
class Grid:
    """A uniform grid of ``split`` pieces per state (``{"p": 20}``); verdicts are final, but a
    cell that times out is halved, down to ``min_width`` (default 1/64 of the initial set)."""

    split: dict = field(default_factory=dict)
    min_width: dict = field(default_factory=dict)

    def __post_init__(self):
        self.min_width = _checked_widths(self.min_width)

    def initial(self, init: Box):
        return grid(init, self.split)

    def prepare(self, cell: Box, init: Box) -> list:
        return [cell]

    def again(self, cell: Box, result, init: Box, timed_out: bool) -> Optional[list]:
        if result.verdict == "unknown" and timed_out and splittable(cell, init, self.min_width):
            return bisect(cell, init, self.min_width, result.split)
        return None

    def learn(self, cell: Box, verdict: str, init: Box) -> None:
        pass


@dataclass
class Bisection(Grid):
    """A grid whose unknown cells are halved down to ``min_width`` (default 1/64 of the initial
    set per state): the ``refine=True`` of :func:`percver.verify`."""

    def again(self, cell: Box, result, init: Box, timed_out: bool) -> Optional[list]:
        if result.verdict == "unknown" and splittable(cell, init, self.min_width):
            return bisect(cell, init, self.min_width, result.split)
        return None


@dataclass
class Adaptive(Bisection):
    """The default: the initial set as it is (or ``start`` pieces along each state it is wide in,
    the first six of them), so a set that verifies whole costs one run; unknown cells halved down
    to ``min_width`` (default 1/1024 of the initial set); at most ``max_cells`` engine runs in all
    (then what is left is reported unknown, with its reason); and cells cut ahead of their run to
    the size their settled neighbours needed.

    Learning is by position: a cell that verified after its ancestors did not says that cells of
    its size are needed there; a cell about to run that touches one is cut to that size along the
    states where it is wider. It never makes a verdict, only cells: every cell still gets its
    own proof. Resuming from a journal settles the journal's cells in the order they come, so a
    resumed run may cut differently and run a few cells again (never fewer proofs)."""

    start: int = 1
    max_cells: int = 1024
    patience: int = 3
    needed: list = field(default_factory=list, repr=False)  # cells that verified below the top
    runs: int = field(default=0, repr=False)
    lineage: dict = field(default_factory=dict, repr=False)  # cell key -> (parent's steps reached, stalls)

    def __post_init__(self):
        super().__post_init__()
        if not (isinstance(self.start, int) and self.start >= 1):
            raise InputError(f"Adaptive(start=...) must be a positive integer, got {self.start!r}")
        if not (isinstance(self.max_cells, int) and self.max_cells >= 1):
            raise InputError(f"Adaptive(max_cells=...) must be a positive integer, got {self.max_cells!r}")

    def initial(self, init: Box):
        widest = [n for n, (lo, hi) in zip(init.names, init.bounds) if hi > lo][:6]
        return grid(init, {n: self.start for n in widest})

    def _min(self, init: Box) -> dict:
        return {n: self.min_width.get(n, (hi - lo) / 1024) for n, (lo, hi) in zip(init.names, init.bounds)}

    def prepare(self, cell: Box, init: Box) -> list:
        """``cell`` cut to the widths its settled neighbours needed (where they are narrower)."""
        target = {}
        for box in self.needed:
            if _touches(cell, box):
                for n, (lo, hi) in zip(box.names, box.bounds):
                    target[n] = min(target.get(n, np.inf), hi - lo)
        pieces = {}
        for j, (n, (lo, hi)) in enumerate(zip(cell.names, cell.bounds)):
            if n in target and hi - lo > 1.5 * target[n]:
                pieces[n] = min(int(2 ** np.ceil(np.log2((hi - lo) / target[n]))), 64)
        if not pieces:
            return [cell]
        cells, _ = grid(cell, pieces)
        return list(cells)

    def again(self, cell: Box, result, init: Box, timed_out: bool) -> Optional[list]:
        """Halves of an unknown cell while halving pays: a lineage whose cells lose precision no
        later than their parents did ``patience`` times in a row stops (splitting does not help
        there: the loss is not the cell's width), as do cells at ``min_width`` and any cell once
        ``max_cells`` have run."""
        self.runs += 1
        if result.verdict != "unknown" or self.runs >= self.max_cells or not splittable(cell, init, self._min(init), 0):
            return None
        reached, stalls = self.lineage.pop(_key(cell), (-1, 0))
        stalls = stalls + 1 if result.steps_done <= reached else 0
        if stalls >= self.patience:
            return None
        halves = bisect(cell, init, self._min(init), result.split)
        for half in halves:
            self.lineage[_key(half)] = (result.steps_done, stalls)
        return halves

    def learn(self, cell: Box, verdict: str, init: Box) -> None:
        if verdict == "verified" and any(hi - lo < ihi - ilo for (lo, hi), (ilo, ihi) in zip(cell.bounds, init.bounds)):
            self.needed.append(cell)


def _key(box: Box) -> tuple:
    return tuple(box.bounds)


def _touches(a: Box, b: Box) -> bool:
    """Whether the closed boxes intersect (a shared face counts: neighbours)."""
    return all(alo <= bhi and blo <= ahi for (alo, ahi), (blo, bhi) in zip(a.bounds, b.bounds))
