"""Splitters: how the initial set is cut into cells, and how a cell the engine leaves unknown is
cut again. A splitter is a parameter of :func:`percver.verify` (``splitter=``), not code inside it.

- :class:`Grid`: a uniform grid (``split={state: pieces}``); a cell's verdict is final.
- :class:`Bisection`: a grid whose unknown cells are halved (along the state the engine wanted
  to split, else the widest relative to the initial set) down to ``min_width``.
- :class:`Adaptive` (the default): no layout to give. It starts from the whole set, halves what
  stays unknown while halving pushes the loss of precision later, cuts cells ahead of their run
  to the size their settled neighbours needed, and retries a cell lost to a domain error or a
  blow-up with ``rebox`` (see its doc).

A splitter has four methods: ``initial(init)`` (the first cells, lazily, and their count),
``prepare(cell, init)`` (the cell cut before it runs), ``learn(cell, result, init)`` (every cell
settled or split) and ``again(cell, result, init, timed_out)`` (None: the verdict is final; else
the cells replacing it, each a Box or ``(Box, engine options)``, or a :class:`Retry`). Whatever
it returns, every verdict comes from the engine (or a simulated counterexample) on that very
cell; the coverage is the share of settled cells, so pieces must tile the cell they replace, as
grids and halves do (a custom splitter's pieces are its own responsibility).

Timed-out cells (``timeout_per_cell``) are halved by every splitter that can.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from percver.errors import InputError
from percver.sets import Box


@dataclass(frozen=True)
class Retry:
    """What :meth:`Adaptive.again` returns to run the same cell again with more engine settings."""

    options: dict


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

    def learn(self, cell: Box, result, init: Box) -> None:
        """Called with every settled or split cell (``result``: its Cell), before :meth:`again`."""


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
    to ``min_width`` (default 1/1024 of the initial set); at most ``max_cells`` cells in all
    (then what is left is reported unknown, with its reason). What it learns from the cells
    settled so far (it never makes a verdict, only cells: every cell gets its own proof):

    - Where cells must be small, and how small: a half that verified after its parent did not
      says that cells of its size are needed there; a cell that verified only after splits
      inside it (``branches``) says that cells half its size are (an in-cell split costs more
      than a cell of its own: on Mountain Car, a cell verified whole in about the time of one
      split). A cell about to run that touches such a cell is cut to that size (along the
      states where it is wider) instead of spending a run at a size that failed or split next
      door. A cell cut ahead of its run that verifies whole proves nothing about its size, and
      counting it would spread the smallest size over the whole set.
    - Which state to halve: the one whose width moves the runs most up to the step where the
      cell was lost (``probe``: the campaign simulates the runs from the centres of the cell's
      opposite faces, :func:`percver.verification.falsify.spread`), else the one the engine
      wanted to split; after a halving that did not push the loss of precision later (a deeper
      ``steps_done`` or ``deepest_step`` than the parent's), the widest of the other states
      relative to the initial set.
    - Where halving stops paying: a lineage that gains no step ``patience`` times per state it
      can halve in a row stops (the loss is not the cell's width).
    - Whether restarting from boxes pays (``rebox``, see :func:`percver.verify`): the first
      ``patience`` unknown cells, and any cell lost because an operation left its domain
      (``division is undefined``, a square root of a negative range) or an enclosure blew up
      (remainders that feed back and grow make both), run again with ``rebox=True`` before
      they are halved; a retry that gets deeper than the plain run wins, and its halves keep
      ``rebox`` (so a loop where it decides, such as F1/10's LiDAR loop, runs reboxed from then
      on). Retries go on while they win more often than not, and for the two reasons above
      until they have lost ``patience`` times more often than won: a loop where reboxing does
      not help pays a few runs for finding out. ``rebox=False`` never retries (``True`` is
      ``pv.verify(rebox=True)``: every cell reboxed from the start).

    Decisions are journaled with the cells (:class:`~percver.verification.journal.Journal`): a
    resumed run replays them (the same pieces for every cell the journal decided; none of its
    cells runs again) and relearns from its cells; what the journal had not decided is decided
    afresh from all of that."""

    start: int = 1
    max_cells: int = 16384
    patience: int = 4
    rebox: Optional[bool] = None
    needed: list = field(default_factory=list, repr=False)  # (cell, widths needed there)
    probe: Optional[Callable] = field(default=None, repr=False)  # (cell, steps) -> {state: spread}, set by the campaign
    runs: int = field(default=0, repr=False)
    lineage: dict = field(default_factory=dict, repr=False)  # half's key -> (parent's steps, deepest step, stalls, state halved)
    retried: dict = field(default_factory=dict, repr=False)  # cell key -> steps the plain run reached
    rebox_score: list = field(default_factory=lambda: [0, 0], repr=False)  # retries that went deeper, and not

    def __post_init__(self):
        super().__post_init__()
        if not (isinstance(self.start, int) and self.start >= 1):
            raise InputError(f"Adaptive(start=...) must be a positive integer, got {self.start!r}")
        if not (isinstance(self.max_cells, int) and self.max_cells >= 1):
            raise InputError(f"Adaptive(max_cells=...) must be a positive integer, got {self.max_cells!r}")
        if not (isinstance(self.patience, int) and self.patience >= 1):
            raise InputError(f"Adaptive(patience=...) must be a positive integer, got {self.patience!r}")

    def initial(self, init: Box):
        if self.rebox:
            raise InputError("Adaptive(rebox=True) is pv.verify(rebox=True): give that instead")
        widest = [n for n, (lo, hi) in zip(init.names, init.bounds) if hi > lo][:6]
        return grid(init, {n: self.start for n in widest})

    def _min(self, init: Box) -> dict:
        return {n: self.min_width.get(n, (hi - lo) / 1024) for n, (lo, hi) in zip(init.names, init.bounds)}

    def prepare(self, cell: Box, init: Box) -> list:
        """``cell`` cut to the widths its settled neighbours needed (where they are narrower)."""
        target = {}
        for box, widths in self.needed:
            if _touches(cell, box):
                for n, w in widths.items():
                    target[n] = min(target.get(n, np.inf), w)
        pieces = {}
        for n, (lo, hi) in zip(cell.names, cell.bounds):
            if n in target and hi - lo > 1.5 * target[n]:
                pieces[n] = min(int(2 ** np.ceil(np.log2((hi - lo) / target[n]))), 64)
        if not pieces:
            return [cell]
        cells, _ = grid(cell, pieces)
        return list(cells)

    def learn(self, cell: Box, result, init: Box) -> None:
        self.runs += 1
        key = _key(cell)
        if key in self.retried and result.options.get("rebox"):
            self.rebox_score[0 if result.verdict == "verified" or result.steps_done > self.retried[key] else 1] += 1
        if result.verdict == "verified" and (result.branches or key in self.lineage):
            size = bisect(cell, init, self._min(init), result.split)[0] if result.branches else cell
            self.needed.append((cell, {n: hi - lo for n, (lo, hi) in zip(size.names, size.bounds)}))

    def again(self, cell: Box, result, init: Box, timed_out: bool):
        """A :class:`Retry` with rebox, halves (with their options), or None (see the class doc)."""
        key = _key(cell)
        if result.verdict != "unknown" or self.runs >= self.max_cells:
            self.lineage.pop(key, None)
            return None
        if self._rebox_pays(key, result):
            self.retried[key] = result.steps_done
            return Retry({"rebox": True})
        if not splittable(cell, init, self._min(init), 0):
            return None
        widths = self._min(init)
        reached, deepest, stalls, halved = self.lineage.pop(key, (-1, -1, 0, None))
        stalls = stalls + 1 if result.steps_done <= reached and result.deepest_step <= deepest else 0
        if stalls >= self.patience * sum(above_min_width(init, init, widths, 0)):
            return None
        hint = result.split
        if self.probe is not None:
            moves = self.probe(cell, result.deepest_step)
            above = above_min_width(cell, init, widths, 0)
            hint = max(((moves.get(n, 0.0), n) for ok, n in zip(above, cell.names) if ok), default=(0.0, hint))[1]
        if stalls:
            above = above_min_width(cell, init, widths, 0)
            others = [
                ((hi - lo) / (ihi - ilo), n)
                for ok, n, (lo, hi), (ilo, ihi) in zip(above, cell.names, cell.bounds, init.bounds)
                if ok and n != halved
            ]
            hint = max(others)[1] if others else hint
        options = dict(result.options)
        if options.get("rebox") and key in self.retried and result.steps_done <= self.retried[key]:
            options.pop("rebox")  # the retry went no deeper than the plain run: the halves run plain
        halves = bisect(cell, init, widths, hint)
        j = next(j for j, (a, b) in enumerate(zip(halves[0].bounds, cell.bounds)) if a != b)
        for half in halves:
            self.lineage[_key(half)] = (result.steps_done, result.deepest_step, stalls, cell.names[j])
        return [(half, options) for half in halves]

    def _rebox_pays(self, key: tuple, result) -> bool:
        if self.rebox is False or result.options.get("rebox") or key in self.retried:
            return False
        wins, losses = self.rebox_score
        lost = any(words in (result.reason or "") for words in PRECISION_LOST)
        return wins + losses < self.patience or wins > losses or (lost and losses - wins < self.patience)


# Reasons (the engine's words) after which a cell is retried with rebox: an operation left its
# domain (taylor's Domain error: division, sqrt, log) or an enclosure blew up.
PRECISION_LOST = (" is undefined on ", " blew up ")


def _key(box: Box) -> tuple:
    return tuple(box.bounds)


def _touches(a: Box, b: Box) -> bool:
    """Whether the closed boxes intersect (a shared face counts: neighbours)."""
    return all(alo <= bhi and blo <= ahi for (alo, ahi), (blo, bhi) in zip(a.bounds, b.bounds))
