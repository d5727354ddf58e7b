"""``pv.verify``: split the initial set into cells, probe each by simulation (its centre and
corners), verify the rest in parallel, sample the cells the engine could not verify for a
counterexample, refine what stays unknown, and journal every finished cell.

Verdicts per cell: "verified" (the engine proved the property for every state of the cell),
"falsified" (a simulated trajectory from the cell violates it; the counterexample replays),
"unknown" (neither; the reason says at which step and on which variable precision was lost).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import sys
import threading
import time
import warnings
import zlib
from collections import deque
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError, PercverError
from percver.expr import Condition
from percver.sets import Box, BoxLike
from percver.systems import ClosedLoop, all_of


class JournalError(PercverError):
    """The journal belongs to another problem, or another process is writing it."""


class JournalWarning(UserWarning):
    """The journal's last line was cut by an interrupted write (power loss, kill -9 mid-line)."""


@dataclass
class Counterexample:
    initial: dict
    trajectory: list  # steps x states
    step: int
    violated: str
    # The run's values of the loop's uncertain parameters: [{"id", "range": [lo, hi], "value"}];
    # replay with ``loop.simulate(x0, steps, parameters=cex.parameter_values())``.
    parameters: list = field(default_factory=list)

    def parameter_values(self) -> dict:
        """``{id: [value]}``, the form :meth:`ClosedLoop.simulate` takes for one run."""
        return {p["id"]: [p["value"]] for p in self.parameters}


@dataclass
class Cell:
    box: dict
    verdict: str
    seconds: float = 0.0
    nn_seconds: float = 0.0
    branches: int = 0
    steps_done: int = 0
    reason: Optional[str] = None
    counterexample: Optional[Counterexample] = None
    boxes: list = field(default_factory=list)  # per step: list of (lo, hi) per state
    # Peak resident memory (MB) of the process that ran the cell, from the start of the cell's
    # batch to its end: an upper bound shared by the cells that ran beside it.
    peak_rss_mb: Optional[float] = None
    # The state the engine would have split next when it gave up: refinement halves it.
    split: Optional[str] = None

    def to_dict(self) -> dict:
        # Shallow (asdict would deep-copy the reach boxes of every journaled cell).
        d = dict(self.__dict__)
        if self.counterexample is not None:
            d["counterexample"] = asdict(self.counterexample)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Cell":
        d = dict(d)
        d["box"] = {k: tuple(v) for k, v in d["box"].items()}
        if d.get("counterexample"):
            d["counterexample"] = Counterexample(**d["counterexample"])
        return cls(**d)


@dataclass
class Result:
    states: list
    init: dict
    cells: list
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)
    # Whether the reach sets stay where the model was validated (percver.validate.verifiable.validity).
    validity: Optional[str] = None

    @property
    def verdict(self) -> str:
        verdicts = {c.verdict for c in self.cells}
        if "falsified" in verdicts:
            return "falsified"
        return "verified" if verdicts == {"verified"} else "unknown"

    @property
    def coverage(self) -> float:
        """Fraction of the initial set (by volume over its non-degenerate dimensions) verified."""
        widths = {n: hi - lo for n, (lo, hi) in self.init.items() if hi > lo}
        if not widths:
            return float(all(c.verdict == "verified" for c in self.cells))

        def volume(box):
            return float(np.prod([(box[n][1] - box[n][0]) / w for n, w in widths.items()]))

        return sum(volume(c.box) for c in self.cells if c.verdict == "verified")

    @property
    def counterexample(self) -> Optional[Counterexample]:
        return next((c.counterexample for c in self.cells if c.counterexample), None)

    def summary(self) -> str:
        """A row like the paper's Table 1: intervals, average time, NN time, branches, coverage."""
        n = len(self.cells)
        run = [c for c in self.cells if c.verdict != "falsified"]
        avg = lambda xs: sum(xs) / len(xs) if xs else 0.0  # noqa: E731
        counts = {v: sum(c.verdict == v for c in self.cells) for v in ("verified", "unknown", "falsified")}
        return (
            f"{'intervals':>9} {'verified':>8} {'unknown':>8} {'falsified':>9} {'avg s':>8} {'avg NN s':>8} {'avg br':>7} {'coverage':>8}\n"
            f"{n:>9} {counts['verified']:>8} {counts['unknown']:>8} {counts['falsified']:>9} "
            f"{avg([c.seconds for c in run]):>8.3f} {avg([c.nn_seconds for c in run]):>8.3f} "
            f"{avg([c.branches for c in run]):>7.2f} {100 * self.coverage:>7.2f}%"
        )

    def to_json(self, path: Optional[str] = None) -> str:
        doc = {"states": self.states, "init": self.init, "seconds": self.seconds, "settings": self.settings,
               "verdict": self.verdict, "coverage": self.coverage, "cells": [c.to_dict() for c in self.cells]}
        text = json.dumps(doc)
        if path:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_json(cls, text_or_path: str) -> "Result":
        text = Path(text_or_path).read_text() if os.path.exists(text_or_path) else text_or_path
        d = json.loads(text)
        return cls(d["states"], {k: tuple(v) for k, v in d["init"].items()}, [Cell.from_dict(c) for c in d["cells"]], d["seconds"], d["settings"])

    def plot(self, x: str, path: Optional[str] = None, loop: Optional[ClosedLoop] = None, samples: int = 20, seed: int = 0):
        """Reach tube of state ``x`` over the steps (one band per cell), over simulated runs."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        j = self.states.index(x)
        fig, ax = plt.subplots(figsize=(7, 4))
        colours = {"verified": "tab:green", "unknown": "tab:orange", "falsified": "tab:red"}
        for c in self.cells:
            if c.boxes:
                b = np.asarray(c.boxes)
                ax.fill_between(np.arange(len(b)), b[:, j, 0], b[:, j, 1], color=colours[c.verdict], alpha=0.3, linewidth=0)
        if loop is not None:
            box = Box.coerce(self.init, self.states)
            traj = loop.simulate(box.sample(samples, seed), self.settings.get("steps", 1))
            ax.plot(traj[:, :, j].T, color="k", linewidth=0.4)
        ax.set_xlabel("step")
        ax.set_ylabel(x)
        ax.set_title(f"{self.verdict}: coverage {100 * self.coverage:.1f}% of {len(self.cells)} cells")
        if path:
            fig.tight_layout()
            fig.savefig(path, dpi=120)
        plt.close(fig)
        return fig


def _conditions(value, what: str, states: list) -> list:
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


_NEGATE = {"<": lambda m: m >= 0, "<=": lambda m: m > 0, ">": lambda m: m <= 0, ">=": lambda m: m < 0}


def _holds(op: str, margin: np.ndarray) -> np.ndarray:
    return {"<": margin < 0, "<=": margin <= 0, ">": margin > 0, ">=": margin >= 0}[op]


class _Property:
    """safe (every step), goal (last step, or some step if within) over the states."""

    def __init__(self, loop: ClosedLoop, safe, unsafe, goal, within: bool, steps: int):
        self.states = loop.states
        self.safe = _conditions(safe, "safe", self.states)
        for u in _conditions(unsafe, "unsafe", self.states):
            # One unsafe half-space is the complement of a safe one.
            self.safe.append(_NEGATE[u.op](u.margin()))
        goals = _conditions(goal, "goal", self.states)
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
        return _holds(condition.op, margin)

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


def _expr_hash(e) -> str:
    return str(e.structural_hash()) if hasattr(e, "structural_hash") else repr(e)


def _condition_hash(c) -> str:
    return f"{c.margin().structural_hash()} {c.op}"


def _fingerprint(loop: ClosedLoop, prop: _Property, settings: dict) -> str:
    """A hash of everything that decides the verdicts; expressions by structure (their text can
    be exponentially long when subexpressions are shared)."""
    h = hashlib.sha256()
    plant = loop.plant
    equations = plant.update if hasattr(plant, "update") else plant.rhs + [plant.period, plant.step, plant.remainder]
    h.update(repr((loop.states, loop.env_names, [_expr_hash(e) for e in equations])).encode())
    for stage in loop.stages:
        if stage.is_network:
            for layer in stage.component.layers:
                h.update(np.ascontiguousarray(layer.weight).tobytes())
                h.update(np.ascontiguousarray(layer.bias).tobytes())
                h.update(repr(layer.activation).encode())
            h.update(repr((stage.component.scale, stage.component.offset)).encode())
        else:
            h.update(repr([_expr_hash(e) for e in stage.component]).encode())
    goal = _condition_hash(prop.goal) if prop.goal is not None else None
    h.update(repr(([_condition_hash(c) for c in prop.safe], goal, prop.within, prop.steps)).encode())
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:16]


class _Journal:
    """Append-only JSONL: a header with the problem's fingerprint, then one line per cell."""

    def __init__(self, path: Optional[str], fingerprint: str):
        self.path = Path(path) if path else None
        self.done: dict = {}
        self.file = None
        self.synced = 0.0
        if self.path is None:
            return
        self.lock = self.path.with_suffix(self.path.suffix + ".lock")
        try:
            fd = os.open(self.lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
        except FileExistsError:
            pid = self.lock.read_text().strip() or "?"
            if pid.isdigit() and not _alive(int(pid)):
                self.lock.write_text(str(os.getpid()))
            else:
                raise JournalError(f"journal {self.path} is in use by process {pid} (lock {self.lock}); wait for it or remove the lock if it is stale") from None
        if self.path.exists() and self.path.stat().st_size:
            lines = self.path.read_bytes().split(b"\n")
            header = json.loads(lines[0])
            if header.get("fingerprint") != fingerprint:
                self.close()
                raise JournalError(f"journal {self.path} was written for a different problem (fingerprint {header.get('fingerprint')} != {fingerprint}); use another journal file")
            for k, line in enumerate(lines[1:], start=2):
                if not line.strip():
                    continue
                try:
                    cell = Cell.from_dict(json.loads(line))
                except (json.JSONDecodeError, TypeError, UnicodeDecodeError):
                    if k == len(lines) or (k == len(lines) - 1 and not lines[-1]):
                        # Cut it off: the next append must start on a line of its own.
                        os.truncate(self.path, sum(len(x) + 1 for x in lines[: k - 1]))
                        warnings.warn(f"journal {self.path}: line {k} was cut by an interrupted write; "
                                      "it is dropped and its cell runs again", JournalWarning, stacklevel=3)
                        continue
                    raise JournalError(f"journal {self.path}, line {k} is corrupt") from None
                self.done[_key(cell.box)] = cell
            self.file = open(self.path, "a")
        else:
            self.file = open(self.path, "w")
            self.file.write(json.dumps({"fingerprint": fingerprint}) + "\n")
            self.file.flush()

    SYNC_SECONDS = 1.0

    def write(self, cell: Cell):
        # Flushed at once (a killed process loses nothing), synced to disk at most once a second
        # (power loss loses at most that second, and a cut last line is tolerated on reading).
        if self.file:
            self.file.write(json.dumps(cell.to_dict()) + "\n")
            self.file.flush()
            if time.monotonic() - self.synced > self.SYNC_SECONDS:
                os.fsync(self.file.fileno())
                self.synced = time.monotonic()

    def close(self):
        if self.file:
            os.fsync(self.file.fileno())
            self.file.close()
            self.file = None
        if self.path is not None and self.lock.exists():
            self.lock.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def _key(box: dict) -> str:
    return json.dumps({k: [float(v[0]), float(v[1])] for k, v in sorted(box.items())})


def _bisect(box: Box, init: Box, min_width: dict, hint: Optional[str] = None) -> list:
    """Halves the cell along ``hint`` (the state the engine wanted to split) while it is above
    its min_width, else along the widest dimension relative to the initial set among those
    above theirs."""
    above = _above_min_width(box, init, min_width)
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


@dataclass(frozen=True)
class Part:
    """A region of the initial set verified with its own grid (``split``), Taylor ``order``,
    in-cell ``max_splits`` and ``journal``: see :func:`verify_parts`."""

    init: Optional[BoxLike] = None
    split: Optional[dict] = None
    order: int = 5
    max_splits: int = 16
    journal: Optional[str] = None


def verify(
    loop: ClosedLoop,
    init: Optional[BoxLike] = None,
    *,
    steps: Optional[int] = None,
    goal: Optional[Condition] = None,
    safe: Union[Condition, Sequence[Condition], None] = None,
    unsafe: Union[Condition, Sequence[Condition], None] = None,
    within: bool = False,
    reward: Optional[dict] = None,
    split: Optional[dict] = None,
    refine: bool = False,
    min_width: Optional[dict] = None,
    method: str = "taylor",
    order: int = 5,
    max_splits: int = 16,
    rebox: bool = False,
    state_symbols: bool = False,
    workers: Optional[int] = None,
    executor=None,
    batch: Optional[int] = None,
    journal: Optional[str] = None,
    timeout_per_cell: Optional[float] = None,
    falsify: int = 32,
    progress: bool = True,
    seed: int = 0,
    validated=None,
) -> Result:
    """Prove ``loop`` satisfies the property from every state of ``init`` (see module doc).

    Cells run on this machine's cores (``workers`` threads, one cell each at a time) or, with
    ``executor=``, on a ``dask.distributed.Client``, a scheduler address ``"tcp://host:8786"`` or
    any ``concurrent.futures.Executor`` (``workers`` then caps the batches in flight; ``batch``
    fixes the cells per task, else tasks are sized to about a quarter second). A cell still running
    after ``timeout_per_cell`` seconds stops at the next step and is bisected down to
    ``min_width`` (default 1/64 of the initial set per dimension), then reported unknown.

    Each cell's centre and corners are simulated before the engine runs it (a violation there
    saves the engine run); a cell the engine does not verify is simulated from ``falsify`` random
    points of it before it is reported or bisected, so a falsified cell's counterexample can come
    from either.

    Inside a cell, a part whose enclosure degrades (or that reaches a ``within`` goal only in
    part) is split where its enclosure was last precise and continued from there, and a condition
    (``pv.where``, in a stage or a discrete plant, e.g. a wall that some runs hit at this step) that
    holds on part of the set forks into one part per side, up to ``max_splits`` splits and forks
    per cell (0: never; conditions then take the hull of both sides); they count as branches. An
    unknown cell's reach boxes end at the last step every part reached. ``rebox=True`` restarts
    a part from its box whenever a remainder is most of a state's enclosure (for loops whose
    remainders feed back and grow, such as the F1/10 LiDAR loop; it loses the dependency on the
    initial state, so it can be looser elsewhere). ``state_symbols=True`` (Taylor method, discrete
    plants) keeps the remainders of the states that feed back as error symbols from step to step,
    so that an error the controller corrects cancels instead of adding its magnitude again (the
    wrapping effect of a stiff feedback); it pays where the loop's Jacobian varies little over a
    cell, and is off by default because on Mountain Car's cells it does not (bench/README.md).
    """
    part = Part(init, split, order, max_splits, journal)
    return verify_parts(loop, [part], steps=steps, goal=goal, safe=safe, unsafe=unsafe, within=within, reward=reward,
                        refine=refine, min_width=min_width, method=method, rebox=rebox, state_symbols=state_symbols,
                        workers=workers, executor=executor, batch=batch, timeout_per_cell=timeout_per_cell,
                        falsify=falsify, progress=progress, seed=seed, validated=validated)[0]


def verify_parts(
    loop: ClosedLoop,
    parts: Sequence[Part],
    *,
    steps: Optional[int] = None,
    goal: Optional[Condition] = None,
    safe: Union[Condition, Sequence[Condition], None] = None,
    unsafe: Union[Condition, Sequence[Condition], None] = None,
    within: bool = False,
    reward: Optional[dict] = None,
    refine: bool = False,
    min_width: Optional[dict] = None,
    method: str = "taylor",
    rebox: bool = False,
    state_symbols: bool = False,
    workers: Optional[int] = None,
    executor=None,
    batch: Optional[int] = None,
    timeout_per_cell: Optional[float] = None,
    falsify: int = 32,
    progress: bool = True,
    seed: int = 0,
    validated=None,
) -> list:
    """:func:`verify` on several :class:`Part` s of an initial set (regions that need different
    cell widths or orders), one :class:`Result` per part, each with the whole call's wall time.

    Locally, all parts' cells share one pool of ``workers`` threads, each running one cell at a
    time and taking the next from the first part that has one: no core waits for the last cell
    of a batch or of a part (verifying the parts one after another left a core idle at each
    part's end). On an executor the parts run one after another. The other keywords are
    :func:`verify`'s, the same for every part."""
    started = time.time()
    if not isinstance(loop, ClosedLoop) and isinstance(getattr(loop, "loop", None), ClosedLoop):
        # A loaded problem (e.g. pv.formats.load_verisig): its file's init, horizon and property fill what is not given.
        d = loop.defaults
        parts = [p if p.init is not None else replace(p, init=d["init"]) for p in parts]
        steps = d["steps"] if steps is None else steps
        if goal is None and safe is None and unsafe is None:
            goal, safe, within = d.get("goal"), d.get("safe"), d.get("within", within)
        loop = loop.loop
    if not isinstance(loop, ClosedLoop):
        raise InputError("verify() needs a pv.ClosedLoop")
    if not parts:
        raise InputError("verify_parts() needs at least one pv.Part")
    for k, p in enumerate(parts):
        if not isinstance(p, Part):
            raise InputError(f"part {k} is a {type(p).__name__}; give pv.Part(init=..., split=..., order=..., max_splits=..., journal=...)")
    if any(p.init is None for p in parts):
        raise InputError("verify() needs init={state: (lo, hi), ...}")
    if not (isinstance(steps, int) and steps >= 0):
        raise InputError(f"steps must be a non-negative integer, got {steps!r}")
    if method not in ("taylor", "verisig"):
        raise InputError(f"unknown method '{method}'; use 'taylor' or 'verisig'")
    for p in parts:
        if not (isinstance(p.max_splits, int) and p.max_splits >= 0):
            raise InputError(f"max_splits must be a non-negative integer, got {p.max_splits!r}")
    if reward is not None:
        loop = loop.with_accumulators(reward)  # sums as extra states: see ClosedLoop.with_accumulators
    boxes = [loop.initial_box(p.init) for p in parts]
    prop = _Property(loop, safe, unsafe, goal, within, steps)
    safe_r, goal_r = prop.rust()
    problem = loop.compile(safe=safe_r, goal=goal_r, within=within, steps=steps)
    runner = None
    if executor is not None:
        from percver.executors import Runner

        runner = Runner(executor, slots=workers, batch=batch)  # checked (and connected) before any work
    jobs, bar = [], _Progress()
    lock = threading.RLock()  # one for all parts: they share the progress bar
    try:
        with ExitStack() as journals:
            for p, box in zip(parts, boxes):
                settings = {"steps": steps, "method": method, "order": p.order, "max_splits": p.max_splits, "rebox": bool(rebox),
                            "timeout_per_cell": timeout_per_cell, "within": within}
                if state_symbols:  # only when on, so that journals written before the option still resume
                    settings["state_symbols"] = True
                fingerprint = _fingerprint(loop, prop, settings)
                options = {"order": p.order, "method": method, "timeout": timeout_per_cell, "max_splits": p.max_splits,
                           "rebox": bool(rebox), "state_symbols": bool(state_symbols)}
                cells, count = _grid(box, p.split or {})
                journal = _Journal(p.journal, fingerprint)
                journals.callback(journal.close)
                campaign = _Campaign(loop, prop, box, cells, count, journal, bar, refine=refine, timeout=timeout_per_cell,
                                     min_width={n: float(w) for n, w in (min_width or {}).items()}, falsify=falsify, seed=seed,
                                     lock=lock)
                jobs.append((campaign, settings, fingerprint, options))
            if progress:
                bar.start(sum(campaign.left for campaign, *_ in jobs))
            if runner is None:
                _run_local([(campaign, problem, options) for campaign, _, _, options in jobs], workers)
            else:
                for campaign, _, fingerprint, options in jobs:
                    runner.run(campaign, (loop, safe_r, goal_r, within, steps), fingerprint, options)
    finally:
        if runner is not None:
            runner.close()
        bar.close()
    seconds = time.time() - started
    results = [Result(loop.states, box.to_dict(), campaign.cells, seconds, settings) for box, (campaign, settings, _, _) in zip(boxes, jobs)]
    from percver.validate.verifiable import validity

    return validity(loop, results, validated)


def _grid(box: Box, split: dict):
    """The cells of ``box.split(split)`` as a lazy iterator, and their count: a campaign of 10^4
    cells never holds them all at once."""
    unknown = set(split) - set(box.names)
    if unknown:
        raise InputError(f"split names {sorted(unknown)}, which are not states ({', '.join(box.names)})")
    axes = [[c.bounds[j] for c in box.split({name: split[name]})] if name in split else [box.bounds[j]]
            for j, name in enumerate(box.names)]
    return (Box(box.names, bounds) for bounds in itertools.product(*axes)), int(np.prod([len(a) for a in axes]))


class _Campaign:
    """The cells of one part of a verify() call as they flow: the lazy grid and sub-cells are
    looked up in the journal, probed in batches (centre and corners simulated), and handed to a
    backend (the local pool of :func:`_run_local` or an executor) that returns outcomes in any
    order; a cell the engine leaves unknown is sampled (``falsify`` random runs) before it is
    settled, and unknown cells (with refine=True) and timed-out ones (always) are bisected down to
    min_width and their halves queued. Memory is a batch plus the results.

    Random runs come after the engine, not before: a verified cell needs none (its proof covers
    every run), and on a row that verifies they were most of the simulation, which competes with
    the engine for the same cores (Mountain Car's composite row: 41 runs per cell cost ~12% of
    the engine's time). A falsified cell then also spent its engine run; its time is kept.

    Outcomes may be recorded from one thread while another falsifies cells (``stock`` runs beside
    the engine): the state is only touched under ``lock``, which no simulation holds."""

    chunk = 128  # cells falsified together at most: one simulation batch, bounded trajectories

    def __init__(self, loop, prop, init: Box, grid, count: int, journal, bar, *, refine: bool, timeout, min_width: dict,
                 falsify: int, seed: int, lock: threading.RLock):
        self.loop, self.prop, self.init, self.grid, self.left, self.journal, self.bar = loop, prop, init, grid, count, journal, bar
        self.refine, self.timeout, self.min_width, self.falsify, self.seed = refine, timeout, min_width, falsify, seed
        self.queue: list = []  # sub-cells, last in first out: depth-first keeps the queue short
        self.ready: deque = deque()  # falsification found nothing: to be run
        self.cells: list = []
        self.cell_seconds = [0.0, 0]  # engine seconds and cells so far, to size executor batches
        self.lock = lock  # the parts of one call share it, with their progress bar

    def remaining(self) -> int:
        """Cells known to be still to run (sub-cells of running cells may add more)."""
        with self.lock:
            return self.left + len(self.queue) + len(self.ready)

    def take(self, n: int, stock: int = 0) -> list:
        """Up to n cells to run (falsifying up to max(n, stock) first); empty when none is left for
        now. Threads may take and stock at once: cells are drawn under the lock, each by one thread."""
        self.stock(max(n, stock))
        with self.lock:
            return [self.ready.popleft() for _ in range(min(n, len(self.ready)))]

    def stock(self, n: int):
        """Falsifies cells until n are ready to run or none is left for now."""
        while True:
            with self.lock:
                if len(self.ready) >= n or not (self.queue or self.left):
                    return
                fresh = self._draw(min(self.chunk, max(n - len(self.ready), 8)))
            found = _falsify(self.loop, self.prop, fresh, self.prop.steps, 0, self.seed)
            with self.lock:
                for cell, cex in zip(fresh, found):
                    if cex is None:
                        self.ready.append(cell)
                    else:
                        self._finish(cell, Cell(cell.to_dict(), "falsified", counterexample=cex,
                                                reason=f"simulation violates {cex.violated} at step {cex.step}"))

    def _draw(self, want: int) -> list:
        """Up to ``want`` cells not in the journal (the journal's are settled on the way)."""
        fresh = []
        while len(fresh) < want and (self.queue or self.left):
            if self.queue:
                cell = self.queue.pop()
            else:
                cell = next(self.grid)
                self.left -= 1
            known = self.journal.done.get(_key(cell.to_dict()))
            if known is not None:
                self._settle(cell, known)
            else:
                fresh.append(cell)
        return fresh

    def record(self, cell: Box, outcome: dict):
        """A cell's outcome from the engine (``_run_cells``); one not verified is sampled first
        (outside the lock: the simulation must not hold up other threads' outcomes)."""
        cex = None
        if outcome["verdict"] != "verified" and self.falsify > 0:
            cex = _falsify(self.loop, self.prop, [cell], self.prop.steps, self.falsify, self.seed, probe=False)[0]
        with self.lock:
            self._record(cell, outcome, cex)

    def _record(self, cell: Box, outcome: dict, cex: Optional[Counterexample]):
        verdict, reason = outcome["verdict"], outcome["reason"]
        if cex is not None:
            verdict, reason = "falsified", f"simulation violates {cex.violated} at step {cex.step}; the engine: {reason}"
        elif verdict == "violated":
            # The engine says every state violates, yet no simulation did: say unknown
            # rather than claim a counterexample we do not have.
            verdict = "unknown"
        c = Cell(cell.to_dict(), verdict, outcome["seconds"], outcome["nn_seconds"], outcome["branches"],
                 outcome["steps_done"], reason, cex, outcome["boxes"], outcome.get("peak_rss_mb"),
                 None if outcome.get("split") is None else self.init.names[outcome["split"]])
        self.cell_seconds[0] += c.seconds
        self.cell_seconds[1] += 1
        if self._timed_out(c) and not self._splits(cell, c):
            c.reason += "; not split further: the cell is at min_width"
        self._finish(cell, c)

    def _finish(self, cell: Box, c: Cell):
        self.journal.write(c)
        self._settle(cell, c)

    def _timed_out(self, c: Cell) -> bool:
        # The engine stops a cell between steps once it has run longer than the timeout.
        return c.verdict == "unknown" and self.timeout is not None and c.seconds > self.timeout

    def _splits(self, cell: Box, c: Cell) -> bool:
        return c.verdict == "unknown" and (self.refine or self._timed_out(c)) and _splittable(cell, self.init, self.min_width)

    def _settle(self, cell: Box, c: Cell):
        """A finished cell (fresh or from the journal) is a result, or replaced by its halves."""
        if self._splits(cell, c):
            self.queue += _bisect(cell, self.init, self.min_width, c.split)
            self.bar.settled(None, more=2)
        else:
            self.cells.append(c)
            self.bar.settled(c.verdict)


class _Progress:
    """The progress bar of a verify call (tqdm once started, else nothing), shared by its parts:
    cells settled and the verdicts so far over all of them. Updated under the parts' lock."""

    def __init__(self):
        self.tqdm = None
        self.counts = dict.fromkeys(("verified", "unknown", "falsified"), 0)

    def start(self, total: int):
        from tqdm import tqdm

        self.tqdm = tqdm(total=total, unit="cell", desc="verify")

    def settled(self, verdict: Optional[str], more: int = 0):
        """A cell is settled with ``verdict``, or (None) replaced by ``more`` sub-cells."""
        if verdict is not None:
            self.counts[verdict] += 1
        if self.tqdm is not None:
            self.tqdm.total += more
            self.tqdm.set_postfix(self.counts, refresh=False)
            self.tqdm.update(1)

    def close(self):
        if self.tqdm is not None:
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


def _run_cells(problem, cells: list, done, options: dict, workers: Optional[int]):
    """``_core.verify_cells`` on cells given as lists of (lo, hi), each outcome with the peak RSS
    of this process from the batch's start to the cell's end; the one place cells run, locally
    and on executor workers."""

    def each(i, outcome):
        outcome["peak_rss_mb"] = _peak_rss_mb()
        return done(i, outcome)

    _reset_peak_rss()
    _core.verify_cells(problem, [list(c) for c in cells], each, workers=workers, **options)


def _run_local(jobs: list, workers: Optional[int]):
    """The cells of all ``jobs`` (campaign, problem, options) on this machine's cores: ``workers``
    threads (the caller's among them) each take one cell at a time from the first campaign that
    has one and run it alone (a rayon pool of one), so sub-cells join in as they are made and no
    core waits for a batch's or a campaign's last cell. A thread that finds no cell ready
    falsifies the next few (numpy, mostly without the GIL) while the others run the engine."""
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise InputError(f"workers must be a positive integer, got {workers!r}")
    count = workers or os.cpu_count() or 1
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
                try:
                    _run_cells(problem, [cell.bounds], lambda i, o: campaign.record(cell, o), options, 1)
                finally:
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


def _above_min_width(cell: Box, init: Box, min_width: dict) -> list:
    """Per dimension: whether halving the cell keeps it at least min_width (default 1/64 of the
    initial set) wide."""
    return [hi - lo > 2 * min_width.get(name, (ihi - ilo) / 64) and ihi > ilo
            for name, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds)]


def _splittable(cell: Box, init: Box, min_width: dict) -> bool:
    return any(_above_min_width(cell, init, min_width))


def _falsify(loop: ClosedLoop, prop: _Property, cells: list, steps: int, samples: int, seed: int, probe: bool = True) -> list:
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
    p_corners = np.vstack([0.5 * (p_lo + p_hi)[None], _corners(p_lo, p_hi, 8)])
    blocks, drawn = [], []
    for cell in cells:
        lo, hi = cell.lo, cell.hi
        rng = np.random.default_rng([seed, zlib.crc32(_key(cell.to_dict()).encode())])
        starts = np.vstack([0.5 * (lo + hi)[None], _corners(lo, hi, 8)]) if probe else np.empty((0, len(lo)))
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


def _corners(lo: np.ndarray, hi: np.ndarray, most: int) -> np.ndarray:
    """The corners of the box over its non-degenerate dimensions, when there are at most ``most``."""
    free = np.nonzero(hi > lo)[0]
    if not len(free) or len(free) > most:
        return np.empty((0, len(lo)))
    bits = (np.arange(2 ** len(free))[:, None] >> np.arange(len(free))) & 1
    corners = np.repeat(lo[None], len(bits), axis=0)
    corners[:, free] = np.where(bits, hi[free], lo[free])
    return corners
