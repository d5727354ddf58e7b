"""``percver cases CASE STAGE``: run one stage of a case study (``percver cases mountain-car data|train|evaluate|verify``)."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

from percver.errors import InputError

# The authors' data is not in the package; where it is found (see percver.cases.mountain_car.networks.default_shared).
SHARED = (
    "the authors' data, read-only beside the repository (default: $PERCVER_SHARED, else ../shared/data "
    "beside the working directory or one of its parents)"
)


def register(sub) -> None:
    parser = sub.add_parser("cases", help="run a stage of a case study of the paper (data, train, evaluate, verify)",
                            description="Stages of the paper's case studies.")  # fmt: skip
    cases = parser.add_subparsers(dest="case", metavar="CASE")
    mountain_car = cases.add_parser(
        "mountain-car",
        help="image-based Mountain Car under contrast and blur (paper, section 5.1, Appendix A)",
        description="Image-based Mountain Car: data set D, models (torch -> ONNX), state-estimation metric, verification (Table 1).",
    )
    mountain_car.set_defaults(func=lambda args: _usage(mountain_car))
    parser.set_defaults(func=lambda args: _usage(parser))
    stages = mountain_car.add_subparsers(dest="stage", metavar="STAGE")

    data = stages.add_parser("data", help="render the paper's training set D (2000 positions x 41 images) to .npz")
    data.add_argument("--out", default="mountain_car_data.npz", help="the .npz to write (default: %(default)s)")
    data.add_argument("--positions", type=int, default=2000, help="evenly spaced positions (default: %(default)s)")
    data.add_argument(
        "--per-position", type=int, default=20, help="contrasted and blurred images per position, each (default: %(default)s)"
    )
    data.add_argument("--seed", type=int, default=0, help="seed of the noise levels (default: %(default)s)")
    data.add_argument(
        "--grid", action="store_true", help="the same evenly spaced noise levels at every position (default: one random level per slice)"
    )
    _common(data)
    data.set_defaults(func=_data)

    train = stages.add_parser("train", help="train generator, contrast, blur, estimator and controller; write ONNX")
    train.add_argument("--data", required=True, help="data set from `percver cases mountain-car data`")
    train.add_argument("--out", default="mountain_car_networks", help="directory for ROLE.onnx and networks.json (default: %(default)s)")
    train.add_argument(
        "--preset",
        default="paper",
        choices=["paper", "small"],
        help="network sizes: the paper's, or the narrower ones percver ships (default: %(default)s)",
    )
    train.add_argument(
        "--models", default="generator,contrast,blur,estimator,controller", help="comma-separated subset to train (default: all)"
    )
    train.add_argument("--seed", type=int, default=0, help="seed of split, initialisation and batches (default: %(default)s)")
    train.add_argument("--epochs-scale", type=float, default=1.0, help="multiply every model's epochs (default: %(default)s)")
    train.add_argument("--composites", type=int, help="synthetic composite images for the estimator (default: 50 per position)")
    train.add_argument("--threads", type=int, default=1, help="torch threads (default: %(default)s; the models are small)")
    _common(train)
    train.set_defaults(func=_train)

    evaluate = stages.add_parser("evaluate", help="the paper's state-estimation metric: plots and summary JSON")
    evaluate.add_argument("--networks", default="ours", help="ours (shipped; default), paper (the authors', from the shared data) or DIR")
    evaluate.add_argument("--controller", help="take the controller from another set: ours, paper, DIR or a network file")
    evaluate.add_argument("--shared", help=SHARED)
    evaluate.add_argument("--noises", default="canonical,contrast,blur,composite", help="comma-separated noise kinds (default: all)")
    evaluate.add_argument("--trajectories", type=int, default=1000, help="random closed-loop runs per noise kind (default: %(default)s)")
    evaluate.add_argument("--steps", type=int, default=150, help="horizon of each run (default: %(default)s)")
    evaluate.add_argument("--seed", type=int, default=0, help="seed of initial positions and noise levels (default: %(default)s)")
    evaluate.add_argument("--out", default="mountain_car_evaluation", help="directory for summary.json and PNGs (default: %(default)s)")
    evaluate.add_argument("--no-plots", action="store_true", help="write summary.json only")
    _common(evaluate)
    evaluate.set_defaults(func=_evaluate)
    _register_mc_verify(stages)
    _register_f1tenth(cases)


def _common(parser) -> None:
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def _command_line() -> str | None:
    """This process's command line, recorded with data sets and networks (None when not run as ``percver``)."""
    return "percver " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["cases"] else None


def _usage(parser) -> int:
    parser.print_help()
    return 2


def _names(text: str, option: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise InputError(f"{option} needs at least one name")
    return names


def _data(args) -> int:
    from percver.cases import mountain_car

    dataset = mountain_car.generate(args.positions, args.per_position, seed=args.seed, stratified=not args.grid,
                                    progress=not args.no_progress)  # fmt: skip
    dataset.meta["command"] = _command_line()
    path = dataset.save(args.out)
    record = {"path": str(path), "examples": len(dataset), "positions": dataset.n_positions,
              "per_position": dataset.per_position, "seed": args.seed, "bytes": path.stat().st_size}  # fmt: skip
    if args.json:
        print(json.dumps(record))
    else:
        print(f"{len(dataset)} examples ({dataset.n_positions} positions x (1 + 2 x {dataset.per_position})) -> {path} "
              f"({record['bytes'] / 1e6:.1f} MB)")  # fmt: skip
    return 0


def _train(args) -> int:
    from percver.cases.mountain_car import training

    result = training.train(
        args.data,
        args.out,
        preset=args.preset,
        models=_names(args.models, "--models"),
        seed=args.seed,
        epochs_scale=args.epochs_scale,
        composites=args.composites,
        threads=args.threads,
        progress=not args.no_progress and not args.json,
        command=_command_line(),
    )
    if args.json:
        print(json.dumps({"out": str(Path(args.out).resolve()), **result.record}))
    else:
        print(result.summary())
        print(f"networks and networks.json -> {Path(args.out).resolve()}")
    return 0


def _evaluate(args) -> int:
    from percver.cases import mountain_car

    evaluation = mountain_car.evaluate(
        args.networks,
        noises=_names(args.noises, "--noises"),
        trajectories=args.trajectories,
        steps=args.steps,
        seed=args.seed,
        controller=args.controller,
        shared=args.shared,
        progress=not args.no_progress and not args.json,
    )
    out = Path(args.out)
    summary = evaluation.to_json(out / "summary.json")
    plots = [] if args.no_plots else evaluation.plot(out)
    if args.json:
        print(json.dumps({**evaluation.summary(), "summary": str(summary), "plots": [str(p) for p in plots]}))
    else:
        print(evaluation.table())
        print(f"summary: {summary}" + (f"; plots: {', '.join(p.name for p in plots)}" if plots else ""))
    return 0


def _register_mc_verify(stages) -> None:
    verify = stages.add_parser(
        "verify",
        help="verify a row of Table 1 (or a slice): the goal with reward > 90 from p0 under contrast/blur",
        description="Verify the closed loop generator -> noise model -> estimator -> controller -> plant: from v0 = 0, "
        "reach p >= 0.45 within 150 steps with reward > 90. Prints the table row next to the paper's and writes "
        "result.json, row.json, coverage.png (cells over p0 x noise) and tube.png (reach tube of p) to --out. "
        "Exit status: 0 verified, 3 unknown cells left, 4 falsified.",
    )
    verify.add_argument(
        "--noise", default="contrast", choices=["canonical", "contrast", "blur", "composite"], help="the row (default: %(default)s)"
    )
    verify.add_argument("--p0", nargs=2, type=float, metavar=("LO", "HI"), help="initial positions (default: the row's)")
    verify.add_argument("--delta-c", nargs=2, type=float, metavar=("LO", "HI"), help="contrast range (default: the row's)")
    verify.add_argument("--delta-b", nargs=2, type=float, metavar=("LO", "HI"), help="blur range (default: the row's)")
    verify.add_argument("--networks", default="ours", help="ours (shipped; default), paper (the authors', from the shared data) or DIR")
    verify.add_argument(
        "--controller",
        help="take the controller from another set: paper, ours, DIR or a network file "
        "(e.g. --networks ours --controller paper: our perception, the authors' verified controller)",
    )
    verify.add_argument("--shared", help=SHARED)
    verify.add_argument(
        "--split",
        metavar="NAME=W,...",
        help="initial cell widths, e.g. p=0.005,dc=0.2 (default: the row's bands, or the adaptive splitter where it has none)",
    )
    verify.add_argument("--min-width", metavar="NAME=W,...", help="refinement stops at these widths, e.g. p=0.0003,dc=0.02")
    verify.add_argument("--no-refine", action="store_true", help="report a grid's unknown cells instead of bisecting them")
    verify.add_argument(
        "--max-splits", type=int, help="in-cell splits per cell (default: the row's bands' own, 16 or 64, or the adaptive splitter's)"
    )
    verify.add_argument("--timeout-per-cell", type=float, help="seconds before a cell is stopped and bisected")
    verify.add_argument("--time-limit", type=float, metavar="SECONDS", help="wall seconds for the row; what did not finish is unknown")
    verify.add_argument("--workers", type=int, help="threads (default: all cores)")
    verify.add_argument("--journal", help="JSONL journal: finished cells are kept, a rerun resumes")
    verify.add_argument("--out", default="mountain_car_verification", help="directory for the JSON and PNGs (default: %(default)s)")
    _common(verify)
    verify.set_defaults(func=_mc_verify)


def _widths(text: str | None, option: str) -> dict | None:
    """``p=0.005,dc=0.2`` as ``{"p": 0.005, "dc": 0.2}``."""
    if text is None:
        return None
    out = {}
    for item in _names(text, option):
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise InputError(f"{option} takes NAME=WIDTH pairs such as p=0.005,dc=0.2; '{item}' is not one") from None
    return out


def _mc_verify(args) -> int:
    from percver.cases.mountain_car import verification
    from percver.commands import EXIT, unknown_lines

    options = {k: v for k, v in (("split", _widths(args.split, "--split")), ("min_width", _widths(args.min_width, "--min-width")),
                                 ("timeout_per_cell", args.timeout_per_cell), ("time_limit", args.time_limit),
                                 ("workers", args.workers), ("max_splits", args.max_splits),
                                 ("journal", args.journal)) if v is not None}  # fmt: skip
    result = verification.verify(
        args.noise,
        args.p0,
        args.networks,
        delta_c=args.delta_c,
        delta_b=args.delta_b,
        controller=args.controller,
        shared=args.shared,
        progress=not args.no_progress and not args.json,
        **({"refine": False} if args.no_refine else {}),
        **options,
    )
    record = verification.save(result, args.out, shared=args.shared)
    if args.json:
        print(json.dumps(record))
    else:
        print(verification.format_row(args.noise, record["row"], record["paper"]))
        for line in unknown_lines(record["reasons"]):
            print(line)
        cex = result.counterexample
        if cex is not None:
            print(f"falsified: from p0 = {cex.initial['p']:.9g}: {cex.violated} fails at step {cex.step}")
        print(f"result, row, coverage and tube -> {Path(args.out).resolve()}")
    return EXIT[result.verdict]


# ------------------------------------------------------------------------------------------ F1/10
def _register_f1tenth(cases) -> None:
    f1 = cases.add_parser(
        "f1tenth",
        help="the F1/10 car with LiDAR under adversarial noise (paper, section 5.2, Appendix B)",
        description="F1/10: simulated real runs, particle-filter poses, t_Delta labels, knock-out classifiers and "
        "denoiser (torch -> ONNX), Table 2 metrics and Figure 6.",
    )
    f1.set_defaults(func=lambda args: _usage(f1))
    stages = f1.add_subparsers(dest="stage", metavar="STAGE")
    shared = "the F1/10 data folder (default: $PERCVER_F1TENTH_DATA, $PERCVER_SHARED/f1tenth or ../shared/data/f1tenth)"

    simulate = stages.add_parser("simulate", help="drive the 12 controllers through the first turn of the 'real' hall")
    simulate.add_argument("--out", default="f1tenth_runs.npz", help="measurements to write (default: %(default)s)")
    simulate.add_argument(
        "--runs", default="paper", help="runs per controller, or 'paper' for the real data's 9-10 each, 116 in all (default: %(default)s)"
    )
    simulate.add_argument("--controllers", help="comma-separated controller names (default: the 12 of the paper)")
    simulate.add_argument("--covered", action="store_true", help="cover the removable reflective panels")
    simulate.add_argument("--seed", type=int, default=0, help="seed of starts and sensor noise (default: %(default)s)")
    simulate.add_argument("--data", help=shared)
    _common(simulate)
    simulate.set_defaults(func=_f1_simulate)

    estimate = stages.add_parser("estimate", help="particle-filter poses for every scan -> the training set D")
    estimate.add_argument("--runs", required=True, help="runs from `percver cases f1tenth simulate`")
    estimate.add_argument("--out", default="f1tenth_training.npz", help="training set to write (default: %(default)s)")
    estimate.add_argument("--particles", type=int, default=300, help="particles per run (default: %(default)s)")
    estimate.add_argument("--seed", type=int, default=0, help="seed of the filter (default: %(default)s)")
    _common(estimate)
    estimate.set_defaults(func=_f1_estimate)

    label = stages.add_parser("label", help="choose t_Delta* and label the rays of D")
    label.add_argument("--training", required=True, help="training set from `percver cases f1tenth estimate`")
    label.add_argument("--out", default="f1tenth_labels.npz", help="labels to write (default: %(default)s)")
    label.add_argument("--plot", help="PNG of the t_Delta curve")
    _common(label)
    label.set_defaults(func=_f1_label)

    train = stages.add_parser("train", help="train knock-out classifiers and the denoiser; write ONNX")
    train.add_argument("--training", required=True, help="training set from `percver cases f1tenth estimate`")
    train.add_argument("--labels", required=True, help="labels from `percver cases f1tenth label`")
    train.add_argument("--out", default="f1tenth_models", help="directory for the networks (default: %(default)s)")
    train.add_argument("--sizes", default="3x100,4x100,5x100,6x100,6x200", help="classifier sizes (default: %(default)s)")
    train.add_argument("--epochs", type=int, default=60, help="classifier epochs (default: %(default)s)")
    train.add_argument("--denoiser-epochs", type=int, default=60, help="denoiser epochs (default: %(default)s)")
    train.add_argument("--test-share", type=float, default=0.2, help="share of runs held out (default: %(default)s)")
    train.add_argument("--threads", type=int, default=2, help="torch threads (default: %(default)s)")
    train.add_argument("--seed", type=int, default=0, help="seed of split and training (default: %(default)s)")
    train.add_argument("--data", help=shared)
    _common(train)
    train.set_defaults(func=_f1_train)

    evaluate = stages.add_parser("evaluate", help="Table 2 metrics, trajectory metric and Figure 6 for a set of models")
    evaluate.add_argument("--training", required=True, help="training set from `percver cases f1tenth estimate`")
    evaluate.add_argument("--labels", required=True, help="labels from `percver cases f1tenth label`")
    evaluate.add_argument("--models", default="f1tenth_models", help="DIR from `train`, or 'paper' for the authors' (default: %(default)s)")
    evaluate.add_argument("--out", default="f1tenth_evaluation", help="directory for evaluation.json and PNGs (default: %(default)s)")
    evaluate.add_argument("--plot-size", default="5x100", help="classifier whose runs are plotted (default: %(default)s)")
    evaluate.add_argument("--no-plots", action="store_true", help="write evaluation.json only")
    evaluate.add_argument("--data", help=shared)
    _common(evaluate)
    evaluate.set_defaults(func=_f1_evaluate)

    verify = stages.add_parser("verify", help="Table 1's F1/10 row (or a slice): LiDAR -> classifier -> denoiser -> controller")
    verify.add_argument(
        "--y1",
        nargs=2,
        type=float,
        metavar=("LO", "HI"),
        default=[0.65, 0.85],
        help="initial distance to the left wall, m (default: %(default)s)",
    )
    verify.add_argument(
        "--cell", type=float, help="uniform cells of this width in y1, m (the paper's: 5e-5; default: the adaptive splitter's)"
    )
    verify.add_argument("--networks", default="paper", help="paper (the authors' classifier and denoiser), ours or DIR from `train`")
    verify.add_argument("--canonical", action="store_true", help="verify the loop without classifier and denoiser")
    verify.add_argument("--max-splits", type=int, help="in-cell splits and forks per cell (default: the engine's, 64 with --cell)")
    verify.add_argument("--workers", type=int, help="threads (default: all cores)")
    verify.add_argument("--journal", help="JSONL journal: finished cells are kept, a rerun resumes")
    verify.add_argument("--out", default="f1tenth_verification", help="directory for result.json and row.json (default: %(default)s)")
    verify.add_argument("--data", help=shared)
    _common(verify)
    verify.set_defaults(func=_f1_verify)


def _count(text: str, option: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{option} takes a whole number or 'paper', got '{text}'") from None


def _f1_report(args, record: dict, lines) -> int:
    if args.json:
        print(json.dumps(record, default=str))
    else:
        print("\n".join(lines))
    return 0


def _f1_simulate(args) -> int:
    from percver.cases.f1tenth import study

    names = _names(args.controllers, "--controllers") if args.controllers else None
    runs = args.runs if args.runs == "paper" else _count(args.runs, "--runs")
    record = study.run_simulate(args.out, runs_per_controller=runs, names=names, seed=args.seed, covered=args.covered, data=args.data)
    cal, real = record["calibration"], record["calibration"]["real"]
    return _f1_report(
        args,
        record,
        [
            f"{cal['runs']} runs, {cal['scans']} scans, {cal['crashes']} crashes (real: {real['runs']} runs, {real['crashes']} crashes)",
            f"reflected rays per 21-ray scan {cal['reflected_per_scan']:.2f} (real {real['uncovered']['reflected_per_scan']:.2f}); "
            f"other rays within 5 cm {100 * cal['within_5cm']:.1f}% (real {100 * real['covered']['within_5cm']:.1f}-"
            f"{100 * real['uncovered']['within_5cm']:.1f}%)",
            f"runs -> {record['path']}",
        ],
    )


def _f1_estimate(args) -> int:
    from percver.cases.f1tenth import study

    record = study.run_estimate(
        args.runs, args.out, particles=args.particles, seed=args.seed, progress=not args.no_progress and not args.json
    )
    error = record["pose_error"]["after_1s"]
    return _f1_report(
        args,
        record,
        [
            f"{record['scans']} scans in {record['seconds']:.0f} s; pose error after 1 s: mean {100 * error['position_mean_m']:.1f} cm, "
            f"median {100 * error['position_median_m']:.1f} cm, heading {error['heading_mean_deg']:.2f} deg",
            f"training set -> {record['path']}",
        ],
    )


def _f1_label(args) -> int:
    from percver.cases.f1tenth import study

    record = study.run_label(args.training, args.out, plot=args.plot)
    return _f1_report(
        args,
        record,
        [
            f"t_Delta* = {record['t_delta']:.3f} m: mean error {record['error_at_best_m']:.3f} m per ray "
            f"(canonical alone {record['error_without_noise_model_m']:.3f} m); {record['labelled_per_scan']:.2f} rays labelled per scan",
            *(
                [
                    f"whole-scan accuracy ceiling of these labels (simulator's world, {record['label_ceiling']['poses']} scans): "
                    f"{100 * record['label_ceiling']['ceiling']:.1f}%"
                ]
                if "label_ceiling" in record
                else []
            ),
            f"labels -> {record['path']}",
        ],
    )


def _f1_train(args) -> int:
    from percver.cases.f1tenth import study

    record = study.run_train(
        args.training,
        args.labels,
        args.out,
        sizes=_names(args.sizes, "--sizes"),
        epochs=args.epochs,
        denoiser_epochs=args.denoiser_epochs,
        threads=args.threads,
        test_share=args.test_share,
        seed=args.seed,
        data=args.data,
        progress=not args.no_progress and not args.json,
    )
    lines = ["size     WSA train  WSA test  control err (sum, train)  mean deg (test)"]
    for size, row in record["classifiers"].items():
        test = row["test"] or {"whole_scan_accuracy": float("nan"), "control_error": {"mean_deg": float("nan")}}
        lines.append(
            f"{size:8s} {100 * row['train']['whole_scan_accuracy']:8.1f}% {100 * test['whole_scan_accuracy']:8.1f}% "
            f"{row['train']['control_error']['sum']:24.0f}  {test['control_error']['mean_deg']:.2f}"
        )
    lines.append(f"networks -> {record['out']}")
    return _f1_report(args, record, lines)


def _f1_evaluate(args) -> int:
    from percver.cases.f1tenth import study

    record = study.run_evaluate(
        args.training, args.labels, args.models, args.out, plot_size=args.plot_size, plots_wanted=not args.no_plots, data=args.data
    )
    lines = [
        f"{record['runs']} runs ({record['real_crashes']} crashes), canonical control error {record['canonical_control_error']['sum']:.0f}",
        "size     WSA     control err  simulated crashes",
    ]
    for size, row in record["noise_models"].items():
        lines.append(f"{size:8s} {100 * row['whole_scan_accuracy']:5.1f}%  {row['control_error']['sum']:11.0f}  {row['simulated_crashes']}")
    lines.append(f"evaluation -> {record['out']}")
    return _f1_report(args, record, lines)


def _f1_verify(args) -> int:
    from percver.cases.f1tenth import verification
    from percver.commands import EXIT

    result = verification.verify(
        tuple(args.y1),
        args.networks,
        noise_model=not args.canonical,
        cell=args.cell,
        data=args.data,
        **({} if args.max_splits is None else {"max_splits": args.max_splits}),
        workers=args.workers,
        journal=args.journal,
        progress=not args.no_progress and not args.json,
    )
    record = verification.save(result, args.out, data=args.data)
    lines = [verification.table(result, args.data)]
    lines += [f"unknown: {n} cells lost at step {step}" for step, n in record["unknown_steps"]]
    if result.counterexample is not None:
        cex = result.counterexample
        lines.append(f"falsified: from y1 = {cex.initial['y1']:.9g}: {cex.violated} fails at step {cex.step}")
    lines.append(f"result and row -> {Path(args.out).resolve()}")
    _f1_report(args, record, lines)
    return EXIT[result.verdict]
