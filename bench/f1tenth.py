"""Benchmark (run by hand): the F1/10 row of Table 1 (``pv.cases.f1tenth.verify``), the paper's
uniform cells against the adaptive default, back to back in one process.

Over ``--y1 LO HI`` (default the whole initial range [0.65, 0.85]): first the paper's 5e-5 cells
(``cell=PAPER_CELL``: every cell reboxed, 64 in-cell splits), then the defaults (the adaptive
splitter, which picks the cells and rebox by itself). Writes bench/results/f1tenth.json with each
run's wall time, CPU seconds of this process, cells, coverage and the load average before and
after (the machine is shared: the ratio of the two runs is what compares).

    python bench/f1tenth.py [--y1 0.75 0.76] [--workers 2] [--only adaptive]
"""

import argparse
import json
import os
import time
from pathlib import Path

from percver.cases.f1tenth import verification as V

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "f1tenth.json"
RUNS = {"paper cells": {"cell": V.PAPER_CELL}, "adaptive": {}}


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def run(y1, workers: int, options: dict) -> dict:
    load, wall, cpu0 = os.getloadavg(), time.time(), cpu()
    res = V.verify(tuple(y1), workers=workers, **options)
    row = V.row(res)
    return {
        "wall_seconds": time.time() - wall,
        "cpu_seconds": cpu() - cpu0,
        "cells": len(res.cells),
        "coverage": res.coverage,
        "rebox_cells": sum(bool(c.options.get("rebox")) for c in res.cells),
        "load_before": load,
        "load_after": os.getloadavg(),
        "row": row,
        "cells_y1": sorted([c.box["y1"][0], c.box["y1"][1], c.verdict, round(c.seconds, 3), c.branches, c.options] for c in res.cells),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--y1", nargs=2, type=float, default=list(V.INIT["y1"]))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", choices=list(RUNS), help="one of the two runs")
    args = ap.parse_args()
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    key = f"{args.y1[0]:g},{args.y1[1]:g}"
    # With --only, the other run of an earlier entry stays (each run carries its own date); a
    # ratio is only of two runs made together.
    entry = {k: v for k, v in doc.get(key, {}).items() if k in RUNS} if args.only else {}
    entry.update({"y1": args.y1, "workers": args.workers, "cpu_count": os.cpu_count()})
    for name, options in RUNS.items():
        if args.only in (None, name):
            entry[name] = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), **run(args.y1, args.workers, options)}
            r = entry[name]
            print(
                f"{name:12s} cells {r['cells']:5d}  coverage {100 * r['coverage']:.2f}%  wall {r['wall_seconds']:.1f} s  cpu {r['cpu_seconds']:.1f} s"
            )
    if args.only is None:
        entry["ratio_wall"] = entry["adaptive"]["wall_seconds"] / entry["paper cells"]["wall_seconds"]
        entry["ratio_cpu"] = entry["adaptive"]["cpu_seconds"] / entry["paper cells"]["cpu_seconds"]
    doc[key] = entry
    OUT.write_text(json.dumps(doc, indent=1))
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
