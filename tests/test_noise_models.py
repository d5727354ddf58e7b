"""percver.noise: t_Delta labels and thresholds, knock-out and generative training, ONNX export
read back by pv.load_network and onnxruntime, and the error without torch."""

import re
import sys

import numpy as np
import onnxruntime
import pytest

torch = pytest.importorskip("torch")

import percver as pv  # noqa: E402
from percver import noise  # noqa: E402
from percver.errors import InputError, MissingDependencyError  # noqa: E402

LIMIT = 5.0


def knocked_scans(n=1500, seed=0):
    """Six 'rays' of canonical ranges and two features; ray 2 reads the range limit whenever
    feature 0 is above 0.5 (a swallowed echo), every ray has 1 cm noise."""
    rng = np.random.default_rng(seed)
    canonical = rng.uniform(0.5, 4.0, (n, 6))
    features = rng.uniform(0.0, 1.0, (n, 2))
    real = canonical + rng.normal(0.0, 0.01, canonical.shape)
    swallowed = features[:, 0] > 0.5
    real[swallowed, 2] = LIMIT
    return canonical, features, real, swallowed


def onnx_outputs(path, x):
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(None, {session.get_inputs()[0].name: x})[0]


def test_threshold_curve_labels_the_jumps_and_replacements_fit_them():
    canonical, _, real, swallowed = knocked_scans()
    curve = noise.threshold_curve(real, canonical, knocked="mean", metric="mse")
    # Below the noise, noise is relabelled; beyond every difference nothing is: both worse.
    assert curve.errors[0] > curve.errors.min() and curve.errors[-1] > curve.errors.min()
    assert np.isinf(curve.thresholds[-1]) and curve.knocked_share[-1] == 0
    labels = noise.label(real, canonical, curve.best)
    assert np.array_equal(labels[:, 2], swallowed) and not labels[:, [0, 1, 3, 4, 5]].any()
    values = noise.replacements(real, labels, "mean")
    assert values[2] == pytest.approx(LIMIT) and np.isnan(values[0])
    assert np.array_equal(noise.noised(real, canonical, curve.best, LIMIT)[:, 2], np.where(swallowed, LIMIT, canonical[:, 2]))
    assert curve.summary()["t_delta"] == curve.best
    with pytest.raises(InputError, match="same shape"):
        noise.threshold_curve(real[:, :5], canonical, knocked=LIMIT)
    with pytest.raises(InputError, match="'mean'"):
        noise.replacements(real, labels, "median")


def test_thresholds_for_accuracy_or_for_removed_error():
    probabilities = np.array([[0.2], [0.4], [0.6], [0.8]])
    labels = np.array([[False], [True], [False], [True]])
    # Accuracy: 3 of 4 right at any threshold in [0.4, 0.6) or [0.6, 0.8); the first such grid point wins.
    assert noise.fit_thresholds(probabilities, labels, grid=[0.1, 0.3, 0.5, 0.7, 1.0])[0] == 0.3
    # Weighted by the error each knock-out removes (+) or adds (-): knocking out the 0.6 entry costs
    # more than missing the 0.4 one gains, so only the 0.8 entry is knocked out.
    gains = np.array([[-1.0], [1.0], [-5.0], [1.0]])
    assert noise.fit_thresholds(probabilities, gains > 0, grid=[0.1, 0.3, 0.5, 0.7, 1.0], weights=np.abs(gains))[0] == 0.7


def test_knockout_classifier_learns_where_rays_are_swallowed_and_round_trips(tmp_path):
    canonical, features, real, swallowed = knocked_scans()
    labels = noise.label(real, canonical, 0.5)
    inputs = np.column_stack([canonical, features])
    train = slice(0, 1000)
    model = noise.train_knockout(inputs[train], labels[train], (16,), knocked=LIMIT, epochs=40, batch=64, seed=0, threads=1)
    held_out = slice(1000, None)
    knocked = model.knockouts(canonical[held_out], features[held_out])
    assert np.mean(knocked[:, 2] == swallowed[held_out]) > 0.95  # 0.994 measured
    assert np.mean(np.all(knocked == labels[held_out], axis=1)) > 0.9
    out = model.apply(canonical[held_out], features[held_out])
    assert np.abs(out - real[held_out]).mean() < 0.25 * np.abs(canonical[held_out] - real[held_out]).mean()  # 0.04
    model.save(tmp_path / "knockout.onnx", tmp_path / "knockout.npz")
    again = noise.KnockoutModel.load(tmp_path / "knockout.onnx", tmp_path / "knockout.npz")
    assert np.array_equal(again.apply(canonical, features), model.apply(canonical, features))
    network = pv.load_network(tmp_path / "knockout.onnx")
    assert [layer.activation for layer in network.layers] == ["tanh", "sigmoid"]
    assert network.domain == tuple(zip(inputs[train].min(axis=0), inputs[train].max(axis=0)))
    np.testing.assert_allclose(onnx_outputs(tmp_path / "knockout.onnx", inputs[:50]), model.network(inputs[:50]), atol=1e-12)
    with pytest.raises(InputError, match="labels N x m"):
        noise.train_knockout(inputs[:, :4], labels, knocked=LIMIT, epochs=1)
    with pytest.raises(InputError, match="one threshold per output"):
        noise.KnockoutModel(network, np.zeros(5), LIMIT)


def contrasted(n=400, seed=0):
    """Eight-pixel 'images' and a gamma per image: the benign noise maps x to x ** gamma."""
    rng = np.random.default_rng(seed)
    canonical = rng.uniform(0.05, 0.95, (n, 8))
    gamma = rng.uniform(0.5, 2.0, (n, 1))
    return canonical, gamma, canonical**gamma


def test_generative_model_learns_a_benign_noise_and_round_trips(tmp_path):
    canonical, gamma, measured = contrasted()
    train, held_out = slice(0, 300), slice(300, None)
    model = noise.train_generative(canonical[train], gamma[train], measured[train], (32,), epochs=300, seed=0, threads=1)
    error = np.sqrt(np.mean((model(canonical[held_out], gamma[held_out]) - measured[held_out]) ** 2))
    identity = np.sqrt(np.mean((canonical[held_out] - measured[held_out]) ** 2))
    assert error < 0.5 * identity  # 0.27 measured
    model.save(tmp_path / "gamma.onnx")
    again = noise.GenerativeModel.load(tmp_path / "gamma.onnx")
    assert again.n_conditions == 1
    x = np.column_stack([canonical, gamma])
    np.testing.assert_allclose(onnx_outputs(tmp_path / "gamma.onnx", x), model.network(x), atol=1e-12)
    loaded = pv.load_network(tmp_path / "gamma.onnx")
    assert loaded.layers[-1].activation == "sigmoid"
    # the training inputs' range is the network's domain, kept in the file
    assert loaded.domain == tuple(zip(x[train].min(axis=0), x[train].max(axis=0)))


def test_generative_model_of_unbounded_measurements_uses_least_squares(tmp_path):
    canonical, gamma, _ = contrasted()
    canonical = canonical * 4.0  # ranges in metres
    measured = canonical * (1.0 + 0.05 * gamma) + 0.1
    with pytest.raises(InputError, match="in \\[0, 1\\]"):
        noise.train_generative(canonical, gamma, measured, loss="bce", epochs=1)
    model = noise.train_generative(canonical[:300], gamma[:300], measured[:300], (32,), epochs=300, seed=0, threads=1)
    error = np.sqrt(np.mean((model(canonical[300:], gamma[300:]) - measured[300:]) ** 2))
    assert error < 0.5 * np.sqrt(np.mean((canonical[300:] - measured[300:]) ** 2))  # 0.20 measured
    model.save(tmp_path / "ranges.onnx")
    x = np.column_stack([canonical, gamma])[:20]
    np.testing.assert_allclose(pv.load_network(tmp_path / "ranges.onnx")(x), model.network(x), atol=1e-12)
    with pytest.raises(InputError, match="one shape"):
        noise.train_generative(canonical[:, :4], gamma, measured, epochs=1)


def test_training_without_torch_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)  # what `import torch` meets when torch is not installed
    canonical, features, real, _ = knocked_scans(50)
    with pytest.raises(MissingDependencyError, match='pip install "percver\\[train\\]"'):
        noise.train_knockout(np.column_stack([canonical, features]), real > 4.9, knocked=LIMIT)
    with pytest.raises(MissingDependencyError, match="learn=True"):
        pv.diagnose(pv.sensors.lidar.canonical(), pv.Measurements(np.zeros((3, 3)), np.zeros((3, 21))), learn=True)


def test_training_with_progress_says_how_long_it_will_take(capsys):
    pytest.importorskip("torch")
    from percver.noise import train_generative

    rng = np.random.default_rng(0)
    canonical = rng.uniform(0, 1, (64, 3))
    train_generative(canonical, rng.uniform(0, 1, (64, 1)), canonical, (4,), epochs=3, progress=True, threads=1)
    err = capsys.readouterr().err
    # The estimate comes before the bar starts, and the bar counts to its total (3 epochs x 2 mini-batches).
    estimate = re.search(r"generative: about [\d.]+ (s|min|h) for 3 epochs of 2 mini-batches", err)
    assert estimate is not None and estimate.start() < err.index("0/6")
    assert "6/6" in err and "epoch=3/3" in err
