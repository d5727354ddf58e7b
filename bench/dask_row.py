"""Benchmark (run by hand): a Mountain Car row of Table 1 on this machine's 2 cores, locally
(``workers=2``) and on a Dask ``LocalCluster(n_workers=2, threads_per_worker=1)``, back to back in
one run, each with journals; the ratio of their wall times, whether their cells and verdicts are
the same, and every journaled cell (refined attempts too, in each band's journal order) for
``bench/scale.py --model``. Appends to ``bench/results/dask_row.json`` (a list of runs per row).

    python bench/dask_row.py [--rows blur contrast] [--first local|dask]
"""

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread: falsification's float simulation otherwise spins threads against the workers.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
from percver.cases.mountain_car import verification  # noqa: E402
from percver.verification.journal import journal_cells  # noqa: E402

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
from mountain_car import _cpu  # noqa: E402

OUT = ROOT / "results" / "dask_row.json"


def journaled(folder: Path) -> list:
    """Every cell of the run's journals (band 0's first), as [box {state: [lo, hi]}, verdict, engine s, branches]."""
    paths = sorted(folder.glob("*.jsonl"), key=lambda p: int(p.stem.rsplit("band", 1)[-1]) if "band" in p.stem else 0)
    return [[c.box, c.verdict, round(c.seconds, 4), c.branches] for path in paths for c in journal_cells(path)]


def cpu_seconds() -> float:
    """CPU time of this process so far, all threads."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def one(noise: str, backend: str, client) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        journal = str(Path(tmp) / "row.jsonl")
        kwargs = {"executor": client} if backend == "dask" else {"workers": 2}
        workers = client.run(cpu_seconds)
        load, start, cpu = os.getloadavg(), time.perf_counter(), cpu_seconds()
        result = verification.verify(noise, journal=journal, progress=False, **kwargs)
        wall, driver_cpu = time.perf_counter() - start, cpu_seconds() - cpu
        after = client.run(cpu_seconds)
        attempts = journaled(Path(tmp))
    return {
        "wall_seconds": wall,
        # CPU of the calling process (locally it runs the cells too; it hosts the scheduler) and
        # of the workers (idle in the local run); a worker that restarted is left out.
        "driver_cpu_seconds": driver_cpu,
        "workers_cpu_seconds": sum(after[w] - workers[w] for w in after if w in workers),
        "load_average_start": load,
        "load_average_end": os.getloadavg(),
        "coverage": verification.table_row(result)["coverage"],
        "verdicts": {v: sum(c.verdict == v for c in result.cells) for v in ("verified", "unknown", "falsified")},
        "cells": len(result.cells),
        "engine_seconds_final_cells": sum(c.seconds for c in result.cells),
        "engine_seconds_all_attempts": sum(a[2] for a in attempts),
        "final": sorted((json.dumps(c.box, sort_keys=True), c.verdict) for c in result.cells),
        "attempts": attempts,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="+", default=["blur"], choices=["contrast", "blur", "composite"])
    parser.add_argument("--first", default="local", choices=["local", "dask"])
    args = parser.parse_args()
    from distributed import Client, LocalCluster

    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    order = [args.first, "dask" if args.first == "local" else "local"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, Client(cluster) as client:
        for noise in args.rows:
            runs = {}
            for backend in order:
                runs[backend] = one(noise, backend, client)
                print(f"{noise} {backend}: {runs[backend]['wall_seconds']:.1f} s, coverage {runs[backend]['coverage']:.4f}", flush=True)
            same = runs["local"]["final"] == runs["dask"]["final"]
            for r in runs.values():
                del r["final"]
            doc.setdefault(noise, []).append(
                {
                    "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                    "cpu": _cpu(),
                    "cpu_count": os.cpu_count(),
                    "order": order,
                    "dask_over_local": runs["dask"]["wall_seconds"] / runs["local"]["wall_seconds"],
                    "same_cells_and_verdicts": same,
                    **runs,
                }
            )
            ratio = doc[noise][-1]["dask_over_local"]
            print(f"{noise}: dask / local = {ratio:.3f}, same cells and verdicts: {same}", flush=True)
            OUT.write_text(json.dumps(doc, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
