"""``percver demo``: the Mountain Car case study in miniature, from the installed package alone.

The networks percver ships (generator, contrast model, estimator and controller, trained by
``percver cases mountain-car train --preset small --seed 0``) drive the car from a slice of
initial positions under a range of contrast; the demo verifies that every run reaches the goal
with reward > 90, prints the row in the paper's Table 1 format and draws the reach tube of p over
simulated runs. ``percver cases mountain-car verify`` runs the full rows.
"""

from __future__ import annotations

import json
import time

# A slice the shipped networks verify in about 20 s on 2 cores (measured 2026-11-22, 60 cells).
P0 = (-0.5, -0.498)
DELTA_C = (0.5, 2.0)


def register(sub) -> None:
    parser = sub.add_parser("demo", help="verify a slice of the Mountain Car case study with the shipped networks and plot it",
                            description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="percver-demo.png", help="PNG of the reach tube (default: %(default)s)")
    parser.add_argument("--p0", nargs=2, type=float, default=P0, metavar=("LO", "HI"),
                        help="initial positions (default: %(default)s)")
    parser.add_argument("--delta-c", nargs=2, type=float, default=DELTA_C, metavar=("LO", "HI"),
                        help="contrast range (default: %(default)s)")
    parser.add_argument("--workers", type=int, help="threads (default: all cores)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(func=run)


def run(args) -> int:
    from percver.cases.mountain_car import verification

    started = time.time()
    result = verification.verify("contrast", args.p0, "ours", delta_c=args.delta_c, workers=args.workers,
                                 progress=not args.no_progress and not args.json)
    row = verification.table_row(result)
    verification.plot_tube(result, args.out, verification.closed_loop("contrast", "ours"))
    doc = {"verdict": result.verdict, "init": result.init, "row": row, "reasons": verification.reasons(result),
           "seconds": time.time() - started, "plot": args.out, "domain_exits": result.domain_exits}
    if args.json:
        print(json.dumps(doc))
        return 0
    (p_lo, p_hi), (c_lo, c_hi) = result.init["p"], result.init["dc"]
    print(f"Mountain Car with percver's shipped networks: from p0 in [{p_lo:g}, {p_hi:g}], v0 = 0, contrast in "
          f"[{c_lo:g}, {c_hi:g}], reach p >= 0.45 within 150 steps with reward > 90")
    print(verification.format_row("contrast", row, verification.published("contrast")))
    for variable, first, last, n in doc["reasons"]:
        print(f"unknown: {n} cells, the enclosure of '{variable}' blew up at steps {first}-{last}")
    print(f"verdict: {result.verdict} ({100 * result.coverage:.2f}% of the slice verified) in {doc['seconds']:.0f} s")
    print(f"reach tube: {args.out}")
    return 0
