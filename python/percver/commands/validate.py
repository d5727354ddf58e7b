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
    parser.add_argument("--min-gain", type=float, default=0.05,
                        help="smallest held-out share of the current model's squared error an effect must remove "
                        "(lower end of its bootstrap interval; default: %(default)s)")
    parser.add_argument("--learn", action="store_true",
                        help="when effects leave a localized residual, train the paper's learned noise model on it "
                        "(a knock-out classifier or a generative model; needs torch) and write it as ONNX into --out")
    parser.add_argument("--dropna", action="store_true", help="drop rows with NaN or inf instead of refusing the data")
    parser.add_argument("--seed", type=int, default=0, help="seed of the folds and the bootstrap (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the diagnosis as JSON instead of tables")
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

    model = load_model(args.model)
    data = Measurements.load(args.data, dropna=args.dropna)
    effects = [name.strip() for name in args.effects.split(",")] if args.effects else None
    diagnosis = validate.diagnose(
        model, data, effects, max_steps=args.max_steps, min_gain=args.min_gain, learn=args.learn, seed=args.seed,
        progress=not args.no_progress and not args.json,
    )
    page = diagnosis.to_html(args.out).resolve()
    if args.json:
        print(json.dumps({**json.loads(diagnosis.to_json()), "report": str(page)}, indent=2))
        return 0
    if diagnosis.rankings:
        print("candidate effects (held-out share of the baseline error removed):")
        print(diagnosis.rankings[0].table())
        print()
    print(diagnosis.table())
    print(f"report: {page}")
    return 0
