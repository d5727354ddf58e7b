"""The wrapping effect, read from a cell's run: its enclosure ended far wider than the float runs
from the cell and grew by a steady factor a step before that, so the errors of one step were fed
back into the next. Symbols for the states' errors (``state_symbols=True``) or boxes to restart
from (``rebox=True``) stop that; the hints name both, and the adaptive splitter tries the first."""

from __future__ import annotations

import itertools
from typing import Optional

import numpy as np

from percver.sets import Box
from percver.systems import ClosedLoop

# An enclosure this many times the spread of the float runs from its cell is loose ...
LOOSE = 10.0
# ... and one that grew at least this factor a step over the last RECENT steps (all, if fewer) is
# growing from errors that feed back through the loop (the float runs of a stable loop do not).
GROWTH = 1.25
RECENT = 5
# Float runs per cell examined for a hint: its corners, then uniform points ...
SAMPLES = 64
# ... and for the adaptive splitter, on each lost cell while its retries with state symbols are
# undecided: 64 runs of the Mountain Car image chain on each of them cost a tenth of the blur
# row's CPU seconds (bench/README.md), and fewer runs only make the spread smaller, so a wrapping more likely to be claimed (then a
# retry with symbols, which is learnt from).
QUICK = 8
# ... on at most this many cells (the hints': unknown cells; the adaptive splitter's: lost cells
# while its retries with state symbols are undecided): the wrapping shows in the first or not at all.
EXAMINED = 16


def wrapping(loop: ClosedLoop, cell, samples: int = SAMPLES) -> Optional[tuple]:
    """(state, enclosure over float spread, growth a step, step, runs) for the cell (a
    :class:`~percver.verification.results.Cell` with its reach boxes) whose enclosure wrapped over
    ``samples`` float runs from it, else None."""
    boxes = np.asarray(cell.boxes or [], dtype=float)
    if boxes.ndim != 3 or len(boxes) < 3 or boxes.shape[1] != len(loop.states):
        return None
    last = len(boxes) - 1
    # Over the last RECENT steps, or all of them for a cell lost earlier (TORA's at order 5: at step 3).
    recent = min(RECENT, last)
    box = Box.coerce(cell.box, loop.states)
    # The first `samples` distinct corners only: a loop of 30 states has 2^30 of them.
    ends = [sorted({lo, hi}) for lo, hi in box.bounds]
    corners = np.array(list(itertools.islice(itertools.product(*ends), samples)), dtype=float)
    x0 = np.vstack([corners, box.sample(samples - len(corners))])
    with np.errstate(all="ignore"):
        runs = loop.simulate(x0, last)
    spread = np.ptp(runs[:, last], axis=0)
    width = boxes[last, :, 1] - boxes[last, :, 0]
    before = boxes[last - recent, :, 1] - boxes[last - recent, :, 0]
    ratio = np.where(spread > 0, width / np.where(spread > 0, spread, 1.0), 0.0)
    j = int(np.argmax(ratio))
    if not (ratio[j] >= LOOSE and before[j] > 0):
        return None
    growth = (width[j] / before[j]) ** (1 / recent)
    return (loop.states[j], float(ratio[j]), float(growth), last, len(x0)) if growth >= GROWTH else None
