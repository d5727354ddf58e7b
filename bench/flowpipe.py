"""Benchmark (run by hand): the eight rows of issue 28 against the Flow* toolbox.

Each row runs twice: with its ``tb_*.model`` file's own settings, and with percver's settings
for the row where they differ (named in ROWS, and why in bench/README.md). Per run: median CPU
seconds of the reachability computation over ``--repeat`` runs (``time.process_time``), the time
reached, the final widths with the default (linear dominated) bounder and with subdivision
(the initial set cut into the toolbox's own number of pieces per variable), and the ratios
against the toolbox's figures measured side by side on this machine kind
(../shared/anchors/README.md, 2026-11-27). Writes bench/results/flowpipe.json.

``--classic`` instead runs the classic Flow* example set in the same folder with the settings
its files ask for and writes bench/results/flowpipe_classic.json.

    python bench/flowpipe.py [--repeat 3] [--rows lorenz laubloomis ...] [--classic]
"""

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time
from pathlib import Path

import percver as pv
from percver.errors import PercverError

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "anchors" / "flowstar_models"

# row: (model file, percver's settings where they differ from the file's, pieces per variable
# for the subdivided widths, toolbox CPU s, toolbox widths to match: subdivided where the
# anchors give them, else the toolbox's printed interval box).
ROWS = {
    "vanderpol": ("tb_vanderpol", {"order": 5}, 16, 0.23, {"x": 0.242, "y": 0.328}),
    # The anchors give the toolbox's subdivided jet_engine widths as 1.01-1.03x narrower than
    # percver's box of the same day (x 1.892e-3, y 3.891e-3): the stricter end is the target.
    "jet_engine": ("tb_jet_engine", {"order": 5}, 16, 0.28, {"x": 1.892e-3 / 1.03, "y": 3.891e-3 / 1.03}),
    "brusselator": ("tb_brusselator", {}, 16, 7.0, {"x": 3.57e-3, "y": 8.52e-3}),
    "roessler": ("tb_roessler", {}, 16, 4.5, {"x": 3.16, "y": 4.00, "z": 4.12e-3}),
    "spring_pendulum": ("tb_spring_pendulum", {}, 16, 10.5, {"r": 0.105, "theta": 0.0208, "dr": 0.0956, "dtheta": 0.0386}),
    "quadrotor": ("tb_quadrotor", {}, 4, 16.2, {"x3": 4.61e-3}),
    "lorenz": ("tb_lorenz", {}, 16, 24.3, {"x": 6.80, "y": 7.82, "z": 8.49}),
    "laubloomis": ("tb_laubloomis", {"order": 5, "step": 0.025}, 3, 34.7, {"x4": 0.262}),
}

CLASSIC = [
    "Brusselator",
    "Lorentz",
    "Lotka_Volterra",
    "Roessler",
    "biology_I",
    "biology_II",
    "buckling_column",
    "coupledVanderPol",
    "jet_engine",
    "lacoperon",
    "spring_pendulum",
    "vanderpol",
    "vanderpol_shipped",
    "wattSteam",
]


def _widths(box: dict) -> dict:
    return {k: hi - lo for k, (lo, hi) in box.items()}


def run(model, settings: dict, repeat: int, split: int) -> dict:
    model = dataclasses.replace(model, **{k: v for k, v in settings.items() if k in ("order", "step", "symbolic_queue")})
    seconds = []
    for _ in range(repeat):
        t = time.process_time()
        fp = model.run(on_failure="return")
        seconds.append(time.process_time() - t)
    row = {
        "settings": {"step": model.step, "order": model.order, "cutoff": model.cutoff, "symbolic_queue": model.symbolic_queue},
        "t_end": model.t_end,
        "time_reached": fp.time_reached,
        "completed": fp.failure is None,
        "failure": fp.failure,
        "cpu_seconds_median": statistics.median(seconds),
        "cpu_seconds_all": seconds,
        "steps": len(fp.times),
        "widths": _widths(fp.final_box()),
    }
    if split:
        t = time.process_time()
        row["widths_subdivided"] = _widths(fp.final_box(split=split))
        row["subdivision"] = {"pieces_per_variable": split, "cpu_seconds": time.process_time() - t}
    return row


def bench_rows(names, repeat: int) -> list:
    rows = []
    for name in names:
        file, ours, split, tb_s, tb_w = ROWS[name]
        model = pv.formats.load_flowstar(str(MODELS / f"{file}.model"))
        entry = {
            "row": name,
            "model": file,
            "toolbox": {"cpu_seconds": tb_s, "widths": tb_w},
            "file_settings": run(model, {}, repeat, split),
        }
        if ours:
            entry["percver_settings"] = {"changed": ours, **run(model, ours, repeat, split)}
        best = entry.get("percver_settings", entry["file_settings"])
        entry["time_ratio"] = best["cpu_seconds_median"] / tb_s if best["completed"] else None
        entry["width_ratios"] = {k: best["widths_subdivided"][k] / w for k, w in tb_w.items()} if best["completed"] else None
        entry["meets_targets"] = bool(
            best["completed"] and entry["time_ratio"] <= 0.2 and all(r <= 1 for r in entry["width_ratios"].values())
        )
        rows.append(entry)
        for label in ("file_settings", "percver_settings"):
            r = entry.get(label)
            if r:
                w = ", ".join(f"{k} {r['widths_subdivided'][k]:.3g}" for k in tb_w)
                print(
                    f"{name:16s} {label:16s} reached {r['time_reached']:.4g}/{r['t_end']:g} {r['cpu_seconds_median']:.3f} s CPU, "
                    f"subdivided {w}",
                    flush=True,
                )
    return rows


def bench_classic(repeat: int) -> list:
    rows = []
    for name in CLASSIC:
        try:
            model = pv.formats.load_flowstar(str(MODELS / f"{name}.model"))
            row = {"model": name, **run(model, {}, repeat, 0)}
        except PercverError as e:
            row = {"model": name, "error": f"{type(e).__name__}: {e}"}
        rows.append(row)
        print(
            name, {k: row[k] for k in ("time_reached", "t_end", "cpu_seconds_median", "steps", "failure", "error") if k in row}, flush=True
        )
    return rows


def machine() -> dict:
    cpu = next(
        (line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")),
        platform.processor(),
    )
    return {"cpu": cpu, "nproc": os.cpu_count(), "load_average_at_start": os.getloadavg()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--rows", nargs="*", default=list(ROWS), choices=list(ROWS))
    parser.add_argument("--classic", action="store_true", help="run the classic Flow* example set instead")
    args = parser.parse_args()
    doc = {"percver": pv.__version__, "date": time.strftime("%Y-%m-%d %H:%M"), "repeat": args.repeat, "machine": machine()}
    if args.classic:
        doc["rows"] = bench_classic(args.repeat)
        out = ROOT / "bench" / "results" / "flowpipe_classic.json"
    else:
        doc["rows"] = bench_rows(args.rows, args.repeat)
        out = ROOT / "bench" / "results" / "flowpipe.json"
    doc["machine"]["load_average_at_end"] = os.getloadavg()
    out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
