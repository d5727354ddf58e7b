"""Journals: an append-only JSONL file per campaign, so a long run resumes where it stopped;
the problem's fingerprint keeps a journal from resuming another problem."""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from pathlib import Path
from typing import Optional

import numpy as np

from percver.errors import PercverError
from percver.sets import Box
from percver.systems import ClosedLoop
from percver.verification.property import Property
from percver.verification.results import Cell


class JournalError(PercverError):
    """The journal belongs to another problem, or another process is writing it."""


class JournalWarning(UserWarning):
    """The journal's last line was cut by an interrupted write (power loss, kill -9 mid-line)."""


def _expr_hash(e) -> str:
    return str(e.structural_hash()) if hasattr(e, "structural_hash") else repr(e)


def _condition_hash(c) -> str:
    return f"{c.margin().structural_hash()} {c.op}"


def fingerprint(loop: ClosedLoop, prop: Property, settings: dict) -> str:
    """A hash of everything that decides the verdicts; expressions by structure (their text can
    be exponentially long when subexpressions are shared)."""
    h = hashlib.sha256()
    plant = loop.plant
    if hasattr(plant, "modes"):
        equations = plant.expressions() + [repr(plant.signature())]
    else:
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
    # A window only when given, so that journals written before windows still resume.
    safe = [_condition_hash(r.condition) if r.window is None else (_condition_hash(r.condition), r.window) for r in prop.safe]
    h.update(repr((safe, goal, prop.within, prop.steps)).encode())
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:16]


class Journal:
    """Append-only JSONL: a header with the problem's fingerprint, then one line per cell, with
    the splitter's decision about it (``"into"``: null when it is final, else the pieces that
    replace it, each ``[box, options]``), and one line per cell cut before it ran (``"cut"``).
    A resumed campaign follows the recorded decisions (every cell decided before gets the same
    pieces, and none runs again); lines written before decisions were journaled have no
    ``"into"``, and the splitter decides again.

    ``done`` maps a cell's key to its cell, ``decided`` to its recorded pieces (None: final),
    ``cuts`` the key of a cell cut before it ran to its pieces."""

    def __init__(self, path: Optional[str], fingerprint: str):
        self.path = Path(path) if path else None
        self.done: dict = {}
        self.decided: dict = {}
        self.cuts: dict = {}
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
                raise JournalError(
                    f"journal {self.path} is in use by process {pid} (lock {self.lock}); wait for it or remove the lock if it is stale"
                ) from None
        if self.path.exists() and self.path.stat().st_size:
            lines = self.path.read_bytes().split(b"\n")
            header = json.loads(lines[0])
            if header.get("fingerprint") != fingerprint:
                self.close()
                raise JournalError(
                    f"journal {self.path} was written for a different problem (fingerprint {header.get('fingerprint')} != {fingerprint}); use another journal file"
                )
            for k, line in enumerate(lines[1:], start=2):
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                    if "cut" in record:
                        self.cuts[cell_key(record["cut"], record["options"])] = _pieces(record["into"])
                        continue
                    into = record.pop("into", _UNDECIDED)
                    cell = Cell.from_dict(record)
                except (json.JSONDecodeError, TypeError, KeyError, UnicodeDecodeError):
                    if k == len(lines) or (k == len(lines) - 1 and not lines[-1]):
                        # Cut it off: the next append must start on a line of its own.
                        os.truncate(self.path, sum(len(x) + 1 for x in lines[: k - 1]))
                        warnings.warn(
                            f"journal {self.path}: line {k} was cut by an interrupted write; it is dropped and its cell runs again",
                            JournalWarning,
                            stacklevel=3,
                        )
                        continue
                    raise JournalError(f"journal {self.path}, line {k} is corrupt") from None
                key = cell_key(cell.box, cell.options)
                self.done[key] = cell
                if into is not _UNDECIDED:
                    self.decided[key] = None if into is None else _pieces(into)
            self.file = open(self.path, "a")
        else:
            self.file = open(self.path, "w")
            self.file.write(json.dumps({"fingerprint": fingerprint}) + "\n")
            self.file.flush()

    SYNC_SECONDS = 1.0

    def write(self, cell: Cell, into: Optional[list] = None):
        """``cell`` and what replaces it (``into``: pieces ``(Box, options)``; None: it is final)."""
        self._append({**cell.to_dict(), "into": _records(into)})

    def write_cut(self, box: dict, options: dict, into: list):
        """A cell cut into ``into`` (pieces ``(Box, options)``) before it ran."""
        self._append({"cut": box, "options": options, "into": _records(into)})

    def _append(self, record: dict):
        # Flushed at once (a killed process loses nothing), synced to disk at most once a second
        # (power loss loses at most that second, and a cut last line is tolerated on reading).
        if self.file:
            self.file.write(json.dumps(record) + "\n")
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


_UNDECIDED = object()  # a cell line without "into": written before decisions were journaled


def journal_cells(path) -> list:
    """Every cell a journal file holds, in the order run (cells later split included; the
    splitter's cut lines left out): for benchmarks that count attempts."""
    cells = []
    for line in Path(path).read_text().splitlines()[1:]:
        record = json.loads(line) if line.strip() else {"cut": None}
        if "cut" not in record:
            record.pop("into", None)
            cells.append(Cell.from_dict(record))
    return cells


def _records(pieces: Optional[list]) -> Optional[list]:
    return None if pieces is None else [[box.to_dict(), options] for box, options in pieces]


def _pieces(records: list) -> list:
    return [(Box({k: tuple(v) for k, v in box.items()}), options) for box, options in records]


def cell_key(box: dict, options: Optional[dict] = None) -> str:
    """A cell's key in a journal: its box and the engine settings chosen for it (the same box
    run again with other settings is another cell)."""
    key = json.dumps({k: [float(v[0]), float(v[1])] for k, v in sorted(box.items())})
    return key + json.dumps(options, sort_keys=True) if options else key
