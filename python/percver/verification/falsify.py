"""Falsification: float runs from a cell's centre, corners and random points, with the loop's
uncertain parameters drawn per run, judged by the property; the first violation is a
counterexample that replays."""

from __future__ import annotations

import zlib

import numpy as np

from percver.systems import ClosedLoop
from percver.verification.journal import cell_key
from percver.verification.property import Property
from percver.verification.results import Counterexample


def falsify(loop: ClosedLoop, prop: Property, cells: list, steps: int, samples: int, seed: int, probe: bool = True) -> list:
    """Simulates each cell's ``samples`` random points and, with ``probe``, its centre and corners
    (up to 2^8), all cells in one batch; per cell, the first violating trajectory is its
    counterexample (else None). The loop's uncertain parameters are drawn per run and held for
    the run: random points draw them uniformly; the probe crosses the centre and corners with
    the parameters' corners and midpoint (up to :data:`PROBE_RUNS` runs per cell, a random subset
    beyond). The draws come from the cell itself (seeded by its bounds), so a cell gets the same
    runs whichever order or process it is run in."""
    if not cells:
        return []
    params = list({p[0]: p for p in loop.parameters() + prop.parameters()}.values())
    p_lo, p_hi = np.array([p[1] for p in params]), np.array([p[2] for p in params])
    p_corners = np.vstack([0.5 * (p_lo + p_hi)[None], corners(p_lo, p_hi, 8)])
    blocks, drawn = [], []
    for cell in cells:
        lo, hi = cell.lo, cell.hi
        rng = np.random.default_rng([seed, zlib.crc32(cell_key(cell.to_dict()).encode())])
        starts = np.vstack([0.5 * (lo + hi)[None], corners(lo, hi, 8)]) if probe else np.empty((0, len(lo)))
        # Every probe start with every parameter corner: a violation may need both at once.
        pick = np.arange(len(starts) * len(p_corners))
        if len(pick) > PROBE_RUNS:
            pick = np.sort(rng.choice(pick, PROBE_RUNS, replace=False))
        blocks.append(np.vstack([starts[pick // len(p_corners)], lo + (hi - lo) * rng.random((samples, len(lo)))]))
        drawn.append(np.vstack([p_corners[pick % len(p_corners)], p_lo + (p_hi - p_lo) * rng.random((samples, len(params)))]))
    x0, values = np.vstack(blocks), np.vstack(drawn)
    parameters = {p[0]: values[:, k] for k, p in enumerate(params)}
    owner = np.repeat(np.arange(len(cells)), [len(b) for b in blocks])
    traj, found = prop.monitor(loop, x0, steps, parameters)
    out = [None] * len(cells)
    # Per cell, its earliest violation (the first run among equals) is the counterexample.
    for r in sorted((r for r in range(len(x0)) if found[r] is not None), key=lambda r: (found[r][0], r)):
        k = owner[r]
        if out[k] is None:
            step, label = found[r]
            used = [{"id": p[0], "range": [p[1], p[2]], "value": float(values[r, j])} for j, p in enumerate(params)]
            out[k] = Counterexample(dict(zip(loop.states, map(float, x0[r]))), traj[r, : step + 1].tolist(), step, label, used)
    return out


PROBE_RUNS = 1024  # probe runs per cell at most: centre and corners crossed with parameter corners


def corners(lo: np.ndarray, hi: np.ndarray, most: int) -> np.ndarray:
    """The corners of the box over its non-degenerate dimensions, when there are at most ``most``."""
    free = np.nonzero(hi > lo)[0]
    if not len(free) or len(free) > most:
        return np.empty((0, len(lo)))
    bits = (np.arange(2 ** len(free))[:, None] >> np.arange(len(free))) & 1
    corners = np.repeat(lo[None], len(bits), axis=0)
    corners[:, free] = np.where(bits, hi[free], lo[free])
    return corners


def spread(loop: ClosedLoop, cell, steps: int) -> dict:
    """How much each dimension of ``cell`` moves the runs up to ``steps``: per dimension, the runs
    from the centres of its two opposite faces (the loop's uncertain parameters at their
    midpoints), their largest distance per state over the steps, relative to the largest any
    dimension makes in that state, summed over the states that change along the runs (a noise
    parameter held as a constant state is not compared with itself). The dimension with the
    largest spread is the one whose width the enclosures pay most for: a first-order picture of
    a Taylor model's dependence on each initial variable."""
    lo, hi = cell.lo, cell.hi
    free = [j for j in range(len(lo)) if hi[j] > lo[j]]
    if not free:
        return {}
    centre = 0.5 * (lo + hi)
    faces = np.repeat(centre[None], 2 * len(free), axis=0)
    for k, j in enumerate(free):
        faces[2 * k, j], faces[2 * k + 1, j] = lo[j], hi[j]
    params = {p[0]: np.full(len(faces), 0.5 * (p[1] + p[2])) for p in loop.parameters()}
    with np.errstate(all="ignore"):
        traj = loop.simulate(faces, max(int(steps), 1), params)
        apart = np.nan_to_num(np.abs(traj[0::2] - traj[1::2]).max(axis=1), nan=np.inf, posinf=np.inf)  # dims x states
    moving = np.ptp(traj, axis=1).max(axis=0) > 0  # states that change along some run
    top = apart[:, moving].max(axis=0)
    share = np.where(top > 0, apart[:, moving] / np.where(top > 0, top, 1.0), 0.0)
    return {cell.names[j]: float(s) for j, s in zip(free, np.nan_to_num(share, nan=1.0).sum(axis=1))}
