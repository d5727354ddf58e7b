"""Benchmark (run by hand): cells per second on 1 and 2 local workers, rayon against a Dask
LocalCluster, in one run; Dask's overhead per task; time to resume a 1,000-cell journal.

Problem: the paper's image-based Mountain Car with contrast noise (generator -> contraster ->
estimator -> sig16x16 controller, the authors' networks), 150 steps, goal p >= 0.45 within the
horizon, on one paper-sized position cell p in [-0.5, -0.49975] with the contrast delta in
[0.3, 0.3 + 0.05 * cells] split into cells of width 0.05. Writes bench/results/scale.json.

    python bench/scale.py [--cells 24] [--repeat 2] [--resume-cells 1000] [--tasks 400]
"""

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread: falsification's float simulation otherwise spins extra threads against the
# workers on 2 cores (10x slower measured under load). Set before numpy loads; workers inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import percver as pv  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from closed_loops import mountain_car, mountain_car_images  # noqa: E402  (the test suite's loops)
from test_distributed import tiny_loop  # noqa: E402


def contrast_slice(cells: int) -> dict:
    p = pv.variables("p")
    return dict(
        init={"p": (-0.5, -0.49975), "v": (0, 0), "delta": (0.3, 0.3 + 0.05 * cells)},
        steps=150,
        goal=p >= 0.45,
        within=True,
        split={"delta": cells},
        progress=False,
    )


def timed(run) -> tuple:
    start = time.perf_counter()
    result = run()
    return time.perf_counter() - start, result


def cluster(workers: int):
    from distributed import Client, LocalCluster

    start = time.perf_counter()
    c = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return c, Client(c), time.perf_counter() - start


def throughput(cells: int, repeat: int) -> dict:
    """Best of `repeat` runs per configuration, rayon and Dask alternating (the machine is shared:
    the best run is the one least disturbed)."""
    loop, kwargs = mountain_car_images(), contrast_slice(cells)
    rows, verdicts = {}, {}
    for workers in (1, 2):
        lc, client, startup = cluster(workers)
        with lc, client:
            runs = {"rayon": lambda: pv.verify(loop, workers=workers, **kwargs), "dask": lambda: pv.verify(loop, executor=client, **kwargs)}
            for k in range(repeat):
                for backend in ("rayon", "dask") if k % 2 == 0 else ("dask", "rayon"):
                    seconds, res = timed(runs[backend])
                    key = f"{backend}_{workers}"
                    row = {
                        "seconds": seconds,
                        "cells_per_second": cells / seconds,
                        "verdict": res.verdict,
                        "engine_seconds_per_cell": statistics.mean(c.seconds for c in res.cells),
                        "peak_rss_mb": max(c.peak_rss_mb for c in res.cells),
                        "load_average": os.getloadavg()[0],
                    }
                    rows.setdefault(key, {"runs": []})["runs"].append(row)
                    verdicts[f"{key}_{k}"] = sorted((c.box["delta"], c.verdict) for c in res.cells)
        rows[f"dask_{workers}"]["cluster_start_seconds"] = startup
        for backend in ("rayon", "dask"):
            row = rows[f"{backend}_{workers}"]
            row["cells_per_second"] = max(r["cells_per_second"] for r in row["runs"])
        print(
            f"{workers} worker(s): rayon {rows[f'rayon_{workers}']['cells_per_second']:.3f} cells/s, "
            f"dask {rows[f'dask_{workers}']['cells_per_second']:.3f} cells/s",
            flush=True,
        )
    for backend in ("rayon", "dask"):
        rows[f"{backend}_efficiency_2"] = rows[f"{backend}_2"]["cells_per_second"] / (2 * rows[f"{backend}_1"]["cells_per_second"])
    for workers in (1, 2):
        rows[f"dask_over_rayon_{workers}"] = rows[f"dask_{workers}"]["cells_per_second"] / rows[f"rayon_{workers}"]["cells_per_second"]
    rows["same_verdicts"] = len({json.dumps(v) for v in verdicts.values()}) == 1
    return rows


def task_overhead(tasks: int) -> dict:
    """One-cell tasks of a cheap loop on one Dask worker, against the same cells on one rayon thread."""
    loop, x = tiny_loop()
    kwargs = dict(init={"x": (-1, 1), "v": (0, 0.1)}, steps=3, safe=x <= 2, split={"x": tasks}, progress=False)
    rayon, _ = timed(lambda: pv.verify(loop, workers=1, **kwargs))
    lc, client, _ = cluster(1)
    with lc, client:
        pv.verify(loop, executor=client, **{**kwargs, "split": {"x": 8}})  # the problem reaches the worker once
        one, _ = timed(lambda: pv.verify(loop, executor=client, batch=1, **kwargs))
        auto, _ = timed(lambda: pv.verify(loop, executor=client, **kwargs))
    return {
        "tasks": tasks,
        "rayon_seconds": rayon,
        "dask_batch_1_seconds": one,
        "dask_auto_batch_seconds": auto,
        "overhead_per_task_ms": 1e3 * (one - rayon) / tasks,
    }


def resume(cells: int) -> dict:
    """A finished journal of `cells` state-based Mountain Car cells (150 reach boxes each), rerun."""
    loop, p, v, u = mountain_car()
    kwargs = dict(init={"p": (-0.55, -0.45), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, split={"p": cells}, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        journal = str(Path(tmp) / "run.jsonl")
        first, _ = timed(lambda: pv.verify(loop, journal=journal, **kwargs))
        reruns = [timed(lambda: pv.verify(loop, journal=journal, **kwargs))[0] for _ in range(3)]
        size = os.path.getsize(journal)
    return {"cells": cells, "journal_mb": size / 2**20, "first_run_seconds": first, "resume_seconds_median_of_3": statistics.median(reruns)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=24)
    parser.add_argument("--resume-cells", type=int, default=1000)
    parser.add_argument("--tasks", type=int, default=400)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    load = os.getloadavg()
    result = {
        "machine": {"cpus": os.cpu_count(), "load_average_before": load},
        "problem": "image Mountain Car, contrast, p in [-0.5, -0.49975], delta cells of 0.05 from 0.3, 150 steps",
        "throughput": throughput(args.cells, args.repeat),
        "dask_task_overhead": task_overhead(args.tasks),
        "resume": resume(args.resume_cells),
    }
    result["machine"]["load_average_after"] = os.getloadavg()
    out = ROOT / "bench" / "results" / "scale.json"
    out.write_text(json.dumps(result, indent=1))
    t, o, r = result["throughput"], result["dask_task_overhead"], result["resume"]
    print(
        f"efficiency on 2 workers: rayon {t['rayon_efficiency_2']:.2f}, dask {t['dask_efficiency_2']:.2f}; "
        f"dask/rayon {t['dask_over_rayon_1']:.2f} (1), {t['dask_over_rayon_2']:.2f} (2); same verdicts {t['same_verdicts']}"
    )
    print(
        f"dask overhead per task {o['overhead_per_task_ms']:.2f} ms; resume of {r['cells']} cells "
        f"({r['journal_mb']:.1f} MB) {r['resume_seconds_median_of_3']:.3f} s"
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
