"""Splitters: how the initial set is cut into cells, and how a cell the engine leaves unknown is
cut again. A splitter is a parameter of :func:`percver.verify` (``splitter=``), not code inside it.

- :class:`Grid`: a uniform grid (``split={state: pieces}``); a cell's verdict is final.
- :class:`Bisection`: a grid whose unknown cells are halved (along the state the engine wanted
  to split, else the widest relative to the initial set) down to ``min_width``.
- :class:`Adaptive` (the default): no layout to give. It starts from the whole set with few
  in-cell splits, halves what stays unknown along the state whose halvings pushed the loss of
  precision furthest, cuts cells ahead of their run to the size needed nearby, gives cells near
  that size the call's in-cell splits, retries a cell with ``rebox`` where that pays at its
  size, and with state symbols where its enclosure wrapped (see its doc).

A splitter has four methods: ``initial(init)`` (the first cells, lazily, and their count),
``prepare(cell, init)`` (the cell cut before it runs), ``learn(cell, result, init)`` (every cell
settled or split; a cell settled unknown that random runs then falsify is learnt again,
falsified: only settled cells are sampled) and ``again(cell, result, init, timed_out)`` (None:
the verdict is final; else the cells replacing it, or a :class:`Retry`). Cells given by
``initial``, ``prepare`` and ``again`` are each a Box (with the options of the cell it comes
from) or ``(Box, engine options)``, e.g. ``{"max_splits": 0}``; a :class:`Retry` option of None
drops that option (the call's applies). Whatever it returns, every verdict comes from the engine (or a simulated counterexample) on that very
cell; the coverage is the share of settled cells, so pieces must tile the cell they replace, as
grids and halves do (a custom splitter's pieces are its own responsibility).

Timed-out cells (``timeout_per_cell``) are halved by every splitter that can.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Optional

import numpy as np

from percver.errors import InputError
from percver.sets import Box
from percver.verification.wrapping import EXAMINED


@dataclass(frozen=True)
class Retry:
    """What :meth:`Adaptive.again` returns to run the same cell again with other engine settings
    (an option of None: the call's)."""

    options: dict


def grid(box: Box, split: dict):
    """The cells of ``box.split(split)`` as a lazy iterator, and their count: a campaign of 10^4
    cells never holds them all at once."""
    if not isinstance(split, Mapping):
        raise InputError(
            f"split= takes a dict of state names to a cell count (int) or width (float), e.g. {{{box.names[0]!r}: 4}}; got {split!r}"
        )
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
    """``box`` halved along state ``j``."""
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
    to ``min_width`` (default ``FLOOR``, 1/8192 of the initial set); at most ``max_cells`` cells in all
    (then what is left is reported unknown, with its reason). What it learns from the cells
    settled so far (it never makes a verdict, only cells: every cell gets its own proof):

    - How much to try inside a cell (its in-cell splits and forks, ``max_splits``): a cell runs
      with ``explore`` of them until a verified cell near it (one it touches, else the nearest)
      is at most ``reach`` halvings smaller; then with the call's. A cell far too big then fails
      at the first loss of precision, cheaply, and is halved; one that could have been split
      inside is not lost: a cell that cannot be halved further, or whose halvings stopped
      gaining steps, runs again with the call's splits before it is given up. So does, before
      it is halved, a cell whose runs reach the goal at different steps (the goal holds on
      part of its set), if the halving that made it gained nothing (``MIN_GAIN``) and it got
      within ``MIN_GAIN`` of the step where the runs of the verified cells near it arrived (or
      none has verified): halving only shrinks the spread of arrivals, a step or so a time,
      while in-cell forks separate them for a few runs (a lineage near the Mountain Car wall
      halved p0 and dc in turn to a tenth of the hand's cells that way). Its halves compare
      with its plain run.
    - Where cells must be small, and how small: a half that verified after its parent did not
      says that cells of its size are needed there, less the halvings of its lineage that
      gained nothing just before the one that verified it (those of other states: the cell
      verified through that halving, and its size with them is an accident of the path); a cell,
      a cut piece too, that verified only after in-cell splits that computed ``REDID`` (half) of
      its steps again (``steps_redone``: a split restarts where the enclosure was last precise,
      step 0 on Mountain Car, so it costs a run of its own and the steps before it) says that
      cells smaller by a halving per doubling of the runs its steps made are (one halving for up
      to three runs' steps, three for 8-15), halved along the state the engine split most (on
      Mountain Car's contrast row, cut pieces that verified after 1-7 such splits cost 3-17 times
      a clean one). Less redone work keeps the size: halving adds a run to every cell, such
      splits only to the cells that split. Forks, and splits where a piece was lost, go on from
      there and say nothing of the size. A cell verified after ``STALLED`` halvings in a row that
      gained nothing says nothing of the size needed (its size is the path's accident: cut to
      it, its neighbours would spread it). A cell about to run is cut to one size needed where it is,
      the latest learnt (of the cells it touches; with ``tile=True`` also of the nearest one
      when it touches none, which spreads the first size found over the whole set), instead of
      spending runs on the sizes that failed there; the narrowest widths of several sizes
      together would make cells smaller than any that was needed. A cut makes at most ``grade``
      pieces along a state (default 4): the pieces that still touch the cells that needed the size are cut
      again when drawn, the others run at their size, so cells grow away from where a size was
      needed (a size needed at a wall holds near it). A cell cut ahead of its run
      that verifies whole proves nothing about its size, and counting it would spread the
      smallest size over the whole set. But settled cells tell which widths did not matter
      there: pairs of neighbours of one shape along a state (any cells, cut pieces or halves)
      that verified at the same step with as many in-cell splits, or both with none, ended
      alike; lost, or redoing steps, ends like no other. Where, within ``grade`` widths of the
      shape around the cell about to be cut, ``GROW_PAIRS`` pairs of that width along a state
      ended alike and ``GROW_RATIO`` times as many as ended differently, or were lost there no
      wider than the grown shape in any state (a halving's verified halves do not grow back into
      their lost parent), the cell is cut twice as wide in that state (and again, while the
      wider pairs agree). A size learnt where another state decided, such as a noise level
      halved on the way down to cells near the Mountain Car wall, where the runs' arrival
      depends on p0 alone, is outgrown that way; a grown cell that fails is halved and its
      verified half teaches the size again.
    - Which state to halve: the one whose recent halvings of cells it touches (its lineage and
      its neighbours') pushed the loss of precision furthest (the halves' ``deepest_step``
      against their parent's; gains far away say little here: near the Mountain Car goal dc does
      not matter, while it does further left), each state tried once first in
      the order of the one whose width moves the runs most up to the step where the cell was
      lost (``probe``: the campaign simulates the runs from the centres of the cell's opposite
      faces, :func:`percver.verification.falsify.spread`), else of the engine's choice. A
      halving gains if it moves the loss of precision later by ``MIN_GAIN`` of the steps its
      parent reached; after one that did not, its lineage halves another state at once (gains
      measured elsewhere, at other sizes, say little about this one), but none whose halving left
      the enclosure as wide (``INERT``) at the last step its parent completed, until a halving
      gains: that state adds nothing there at this size (near the Mountain Car goal, halvings of
      dc left it as wide while p0's narrowed it without moving the arrival, and the turns between
      them made cells a quarter of the hand's width in dc).
      ``learn_states=False``: that first choice, and after a halving that gained no step the
      widest other state relative to the initial set. A cell lost after in-cell splits that
      computed ``REDONE`` runs' steps again is halved along the state the engine split, once:
      its own splits were halvings along it, each at the cost of a run. Once, not once per
      doubling of those runs: the engine's last split state may not be the state the cell is too
      wide in (a composite Mountain Car cell eight times too wide in dc, lost splitting p0, was
      cut into quarters along p0, and that size spread to its neighbours).
    - Where halving stops paying: a lineage that gains no step ``patience`` times per state it
      can halve in a row stops (the loss is not the cell's width; its last cell runs with the
      call's in-cell splits, then reboxed, before it is given up), unless a cell it touches
      verified at its size or smaller (it then goes on to one halving below it: a loss that no
      halving moves may still end at the size where the cell verifies). Once a cell is falsified the
      loop is unsafe: unknown cells are no longer halved (the coverage is then a lower bound).
    - Whether restarting from boxes pays (``rebox``, see :func:`percver.verify`), per size: what
      it gains depends on the cell's size (Mountain Car's whole set goes twice as deep reboxed,
      while its cells eight halvings smaller verify plain), so only retries of cells within
      ``REBOX_SIZES`` halvings of a cell's size decide for it. Where none was made yet, the first
      unknown cells, and any cell lost because an operation left its domain (``division is
      undefined``, a square root of a negative range) or an enclosure blew up (remainders that
      feed back and grow make both), run again with ``rebox=True`` before they are halved. A
      retry pays if it gets more steps deeper than the plain run than ``REBOX_COST`` times what a
      plain halving of a cell of its size gains (the mean of the latest, for the state where
      halving gains most, once every state has been halved plain at that size; for a retry that
      verified, once one has, and then it must also gain ``MIN_GAIN`` of the plain run's steps:
      docking's splitter halves two of its four states for many sizes), whether it
      verified or not: a reboxed step carries a Taylor-model variable per state and costs about
      two plain ones, while halving moves the loss of precision later at no such cost (near the
      Mountain Car wall, retries that verified a few steps deeper than plain runs made every cell
      there run reboxed, at an eighth of the plain cells' width in dc). Steps, not
      seconds, decide: the first runs last a fraction of a second, and their seconds say more
      about the load than about the method. New cells (halves, cut pieces) run reboxed where the
      retries near their size paid more often than not and plain cells of their very size (within
      half a halving; those given up at their ``max_redone`` only where no other plain cell of the
      size ran, ``REBOX_TRIALS`` of them) were lost more often than not; the first cell of a size runs plain, a trial
      (so a loop where it decides at every size, such as F1/10's LiDAR loop, pays a plain run or
      two per new size; near the Mountain Car wall, retries of cells four times larger paid, while
      the cells that verify there verify plain in half a reboxed run's work); else plain; halves
      compare with the cell's run made as they run. A cell at ``min_width`` that cannot be halved
      is retried with rebox, then (if it split inside) with ``DEEPEN`` times the in-cell splits it
      used up, before it is given up. A cell that verified only reboxed (its own plain run, or its
      parent's, lost) teaches no size: docking's plain cells are lost at every size where reboxed
      ones 2^8 times as large verify. ``rebox_order`` is the Taylor order of reboxed runs where the
      call's is higher: their models restart from a box whenever a remainder dominates, a variable
      per state, and order 5 in four variables has 3.6 times the monomials of order 3 (docking's
      reboxed cells verify as often at order 3, at a fifth to a tenth of the seconds). None (the
      default) learns it: once a reboxed run at the call's order has verified, reboxed runs start at
      ``LOW_ORDER`` while those that verified, ``LOW_ODDS`` times over, are not ``patience`` fewer
      than the reruns at the call's order that did better (verified, or got ``MIN_GAIN`` of the lost
      run's steps deeper); a run at ``LOW_ORDER`` that is lost runs again at the call's before
      anything is learnt from it, until those runs have verified ``patience`` times more often than
      the reruns did better (the camera loop of ``tests/test_validate_camera_verify.py``, which
      verifies reboxed at order 5 in 44 cells, was still unknown after 4,763 at order 3 alone). A
      given order is kept, and a lost run at it is not run again. Retries go on while they pay more
      often than not, and for the two reasons above until they have lost ``patience`` times more
      often than paid; retries still running, or not yet comparable with a halving, count as lost.
      ``rebox=False`` never retries (``True`` is ``pv.verify(rebox=True)``: every cell reboxed
      from the start).
    - Whether state symbols pay (``state_symbols``, see :func:`percver.verify`), for the whole
      call: a cell lost without them whose enclosure wrapped (the campaign's float runs from it,
      :func:`~percver.verification.wrapping.wrapping`, on the first ``EXAMINED`` cells lost: the
      wrapping shows there or not at all) runs again with them, before a rebox retry; the retry
      pays if it verifies or moves the loss of precision ``MIN_GAIN`` of the plain run's steps
      later. Once more retries paid than not (those out count as not), new cells run with them
      and a cell drawn before and lost is retried with them; the retries stop after ``patience``
      more losses than wins (those out count as losses), and their halves run without. Whether
      they pay does not depend on the cell's size as rebox's does: the wrapping is the loop's
      gain, which symbols cancel at any size (ARCH-COMP's TORA with its ReLU controller: at order
      5 its cells are lost at step 3 or 4 without them, and with them it verifies in as many
      cells as when they are given). ``symbols=False`` never retries (nor does the splitter of
      ``pv.verify`` with ``state_symbols=True``, ``rebox=True`` or another method than Taylor
      models).

    Decisions are journaled with the cells (:class:`~percver.verification.journal.Journal`): a
    resumed run replays them (the same pieces, with their engine options, for every cell the
    journal decided; none of its cells runs again) and relearns from its cells; what the journal
    had not decided is decided afresh from all of that. Outcomes are learnt in the order the cells
    were drawn, ``window`` draws late (:class:`~percver.verification.campaign.Campaign`): the
    cells do not depend on which cell finishes first, nor on the number of threads up to
    ``window``."""

    # Cells drawn (and probed) ahead of a free thread: one, so that every outcome can reshape the next cell.
    lookahead = 1

    start: int = 1
    # Cells drawn whose outcomes the next draw does not wait for (the campaign's ``window``): what
    # is learnt when a cell is drawn, and so every cell, is the same on every run and for up to
    # this many threads (with 2 workers, finish order had made 24 to 1,939 cells of one call).
    window: int = 4
    max_cells: int = 16384
    patience: int = 4
    rebox: Optional[bool] = None
    explore: int = 0
    reach: int = 2
    learn_states: bool = True
    tile: bool = False
    # Pieces a cut makes along a state at most: the pieces still touching where the size was
    # needed are cut again when drawn, with what was learnt by then (a size needed at the
    # Mountain Car wall had cut a cell 64 times as wide into 128 pieces). 2 and 4 are compared in
    # bench/README.md ("Growth evidence pooled").
    grade: int = 4
    needed: list = field(default_factory=list, repr=False)  # (cell, widths needed there)
    probe: Optional[Callable] = field(default=None, repr=False)  # (cell, steps) -> {state: spread}, set by the campaign
    symbols: Optional[bool] = None
    # The Taylor order of the cells it runs reboxed where the call's is higher (None: learnt; class doc).
    rebox_order: Optional[int] = None
    # (Cell) -> evidence that its enclosure wrapped, or None: set by the campaign (Taylor method only)
    wrapping: Optional[Callable] = field(default=None, repr=False)
    examined: int = field(default=0, repr=False)  # lost plain cells whose float runs were compared with their enclosure
    symbol_runs: dict = field(default_factory=dict, repr=False)  # cell key -> deepest step of its plain run, while its retry is out
    symbols_paid: list = field(default_factory=list, repr=False)  # per retry with state symbols, in order: whether it paid
    runs: int = field(default=0, repr=False)
    # half's key -> (parent's steps, deepest step, stalls, state halved, the lineage's earlier halvings as (state, gained))
    lineage: dict = field(default_factory=dict, repr=False)
    retried: dict = field(default_factory=dict, repr=False)  # cell key -> (steps done, deepest step) of the plain run, its size
    tried: dict = field(default_factory=dict, repr=False)  # cell key -> steps its reboxed retry went deeper than the plain run
    paid: dict = field(default_factory=dict, repr=False)  # cell key -> whether that retry paid, once decided
    plain: dict = field(default_factory=dict, repr=False)  # size -> [verified, runs, given up at max_redone] of plain runs
    pending: set = field(default_factory=set, repr=False)  # keys of reboxed retries not yet run
    verified_retries: set = field(default_factory=set, repr=False)  # keys of reboxed retries that verified
    call_order: Optional[int] = field(default=None, repr=False)  # the call's Taylor order (set by pv.verify)
    low_out: set = field(default_factory=set, repr=False)  # keys of cells drawn to run reboxed at LOW_ORDER, until learnt
    low_verified: int = field(default=0, repr=False)  # reboxed runs at LOW_ORDER that verified
    call_verified: int = field(default=0, repr=False)  # reboxed runs at the call's order that verified
    reruns: dict = field(default_factory=dict, repr=False)  # key -> deepest step of its lost LOW_ORDER run, while its rerun is out
    rerun_better: list = field(default_factory=list, repr=False)  # per rerun at the call's order, in order: whether it did better
    deepened: set = field(default_factory=set, repr=False)  # keys of cells at min_width retried with DEEPEN times the in-cell splits
    stopped: dict = field(
        default_factory=dict, repr=False
    )  # key of a cell its stalled lineage gave up -> (cell, state split, steps, deepest)
    verified: list = field(default_factory=list, repr=False)  # (cell, halvings from the initial set) of every verified cell
    arrivals: list = field(default_factory=list, repr=False)  # (cell, step its runs all arrived) of every verified cell
    goal_retried: dict = field(default_factory=dict, repr=False)  # cell key -> (steps, deepest step, reboxed) before its split retry
    gains: dict = field(default_factory=dict, repr=False)  # state -> steps its halvings gained (latest last)
    plain_gains: dict = field(default_factory=dict, repr=False)  # state -> (parent's size, gain) of plain halves of plain runs
    # half's key -> (parent's deepest step, state halved, parent's size, whether that run was reboxed), until it runs
    halved: dict = field(default_factory=dict, repr=False)
    falsified: bool = field(default=False, repr=False)  # a counterexample decided the loop: no more halvings
    cut: dict = field(default_factory=dict, repr=False)  # key of a piece cut ahead of its run -> its cut's index in cuts
    cuts: list = field(default_factory=list, repr=False)  # every cut's _Cut, in order
    ended: dict = field(default_factory=dict, repr=False)  # placed bounds (_place) of a settled cell -> how it ended, for growth
    pairs: "_Boxes" = field(default_factory=lambda: _Boxes(3), repr=False)  # neighbours' union -> (state, width, ended alike)
    lost: "_Boxes" = field(default_factory=lambda: _Boxes(None), repr=False)  # cells lost or redoing steps -> their widths
    made: int = field(default=0, repr=False)  # cells made so far (initial, halves, cut pieces), held to max_cells
    near_gains: "_Boxes" = field(default_factory=lambda: _Boxes(2), repr=False)  # halves -> (state halved, steps gained)
    # half's key -> states its lineage halved without narrowing the enclosure (INERT), since its last gain
    inert: dict = field(default_factory=dict, repr=False)
    # half's key -> its parent's run's (options, steps done, box at that step, states that moved), until it runs
    enclosed: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        super().__post_init__()
        if not (isinstance(self.start, int) and self.start >= 1):
            raise InputError(f"Adaptive(start=...) must be a positive integer, got {self.start!r}")
        if not (isinstance(self.max_cells, int) and self.max_cells >= 1):
            raise InputError(f"Adaptive(max_cells=...) must be a positive integer, got {self.max_cells!r}")
        if not (isinstance(self.patience, int) and self.patience >= 1):
            raise InputError(f"Adaptive(patience=...) must be a positive integer, got {self.patience!r}")
        if not (isinstance(self.grade, int) and self.grade >= 2):
            raise InputError(f"Adaptive(grade=...) must be an integer of at least 2, got {self.grade!r}")
        if not (isinstance(self.window, int) and self.window >= 1):
            raise InputError(f"Adaptive(window=...) must be a positive integer, got {self.window!r}")
        for name in ("explore", "reach"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 0):
                raise InputError(f"Adaptive({name}=...) must be a non-negative integer, got {value!r}")
        if self.rebox_order is not None and not (
            isinstance(self.rebox_order, int) and not isinstance(self.rebox_order, bool) and self.rebox_order >= 1
        ):
            raise InputError(f"Adaptive(rebox_order=...) must be a positive integer or None, got {self.rebox_order!r}")

    def initial(self, init: Box):
        if self.rebox:
            raise InputError("Adaptive(rebox=True) is pv.verify(rebox=True): give that instead")
        if self.symbols:
            raise InputError("Adaptive(symbols=True) is pv.verify(state_symbols=True): give that instead")
        widest = [n for n, (lo, hi) in zip(init.names, init.bounds) if hi > lo][:6]
        cells, count = grid(init, {n: self.start for n in widest})
        self.made = count
        return ((cell, self._budget(cell, init)) for cell in cells), count

    def _min(self, init: Box) -> dict:
        return {n: self.min_width.get(n, (hi - lo) * FLOOR) for n, (lo, hi) in zip(init.names, init.bounds)}

    def prepare(self, cell: Box, init: Box) -> list:
        """``cell`` cut to the widths its settled neighbours needed (where they are narrower)."""
        shapes = _near(cell, self.needed, init) if self.tile else [w for box, w in self.needed if _touches(cell, box)]
        # One shape, the latest learnt: the narrowest widths of several shapes together make
        # cells smaller than any that was needed.
        target = self._grown(cell, shapes[-1]) if shapes else {}
        wanted, floor = {}, self._min(init)
        for n, (lo, hi) in zip(cell.names, cell.bounds):
            if target.get(n, 0.0) > 0.0 and hi - lo > 1.5 * target[n]:
                # Never below min_width: the floor the user set (or FLOOR of the initial set).
                most = 2 ** int(np.floor(np.log2((hi - lo) / floor[n]))) if floor[n] > 0 else 64
                # Widths made by the same halvings differ by float rounding: a ratio of 2.0000001 is 2 pieces, not 4.
                wanted[n] = min(int(2 ** np.ceil(np.log2((hi - lo) / target[n]) - 1e-6)), most)
        # At most `grade` pieces a state: those that still touch the cells that needed the size are
        # cut again when drawn, the others run at their size (the size needed where precision is
        # lost holds near there, not across a cell 64 times as wide).
        pieces = {n: min(k, self.grade) for n, k in wanted.items()}
        pieces = {n: k for n, k in pieces.items() if k > 1}
        # At most max_cells cells in all: a cut that would pass it is coarsened (the pieces are cut
        # again when drawn, while room is left), since a size needed at a fork can be tiny in every
        # state and its grid astronomically large.
        while pieces and self.made + int(np.prod(list(pieces.values()))) - 1 > self.max_cells:
            widest = max(pieces, key=pieces.get)
            pieces[widest] //= 2
            pieces = {n: k for n, k in pieces.items() if k > 1}
        if not pieces:
            return [cell]
        self.low_out.discard(_key(cell))  # its pieces run instead, with their own options
        cells, count = grid(cell, pieces)
        self.made += count - 1
        cells = list(cells)
        self.cuts.append(_Cut(cell, {n: (hi - lo) / pieces.get(n, 1) for n, (lo, hi) in zip(cell.names, cell.bounds)}))
        for piece in cells:
            self.cut[_key(piece)] = len(self.cuts) - 1
        return [(piece, self._options(piece, init)) for piece in cells]

    def learn(self, cell: Box, result, init: Box) -> None:
        self.runs += 1
        self.falsified |= result.verdict == "falsified"
        key = _key(cell)
        parent_reboxed = None
        if key in self.halved:
            deepest, state, size, reboxed = self.halved.pop(key)
            parent_reboxed = reboxed
            self.gains.setdefault(state, []).append(result.deepest_step - deepest)
            self.near_gains.add(cell, [cell.names.index(state), result.deepest_step - deepest])
            if not result.options.get("rebox") and not reboxed:
                self.plain_gains.setdefault(state, []).append((size, result.deepest_step - deepest))
        if not result.options.get("rebox") and result.verdict in ("verified", "unknown"):
            tally = self.plain.setdefault(round(_halvings(cell, init), 6), [0, 0, 0])
            if REDONE_PAST in (result.reason or ""):
                # A cell given up at its max_redone asks for halving, whatever rebox would do: it
                # counts apart (blur's cells near p0 -0.5 ran reboxed where it counted as lost).
                tally[2] += 1
            else:
                tally[0] += result.verdict == "verified"
                tally[1] += 1
        if result.verdict == "verified":
            self.verified.append((cell, _halvings(cell, init)))
            self.arrivals.append((cell, result.deepest_step))
        if key in self.symbol_runs and result.options.get("state_symbols"):
            plain = self.symbol_runs.pop(key)
            self.symbols_paid.append(result.verdict == "verified" or result.deepest_step - plain >= max(1, MIN_GAIN * plain))
        if result.options.get("rebox"):
            self._learn_order(key, result)
        if key in self.retried and result.options.get("rebox") and key in self.pending:
            self.pending.discard(key)
            # A retry that verified went as deep as its runs needed: that counts, not the verdict
            # (a plain halving might have verified too, for as little).
            self.tried[key] = result.deepest_step - self.retried[key][1]
            if result.verdict == "verified":
                self.verified_retries.add(key)
        if result.verdict in ("verified", "unknown"):
            self._compare(cell, result, init)
        if result.verdict == "verified" and (result.branches or key in self.lineage) and not self._stalled(key):
            # Only splits that computed steps again say the cell was too big: halves cut ahead
            # would have verified without that work. A cell that forked, or split where a piece
            # was lost (on a condition that crosses it at every size), cost little more than its
            # run, and keeps its size (a cut piece: its cut's shape, as grown from its pieces).
            halve = _redid(result)
            size = cell
            for _ in range(_redone_runs(result) if halve else 0):
                size = bisect(size, init, self._min(init), result.split or self._gaining_state())[0]
            widths = {n: hi - lo for n, (lo, hi) in zip(size.names, size.bounds)}
            if key in self.cut and not halve:
                widths = dict(self.cuts[self.cut[key]].widths)
            if key in self.lineage and not halve:
                if result.options.get("rebox") and (key in self.retried or parent_reboxed is False):
                    return  # verified only reboxed: no size (class doc)
                _, _, _, state, path = self.lineage[key]
                widths = _undo_stalled(widths, (*path, (state, True)))
            self.needed.append((cell, widths))
            if halve and key in self.cut:
                # The whole cut was cut to one shape: its pieces not yet run are cut to the half's
                # (else only those touching this piece are, and the next ones along redo the same).
                c = self.cuts[self.cut[key]]
                c.widths = {n: widths[n] if widths[n] < 0.75 * w else w for n, w in c.widths.items()}  # the states halved
                self.needed.append((c.cell, dict(c.widths)))

    def _compare(self, cell: Box, result, init: Box) -> None:
        """Compares how a settled cell ended with its settled neighbours of the same shape (one face
        shared) along each state: the pairs are the evidence :meth:`_grown` reads. A cell lost, or
        one that computed steps again (its width mattered), ends like no other and is kept in
        ``lost`` with its widths."""
        key = _key(cell)
        reboxed = bool(result.options.get("rebox"))
        outcome = (result.deepest_step, result.branches, reboxed) if result.verdict == "verified" and not _redid(result) else None
        if outcome is None:
            self.lost.add(cell, [hi - lo for lo, hi in cell.bounds])
        self.ended[self._place(key, init)] = outcome
        for j, (lo, hi) in enumerate(key):
            if not hi > lo:
                continue
            for face in ((2 * lo - hi, lo), (hi, 2 * hi - lo)):
                other = self.ended.get(self._place((*key[:j], face, *key[j + 1 :]), init), False)
                if other is False:
                    continue
                alike = outcome is not None and other is not None and (other == outcome or other[1:] == outcome[1:] == (0, reboxed))
                pair = Box(cell.names, tuple(key[:j]) + ((min(lo, face[0]), max(hi, face[1])),) + tuple(key[j + 1 :]))
                self.pairs.add(pair, [j, hi - lo, alike])
        if _key(cell) in self.cut:
            # The cut's shape grown where its pieces say so spreads as a needed one would (to
            # cells beside the cut that no needed shape touches).
            c = self.cuts[self.cut[_key(cell)]]
            grown = self._grown(c.cell, c.widths)
            if grown != c.widths and grown != c.grown:
                c.grown = grown
                self.needed.append((c.cell, grown))

    def _place(self, bounds: tuple, init: Box) -> tuple:
        """Bounds as whole units of 1/64 of ``min_width`` from the initial set's lower corner: the
        bounds of neighbours made by different cuts meet only up to their last bits, which are
        far coarser than decimals where a state sits far from zero (at 1e6, a cut and a halving
        of a 1e-3 wide set put one face 1e-10 apart), and rounded decimals would make cells of a
        set narrower than them all one."""
        floor = self._min(init)
        return tuple(
            (round((lo - ilo) * 64 / floor[n]), round((hi - ilo) * 64 / floor[n])) if floor[n] > 0 else (lo, hi)
            for n, (lo, hi), (ilo, _) in zip(init.names, bounds, init.bounds)
        )

    def _grown(self, cell: Box, target: dict) -> dict:
        """``target`` (a shape needed near ``cell``) doubled in each state, again and again, while
        the settled neighbour pairs of its width along that state near ``cell`` (within ``grade``
        widths of the shape) ended alike: at least ``GROW_PAIRS`` of them, and ``GROW_RATIO`` times
        as many as ended differently or were lost there no wider than the grown shape in any
        state (that size failed there already: a halving's two verified halves, alike, do not grow
        back into their lost parent); such a cell touching ``cell`` is enough to keep the width."""
        # The pairs within a cut's reach (`grade` pieces of the shape on each side): those touching
        # a cell at the Mountain Car wall are two or three, its neighbourhood holds dozens.
        reach = Box(
            cell.names,
            tuple(
                (lo - self.grade * target.get(n, 0.0), hi + self.grade * target.get(n, 0.0)) for n, (lo, hi) in zip(cell.names, cell.bounds)
            ),
        )
        pairs = self.pairs.touching(reach)
        if not len(pairs):
            return target
        lost = np.flatnonzero(self.lost.mask(reach)) if len(self.lost) else np.empty(0, dtype=int)
        out = dict(target)
        for j, (n, (lo, hi)) in enumerate(zip(cell.names, cell.bounds)):
            while out.get(n, 0.0) > 0.0 and hi - lo > 1.5 * out[n]:
                votes = pairs[(pairs[:, 0] == j) & np.isclose(pairs[:, 1], out[n], rtol=1e-6, atol=0.0), 2]
                grown = {**out, n: 2 * out[n]}
                shape = np.array([grown.get(m, np.inf) for m in cell.names]) * (1 + 1e-6)
                failed = lost[np.all(self.lost.values[lost] <= shape, axis=1)] if len(lost) else lost
                alike = int(votes.sum())
                if (
                    alike < GROW_PAIRS
                    or alike < GROW_RATIO * (len(votes) - alike + len(failed))
                    or (len(failed) and self.lost.mask(cell, failed).any())
                ):
                    break
                out = grown
        return out

    def again(self, cell: Box, result, init: Box, timed_out: bool):
        """A :class:`Retry` (with rebox, or with the call's in-cell splits), halves (with their
        options), or None (see the class doc)."""
        key = _key(cell)
        if result.verdict != "unknown" or self.runs >= self.max_cells or self.falsified:
            self.lineage.pop(key, None)
            self.inert.pop(key, None)
            self.enclosed.pop(key, None)
            return None
        if self._rerun_due(result, timed_out):
            # Before anything is learnt from the loss: the call's order may verify it.
            self.reruns[key] = result.deepest_step
            if key in self.retried:  # the retry is judged by its run at the call's order
                self.tried.pop(key, None)
                self.paid.pop(key, None)
                self.pending.add(key)
            return Retry({"rebox": True, "order": None})
        size = _halvings(cell, init)
        halved, before = self.lineage.get(key, (None,) * 4)[3], self.enclosed.get(key)
        if halved is not None and before is not None and _as_wide(before, result):
            # Whichever of the cell's runs has its parent's options (a retry runs with others).
            self.inert[key] = self.inert.get(key, frozenset()) | {halved}
        if not timed_out and self._symbols_pay(key, result):
            self.symbol_runs[key] = result.deepest_step
            return Retry({"state_symbols": True})
        if self._rebox_pays(cell, result, init):
            self.retried[key] = (result.steps_done, result.deepest_step, size)
            self.pending.add(key)
            return Retry(self._reboxed(key))
        # Ran with the small budget: the call's is left to try.
        explored = "max_splits" in result.options and key not in self.deepened
        capped = explored or "max_redone" in result.options
        widths = self._min(init)
        if not splittable(cell, init, widths, 0):
            retry = self._last_tries(key, result, size, capped)
            if retry is None and result.branches > 0 and key not in self.deepened:
                # In-cell splits are the halvings left to it: DEEPEN times the ones it used up
                # (a cell of 1/4096 of F1/10's row needs 19 of them, where the call gives 16).
                self.deepened.add(key)
                return Retry({"max_splits": DEEPEN * result.branches})
            return retry
        options = dict(result.options)
        steps, deepest_step, reboxed = result.steps_done, result.deepest_step, bool(options.pop("rebox", False))
        # The halves run as decided at their size (``_options``); the cell's plain run, where it had
        # one, compares with plain halves.
        rebox = self._reboxing(size + 1, init)
        if reboxed and not rebox and key in self.retried:
            steps, deepest_step, _ = self.retried[key]
            reboxed = False
        if key in self.goal_retried:
            # The halves run with the small budget: compared with the run that had it.
            steps, deepest_step, reboxed = self.goal_retried.pop(key)
        reached, deepest, stalls, halved, path = self.lineage.pop(key, (-1, -1, 0, None, ()))
        stalls = stalls + 1 if steps <= reached and deepest_step <= deepest else 0
        # Moved the loss of precision by a fair share of the steps reached (see MIN_GAIN).
        gained = steps - reached >= max(1, MIN_GAIN * reached) or deepest_step - deepest >= max(1, MIN_GAIN * deepest)
        # A halving that gained steps starts afresh: at the new size another state may decide.
        inert = frozenset() if gained else self.inert.get(key, frozenset())
        if explored and halved is not None and not gained and GOAL_PART in (result.reason or "") and self._late(cell, deepest_step, init):
            # Runs from parts of the cell arrive at different steps, and halving did not move
            # that: the engine's in-cell forks separate the arrivals for a few runs' cost.
            self.lineage[key] = (reached, deepest, stalls, halved, path)
            self.goal_retried[key] = (steps, deepest_step, reboxed)
            return Retry({"max_splits": None, "order": None, **(self._reboxed(key) if reboxed else {"rebox": None})})
        if stalls >= self.patience * sum(above_min_width(init, init, widths, 0)) and not self._as_small_verified(cell, init):
            retry = self._last_tries(key, result, size, capped)
            if retry is not None:
                self.lineage[key] = (reached, deepest, stalls - 1, halved, path)  # the retry stops the lineage unless it goes deeper
            else:
                self.stopped[key] = (cell, result.split, steps, deepest_step)
            return retry
        if halved is not None:
            path = (*path, (halved, gained))
        j = None if result.split is None else cell.names.index(result.split)
        heavy = REDONE_PAST in (result.reason or "") or result.steps_redone >= REDONE * max(1, result.deepest_step)
        if heavy and j is not None and above_min_width(cell, init, widths, 0)[j] and (gained or halved != result.split):
            # The engine's splits along it restarted, computing REDONE runs' steps again, and the
            # cell was still lost: halved along it (blur cells near p0 -0.55 halved along the
            # noise, each losing 16 splits that restarted from step 0, while the engine split p0).
            # Splits where part of the cell arrived redo a few steps each: a big cell's 16 of
            # them, a run's steps, say nothing of the state to halve.
            state = result.split
        else:
            state = self._state_to_halve(cell, result, init, widths, stalls, halved, gained, inert)
        for decided in ("max_splits", "max_redone", "state_symbols", "order"):  # the halves' are their own (_options)
            options.pop(decided, None)
        halves = _halves(cell, cell.names.index(state))
        self.made += len(halves) - 1
        enclosure = _enclosure(cell, result)
        self.inert.pop(key, None)
        self.enclosed.pop(key, None)
        for half in halves:
            self.inert[_key(half)] = inert
            if enclosure is not None:
                self.enclosed[_key(half)] = enclosure
            if reboxed == rebox:
                self.lineage[_key(half)] = (steps, deepest_step, stalls, state, path)
                self.halved[_key(half)] = (deepest_step, state, size, reboxed)
            else:  # no run of the cell made as the halves run: their lineage compares afresh
                self.lineage[_key(half)] = (-1, -1, stalls, state, path)
        return [(half, {**options, **self._options(half, init)}) for half in halves]

    def revisit(self, init: Box) -> list:
        """``[(cell, pieces)]``, once every cell drawn is settled: the cells a stalled lineage gave
        up beside a cell that has since verified at their size or smaller, halved again (a new
        lineage), as :meth:`again` would have done had that cell verified first. Outcomes are
        learnt in draw order, and F1/10's row had given up a cell of 1/128 of it whose neighbours
        of 1/256, drawn after it, all verified."""
        if self.falsified or self.runs >= self.max_cells:
            return []
        out = []
        for key, (cell, split, steps, deepest_step) in list(self.stopped.items()):
            widths = self._min(init)
            if not (splittable(cell, init, widths, 0) and self._as_small_verified(cell, init)):
                continue
            del self.stopped[key]
            above = above_min_width(cell, init, widths, 0)
            state = split if split in cell.names and above[cell.names.index(split)] else cell.names[above.index(True)]
            halves = _halves(cell, cell.names.index(state))
            self.made += len(halves) - 1
            # Stalled already: halves that gain nothing stop at once, unless still beside a cell
            # verified at their size or smaller (no fresh patience, which could cost a binary tree
            # of patience x states halvings under every cell taken back).
            stalls = self.patience * sum(above_min_width(init, init, widths, 0))
            for half in halves:
                self.lineage[_key(half)] = (steps, deepest_step, stalls, state, ())
            out.append((cell, [(half, self._options(half, init)) for half in halves]))
        return out

    def _last_tries(self, key: tuple, result, size: float, capped: bool) -> Optional[Retry]:
        """Before a cell is given up (at ``min_width``, or its lineage stalled): a run with the
        call's in-cell budget if it had a smaller one, then one reboxed if it never ran so (F1/10's
        row left five cells at min_width unknown, plain, after the rebox trials near their size had
        stopped; a lineage of plain cells can stall where one reboxed run verifies, when the
        retries that would have taught rebox ran on the other thread)."""
        if capped:
            return Retry({"max_splits": None, "max_redone": None})
        if self.rebox is not False and not result.options.get("rebox") and key not in self.retried:
            self.retried[key] = (result.steps_done, result.deepest_step, size)
            self.pending.add(key)
            return Retry(self._reboxed(key))
        return None

    def _state_to_halve(
        self, cell: Box, result, init: Box, widths: dict, stalls: int, halved: Optional[str], gained: bool, inert: frozenset
    ) -> str:
        """The state whose halvings of cells touching ``cell`` have gained the most steps lately
        (each state above its min_width tried first, and again when not halved lately, in the order of the probe's,
        else the engine's, choice), another one than ``halved`` when that halving did not gain
        (``MIN_GAIN``), none of the lineage's ``inert`` states while another is left; with
        ``learn_states=False`` that choice, and after a halving that gained no step the widest
        other state relative to the initial set."""
        above = above_min_width(cell, init, widths, 0)
        candidates = [n for ok, n in zip(above, cell.names) if ok]
        if any(n not in inert for n in candidates):
            candidates = [n for n in candidates if n not in inert]
        if halved is not None and not gained and self.learn_states and any(n != halved for n in candidates):
            # The halving that made this cell gained (almost) nothing: its state is not what
            # loses the cell at this size, whatever it gained elsewhere (at other sizes).
            candidates = [n for n in candidates if n != halved]
        if stalls and not self.learn_states:
            others = [
                ((hi - lo) / (ihi - ilo), n)
                for n, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds)
                if n in candidates and n != halved
            ]
            if others:
                return max(others)[1]
        hint = result.split if result.split in candidates else None
        if self.probe is not None:
            moves = self.probe(cell, result.deepest_step)
            hint = max(((moves.get(n, 0.0), n) for n in candidates), default=(0.0, hint))[1]
        if hint is None:
            rel = [((hi - lo) / (ihi - ilo), n) for n, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds) if n in candidates]
            hint = max(rel)[1]
        if not self.learn_states:
            return hint
        # Untried, or not tried lately: a state whose halving gained nothing near the whole set
        # may be the one that decides once the others are narrow.
        rows = self.near_gains.touching(cell)
        gains = {n: [g for j, g in rows if cell.names[int(j)] == n] for n in candidates}
        lately = {cell.names[int(j)] for j, _ in rows[-RECENT * len(candidates) :]}
        untried = [n for n in candidates if not gains[n] or n not in lately]
        if untried:
            return hint if hint in untried else untried[0]
        return max(candidates, key=lambda n: (np.mean(gains[n][-RECENT:]), n == hint))

    def _late(self, cell: Box, step: int, init: Box) -> bool:
        """Whether a cell lost at ``step`` got within ``MIN_GAIN`` of the step where the runs of the
        verified cells near it all arrived (or none has verified yet)."""
        near = _near(cell, self.arrivals, init)
        return not near or step >= (1 - MIN_GAIN) * max(near)

    def _as_small_verified(self, cell: Box, init: Box) -> bool:
        """Whether a cell it touches verified at its size or smaller: there halving reached a
        verdict, so a lineage whose halvings gained no step goes on to one halving below that size
        (on F1/10's row the knock-outs are lost near the last step at every size down to the one
        where a cell verifies at once, and a cell of 1/64 of the row stopped there, between cells
        of 1/256 that verified)."""
        return any(h >= _halvings(cell, init) - 1e-6 for box, h in self.verified if _touches(cell, box))

    def _stalled(self, key: tuple) -> bool:
        """Whether the cell ``key`` comes from ``STALLED`` halvings in a row that gained nothing
        (``MIN_GAIN``) before the one that made it."""
        path = self.lineage[key][4] if key in self.lineage else ()
        return len(path) >= STALLED and not any(gained for _, gained in path[-STALLED:])

    def _gaining_state(self) -> Optional[str]:
        """The state whose recent halvings gained the most steps (None before any halving)."""
        return max(self.gains, key=lambda n: np.mean(self.gains[n][-RECENT:]), default=None)

    def _options(self, cell: Box, init: Box) -> dict:
        """A new cell's engine options: its in-cell budget, rebox once retries of cells near its
        size have paid more often than not (a plain run first would only be lost), and state
        symbols once their retries have."""
        rebox = self._reboxed(_key(cell)) if self._reboxing(_halvings(cell, init), init) else {}
        return {**self._budget(cell, init), **rebox, **({"state_symbols": True} if self._symbolic() else {})}

    def _symbolic(self) -> bool:
        """Whether new cells run with state symbols: more retries with them paid than not (those
        still out count as not)."""
        wins = sum(self.symbols_paid)
        return self.symbols is not False and wins > len(self.symbols_paid) - wins + len(self.symbol_runs)

    def _symbols_pay(self, key: tuple, result) -> bool:
        """Whether the unknown cell runs again with state symbols: once they pay, every cell that
        ran without (drawn before they did); until then a cell whose enclosure wrapped (the
        campaign's float runs, of the first ``EXAMINED`` cells lost), while the retries (those out
        counted as lost) have not lost ``patience`` times more often than paid."""
        if self.symbols is False or self.wrapping is None or result.options.get("state_symbols") or result.options.get("rebox"):
            return False
        if self._symbolic():
            return True
        # Retries still out count as lost: cells run side by side must not all be retried before
        # the first retry has shown whether they pay (F1/10's row made 7 retries, none paid).
        wins = sum(self.symbols_paid)
        if len(self.symbols_paid) - 2 * wins + len(self.symbol_runs) >= self.patience or self.examined >= EXAMINED or not result.boxes:
            return False
        self.examined += 1
        return self.wrapping(result) is not None

    def _budget(self, cell: Box, init: Box) -> dict:
        """The in-cell splits of a cell about to run: the call's when a verified cell near it (one
        it touches, else the nearest) is at most ``reach`` halvings smaller (with ``REDONE`` runs'
        steps for those that restart), else ``explore`` (a cell far too big fails fast and is
        halved, instead of splitting inside many times)."""
        near = _near(cell, self.verified, init)
        if not (near and max(near) - _halvings(cell, init) <= self.reach):
            return {"max_splits": self.explore}
        # Splits that restart from an earlier step cost most of a run each: past REDONE runs'
        # steps the cell is given up and cut along the split state instead, except at min_width,
        # where in-cell splits are the halvings left.
        return {"max_redone": REDONE} if splittable(cell, init, self._min(init), 0) else {}

    def rebox_score(self, init: Box, size: Optional[float] = None) -> tuple:
        """Reboxed retries that paid, and not (see the class doc); with ``size``, those of cells
        within ``REBOX_SIZES`` halvings of it."""
        keys = [key for key in self.tried if size is None or _near_size(self.retried[key][2], size)]
        wins = sum(self._rebox_won(key, init) for key in keys)
        return wins, len(keys) - wins

    def _reboxed(self, key: tuple) -> dict:
        """The engine options of the reboxed run of cell ``key``: rebox, at ``rebox_order`` where
        the call's order is higher, or (``rebox_order=None``) at ``LOW_ORDER`` while that pays."""
        order = self.rebox_order if self.rebox_order is not None else LOW_ORDER if self._low_order() else None
        if order is None or self.call_order is None or order >= self.call_order:
            return {"rebox": True}
        if self.rebox_order is None:
            self.low_out.add(key)
        return {"rebox": True, "order": order}

    def _low_order(self) -> bool:
        """Whether reboxed runs start at ``LOW_ORDER``: once a reboxed run at the call's order has
        verified (where none does, a cheaper order would only add runs: on Mountain Car's blur row,
        runs at order 3 went as deep, and the reruns that followed them reordered what was learnt
        when, making 637 cells instead of 285), while its runs that verified, ``LOW_ODDS`` times
        over, are not ``patience`` fewer than the reruns at the call's order that did better after
        one of them was lost (reruns and runs at ``LOW_ORDER`` still out count as such)."""
        better = sum(self.rerun_better) + len(self.reruns) + len(self.low_out)
        return self.rebox_order is None and self.call_verified > 0 and better - LOW_ODDS * self.low_verified < self.patience

    def _rerun_due(self, result, timed_out: bool) -> bool:
        """Whether a reboxed run at ``LOW_ORDER`` that was lost runs again at the call's order:
        until runs at ``LOW_ORDER`` have verified ``patience`` times more often than reruns did
        better (a loop whose reboxed cells need the call's order would else halve them at the low
        one for ever)."""
        if timed_out or self.rebox_order is not None or not result.options.get("rebox") or result.options.get("order") != LOW_ORDER:
            return False
        return self.low_verified < sum(self.rerun_better) + self.patience

    def _learn_order(self, key: tuple, result) -> None:
        """Tallies a reboxed run for :meth:`_low_order`: one at ``LOW_ORDER`` (verified or not),
        or the rerun of one that was lost (better if it verified, or got ``MIN_GAIN`` of the lost
        run's steps deeper)."""
        if result.options.get("order") == LOW_ORDER and key in self.low_out:
            self.low_out.discard(key)
            self.low_verified += result.verdict == "verified"
        elif "order" not in result.options:
            self.call_verified += result.verdict == "verified"
            if key in self.reruns:
                low = self.reruns.pop(key)
                self.rerun_better.append(result.verdict == "verified" or result.deepest_step - low >= max(1, MIN_GAIN * low))

    def _rebox_won(self, key: tuple, init: Box) -> bool:
        """Whether the reboxed retry of cell ``key`` paid against halving plain cells of its size
        (within ``REBOX_SIZES`` halvings): more steps deeper than ``REBOX_COST`` times what plain
        halvings of such a size gained. Decided once every state the initial set is wide in has
        been halved plain at such a size (until then: lost), and then kept: halvings of smaller
        cells gain fewer steps, which says nothing about the retry's size. A retry that verified
        is decided once one state has been (a splitter that learns which state to halve leaves
        the others unhalved for many sizes: docking's four states), and must also have gained
        ``MIN_GAIN`` of the plain run's steps (a halving that gains nothing must not make a retry
        that gains as little win). Unverified retries wait for every state: on Mountain Car's
        blur row, retries that went deeper but never verified won on one state's halvings and
        made 1.7x the cells."""
        if key not in self.paid:
            gain, (_, deepest, size) = self.tried[key], self.retried[key]
            states = [n for ok, n in zip(above_min_width(init, init, self._min(init), 0), init.names) if ok]
            near = [gains for n in states if (gains := [g for s, g in self.plain_gains.get(n, []) if _near_size(s, size)])]
            every = len(near) == len(states) > 0
            if not (every or (near and key in self.verified_retries)):
                return False
            beats = gain > REBOX_COST * max(np.mean(g[-RECENT:]) for g in near)
            self.paid[key] = beats and (every or gain >= max(1, MIN_GAIN * deepest))
        return self.paid[key]

    def _reboxing(self, size: float, init: Box) -> bool:
        """Whether cells of ``size`` run reboxed: retries near it paid more often than not, and
        plain cells of that very size (within half a halving) were lost more often than not (none
        run yet: the next runs plain, a trial). Plain cells given up at their ``max_redone`` count
        only where no other plain cell of the size ran: ``REBOX_TRIALS`` of them are then lost
        trials (else every cell of a lineage whose plain runs are all given up so is a trial, and
        its halves are new sizes with trials of their own)."""
        wins, losses = self.rebox_score(init, size)
        if self.rebox is False or wins <= losses:
            return False
        tallies = [tally for s, tally in self.plain.items() if abs(s - size) < 0.5]
        verified, runs, given_up = np.sum(tallies or [[0, 0, 0]], axis=0)
        return (runs > 0 and 2 * verified < runs) or (runs == 0 and given_up >= REBOX_TRIALS)

    def _rebox_pays(self, cell: Box, result, init: Box) -> bool:
        key, size = _key(cell), _halvings(cell, init)
        if self.rebox is False or result.options.get("rebox") or key in self.retried:
            return False
        if self._reboxing(size, init):
            return True  # a plain cell drawn before the retries near its size paid
        wins, losses = self.rebox_score(init, size)
        lost = any(words in (result.reason or "") for words in PRECISION_LOST)
        # Retries still running count as lost until they end: cells that run side by side must
        # not all be retried before the first retry has shown whether it pays.
        losses += sum(_near_size(self.retried[k][2], size) for k in self.pending)
        return wins + losses < REBOX_TRIALS or (lost and losses - wins < self.patience)


# Reasons (the engine's words) after which a cell is retried with rebox: an operation left its
# domain (taylor's Domain error: division, sqrt, log) or an enclosure blew up.
PRECISION_LOST = (" is undefined on ", " blew up ")
# The engine's reason when runs from parts of a cell arrive at the goal at different steps.
GOAL_PART = " holds on part of the set only since step "
# In the reason of a cell the call's time limit stopped or left out (the campaign's words).
TIME_LIMIT = "time_limit="
# The engine's words when a cell gives up before a split that would pass its max_redone.
REDONE_PAST = "past max_redone"
# Halvings in a row that gained nothing before a cell verified, after which its size is an
# accident of the path and is not learnt as needed.
STALLED = 2


# The default min_width of pv.Adaptive, per state relative to the initial set: halving stops where
# it stops gaining (patience) or at max_cells long before this on most loops; F1/10's whole row
# (y1 0.2 wide) needs cells of 1/4096 of it where knock-outs fork, and at 1/1024 it left 19 cells
# unknown (3.7% of the row).
FLOOR = 1 / 8192
DEEPEN = 4  # a cell at min_width lost after in-cell splits runs once more with this many times as many
REBOX_TRIALS = 2  # unknown cells retried with rebox whatever the reason, per size, to find out whether it pays
# Halvings apart within which a retry's outcome decides for other cells, and plain halvings' gains compare
# with it: on Mountain Car the whole set's retry goes twice as deep, while cells eight halvings smaller
# verify plain.
REBOX_SIZES = 2
# The Taylor order reboxed runs start at where the call's is higher (rebox_order=None): models that
# restart from a box carry a variable per state, and order 5 in four variables has 3.6 times the
# monomials of order 3 (docking's reboxed cells verify as often at order 3, at a fifth to a tenth of
# the seconds); a lost run at it costs about a third of one at order 5.
LOW_ORDER = 3
# Reruns at the call's order that did better which one verified run at LOW_ORDER outweighs: it
# saves about two thirds of a run, a lost one costs a third.
LOW_ODDS = 2
REBOX_COST = 2  # plain steps a reboxed step costs, about (Mountain Car: 1.75 at its verified cell size)
RECENT = 4  # halvings of a state whose gains choose the next state to halve
# A halving gained if it moved the loss of precision later by at least this share of the steps its
# parent reached (and a step): at less, going as far again would take six more halvings (64 times
# the cells) of that state, so the lineage halves another one, and the size a verified half needed
# does not count it (1/8: Mountain Car's halvings near the size needed gain 1-5% and far above it
# 25-95%).
MIN_GAIN = 1 / 8


# The share of its parent's enclosure width (mean over the states that moved) at or above which a
# half's run says the state halved did not matter at that size: its lineage halves the others
# (a state adding a tenth of the width narrows it by a twentieth when halved).
INERT = 0.95


# Neighbour pairs along a state that must end alike (verified at the same step with as many
# in-cell splits, or both with none) before cells twice as wide in it are tried there, and how many
# times the pairs that ended differently: cells whose runs do not depend on a state's width end
# alike, others differ by a step or more. Counted over every settled cell near the one cut, not
# per cut: at the Mountain Car wall, cuts of two pieces along p0 never held three pairs along dc,
# and 400 of 428 pairs there ended alike while dc stayed at a quarter of the hand's width.
GROW_PAIRS = 3
GROW_RATIO = 4

# Runs' steps a cell near the size needed may compute again in splits that restart (the engine's
# ``max_redone``): with them it costs as much as four cells. Composite Mountain Car cells lost
# after 16 such splits cost 15 runs (30 s) each.
REDONE = 3

# The share of a run's steps (its deepest step) a verified cell computed again in splits that
# restart past which it says cells must be smaller there. Such a split costs the steps before it
# and a run for its second piece (1 + r runs for r runs' steps redone), halving a run for every
# cell, split or not: how many of the cells around split decides, and one cell does not tell.
# Of the shares measured (bench/README.md, "A cell that redid less than half a run"), 1/2 alone
# cost no row more than the earlier 1/8.
REDID = 1 / 2


@dataclass
class _Cut:
    """A cell cut ahead of its run into pieces of ``widths`` (narrowed where a piece redid steps),
    and the shape its pieces' outcomes grew it to last (see :meth:`Adaptive._grown`)."""

    cell: Box
    widths: dict
    grown: Optional[dict] = None


class _Boxes:
    """Boxes with a row of values each, in arrays: which touch a cell is asked at every cut, over
    thousands of them (``width=None``: the values are the box's own widths, one per state)."""

    def __init__(self, width: Optional[int]):
        self.width, self.n = width, 0
        self.lo = self.hi = self.values = None

    def add(self, box: Box, values: list) -> None:
        if self.lo is None:
            self.lo, self.hi, self.values = np.empty((64, len(box.bounds))), np.empty((64, len(box.bounds))), np.empty((64, len(values)))
        elif self.n == len(self.lo):
            self.lo, self.hi, self.values = (np.concatenate([a, np.empty_like(a)]) for a in (self.lo, self.hi, self.values))
        self.lo[self.n], self.hi[self.n] = zip(*box.bounds)
        self.values[self.n] = values
        self.n += 1

    def __len__(self) -> int:
        return self.n

    def touching(self, cell: Box) -> np.ndarray:
        """The values of the boxes that touch ``cell`` (a shared face counts)."""
        return self.values[: self.n][self.mask(cell)] if self.n else np.empty((0, self.width or len(cell.bounds)))

    def mask(self, cell: Box, rows: Optional[np.ndarray] = None) -> np.ndarray:
        """Which boxes (of ``rows``, else all) touch ``cell``."""
        rows = np.arange(self.n) if rows is None else rows
        lo, hi = np.array(cell.bounds).T
        return np.all(
            (self.lo[rows] <= hi + SLACK * np.spacing(np.abs(hi))) & (lo <= self.hi[rows] + SLACK * np.spacing(np.abs(self.hi[rows]))),
            axis=1,
        )


def _enclosure(cell: Box, result) -> Optional[tuple]:
    """A lost run's reach box at the last step every part of it completed, with its options and
    the states that moved by then (not those that kept the cell's bounds, such as a noise level):
    what its halves' runs compare with (:func:`_as_wide`)."""
    t = result.steps_done
    box = result.boxes[t] if 0 < t < len(result.boxes) else None
    if not box:
        return None
    moved = [
        j
        for j, ((lo, hi), (clo, chi)) in enumerate(zip(box, cell.bounds))
        if hi > lo and not (math.isclose(lo, clo, rel_tol=1e-9, abs_tol=1e-12) and math.isclose(hi, chi, rel_tol=1e-9, abs_tol=1e-12))
    ]
    return (dict(result.options), t, [tuple(b) for b in box], moved) if moved else None


def _as_wide(before: tuple, result) -> bool:
    """Whether a half's run (with the options of its parent's) enclosed the moved states at
    the step its parent last completed as wide as the parent did, within ``INERT``: the state
    halved adds almost nothing to the enclosure there (on Mountain Car's contrast row near the
    goal, plain runs: halving dc 0.106 -> 0.053 left the enclosure 1.01 times as wide at step 80,
    where the parent was lost, and halving p0 0.024 -> 0.012 made it 0.81 times as wide; in cells
    16 times that size, halving dc made it 0.22 times as wide)."""
    options, t, box, moved = before
    if dict(result.options) != options or result.steps_done < t or t >= len(result.boxes) or not result.boxes[t]:
        return False
    now = result.boxes[t]
    ratios = [(now[j][1] - now[j][0]) / (box[j][1] - box[j][0]) for j in moved]
    return float(np.mean(ratios)) >= INERT


def _redid(result) -> bool:
    """Whether the run computed steps again after splitting a lost piece at an earlier step, for
    at least ``REDID`` of the steps it reached: its width mattered, and cut along the split state
    ahead of the run, cells like it would cost less."""
    return result.steps_redone >= max(1, REDID * result.deepest_step)


def _redone_runs(result) -> int:
    """The halvings a cell that redid steps says were needed: log2 of the runs its steps made
    (floored, at least one). A composite Mountain Car cell that verified after 15 splits that
    restarted from step 0 made 14 runs' steps, as 16 cells would have; taught one halving, its
    neighbours redid as much."""
    return max(1, int(np.floor(np.log2(1 + result.steps_redone / max(1, result.deepest_step)))))


def _undo_stalled(widths: dict, path: tuple) -> dict:
    """The widths of a verified cell with the halvings that did not gain (``MIN_GAIN``) just before
    the one that verified it (``path``'s last) undone, except those of that halving's state: the cell
    verified through that halving, and neighbours cut to the accidental size would cost cells for
    nothing. Earlier stalls stay (the loss of precision they did not move was another one)."""
    out, final = dict(widths), path[-1][0]
    for state, gained in reversed(path[:-1]):
        if gained:
            break
        if state != final:
            out[state] *= 2
    return out


def _near_size(a: float, b: float) -> bool:
    """Whether two cells' sizes (``_halvings``) are within ``REBOX_SIZES`` halvings (widths made by
    halvings differ from the exact ones in their last bits)."""
    return abs(a - b) <= REBOX_SIZES + 1e-6


def _halvings(cell: Box, init: Box) -> float:
    """How many halvings of the initial set make the cell (log2 of the volume ratio, over the states the initial set is wide in)."""
    return float(sum(np.log2((ihi - ilo) / (hi - lo)) for (lo, hi), (ilo, ihi) in zip(cell.bounds, init.bounds) if ihi > ilo and hi > lo))


def _near(cell: Box, entries: list, init: Box) -> list:
    """The values of the ``(box, value)`` entries whose boxes touch ``cell``, else of the nearest ones."""
    touching = [value for box, value in entries if _touches(cell, box)]
    if touching or not entries:
        return touching
    gaps = [(_gap(cell, box, init), value) for box, value in entries]
    nearest = min(g for g, _ in gaps)
    return [value for g, value in gaps if g == nearest]


def _gap(a: Box, b: Box, init: Box) -> float:
    """The distance between two boxes, per state relative to the initial set's width (0: they touch)."""
    return float(
        sum(
            max(0.0, blo - ahi, alo - bhi) / (ihi - ilo)
            for (alo, ahi), (blo, bhi), (ilo, ihi) in zip(a.bounds, b.bounds, init.bounds)
            if ihi > ilo
        )
    )


def _key(box: Box) -> tuple:
    return tuple(box.bounds)


def _touches(a: Box, b: Box) -> bool:
    """Whether the closed boxes intersect (a shared face counts: neighbours, also where the face
    made by one cut and by another differs in its last bits, by up to ``SLACK`` units)."""
    return all(
        alo <= bhi + SLACK * math.ulp(bhi) and blo <= ahi + SLACK * math.ulp(ahi) for (alo, ahi), (blo, bhi) in zip(a.bounds, b.bounds)
    )


# Units in the last place by which one face, computed by two cuts (or halvings), may differ (a
# cut's and a halving's at 1e6 were one apart); cells are far wider than this.
SLACK = 64
