"""``pv.verify``: split the initial set into cells, falsify first, verify the rest in parallel,
refine what stays unknown, and journal every finished cell.

Verdicts per cell: "verified" (the engine proved the property for every state of the cell),
"falsified" (a simulated trajectory from the cell violates it; the counterexample replays),
"unknown" (neither; the reason says at which step and on which variable precision was lost).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError, PercverError
from percver.expr import Condition
from percver.sets import Box, BoxLike
from percver.systems import ClosedLoop


class JournalError(PercverError):
    """The journal belongs to another problem, or another process is writing it."""


@dataclass
class Counterexample:
    initial: dict
    trajectory: list  # steps x states
    step: int
    violated: str


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

    def to_dict(self) -> dict:
        return asdict(self)

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
        if len(goals) > 1:
            raise InputError("give one goal condition (combine several with separate runs)")
        self.goal = goals[0] if goals else None
        self.within = within
        self.steps = steps
        if not self.safe and self.goal is None:
            raise InputError("nothing to verify: give safe=..., unsafe=... or goal=...")

    def rust(self):
        safe = [(c.margin(), c.op, str(c)) for c in self.safe]
        goal = (self.goal.margin(), self.goal.op, str(self.goal)) if self.goal is not None else None
        return safe, goal

    def violation(self, traj: np.ndarray):
        """(row, step, label) of the first violation in trajectories (N x T x n), else None."""
        names = self.states
        for t in range(traj.shape[1]):
            for c in self.safe:
                m = _core.eval_float([c.margin()], names, np.ascontiguousarray(traj[:, t]))[:, 0]
                bad = np.nonzero(~_holds(c.op, m))[0]
                if len(bad):
                    return int(bad[0]), t, str(c)
        if self.goal is not None:
            steps = range(traj.shape[1]) if self.within else [traj.shape[1] - 1]
            ok = np.zeros(traj.shape[0], dtype=bool)
            for t in steps:
                m = _core.eval_float([self.goal.margin()], names, np.ascontiguousarray(traj[:, t]))[:, 0]
                ok |= _holds(self.goal.op, m)
            bad = np.nonzero(~ok)[0]
            if len(bad):
                return int(bad[0]), traj.shape[1] - 1, f"goal {self.goal}"
        return None


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
            lines = self.path.read_text().split("\n")
            header = json.loads(lines[0])
            if header.get("fingerprint") != fingerprint:
                self.close()
                raise JournalError(f"journal {self.path} was written for a different problem (fingerprint {header.get('fingerprint')} != {fingerprint}); use another journal file")
            for k, line in enumerate(lines[1:], start=2):
                if not line.strip():
                    continue
                try:
                    cell = Cell.from_dict(json.loads(line))
                except (json.JSONDecodeError, TypeError):
                    if k == len(lines) or (k == len(lines) - 1 and not lines[-1]):
                        print(f"percver: journal {self.path}: ignoring a truncated last line (line {k})")
                        continue
                    raise JournalError(f"journal {self.path}, line {k} is corrupt") from None
                self.done[_key(cell.box)] = cell
            self.file = open(self.path, "a")
        else:
            self.file = open(self.path, "w")
            self.file.write(json.dumps({"fingerprint": fingerprint}) + "\n")
            self.file.flush()

    def write(self, cell: Cell):
        if self.file:
            self.file.write(json.dumps(cell.to_dict()) + "\n")
            self.file.flush()
            os.fsync(self.file.fileno())

    def close(self):
        if self.file:
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


def _bisect(box: Box, init: Box) -> list:
    """Halves the cell along its widest dimension relative to the initial set."""
    rel = [(hi - lo) / (ihi - ilo) if ihi > ilo else 0.0 for (lo, hi), (ilo, ihi) in zip(box.bounds, init.bounds)]
    j = int(np.argmax(rel))
    lo, hi = box.bounds[j]
    mid = 0.5 * (lo + hi)
    left = list(box.bounds)
    right = list(box.bounds)
    left[j] = (lo, mid)
    right[j] = (mid, hi)
    return [Box(box.names, tuple(left)), Box(box.names, tuple(right))]


def verify(
    loop: ClosedLoop,
    init: Optional[BoxLike] = None,
    *,
    steps: Optional[int] = None,
    goal: Optional[Condition] = None,
    safe: Union[Condition, Sequence[Condition], None] = None,
    unsafe: Union[Condition, Sequence[Condition], None] = None,
    within: bool = False,
    split: Optional[dict] = None,
    refine: bool = False,
    min_width: Optional[dict] = None,
    method: str = "taylor",
    order: int = 5,
    workers: Optional[int] = None,
    executor=None,
    journal: Optional[str] = None,
    timeout_per_cell: Optional[float] = None,
    falsify: int = 32,
    progress: bool = True,
    seed: int = 0,
) -> Result:
    """Prove ``loop`` satisfies the property from every state of ``init`` (see module doc)."""
    started = time.time()
    if not isinstance(loop, ClosedLoop) and isinstance(getattr(loop, "loop", None), ClosedLoop):
        # A loaded problem (e.g. pv.formats.load_verisig): its file's init, horizon and property fill what is not given.
        d = loop.defaults
        init, steps = d["init"] if init is None else init, d["steps"] if steps is None else steps
        if goal is None and safe is None and unsafe is None:
            goal, safe, within = d.get("goal"), d.get("safe"), d.get("within", within)
        loop = loop.loop
    if not isinstance(loop, ClosedLoop):
        raise InputError("verify() needs a pv.ClosedLoop")
    if init is None:
        raise InputError("verify() needs init={state: (lo, hi), ...}")
    if not (isinstance(steps, int) and steps >= 0):
        raise InputError(f"steps must be a non-negative integer, got {steps!r}")
    if executor is not None:
        raise InputError("executor= (distributed cells) is not available yet; cells run on local threads (workers=N)")
    if method not in ("taylor", "verisig"):
        raise InputError(f"unknown method '{method}'; use 'taylor' or 'verisig'")
    box = Box.coerce(init, loop.states)
    prop = _Property(loop, safe, unsafe, goal, within, steps)
    safe_r, goal_r = prop.rust()
    problem = loop.compile(safe=safe_r, goal=goal_r, within=within, steps=steps)
    settings = {"steps": steps, "method": method, "order": order, "timeout_per_cell": timeout_per_cell, "within": within}
    journal_ = _Journal(journal, _fingerprint(loop, prop, settings))
    rng = np.random.default_rng(seed)
    cells_out: list = []
    bar = None
    try:
        pending = box.split(split or {})
        min_w = {n: float(w) for n, w in (min_width or {}).items()}
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(pending), unit="cell", desc="verify")
        while pending:
            todo = []
            fresh = []
            for cell in pending:
                known = journal_.done.get(_key(cell.to_dict()))
                if known is not None:
                    cells_out.append(known)
                    _tick(bar, cells_out)
                else:
                    fresh.append(cell)
            for cell, cex in zip(fresh, _falsify(loop, prop, fresh, steps, falsify, rng)):
                if cex is not None:
                    c = Cell(cell.to_dict(), "falsified", counterexample=cex, reason=f"simulation violates {cex.violated} at step {cex.step}")
                    journal_.write(c)
                    cells_out.append(c)
                    _tick(bar, cells_out)
                else:
                    todo.append(cell)
            finished: dict = {}

            def done(i, outcome):
                verdict = outcome["verdict"]
                if verdict == "violated":
                    # The engine says every state violates, yet no simulation did: say unknown
                    # rather than claim a counterexample we do not have.
                    verdict = "unknown"
                c = Cell(todo[i].to_dict(), verdict, outcome["seconds"], outcome["nn_seconds"], outcome["branches"],
                         outcome["steps_done"], outcome["reason"], None, outcome["boxes"])
                finished[i] = c
                journal_.write(c)
                cells_out.append(c)
                _tick(bar, cells_out)
                return True

            if todo:
                _core.verify_cells(problem, [list(c.bounds) for c in todo], done, order=order, method=method,
                                   timeout=timeout_per_cell, workers=workers)
            pending = []
            if refine:
                for i, c in finished.items():
                    if c.verdict == "unknown" and _splittable(todo[i], box, min_w):
                        cells_out.remove(c)
                        halves = _bisect(todo[i], box)
                        pending += halves
                if bar is not None and pending:
                    bar.total += len(pending)
                    bar.refresh()
    finally:
        if bar is not None:
            bar.close()
        journal_.close()
    result = Result(loop.states, box.to_dict(), cells_out, time.time() - started, settings)
    return result


def _splittable(cell: Box, init: Box, min_width: dict) -> bool:
    for name, (lo, hi), (ilo, ihi) in zip(cell.names, cell.bounds, init.bounds):
        limit = min_width.get(name, (ihi - ilo) / 64)
        if hi - lo > 2 * limit and ihi > ilo:
            return True
    return False


def _tick(bar, cells):
    if bar is None:
        return
    counts = {v: sum(c.verdict == v for c in cells) for v in ("verified", "unknown", "falsified")}
    bar.set_postfix(counts, refresh=False)
    bar.update(1)


def _falsify(loop: ClosedLoop, prop: _Property, cells: list, steps: int, samples: int, rng) -> list:
    """Simulates each cell's centre, corners (up to 2^8) and random points, all cells in one
    batch; per cell, the first violating trajectory is its counterexample (else None)."""
    if not cells:
        return []
    points, owner = [], []
    for k, cell in enumerate(cells):
        lo, hi = cell.lo, cell.hi
        pts = [0.5 * (lo + hi)]
        free = [j for j in range(len(lo)) if hi[j] > lo[j]]
        if len(free) <= 8:
            for mask in range(2 ** len(free)):
                p = lo.copy()
                for b, j in enumerate(free):
                    if mask >> b & 1:
                        p[j] = hi[j]
                pts.append(p)
        pts += list(lo + (hi - lo) * rng.random((samples, len(lo))))
        points += pts
        owner += [k] * len(pts)
    x0 = np.array(points)
    owner = np.array(owner)
    traj = loop.simulate(x0, steps)
    out = [None] * len(cells)
    remaining = np.ones(len(x0), dtype=bool)
    while remaining.any():
        rows = np.nonzero(remaining)[0]
        hit = prop.violation(traj[rows])
        if hit is None:
            break
        row, step, label = hit
        r = rows[row]
        k = owner[r]
        out[k] = Counterexample(dict(zip(loop.states, map(float, x0[r]))), traj[r, : step + 1].tolist(), step, label)
        remaining &= owner != k
    return out
