"""Image-based Mountain Car, end to end: data -> models -> state-estimation metric -> verification (paper, section 5.1).

The defaults are small (177 s measured on this project's 2-core machine at low load, issue 29);
--full takes the paper's sizes (data set 20 s, training 2-5 min, evaluation 3-8 min on that
machine, idle to loaded: percver/cases/mountain_car/README.md):

    python examples/mountain_car.py           # 400 positions x 10 noise levels, small batches, 100 runs per noise
    python examples/mountain_car.py --full    # the paper's D (82,000 images) and models, 1000 runs per noise

The same stages from the command line, at full size:

    percver cases mountain-car data --out out/mc/data.npz
    percver cases mountain-car train --data out/mc/data.npz --out out/mc/networks
    percver cases mountain-car evaluate --networks out/mc/networks --out out/mc/evaluation
    percver cases mountain-car evaluate --networks paper --out out/mc/evaluation-paper
    percver cases mountain-car verify --noise contrast --networks out/mc/networks --p0 -0.5 -0.499 --delta-c 1.5 2

Times measured on this project's 2-core machine are in percver/cases/mountain_car/README.md and
bench/README.md (verification of the paper's whole rows).
"""

import argparse
from pathlib import Path

from percver.cases import mountain_car as mc
from percver.cases.mountain_car import verification
from percver.errors import MissingFileError


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="the paper's sizes (6-14 minutes on 2 cores, idle to loaded)")
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

    # 4. Verification, a slice of Table 1's contrast row: from every p0 in [-0.5, -0.499] (v0 = 0)
    #    and contrast in [1.5, 2], the car reaches p >= 0.45 within 150 steps with reward > 90.
    #    The chain generator -> contrast -> estimator -> controller -> plant is enclosed in Taylor
    #    models cell by cell; cells the engine cannot decide are bisected (refine=True).
    result = mc.verify("contrast", p0=(-0.5, -0.499), networks=out / "networks", delta_c=(1.5, 2.0), split={"p": 0.001, "dc": 0.05})
    record = verification.save(result, out / "verification")  # result.json, row.json, coverage.png, tube.png
    print(verification.format_row("contrast", record["row"], record["paper"]))
    print(f"verdict: {result.verdict}; reach tube and coverage map under {out / 'verification'}")


if __name__ == "__main__":
    main()
