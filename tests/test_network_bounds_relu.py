"""ReLU network bounds: back-substituted ReLU ranges (``back_substitution``) and branch-and-bound
refinement (``Network.bounds(..., leaves=N)``), sound against an independent numpy or onnxruntime
evaluation, never wider than the bounds without them, and far tighter on a ReLU network over a
box where most neurons change sign."""

import numpy as np
import pytest
from shared_networks import DATA, assert_inside, reference, samples

import percver as pv


def relu_network(seed: int, sizes=(4, 40, 40, 3)):
    rng = np.random.default_rng(seed)
    layers = []
    for k, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        last = k == len(sizes) - 2
        layers.append((rng.normal(0, 1 / np.sqrt(n_in), (n_out, n_in)), rng.normal(0, 0.1, n_out), "identity" if last else "relu"))
    return layers


def numpy_eval(layers, x):
    for w, b, act in layers:
        x = x @ w.T + b
        if act == "relu":
            x = np.maximum(x, 0.0)
    return x


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refined_bounds_enclose_numpy_samples(seed):
    layers = relu_network(seed)
    net = pv.Network(layers)
    centre = np.random.default_rng(seed + 10).uniform(-1, 1, 4)
    box = [(c - 0.5, c + 0.5) for c in centre]
    whole = np.array(net.bounds(box))
    refined = np.array(net.bounds(box, leaves=256))
    rng = np.random.default_rng(seed + 20)
    x = centre + rng.uniform(-0.5, 0.5, (20000, 4))
    corners = centre + 0.5 * np.array(np.meshgrid(*[[-1, 1]] * 4)).reshape(4, -1).T
    y = numpy_eval(layers, np.vstack([x, corners]))
    assert np.all(y >= refined[:, 0]) and np.all(y <= refined[:, 1])
    assert np.all(refined[:, 0] >= whole[:, 0]) and np.all(refined[:, 1] <= whole[:, 1])
    sampled = y.max(0) - y.min(0)
    assert np.max((refined[:, 1] - refined[:, 0]) / sampled) < np.max((whole[:, 1] - whole[:, 0]) / sampled)


def test_leaves_must_be_a_positive_integer_and_a_box():
    net = pv.Network(relu_network(0))
    with pytest.raises(pv.InputError, match="leaves must be a positive integer"):
        net.bounds([(0, 1)] * 4, leaves=0)
    with pytest.raises(pv.InputError, match="method='taylor'"):
        net.bounds([(0, 1)] * 4, method="interval", leaves=4)


def relu_onnx_files():
    return [p for p in sorted((DATA / "onnx").glob("nn_*relu*.onnx"))]


def compare(net, box, y, label):
    """Bounds and Taylor-model ranges with and without back-substitution contain the samples y;
    with it, each end is at most 0.1% of the width beyond the end without (the zonotope
    relaxation is not monotone in its ranges), and the total width is no larger."""
    widths = {}
    for back in (True, False):
        bounds = np.array(net.bounds(box, back_substitution=back))
        models = np.array(net.taylor_models(box, back_substitution=back).bounds())
        assert_inside(bounds, y, f"{label} bounds, back_substitution={back}")
        assert_inside(models, y, f"{label} models, back_substitution={back}")
        widths[back] = bounds
    with_, without = widths[True], widths[False]
    slack = 1e-3 * (without[:, 1] - without[:, 0])
    assert np.all(with_[:, 0] >= without[:, 0] - slack) and np.all(with_[:, 1] <= without[:, 1] + slack), label
    return np.sum(with_[:, 1] - with_[:, 0]), np.sum(without[:, 1] - without[:, 0])


def test_back_substitution_is_sound_on_shared_relu_networks_against_onnxruntime():
    rng = np.random.default_rng(5)
    files = relu_onnx_files()
    assert len(files) >= 10
    totals = np.zeros(2)
    for path in files:
        net = pv.load_network(path)
        centre = rng.uniform(-0.5, 0.5, net.n_in)
        box = [(c - 0.5, c + 0.5) for c in centre]
        x = samples(rng, box, 4000)
        totals += compare(net, box, reference(path, net, x), path.name)
    assert totals[0] <= totals[1]


@pytest.mark.parametrize("sizes", [(4, 40, 40, 3), (6, 30, 30, 30, 30, 2), (12, 50, 50, 10, 4)])
def test_back_substitution_is_sound_and_tighter_on_random_relu_networks(sizes):
    layers = relu_network(sum(sizes), sizes)
    net = pv.Network(layers)
    rng = np.random.default_rng(len(sizes))
    totals = np.zeros(2)
    for _ in range(3):
        centre = rng.uniform(-1, 1, sizes[0])
        box = [(c - 0.5, c + 0.5) for c in centre]
        y = numpy_eval(layers, samples(rng, box, 5000))
        totals += compare(net, box, y, f"{sizes}")
    assert totals[0] < totals[1], f"back-substitution must tighten deep ReLU bounds: {totals}"


def test_optimised_slopes_are_sound_and_tighter_on_the_archcomp_airplane_controller():
    """alpha-CROWN on the 12-input ARCH-COMP Airplane controller (most neurons change sign over
    this box): the numpy forward pass of every sample lies inside, and the bounds are tighter
    than with the adaptive slopes."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        net = pv.load_network(DATA / "archcomp2024" / "models" / "Airplane" / "controller_airplane.nnet")
    layers = [(layer.weight, layer.bias, layer.activation) for layer in net.layers]
    centre = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0])
    box = [(c - 0.5, c + 0.5) for c in centre]
    y = numpy_eval(layers, samples(np.random.default_rng(3), box, 20000))
    adaptive = np.array(net.bounds(box))
    optimised = np.array(net.bounds(box, alpha_steps=20))
    for bounds in (adaptive, optimised):
        assert_inside(bounds, y, "airplane")
    assert np.sum(optimised[:, 1] - optimised[:, 0]) < np.sum(adaptive[:, 1] - adaptive[:, 0])
