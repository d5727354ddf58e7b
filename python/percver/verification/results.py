"""What a verification found: per cell its verdict, reach boxes and counterexample; per call
the :class:`Result` (summary, JSON, plot)."""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from percver.sets import Box
from percver.systems import ClosedLoop


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
    # Steps every part of the cell completed: the reach boxes cover steps 0..steps_done.
    steps_done: int = 0
    reason: Optional[str] = None
    counterexample: Optional[Counterexample] = None
    boxes: list = field(default_factory=list)  # per step: list of (lo, hi) per state
    # Peak resident memory (MB) of the process that ran the cell, from the start of the cell's
    # batch to its end: an upper bound shared by the cells that ran beside it.
    peak_rss_mb: Optional[float] = None
    # The state the engine would have split next when it gave up: refinement halves it (for a
    # verified cell: the one it split most, if any).
    split: Optional[str] = None
    # The deepest step any part of the cell reached (an unknown cell's parts stop at different
    # steps; steps_done is the shallowest, where the boxes stop being complete).
    deepest_step: int = 0
    # Engine settings the splitter chose for this cell beyond the call's (e.g. {"rebox": True}).
    options: dict = field(default_factory=dict)
    # Steps computed again after splits at an earlier step: what cutting the cell smaller ahead
    # of its run would have saved (forks, whose parts go on, redo none).
    steps_redone: int = 0

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
    # Where a network stage's input left the network's domain: one dict per (stage, input) with
    # the first step, the input's box over the cells leaving there, the domain and the cell count.
    domain_exits: list = field(default_factory=list)
    # Whether the reach sets stay where the model was validated (percver.validate.verifiable.validity).
    validity: Optional[str] = None
    # Cells the engine left unknown that the splitter then replaced (halves, retries), the first
    # few of each part: evidence for hints() when the cells that remain carry none (a time limit).
    lost: list = field(default_factory=list)

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

    def hints(self, loop: Optional[ClosedLoop] = None) -> list:
        """What to try when the verdict is unknown (:func:`percver.verification.advice.hints`)."""
        from percver.verification.advice import hints

        return hints(self, loop)

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
        doc = {
            "states": self.states,
            "init": self.init,
            "seconds": self.seconds,
            "settings": self.settings,
            "verdict": self.verdict,
            "coverage": self.coverage,
            "cells": [c.to_dict() for c in self.cells],
            "domain_exits": self.domain_exits,
            "lost": [c.to_dict() for c in self.lost],
        }
        text = json.dumps(doc)
        if path:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_json(cls, text_or_path: str) -> "Result":
        text = Path(text_or_path).read_text() if os.path.exists(text_or_path) else text_or_path
        d = json.loads(text)
        return cls(
            d["states"],
            {k: tuple(v) for k, v in d["init"].items()},
            [Cell.from_dict(c) for c in d["cells"]],
            d["seconds"],
            d["settings"],
            d.get("domain_exits", []),
            lost=[Cell.from_dict(c) for c in d.get("lost", [])],
        )

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
                # Edges drawn too: a band narrower than a pixel (a 5e-5 cell) still shows as a line.
                ax.fill_between(np.arange(len(b)), b[:, j, 0], b[:, j, 1], facecolor=colours[c.verdict], alpha=0.3, linewidth=0)
                ax.plot(np.arange(len(b)), b[:, j, :], color=colours[c.verdict], linewidth=0.8)
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
