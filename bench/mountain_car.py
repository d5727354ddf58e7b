"""Benchmark (run by hand): the Mountain Car rows of the paper's Table 1 with percver.

For each row (contrast, blur, composite) and network set (the authors' "paper", percver's "ours"),
verifies the row's whole initial set (or ``--p0 LO HI``) with ``pv.cases.mountain_car.verify``'s
defaults on ``--workers`` threads, journaled (``--journal-dir``; a killed run resumes where it
stopped, and the wall time adds up the sessions). Records per-cell times and verdicts, coverage,
wall time, ``os.getloadavg()`` at the start and end of each session (other jobs share this
machine), why cells stayed unknown, and the paper's published numbers, in
``bench/results/mountain_car.json`` (one entry per row and network set, merged with earlier runs),
plus a coverage map per entry (``bench/results/mountain_car_<row>_<networks>.png``).

    python bench/mountain_car.py --rows contrast --networks paper [--p0 -0.5 -0.45] [--workers 2]
    python bench/mountain_car.py --rows composite --combine   # join the --p0 slices run so far into one row
    python bench/mountain_car.py --rows contrast --networks ours --p0 -0.51 -0.4 --survey  # a quick map, not the row
    python bench/mountain_car.py --rows contrast --networks ours --controller paper  # our perception, the authors' controller
"""

import argparse
import json
import os
import re
import time
from pathlib import Path

from percver.cases.mountain_car import verification
from percver.verification import Cell
from percver.verification.journal import journal_cells

ROOT = Path(__file__).resolve().parent
# The hand-made bands the library had for the authors' chain before the adaptive default was
# measured faster on these rows (bench/README.md); kept here as the baseline ``--variants hand``
# passes as data (``layout=``).
_Band, _WALL = verification.Band, verification.WALL
OLD_LAYOUT = {
    "canonical": [_Band({"p": (-float("inf"), _WALL)}, {"p": 0.005}, 16), _Band({"p": (_WALL, float("inf"))}, {"p": 0.001}, 64)],
    "blur": verification.LAYOUT["ours+paper"]["blur"],  # the same bands: our perception keeps them
}
SURVEY_SPLITS = 4  # in-cell splits per cell of a --survey: enough for the easy cells, cheap on the hard ones
RESULTS = ROOT / "results"


def _journal_cells(path: Path) -> list:
    """Every cell the journal (or the journals of its bands, ``run.band0.jsonl`` ...) holds, refined (bisected) ones included."""
    return [cell for p in _journals(path) for cell in journal_cells(p)]


def _journals(path: Path) -> list:
    return sorted(p for p in [path, *path.parent.glob(f"{path.stem}.band*{path.suffix}")] if p.exists())


def _sessions(path: Path, journal: Path) -> list:
    """Earlier sessions of this run; one cut short (killed) ends at the journal's last write."""
    sessions = json.loads(path.read_text()) if path.exists() else []
    last = max((p.stat().st_mtime for p in _journals(journal)), default=0.0)
    for s in sessions:
        if s.get("end") is None:
            s["end"], s["interrupted"] = max(s["start"], last), True
    return sessions


def _networks_key(networks: str, controller) -> str:
    """``ours`` or, with another set's controller, ``ours+paper-controller`` (results keys, file names)."""
    return networks if controller is None else f"{networks}+{controller}-controller"


def _cpu() -> str:
    """The processor as /proc/cpuinfo names it, with its family and model: machines of this kind
    differ (an EPYC of family 25 model 1 ran the composite row's cells 2.6x slower than another)."""
    try:
        info = dict(line.split(":", 1) for line in Path("/proc/cpuinfo").read_text().splitlines() if ":" in line)
    except OSError:
        return "unknown"
    info = {k.strip(): v.strip() for k, v in info.items()}
    return f"{info.get('model name', '?')} (family {info.get('cpu family', '?')}, model {info.get('model', '?')})"


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process so far (every thread's)."""
    t = os.times()
    return t.user + t.system


def run(
    noise: str, networks: str, p0, workers: int, journal_dir: Path, options: dict, survey: bool = False, controller=None, label: str = ""
) -> dict:
    tag = f"{noise}_{_networks_key(networks, controller)}" + ("_survey" if survey else "") + ("" if p0 is None else f"_{p0[0]:g}_{p0[1]:g}")
    tag += f"_{label}" if label else ""
    journal = journal_dir / f"mc_{tag}.jsonl"
    session_file = journal_dir / f"mc_{tag}.sessions.json"
    sessions = _sessions(session_file, journal)
    session = {
        "start": time.time(),
        "end": None,
        "loadavg_start": os.getloadavg(),
        "cpu": _cpu(),
        "cpu_seconds_start": _cpu_seconds(),
        "cells_in_journal": len(_journal_cells(journal)),
    }
    session_file.write_text(json.dumps(sessions + [session]))
    result = verification.verify(noise, p0, networks, controller=controller, workers=workers, journal=str(journal), **options)
    session.update(end=time.time(), loadavg_end=os.getloadavg(), cpu_seconds=_cpu_seconds() - session["cpu_seconds_start"])
    sessions.append(session)
    session_file.write_text(json.dumps(sessions))
    attempts = _journal_cells(journal)
    row = verification.table_row(result)
    row["wall_seconds"] = sum(s["end"] - s["start"] for s in sessions)
    row["engine_seconds_all_attempts"] = sum(c.seconds for c in attempts)
    row["cpu_seconds"] = sum(s.get("cpu_seconds", 0.0) for s in sessions)
    row["engine_runs"] = len(attempts)
    # The deepest step of every run, plain and reboxed apart (a reboxed step costs about two
    # plain ones): the engine's work in a measure the load cannot change.
    row["engine_steps"] = sum(c.deepest_step for c in attempts if not c.options.get("rebox"))
    row["engine_steps_reboxed"] = sum(c.deepest_step for c in attempts if c.options.get("rebox"))
    plot = RESULTS / f"mountain_car_{tag}.png"
    verification.plot_coverage(result, plot)
    noise_states = verification.NOISE_STATES[noise]
    return {
        "noise": noise,
        "networks": networks,
        **({} if controller is None else {"controller": controller}),
        "init": result.init,
        "settings": result.settings,
        "workers": workers,
        "cpu_count": os.cpu_count(),
        "sessions": sessions,
        "row": row,
        "reasons": verification.reasons(result),
        "paper": verification.published(noise),
        "coverage_plot": str(plot.relative_to(ROOT.parent)),
        # Per cell: p0 interval, noise intervals, verdict, engine seconds, NN seconds, branches, reason.
        "cells": [
            [
                *c.box["p"],
                *(x for n in noise_states for x in c.box[n]),
                c.verdict,
                round(c.seconds, 3),
                round(c.nn_seconds, 3),
                c.branches,
                c.reason,
            ]
            for c in result.cells
        ],
        "cell_columns": [
            "p_lo",
            "p_hi",
            *(f"{n}_{e}" for n in noise_states for e in ("lo", "hi")),
            "verdict",
            "seconds",
            "nn_seconds",
            "branches",
            "reason",
        ],
        "refined_attempts": len(attempts) - len(result.cells),
    }


def combine(doc: dict, noise: str, networks: str) -> dict:
    """One row from runs of p0 slices (``--p0``) that tile it: their cells as one result, the wall
    time the sum of the slices' (they ran one after another), the gaps listed if any."""
    import percver as pv

    prefix = f"{noise}/{networks}/"
    slices = sorted(
        (e for k, e in doc.items() if k.startswith(prefix) and k != prefix + "slices" and not k.startswith(prefix + "survey")),
        key=lambda e: e["init"]["p"][0],
    )
    if not slices:
        raise SystemExit(f"no slices of {noise}/{networks} in the results to combine")
    init = {n: tuple(b) for n, b in slices[0]["init"].items()}
    init["p"] = tuple(verification.initial_set(noise)["p"])
    cells, edge, gaps = [], init["p"][0], []
    for e in slices:
        lo, hi = e["init"]["p"]
        if lo > edge + 1e-12:
            gaps.append((edge, lo))
        elif lo < edge - 1e-12:
            raise SystemExit(f"slices of {noise}/{networks} overlap at p0 {lo:g} (remove the older entry from the results)")
        edge = max(edge, hi)
        columns = e["cell_columns"]
        for row in e["cells"]:
            value = dict(zip(columns, row))
            box = {**init, "p": (value["p_lo"], value["p_hi"])}
            box.update({n: (value[f"{n}_lo"], value[f"{n}_hi"]) for n in verification.NOISE_STATES[noise]})
            cells.append(Cell(box, value["verdict"], value["seconds"], value["nn_seconds"], value["branches"], reason=value["reason"]))
    if edge < init["p"][1] - 1e-12:
        gaps.append((edge, init["p"][1]))
    wall = sum(e["row"]["wall_seconds"] for e in slices)
    row = verification.table_row(pv.Result(slices[0]["settings"].get("states", list(init)), init, cells, wall))
    row["engine_seconds_all_attempts"] = sum(e["row"]["engine_seconds_all_attempts"] for e in slices)
    # Per paper interval over the part the slices cover (table_row divides by the whole row).
    covered = sum(e["init"]["p"][1] - e["init"]["p"][0] for e in slices)
    row["engine_seconds_per_paper_interval"] = row["engine_seconds"] * verification.PAPER_INTERVAL / covered
    row["wall_seconds_per_paper_interval"] = wall * verification.PAPER_INTERVAL / covered
    return {
        "noise": noise,
        "networks": networks,
        "init": init,
        "row": row,
        "gaps": gaps,
        "paper": slices[0]["paper"],
        "slices": [
            {
                "p0": e["init"]["p"],
                "cells": e["row"]["intervals"],
                "coverage": e["row"]["coverage"],
                "wall_seconds": e["row"]["wall_seconds"],
                "loadavg": [s.get("loadavg_start") for s in e["sessions"]],
            }
            for e in slices
        ],
    }


COMPARED = RESULTS / "mountain_car_adaptive.json"
# Each comparison's per-cell rows, one file per row key and day (the summaries passed 5 MB with
# them, and so did one file per row key after a week of whole-row comparisons).
COMPARED_CELLS = RESULTS / "mountain_car_adaptive"


def _cells_apart(key: str, index: int, runs: dict) -> None:
    """Moves the per-cell rows of ``runs`` (comparison ``index`` of ``key``) to ``COMPARED_CELLS``,
    in the file of its day, under its index and date (two runs can share a minute); the summary
    keeps everything else."""
    rows = {label: entry.pop("cells") for label, entry in runs.items() if isinstance(entry, dict) and "cells" in entry}
    if not rows:
        return
    day = str(runs.get("date", "undated"))[:10]
    path = COMPARED_CELLS / (key.replace("/", "_").replace(",", "_") + f"_{day}.json")
    COMPARED_CELLS.mkdir(exist_ok=True)
    doc = json.loads(path.read_text()) if path.exists() else {}
    doc[f"{index} {runs.get('date', 'undated')}"] = rows
    path.write_text(_dumps(doc))


def variant(spec: str) -> dict:
    """``verify`` keywords of a --variants entry: ``hand`` (the layout; see :func:`hand`),
    ``adaptive`` (the default splitter) or ``adaptive:key=value:...`` (``pv.Adaptive`` with those
    settings, e.g. ``adaptive:reach=0:rebox=False``; a key that is not one of its fields, such as
    ``order``, goes to ``verify``)."""
    import ast

    import percver as pv

    name, *settings = spec.split(":")
    if name == "hand" and not settings:
        return {}
    if name != "adaptive":
        raise SystemExit(f"unknown variant {spec!r}: give hand, adaptive or adaptive:key=value:...")
    given = {k: ast.literal_eval(v) for k, v in (s.split("=", 1) for s in settings)}
    fields = set(pv.Adaptive.__dataclass_fields__)
    return {
        "splitter": pv.Adaptive(**{k: v for k, v in given.items() if k in fields}),
        **{k: v for k, v in given.items() if k not in fields},
    }


def hand(noise: str, networks: str, controller) -> dict:
    """``verify`` keywords of the hand layout of a row: the library's bands where it still has
    them, else the authors' old bands above."""
    return {} if verification._layout(networks, controller, noise) is not None else {"layout": OLD_LAYOUT[noise]}


def compare(args) -> None:
    """The hand layout and adaptive splitters (``--variants``) on the same rows, one after the other
    in one process (the same machine and nearly the same load): wall, CPU seconds, engine runs,
    load average. Ratios are each variant's against the first (``hand``)."""
    journal_dir = Path(args.journal_dir) / f"compare-{int(time.time())}"
    journal_dir.mkdir(parents=True, exist_ok=True)
    options = {} if args.timeout_per_cell is None else {"timeout_per_cell": args.timeout_per_cell}
    labels = args.variants.split(",")
    commit = _commit()  # at the start: the tree may change while a long comparison runs
    extras = {label: variant(label) for label in labels}
    for networks in args.networks.split(","):
        for noise in args.rows.split(","):
            runs = {}
            for label in labels:
                entry = run(
                    noise,
                    networks,
                    args.p0,
                    args.workers,
                    journal_dir,
                    {**options, **extras[label], **(hand(noise, networks, args.controller) if label == "hand" else {})},
                    controller=args.controller,
                    label=label.replace(":", "_").replace("=", ""),
                )
                runs[label] = entry
                row = entry["row"]
                steps = f"steps {row['engine_steps']} (+{row['engine_steps_reboxed']} reboxed)"
                print(label, verification.format_row(noise, row, None), f"cpu s {row['cpu_seconds']:.0f}", steps, flush=True)
            doc = json.loads(COMPARED.read_text()) if COMPARED.exists() else {}
            key = f"{noise}/{_networks_key(networks, args.controller)}" + ("" if args.p0 is None else f"/{args.p0[0]:g},{args.p0[1]:g}")
            first = runs[labels[0]]["row"]
            runs["ratio_wall"] = {k: e["row"]["wall_seconds"] / first["wall_seconds"] for k, e in runs.items() if k != labels[0]}
            runs["ratio_cpu"] = {
                k: e["row"]["cpu_seconds"] / first["cpu_seconds"] for k, e in runs.items() if k not in (labels[0], "ratio_wall")
            }
            runs["ratio_steps"] = {
                k: (e["row"]["engine_steps"] + 2 * e["row"]["engine_steps_reboxed"])
                / (first["engine_steps"] + 2 * first["engine_steps_reboxed"])
                for k, e in runs.items()
                if k not in (labels[0], "ratio_wall", "ratio_cpu")
            }
            runs["date"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
            runs["commit"] = commit
            earlier = doc.get(key)  # a single comparison (written before --variants) becomes the first of the list
            doc[key] = {"runs": (earlier["runs"] if "runs" in earlier else [earlier]) if earlier else []}
            _cells_apart(key, len(doc[key]["runs"]), runs)
            doc[key]["runs"].append(runs)
            COMPARED.write_text(_dumps(doc))


def _dumps(doc: dict) -> str:
    """``doc`` as JSON, indented, with each list of plain values (a cell's row) on one line: with
    every value on its own line, the results of a few dozen rows pass 5 MB. Checked by reading it
    back (a string holding a bracket could fool the pattern): if it differs, plain indented JSON."""
    text = json.dumps(doc, indent=1)
    packed = re.sub(r"\[\s*\n\s*([^\[\]{}]*?)\s*\]", lambda m: "[" + re.sub(r",\s*\n\s*", ", ", m.group(1)) + "]", text)
    return packed if json.loads(packed) == json.loads(text) else text


def _commit() -> str:
    """The worktree's commit (and whether it had changes): which code a comparison measured."""
    import subprocess

    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    return git("rev-parse", "--short", "HEAD") + ("+changes" if git("status", "--porcelain", "--untracked-files=no") else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", default="contrast,blur,composite")
    parser.add_argument("--networks", default="paper")
    parser.add_argument("--controller", help="the controller of another set (e.g. --networks ours --controller paper)")
    parser.add_argument("--p0", nargs=2, type=float, help="a sub-range of the rows' initial positions")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--journal-dir", default="/tmp/percver-bench-mountain-car", help="journals (large; not in the repository)")
    parser.add_argument("--timeout-per-cell", type=float, help="override the case's default")
    parser.add_argument("--out", default=str(RESULTS / "mountain_car.json"))
    parser.add_argument("--combine", action="store_true", help="no run: join the rows' --p0 slices in --out into one row each")
    parser.add_argument(
        "--survey",
        action="store_true",
        help=f"a map of where the row verifies, not the row: no refinement, at most {SURVEY_SPLITS} in-cell "
        "splits; stored as <row>/<networks>/survey/<lo>,<hi> and never combined",
    )
    parser.add_argument(
        "--compare",
        action="store_true",
        help="each row once per --variants entry, back to back from fresh journals (the hand layout, adaptive splitters "
        "with no layout); summaries in bench/results/mountain_car_adaptive.json, per-cell rows beside it",
    )
    parser.add_argument(
        "--variants", default="hand,adaptive", help="for --compare: hand, adaptive, adaptive:key=value:... (comma-separated)"
    )
    args = parser.parse_args()
    out = Path(args.out)
    if args.compare:
        compare(args)
        return
    if args.combine:
        doc = json.loads(out.read_text())
        for networks in args.networks.split(","):
            key = _networks_key(networks, args.controller)
            for noise in args.rows.split(","):
                entry = combine(doc, noise, key)
                doc[f"{noise}/{key}/slices"] = entry
                out.write_text(_dumps(doc))
                print(verification.format_row(noise, entry["row"], entry["paper"]), "gaps:", entry["gaps"], flush=True)
        return
    journal_dir = Path(args.journal_dir)
    journal_dir.mkdir(parents=True, exist_ok=True)
    options = {} if args.timeout_per_cell is None else {"timeout_per_cell": args.timeout_per_cell}
    if args.survey:
        options.update(refine=False, max_splits=SURVEY_SPLITS)
    for networks in args.networks.split(","):
        for noise in args.rows.split(","):
            entry = run(noise, networks, args.p0, args.workers, journal_dir, options, args.survey, args.controller)
            doc = json.loads(out.read_text()) if out.exists() else {}
            doc[
                f"{noise}/{_networks_key(networks, args.controller)}"
                + ("/survey" if args.survey else "")
                + ("" if args.p0 is None else f"/{args.p0[0]:g},{args.p0[1]:g}")
            ] = entry
            out.write_text(_dumps(doc))
            print(verification.format_row(noise, entry["row"], entry["paper"]), flush=True)


if __name__ == "__main__":
    main()
