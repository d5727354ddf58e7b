"""Benchmark (run by hand): the F1/10 row in the engine (the paper's uniform cells, ``rebox=True``).

Verifies ``--sample`` paper-sized cells (y1 width 5e-5) spread evenly over y1 in [0.65, 0.85],
``--jobs`` processes at once, and writes bench/results/f1tenth_engine.json: per-cell verdict,
time, network time and branches, with the load average (the machine is shared).

``--full`` runs the whole row instead: y1 in [0.65, 0.85] in cells of ``--cell`` metres, unknown
cells bisected down to the paper's 5e-5 (``refine=True``), journaled (a killed run resumes), and
records Table 1's columns under "full" in the same file.

    python bench/f1tenth_engine.py [--sample 200] [--jobs 2]
    python bench/f1tenth_engine.py --full [--cell 1e-4] [--journal /tmp/f1tenth_full.jsonl]
"""

import argparse
import json
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

CELL = 5e-5
OUT = Path(__file__).resolve().parent / "results" / "f1tenth_engine.json"


def one(lo: float) -> dict:
    from percver.cases.f1tenth import verification as fv

    t = time.time()
    cell = fv.verify((lo, lo + CELL), cell=CELL, progress=False, workers=1, falsify=4).cells[0]
    return {
        "y1": lo,
        "verdict": cell.verdict,
        "seconds": cell.seconds,
        "nn_seconds": cell.nn_seconds,
        "branches": cell.branches,
        "wall": time.time() - t,
        "reason": cell.reason,
    }


def full(cell: float, jobs: int, journal: str) -> dict:
    """The whole initial range through ``pv.verify`` (one campaign, ``jobs`` worker threads)."""
    from percver.cases.f1tenth import verification as fv

    load0, t = os.getloadavg(), time.time()
    result = fv.verify(cell=cell, workers=jobs, refine=True, min_width={"y1": CELL}, journal=journal, progress=True)
    table = fv.table(result)
    print(table)
    cells = [
        {"y1": c.box["y1"], "verdict": c.verdict, "seconds": c.seconds, "branches": c.branches, "reason": c.reason} for c in result.cells
    ]
    return {
        "row": fv.row(result),
        "cell": cell,
        "min_width": CELL,
        "table": table,
        "session_wall_seconds": time.time() - t,
        "load_start": load0,
        "load_end": os.getloadavg(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "cells": cells,
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sample", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--cell", type=float, default=1e-4)
    ap.add_argument("--journal", default="/tmp/f1tenth_full.jsonl")
    args = ap.parse_args()
    if args.full:
        doc = json.loads(OUT.read_text()) if OUT.exists() else {}
        doc["full"] = full(args.cell, args.jobs, args.journal)
        OUT.write_text(json.dumps(doc, indent=1))
        return
    starts = 0.65 + CELL * np.unique(np.linspace(0, 3999, args.sample).round())
    load0, t = os.getloadavg(), time.time()
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, [float(a) for a in starts]))
    wall = time.time() - t
    summary = {
        "cells": len(rows),
        "verified": sum(r["verdict"] == "verified" for r in rows),
        "avg_seconds": statistics.mean(r["seconds"] for r in rows),
        "avg_nn_seconds": statistics.mean(r["nn_seconds"] for r in rows),
        "avg_branches": statistics.mean(r["branches"] for r in rows),
        "wall_seconds": wall,
        "projected_full_range_wall_s": statistics.mean(r["seconds"] for r in rows) * 4000 / args.jobs,
        "load_start": load0,
        "load_end": os.getloadavg(),
        "date": time.strftime("%Y-%m-%d"),
    }
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    OUT.write_text(json.dumps({**doc, "summary": summary, "rows": rows}, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
