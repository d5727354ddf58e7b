"""Benchmark (run by hand): the engine's cost per cell on a fixed sample of a Mountain Car row's cells.

Takes ``--cells`` cells spread evenly over the row's layout (``verification.LAYOUT``, or
``OLD_LAYOUT`` of ``bench/mountain_car.py`` for blur; all bands' cells in order, so the sample
crosses the bands: edges, valley, wall, low and high contrast) and
runs each alone, one after another on one thread, with its band's order and in-cell splits, no
refinement and no falsification: the per-cell CPU seconds (``time.process_time``, the whole
process), engine seconds, verdict and branches of the same cells from run to run. Two builds are
compared by running this script with each, back to back (the machine is shared: note the load).
Writes ``bench/results/mountain_car_probe.json`` (one entry per ``--label``, merged).

    python bench/mountain_car_probe.py --row composite --cells 30 --label before
    python bench/mountain_car_probe.py --compare before after
"""

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

RESULTS = Path(__file__).resolve().parent / "results" / "mountain_car_probe.json"


def sample(row: str, count: int) -> list:
    """``(cell box dict, band)`` for ``count`` cells evenly spread over the row's layout."""
    from percver.cases.mountain_car import verification
    from percver.sets import Box

    from mountain_car import OLD_LAYOUT  # the bands the library no longer has (blur)

    layout = verification._layout("paper", None, row) or OLD_LAYOUT[row]
    bands = verification._grid(verification.initial_set(row), layout, {})
    cells = []
    for box, band in bands:
        names = list(box)
        cells += [(dict(zip(names, c.bounds)), band) for c in Box(names, [box[n] for n in names]).split(band.cells)]
    picks = sorted({round(k * (len(cells) - 1) / max(1, count - 1)) for k in range(count)})
    return [cells[k] for k in picks]


def run(row: str, count: int) -> dict:
    import percver as pv
    from percver.cases.mountain_car import verification

    loop = verification.closed_loop(row, "paper")
    spec = verification.specification()
    out = []
    for box, band in sample(row, count):
        cpu = time.process_time()
        result = pv.verify(
            loop, box, **spec, split={"p": 1}, order=band.order, max_splits=band.max_splits, workers=1, falsify=0, progress=False
        )
        cell = result.cells[0]
        out.append(
            {
                "box": box,
                "order": band.order,
                "cpu_seconds": round(time.process_time() - cpu, 3),
                "engine_seconds": round(cell.seconds, 3),
                "verdict": cell.verdict,
                "branches": cell.branches,
            }
        )
        print(f"{len(out):3d} {out[-1]['cpu_seconds']:7.2f} s {cell.verdict:9s} branches {cell.branches}", flush=True)
    return {"row": row, "cells": out, "cpu_seconds": round(sum(c["cpu_seconds"] for c in out), 2)}


def compare(doc: dict, before: str, after: str) -> None:
    a, b = doc[before], doc[after]
    same = [x["verdict"] == y["verdict"] for x, y in zip(a["cells"], b["cells"])]
    branches = [sum(c["branches"] for c in run["cells"]) for run in (a, b)]
    ratio = a["cpu_seconds"] / b["cpu_seconds"]
    print(f"{before}: {a['cpu_seconds']:.1f} CPU s, {after}: {b['cpu_seconds']:.1f} CPU s, ratio {ratio:.2f}x")
    print(f"verdicts identical: {all(same)} ({sum(same)}/{len(same)}); branches {branches[0]} -> {branches[1]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--row", default="composite", choices=["contrast", "blur", "composite"])
    parser.add_argument("--cells", type=int, default=30)
    parser.add_argument("--label", default="run")
    parser.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    args = parser.parse_args()
    doc = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    if args.compare:
        compare(doc, *(f"{args.row}/{label}" for label in args.compare))
        return
    start = {"time": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), "loadavg_start": os.getloadavg()}
    entry = run(args.row, args.cells)
    doc[f"{args.row}/{args.label}"] = {**start, **entry, "loadavg_end": os.getloadavg()}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(doc, indent=1))
    print(f"total {entry['cpu_seconds']:.1f} CPU s over {len(entry['cells'])} cells")


if __name__ == "__main__":
    main()
