"""The original study's files through percver's F1/10 pipeline: controllers, the paper's
knock-out classifier with its thresholds, its denoiser, and the real-data statistics."""

from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import data, loop, noise, pipeline, world

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "f1tenth"


def test_shared_data_is_there():
    # These tests read the original files; a missing folder is a failure, not a skip.
    assert (DATA / "controllers").is_dir(), f"F1/10 data missing at {DATA}"
    assert data.data_dir(DATA) == DATA


def test_real_statistics_match_reference():
    stats = data.real_statistics(DATA)
    assert stats.runs == 116 and stats.crash_count == 45
    summary = stats.summary()
    assert summary["uncovered"]["reflected_per_scan"] == pytest.approx(3.26, abs=0.01)
    assert summary["covered"]["reflected_per_scan"] == pytest.approx(3.20, abs=0.01)
    assert summary["uncovered"]["within_5cm"] == pytest.approx(0.911, abs=0.001)
    assert summary["covered"]["within_5cm"] == pytest.approx(0.948, abs=0.001)
    assert stats.outputs.shape == (12, 25042)
    assert {ctl.short_name(n) for n in ctl.NAMES} == set(stats.crashes)


def test_controllers_load_with_the_car_conventions():
    controllers = ctl.load_all(data=DATA)
    assert list(controllers) == list(ctl.NAMES)
    scan = world.controller_lidar().scan(world.square(), world.from_local([[0.75, 9.0, 0.0], [0.75, 2.0, 0.0]]))
    for controller in controllers.values():
        steering = controller(scan)
        assert np.all(np.abs(steering) <= np.radians(15) + 1e-12)
        assert steering[1] < -np.radians(14)  # 2 m from the front wall: all turn hard right
    with pytest.raises(pv.InputError, match="unknown F1/10 controller"):
        ctl.load("TD3_L41_64x64_C1", DATA)


@pytest.fixture(scope="module")
def authors():
    return noise.NoiseModel.load(*data.authors_noise_model(DATA)), noise.Denoiser.load(data.authors_denoiser(DATA))


def first_hallway_scans(n=400, seed=0):
    rng = np.random.default_rng(seed)
    local = np.column_stack([rng.uniform(0.4, 1.1, n), rng.uniform(1.0, 9.0, n), rng.uniform(-0.2, 0.2, n)])
    return local, world.controller_lidar().scan(world.right_turn(), world.from_local(local))


def test_authors_noise_model_and_denoiser(authors, tmp_path):
    model, denoiser = authors
    assert model.network.n_in == 24 and model.thresholds.shape == (21,)
    local, canonical = first_hallway_scans()
    normalised = world.normalise(canonical)
    knocked = model.knockouts(normalised, world.pose_features(local))
    assert 2.0 < knocked.sum(axis=1).mean() < 5.0  # about the 3.2 reflected rays per real scan
    noised = model.apply(normalised, world.pose_features(local))
    assert np.all(noised[knocked] == noise.KNOCKED) and np.array_equal(noised[~knocked], normalised[~knocked])
    # The denoiser pulls knocked-out rays back towards the canonical scan.
    assert np.abs(denoiser(noised) - normalised).mean() < 0.7 * np.abs(noised - normalised).mean()
    # Exported to ONNX they read back identical.
    model.save(tmp_path / "noiser.onnx", tmp_path / "thresholds.npy")
    again = noise.NoiseModel.load(tmp_path / "noiser.onnx", tmp_path / "thresholds.npy")
    assert np.allclose(
        again.probabilities(normalised, world.pose_features(local)), model.probabilities(normalised, world.pose_features(local)), atol=1e-12
    )


def test_authors_models_in_the_closed_loop(authors):
    model, denoiser = authors
    controllers = ctl.load_all([ctl.VERIFIED], DATA)
    starts = loop.StartBox().sample(10, np.random.default_rng(0))
    names = [ctl.VERIFIED] * 10
    canonical = pipeline.simulate_model(starts, names, controllers)
    noisy = pipeline.simulate_model(starts, names, controllers, model)
    cleaned = pipeline.simulate_model(starts, names, controllers, model, denoiser)
    assert canonical.crashed.sum() == 0  # verified safe on the canonical model
    assert noisy.crashed.sum() >= 3  # the adversarial noise crashes it
    assert cleaned.crashed.sum() < noisy.crashed.sum()  # the denoiser is the fix of the paper


def test_authors_classifier_metrics_on_a_training_set(authors):
    model, _ = authors
    local, canonical = first_hallway_scans(200, seed=1)
    real = canonical.copy()
    real[:, 10] = 5.0  # a glass door ahead
    dataset = pipeline.TrainingSet(
        world.from_local(local),
        real,
        np.repeat(np.arange(4), 50),
        np.tile(np.arange(50) * 0.025, 4),
        [ctl.VERIFIED] * 4,
        np.zeros(4, dtype=bool),
    )
    labels = noise.label(dataset.real, dataset.canonical, 0.1)
    metrics = pipeline.evaluate_noise_model(model, dataset, labels, ctl.load_all([ctl.VERIFIED], DATA))
    assert 0.0 <= metrics["whole_scan_accuracy"] <= 1.0 and 0.5 < metrics["ray_accuracy"] < 1.0
    assert metrics["control_error"]["scans"] == 200 and metrics["control_error"]["sum"] > 0
