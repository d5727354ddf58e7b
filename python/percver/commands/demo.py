"""``percver demo``: the Mountain Car case study in miniature, from the installed package alone.

The networks percver ships (generator, contrast model, estimator and controller, trained by
``percver cases mountain-car train --preset small --seed 0``) drive the car from a slice of
initial positions under a range of contrast; the demo verifies that every run reaches the goal
with reward > 90, prints the row in the paper's Table 1 format, writes the result as JSON and,
where matplotlib is installed, draws the reach tube of p over simulated runs.
``percver cases mountain-car verify --networks paper`` runs the paper's full rows.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from percver.commands import EXIT, unknown_lines

# A slice the shipped networks verify in 11.5 s wall with 2 threads on this project's 2-core
# machine when idle (60 cells; 3-4 min when the machine's load average is ~15).
P0 = (-0.5, -0.498)
DELTA_C = (0.5, 2.0)
PLOT_HINT = 'the figure needs matplotlib: pip install "percver[plot]"'

DESCRIPTION = """\
Verify a slice of the Mountain Car case study (paper, section 5.1) with the networks percver
ships: from p0 in [LO, HI], v0 = 0, under contrast in [LO, HI], every run reaches the goal
p >= 0.45 within 150 steps with reward > 90. Prints the row in the paper's Table 1 format,
writes the result as JSON next to the figure (OUT with .json) and, with matplotlib installed,
the figure OUT: the reach tube of p over simulated runs and the reward.

Exit status: 0 verified, 3 unknown, 4 falsified, 1 bad input.
'percver cases mountain-car verify --networks paper' runs the paper's full rows."""


def register(sub) -> None:
    import argparse

    parser = sub.add_parser(
        "demo",
        help="verify a slice of the Mountain Car case study with the shipped networks and plot it",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", default="percver-demo.png", help="PNG of the reach tube; the JSON goes beside it (default: %(default)s)")
    parser.add_argument("--p0", nargs=2, type=float, default=P0, metavar=("LO", "HI"), help="initial positions (default: %(default)s)")
    parser.add_argument(
        "--delta-c", nargs=2, type=float, default=DELTA_C, metavar=("LO", "HI"), help="contrast range (default: %(default)s)"
    )
    parser.add_argument("--workers", type=int, help="threads (default: all cores)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(func=run)


def run(args) -> int:
    from percver.cases.mountain_car import verification

    started = time.time()
    result = verification.verify(
        "contrast", args.p0, "ours", delta_c=args.delta_c, workers=args.workers, progress=not args.no_progress and not args.json
    )
    figure = Path(args.out)
    record = figure.with_suffix(".json")
    doc = {
        "verdict": result.verdict,
        "init": result.init,
        "row": verification.table_row(result),
        "reasons": verification.reasons(result),
        "seconds": time.time() - started,
        "json": str(record),
        "plot": None,
        "domain_exits": result.domain_exits,
    }
    # The result is written before any plotting, so a missing or failing matplotlib never loses it.
    record.write_text(json.dumps(doc, indent=1))
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        plotted = None
    else:
        plotted = verification.plot_tube(result, figure, verification.closed_loop("contrast", "ours"))
        doc["plot"] = str(plotted)
        record.write_text(json.dumps(doc, indent=1))
    if args.json:
        print(json.dumps(doc))
        return EXIT[result.verdict]
    (p_lo, p_hi), (c_lo, c_hi) = result.init["p"], result.init["dc"]
    print(
        f"Mountain Car with percver's shipped networks: from p0 in [{p_lo:g}, {p_hi:g}], v0 = 0, contrast in "
        f"[{c_lo:g}, {c_hi:g}], reach p >= 0.45 within 150 steps with reward > 90"
    )
    print(verification.format_row("contrast", doc["row"], verification.published("contrast")))
    for line in unknown_lines(doc["reasons"]):
        print(line)
    print(f"verdict: {result.verdict} ({100 * result.coverage:.2f}% of the slice verified) in {doc['seconds']:.0f} s")
    print(f"result: {record}")
    print(f"reach tube: {plotted}" if plotted else PLOT_HINT)
    return EXIT[result.verdict]
