"""Benchmark (run by hand): Flow* benchmark models with their own settings.

Writes bench/results/flowpipe.json: median wall seconds of 3 runs, time reached, final-box
widths, and the ratios against Flow*'s figures measured on this machine kind
(../shared/anchors/README.md; Flow* is not installed here, so those are the baseline).

    python bench/flowpipe.py [--repeat 3] [--models vanderpol tb_vanderpol ...]
"""

import argparse
import json
import statistics
import time
from pathlib import Path

import percver as pv

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "anchors" / "flowstar_models"
DEFAULT = ["vanderpol", "vanderpol_shipped", "tb_vanderpol", "tb_jet_engine", "tb_brusselator", "tb_roessler",
           "tb_lorenz", "tb_spring_pendulum", "tb_laubloomis", "Lotka_Volterra", "buckling_column"]

# Flow* figures from ../shared/anchors/README.md (seconds are the lower end of reported ranges).
ANCHORS = {
    "tb_vanderpol": {"toolbox_s": 0.40, "v210_s": 0.81, "toolbox_widths": {"x": 0.281, "y": 0.396}, "v210_widths": {"x": 0.301, "y": 0.434}},
    "tb_jet_engine": {"toolbox_s": 0.46, "v210_s": 0.83, "toolbox_widths": {"x": 2.25e-3, "y": 4.22e-3}, "v210_widths": {"x": 0.107, "y": 0.144}},
    "tb_brusselator": {"toolbox_s": 10.7, "v210_s": 17.1, "toolbox_widths": {"x": 3.57e-3, "y": 8.52e-3}, "v210_widths": {"x": 5.60e-3, "y": 1.40e-2}},
    "tb_roessler": {"toolbox_s": 7.0, "v210_s": 15.4, "toolbox_widths": {"x": 4.67, "y": 5.23, "z": 6.0e-3}, "v210_widths": {"x": 3.96, "y": 4.74, "z": 5.3e-3}},
    "tb_spring_pendulum": {"toolbox_s": 15.4, "v210_s": 27.2, "toolbox_widths": {"r": 0.105, "theta": 0.0208, "dr": 0.0956, "dtheta": 0.0386},
                           "v210_widths": {"r": 0.257, "theta": 0.0533, "dr": 0.241, "dtheta": 0.108}},
    "tb_laubloomis": {"toolbox_s": 45.2, "v210_s": 487.5, "toolbox_widths": {"x4": 0.262}},
    "tb_lorenz": {"toolbox_s": 37.9, "toolbox_widths": {"x": 6.80, "y": 7.82, "z": 8.49}},
    "vanderpol_shipped": {"v210_s": 0.14, "v210_widths": {"x": 9.93e-2}},
}


def run(name: str, repeat: int) -> dict:
    model = pv.formats.load_flowstar(str(MODELS / f"{name}.model"))
    seconds = []
    for _ in range(repeat):
        t = time.perf_counter()
        fp = model.run(on_failure="return")
        seconds.append(time.perf_counter() - t)
    widths = {k: hi - lo for k, (lo, hi) in fp.final_box().items()}
    row = {
        "model": name, "t_end": model.t_end, "time_reached": fp.time_reached, "completed": fp.failure is None,
        "failure": fp.failure, "seconds_median": statistics.median(seconds), "seconds_all": seconds,
        "steps": len(fp.times), "widths": widths, "settings": {"step": model.step, "order": model.order, "cutoff": model.cutoff},
    }
    anchor = ANCHORS.get(name)
    if anchor:
        row["anchor"] = anchor
        for which in ("toolbox", "v210"):
            if f"{which}_s" in anchor and row["completed"]:
                row[f"time_ratio_vs_{which}"] = row["seconds_median"] / anchor[f"{which}_s"]
            if f"{which}_widths" in anchor and row["completed"]:
                row[f"width_ratio_vs_{which}"] = {k: widths[k] / w for k, w in anchor[f"{which}_widths"].items() if k in widths}
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--models", nargs="*", default=DEFAULT)
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "flowpipe.json"))
    args = parser.parse_args()
    rows = []
    for name in args.models:
        row = run(name, args.repeat)
        rows.append(row)
        w = ", ".join(f"{k} {v:.3g}" for k, v in row["widths"].items())
        print(f"{name:20s} reached {row['time_reached']:.4g}/{row['t_end']:g} {'ok ' if row['completed'] else 'STOP'} "
              f"{row['seconds_median']:.3f} s  widths {w}", flush=True)
    doc = {"percver": pv.__version__, "date": time.strftime("%Y-%m-%d"), "repeat": args.repeat, "rows": rows}
    Path(args.out).write_text(json.dumps(doc, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
