"""``percver validate``: diagnose a model against measurements and write an HTML report."""

from __future__ import annotations

import inspect
import json
import runpy
from pathlib import Path

from percver.errors import InputError

BUILT_IN = ("lidar-f1tenth", "mc-camera")


def register(sub) -> None:
    parser = sub.add_parser(
        "validate",
        help="compare a model with measurements, name the missing effects, write a report",
        description="Compare a model with measured data, rank candidate physical effects on held-out data, "
        "add them while they help, and write an HTML report.",
    )
    parser.add_argument(
        "--model",
        required=True,
        help="lidar-f1tenth (canonical F1/10 LiDAR on the square track), mc-camera (Mountain Car camera), "
        "or PLANT.py:NAME (a model, plant or sensor object, or a function returning one, in a Python file)",
    )
    parser.add_argument("--data", required=True, help="measurements (.npz or .parquet, see percver.Measurements)")
    parser.add_argument("--out", default="validation-report", help="directory for the HTML report (default: %(default)s)")
    parser.add_argument("--effects", help="comma-separated effect names to consider (default: the whole library)")
    parser.add_argument("--max-steps", type=int, default=6, help="most effects to add (default: %(default)s)")
    parser.add_argument(
        "--min-gain",
        type=float,
        default=0.05,
        help="smallest held-out share of the current model's squared error an effect must remove "
        "(lower end of its bootstrap interval; default: %(default)s)",
    )
    parser.add_argument(
        "--learn",
        action="store_true",
        help="when effects leave a localized residual, train the paper's learned noise model on it "
        "(a knock-out classifier or a generative model; needs torch) and write it as ONNX into --out",
    )
    parser.add_argument("--dropna", action="store_true", help="drop rows with NaN or inf instead of refusing the data")
    parser.add_argument("--seed", type=int, default=0, help="seed of the folds and the bootstrap (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the diagnosis as JSON instead of tables")
    parser.add_argument(
        "--verify",
        metavar="CONFIG.toml",
        help="then verify the diagnosed model: the config of 'percver verify' whose [plant] python = "
        '"FILE.py:NAME" names a function taking the diagnosed plant (or sensor expressions, or a '
        "LearnedSensor whose stages() go into the loop) and returning the pv.ClosedLoop; exit status as 'percver verify' (0 verified, 3 unknown, 4 falsified)",
    )
    parser.add_argument(
        "--uncertainty",
        default="ci95",
        help="with --verify: fitted parameters as their bootstrap confidence intervals (ci95, ci99, "
        "a level such as 0.9) or 'none' for the fitted values (default: %(default)s)",
    )
    parser.add_argument(
        "--per",
        choices=("run", "step"),
        default="run",
        help="with --verify: the parameter intervals held over a run (constants of the system) or re-drawn "
        "every step (parameters that drift; looser) (default: %(default)s)",
    )
    parser.add_argument(
        "--residual",
        help="with --verify: the unexplained residual as a bounded disturbance, 'max' (the largest "
        "measured) or a quantile such as 0.999 (statistical, not worst case); default: none",
    )
    parser.set_defaults(func=run)


def load_model(spec: str):
    """A model from the command line: a built-in name or ``FILE.py:NAME``."""
    if spec == "lidar-f1tenth":
        from percver.sensors import lidar

        return lidar.canonical(lidar.square_track(), lidar.Lidar.f1tenth21())
    if spec == "mc-camera":
        try:
            from percver.cases import mountain_car
        except ImportError:
            raise InputError(
                "--model mc-camera needs percver.cases.mountain_car, which this installation does not have; "
                "pass the camera as FILE.py:NAME instead"
            ) from None
        return mountain_car.canonical_camera()
    path, colon, name = spec.rpartition(":")
    if not colon or not path.endswith(".py"):
        raise InputError(f"--model '{spec}' is neither {' nor '.join(BUILT_IN)} nor FILE.py:NAME")
    if not Path(path).exists():
        raise InputError(f"--model file '{path}' does not exist")
    namespace = runpy.run_path(path)
    if name not in namespace:
        raise InputError(f"'{path}' defines no '{name}'")
    obj = namespace[name]
    # A factory (function or class) builds the model; anything else is the model itself.
    return obj() if inspect.isfunction(obj) or inspect.isclass(obj) else obj


def run(args) -> int:
    from percver import validate
    from percver.measurements import Measurements

    if args.verify is not None and args.json:
        raise InputError("--json prints the diagnosis alone; drop it to run --verify (the result JSON goes into --out)")
    model = load_model(args.model)
    data = Measurements.load(args.data, dropna=args.dropna)
    effects = [name.strip() for name in args.effects.split(",")] if args.effects else None
    diagnosis = validate.diagnose(
        model,
        data,
        effects,
        max_steps=args.max_steps,
        min_gain=args.min_gain,
        learn=args.learn,
        seed=args.seed,
        progress=not args.no_progress and not args.json,
    )
    page = diagnosis.to_html(args.out).resolve()
    if args.json:
        print(json.dumps({**json.loads(diagnosis.to_json()), "report": str(page)}, indent=2))
        return 0
    if diagnosis.rankings:
        print("candidate effects (held-out share of the baseline error removed):")
        print(diagnosis.rankings[0].table(added=diagnosis.effects))
        print()
    print(diagnosis.table())
    print(f"report: {page}")
    return 0 if args.verify is None else verify_diagnosed(diagnosis, args)


def verify_diagnosed(diagnosis, args) -> int:
    """``--verify CONFIG.toml``: the config's loop function applied to the diagnosed model, verified
    with the config's initial set, property and settings; the result JSON goes into ``--out``."""
    from percver.commands.verify import EXIT, Config, report
    from percver.systems import ClosedLoop
    from percver.verification import verify

    config = Config(args.verify)
    spec = config.section("plant").get("python")
    path, colon, name = str(spec).rpartition(":")
    if spec is None or not colon or not path.endswith(".py"):
        raise config.error(
            "[plant] python",
            '--verify needs python = "FILE.py:NAME", a function of the diagnosed model '
            "returning the pv.ClosedLoop (e.g. def loop(plant): return pv.ClosedLoop(plant, stages=[...]))",
        )
    namespace = runpy.run_path(str(config.file("[plant] python", path)))
    function = namespace.get(name)
    if not callable(function):
        raise config.error("[plant] python", f"{path} defines no function '{name}' of the diagnosed model")
    uncertainty = None if args.uncertainty == "none" else _number_or_text(args.uncertainty)
    residual = None if args.residual is None else _number_or_text(args.residual)
    # A learned noise model is verified as the ONNX file written into --out.
    model = diagnosis.system(uncertainty=uncertainty, residual=residual, per=args.per, onnx=args.out, seed=args.seed)
    loop = function(model)
    if not isinstance(loop, ClosedLoop):
        raise config.error("[plant] python", f"{name}(model) returned a {type(loop).__name__}, not a pv.ClosedLoop")
    print(f"\nverifying the diagnosed model ({config.path}):\n{model.validation}")
    result = verify(loop, progress=not args.no_progress, **config.verify_kwargs())
    out = Path(args.out) / "verify.json"
    result.to_json(str(out))
    print(report(result, loop))
    print(result.validity)
    print(f"result: {out.resolve()}")
    return EXIT[result.verdict]


def _number_or_text(value: str):
    try:
        return float(value)
    except ValueError:
        return value
