"""Benchmark (run by hand): Flow* hybrid models run with Taylor models carried through the jumps
against the same engine boxing the state at every jump (``jumps="box"``). Per model and mode:
median CPU seconds over ``--repeat`` runs (``time.process_time``), the widths of the final box
(the states at the horizon, or the reach box of the last mode for the exported network) and
their ratio. Models: examples/flowstar/*.model and the Verisig 1.0-style export of a small
random network (2 -> 6 sigmoid -> 6 sigmoid -> 1 tanh, run with a fixed step of 0.05). Writes
bench/results/hybrid.json.

    python bench/hybrid.py [--repeat 3]
"""

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import percver as pv
from percver.networks import Layer, Network

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "flowstar"


def network_model(folder: Path):
    rng = np.random.default_rng(0)
    sizes = [(6, 2, "sigmoid"), (6, 6, "sigmoid"), (1, 6, "tanh")]
    net = Network([Layer(rng.normal(size=(o, i)) / np.sqrt(i), 0.1 * rng.normal(size=o), act) for o, i, act in sizes])
    model = pv.formats.load_flowstar(str(pv.formats.to_flowstar(net, folder / "network.model", [(0.1, 0.14), (-0.2, -0.16)])))
    model.step = 0.05
    return model


def widths(run, last_mode):
    box = run.reach_box(last_mode) if last_mode else run.final_box()
    return {v: hi - lo for v, (lo, hi) in box.items() if v not in ("time", "clock")}


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    load_at_start = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        models = [(p.stem, pv.formats.load_flowstar(str(p)), None) for p in sorted(EXAMPLES.glob("*.model"))]
        models.append(("network_6x6", network_model(Path(tmp)), "_out"))
        for name, model, last in models:
            row = {"model": name, "variables": len(model.variables), "modes": len(model.modes)}
            for jumps in ("taylor", "box"):
                seconds = []
                for _ in range(args.repeat):
                    start = time.process_time()
                    run = model.run(jumps=jumps)
                    seconds.append(time.process_time() - start)
                row[jumps] = {"cpu_s": round(statistics.median(seconds), 3), "failure": run.failure, "widths": widths(run, last)}
                if last == "_out":
                    row[jumps]["widths"] = {"y1": row[jumps]["widths"]["y1"]}
            row["box_over_taylor"] = {v: round(row["box"]["widths"][v] / w, 2) for v, w in row["taylor"]["widths"].items() if w > 0}
            print(json.dumps(row))
            rows.append(row)
    doc = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load_at_start:.2f} at start, {os.getloadavg()[0]:.2f} at end",
        "repeat": args.repeat,
        "rows": rows,
    }
    (ROOT / "bench" / "results" / "hybrid.json").write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
