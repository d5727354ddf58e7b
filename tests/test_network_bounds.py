"""Sound bounds through networks: every float sample from inside a box lies inside the bounds.

The shared networks are read from ../shared/data (the tests fail if it is missing: CI has it).
References are onnxruntime for ONNX files and the numpy forward pass for Verisig .yml files
(tests/shared_networks.py); the Verisig translation's campaign is in test_network_bounds_verisig.py.
"""

import numpy as np
import pytest
from shared_networks import MC, assert_inside, load_shared, reference, samples

import percver as pv
from percver.errors import BlowUpError, InputError, NetworkFormatError


@pytest.fixture(scope="module")
def shared():
    return load_shared()


@pytest.mark.parametrize("half_width", [1e-6, 1e-3, 0.05])
def test_shared_networks_direct_and_interval_are_sound(shared, half_width):
    """Boxes from 1e-6 to 10% of the unit input range around random centres."""
    rng = np.random.default_rng(int(half_width * 1e6) + 7)
    for path, network in shared.items():
        centre = rng.uniform(-0.5, 0.5, network.n_in)
        box = list(zip(centre - half_width, centre + half_width))
        x = samples(rng, box)
        y = reference(path, network, x)
        for method in ("taylor", "interval"):
            assert_inside(network.bounds(box, method=method), y, f"{path.name} {method} +-{half_width}")


def _mc(name: str) -> pv.Network:
    return pv.load_network(next(MC.glob(f"{name}*.yml")))


@pytest.fixture(scope="module")
def mountain_car():
    assert MC.is_dir(), f"shared data missing at {MC}"
    generator, contraster, blurer = _mc("Generator"), _mc("Contraster"), _mc("Blurer")
    estimator = pv.Network(_mc("CompositeRegressor").layers, scale=0.9, offset=-0.3, name="estimator")
    return generator, contraster, blurer, estimator, _mc("ControllerSigmoid")


def _manual_chain(mc, x):
    """The paper's perception and control chain written out stage by stage: (p, delta, v) -> u."""
    generator, contraster, _, estimator, controller = mc
    image = generator(x[:, :1])
    noisy = contraster(np.column_stack([image, x[:, 1]]))
    return controller(np.column_stack([estimator(noisy), x[:, 2]]))


def test_mountain_car_chain_is_sound_and_tight(mountain_car):
    generator, contraster, _, estimator, controller = mountain_car
    chain = pv.chain(
        generator.passthrough(["delta", "v"]), contraster.passthrough(["v"]), estimator.passthrough(["v"]), controller
    ).with_input_names(["p", "delta", "v"])
    box = {"p": (-0.5, -0.49975), "delta": (0.3, 2.0), "v": (-1e-4, 1e-4)}
    rng = np.random.default_rng(3)
    x = samples(rng, list(box.values()))
    y = chain(x)
    np.testing.assert_allclose(y, _manual_chain(mountain_car, x), rtol=0, atol=1e-12)
    bounds = chain.bounds(box, order=4, pieces={"delta": 5}, max_vars=2)
    assert_inside(bounds, y, "chain, direct")
    sampled = y.max() - y.min()
    width = bounds[0][1] - bounds[0][0]
    assert width <= 2.0 * sampled, f"direct width {width} vs sampled {sampled}"
    naive = chain.bounds(box, method="interval")
    assert_inside(naive, y, "chain, interval")
    assert naive[0][1] - naive[0][0] > 10 * width


def test_mountain_car_chain_verisig_on_a_narrow_contrast(mountain_car):
    generator, contraster, _, estimator, controller = mountain_car
    chain = pv.chain(
        generator.passthrough(["delta", "v"]), contraster.passthrough(["v"]), estimator.passthrough(["v"]), controller
    ).with_input_names(["p", "delta", "v"])
    box = {"p": (-0.5, -0.49975), "delta": (1.0, 1.01), "v": (-1e-4, 1e-4)}
    y = chain(samples(np.random.default_rng(4), list(box.values())))
    verisig = chain.bounds(box, method="verisig", order=3, max_vars=2)
    direct = chain.bounds(box, order=4, max_vars=2)
    assert_inside(verisig, y, "chain, verisig")
    assert_inside(direct, y, "chain, direct")
    assert verisig[0][0] <= direct[0][1] and direct[0][0] <= verisig[0][1]


@pytest.mark.parametrize("noise, noise_box", [("contraster", (0.3, 2.0)), ("blurer", (0.0, 0.3))])
def test_image_networks_through_the_generator(mountain_car, noise, noise_box):
    """600-pixel inputs: boxes induced by the generator on a position interval of width 0.00025."""
    generator, contraster, blurer, estimator, _ = mountain_car
    noise_net = contraster if noise == "contraster" else blurer
    chain = pv.chain(generator.passthrough(["delta"]), noise_net, estimator).with_input_names(["p", "delta"])
    box = {"p": (-0.52, -0.51975), "delta": noise_box}
    x = samples(np.random.default_rng(5), list(box.values()))
    y = estimator(noise_net(np.column_stack([generator(x[:, :1]), x[:, 1]])))
    np.testing.assert_allclose(chain(x), y, rtol=0, atol=1e-12)
    assert_inside(chain.bounds(box, order=4, pieces={"delta": 4}), y, f"generator -> {noise} -> estimator")
    # The image alone and the estimator on generated images (no noise).
    image_box = {"in0": (-0.52, -0.51975)}
    images = generator(x[:, :1])
    assert_inside(generator.bounds(image_box), images, "generator")
    assert_inside(pv.chain(generator, estimator).bounds(image_box), estimator(images), "generator -> estimator")


def test_taylor_models_carry_between_networks(mountain_car):
    generator, contraster, _, estimator, _ = mountain_car
    box = {"p": (-0.5, -0.49975), "delta": (1.0, 1.2)}
    first = generator.passthrough(["delta"]).with_input_names(["p", "delta"])
    models = first.taylor_models(box)
    assert len(models) == 601 and models.order == 5
    assert [v[0] for v in models.variables] == [0, 1]
    noisy = contraster.taylor_models(models)
    x = samples(np.random.default_rng(6), list(box.values()), 3000)
    truth = estimator(contraster(np.column_stack([generator(x[:, :1]), x[:, 1]])))
    carried = estimator.bounds(noisy)
    assert_inside(carried, truth, "models carried generator -> contraster -> estimator")
    assert_inside(models.bounds(), first(x), "generator models")
    whole = pv.chain(first, contraster, estimator).bounds(box)
    assert carried[0][1] - carried[0][0] <= 1.0001 * (whole[0][1] - whole[0][0]) + 1e-12


def test_passthrough_carries_inputs_exactly():
    rng = np.random.default_rng(8)
    net = pv.Network([(rng.normal(size=(4, 2)), rng.normal(size=4), "tanh"), (rng.normal(size=(1, 4)), [0.5], "sigmoid")], scale=2.0)
    wide = net.passthrough(["a", "b"])
    assert wide.n_in == 4 and wide.n_out == 3 and wide.input_names == ("in0", "in1", "a", "b")
    x = rng.normal(size=(50, 4))
    np.testing.assert_array_equal(wide(x)[:, 1:], x[:, 2:])
    np.testing.assert_allclose(wide(x)[:, 0], net(x[:, :2])[:, 0], rtol=1e-15)
    assert wide.layers[0].activations == ("tanh",) * 4 + ("identity",) * 2
    assert "4 tanh+2 identity" in repr(wide)
    box = {"in0": (0.1, 0.2), "in1": (-0.3, -0.1), "a": (1.0, 1.0), "b": (-2.0, 2.0)}
    bounds = wide.bounds(box)
    assert bounds[1][0] <= 1.0 <= bounds[1][1] and bounds[1][1] - bounds[1][0] < 1e-14
    assert bounds[2][0] <= -2.0 and 2.0 <= bounds[2][1] < 2.0 + 1e-14
    assert net.passthrough(1).input_names == ("in0", "in1", "in2")


def test_mixed_layers_cannot_be_written(tmp_path):
    net = pv.Network([(np.eye(2), [0.0, 0.0], ("tanh", "identity"))])
    with pytest.raises(NetworkFormatError, match="mixes"):
        pv.save_network(net, tmp_path / "mixed.onnx")
    with pytest.raises(NetworkFormatError, match="per neuron"):
        pv.save_network(net, tmp_path / "mixed.yml")
    with pytest.raises(NetworkFormatError, match="3 activations for 2 neurons"):
        pv.Network([(np.eye(2), [0.0, 0.0], ("tanh", "identity", "relu"))])


def test_bad_boxes_and_settings_are_clear_errors():
    net = pv.Network([(np.ones((3, 2)), np.zeros(3), "sigmoid")], input_names=["x", "y"])
    with pytest.raises(InputError, match="takes 2 inputs, the box has 3"):
        net.bounds([(0, 1), (0, 1), (0, 1)])
    with pytest.raises(InputError, match="NaN"):
        net.bounds({"x": (float("nan"), 1.0), "y": (0, 1)})
    with pytest.raises(InputError, match="swap"):
        net.bounds({"x": (1.0, 0.0), "y": (0, 1)})
    with pytest.raises(InputError, match=r"\['z'\] not among its inputs"):
        net.bounds({"x": (0, 1), "z": (0, 1)})
    with pytest.raises(InputError, match="unknown method 'exact'"):
        net.bounds({"x": (0, 1), "y": (0, 1)}, method="exact")
    with pytest.raises(InputError, match="order must be between"):
        net.bounds([(0, 1), (0, 1)], order=0)
    with pytest.raises(InputError, match="cannot split 'q'"):
        net.bounds([(0, 1), (0, 1)], pieces={"q": 3})
    models = net.taylor_models([(0, 1), (0, 1)])
    with pytest.raises(InputError, match="takes 2 inputs, the models have 3"):
        net.bounds(models)
    with pytest.raises(InputError, match="distinct names"):
        net.with_input_names(["x", "x"])


def test_verisig_reports_divergence_as_blow_up():
    # A wide box through a steep tanh layer: Verisig's enclosure cannot follow, and says so.
    rng = np.random.default_rng(9)
    net = pv.Network([(rng.normal(scale=8, size=(20, 2)), rng.normal(size=20), "tanh"), (rng.normal(size=(20, 20)), np.zeros(20), "tanh")])
    with pytest.raises(BlowUpError, match="Verisig translation, layer"):
        net.bounds([(-1, 1), (-1, 1)], method="verisig", order=3)


def _one_input_prefix(rng) -> pv.Network:
    """Inputs (p, q): p -> 8 tanh -> 12 sigmoid with q carried as an identity neuron, then 4 tanh
    reading both, then 2 outputs: the engine takes the first two layers over p's range as one
    variable (a generator and its noise model in miniature)."""
    w1 = np.zeros((9, 2))
    w1[:8, 0], w1[8, 1] = rng.normal(scale=3.0, size=8), 1.0
    w2 = np.zeros((13, 9))
    w2[:12, :8], w2[12, 8] = rng.normal(scale=1.5, size=(12, 8)), 1.0
    return pv.Network(
        [
            (w1, rng.normal(scale=0.5, size=9), ("tanh",) * 8 + ("identity",)),
            (w2, rng.normal(scale=0.5, size=13), ("sigmoid",) * 12 + ("identity",)),
            (rng.normal(size=(4, 13)), rng.normal(scale=0.2, size=4), "tanh"),
            (rng.normal(size=(2, 4)), [0.1, -0.1], "identity"),
        ],
        scale=[2.0, 0.5],
    )


@pytest.mark.parametrize("half_width", [1e-3, 0.05, 0.4])
def test_one_input_prefix_encloses_samples(half_width):
    """Models of (p, q) from a first network (polynomials with error symbols) through a network
    whose first layers read p alone: the float forward passes of both lie inside the bounds, which
    are tight on small boxes (on wide ones Taylor models are loose either way)."""
    rng = np.random.default_rng(31)
    first = pv.Network([(rng.normal(size=(2, 2)), rng.normal(scale=0.3, size=2), "tanh")])
    net = _one_input_prefix(rng)
    box = [(0.2 - half_width, 0.2 + half_width), (-0.3 - half_width, -0.3 + half_width)]
    x = samples(rng, box, 5000)
    y = net(first(x))
    bounds = net.bounds(first.taylor_models(box, order=5), order=5)
    assert_inside(bounds, y, f"one-input prefix +-{half_width}")
    assert_inside(net.bounds(first.taylor_models(box, order=3), order=3), y, f"one-input prefix order 3 +-{half_width}")
    spread = y.max(axis=0) - y.min(axis=0)
    widths = np.diff(np.array(bounds), axis=1)[:, 0]
    if half_width <= 0.05:
        assert (widths <= 2.0 * spread + 1e-9).all(), f"{widths} against sampled {spread}"
