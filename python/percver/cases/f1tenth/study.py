"""The stages of the F1/10 study as file-to-file steps (what ``percver cases f1tenth`` runs).

simulate -> runs.npz (Measurements: raw 1081-ray scans, steering, run ids, times; true states
            for checking the filter only)
estimate -> training.npz (Measurements: estimated poses and the real 21-ray scans, i.e. D)
label    -> labels.npz (t_Delta curve, t_Delta*, the knock-out labels)
train    -> DIR/noiser{size}.onnx + thresholds{size}.npy per size, denoiser.onnx, training.json
evaluate -> DIR/evaluation.json and figures (Table 2 metrics, trajectory metric, Figure 5/6)

Every stage returns a JSON-ready record.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import data as f1data
from percver.cases.f1tenth import particle_filter
from percver.cases.f1tenth import noise, pipeline, plots, simulate, world
from percver.errors import InputError, MissingFileError
from percver.measurements import Measurements

LABEL_KEYS = ("labels", "t_delta", "thresholds", "errors", "knocked_share")
CEILING_POSES = 2000  # scans at which the label ceiling is estimated (10 draws each)


def run_simulate(out, *, runs_per_controller="paper", names=None, seed: int = 0, covered: bool = False, data=None) -> dict:
    """``runs_per_controller``: a count, or "paper" for the real data's 9-10 runs each."""
    if runs_per_controller == "paper":
        runs_per_controller = simulate.paper_run_counts(data)
    real = simulate.RealWorld()
    real = real.covered() if covered else real
    controllers = ctl.load_all(data=data)
    began = time.perf_counter()
    runs = simulate.simulate(runs_per_controller, names=names, world_model=real, seed=seed, controllers=controllers)
    path = simulate.to_measurements(runs).save(out)
    stats = f1data.real_statistics(data)
    safe = runs.safe_share()
    return {
        "path": str(path),
        "seconds": time.perf_counter() - began,
        "calibration": simulate.calibration(runs, stats=stats, controllers=controllers),
        "safe_share": {
            name: {"simulated": share, "real": 100.0 * (1.0 - float(np.mean(stats.crashes[ctl.short_name(name)])))}
            for name, share in safe.items()
        },
    }


def load_runs(path):
    return simulate.from_measurements(Measurements.load(path))


def run_estimate(runs_path, out, *, particles: int = 300, seed: int = 0, progress: bool = False) -> dict:
    runs = load_runs(runs_path)
    began = time.perf_counter()
    settings = particle_filter.FilterSettings(particles=particles)
    poses = particle_filter.estimate_poses(runs.scans, runs.controls, runs.run, runs.time, settings=settings, seed=seed, progress=progress)
    seconds = time.perf_counter() - began
    # The simulator's true states are used here only to report how good the filter is.
    settled = runs.time >= 1.0
    errors = {
        "all": poses.errors(runs.states),
        "after_1s": particle_filter.PoseEstimate(poses.poses[settled], poses.speed[settled], poses.spread[settled]).errors(
            runs.states[settled]
        ),
    }
    dataset = pipeline.training_set(runs, poses)
    dataset.meta["pose_error"] = errors
    path = dataset.to_measurements().save(out)
    calibration = simulate.calibration(runs, poses=poses.poses)
    return {
        "path": str(path),
        "seconds": seconds,
        "scans": len(runs.run),
        "pose_error": errors,
        "calibration_at_estimated_poses": calibration,
    }


def load_training(path) -> pipeline.TrainingSet:
    return pipeline.TrainingSet.from_measurements(Measurements.load(path))


def run_label(training_path, out, *, plot=None) -> dict:
    dataset = load_training(training_path)
    curve = noise.threshold_curve(dataset.real, dataset.canonical)
    labels = noise.label(dataset.real, dataset.canonical, curve.best)
    path = Path(out)
    np.savez_compressed(
        path,
        labels=labels.astype(np.uint8),
        t_delta=curve.best,
        thresholds=curve.thresholds,
        errors=curve.errors,
        knocked_share=curve.knocked_share,
    )
    record = {
        "path": str(path),
        **curve.summary(),
        "labelled_share": float(labels.mean()),
        "labelled_per_scan": float(labels.sum(axis=1).mean()),
    }
    if "world" in dataset.meta:
        # Runs of the measurement simulator: how predictable its labels are at all (diagnostic).
        rows = np.random.default_rng(0).permutation(len(dataset))[:CEILING_POSES]
        real = simulate.RealWorld.from_description(dataset.meta["world"])
        record["label_ceiling"] = simulate.label_ceiling(real, dataset.poses[rows], curve.best)
    if plot:
        record["plot"] = str(plots.threshold_curve(curve, plot))
    return record


def load_labels(path, rows: int) -> tuple[np.ndarray, float]:
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"labels file not found: {path} (write it with percver cases f1tenth label)")
    try:
        with np.load(path) as npz:
            missing = [k for k in LABEL_KEYS if k not in npz.files]
            if missing:
                raise InputError(f"'{path}' lacks {missing}: write it with percver cases f1tenth label")
            labels = npz["labels"].astype(bool)
            t_delta = float(npz["t_delta"])
    except (OSError, ValueError) as error:
        raise InputError(f"cannot read labels from '{path}' ({error}): write them with percver cases f1tenth label") from None
    if labels.shape != (rows, 21):
        raise InputError(f"'{path}' labels {labels.shape[0]} scans but the training set has {rows}: label that training set")
    return labels, t_delta


def run_train(
    training_path,
    labels_path,
    out_dir,
    *,
    sizes=("5x100",),
    epochs: int = 60,
    denoiser_epochs: int = 60,
    threads: int | None = 2,
    test_share: float = 0.2,
    seed: int = 0,
    data=None,
    progress: bool = False,
) -> dict:
    dataset = load_training(training_path)
    labels, t_delta = load_labels(labels_path, len(dataset))
    unknown = [s for s in sizes if s not in noise.SIZES]
    if unknown:
        raise InputError(f"unknown classifier sizes {unknown}; the paper's are {', '.join(noise.SIZES)}")
    controllers = ctl.load_all(sorted(set(dataset.controllers)), data)
    train_runs, test_runs = dataset.split_runs(test_share, seed)
    train, test = dataset.select_runs(train_runs), dataset.select_runs(test_runs)
    train_labels, test_labels = labels[dataset.rows_of(train_runs)], labels[dataset.rows_of(test_runs)]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    record = {"t_delta": t_delta, "train_scans": len(train), "test_scans": len(test), "classifiers": {}}
    for size in sizes:
        began = time.perf_counter()
        model = noise.train_classifier(
            train.inputs(),
            train_labels,
            noise.SIZES[size],
            epochs=epochs,
            seed=seed,
            threads=threads,
            progress=progress,
            name=f"noiser{size}",
        )
        seconds = time.perf_counter() - began
        model.save(out / f"noiser{size}.onnx", out / f"thresholds{size}.npy")
        record["classifiers"][size] = {
            "seconds": seconds,
            "train": pipeline.evaluate_noise_model(model, train, train_labels, controllers),
            "test": pipeline.evaluate_noise_model(model, test, test_labels, controllers) if len(test) else None,
        }
    began = time.perf_counter()
    denoiser = noise.train_denoiser(
        world.normalise(train.real), world.normalise(train.canonical), epochs=denoiser_epochs, seed=seed, threads=threads, progress=progress
    )
    denoiser.save(out / "denoiser.onnx")
    record["denoiser"] = {
        "seconds": time.perf_counter() - began,
        "train": pipeline.evaluate_denoiser(denoiser, train, controllers),
        "test": pipeline.evaluate_denoiser(denoiser, test, controllers) if len(test) else None,
    }
    (out / "training.json").write_text(json.dumps(record, indent=2))
    record["out"] = str(out)
    return record


def load_models(source, sizes=None, data=None) -> tuple[dict, noise.Denoiser | None]:
    """``{size: NoiseModel}`` and the denoiser from a directory written by ``run_train``, or the
    authors' (``source="paper"``: their 5x100 classifier and denoiser)."""
    if source == "paper":
        network, thresholds = f1data.authors_noise_model(data)
        return {"5x100": noise.NoiseModel.load(network, thresholds)}, noise.Denoiser.load(f1data.authors_denoiser(data))
    folder = Path(source)
    if not folder.is_dir():
        raise MissingFileError(f"models directory not found: {folder} (write it with percver cases f1tenth train, or pass 'paper')")
    models = {}
    for size in sizes or noise.SIZES:
        network, thresholds = folder / f"noiser{size}.onnx", folder / f"thresholds{size}.npy"
        if network.is_file() and thresholds.is_file():
            models[size] = noise.NoiseModel.load(network, thresholds)
    if not models:
        raise MissingFileError(f"'{folder}' holds no noiser<size>.onnx with thresholds<size>.npy")
    denoiser = folder / "denoiser.onnx"
    return models, noise.Denoiser.load(denoiser) if denoiser.is_file() else None


def run_evaluate(
    training_path, labels_path, models_source, out_dir, *, sizes=None, plot_size: str = "5x100", plots_wanted: bool = True, data=None
) -> dict:
    dataset = load_training(training_path)
    labels, t_delta = load_labels(labels_path, len(dataset))
    models, denoiser = load_models(models_source, sizes, data)
    controllers = ctl.load_all(sorted(set(dataset.controllers)), data)
    stats = f1data.real_statistics(data)
    starts = pipeline.start_states(dataset)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    record = {
        "models": str(models_source),
        "t_delta": t_delta,
        "scans": len(dataset),
        "runs": len(dataset.controllers),
        "canonical_control_error": pipeline.control_error(dataset, dataset.canonical, controllers),
        "noise_models": {},
    }
    simulated = {}
    for size, model in models.items():
        metrics = pipeline.evaluate_noise_model(model, dataset, labels, controllers)
        simulated[size] = pipeline.simulate_model(starts, dataset.controllers, controllers, model)
        metrics["trajectory"] = pipeline.trajectory_metric(dataset, simulated[size], stats)
        metrics["simulated_crashes"] = int(simulated[size].crashed.sum())
        record["noise_models"][size] = metrics
    record["real_crashes"] = int(dataset.crashed.sum())
    if denoiser is not None:
        record["denoiser"] = pipeline.evaluate_denoiser(denoiser, dataset, controllers)
        chosen = models.get(plot_size) or next(iter(models.values()))
        with_denoiser = pipeline.simulate_model(starts, dataset.controllers, controllers, chosen, denoiser)
        record["denoiser"]["simulated_crashes_with_noise_model"] = int(with_denoiser.crashed.sum())
    if plots_wanted:
        size = plot_size if plot_size in simulated else next(iter(simulated))
        figures = [
            plots.trajectories(dataset, simulated[size], out / f"trajectories_{size}.png", sim_label=f"simulated, {size} noise model")
        ]
        model = models[size]
        canonical = world.normalise(dataset.canonical)
        noised = world.denormalise(model.apply(canonical, world.pose_features(dataset.local)))
        crashed = np.flatnonzero(dataset.crashed)
        run = int(crashed[0]) if crashed.size else 0
        figures.append(plots.control_outputs(dataset, run, noised, controllers, out / f"controls_run{run}.png"))
        record["figures"] = [str(f) for f in figures]
    (out / "evaluation.json").write_text(json.dumps(record, indent=2, default=str))
    record["out"] = str(out)
    return record
