"""A campaign: the cells of a part as they flow from the grid through the journal, the probe, the
engine (a local pool of threads, or an executor) and falsification to their verdicts."""

from __future__ import annotations

import functools
import os
import sys
import threading
import time
from collections import deque
from dataclasses import replace
from typing import Optional

from percver import _core
from percver.errors import InputError
from percver.sets import Box
from percver.verification.falsify import falsify, spread
from percver.verification.journal import cell_key
from percver.verification.results import Cell, Counterexample
from percver.verification.splitters import TIME_LIMIT, Retry
from percver.verification.wrapping import QUICK, wrapping


class Campaign:
    """The cells of one part of a verify() call as they flow: the lazy grid and sub-cells are
    looked up in the journal, probed in batches (centre and corners simulated), and handed to a
    backend (the local pool of :func:`run_local` or an executor) that returns outcomes in any
    order; unknown cells (with refine=True) and timed-out ones (always) are bisected down to
    min_width and their halves queued, and a cell left unknown is sampled (``falsify`` random
    runs) once the splitter settles it, not when it cuts it: its pieces are probed, and the cells
    a splitter halves on its way down are many (on a Mountain Car slice their random runs took
    more time than the engine). One rule on every backend: the local pool samples in the thread
    that ran the cell, an executor on its workers (:meth:`settle`, :meth:`sampled`). An engine
    verdict of "violated" is sampled before the splitter sees it. Memory is a batch plus the
    results.

    Random runs come after the engine, not before: a verified cell needs none (its proof covers
    every run), and on a row that verifies they were most of the simulation, which competes with
    the engine for the same cores (Mountain Car's composite row: 41 runs per cell cost ~12% of
    the engine's time). A falsified cell then also spent its engine run; its time is kept.

    Outcomes may be recorded from one thread while another falsifies cells (``stock`` runs beside
    the engine): the state is only touched under ``lock``, which no simulation holds."""

    chunk = 128  # cells falsified together at most: one simulation batch, bounded trajectories

    def __init__(
        self,
        loop,
        prop,
        init: Box,
        splitter,
        cells,
        journal,
        bar,
        *,
        timeout,
        falsify: int,
        seed: int,
        lock: threading.RLock,
        deadline: Optional[tuple] = None,
    ):
        self.loop, self.prop, self.init, self.splitter, self.journal, self.bar = loop, prop, init, splitter, journal, bar
        self.grid, self.left = cells  # the splitter's initial cells (a lazy iterator) and their count
        self.timeout, self.falsify, self.seed = timeout, falsify, seed
        # (time_limit, its time.monotonic() deadline) of the whole call, or None: see expire().
        self.deadline = deadline
        self.queue: list = []  # sub-cells as (box, options), last in first out: depth-first keeps the queue short
        self.chosen: dict = {}  # cell key -> engine settings the splitter chose for it, while it is out
        self.ready: deque = deque()  # falsification found nothing: to be run
        self.cells: list = []
        self.lost: list = []  # the first LOST_KEPT cells left unknown and replaced: see Result.lost
        self.cell_seconds = [0.0, 0]  # engine seconds and cells so far, to size executor batches
        self.lock = lock  # the parts of one call share it, with their progress bar
        # Outcomes are applied (learnt, split, journaled) in the order their cells were drawn, and
        # the next cell is drawn only once every outcome but the last ``window`` draws' is applied
        # (None: each as soon as it and all earlier ones are in): what the splitter knows when it
        # draws a cell is then the same on every run, whichever cell finishes first.
        self.window: Optional[int] = getattr(splitter, "window", None)
        self.drawn = 0  # cells given a turn (run, or read from the journal) so far
        self.applied = 0  # turns whose outcome is applied, in order
        self.outcomes: dict = {}  # turn -> its outcome applied (a function, called under the lock), once in
        self.turn_of: dict = {}  # cell key -> its turn, while it is out
        # (cell, Cell, claimed) of the cell settled unknown whose random runs the next turns wait for
        self.awaiting: Optional[tuple] = None
        if hasattr(splitter, "probe"):
            splitter.probe = functools.partial(spread, loop)
        if hasattr(splitter, "wrapping"):
            splitter.wrapping = functools.partial(wrapping, loop, samples=QUICK)

    def run_on(self, workers: int) -> None:
        """Sets the window for ``workers`` threads, or an executor's cells in flight (two per
        worker, one cell a batch). Threads past the splitter's window widen it to their number, so
        no thread waits for lack of cells drawn ahead; with as many cells out, a cluster makes the
        cells a local run makes, where drawing far ahead of the outcomes made others, and more
        (bench/README.md, "Dask and the adaptive splitter")."""
        if self.window is not None:
            self.window = max(self.window, workers)

    def remaining(self) -> int:
        """Cells known to be still to run (sub-cells of running cells may add more); past the
        time limit only those out."""
        with self.lock:
            if self.over():  # only cells running: outcomes still to apply are applied by flush()
                return len(self.turn_of)
            return self.left + len(self.queue) + len(self.ready) + self.drawn - self.applied + (self.awaiting is not None)

    def over(self) -> bool:
        """Whether the call's time limit has passed: no cell starts any more."""
        return self.deadline is not None and time.monotonic() >= self.deadline[1]

    def engine_options(self, options: dict) -> dict:
        """``options`` for a cell starting now: under a time limit its engine stops at the next
        step past the deadline (or its own timeout, if sooner)."""
        if self.deadline is None:
            return options
        return until(options, self.deadline[1] - time.monotonic())

    def batch_options(self, options: dict) -> dict:
        """``options`` for a batch sent to an executor: under a time limit, the deadline as the
        clock's time, so that each cell gets the time left when it starts on the worker."""
        if self.deadline is None:
            return options
        return {**options, "deadline": time.time() + self.deadline[1] - time.monotonic()}

    def _drop_ready(self):
        """Past the time limit, cells drawn but not started are settled in their turns, not run."""
        with self.lock:
            while self.ready:
                cell = self.ready.popleft()
                self._done(cell, functools.partial(self._unrun, cell))

    def _unrun(self, cell: Box, options: Optional[dict] = None):
        """``cell`` settled unknown without a run: the time limit came first. Not journaled."""
        options = self.chosen.pop(cell_key(cell.to_dict()), {}) if options is None else options
        self._place(cell, Cell(cell.to_dict(), "unknown", reason=f"not run within {self._limit()}", options=options), None)

    def _limit(self) -> str:
        """The time limit as the reasons of the cells it stopped or left out name it."""
        return f"{TIME_LIMIT}{self.deadline[0]:g} s"

    def expire(self):
        """Past the time limit, the cells not drawn yet (queued, or in the initial grid) become
        unknown results with the limit as their reason, so that the result still covers the
        initial set; like the cells the limit stopped, they are not journaled (a rerun runs them)."""
        if not self.over():
            return
        with self.lock:
            left = self.queue + [_with_options(next(self.grid)) for _ in range(self.left)]
            self.queue, self.left = [], 0
            for cell, options in left:
                self._unrun(cell, options)

    def take(self, n: int, stock: int = 0) -> list:
        """Up to n cells to run (falsifying up to max(n, stock) first), all with the same
        :meth:`options_of`; empty when none is left for now. Threads may take and stock at once:
        cells are drawn under the lock, each by one thread. A splitter with a ``lookahead`` draws at
        most that many ahead (one that learns from each outcome wants its next cells cut after it)."""
        self._sample_awaiting()
        if self.over():
            self._drop_ready()
            return []
        self.stock(max(n, min(stock, getattr(self.splitter, "lookahead", stock))))
        with self.lock:
            out = []
            while self.ready and len(out) < n and (not out or self.options_of(self.ready[0]) == self.options_of(out[0])):
                out.append(self.ready.popleft())
            return out

    def options_of(self, cell: Box) -> dict:
        """Engine settings the splitter chose for ``cell`` beyond the call's (e.g. rebox)."""
        return self.chosen.get(cell_key(cell.to_dict()), {})

    def stock(self, n: int):
        """Falsifies cells until n are ready to run or none is left for now."""
        while True:
            with self.lock:
                if len(self.ready) >= n:
                    return
                fresh = self._draw(min(self.chunk, max(n - len(self.ready), min(n, 8))))
                if not fresh:  # none left, or the next waits for an outcome
                    return
            found = falsify(self.loop, self.prop, [cell for cell, _ in fresh], self.prop.steps, 0, self.seed)
            with self.lock:
                for (cell, options), cex in zip(fresh, found):
                    if cex is None:
                        self.ready.append(cell)
                        if options:
                            self.chosen[cell_key(cell.to_dict())] = options
                    else:
                        self._done(cell, functools.partial(self._probed, cell, cex, options))

    def _probed(self, cell: Box, cex: Counterexample, options: dict):
        """A cell whose probe (centre and corners) violates the property: falsified, no engine run."""
        c = Cell(
            cell.to_dict(),
            "falsified",
            counterexample=cex,
            reason=f"simulation violates {cex.violated} at step {cex.step}",
            options=options,
        )
        self.journal.write(c)
        self.splitter.learn(cell, c, self.init)
        self._place(cell, c, None)

    def draw(self, n: int) -> list:
        """Up to n cells for an executor as ``(box, options)``, unprobed: its workers probe and run
        them (:func:`percver.verification.executors.run_batch`), and sample those :meth:`settle`
        returns, so the driver only journals and splits. ``options`` are the engine settings the
        splitter chose for the cell."""
        with self.lock:
            drawn = self._draw(n)
            for cell, options in drawn:
                if options:
                    self.chosen[cell_key(cell.to_dict())] = options
            return drawn

    def settle(self, cell: Box, outcome: dict):
        """A cell's outcome from an executor's worker: ``{"probe": cex}`` when its probe falsified it
        (no engine run), else ``{"outcome", "rss", "counterexample"}``: the engine's outcome, the
        worker's peak RSS and what its random runs found (run for a "violated" verdict only). A cell
        the splitter settles unknown is then sampled on the executor (:meth:`unsampled`)."""
        with self.lock:
            if outcome.get("probe") is not None:
                chosen = self.chosen.pop(cell_key(cell.to_dict()), {})
                self._done(cell, functools.partial(self._probed, cell, outcome["probe"], chosen))
            else:
                self._done(cell, functools.partial(self._record, cell, outcome["outcome"], outcome["rss"], outcome["counterexample"]))

    def unsampled(self) -> list:
        """``[(cell, Cell)]``: the cell settled unknown whose random runs the next outcomes wait for,
        if no one runs them yet (an executor samples it and gives the result to :meth:`sampled`)."""
        with self.lock:
            if self.awaiting is None or self.awaiting[2]:
                return []
            self.awaiting = (*self.awaiting[:2], True)
            return [self.awaiting[:2]]

    def _sample_awaiting(self):
        """The random runs the next outcomes wait for, on this thread (outside the lock)."""
        for cell, c in self.unsampled():
            self.sampled(cell, c, self.sample(cell))

    def _done(self, cell: Box, apply):
        """A cell's outcome is in: ``apply`` (under the lock) learns and places it in its turn."""
        self.outcomes[self.turn_of.pop(cell_key(cell.to_dict()))] = apply
        self._apply(self._due())

    def _due(self) -> int:
        """Turns whose outcomes must be applied before the next cell is drawn."""
        return self.drawn if self.window is None else self.drawn - self.window + 1

    def _apply(self, upto: int) -> bool:
        """Applies the outcomes that are in, in turn, up to turn ``upto`` (excluded); whether all were."""
        while self.applied < upto:
            if self.awaiting is not None or self.applied not in self.outcomes:
                return False
            apply = self.outcomes.pop(self.applied)
            self.applied += 1
            settled = apply()
            if settled is not None:
                self.awaiting = (*settled, False)
        return True

    def _draw(self, want: int) -> list:
        """Up to ``want`` cells ``(box, options)`` not in the journal (the journal's are settled on
        the way, following its recorded decisions, in their turn like the cells that run); fewer
        while an outcome the next draw must see is not in."""
        fresh = []
        while len(fresh) < want and not self.over():
            if not self._apply(self._due()) and self.window is not None:
                break
            if not (self.queue or self.left):
                # Nothing to draw: the next outcome may make more (its turn has come).
                if self.applied < self.drawn and self._apply(self.applied + 1):
                    continue
                if self.applied == self.drawn and self.awaiting is None and self._reopen():
                    continue
                break
            if self.queue:
                cell, options = self.queue.pop()
            else:
                cell, options = _with_options(next(self.grid))
                self.left -= 1
            key = cell_key(cell.to_dict(), options)
            known = self.journal.done.get(key)
            if known is not None:
                self.outcomes[self.drawn] = functools.partial(self._replay, cell, known, key)
                self.drawn += 1
                continue
            # The splitter sees every cut, a replayed one too (what it learns may depend on it).
            pieces = [_with_options(piece, options) for piece in self.splitter.prepare(cell, self.init)]
            if key in self.journal.cuts:
                pieces = self.journal.cuts[key]
            elif pieces != [(cell, options)]:
                self.journal.write_cut(cell.to_dict(), options, pieces)
            if pieces != [(cell, options)]:  # cut, or run with other options: looked up in the journal as such
                self.queue += pieces
                self.bar.settled(None, more=len(pieces))
            else:
                self.turn_of[cell_key(cell.to_dict())] = self.drawn
                self.drawn += 1
                fresh.append((cell, options))
        return fresh

    def _reopen(self) -> bool:
        """Every cell drawn is settled: the splitter may take back cells it gave up (``revisit``),
        given what it learnt since; their pieces are queued. Whether it did."""
        revisit = getattr(self.splitter, "revisit", None)
        reopened = revisit(self.init) if revisit is not None else []
        taken = False
        for cell, pieces in reopened:
            box = cell.to_dict()
            given_up = next((k for k, c in enumerate(self.cells) if c.box == box and c.verdict == "unknown"), None)
            if given_up is None:  # a journal recorded other pieces for it: they stand
                continue
            self.bar.reopened(self.cells.pop(given_up).verdict, len(pieces))
            self.queue += pieces
            taken = True
        return taken

    def _replay(self, cell: Box, known: Cell, key: str):
        """A cell the journal holds, in its turn: learnt, and replaced by the pieces it recorded."""
        self.splitter.learn(cell, known, self.init)
        pieces = self._again(cell, known)
        self._place(cell, known, self.journal.decided[key] if key in self.journal.decided else pieces)

    def flush(self):
        """Applies (journals) every outcome that is in, in turn: at the end of a run, or when it
        stops early (then past the turns of cells that did not finish, and of a cell settled
        unknown still to be sampled, which a resumed run runs again), so no finished cell's work
        is lost."""
        with self.lock:
            self._sample_when_over()
            self.awaiting = None
            for turn in sorted(self.outcomes):
                self.applied = turn
                self._apply(turn + 1)
                self._sample_when_over()
                self.awaiting = None

    def _sample_when_over(self):
        """A time-limited call returns its results: a cell settled unknown gets its random runs now
        (sampling may settle the next outcomes, and another cell with them), not in a rerun."""
        while self.awaiting is not None and self.over():
            cell, c, _ = self.awaiting
            self.awaiting = None
            self.sampled(cell, c, self.sample(cell))

    def record(self, cell: Box, outcome: _core.CellOutcome, peak_rss_mb: Optional[float]):
        """A cell's outcome from the engine (``run_cells``) on the local pool. Random runs go
        outside the lock: the simulation must not hold up other threads' outcomes."""
        cex = self.sample(cell) if outcome.verdict == "violated" else None
        with self.lock:
            self._done(cell, functools.partial(self._record, cell, outcome, peak_rss_mb, cex))
        self._sample_awaiting()

    def sample(self, cell: Box) -> Optional[Counterexample]:
        """The first violation among the cell's ``falsify`` random runs (they depend only on the
        cell and the seed: the same on every backend)."""
        if self.falsify <= 0:
            return None
        return falsify(self.loop, self.prop, [cell], self.prop.steps, self.falsify, self.seed, probe=False)[0]

    def _record(
        self, cell: Box, outcome: _core.CellOutcome, peak_rss_mb: Optional[float], cex: Optional[Counterexample]
    ) -> Optional[tuple]:
        """The engine's outcome (``cex``: what the random runs of a "violated" verdict found)
        learnt and finished; or ``(cell, Cell)`` returned, when the splitter settles it unknown and
        it is still to be sampled (:meth:`sampled` finishes it)."""
        verdict, reason = outcome.verdict, outcome.reason
        violated = verdict == "violated"  # its random runs are done
        if cex is not None:
            verdict, reason = "falsified", _falsified_reason(cex, reason)
        elif verdict == "violated":
            # The engine says every state violates, yet no simulation did: say unknown
            # rather than claim a counterexample we do not have.
            verdict = "unknown"
        c = Cell(
            cell.to_dict(),
            verdict,
            outcome.seconds,
            outcome.nn_seconds,
            outcome.branches,
            outcome.steps_done,
            reason,
            cex,
            outcome.boxes,
            peak_rss_mb,
            None if outcome.split is None else self.init.names[outcome.split],
            outcome.deepest_step,
            self.chosen.pop(cell_key(cell.to_dict()), {}),
            outcome.steps_redone,
        )
        self.cell_seconds[0] += c.seconds
        self.cell_seconds[1] += 1
        if c.verdict == "unknown" and reason.startswith("timeout after") and self.over() and not self._timed_out(c):
            # Stopped by the call's time limit, not by anything about the cell: nothing to learn or
            # journal (a rerun runs it again).
            self._place(cell, replace(c, reason=f"stopped at step {c.steps_done} by {self._limit()}"), None)
            return None
        self.splitter.learn(cell, c, self.init)
        pieces = self._again(cell, c)
        if pieces and c.verdict == "unknown" and len(self.lost) < LOST_KEPT:
            self.lost.append(c)
        if not pieces and c.verdict == "unknown" and not violated and self.falsify > 0:
            return cell, c
        self._finish(cell, c, pieces)
        return None

    def sampled(self, cell: Box, c: Cell, cex: Optional[Counterexample]):
        """A cell settled unknown, with what its random runs found: falsified by them, it is
        learnt again as such (see :mod:`percver.verification.splitters`)."""
        with self.lock:
            if cex is not None:
                c = replace(c, verdict="falsified", reason=_falsified_reason(cex, c.reason), counterexample=cex)
                self.splitter.learn(cell, c, self.init)
            self._finish(cell, c, None)
            self.awaiting = None
            self._apply(self._due())

    def _finish(self, cell: Box, c: Cell, pieces: Optional[list]):
        if self._timed_out(c) and not pieces:
            c.reason += "; not split further: the cell is at min_width"
        self.journal.write(c, pieces)
        self._place(cell, c, pieces)

    def _timed_out(self, c: Cell) -> bool:
        # The engine stops a cell between steps once it has run longer than the timeout.
        return c.verdict == "unknown" and self.timeout is not None and c.seconds > self.timeout

    def _again(self, cell: Box, c: Cell) -> Optional[list]:
        """The splitter's pieces ``(box, options)`` replacing an outcome, or None (it is final):
        halves keep the cell's options unless the splitter gives their own; a :class:`Retry` is the
        same box with more options."""
        pieces = self.splitter.again(cell, c, self.init, self._timed_out(c))
        if isinstance(pieces, Retry):
            return [(cell, {k: v for k, v in {**c.options, **pieces.options}.items() if v is not None})]
        return None if not pieces else [piece if isinstance(piece, tuple) else (piece, c.options) for piece in pieces]

    def _place(self, cell: Box, c: Cell, pieces: Optional[list]):
        """A finished cell (fresh or from the journal) is a result, or replaced by its pieces."""
        if pieces:
            self.queue += pieces
            self.bar.settled(None, more=len(pieces))
        else:
            self.cells.append(c)
            self.bar.settled(c.verdict)


def until(options: dict, left: float) -> dict:
    """Engine ``options`` with the timeout cut to ``left`` seconds (at least a millisecond)."""
    left = max(left, 1e-3)
    own = options.get("timeout")
    return {**options, "timeout": left if own is None else min(own, left)}


def _falsified_reason(cex: Counterexample, engine: str) -> str:
    return f"simulation violates {cex.violated} at step {cex.step}; the engine: {engine}"


def _with_options(piece, options: Optional[dict] = None) -> tuple:
    """A splitter's cell as ``(box, options)``: a bare Box takes ``options`` (none given: {})."""
    return piece if isinstance(piece, tuple) else (piece, options or {})


class Progress:
    """The progress bar of a verify call (tqdm once started, else nothing), shared by its parts:
    cells settled and the verdicts so far over all of them, and the step each running cell has
    reached (``steps``: deepest first, as step/horizon). Updated under the parts' ``lock``; the
    running cells' steps are read from their engine counters once a second by a thread of its
    own, which takes the same lock, so a long cell shows progress before it ends."""

    SECONDS = 1.0

    def __init__(self, lock: threading.RLock):
        self.tqdm = None
        self.lock = lock
        self.counts = dict.fromkeys(("verified", "unknown", "falsified"), 0)
        self.running: dict = {}  # thread -> (_core.StepCounter of its cell, the cell's horizon)
        self.stopped = threading.Event()

    def start(self, total: int):
        from tqdm import tqdm

        self.tqdm = tqdm(total=total, unit="cell", desc="verify")
        threading.Thread(target=self._watch, name="percver-progress", daemon=True).start()

    def _watch(self):
        while not self.stopped.wait(self.SECONDS):
            with self.lock:
                if self.tqdm is not None and self.running:
                    self._postfix()
                    self.tqdm.refresh()

    def _postfix(self):
        shown = dict(self.counts)
        steps = sorted(((counter.get(), horizon) for counter, horizon in self.running.values()), reverse=True)
        if steps:
            shown["steps"] = " ".join(f"{s}/{h}" for s, h in steps[:4])
        self.tqdm.set_postfix(shown, refresh=False)

    def cell_started(self, counter, horizon: int):
        with self.lock:
            self.running[threading.get_ident()] = (counter, horizon)

    def cell_ended(self):
        with self.lock:
            self.running.pop(threading.get_ident(), None)

    def settled(self, verdict: Optional[str], more: int = 0):
        """A cell is settled with ``verdict``, or (None) replaced by ``more`` sub-cells."""
        if verdict is not None:
            self.counts[verdict] += 1
        if self.tqdm is not None:
            self.tqdm.total += more
            self._postfix()
            self.tqdm.update(1)

    def reopened(self, verdict: str, more: int):
        """A cell settled with ``verdict`` is replaced by ``more`` sub-cells after all."""
        self.counts[verdict] -= 1
        if self.tqdm is not None:
            self.tqdm.total += more
            self._postfix()

    def close(self):
        self.stopped.set()
        if self.tqdm is not None:
            with self.lock:
                self.tqdm.close()


_CLEAR: dict = {}  # pid -> descriptor of /proc/self/clear_refs (a forked child opens its own)


def _reset_peak_rss():
    """Restarts the process's peak RSS (Linux; elsewhere the peak stays the one since the start).
    It takes the address-space lock, so once per batch, not per cell."""
    pid = os.getpid()
    if pid not in _CLEAR:
        _CLEAR.clear()
        try:
            _CLEAR[pid] = os.open("/proc/self/clear_refs", os.O_WRONLY)
        except OSError:
            _CLEAR[pid] = None
    if _CLEAR[pid] is not None:
        os.pwrite(_CLEAR[pid], b"5", 0)


def _peak_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024


def run_cells(problem, cells: list, done, options: dict, workers: Optional[int], progress=None):
    """``_core.verify_cells`` on cells given as lists of (lo, hi): ``done(index, outcome,
    peak_rss_mb)`` gets each outcome with the peak RSS of this process from the batch's start to
    the cell's end; the one place cells run, locally and on executor workers. ``progress`` (a
    ``_core.StepCounter``) follows the deepest step."""

    def each(i, outcome):
        return done(i, outcome, _peak_rss_mb())

    _reset_peak_rss()
    _core.verify_cells(problem, [list(c) for c in cells], each, _core.CellSettings(**options), workers=workers, progress=progress)


def run_local(jobs: list, workers: Optional[int], bar: Progress):
    """The cells of all ``jobs`` (campaign, problem, options) on this machine's cores: ``workers``
    threads (the caller's among them) each take one cell at a time from the first campaign that
    has one and run it alone (a rayon pool of one), so sub-cells join in as they are made and no
    core waits for a batch's or a campaign's last cell. A thread that finds no cell ready
    falsifies the next few (numpy, mostly without the GIL) while the others run the engine."""
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise InputError(f"workers must be a positive integer, got {workers!r}")
    count = workers or os.cpu_count() or 1
    for campaign, _, _ in jobs:
        campaign.run_on(count)
    idle = threading.Condition()
    busy = [0]  # threads taking or running a cell: while any is, more cells may come
    stop = threading.Event()
    failures: list = []

    def next_cell():
        with idle:
            busy[0] += 1
        for campaign, problem, options in jobs:
            cells = campaign.take(1, stock=STOCK)
            if cells:
                return campaign, problem, options, cells[0]
        with idle:
            busy[0] -= 1
            if busy[0] == 0:
                idle.notify_all()
        return None

    def work():
        counter = _core.StepCounter()  # the step this thread's cell has reached, for the bar
        try:
            while not stop.is_set():
                got = next_cell()
                if got is None:
                    with idle:
                        if busy[0] == 0 and not any(campaign.remaining() for campaign, _, _ in jobs):
                            return
                        idle.wait(0.1)  # a running cell may be bisected into more
                    continue
                campaign, problem, options, cell = got
                counter.reset()
                bar.cell_started(counter, campaign.prop.steps)
                try:
                    run_cells(
                        problem,
                        [cell.bounds],
                        lambda i, o, rss: campaign.record(cell, o, rss),
                        campaign.engine_options({**options, **campaign.options_of(cell)}),
                        1,
                        counter,
                    )
                finally:
                    bar.cell_ended()
                    with idle:
                        busy[0] -= 1
                        idle.notify_all()
        except BaseException as error:
            failures.append(error)
            stop.set()

    helpers = [threading.Thread(target=work, name=f"percver-cells-{k}", daemon=True) for k in range(1, count)]
    for t in helpers:
        t.start()
    try:
        work()
    finally:
        stop.set()  # an interrupt or an error: the others stop after their current cell
        for t in helpers:
            t.join()
    if failures:
        raise failures[0]


STOCK = 16  # cells falsified together when a thread finds none ready (one numpy batch)
LOST_KEPT = 16  # replaced unknown cells a campaign keeps as evidence (their boxes: steps x states)
