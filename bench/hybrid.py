"""Benchmark (run by hand): Flow* hybrid models run with Taylor models carried through the jumps
against the same engine boxing the state at every jump (``jumps="box"``). Per model and mode:
median CPU seconds over ``--repeat`` runs (``time.process_time``), the widths of the final box
(the states at the horizon, or the reach box of the last mode for the exported networks) and
their ratio. Models: examples/flowstar/*.model; the Verisig 1.0-style export of a small random
network (2 -> 6 sigmoid -> 6 sigmoid -> 1 tanh, 16 variables) with a fixed step of 0.05 and
with the file's adaptive steps; wide exports (two sigmoid layers of 20 and of 100 neurons: 44
and 204 variables, wider than one Taylor model's space) with the file's settings; and, with
``--key-chain``, the paper's Mountain Car chain (12 layers up to 602 wide: 1,207 variables) over
the key figure's box and over contrast in [1.0, 1.01] (the box the removed Python box runner was
measured on). The machine is shared: CPU seconds, and
ratios between the two modes of one run, are the figures to read. Writes
bench/results/hybrid.json.

    python bench/hybrid.py [--repeat 3] [--key-chain]
"""

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import percver as pv
from percver.networks import Layer, Network

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "flowstar"
SAMPLES = 20_000


def random_network(width: int) -> Network:
    rng = np.random.default_rng(0)
    sizes = [(width, 2, "sigmoid"), (width, width, "sigmoid"), (1, width, "tanh")]
    return Network([Layer(rng.normal(size=(o, i)) / np.sqrt(i), 0.1 * rng.normal(size=o), act) for o, i, act in sizes])


def exported(network: Network, box, path: Path, step=None):
    """The network's Flow* export read back (optionally with another step), and its sampled output range."""
    model = pv.formats.load_flowstar(str(pv.formats.to_flowstar(network, path, box)))
    if step is not None:
        model.step = step
    lo, hi = np.array(list(box.values()) if isinstance(box, dict) else box).T
    y = network(np.random.default_rng(1).uniform(lo, hi, (SAMPLES, len(lo))))[:, 0]
    return model, [float(y.min()), float(y.max())]


def key_chain(path: Path, delta=None):
    """The key chain's export over the key figure's box, or with contrast ``delta`` instead."""
    sys.path.insert(0, str(ROOT / "bench"))
    from networks import BOX, mountain_car_chain

    return exported(mountain_car_chain(), BOX if delta is None else {**BOX, "delta": delta}, path)


def widths(run, last_mode):
    box = run.reach_box(last_mode) if last_mode else run.final_box()
    return {v: hi - lo for v, (lo, hi) in box.items() if v not in ("time", "clock")}


def measure(model, jumps: str, repeat: int, last, sampled) -> dict:
    seconds = []
    for _ in range(repeat):
        start = time.process_time()
        run = model.run(jumps=jumps)
        seconds.append(time.process_time() - start)
    row = {"cpu_s": round(statistics.median(seconds), 3), "failure": run.failure, "segments": len(run.times)}
    if run.failure:
        row["modes_reached"] = sorted(set(run.modes))
        return row
    row["widths"] = widths(run, last)
    if last == "_out":
        lo, hi = run.reach_box("_out")["y1"]
        row["widths"] = {"y1": hi - lo}
        row["encloses_samples"] = bool(lo <= sampled[0] and sampled[1] <= hi)
    return row


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--key-chain", action="store_true")
    args = parser.parse_args()
    load_at_start = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = [(p.stem, pv.formats.load_flowstar(str(p)), None, None, ("taylor", "box")) for p in sorted(EXAMPLES.glob("*.model"))]
        box = [(0.1, 0.14), (-0.2, -0.16)]
        for name, width, step in (
            ("network_6x6", 6, 0.05),
            ("network_6x6_file_steps", 6, None),
            ("network_20x20", 20, None),
            ("network_100x100", 100, None),
        ):
            model, sampled = exported(random_network(width), box, tmp / f"{name}.model", step)
            cases.append((name, model, "_out", sampled, ("taylor", "box")))
        if args.key_chain:
            for name, delta in (("mountain_car_key_chain", None), ("mountain_car_key_chain_narrow", (1.0, 1.01))):
                model, sampled = key_chain(tmp / f"{name}.model", delta)
                cases.append((name, model, "_out", sampled, ("taylor", "box")))
        for name, model, last, sampled, modes in cases:
            row = {"model": name, "variables": len(model.variables), "modes": len(model.modes), "step": model.step, "order": model.order}
            if sampled:
                row["sampled_range"] = sampled
            for jumps in modes:
                row[jumps] = measure(model, jumps, 1 if len(model.variables) > 40 else args.repeat, last, sampled)
            if "widths" in row["taylor"] and "widths" in row.get("box", {}):
                row["box_over_taylor"] = {
                    "width": {v: round(row["box"]["widths"][v] / w, 2) for v, w in row["taylor"]["widths"].items() if w > 0},
                    "cpu": round(row["box"]["cpu_s"] / max(row["taylor"]["cpu_s"], 1e-3), 1),
                }
            print(json.dumps(row), flush=True)
            rows.append(row)
    doc = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load_at_start:.2f} at start, {os.getloadavg()[0]:.2f} at end",
        "repeat": args.repeat,
        "rows": rows,
    }
    (ROOT / "bench" / "results" / "hybrid.json").write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
