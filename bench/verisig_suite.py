"""Benchmark (run by hand): the Verisig 2.0 suite from its own Flow* model files.

Each benchmark is loaded with ``pv.load_verisig`` and verified with the file's initial
set, horizon and property (``problem.verify()``: one cell unless --split is given). Writes
bench/results/verisig_suite.json: median wall seconds of 3 runs (falsification included), the
load time, verdict, cells, and the ratio against Verisig 2.0's times measured on this machine
kind (../shared/anchors/README.md; Verisig is not installed here, so those are the baseline).

    python bench/verisig_suite.py [--repeat 3] [--only ex1_tanh ...]

Every benchmark runs at the defaults. F1/10 (which Verisig 2.0 did not finish in 40 minutes)
needs ``rebox``, which the adaptive splitter picks by itself: the whole set is lost at step 31
(a division by a range containing zero) and its retry with ``rebox`` verifies it.
"""

import argparse
import json
import statistics
import time
import warnings
from pathlib import Path

import percver as pv

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT.parent / "shared" / "data" / "verisig2_suite"

# name -> (model, network)
BENCHMARKS = {
    "mountain_car_small": ("MC_small_sig_verisig.model", "sig16x16.yml"),
    "ex1_tanh": ("ex1_tanh_verisig.model", "tanh20x20.yml"),
    "ex2_sig": ("ex2_sig_verisig.model", "sig20x20.yml"),
    "ex3_tanh": ("ex3_tanh_verisig.model", "tanh20x20.yml"),
    "f1tenth": ("f1tenth_tanh_verisig.model", "tanh64x64.yml"),
}

# ../shared/anchors/README.md: measured on this machine kind unless marked published.
ANCHORS = {
    "mountain_car_small": {"verisig2_s": 36.7, "polar_s_published": 4.1},
    "ex1_tanh": {"verisig2_s": 36.8},
    "ex2_sig": {"verisig2_s": 5.8},
    "ex3_tanh": {"verisig2_s": 27.8},
    "f1tenth": {"verisig2_s": None, "verisig2_note": "not finished after 40 min (step 31 of 50)"},
}


def load(name: str):
    model, net = BENCHMARKS[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # f1tenth's stray brace; recorded in problem.notes
        return pv.load_verisig(str(SUITE / name / model), networks=[str(SUITE / name / net)])


def run(name: str, repeat: int, split: dict) -> dict:
    t = time.perf_counter()
    problem = load(name)
    load_s = time.perf_counter() - t
    seconds, res = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        res = problem.verify(progress=False, split=split or None)
        seconds.append(time.perf_counter() - t)
    row = {
        "benchmark": name,
        "kind": problem.kind,
        "states": problem.states,
        "steps": problem.steps,
        "period": problem.period,
        "init": problem.init,
        "goal": None if problem.goal is None else str(problem.goal),
        "within": problem.within,
        "safe": [str(c) for c in problem.safe],
        "verdict": res.verdict,
        "cells": len(res.cells),
        "coverage": res.coverage,
        "branches": sum(c.branches for c in res.cells),
        "reasons": [c.reason for c in res.cells if c.reason],
        "seconds_median": statistics.median(seconds),
        "seconds_all": seconds,
        "load_seconds": load_s,
        "nn_seconds": sum(c.nn_seconds for c in res.cells),
        "notes": problem.notes,
        "anchor": ANCHORS[name],
        "options": [c.options for c in res.cells],
    }
    base = ANCHORS[name].get("verisig2_s")
    if base and res.verdict == "verified":
        row["speedup_vs_verisig2"] = base / row["seconds_median"]
    elif name == "f1tenth" and res.verdict == "verified":
        row["speedup_vs_verisig2_lower_bound"] = 40 * 60 / row["seconds_median"]  # Verisig 2.0 had not finished at 40 min
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "verisig_suite.json"))
    args = ap.parse_args()
    names = args.only or list(BENCHMARKS)
    rows = []
    for name in names:
        row = run(name, args.repeat, {})
        rows.append(row)
        ratio = f"{row['speedup_vs_verisig2']:.0f}x" if "speedup_vs_verisig2" in row else "-"
        print(
            f"{name:20s} {row['verdict']:9s} cells {row['cells']:3d}  {row['seconds_median']:8.3f} s  "
            f"(load {row['load_seconds']:.2f} s)  vs Verisig 2.0: {ratio}",
            flush=True,
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"date": time.strftime("%Y-%m-%d"), "repeat": args.repeat, "results": rows}
    out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
