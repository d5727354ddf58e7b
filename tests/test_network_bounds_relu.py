"""Branch-and-bound refinement of network bounds (``Network.bounds(..., leaves=N)``): sound
against an independent numpy evaluation, never wider than the unrefined bounds, and far tighter
on a ReLU network over a box where most neurons change sign."""

import numpy as np
import pytest

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
