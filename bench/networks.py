"""Benchmark (run by hand): sound output bounds of the shared networks, three methods, one run.

Writes bench/results/networks.json. Per network: wall time (minimum over --repeat runs; Verisig
once) and output width of naive interval propagation, direct Taylor models and the Verisig
translation, next to the width of the range of 10,000 float samples. The key figure is the
paper's Mountain Car chain generator -> contraster -> estimator -> controller over
p in [-0.5, -0.49975], contrast in [0.3, 2.0], v = 0, timed with both cores (rayon) and, in a
child process, on one thread (RAYON_NUM_THREADS=1: the figure other load disturbs least).
``--baseline CORE.so`` times the key figure also with another build of ``percver._core`` (e.g.
of an earlier commit), in the same processes, for a before/after on equal terms.

    python bench/networks.py [--repeat 10] [--skip-verisig-chain] [--baseline /path/to/lib_core.so]

``--archcomp`` measures instead the ARCH-COMP 2024 AINNCS controllers (ReLU and, for comparison,
smooth) on boxes of half-width 0.5 around the centre of their benchmark's initial set: the
ratio of the bound's width to the sampled range (worst output), unrefined and refined by
branch and bound (``leaves=``), with the adaptive ReLU slopes and with ``--alpha`` steps of their
optimisation (``alpha_steps=``); writes bench/results/networks_archcomp.json.

    python bench/networks.py --archcomp 1 256 1024 --alpha 0 20
"""

import argparse
import importlib.util
import json
import os
import subprocess
import sys
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


BOX = {"p": (-0.5, -0.49975), "delta": (0.3, 2.0), "v": (0.0, 0.0)}


def mountain_car_chain() -> pv.Network:
    generator, contraster, controller = mc("Generator"), mc("Contraster"), mc("ControllerSigmoid")
    estimator = pv.Network(mc("CompositeRegressor").layers, scale=0.9, offset=-0.3, name="estimator")
    return pv.chain(
        generator.passthrough(["delta", "v"]), contraster.passthrough(["v"]), estimator.passthrough(["v"]), controller
    ).with_input_names(["p", "delta", "v"])


def baseline_bounds(path: str, chain: pv.Network):
    """The key figure's direct bounds by another build of percver._core (its own Network class)."""
    spec = importlib.util.spec_from_file_location("_core", path)
    core = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(core)
    network = core.Network([(layer.weight, layer.bias, list(layer.activations)) for layer in chain.layers], None, None)
    pieces = [(chain.input_names.index(name), count) for name, count in CHAIN_SETTINGS["pieces"].items()]
    settings = dict(order=CHAIN_SETTINGS["order"], max_vars=CHAIN_SETTINGS["max_vars"], splits=pieces)
    return lambda: network.bounds(list(BOX.values()), "taylor", **settings)


def key_figure(repeat: int, baseline) -> dict:
    """Wall time and width of the key figure's direct method (and of the baseline build)."""
    chain = mountain_car_chain()
    seconds, bounds = timed(lambda: chain.bounds(BOX, **CHAIN_SETTINGS), repeat)
    row = {"seconds": seconds, "width": width(bounds)}
    if baseline:
        seconds, bounds = timed(baseline_bounds(baseline, chain), repeat)
        row["baseline"] = {"core": baseline, "seconds": seconds, "width": width(bounds)}
    return row


def one_thread(repeat: int, baseline) -> dict:
    """The key figure in a child process whose rayon pool has one thread."""
    command = [sys.executable, __file__, "--key-figure-only", "--repeat", str(repeat)] + (["--baseline", baseline] if baseline else [])
    done = subprocess.run(command, env={**os.environ, "RAYON_NUM_THREADS": "1"}, capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def key_chain(repeat: int, verisig: bool, baseline) -> dict:
    chain = mountain_car_chain()
    box = BOX
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(*box[k], 20_000) for k in ("p", "delta", "v")])
    u = chain(x)
    row = measure(chain, box, u, repeat, verisig=verisig, **CHAIN_SETTINGS)
    row["sampled_range"] = [float(u.min()), float(u.max())]
    row["taylor"]["cpu_seconds"] = cpu_seconds(lambda: chain.bounds(box, **CHAIN_SETTINGS), repeat)
    row["taylor"]["one_thread"] = one_thread(repeat, baseline)
    if baseline:
        row["taylor"]["baseline"] = key_figure(repeat, baseline)["baseline"]
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


ARCHCOMP = DATA / "archcomp2024" / "models"
# Controller -> the centre of its benchmark's initial set, in the network's input order (ACC:
# v_set, T_gap, v_ego, D_rel, v_rel; Airplane: its 12 states; ...).
ARCHCOMP_CENTRES = {
    "InvertedPendulum/controller_single_pendulum.nnet": [1.0875, 0.1],
    "InvertedTwoLinkPendulum/controller_double_pendulum_less_robust.nnet": [1.15] * 4,
    "InvertedTwoLinkPendulum/controller_double_pendulum_more_robust.nnet": [1.15] * 4,
    "TORA/controllerTora.mat": [0.65, -0.65, -0.35, 0.55],
    "TORA/nn_tora_relu_tanh.mat": [-0.76, -0.44, 0.525, -0.29],
    "TORA/nn_tora_sigmoid.mat": [-0.76, -0.44, 0.525, -0.29],
    "ACC/controller_5_20.mat": [30.0, 1.4, 30.1, 89.5, 2.0],
    "ACC/tanh.yml": [30.0, 1.4, 30.1, 89.5, 2.0],
    "Unicycle/controllerB_nnv.mat": [9.525, -4.475, 2.105, 1.505],
    "NAV/nn-nav-set.mat": [3.0, 3.0, 0.0, 0.0],
    "Airplane/controller_airplane.nnet": [0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0],
    "AttitudeControl/model.mat": [-0.445, -0.545, 0.655, -0.745, 0.855, -0.645],
    "Quadrotor/model.mat": [0.0] * 12,
    "SpacecraftDocking/model.mat": [88.0, 88.0, 0.0, 0.0],
}


def archcomp(leaves: list, alphas: list) -> dict:
    """Per controller: worst-output ratio of bound width to sampled range (100,000 uniform points
    and the box's corners up to 2^12), CPU seconds, per number of leaves (1: unrefined) and of
    slope optimisation steps (rows ``leaves_N`` for 0 steps, ``leaves_N_alpha_K`` for K)."""
    import itertools
    import warnings

    rows = {}
    rng = np.random.default_rng(0)
    for name, centre in ARCHCOMP_CENTRES.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            network = pv.load_network(ARCHCOMP / name)
        centre = np.array(centre)
        box = [(c - 0.5, c + 0.5) for c in centre]
        corners = centre + 0.5 * np.array(list(itertools.product([-1.0, 1.0], repeat=len(centre))))
        y = network(np.vstack([centre + rng.uniform(-0.5, 0.5, (100_000, len(centre))), corners]))
        sampled = y.max(0) - y.min(0)
        acts = sorted(
            {a for layer in network.layers for a in ([layer.activation] if isinstance(layer.activation, str) else layer.activation)}
            - {"identity"}
        )
        row = {"activations": acts, "sampled": [[float(a), float(b)] for a, b in zip(y.min(0), y.max(0))]}
        keys = []
        for alpha in alphas:
            for n in leaves:
                start = time.process_time()
                bounds = np.array(network.bounds(box, leaves=n, alpha_steps=alpha))
                seconds = time.process_time() - start
                if np.any(y < bounds[:, 0]) or np.any(y > bounds[:, 1]):
                    raise AssertionError(f"{name}: a sample lies outside the bounds with leaves={n}, alpha_steps={alpha}")
                key = f"leaves_{n}" + (f"_alpha_{alpha}" if alpha else "")
                row[key] = {
                    "ratio": float(np.max((bounds[:, 1] - bounds[:, 0]) / np.maximum(sampled, 1e-12))),
                    "cpu_seconds": seconds,
                }
                keys.append(key)
        rows[name] = row
        print(
            f"{name:60s} {'/'.join(acts):10s}" + "".join(f"  {k}: {row[k]['ratio']:6.2f}x {row[k]['cpu_seconds']:6.2f} s" for k in keys),
            flush=True,
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--skip-verisig-chain", action="store_true", help="the chain through Verisig takes about a minute")
    parser.add_argument("--baseline", help="another build of percver._core (lib_core.so) to time the key figure with")
    parser.add_argument("--key-figure-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--archcomp", type=int, nargs="*", metavar="LEAVES", help="the ARCH-COMP controllers (default leaves: 1 256 1024)")
    parser.add_argument("--alpha", type=int, nargs="*", default=[0], metavar="STEPS", help="ReLU slope optimisation steps (default: 0)")
    args = parser.parse_args()
    if args.archcomp is not None:
        leaves = args.archcomp or [1, 256, 1024]
        doc = {
            "machine": {"cpus": os.cpu_count(), "load_average": os.getloadavg()},
            "half_width": 0.5,
            "networks": archcomp(leaves, args.alpha),
        }
        (ROOT / "bench" / "results" / "networks_archcomp.json").write_text(json.dumps(doc, indent=1))
        return
    if args.key_figure_only:
        print(json.dumps(key_figure(args.repeat, args.baseline)))
        return
    result = {
        "machine": {"cpus": os.cpu_count(), "load_average": os.getloadavg()},
        "mountain_car_chain": key_chain(args.repeat, not args.skip_verisig_chain, args.baseline),
        "networks": shared_networks(args.repeat),
    }
    out = ROOT / "bench" / "results" / "networks.json"
    out.write_text(json.dumps(result, indent=1))
    chain = result["mountain_car_chain"]
    print(f"chain: sampled width {chain['sampled_width']:.4g}")
    for method in ("interval", "taylor", "taylor_unsplit", "taylor_8_pieces", "verisig"):
        if method in chain:
            r = chain[method]
            print(
                f"  {method:16s}"
                + (
                    f" {r['seconds'] * 1e3:9.1f} ms  width {r['width']:.4g}  ratio {r['ratio']:.3g}"
                    if "seconds" in r
                    else f" failed: {r['failed']}"
                )
            )
    taylor = chain["taylor"]
    print(f"  taylor CPU time (both cores) {taylor['cpu_seconds'] * 1e3:.1f} ms; one thread {taylor['one_thread']['seconds'] * 1e3:.1f} ms")
    if "baseline" in taylor:
        print(
            f"  baseline build: {taylor['baseline']['seconds'] * 1e3:.1f} ms (one thread {taylor['one_thread']['baseline']['seconds'] * 1e3:.1f} ms), width {taylor['baseline']['width']:.4g}"
        )
    print(f"  load average {result['machine']['load_average']}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
