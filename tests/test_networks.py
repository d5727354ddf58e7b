"""Networks: loading ONNX and Verisig .yml files, float evaluation, writing back, chaining, errors.

The shared networks are read from ../shared/data (never copied here); if that folder is missing the
tests fail, since CI has it. All other fixtures are generated below.
"""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
import yaml
from onnx import TensorProto, helper, numpy_helper
from scipy.special import expit

import percver as pv
from percver.errors import InputError, MissingFileError, NetworkFormatError
from percver.networks import Layer

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
N_SHARED_ONNX = 28
N_SHARED_YAML_NETWORKS = 30


def _yaml_candidates() -> list[Path]:
    return sorted(
        [
            *(DATA / "mountain_car" / "networks").glob("*.yml"),
            DATA / "mountain_car" / "state_based" / "sig16x16.yml",
            *(DATA / "f1tenth" / "controllers").glob("*.yml"),
            *(DATA / "f1tenth" / "noise_models").glob("*.yml"),
            *(DATA / "verisig2_suite").glob("*/*.yml"),
        ]
    )


def _read_yaml(path: Path):
    with open(path) as file:
        return yaml.load(file, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


@pytest.fixture(scope="module")
def shared_onnx():
    assert DATA.is_dir(), f"shared data missing at {DATA}"
    files = sorted(DATA.glob("**/*.onnx"))
    assert len(files) == N_SHARED_ONNX, [f.name for f in files]
    return {path: pv.load_network(path) for path in files}


@pytest.fixture(scope="module")
def shared_yaml():
    """{path: (network, parsed document)} for every network .yml; Verisig run configs are left out."""
    assert DATA.is_dir(), f"shared data missing at {DATA}"
    documents = {path: _read_yaml(path) for path in _yaml_candidates()}
    networks = {path: (pv.load_network(path), doc) for path, doc in documents.items() if "weights" in doc}
    assert len(networks) == N_SHARED_YAML_NETWORKS, sorted(p.name for p in networks)
    return networks


# ---------------------------------------------------------------------------------------------- references


def _numpy_forward(document, x):
    """Verisig semantics written out directly: h = act(W h + b), layer by layer."""
    h = x
    for index in sorted(document["weights"]):
        h = h @ np.array(document["weights"][index]).T + np.array(document["offsets"][index])
        activation = document["activations"][index]
        h = {"Sigmoid": expit, "Tanh": np.tanh, "Relu": lambda z: np.maximum(z, 0)}.get(activation, lambda z: z)(h)
    return h


def _session(model):
    data = model.SerializeToString() if isinstance(model, onnx.ModelProto) else str(model)
    return onnxruntime.InferenceSession(data, providers=["CPUExecutionProvider"])


def _run(session, x):
    return session.run(None, {session.get_inputs()[0].name: x})[0]


def _in_double(path: Path):
    """The same graph in float64 with a dynamic batch, so onnxruntime and percver do the same arithmetic."""
    model = onnx.load(str(path))
    for tensor in model.graph.initializer:
        if tensor.data_type == TensorProto.FLOAT:
            array = numpy_helper.to_array(tensor).astype(np.float64)
            tensor.CopyFrom(numpy_helper.from_array(array, tensor.name))
    for value in [*model.graph.input, *model.graph.output]:
        value.type.tensor_type.elem_type = TensorProto.DOUBLE
        value.type.tensor_type.shape.dim[0].dim_param = "batch"
    del model.graph.value_info[:]
    return _session(model)


def _model(nodes, inputs, outputs, initializers=(), opset=13):
    graph = helper.make_graph(nodes, "fixture", inputs, outputs, [numpy_helper.from_array(a, name) for name, a in initializers])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 8
    return model


def _save(model, path: Path) -> Path:
    onnx.save(model, str(path))
    return path


def _tensor(name, shape, dtype=TensorProto.DOUBLE):
    return helper.make_tensor_value_info(name, dtype, shape)


def _node(op, inputs, output, name=None, **attributes):
    return helper.make_node(op, inputs, [output], name=name or output, **attributes)


def _close(actual, expected, rtol=1e-6, atol=1e-12):
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol)


# ------------------------------------------------------------------------------------------- shared data


def test_shared_onnx_networks_agree_with_onnxruntime(shared_onnx):
    rng = np.random.default_rng(0)
    for path, network in shared_onnx.items():
        x = rng.uniform(-2, 2, size=(64, network.n_in))
        _close(network(x), _run(_in_double(path), x), rtol=1e-6, atol=1e-12)


def test_shared_onnx_conventions(shared_onnx):
    by_name = {path.stem: net for path, net in shared_onnx.items()}
    # three Gemms without activation in between fold into one 8 -> 20 tanh layer
    acc = by_name["acc_tanh20x20x20_"]
    assert [(layer.weight.shape, layer.activation) for layer in acc.layers] == [
        ((20, 8), "tanh"), ((20, 20), "tanh"), ((20, 20), "tanh"), ((1, 20), "identity")
    ]  # fmt: skip
    # the 1x1 "affine" Gemm after the last activation is an output map: sigmoid in (0, 1) -> (-4, 4)
    nn1 = by_name["nn_1_sigmoid"]
    assert [layer.activation for layer in nn1.layers] == ["sigmoid"] * 3
    assert nn1.scale.tolist() == [8.0] and nn1.offset.tolist() == [-4.0]


def test_shared_yaml_networks_agree_with_numpy(shared_yaml):
    rng = np.random.default_rng(1)
    for path, (network, document) in shared_yaml.items():
        assert network.source == path and network.name == path.stem
        assert len(network.layers) == len(document["weights"])
        x = rng.uniform(-1, 1, size=(32, network.n_in))
        _close(network(x), _numpy_forward(document, x))


def test_shared_yaml_shapes(shared_yaml):
    by_name = {path.stem: net for path, (net, _) in shared_yaml.items()}
    generator = by_name["Generator2x50_100_Decay1TestLoss1.035e-06"]
    assert (generator.n_in, generator.n_out) == (1, 600)
    assert [layer.activation for layer in generator.layers] == ["tanh", "tanh", "sigmoid"]
    assert (by_name["Contraster1x50_Decay5TestLoss47.74"].n_in, by_name["noiser5x100"].n_in) == (601, 24)


def test_shared_run_configs_are_not_networks(shared_yaml):
    configs = [path for path in _yaml_candidates() if path not in shared_yaml]
    assert len(configs) == 4
    for path in configs:
        with pytest.raises(NetworkFormatError, match="not a Verisig network file"):
            pv.load_network(path)


def test_shared_round_trips(shared_onnx, shared_yaml, tmp_path):
    rng = np.random.default_rng(2)
    networks = [*shared_onnx.values(), *(net for net, _ in shared_yaml.values())]
    for network in networks:
        x = rng.uniform(-1, 1, size=(16, network.n_in))
        expected = network(x)
        pv.save_network(network, tmp_path / "net.onnx")
        _close(_run(_session(tmp_path / "net.onnx"), x), expected, rtol=1e-12)
        again = pv.load_network(tmp_path / "net.onnx")
        assert all(np.array_equal(a.weight, b.weight) for a, b in zip(again.layers, network.layers))
        np.testing.assert_array_equal(again(x), expected)
        pv.save_network(network, tmp_path / "net.yml")
        _close(pv.load_network(tmp_path / "net.yml")(x), expected, rtol=1e-12)


def test_chain_generator_into_estimator(shared_yaml):
    by_name = {path.stem: net for path, (net, _) in shared_yaml.items()}
    generator = by_name["Generator2x50_100_Decay1TestLoss1.035e-06"]
    regressor = by_name["CompositeRegressor3x20_20_20_Decay0.001TestLoss5.15e-06Composite"]
    estimator = pv.Network(regressor.layers, scale=0.9, offset=-0.3, name="estimator")  # p_hat = 0.9 out - 0.3
    composed = pv.chain(generator, estimator)
    assert len(composed.layers) == 7 and (composed.n_in, composed.n_out) == (1, 1)
    p = np.linspace(-0.59, -0.4, 50)[:, None]  # the verified initial positions
    _close(composed(p), estimator(generator(p)), rtol=1e-12)
    assert np.abs(composed(p) - p).max() < 0.02  # the estimator recovers the position from the image
    with pytest.raises(InputError, match=r"600 outputs.*601 inputs"):
        pv.chain(generator, by_name["Contraster1x50_Decay5TestLoss47.74"])


# ------------------------------------------------------------------------------- generated ONNX fixtures


def test_keras_style_matmul_add(tmp_path):
    rng = np.random.default_rng(3)
    w1, b1, w2, b2, w3, b3 = (rng.normal(size=s) for s in [(3, 5), 5, (5, 4), 4, (4, 2), 2])
    nodes = [
        _node("MatMul", ["dense_input", "w1"], "m1"),
        _node("Add", ["m1", "b1"], "a1"),
        _node("Relu", ["a1"], "r1"),
        _node("MatMul", ["r1", "w2"], "m2"),
        _node("Add", ["b2", "m2"], "a2"),  # constant first
        _node("Sigmoid", ["a2"], "s2"),
        _node("MatMul", ["s2", "w3"], "m3"),
        _node("Add", ["m3", "b3"], "dense_2"),
    ]
    inits = [("w1", w1), ("b1", b1), ("w2", w2), ("b2", b2), ("w3", w3), ("b3", b3)]
    path = _save(_model(nodes, [_tensor("dense_input", ["unk__0", 3])], [_tensor("dense_2", ["unk__0", 2])], inits),
                 tmp_path / "keras.onnx")  # fmt: skip
    network = pv.load_network(path)
    assert [(layer.n_out, layer.activation) for layer in network.layers] == [
        (5, "relu"), (4, "sigmoid"), (2, "identity")
    ]  # fmt: skip
    x = rng.normal(size=(40, 3))
    _close(network(x), _run(_session(path), x))


def test_pytorch_style_gemm_attributes_and_folding(tmp_path):
    rng = np.random.default_rng(4)
    w1, b1, w2, c2, w3 = (rng.normal(size=s) for s in [(6, 4), 6, (6, 3), (1, 3), (2, 3)])
    nodes = [
        _node("Gemm", ["x", "w1", "b1"], "g1", transB=1, alpha=0.5, beta=2.0),
        _node("Gemm", ["g1", "w2", "c2"], "g2"),  # no activation in between: folds into one layer
        _node("Tanh", ["g2"], "t"),
        _node("Transpose", ["t"], "tt", perm=[1, 0]),
        _node("Gemm", ["tt", "w3"], "g3", transA=1, transB=1),
        _node("Identity", ["g3"], "y"),
    ]
    inits = [("w1", w1), ("b1", b1), ("w2", w2), ("c2", c2), ("w3", w3)]
    path = _save(_model(nodes, [_tensor("x", ["N", 4])], [_tensor("y", ["N", 2])], inits), tmp_path / "torch.onnx")
    network = pv.load_network(path)
    assert [(layer.weight.shape, layer.activation) for layer in network.layers] == [
        ((3, 4), "tanh"), ((2, 3), "identity")
    ]  # fmt: skip
    x = rng.normal(size=(40, 4))
    _close(network(x), _run(_session(path), x))


def _float32(rng, *shape):
    return rng.normal(size=shape).astype(np.float32)


def test_matlab_style_sub_conv_flatten(tmp_path):
    rng = np.random.default_rng(5)
    mean = helper.make_tensor("mean_value", TensorProto.FLOAT, [1, 1, 1, 5], _float32(rng, 5).tolist())
    scale, offset = _float32(rng, 3), np.array(0.25, dtype=np.float32)
    nodes = [
        helper.make_node("Constant", [], ["mean"], name="mean", value=mean),
        _node("Sub", ["input", "mean"], "centred"),
        _node("Div", ["centred", "std"], "normalised"),
        _node("Transpose", ["normalised"], "channels", perm=[0, 3, 1, 2]),  # 1x1x1x5 -> 1x5x1x1
        _node("Conv", ["channels", "w1", "b1"], "fc1", kernel_shape=[1, 1]),
        _node("Tanh", ["fc1"], "tanh1"),
        _node("Conv", ["tanh1", "w2"], "fc2"),
        _node("Flatten", ["fc2"], "flat", axis=1),
        _node("Sigmoid", ["flat"], "sig"),
        _node("Reshape", ["sig", "shape"], "column"),
        _node("Squeeze", ["column", "last_axis"], "row"),
        _node("Unsqueeze", ["row", "first_axis"], "batched"),
        _node("Mul", ["batched", "scale"], "scaled"),
        _node("Add", ["scaled", "offset"], "output"),
    ]
    inits = [
        ("std", np.abs(_float32(rng, 1, 1, 1, 5)) + 0.5),
        ("w1", _float32(rng, 8, 5, 1, 1)), ("b1", _float32(rng, 8)), ("w2", _float32(rng, 3, 8, 1, 1)),
        ("shape", np.array([1, 3, 1])), ("last_axis", np.array([2])), ("first_axis", np.array([0])),
        ("scale", scale), ("offset", offset),
    ]  # fmt: skip
    inputs = [_tensor("input", [1, 1, 1, 5], TensorProto.FLOAT)]
    outputs = [_tensor("output", [1, 1, 3], TensorProto.FLOAT)]
    path = _save(_model(nodes, inputs, outputs, inits), tmp_path / "matlab.onnx")
    network = pv.load_network(path)
    assert [(layer.weight.shape, layer.activation) for layer in network.layers] == [
        ((8, 5), "tanh"), ((3, 8), "sigmoid")
    ]  # fmt: skip
    np.testing.assert_array_equal(network.scale, scale.astype(np.float64))
    np.testing.assert_array_equal(network.offset, np.full(3, 0.25))
    session = _session(path)
    for x in rng.normal(size=(20, 5)).astype(np.float32):
        _close(network(x), _run(session, x.reshape(1, 1, 1, 5)).ravel(), rtol=1e-5, atol=1e-6)


def test_strided_padded_convolution(tmp_path):
    rng = np.random.default_rng(6)
    nodes = [
        _node("Conv", ["x", "w", "b"], "conv", pads=[1, 1], strides=[2], dilations=[1]),
        _node("Relu", ["conv"], "relu"),
        _node("Flatten", ["relu"], "flat"),
        _node("Gemm", ["flat", "w2"], "y", transB=1),
    ]
    inits = [("w", _float32(rng, 4, 2, 3)), ("b", _float32(rng, 4)), ("w2", _float32(rng, 3, 16))]
    inputs, outputs = [_tensor("x", [1, 2, 7], TensorProto.FLOAT)], [_tensor("y", [1, 3], TensorProto.FLOAT)]
    path = _save(_model(nodes, inputs, outputs, inits), tmp_path / "conv.onnx")
    network = pv.load_network(path)
    assert (network.n_in, network.layers[0].n_out, network.n_out) == (14, 16, 3)
    session = _session(path)
    for x in rng.normal(size=(20, 14)).astype(np.float32):
        _close(network(x), _run(session, x.reshape(1, 2, 7)).ravel(), rtol=1e-5, atol=1e-6)


def _simple(nodes, inits=(), inputs=None):
    w = np.ones((3, 3))
    return _model(nodes, inputs or [_tensor("x", ["N", 3])], [_tensor("y", ["N", 3])], [("w", w), *inits])


def test_unsupported_op_is_named(tmp_path):
    path = _save(_simple([_node("Gemm", ["x", "w"], "g"), _node("LeakyRelu", ["g"], "y", name="leaky")]), tmp_path / "leaky.onnx")
    with pytest.raises(NetworkFormatError) as error:
        pv.load_network(path)
    message = str(error.value)
    for part in ["leaky.onnx", "'leaky'", "'LeakyRelu'", "Gemm", "MatMul", "Sigmoid", "Conv"]:
        assert part in message, message
    unnamed = _simple([helper.make_node("Softmax", ["x"], ["y"])])
    with pytest.raises(NetworkFormatError, match=r"node #0 \(unnamed, output 'y'\).*'Softmax'"):
        pv.load_network(_save(unnamed, tmp_path / "softmax.onnx"))


def test_branching_graph_is_rejected(tmp_path):
    nodes = [
        _node("Relu", ["x"], "r"),
        _node("Gemm", ["r", "w"], "left"),
        _node("Gemm", ["r", "w"], "right"),
        _node("Add", ["left", "right"], "y"),
    ]
    pattern = (
        r"branch\.onnx: node 'left' \(Gemm\): the graph branches: tensor 'r' is read by node 'left', node 'right'; "
        r".*Relu"
    )
    with pytest.raises(NetworkFormatError, match=pattern):
        pv.load_network(_save(_simple(nodes), tmp_path / "branch.onnx"))


def test_second_input_and_non_affine_division_are_rejected(tmp_path):
    two_inputs = _simple([_node("Add", ["x", "z"], "y")], inputs=[_tensor("x", ["N", 3]), _tensor("z", ["N", 3])])
    with pytest.raises(NetworkFormatError, match=r"2 non-constant inputs \['x', 'z'\]"):
        pv.load_network(_save(two_inputs, tmp_path / "two.onnx"))
    divide = _simple([_node("Div", ["w", "x"], "y", name="reciprocal")])
    with pytest.raises(NetworkFormatError, match=r"'reciprocal' \(Div\).*not affine"):
        pv.load_network(_save(divide, tmp_path / "div.onnx"))


def test_nan_weight_in_onnx_is_located(tmp_path):
    weight = np.ones((3, 3))
    weight[1, 2] = np.nan
    model = _model(
        [_node("Gemm", ["x", "fc.weight"], "y", name="fc")], [_tensor("x", ["N", 3])], [_tensor("y", ["N", 3])],
        [("fc.weight", weight)],
    )  # fmt: skip
    with pytest.raises(NetworkFormatError, match=r"nan\.onnx.*'fc\.weight'.*node 'fc'.*nan at index \(1, 2\)"):
        pv.load_network(_save(model, tmp_path / "nan.onnx"))
    nodes = [
        helper.make_node("Constant", [], ["shift"], value_floats=[0.0, np.inf, 0.0]),
        _node("Add", ["x", "shift"], "y"),
    ]
    with pytest.raises(NetworkFormatError, match=r"constant tensor 'shift' \(read by node 'y'\).*inf at index \(1,\)"):
        pv.load_network(_save(_simple(nodes), tmp_path / "inf.onnx"))


def test_corrupt_and_missing_files(tmp_path):
    (tmp_path / "garbage.onnx").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(NetworkFormatError, match="garbage.onnx.*not a readable ONNX file"):
        pv.load_network(tmp_path / "garbage.onnx")
    with pytest.raises(MissingFileError, match="not found"):
        pv.load_network(tmp_path / "absent.onnx")
    with pytest.raises(FileNotFoundError):
        pv.load_network(tmp_path / "absent.yml")
    (tmp_path / "net.h5").write_bytes(b"")
    with pytest.raises(NetworkFormatError, match=r"unknown network file type '\.h5'"):
        pv.load_network(tmp_path / "net.h5")
    (tmp_path / "broken.yml").write_text("weights: {1: [[1, 2]\n")
    with pytest.raises(NetworkFormatError, match="broken.yml.*not a readable YAML file"):
        pv.load_network(tmp_path / "broken.yml")


# ------------------------------------------------------------------------------- generated YAML fixtures


def _verisig_document(rng, widths, activations):
    return {
        "activations": {i + 1: a for i, a in enumerate(activations)},
        "offsets": {i + 1: rng.normal(size=n).tolist() for i, n in enumerate(widths[1:])},
        "weights": {i + 1: rng.normal(size=(n, m)).tolist() for i, (m, n) in enumerate(zip(widths, widths[1:]))},
    }


def _write_yaml(document, path: Path) -> Path:
    path.write_text(yaml.safe_dump(document))
    return path


def test_yaml_fixture_layers_and_layout(tmp_path):
    rng = np.random.default_rng(7)
    document = _verisig_document(rng, [3, 5, 4, 2], ["Relu", "Sigmoid", "Linear"])
    document["name"] = "extra top-level keys are ignored"
    document["weights"] = {str(k): v for k, v in document["weights"].items()}  # digit-string layer keys
    network = pv.load_network(_write_yaml(document, tmp_path / "small.yaml"))
    assert [layer.activation for layer in network.layers] == ["relu", "sigmoid", "identity"]
    x = rng.normal(size=(10, 3))
    document["weights"] = {int(k): v for k, v in document["weights"].items()}
    _close(network(x), _numpy_forward(document, x))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["weights"][2][1].__setitem__(3, float("nan")), r"layer 2 weights.*nan at row 2, column 4"),
        (lambda d: d["offsets"][1].__setitem__(0, float("inf")), r"layer 1 offsets.*inf at entry 1"),
        (
            lambda d: d["weights"].__setitem__(2, [row[:4] for row in d["weights"][2]]),
            r"layer 2 weights have 4 columns but layer 1 has 5",
        ),
        (lambda d: d["offsets"][2].pop(), r"layer 2 offsets have 3 entries but its weights have 4 rows"),
        (lambda d: d["weights"][1][2].pop(), r"layer 1 weights: row 3 has 2 entries but row 1 has 3"),
        (lambda d: d["weights"][1][0].__setitem__(0, "x"), r"layer 1 weights contain a non-numeric entry"),
        (lambda d: d["activations"].__setitem__(1, "tanh"), r"layer 1 activation 'tanh'.*write 'Tanh'"),
        # Verisig reads unknown names as linear: a silent identity would verify another network
        (
            lambda d: d["activations"].__setitem__(2, "Swish"),
            r"layer 2 activation 'Swish' is not supported: the format names 'Sigmoid', 'Tanh', 'Relu', 'Linear'",
        ),
        (lambda d: d["activations"].__setitem__(3, None), r"layer 3 activation None is not supported"),
        (lambda d: d["weights"].__setitem__(4, d["weights"].pop(3)), r"'weights' must number its layers 1, 2, \.\.\., 3"),
        (lambda d: d["offsets"].pop(3), r"weights, offsets and activations must list the same layers"),
        (lambda d: d.pop("activations"), r"not a Verisig network file"),
    ],
)  # fmt: skip
def test_bad_yaml_is_located(tmp_path, edit, message):
    document = _verisig_document(np.random.default_rng(8), [3, 5, 4, 2], ["Tanh", "Tanh", "Linear"])
    edit(document)
    path = _write_yaml(document, tmp_path / "bad.yml")
    with pytest.raises(NetworkFormatError, match="bad.yml: " + message):
        pv.load_network(path)


# ------------------------------------------------------------------------------------ the Network object


def _mixed(rng) -> pv.Network:
    widths = [3, 6, 5, 4, 2]
    layers = [
        Layer(rng.normal(size=(n, m)), rng.normal(size=n), activation)
        for m, n, activation in zip(widths, widths[1:], ["relu", "identity", "sigmoid", "tanh"])
    ]
    return pv.Network(layers, scale=[2.0, -3.0], offset=0.5, name="mixed")


def test_call_accepts_samples_and_batches():
    network = _mixed(np.random.default_rng(9))
    x = np.random.default_rng(10).normal(size=(7, 3))
    assert network(x).shape == (7, 2) and network(x[0]).shape == (2,)
    _close(network(x[0]), network(x)[0], rtol=1e-12)
    np.testing.assert_array_equal(network(x.tolist()), network(x))
    for bad in [np.zeros(4), np.zeros((7, 4)), np.zeros((2, 7, 3)), np.zeros(())]:
        with pytest.raises(InputError, match=r"'mixed' takes 3 inputs per sample"):
            network(bad)
    with pytest.raises(InputError, match="not numeric"):
        network([["a", "b", "c"]])


def test_output_map_and_sigmoid_tails():
    rng = np.random.default_rng(11)
    network = _mixed(rng)
    x = rng.normal(size=(5, 3))
    h = x
    for layer in network.layers:
        h = {"relu": lambda z: np.maximum(z, 0), "sigmoid": expit, "tanh": np.tanh, "identity": lambda z: z}[layer.activation](
            h @ layer.weight.T + layer.bias
        )
    _close(network(x), h * [2.0, -3.0] + 0.5)
    sigmoid = pv.Network([(np.eye(1), np.zeros(1), "sigmoid")])
    z = np.array([[-800.0], [-30.0], [0.0], [30.0], [800.0]])
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        _close(sigmoid(z), expit(z), rtol=1e-15, atol=0)


def test_network_is_an_immutable_copy():
    weight = np.ones((2, 3))
    network = pv.Network([Layer(weight, [0.0, 1.0], "Tanh")])
    weight[0, 0] = 5.0
    assert network.layers[0].weight[0, 0] == 1.0 and network.layers[0].activation == "tanh"
    assert not network.layers[0].weight.flags.writeable and network.layers[0].weight.dtype == np.float64
    assert (network.n_in, network.n_out, network.name, network.source) == (3, 2, "network", None)
    assert network.scale is None and network.offset is None


@pytest.mark.parametrize(
    ("layers", "options", "message"),
    [
        ([(np.ones((2, 3)), [0, 0], "tanh"), (np.ones((1, 2)), [np.nan], "relu")], {}, r"layer 2 bias .* nan"),
        ([(np.ones((2, 3)), [0, 0], "tanh"), (np.ones((1, 4)), [0], "relu")], {}, r"layer 2: weight has 4 columns"),
        ([(np.ones((2, 3)), [0, 0, 0], "tanh")], {}, r"layer 1: bias has 3 entries but weight has 2 rows"),
        ([(np.ones((2, 3)), [0, 0], "softplus")], {}, r"layer 1: unknown activation 'softplus'"),
        ([(np.ones(3), [0], "tanh")], {}, r"layer 1 weight must be a non-empty 2-D array"),
        ([(np.ones((2, 3)), [0, 0], "tanh")], {"scale": [1, 2, 3]}, r"output scale must be a number or have one entry"),
        ([(np.ones((2, 3)), [0, 0], "tanh")], {"offset": [0, np.inf]}, r"output offset has the non-finite value inf"),
        ([], {}, r"at least one layer"),
        ([(np.ones((2, 3)),)], {}, r"layer 1 must be a Layer or a \(weight, bias, activation\) tuple"),
    ],
)  # fmt: skip
def test_network_validation(layers, options, message):
    with pytest.raises(NetworkFormatError, match=message):
        pv.Network(layers, **options)


def test_fixture_round_trips(tmp_path):
    rng = np.random.default_rng(12)
    network = _mixed(rng)
    x = rng.normal(size=(20, 3))
    pv.save_network(network, tmp_path / "mixed.onnx")
    _close(_run(_session(tmp_path / "mixed.onnx"), x), network(x), rtol=1e-12)
    again = pv.load_network(tmp_path / "mixed.onnx")
    # reading folds the linear layer into the next one; the output map stays an output map
    assert [layer.activation for layer in again.layers] == ["relu", "sigmoid", "tanh"]
    np.testing.assert_array_equal(again.scale, [2.0, -3.0])
    np.testing.assert_array_equal(again.offset, [0.5, 0.5])
    _close(again(x), network(x), rtol=1e-12)

    pv.save_network(network, tmp_path / "mixed.yml")
    document = _read_yaml(tmp_path / "mixed.yml")
    assert document["activations"] == {1: "Relu", 2: "Linear", 3: "Sigmoid", 4: "Tanh", 5: "Linear"}
    assert document["weights"][5] == [[2.0, 0.0], [0.0, -3.0]] and document["offsets"][5] == [0.5, 0.5]
    _close(pv.load_network(tmp_path / "mixed.yml")(x), network(x), rtol=1e-14)
    _close(_numpy_forward(document, x), network(x), rtol=1e-14)


def test_chain_folds_output_maps():
    rng = np.random.default_rng(13)
    first = _mixed(rng)
    second = pv.Network([(rng.normal(size=(4, 2)), rng.normal(size=4), "tanh")], scale=3.0, name="second")
    composed = pv.chain(first, second)
    assert len(composed.layers) == 5 and composed.name == "mixed -> second"
    np.testing.assert_array_equal(composed.scale, [3.0] * 4)
    assert composed.offset is None
    x = rng.normal(size=(9, 3))
    _close(composed(x), second(first(x)), rtol=1e-12)
    assert pv.chain(first)(x).tolist() == first(x).tolist()
    with pytest.raises(InputError, match=r"cannot chain 'second' \(4 outputs\) into 'mixed' \(3 inputs\)"):
        pv.chain(second, first)
    with pytest.raises(InputError, match="at least one network"):
        pv.chain()
