"""Shared networks of ../shared/data and their float references, for the network bound tests."""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime
from onnx import TensorProto, numpy_helper

import percver as pv
from percver.errors import NetworkFormatError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MC = DATA / "mountain_car" / "networks"
SAMPLES = 10_000


def shared_paths() -> list[Path]:
    assert DATA.is_dir(), f"shared data missing at {DATA}"
    paths = [
        *sorted(DATA.glob("**/*.onnx")),
        *sorted(MC.glob("*.yml")),
        DATA / "mountain_car" / "state_based" / "sig16x16.yml",
        *sorted((DATA / "f1tenth" / "controllers").glob("*.yml")),
        *sorted((DATA / "f1tenth" / "noise_models").glob("*.yml")),
        *sorted(DATA.glob("verisig2_suite/*/*.yml")),
    ]
    return paths


def load_shared() -> dict:
    """{path: network} for every shared network whose inputs are not images (those are chained in
    test_network_bounds.py)."""
    networks = {}
    for path in shared_paths():
        try:
            network = pv.load_network(path)
        except NetworkFormatError:
            continue  # Verisig run configs, not networks (test_networks.py counts them)
        if network.n_in < 600:
            networks[path] = network
    assert len(networks) >= 50, sorted(p.name for p in networks)
    return networks


def reference(path: Path, network: pv.Network, x: np.ndarray) -> np.ndarray:
    """onnxruntime on the file's graph converted to float64 (batch made dynamic), else numpy."""
    if path.suffix != ".onnx":
        return network(x)
    model = onnx.load(str(path))
    for tensor in model.graph.initializer:
        if tensor.data_type == TensorProto.FLOAT:
            tensor.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(tensor).astype(np.float64), tensor.name))
    for value in [*model.graph.input, *model.graph.output]:
        value.type.tensor_type.elem_type = TensorProto.DOUBLE
        value.type.tensor_type.shape.dim[0].dim_param = "batch"
    del model.graph.value_info[:]
    session = onnxruntime.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run(None, {session.get_inputs()[0].name: x})[0].reshape(len(x), -1)


def samples(rng, box, count=SAMPLES) -> np.ndarray:
    lo, hi = np.array(box).T
    x = rng.uniform(lo, hi, size=(count, len(box)))
    x[0], x[1] = lo, hi
    return x


def assert_inside(bounds, y, label):
    """Float references are within 1e-12 (relative) of the exact values that the bounds enclose."""
    lo, hi = np.array(bounds).T
    slack = 1e-12 * (1 + np.abs(y))
    outside = (y < lo - slack) | (y > hi + slack)
    assert not outside.any(), f"{label}: {outside.sum()} samples outside, first at output {np.argwhere(outside)[0]}"
