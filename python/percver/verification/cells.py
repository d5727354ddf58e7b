"""Cells of the initial set: the grid, and the bisection of a cell that stays unknown (along the
state the engine wanted to split, down to ``min_width``)."""

from __future__ import annotations

import itertools
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
    axes = [[c.bounds[j] for c in box.split({name: split[name]})] if name in split else [box.bounds[j]]
            for j, name in enumerate(box.names)]
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
    lo, hi = box.bounds[j]
    mid = 0.5 * (lo + hi)
    left = list(box.bounds)
    right = list(box.bounds)
    left[j] = (lo, mid)
    right[j] = (mid, hi)
    return [Box(box.names, tuple(left)), Box(box.names, tuple(right))]


def above_min_width(cell: Box, init: Box, min_width: dict) -> list:
    """Per dimension: whether halving the cell keeps it at least min_width (default 1/64 of the
    initial set) wide."""
    return [hi - lo > 2 * min_width.get(name, (ihi - ilo) / 64) and ihi > ilo
            for name, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds)]


def splittable(cell: Box, init: Box, min_width: dict) -> bool:
    return any(above_min_width(cell, init, min_width))
