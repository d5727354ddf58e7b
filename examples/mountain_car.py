"""Image-based Mountain Car, end to end: data -> models -> state-estimation metric (paper, section 5.1).

The defaults are small (about 80 s on this project's 2-core machine; --full about 9 minutes):

    python examples/mountain_car.py           # 400 positions x 10 noise levels, small batches, 100 runs per noise
    python examples/mountain_car.py --full    # the paper's D (82,000 images) and models, 1000 runs per noise

The same stages from the command line, at full size:

    percver cases mountain-car data --out out/mc/data.npz
    percver cases mountain-car train --data out/mc/data.npz --out out/mc/networks
    percver cases mountain-car evaluate --networks out/mc/networks --out out/mc/evaluation
    percver cases mountain-car evaluate --networks paper --out out/mc/evaluation-paper

Times measured on this project's 2-core machine are in percver/cases/mountain_car/README.md.
Verification of the trained chain (Table 1) comes with ``pv.cases.mountain_car.verify``.
"""

import argparse
from pathlib import Path

from percver.cases import mountain_car as mc
from percver.errors import MissingFileError


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="the paper's sizes (about 10 minutes in all)")
    parser.add_argument("--out", default="out/mountain_car", help="output directory (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    positions, per_position, preset, runs = (2000, 20, "paper", 1000) if args.full else (400, 10, "small", 100)
    # With 20x less data than D, smaller batches keep the number of optimisation steps up.
    batches = {} if args.full else {role: {"batch": 64} for role in ("generator", "contrast", "blur", "estimator")}
    out = Path(args.out)

    # 1. Data: canonical gymnasium images, PIL contrast and the paper's blur at evenly spaced positions.
    data = mc.generate(positions, per_position, seed=args.seed)
    data.save(out / "data.npz")
    print(f"data set: {len(data)} images of {data.n_positions} positions")

    # 2. Models: generator, contrast and blur models, estimator, controller; written as ONNX and
    #    loadable with pv.load_network (or all at once with mc.load(directory)).
    training = mc.train(data, out / "networks", preset=preset, overrides=batches, seed=args.seed)
    print(training.summary())

    # 3. The state-estimation metric: closed-loop runs on true images; at each state, compare the
    #    estimator on the true image with the estimator on the model's image.
    ours = mc.evaluate(out / "networks", trajectories=runs, seed=args.seed, out=out / "evaluation-ours")
    print(ours.table())
    try:
        paper = mc.evaluate("paper", trajectories=runs, seed=args.seed, out=out / "evaluation-paper")
        print(paper.table())
    except MissingFileError as error:
        print(f"(the authors' networks are not available: {error})")
    print(f"plots and summary.json under {out}")


if __name__ == "__main__":
    main()
