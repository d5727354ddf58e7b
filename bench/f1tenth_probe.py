"""Benchmark (run by hand): the engine's cost per F1/10 cell, on a fixed sample (issue 30).

``--cells`` paper-sized cells (y1 width 5e-5, the other states at the original model's start)
spread evenly over y1 in [0.65, 0.85], run one after another in one thread straight through
``_core.verify_cells`` with the row's settings (``rebox=True``, 64 in-cell splits and forks,
``CELL_ORDER`` of ``pv.cases.f1tenth.verification`` unless ``--order``): no falsification, no
campaign, so the CPU seconds are the engine's. ``--y1`` names the cells' lower ends instead.
Records per cell the verdict, steps, branches and CPU seconds of this process, with the load
average, into bench/results/f1tenth_probe.json under ``--label``; ``--compare A B`` prints the
per-cell ratio of two labels and whether their verdicts agree.

    python bench/f1tenth_probe.py --label before [--cells 40]
    python bench/f1tenth_probe.py --compare before after
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results" / "f1tenth_probe.json"
CELL = 5e-5


def starts(count: int) -> list:
    """The cells' lower y1: every (4000 / count)-th of the row's 4,000 paper cells."""
    return [float(0.65 + CELL * k) for k in np.unique(np.linspace(0, 3999, count).round())]


def problem():
    """The row's loop and property compiled as ``pv.verify`` compiles them."""
    from percver.cases.f1tenth import verification as fv
    from percver.verification.property import Property

    loop = fv.closed_loop().with_held_parameters()
    p = fv.property_()
    prop = Property(loop, p["safe"], None, p["goal"], p["within"], fv.STEPS)
    safe, goal = prop.rust()
    return loop, loop.compile(safe=safe, goal=goal, within=True, steps=fv.STEPS)


def probe(lows: list, order=None) -> dict:
    from percver import _core
    from percver.cases.f1tenth import verification as fv

    loop, compiled = problem()
    settings = _core.CellSettings(rebox=True, max_splits=64, order=order or fv.CELL_ORDER)
    cells = []
    for lo in lows:
        box = loop.initial_box({**fv.INIT, "y1": (lo, lo + CELL)})
        cells.append([tuple(map(float, b)) for b in box.bounds])
    rows, clock = [], [time.process_time()]

    def done(i, outcome):
        now = time.process_time()
        rows.append(
            {
                "y1": cells[i][loop.states.index("y1")][0],
                "verdict": outcome.verdict,
                "steps_done": outcome.steps_done,
                "branches": outcome.branches,
                "cpu_seconds": now - clock[0],
                "nn_seconds": outcome.nn_seconds,
            }
        )
        clock[0] = now
        return True

    load0, wall = os.getloadavg(), time.time()
    _core.verify_cells(compiled, cells, done, settings, workers=1)
    cpu = [r["cpu_seconds"] for r in rows]
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "order": settings.order,
        "cells": len(rows),
        "verified": sum(r["verdict"] == "verified" for r in rows),
        "cpu_seconds": sum(cpu),
        "mean_cpu_seconds": float(np.mean(cpu)),
        "median_cpu_seconds": float(np.median(cpu)),
        "wall_seconds": time.time() - wall,
        "load_start": load0,
        "load_end": os.getloadavg(),
        "rows": rows,
    }


def compare(doc: dict, a: str, b: str) -> dict:
    ra, rb = ({r["y1"]: r for r in doc[k]["rows"]} for k in (a, b))
    same = sorted(ra) == sorted(rb) and all(ra[y]["verdict"] == rb[y]["verdict"] for y in ra)
    ratios = [rb[y]["cpu_seconds"] / ra[y]["cpu_seconds"] for y in ra if y in rb]
    return {
        "labels": [a, b],
        "verdicts_identical": same,
        "branches": [sum(r["branches"] for r in ra.values()), sum(r["branches"] for r in rb.values())],
        "cells_with_other_branches": sum(ra[y]["branches"] != rb[y]["branches"] for y in ra if y in rb),
        "total_ratio": doc[b]["cpu_seconds"] / doc[a]["cpu_seconds"],
        "median_cell_ratio": float(np.median(ratios)),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=int, default=40)
    ap.add_argument("--label", default="run")
    ap.add_argument("--y1", type=float, nargs="+", help="the cells' lower y1 instead of the even spread")
    ap.add_argument("--order", type=int, help="Taylor order (default: the row's, CELL_ORDER)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"))
    args = ap.parse_args()
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    if args.compare:
        print(json.dumps(compare(doc, *args.compare), indent=1))
        return
    doc[args.label] = probe(args.y1 or starts(args.cells), args.order)
    OUT.write_text(json.dumps(doc, indent=1))
    summary = {k: v for k, v in doc[args.label].items() if k != "rows"}
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
