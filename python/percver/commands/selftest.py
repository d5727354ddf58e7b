"""``percver selftest``: verify random closed loops and check every result against an independent
float oracle (numpy, onnxruntime, scipy); see docs/selftest.md.

Exit status: 0 when no check failed, 1 when one did (its shrunk reproducer is printed), 2 bad usage.
"""

from __future__ import annotations

import sys


def register(sub) -> None:
    parser = sub.add_parser(
        "selftest",
        help="verify random closed loops and check the results against an independent float oracle",
        description="Generate random closed loops (discrete and continuous plants, networks, conditions, uncertain "
        "parameters, accumulators, properties, verify options), verify each with percver and check the result against "
        "sampled runs of an oracle that does not use percver: a verified cell has no violating run, every run lies in "
        "the reach boxes, a counterexample replays. A violation is shrunk and printed as a runnable Python reproducer. "
        "Exit status: 0 clean, 1 a violation, 2 bad usage.",
    )
    parser.add_argument("--minutes", type=float, help="stop after this long (default: 1 unless --programs is given)")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed: program k of seed s is always the same (default: %(default)s)")
    parser.add_argument("--programs", type=int, help="stop after this many programs")
    parser.add_argument("--start", type=int, default=0, help="first program (e.g. the one a report names; default: %(default)s)")
    parser.add_argument("--runs", type=int, default=350, help="oracle runs sampled per program (default: %(default)s)")
    parser.add_argument("--keep-going", action="store_true", help="report every violation, not just the first")
    parser.add_argument("--no-shrink", action="store_true", help="print the reproducer of the program as generated")
    parser.add_argument(
        "--shrink-seconds", type=float, default=120.0, help="CPU seconds spent shrinking a violation (default: %(default)s)"
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(func=run)


def run(args) -> int:
    from percver.selftest import run_campaign

    if (
        args.minutes is not None
        and args.minutes <= 0
        or args.programs is not None
        and args.programs <= 0
        or args.runs <= 0
        or args.start < 0
    ):
        print("percver selftest: error: --minutes, --programs and --runs must be positive, --start not negative", file=sys.stderr)
        return 2
    minutes = args.minutes if args.minutes is not None or args.programs is not None else 1.0

    def show(finding):
        v = finding.shrunk_violation
        print(f"\nVIOLATION in program {finding.index} ({finding.violation.kind}): {finding.violation.message}", flush=True)
        if finding.shrunk != finding.program:
            print(f"shrunk: {v.message}")
        print(f"reproducer:\n{'-' * 72}\n{finding.reproducer}{'-' * 72}", flush=True)

    tally = run_campaign(
        args.seed,
        programs=args.programs,
        minutes=minutes,
        runs=args.runs,
        start=args.start,
        shrink_seconds=0.0 if args.no_shrink else args.shrink_seconds,
        keep_going=args.keep_going,
        progress=not args.no_progress,
        on_finding=show,
    )
    print(f"percver selftest: {tally.line()}")
    return 1 if tally.findings else 0
