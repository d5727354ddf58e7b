"""Benchmark (run by hand): cells per second on 1 and 2 local workers, rayon against a Dask
LocalCluster, in one run; Dask's overhead per task; time to resume a 1,000-cell journal. With
``--model``: scale on paper instead, from measured cells (see :func:`model`).

Problem: the paper's image-based Mountain Car with contrast noise (generator -> contraster ->
estimator -> sig16x16 controller, the authors' networks), 150 steps, goal p >= 0.45 within the
horizon, on one paper-sized position cell p in [-0.5, -0.49975] with the contrast delta in
[0.3, 0.3 + 0.05 * cells] split into cells of width 0.05. Writes bench/results/scale.json.

    python bench/scale.py [--cells 24] [--repeat 2] [--resume-cells 1000] [--tasks 400]
    python bench/scale.py --model [--trivial 2000]   # writes bench/results/scale_model.json
"""

import argparse
import heapq
import json
import os
import statistics
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

# One BLAS thread: falsification's float simulation otherwise spins extra threads against the
# workers on 2 cores (10x slower measured under load). Set before numpy loads; workers inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import numpy as np  # noqa: E402
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


IDLE_SECONDS = 10.0


def noop(x):
    return x


def trivial_tasks(tasks: int) -> dict:
    """Dask's own cost per task, with tasks that do nothing, on a LocalCluster of 2 single-threaded
    workers: ``tasks`` submitted at once (the scheduler's throughput, and the CPU it and the client
    spend per task: they share this process) and one at a time (a task's round trip); and the
    CPU the client and scheduler spend while no task runs."""
    lc, client, _ = cluster(2)
    with lc, client:
        client.gather(client.map(noop, range(100), pure=False))  # warm: connections, function pickled
        cpu, start = time.process_time(), time.perf_counter()
        client.gather(client.map(noop, range(tasks), pure=False))
        wall, head_cpu = time.perf_counter() - start, time.process_time() - cpu
        trips = []
        for k in range(200):
            t = time.perf_counter()
            client.submit(noop, k, pure=False).result()
            trips.append(time.perf_counter() - t)
        cpu, start = time.process_time(), time.perf_counter()
        time.sleep(IDLE_SECONDS)
        idle = (time.process_time() - cpu) / (time.perf_counter() - start)
    return {
        "tasks": tasks,
        "throughput_tasks_per_second": tasks / wall,
        "wall_ms_per_task": 1e3 * wall / tasks,
        "head_cpu_ms_per_task": 1e3 * head_cpu / tasks,
        "round_trip_ms_median": 1e3 * statistics.median(trips),
        # The client and scheduler with nothing to do (heartbeats): CPU seconds per second.
        "idle_head_cpu_per_second": idle,
        "load_average": os.getloadavg(),
    }


def tree(attempts: list) -> tuple:
    """From a journal's attempts (box, verdict, seconds, ...), in journal order: each attempt's
    cost, its children (the attempts made by bisecting it: the largest boxes strictly inside it),
    and the roots in order."""
    spans = [{k: tuple(v) for k, v in a[0].items()} for a in attempts]

    def inside(a, b):  # box a strictly inside box b
        return a != b and all(b[k][0] <= a[k][0] and a[k][1] <= b[k][1] for k in a)

    def volume(b):
        return statistics.fmean(v[1] - v[0] for v in b.values())

    children = [[] for _ in attempts]
    roots = []
    for i, a in enumerate(spans):
        holders = [j for j, b in enumerate(spans) if inside(a, b)]
        if holders:
            children[min(holders, key=lambda j: volume(spans[j]))].append(i)
        else:
            roots.append(i)
    return [a[2] for a in attempts], children, roots


def schedule(costs: list, children: list, roots: list, cores: int, longest_first: bool, task_s: float, head_s: float) -> float:
    """Wall time of list scheduling on ``cores``: a cell starts when a core is free and it is
    ready (its parent has finished: bisected halves exist only then). ``longest_first`` takes the
    costliest ready cell (costs known in advance: the best a scheduler could do), else the
    campaign's order (sub-cells first, last made first; then the grid in order). Each cell costs
    its core ``task_s`` on top (the task's round trip) and the head (client and scheduler, one
    process) ``head_s`` of serial time, during which no other cell is dispatched."""
    ready_lifo, grid, best = [], deque(roots), []
    if longest_first:
        best = [(-costs[i], i) for i in roots]
        heapq.heapify(best)
    running: list = []  # (finish time, cell)
    now = head = 0.0
    free = cores

    def pop():
        if longest_first:
            return heapq.heappop(best)[1] if best else None
        if ready_lifo:
            return ready_lifo.pop()
        return grid.popleft() if grid else None

    while True:
        while free:
            i = pop()
            if i is None:
                break
            head = max(head, now) + head_s
            heapq.heappush(running, (head + task_s + costs[i], i))
            free -= 1
        if not running:
            return now
        now, i = heapq.heappop(running)
        free += 1
        for c in children[i]:
            if longest_first:
                heapq.heappush(best, (-costs[c], c))
            else:
                ready_lifo.append(c)


def critical_path(costs: list, children: list, roots: list) -> float:
    """The costliest chain of a cell and its bisected descendants: no number of cores beats it."""

    def chain(i):
        return costs[i] + max((chain(c) for c in children[i]), default=0.0)

    return max(chain(r) for r in roots)


EDGES = [2.0**e for e in range(-3, 7)] + [float("inf")]


def quantiles(costs: list) -> dict:
    q = statistics.quantiles(costs, n=100, method="inclusive")
    return {
        "cells": len(costs),
        "sum_s": sum(costs),
        "mean_s": statistics.fmean(costs),
        **{f"p{k}_s": q[k - 1] for k in (10, 50, 90, 99)},
        "max_s": max(costs),
        "share_of_time_in_costliest_1%": sum(sorted(costs)[-max(1, len(costs) // 100) :]) / sum(costs),
        # Cells per bin of cost: upper edges in seconds, doubling.
        "histogram": {f"<={edge:g}": int(n) for edge, n in zip(EDGES, np.bincount(np.searchsorted(EDGES, costs), minlength=len(EDGES)))},
    }


def model(trivial: int) -> dict:
    """Scale on paper: the measured cells of Mountain Car rows (every journaled attempt of
    ``bench/results/dask_row.json``, refined ones with their bisected halves as children; and the
    composite row's 3,282 final cells of ``bench/results/mountain_car.json``, refined attempts not
    listed there; likewise its contrast and blur rows) scheduled on 2, 64 and 1,000 cores,
    arrival order against longest first, with Dask's cost per task measured here with trivial
    tasks and the head's measured CPU per cell."""
    over = trivial_tasks(trivial)
    rows = {}
    sources = {}
    dask_rows = json.loads((ROOT / "bench" / "results" / "dask_row.json").read_text())
    for noise, runs in dask_rows.items():
        entry = runs[-1]
        attempts = entry["local"]["attempts"]
        # The head's CPU per cell: the Dask run's client process less what it spends idle.
        d = entry["dask"]
        head = max(0.0, d["driver_cpu_seconds"] - over["idle_head_cpu_per_second"] * d["wall_seconds"]) / len(d["attempts"])
        sources[f"{noise} (all attempts, local run of {entry['date']})"] = (tree(attempts), head)
    rows_before = json.loads((ROOT / "bench" / "results" / "mountain_car.json").read_text())
    for noise in ("contrast", "blur", "composite"):
        entry = rows_before[f"{noise}/paper"]
        at = entry["cell_columns"].index("seconds")
        costs = [c[at] for c in entry["cells"]]
        sources[f"{noise} (final cells of mountain_car.json)"] = ((costs, [[] for _ in costs], list(range(len(costs)))), None)
    task_s = 1e-3 * over["round_trip_ms_median"]
    measured_heads = [h for _, h in sources.values() if h is not None]
    for name, ((costs, children, roots), head) in sources.items():
        head_s = head if head is not None else max(measured_heads)
        row = {"costs": quantiles(costs), "head_s_per_cell": head_s, "task_s": task_s}
        row["critical_path_s"] = critical_path(costs, children, roots)
        for cores in (2, 64, 1000):
            bound = max(sum(costs) / cores, row["critical_path_s"])
            walls = {
                order: schedule(costs, children, roots, cores, order == "longest_first", task_s, head_s)
                for order in ("arrival", "longest_first")
            }
            row[f"cores_{cores}"] = {
                **{f"{k}_s": v for k, v in walls.items()},
                "lower_bound_s": bound,
                "efficiency_arrival": sum(costs) / (cores * walls["arrival"]),
                "head_bound_s": len(costs) * head_s,
            }
        rows[name] = row
    return {"trivial_tasks": over, "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=24)
    parser.add_argument("--resume-cells", type=int, default=1000)
    parser.add_argument("--tasks", type=int, default=400)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--model", action="store_true", help="scale on paper from measured cells (no verification run)")
    parser.add_argument("--trivial", type=int, default=2000, help="trivial tasks to measure Dask's cost per task (--model)")
    args = parser.parse_args()
    if args.model:
        result = {"machine": {"cpus": os.cpu_count(), "load_average_before": os.getloadavg()}, **model(args.trivial)}
        out = ROOT / "bench" / "results" / "scale_model.json"
        out.write_text(json.dumps(result, indent=1))
        o = result["trivial_tasks"]
        print(
            f"trivial tasks: {o['wall_ms_per_task']:.2f} ms each at {o['throughput_tasks_per_second']:.0f}/s, round trip {o['round_trip_ms_median']:.2f} ms"
        )
        for name, row in result["rows"].items():
            c = row["costs"]
            print(
                f"{name}: {c['cells']} cells, {c['sum_s']:.0f} s, median {c['p50_s']:.2f} s, max {c['max_s']:.1f} s, critical path {row['critical_path_s']:.1f} s"
            )
            for cores in (2, 64, 1000):
                r = row[f"cores_{cores}"]
                print(
                    f"  {cores:5d} cores: arrival {r['arrival_s']:.1f} s, longest first {r['longest_first_s']:.1f} s, bound {r['lower_bound_s']:.1f} s"
                )
        print(f"wrote {out}")
        return
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
