"""``.nnet`` and ``.mat`` networks: files written here and ARCH-COMP's (../shared), each compared
with a numpy forward pass of weights read independently (a flat number scan of the .nnet text,
scipy.io.loadmat's arrays), and malformed files refused with the file and the field."""

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

import percver as pv
from percver.formats.nnet import NNetNormalizationWarning

ARCHCOMP = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "archcomp2024" / "models"
ACT = {"relu": lambda z: np.maximum(z, 0), "tanh": np.tanh, "sigmoid": lambda z: 1 / (1 + np.exp(-z)), "identity": lambda z: z}
MAT_ACT = {
    "relu": "relu",
    "poslin": "relu",
    "tanh": "tanh",
    "tansig": "tanh",
    "sigmoid": "sigmoid",
    "logsig": "sigmoid",
    "linear": "identity",
    "purelin": "identity",
}


def forward(layers, x):
    for w, b, a in layers:
        x = ACT[a](x @ w.T + b)
    return x


def nnet_text(layers, normalization="0\n0\n0\n0\n0\n"):
    sizes = [layers[0][0].shape[1]] + [w.shape[0] for w, _, _ in layers]
    out = [
        "// written by the test",
        f"{len(layers)},{sizes[0]},{sizes[-1]},{max(sizes)},",
        ",".join(map(str, sizes)) + ",",
        normalization.rstrip("\n"),
    ]
    for w, b, _ in layers:
        out += [",".join(repr(float(v)) for v in row) + "," for row in w] + [f"{float(v)!r}," for v in b]
    return "\n".join(out) + "\n"


def nnet_layers(path):
    """The layers of a .nnet file from a flat scan of its numbers (independent of percver's reader)."""
    text = "\n".join(l for l in Path(path).read_text().splitlines() if not l.lstrip().startswith("//"))
    lines = [[float(t) for t in re.split(r"[,\s]+", l.strip()) if t] for l in text.splitlines() if l.strip()]
    count, n_in = int(lines[0][0]), int(lines[0][1])
    sizes = [int(v) for v in lines[1][: count + 1]]
    flat = [v for l in lines[7:] for v in l]  # header, sizes, flag, min, max, mean, range
    layers, at = [], 0
    for k in range(count):
        n = sizes[k] * sizes[k + 1]
        w = np.array(flat[at : at + n]).reshape(sizes[k + 1], sizes[k])
        b = np.array(flat[at + n : at + n + sizes[k + 1]])
        at += n + sizes[k + 1]
        layers.append((w, b, "relu" if k < count - 1 else "identity"))
    assert at == len(flat) and sizes[0] == n_in
    return layers


def mat_layers(path):
    doc = scipy.io.loadmat(str(path))
    acts = doc["act_fcns"] if "act_fcns" in doc else doc["act"]
    names = [str(np.asarray(a).ravel()[0] if isinstance(a, np.ndarray) else a).strip().lower() for a in acts.ravel()]
    return [(np.asarray(w, float), np.asarray(b, float).ravel(), MAT_ACT[a]) for w, b, a in zip(doc["W"].ravel(), doc["b"].ravel(), names)]


def random_layers(seed, sizes, acts):
    rng = np.random.default_rng(seed)
    return [(rng.normal(size=(m, n)), rng.normal(size=m), a) for n, m, a in zip(sizes, sizes[1:], acts)]


def assert_same(net, layers, seed=0):
    x = np.random.default_rng(seed).uniform(-2, 2, size=(500, layers[0][0].shape[1]))
    np.testing.assert_allclose(net(x), forward(layers, x), rtol=1e-12, atol=1e-12)
    assert [l.activation for l in net.layers] == [a for _, _, a in layers]


def test_nnet_written_here(tmp_path):
    layers = random_layers(1, [3, 7, 5, 2], ["relu", "relu", "identity"])
    (tmp_path / "n.nnet").write_text(nnet_text(layers))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        net = pv.load_network(tmp_path / "n.nnet")
    assert_same(net, layers)
    assert_same(net, nnet_layers(tmp_path / "n.nnet"))


def cell(arrays):
    """A MATLAB cell array (1 x n) of the arrays, as scipy.io.savemat writes one."""
    out = np.empty((1, len(arrays)), dtype=object)
    for i, a in enumerate(arrays):
        out[0, i] = np.asarray(a)
    return out


def save_mat(path, layers, key="act_fcns", **extra):
    names = {"relu": "relu", "tanh": "tansig", "sigmoid": "logsig", "identity": "purelin"}
    scipy.io.savemat(
        str(path),
        {
            "W": cell([w for w, _, _ in layers]),
            "b": cell([b.reshape(-1, 1) for _, b, _ in layers]),
            key: np.array([names[a] for _, _, a in layers], dtype=object),
            **extra,
        },
    )


def test_mat_written_here(tmp_path):
    layers = random_layers(2, [4, 6, 6, 2], ["tanh", "sigmoid", "identity"])
    save_mat(tmp_path / "m.mat", layers)
    net = pv.load_network(tmp_path / "m.mat")
    assert_same(net, layers)
    assert_same(net, mat_layers(tmp_path / "m.mat"))
    save_mat(tmp_path / "act.mat", layers, key="act")
    assert_same(pv.load_network(tmp_path / "act.mat"), layers)


ARCHCOMP_FILES = sorted(ARCHCOMP.glob("*/*.nnet")) + sorted(ARCHCOMP.glob("*/*.mat"))


@pytest.mark.skipif(not ARCHCOMP_FILES, reason="../shared/data/archcomp2024 is not beside the repo")
def test_archcomp_networks_match_their_weights():
    for path in ARCHCOMP_FILES:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            net = pv.load_network(path)
        layers = nnet_layers(path) if path.suffix == ".nnet" else mat_layers(path)
        assert_same(net, layers)
        # VerticalCAS's files carry a normalization, which is not applied (as JuliaReach).
        assert bool(caught) == ("VertCAS" in path.name), (path, [str(w.message) for w in caught])
        if caught:
            assert issubclass(caught[0].category, NNetNormalizationWarning) and "not applied" in str(caught[0].message)


BAD_NNET = {
    "truncated": (lambda t: t[: t.index("\n", len(t) // 2)], "the file ends before layer"),
    "not a number": (lambda t: t.replace("2,3,", "2,x,", 1), "'x' is not a number"),
    "sizes": (lambda t: t.replace("\n3,4,2,\n", "\n3,5,2,\n", 1), "expected 3 numbers, found"),
    "header": (lambda t: t.replace("// written by the test\n2,3,2,", "// written by the test\n2,4,2,", 1), "the header says 4 inputs"),
    "extra": (lambda t: t + "1.0,\n", "numbers after the last layer's biases"),
    "layer count": (
        lambda t: t.replace("// written by the test\n2,", "// written by the test\n0.5,", 1),
        "layer count must be a positive integer",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_NNET))
def test_malformed_nnet_is_refused(case, tmp_path):
    edit, message = BAD_NNET[case]
    text = nnet_text(random_layers(3, [3, 4, 2], ["relu", "identity"]))
    (tmp_path / "bad.nnet").write_text(edit(text))
    with pytest.raises(pv.NetworkFormatError, match=re.escape(message)) as error:
        pv.load_network(tmp_path / "bad.nnet")
    assert str(tmp_path / "bad.nnet") in str(error.value)


def test_malformed_mat_is_refused(tmp_path):
    layers = random_layers(4, [3, 4, 2], ["relu", "identity"])
    scipy.io.savemat(str(tmp_path / "keys.mat"), {"weights": np.eye(2)})
    with pytest.raises(pv.NetworkFormatError, match="needs the variables W, b and one of act_fcns.*found weights"):
        pv.load_network(tmp_path / "keys.mat")
    save_mat(tmp_path / "act.mat", layers)
    doc = scipy.io.loadmat(str(tmp_path / "act.mat"))
    scipy.io.savemat(str(tmp_path / "act.mat"), {"W": doc["W"], "b": doc["b"], "act_fcns": np.array(["relu", "softmax"], dtype=object)})
    with pytest.raises(pv.NetworkFormatError, match=r"act_fcns\{2\} is 'softmax'"):
        pv.load_network(tmp_path / "act.mat")
    wrong = [(layers[0][0], layers[0][1], "relu"), (np.ones((2, 5)), layers[1][1], "identity")]
    save_mat(tmp_path / "dims.mat", wrong)
    with pytest.raises(pv.NetworkFormatError, match=r"W\{2\} has 5 columns but layer 1 has 4 outputs"):
        pv.load_network(tmp_path / "dims.mat")
    save_mat(tmp_path / "bias.mat", [(layers[0][0], np.ones(3), "relu"), layers[1]])
    with pytest.raises(pv.NetworkFormatError, match=r"b\{1\} has shape \(3, 1\) but W\{1\} has 4 rows"):
        pv.load_network(tmp_path / "bias.mat")
    (tmp_path / "text.mat").write_text("not a mat file at all")
    with pytest.raises(pv.NetworkFormatError, match="not a readable MATLAB .mat file"):
        pv.load_network(tmp_path / "text.mat")
