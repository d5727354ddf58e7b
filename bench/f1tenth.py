"""Benchmark (run by hand): the F1/10 row of Table 1 (``pv.cases.f1tenth.verify``).

Part 1 (``--probes``): narrow cells (y1 width --probe-width from 0.75) in both modes, without and
with the classifier/denoiser: steps reached, seconds per step, and the reason a cell is lost.
Part 2: the campaign over ``--y1 LO HI`` (default the whole initial range [0.65, 0.85]) in the
paper's 5e-5 cells, stepwise mode, with a coverage map; ``--sample N`` runs N cells spread over
the range instead and projects the whole campaign's wall time. Writes bench/results/f1tenth.json with
the load average before and after each part (the machine is shared).

    python bench/f1tenth.py [--y1 0.65 0.85] [--cell 5e-5] [--sample 200] [--workers 2] [--journal f1.jsonl] [--no-probes]
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from percver.cases.f1tenth import verification as V

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "f1tenth.json"


def load() -> list:
    return [round(x, 2) for x in os.getloadavg()]


def probe(mode: str, noise_model: bool, width: float, lo: float = 0.75) -> dict:
    started = time.perf_counter()
    res = V.verify((lo, lo + width), cell=width, mode=mode, noise_model=noise_model, workers=1, progress=False, falsify=0)
    c = res.cells[0]
    widths = [[hi - lo for lo, hi in b] for b in c.boxes]
    return {
        "mode": mode,
        "classifier": noise_model,
        "y1": [lo, lo + width],
        "verdict": c.verdict,
        "steps_done": c.steps_done,
        "seconds": c.seconds,
        "seconds_per_step": c.seconds / max(c.steps_done, 1),
        "nn_seconds": c.nn_seconds,
        "branches": c.branches,
        "reason": c.reason,
        "wall_s": time.perf_counter() - started,
        "box_widths": {k: widths[k] for k in range(0, len(widths), 5)},
    }


def coverage_map(res) -> list:
    return [
        [c.box["y1"][0], c.box["y1"][1], c.verdict, round(c.seconds, 3), c.branches, c.steps_done, c.reason]
        for c in sorted(res.cells, key=lambda c: c.box["y1"][0])
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--y1", nargs=2, type=float, default=list(V.INIT["y1"]))
    ap.add_argument("--cell", type=float, default=V.PAPER_CELL)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-splits", type=int, default=16)
    ap.add_argument("--journal")
    ap.add_argument("--sample", type=int, help="verify only this many cells spread over the range (an estimate)")
    ap.add_argument("--falsify", type=int, default=8, help="simulations per cell before verifying it")
    ap.add_argument("--probe-width", type=float, default=1e-3)
    ap.add_argument("--no-probes", action="store_true")
    ap.add_argument("--no-campaign", action="store_true")
    args = ap.parse_args()
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    if not args.no_probes:
        doc["probes"] = {"load_before": load(), "runs": []}
        for mode in ("engine", "stepwise"):
            for noise_model in (False, True):
                for width in (args.probe_width, V.PAPER_CELL):
                    r = probe(mode, noise_model, width)
                    print(
                        f"{mode:8s} classifier={noise_model!s:5s} width={width:g}: {r['verdict']} after {r['steps_done']} steps, "
                        f"{r['seconds_per_step']:.3f} s/step, {r['branches']} branches; {r['reason']}"
                    )
                    doc["probes"]["runs"].append(r)
        doc["probes"]["load_after"] = load()
    if not args.no_campaign:
        before = load()
        res = V.verify(
            tuple(args.y1),
            cell=args.cell,
            workers=args.workers,
            journal=args.journal,
            max_splits=args.max_splits,
            falsify=args.falsify,
            sample=args.sample,
            mode="stepwise",
        )
        print(V.table(res))
        total = int(round((args.y1[1] - args.y1[0]) / args.cell))
        row = V.row(res)
        doc["campaign"] = {
            "y1": args.y1,
            "cell": args.cell,
            "workers": args.workers,
            "max_splits": args.max_splits,
            "falsify": args.falsify,
            "sample": args.sample,
            "cells_in_range": total,
            "sampled_coverage": row["verified"] / row["intervals"],
            "projected_wall_s": row["wall_seconds"] * total / row["intervals"],
            "load_before": before,
            "load_after": load(),
            "row": row,
            "paper_row": V.PAPER_ROW,
            "published": V.published(),
            "table": V.table(res),
            "cells": coverage_map(res),
            "unknown_steps": np.bincount([c.steps_done for c in res.cells if c.verdict == "unknown"], minlength=V.STEPS + 1).tolist(),
        }
    OUT.write_text(json.dumps(doc, indent=1))
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
