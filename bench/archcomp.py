"""Benchmark (run by hand): the ARCH-COMP 2024 AINNCS problems of examples/archcomp/, each in a
child process with a wall-clock limit, against the verdict JuliaReach's repeatability package
asserts. Writes bench/results/archcomp.json (rows of earlier runs not selected are kept): verdict,
JuliaReach's verdict, wall and CPU seconds (user + system of the child, all threads), cell counts,
the deepest step an unknown cell reached, whether a counterexample replays, and the settings.

    python bench/archcomp.py                      # all
    python bench/archcomp.py tora acc:tanh        # a file, or file:variant
    python bench/archcomp.py --limit 600 --list
    nice -n 10 python bench/archcomp.py inverted_two_link_pendulum:less_robust --journal /tmp/j
                                                  # cells journaled: a rerun resumes
    python bench/archcomp.py --defaults 60         # as a new user would: no settings, 60 s each
"""

import argparse
import datetime
import importlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "archcomp"
RESULTS = ROOT / "bench" / "results" / "archcomp.json"


def module(name: str):
    sys.path.insert(0, str(EXAMPLES))
    return importlib.import_module(name)


def benchmarks() -> list:
    """(file, variant, JuliaReach's verdict) of every example."""
    out = []
    for path in sorted(EXAMPLES.glob("[!_]*.py")):
        for variant, expected in module(path.stem).VARIANTS.items():
            out.append((path.stem, variant, expected))
    return out


def label(name: str, variant: str) -> str:
    return f"{name}:{variant}" if variant else name


# The example's own choices of how to verify, left out with --defaults (the problem stays).
TUNING = ("split", "refine", "min_width", "splitter", "order", "max_splits", "rebox", "state_symbols", "timeout_per_cell")


def one(name: str, variant: str, journal: Optional[str] = None, defaults: Optional[float] = None) -> dict:
    """Runs one benchmark in this process; the row of the results file. With ``journal`` (a
    directory) its finished cells are journaled there, and a rerun resumes from them. With
    ``defaults`` (seconds) the example's settings are left out: ``pv.verify``'s defaults, with
    that ``time_limit``, and the row records what ``Result.hints`` says to try."""
    import numpy as np  # noqa: F401 - imported before timing, as percver is

    import percver as pv

    examples = module("_common")
    bench = module(name)
    loop, kwargs = bench.problem(variant)
    if defaults is not None:
        kwargs = {k: v for k, v in kwargs.items() if k not in TUNING} | {"time_limit": defaults}
    if journal:
        Path(journal).mkdir(parents=True, exist_ok=True)
        kwargs["journal"] = str(Path(journal) / f"{label(name, variant).replace(':', '-')}.jsonl")
    settings = {k: v for k, v in kwargs.items() if k in (*TUNING, "steps", "time_limit")}
    start, usage = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    result = pv.verify(loop, progress=False, **kwargs)
    wall = time.perf_counter() - start
    end = resource.getrusage(resource.RUSAGE_SELF)
    cells = {v: sum(c.verdict == v for c in result.cells) for v in ("verified", "unknown", "falsified")}
    row = {
        "verdict": result.verdict,
        "wall_s": round(wall, 2),
        "cpu_s": round(end.ru_utime - usage.ru_utime + end.ru_stime - usage.ru_stime, 2),
        "sys_s": round(end.ru_stime - usage.ru_stime, 2),
        "cells": cells,
        "settings": settings,
    }
    unknown = [c for c in result.cells if c.verdict == "unknown"]
    if unknown:
        row["deepest_step"] = min(c.deepest_step for c in unknown)
        row["reason"] = unknown[0].reason
        row["hints"] = [str(h) for h in result.hints(loop)]
    if result.counterexample is not None:
        cex = result.counterexample
        row["counterexample"] = {
            "initial": cex.initial,
            "step": cex.step,
            "violated": cex.violated,
            "replays": examples.replays(loop, cex, kwargs),
        }
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("select", nargs="*", help="file names or file:variant (default: all)")
    parser.add_argument("--limit", type=float, default=900.0, help="wall seconds per benchmark (default 900)")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    parser.add_argument("--journal", help="directory of journals (one per benchmark): a rerun resumes the finished cells")
    parser.add_argument(
        "--defaults",
        type=float,
        metavar="SECONDS",
        help="pv.verify's defaults instead of the example's settings, with this time_limit (results: archcomp_defaults_<SECONDS>s.json)",
    )
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        name, _, variant = args.one.partition(":")
        print(json.dumps(one(name, variant, args.journal, args.defaults)))
        return
    results = RESULTS if args.defaults is None else RESULTS.with_name(f"archcomp_defaults_{args.defaults:g}s.json")
    chosen = [b for b in benchmarks() if not args.select or b[0] in args.select or label(b[0], b[1]) in args.select]
    if args.list:
        for name, variant, expected in chosen:
            print(f"{label(name, variant):32} JuliaReach: {expected}")
        return
    doc = json.loads(results.read_text()) if results.exists() else {"benchmarks": {}}
    for name, variant, expected in chosen:
        key = label(name, variant)
        print(f"{key} ...", flush=True)
        before = os.getloadavg()[0]
        start = time.perf_counter()
        try:
            extra = ["--journal", args.journal] if args.journal else []
            extra += [] if args.defaults is None else ["--defaults", str(args.defaults)]
            done = subprocess.run(
                [sys.executable, __file__, "--one", key, *extra], capture_output=True, text=True, timeout=args.limit, check=False
            )
            row = (
                json.loads(done.stdout.strip().splitlines()[-1])
                if done.returncode == 0
                else {"verdict": "error", "returncode": done.returncode, "error": done.stderr[-2000:]}
            )
        except subprocess.TimeoutExpired:
            row = {"verdict": "timeout", "wall_s": round(time.perf_counter() - start, 2)}
        row.update(juliareach=expected, load_before=round(before, 2), date=datetime.date.today().isoformat())
        doc["benchmarks"][key] = row
        doc["machine"] = {"cpus": os.cpu_count(), "note": "shared with other agents; load_before is the 1-min load average"}
        results.write_text(json.dumps(doc, indent=1) + "\n")
        print(
            f"  {row['verdict']} (JuliaReach: {expected}) {row.get('wall_s', '-')} s wall, {row.get('cpu_s', '-')} s CPU, cells {row.get('cells')}",
            flush=True,
        )


if __name__ == "__main__":
    main()
