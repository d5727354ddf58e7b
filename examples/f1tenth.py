"""The F1/10 case study of the paper (section 5.2, Appendix B), end to end on a small scale.

1. "Real" runs: the 12 controllers drive through the first right turn of a hall whose glass
   and metal surfaces swallow LiDAR rays (percver's stand-in for the original real traces).
2. A particle filter estimates the car's pose for every scan (the runs carry no states).
3. Rays are labelled adversarial where the real scan differs from the canonical one by more
   than t_Delta*, the threshold that makes noised canonical scans closest to the real ones.
4. A knock-out classifier c_n and a denoiser h_d are trained (torch), exported to ONNX and
   read back with pv.load_network; the authors' classifier and denoiser run alongside.
5. The paper's metrics: whole-scan accuracy, control error, and safe runs real vs simulated
   with the noise model (Table 2); plots of the runs (Figure 6) and control outputs (Figure 5).
6. Verification (Table 1): canonical LiDAR -> authors' classifier with thresholds -> denoiser ->
   TD3_L21_64x64_C2 -> bicycle model, from a slice of the original initial range (two cells).

    python examples/f1tenth.py [--runs 3] [--size 5x100] [--epochs 40] [--out out/f1tenth]

The defaults take a few minutes on two cores; `percver cases f1tenth ...` runs the full study.
"""

import argparse
from pathlib import Path

import numpy as np
import torch

import percver as pv
from percver.cases.f1tenth import controllers, data, noise, particle_filter, pipeline, plots, simulate, world

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("--runs", type=int, default=3, help="runs per controller (the paper has 9-10)")
parser.add_argument("--particles", type=int, default=200, help="particles per run")
parser.add_argument("--size", default="5x100", choices=list(noise.SIZES), help="classifier size")
parser.add_argument("--epochs", type=int, default=40, help="training epochs")
parser.add_argument("--out", default="out/f1tenth", help="directory for networks and figures")
args = parser.parse_args()
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
torch.set_num_threads(2)

# ---- 1. real runs, and how they compare with the statistics of the original real runs
cars = controllers.load_all()
runs = simulate.simulate(args.runs, controllers=cars, seed=0)
stats = data.real_statistics()
calibration = simulate.calibration(runs, stats=stats)
real = calibration["real"]
print(
    f"{calibration['runs']} runs, {calibration['scans']} scans at 40 Hz, {calibration['crashes']} crashes "
    f"(real: {real['crashes']} of {real['runs']})"
)
print(
    f"reflected rays per 21-ray scan: {calibration['reflected_per_scan']:.2f} (real {real['uncovered']['reflected_per_scan']:.2f}); "
    f"other rays within 5 cm: {100 * calibration['within_5cm']:.1f}% (real {100 * real['uncovered']['within_5cm']:.1f}-"
    f"{100 * real['covered']['within_5cm']:.1f}%)"
)

# ---- 2. poses from scans and steering only
poses = particle_filter.estimate_poses(
    runs.scans, runs.controls, runs.run, runs.time, settings=particle_filter.FilterSettings(particles=args.particles), progress=True
)
settled = runs.time >= 1.0
error = particle_filter.PoseEstimate(poses.poses[settled], poses.speed[settled], poses.spread[settled]).errors(runs.states[settled])
print(
    f"pose error after 1 s: median {100 * error['position_median_m']:.1f} cm, mean {100 * error['position_mean_m']:.1f} cm, "
    f"heading {error['heading_mean_deg']:.2f} deg"
)
dataset = pipeline.training_set(runs, poses)

# ---- 3. labels at t_Delta*
curve = noise.threshold_curve(dataset.real, dataset.canonical)
labels = noise.label(dataset.real, dataset.canonical, curve.best)
print(
    f"t_Delta* = {curve.best:.3f} m: noised canonical scans {curve.errors.min():.3f} m per ray from the real ones "
    f"(canonical alone {curve.errors[-1]:.3f} m); {labels.sum(axis=1).mean():.2f} rays knocked out per scan"
)
plots.threshold_curve(curve, out / "t_delta.png")

# ---- 4. noise model and denoiser, through ONNX
train_runs, test_runs = dataset.split_runs(0.2, seed=0)
train, test = dataset.select_runs(train_runs), dataset.select_runs(test_runs)
model = noise.train_classifier(
    train.inputs(), labels[dataset.rows_of(train_runs)], noise.SIZES[args.size], epochs=args.epochs, progress=True
)
model.save(out / f"noiser{args.size}.onnx", out / f"thresholds{args.size}.npy")
model = noise.NoiseModel.load(out / f"noiser{args.size}.onnx", out / f"thresholds{args.size}.npy")
denoiser = noise.train_denoiser(world.normalise(train.real), world.normalise(train.canonical), epochs=args.epochs, progress=True)
denoiser.save(out / "denoiser.onnx")
print(f"exported: {pv.load_network(out / f'noiser{args.size}.onnx')}, {pv.load_network(out / 'denoiser.onnx')}")
authors = noise.NoiseModel.load(*data.authors_noise_model())
authors_denoiser = noise.Denoiser.load(data.authors_denoiser())

# ---- 5. the paper's metrics
held_out = (f"ours {args.size} (held-out runs)", model, test, labels[dataset.rows_of(test_runs)])
for name, noise_model, part, part_labels in (
    *([held_out] if test_runs else []),
    (f"ours {args.size} (training runs)", model, train, labels[dataset.rows_of(train_runs)]),
    ("authors' 5x100 (all runs)", authors, dataset, labels),
):
    metrics = pipeline.evaluate_noise_model(noise_model, part, part_labels, cars)
    print(
        f"{name}: whole-scan accuracy {100 * metrics['whole_scan_accuracy']:.0f}%, ray accuracy "
        f"{100 * metrics['ray_accuracy']:.1f}%, control error {metrics['control_error']['mean_deg']:.2f} deg per scan"
    )
print(f"canonical model alone: control error {pipeline.control_error(dataset, dataset.canonical, cars)['mean_deg']:.2f} deg per scan")

starts = pipeline.start_states(dataset)
simulated = pipeline.simulate_model(starts, dataset.controllers, cars, model)
with_denoiser = pipeline.simulate_model(starts, dataset.controllers, cars, model, denoiser)
print(
    f"\ncrashes: real {dataset.crashed.sum()}, simulated with the noise model {simulated.crashed.sum()}, "
    f"with the denoiser too {with_denoiser.crashed.sum()} (of {len(dataset.controllers)})"
)
print(f"{'controller':22s} {'safe real':>9s} {'simulated':>9s} {'paper real':>10s}")
for name, row in pipeline.trajectory_metric(dataset, simulated, stats).items():
    print(f"{name:22s} {row['real_safe']:8.0f}% {row['sim_safe']:8.0f}% {row['paper_real_safe']:9.0f}%")

figures = [plots.trajectories(dataset, simulated, out / "trajectories.png", sim_label=f"simulated, {args.size} noise model")]
run = int(np.flatnonzero(dataset.crashed)[0]) if dataset.crashed.any() else 0
noised = world.denormalise(model.apply(world.normalise(dataset.canonical), world.pose_features(dataset.local)))
figures.append(plots.control_outputs(dataset, run, noised, cars, out / "controls.png"))
print("figures:", ", ".join(str(f) for f in figures + [out / "t_delta.png"]))

# ---- 6. verification of the paper's loop from two 5e-5 cells (the whole range: bench/f1tenth.py)
from percver.cases.f1tenth import verification  # noqa: E402

result = verification.verify(y1=(0.75, 0.7501), networks="paper", workers=2)
print()
print(verification.table(result))
result.plot("y1", out / "verified_y1.png")
