"""Soak (run by hand, not in CI): verification campaigns on a Dask LocalCluster while workers and
clients are killed at random, checking that every finished journal equals the fault-free result.

A LocalCluster (2 worker processes, restarted by their nannies) runs for the whole soak. Each
round picks one of several campaigns (state-based Mountain Car: all verified, refined to
min_width, partly falsified, a safety property) and runs it in a client subprocess
(``pv.verify(executor="tcp://...", journal=...)``). Meanwhile, at random moments (exponential,
mean ``--every`` seconds), a worker process (2 times in 3) or the client is killed with SIGKILL; a killed client
is started again on the same journal until it finishes. The round then checks: the journal holds
each cell once, a rerun takes every cell from it without running any, and its cells and verdicts
equal a fault-free run. Writes bench/results/soak.json.

    python bench/soak.py [--minutes 30] [--every 1.5] [--seed 0]
"""

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see bench/scale.py
import percver as pv  # noqa: E402
from percver.verification.journal import journal_cells  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from closed_loops import mountain_car  # noqa: E402


def campaigns() -> tuple:
    """The loop and the campaigns' pv.verify arguments (deterministic: no timeouts)."""
    loop, p, v, u = mountain_car()
    common = dict(steps=150, goal=p >= 0.45, within=True, progress=False)
    return loop, {
        "verified": dict(common, init={"p": (-0.55, -0.45), "v": (0, 0)}, split={"p": 120}),
        "refined": dict(common, init={"p": (-0.58, -0.40), "v": (0, 0)}, split={"p": 6}, order=3, refine=True, min_width={"p": 0.001}),
        "falsified": dict(common, init={"p": (-0.62, -0.56), "v": (0, 0)}, split={"p": 60}),
        "safety": dict(
            init={"p": (-0.5, -0.4), "v": (-0.01, 0.01)},
            split={"p": 10, "v": 3},
            steps=60,
            safe=[v >= -0.07, v <= 0.07],
            unsafe=p <= -1.2,
            progress=False,
        ),
    }


def client(name: str, journal: str, scheduler: str) -> None:
    loop, runs = campaigns()
    pv.verify(loop, executor=scheduler, journal=journal, **runs[name])


def outcome(result) -> list:
    return sorted((json.dumps(c.box, sort_keys=True), c.verdict) for c in result.cells)


def journal_boxes(path: Path) -> list:
    return [json.dumps(c.box, sort_keys=True) for c in journal_cells(path)]


def wait_and_kill(proc, cluster, rng, every: float, stats: dict) -> None:
    """Until the client exits: at random moments, SIGKILL a worker (2 times in 3) or the client."""
    while proc.poll() is None:
        try:
            proc.wait(timeout=rng.expovariate(1 / every))
            return
        except subprocess.TimeoutExpired:
            pass
        if rng.random() < 1 / 3:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            stats["client_kills"] += 1
        else:
            pids = [n.process.process.pid for n in cluster.workers.values() if n.process and n.process.process and n.process.process.pid]
            try:
                os.kill(rng.choice(pids), signal.SIGKILL)
                stats["worker_kills"] += 1
            except (IndexError, ProcessLookupError):  # both restarting: no kill this time
                pass
        if len(cluster.workers) < 2:
            # A worker killed while its nanny restarts it can take the nanny along (Dask drops it
            # from cluster.workers); scale() starts the missing ones again.
            cluster.scale(2)
            stats["nanny_repairs"] += 1


def soak(minutes: float, every: float, seed: int) -> dict:
    from distributed import LocalCluster

    rng = random.Random(seed)
    loop, runs = campaigns()
    reference = {name: outcome(pv.verify(loop, **kwargs)) for name, kwargs in runs.items()}
    stats = {
        "rounds": 0,
        "worker_kills": 0,
        "client_kills": 0,
        "client_starts": 0,
        "nanny_repairs": 0,
        "cells_checked": 0,
        "mismatches": [],
        "duplicates": [],
        "reran_cells": [],
        "client_failures": [],
        "by_campaign": {},
    }
    start = time.time()
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        tempfile.TemporaryDirectory() as tmp,
    ):
        while time.time() - start < 60 * minutes:
            name = rng.choice(sorted(runs))
            journal = Path(tmp) / f"round{stats['rounds']}.jsonl"
            log = Path(tmp) / "client.log"
            while True:
                stats["client_starts"] += 1
                with open(log, "w") as out:
                    proc = subprocess.Popen(
                        [sys.executable, __file__, "--client", name, str(journal), cluster.scheduler_address],
                        stdout=out,
                        stderr=subprocess.STDOUT,
                    )
                try:
                    wait_and_kill(proc, cluster, rng, every, stats)
                finally:
                    if proc.poll() is None:  # the soak itself is stopping
                        proc.kill()
                if proc.returncode == 0:
                    break
                if proc.returncode != -signal.SIGKILL:
                    stats["client_failures"].append({"campaign": name, "code": proc.returncode, "log": log.read_text()[-2000:]})
                    break
            if not journal.exists():  # the client failed before its first cell (recorded above)
                continue
            boxes = journal_boxes(journal)
            if len(boxes) != len(set(boxes)):
                stats["duplicates"].append({"round": stats["rounds"], "campaign": name, "lines": len(boxes), "distinct": len(set(boxes))})
            size = journal.stat().st_size
            final = outcome(pv.verify(loop, journal=str(journal), **runs[name]))
            if journal.stat().st_size != size:
                stats["reran_cells"].append({"round": stats["rounds"], "campaign": name})
            if final != reference[name]:
                stats["mismatches"].append({"round": stats["rounds"], "campaign": name})
            stats["cells_checked"] += len(final)
            stats["rounds"] += 1
            stats["by_campaign"][name] = stats["by_campaign"].get(name, 0) + 1
            print(
                f"{time.time() - start:7.0f} s  round {stats['rounds']:3d} {name:9s} cells {len(final):3d}  kills: workers "
                f"{stats['worker_kills']}, clients {stats['client_kills']}; nanny repairs {stats['nanny_repairs']}",
                flush=True,
            )
    stats["seconds"] = time.time() - start
    stats["ok"] = not (stats["mismatches"] or stats["duplicates"] or stats["reran_cells"] or stats["client_failures"])
    return stats


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--client":
        client(*sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30)
    parser.add_argument("--every", type=float, default=1.5, help="mean seconds between kills")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    stats = {"settings": vars(args), "load_average_before": os.getloadavg(), **soak(args.minutes, args.every, args.seed)}
    stats["load_average_after"] = os.getloadavg()
    out = ROOT / "bench" / "results" / "soak.json"
    out.write_text(json.dumps(stats, indent=1))
    print(
        f"{'OK' if stats['ok'] else 'FAILED'}: {stats['rounds']} rounds, {stats['cells_checked']} cells checked, "
        f"{stats['worker_kills']} worker and {stats['client_kills']} client kills; wrote {out}"
    )
    sys.exit(0 if stats["ok"] else 1)


if __name__ == "__main__":
    main()
