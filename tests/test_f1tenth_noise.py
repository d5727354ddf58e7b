"""F1/10 noise modelling: t_Delta labels, a reduced knock-out classifier, thresholds, the
denoiser, ONNX round trips through pv.load_network."""

import numpy as np
import pytest
import torch

import percver as pv
from percver.cases.f1tenth import noise, world
from percver.errors import InputError
from percver.noise import to_network

torch.set_num_threads(2)


def synthetic_scans(n=2000, seed=0):
    """Canonical scans with two hidden mechanisms: ray 4 is swallowed (reads 5 m) whenever the
    car is within 6 m of the front wall and the ray sees a wall, and every ray has 1 cm noise."""
    rng = np.random.default_rng(seed)
    local = np.column_stack([rng.uniform(0.3, 1.2, n), rng.uniform(2.0, 10.0, n), rng.uniform(-0.3, 0.3, n)])
    canonical = world.controller_lidar().scan(world.right_turn(), world.from_local(local))
    real = np.minimum(canonical + rng.normal(0.0, 0.01, canonical.shape), 5.0)
    swallowed = (local[:, 1] < 6.0) & (canonical[:, 4] < 4.9)
    real[swallowed, 4] = 5.0
    return local, canonical, real, swallowed


def test_threshold_curve_finds_the_knock_outs():
    local, canonical, real, swallowed = synthetic_scans()
    curve = noise.threshold_curve(real, canonical)
    # Below the noise every ray is knocked out; beyond every difference nothing is: both worse.
    assert curve.errors[0] > curve.errors.min() and curve.errors[-1] > curve.errors.min()
    assert 0.03 < curve.best < 0.6
    labels = noise.label(real, canonical, curve.best)
    assert np.array_equal(labels[:, 4], swallowed)
    assert not labels[:, :4].any() and not labels[:, 5:].any()
    noised = noise.noised(real, canonical, curve.best)
    assert np.abs(noised - real).mean() == pytest.approx(curve.errors.min())
    summary = curve.summary()
    assert summary["t_delta"] == curve.best and summary["curve"]
    with pytest.raises(InputError, match="same shape"):
        noise.threshold_curve(real[:, :20], canonical)


def test_fit_thresholds_per_ray():
    rng = np.random.default_rng(0)
    labels = rng.random((500, 21)) < 0.3
    probabilities = np.where(labels, rng.uniform(0.6, 1.0, labels.shape), rng.uniform(0.0, 0.55, labels.shape))
    thresholds = noise.fit_thresholds(probabilities, labels)
    assert thresholds.shape == (21,)
    assert np.all((thresholds >= 0.5) & (thresholds < 0.6))
    assert np.array_equal(probabilities > thresholds, labels)


def test_reduced_classifier_learns_the_knock_out_and_round_trips_through_onnx(tmp_path):
    local, canonical, real, swallowed = synthetic_scans()
    labels = noise.label(real, canonical, 0.2)
    inputs = np.column_stack([world.normalise(canonical), world.pose_features(local)])
    model = noise.train_classifier(inputs, labels, hidden=(32, 32), epochs=25, seed=0, threads=1)
    knocked = model.knockouts(inputs[:, :21], inputs[:, 21:])
    assert np.mean(knocked[:, 4] == labels[:, 4]) > 0.95
    assert np.mean(np.all(knocked == labels, axis=1)) > 0.9  # whole-scan accuracy
    assert np.all(model.apply(inputs[:, :21], inputs[:, 21:])[knocked] == noise.KNOCKED)
    model.save(tmp_path / "noiser.onnx", tmp_path / "thresholds.npy")
    again = noise.NoiseModel.load(tmp_path / "noiser.onnx", tmp_path / "thresholds.npy")
    assert np.allclose(again.probabilities(inputs[:, :21], inputs[:, 21:]), model.probabilities(inputs[:, :21], inputs[:, 21:]), atol=1e-12)
    assert np.array_equal(again.thresholds, model.thresholds)
    network = pv.load_network(tmp_path / "noiser.onnx")
    assert [layer.activation for layer in network.layers] == ["tanh", "tanh", "sigmoid"]
    with pytest.raises(InputError, match="N x 24"):
        noise.train_classifier(inputs[:, :20], labels, hidden=(4,), epochs=1)


def test_to_network_matches_torch():
    torch.manual_seed(0)
    module = torch.nn.Sequential(torch.nn.Linear(5, 7), torch.nn.Tanh(), torch.nn.Linear(7, 3), torch.nn.Sigmoid()).double()
    network = to_network(module, "probe")
    x = np.random.default_rng(0).normal(size=(10, 5))
    assert np.allclose(network(x), module(torch.as_tensor(x)).detach().numpy(), atol=1e-12)
    with pytest.raises(InputError, match="dense layer"):
        to_network(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.Dropout()), "bad")


def test_denoiser_trains_and_round_trips(tmp_path):
    local, canonical, real, swallowed = synthetic_scans(2000)
    before = np.abs(world.normalise(real) - world.normalise(canonical))[swallowed, 4].mean()
    denoiser = noise.train_denoiser(world.normalise(real), world.normalise(canonical), epochs=40, seed=0, threads=1)
    out = denoiser(world.normalise(real))
    assert np.all(np.abs(out) <= noise.DENOISER_SCALE)
    after = np.abs(out - world.normalise(canonical))[swallowed, 4].mean()
    assert after < 0.5 * before
    denoiser.save(tmp_path / "denoiser.onnx")
    again = noise.Denoiser.load(tmp_path / "denoiser.onnx")
    assert np.allclose(again(world.normalise(real[:50])), out[:50], atol=1e-12)
    with pytest.raises(InputError, match="21 rays"):
        noise.Denoiser(pv.load_network(tmp_path / "denoiser.onnx").passthrough(1))
