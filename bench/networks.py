"""Benchmark (run by hand): sound output bounds of the shared networks, three methods, one run.

Writes bench/results/networks.json. Per network: wall time (minimum over --repeat runs; Verisig
once) and output width of naive interval propagation, direct Taylor models and the Verisig
translation, next to the width of the range of 10,000 float samples. The key figure is the
paper's Mountain Car chain generator -> contraster -> estimator -> controller over
p in [-0.5, -0.49975], contrast in [0.3, 2.0], v = 0.

    python bench/networks.py [--repeat 10] [--skip-verisig-chain]
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import percver as pv
from percver.errors import BlowUpError

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
MC = DATA / "mountain_car" / "networks"
SAMPLES = 10_000
# The key figure's direct-method settings: order 4, contrast split in 5 pieces, p and delta as
# polynomial variables.
CHAIN_SETTINGS = {"order": 4, "pieces": {"delta": 5}, "max_vars": 2}


def timed(function, repeat: int):
    """Minimum wall seconds over `repeat` runs (the machine is shared: minima are the signal)."""
    best, result = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def cpu_seconds(function, repeat: int) -> float:
    """Minimum CPU seconds of the process (all threads) per run: less sensitive to other load."""
    best = float("inf")
    for _ in range(repeat):
        start = time.process_time()
        function()
        best = min(best, time.process_time() - start)
    return best


def width(bounds) -> float:
    return max(hi - lo for lo, hi in bounds)


def measure(network, box, samples_y, repeat: int, verisig: bool = True, **settings) -> dict:
    row = {"sampled_width": float(np.max(samples_y.max(0) - samples_y.min(0)))}
    for method, runs in (("interval", repeat), ("taylor", repeat), ("verisig", 1)):
        if method == "verisig" and not verisig:
            continue
        options = {} if method == "interval" else settings
        try:
            seconds, bounds = timed(lambda: network.bounds(box, method=method, **options), runs)
            row[method] = {"seconds": seconds, "width": width(bounds), "ratio": width(bounds) / max(row["sampled_width"], 1e-300)}
        except BlowUpError as error:
            row[method] = {"failed": str(error)}
    return row


def mc(name: str) -> pv.Network:
    return pv.load_network(next(MC.glob(f"{name}*.yml")))


def key_chain(repeat: int, verisig: bool) -> dict:
    generator, contraster, controller = mc("Generator"), mc("Contraster"), mc("ControllerSigmoid")
    estimator = pv.Network(mc("CompositeRegressor").layers, scale=0.9, offset=-0.3, name="estimator")
    chain = pv.chain(
        generator.passthrough(["delta", "v"]), contraster.passthrough(["v"]), estimator.passthrough(["v"]), controller
    ).with_input_names(["p", "delta", "v"])
    box = {"p": (-0.5, -0.49975), "delta": (0.3, 2.0), "v": (0.0, 0.0)}
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(*box[k], 20_000) for k in ("p", "delta", "v")])
    u = chain(x)
    row = measure(chain, box, u, repeat, verisig=verisig, **CHAIN_SETTINGS)
    row["sampled_range"] = [float(u.min()), float(u.max())]
    row["taylor"]["cpu_seconds"] = cpu_seconds(lambda: chain.bounds(box, **CHAIN_SETTINGS), repeat)
    seconds, bounds = timed(lambda: chain.bounds(box, order=5, max_vars=2), max(1, repeat // 3))
    row["taylor_unsplit"] = {"seconds": seconds, "width": width(bounds), "ratio": width(bounds) / row["sampled_width"]}
    seconds, bounds = timed(lambda: chain.bounds(box, order=4, pieces={"delta": 8}, max_vars=2), max(1, repeat // 3))
    row["taylor_8_pieces"] = {"seconds": seconds, "width": width(bounds), "ratio": width(bounds) / row["sampled_width"]}
    row["settings"] = CHAIN_SETTINGS
    return row


def shared_networks(repeat: int) -> dict:
    paths = [
        *sorted(DATA.glob("**/*.onnx")),
        DATA / "mountain_car" / "state_based" / "sig16x16.yml",
        mc("ControllerSigmoid").source,
        *sorted((DATA / "f1tenth" / "controllers").glob("*.yml")),
        *sorted((DATA / "f1tenth" / "noise_models").glob("*.yml")),
        *sorted(DATA.glob("verisig2_suite/*/*.yml")),
    ]
    rows = {}
    rng = np.random.default_rng(1)
    for path in paths:
        try:
            network = pv.load_network(path)
        except pv.NetworkFormatError:
            continue  # Verisig run configs
        centre = rng.uniform(-0.5, 0.5, network.n_in)
        box = list(zip(centre - 0.01, centre + 0.01))
        x = rng.uniform(centre - 0.01, centre + 0.01, size=(SAMPLES, network.n_in))
        rows[str(path.relative_to(DATA))] = {"network": repr(network), **measure(network, box, network(x), repeat)}
    # Image networks, on boxes induced by the generator on a position interval of width 0.00025.
    generator, estimator = mc("Generator"), pv.Network(mc("CompositeRegressor").layers, scale=0.9, offset=-0.3)
    for name, noise_box in (("Contraster", (0.3, 2.0)), ("Blurer", (0.0, 0.3))):
        noise = mc(name)
        chain = pv.chain(generator.passthrough(["delta"]), noise, estimator).with_input_names(["p", "delta"])
        box = {"p": (-0.5, -0.49975), "delta": noise_box}
        x = np.column_stack([rng.uniform(*box["p"], SAMPLES), rng.uniform(*noise_box, SAMPLES)])
        rows[f"generator -> {name.lower()} -> estimator"] = measure(chain, box, chain(x), repeat, verisig=False, **CHAIN_SETTINGS)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--skip-verisig-chain", action="store_true", help="the chain through Verisig takes about a minute")
    args = parser.parse_args()
    result = {
        "machine": {"cpus": os.cpu_count(), "load_average": os.getloadavg()},
        "mountain_car_chain": key_chain(args.repeat, not args.skip_verisig_chain),
        "networks": shared_networks(args.repeat),
    }
    out = ROOT / "bench" / "results" / "networks.json"
    out.write_text(json.dumps(result, indent=1))
    chain = result["mountain_car_chain"]
    print(f"chain: sampled width {chain['sampled_width']:.4g}")
    for method in ("interval", "taylor", "taylor_unsplit", "taylor_8_pieces", "verisig"):
        if method in chain:
            r = chain[method]
            print(f"  {method:16s}" + (f" {r['seconds'] * 1e3:9.1f} ms  width {r['width']:.4g}  ratio {r['ratio']:.3g}" if "seconds" in r else f" failed: {r['failed']}"))
    print(f"  taylor CPU time (both cores) {chain['taylor']['cpu_seconds'] * 1e3:.1f} ms; load average {result['machine']['load_average']}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
