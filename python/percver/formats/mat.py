"""MATLAB ``.mat`` networks in the layout NNV, CORA and JuliaReach share (ARCH-COMP AINNCS):
cell arrays ``W`` (layer i: n_out x n_in) and ``b`` (n_out values), and the activations in
``act_fcns`` (or ``act``), one name per layer: relu, tanh/tansig, sigmoid/logsig,
linear/purelin. Read with ``scipy.io.loadmat`` (MATLAB files up to version 7; 7.3 files are HDF5
and are refused with how to convert them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from percver.errors import NetworkFormatError
from percver.networks import Layer, Network

ACTIVATIONS = {
    "relu": "relu",
    "poslin": "relu",
    "tanh": "tanh",
    "tansig": "tanh",
    "sigmoid": "sigmoid",
    "logsig": "sigmoid",
    "linear": "identity",
    "purelin": "identity",
    "identity": "identity",
    "id": "identity",
    "none": "identity",
}
ACTIVATION_KEYS = ("act_fcns", "act", "activation_fcns", "activations")


def read_mat(path) -> Network:
    import scipy.io

    path = Path(path)
    try:
        doc = scipy.io.loadmat(str(path))
    except NotImplementedError:
        raise NetworkFormatError(f"{path}: a MATLAB 7.3 (HDF5) file; save it again with save(..., '-v7') to read it") from None
    except (ValueError, TypeError, OSError, IndexError, KeyError, scipy.io.matlab.MatReadError) as error:
        raise NetworkFormatError(f"{path}: not a readable MATLAB .mat file ({error})") from None
    keys = sorted(k for k in doc if not k.startswith("__"))
    act_key = next((k for k in ACTIVATION_KEYS if k in doc), None)
    if "W" not in doc or "b" not in doc or act_key is None:
        raise NetworkFormatError(
            f"{path}: a network needs the variables W, b and one of {', '.join(ACTIVATION_KEYS)} "
            f"(NNV/CORA/JuliaReach layout); found {', '.join(keys) or 'none'}"
        )
    weights, biases, acts = _cells(doc["W"]), _cells(doc["b"]), _names(doc[act_key], act_key, path)
    if not (len(weights) == len(biases) == len(acts)):
        raise NetworkFormatError(f"{path}: W has {len(weights)} layers, b {len(biases)} and {act_key} {len(acts)}; they must agree")
    layers = []
    for i, (w, b, a) in enumerate(zip(weights, biases, acts), start=1):
        w = _numeric(w, f"W{{{i}}}", path)
        b = _numeric(b, f"b{{{i}}}", path)
        if w.ndim != 2:
            raise NetworkFormatError(f"{path}: W{{{i}}} must be a matrix (n_out x n_in), got shape {w.shape}")
        if b.size != w.shape[0] or (b.ndim == 2 and 1 not in b.shape) or b.ndim > 2:
            raise NetworkFormatError(f"{path}: b{{{i}}} has shape {b.shape} but W{{{i}}} has {w.shape[0]} rows: one bias per row")
        if layers and w.shape[1] != layers[-1].n_out:
            raise NetworkFormatError(f"{path}: W{{{i}}} has {w.shape[1]} columns but layer {i - 1} has {layers[-1].n_out} outputs")
        if a not in ACTIVATIONS:
            raise NetworkFormatError(f"{path}: {act_key}{{{i}}} is {a!r}; known: {', '.join(sorted(ACTIVATIONS))}")
        layers.append(Layer(w, b.reshape(-1), ACTIVATIONS[a]))
    return Network(layers, name=path.stem, source=path)


def _cells(value) -> list:
    """A MATLAB cell array (object array of any shape) as a list; a plain matrix is one layer."""
    value = np.asarray(value)
    return list(value.ravel()) if value.dtype == object else [value]


def _names(value, key: str, path: Path) -> list:
    """Activation names from a char matrix (padded rows) or a cell array of strings."""
    out = []
    for item in np.asarray(value).ravel():
        while isinstance(item, np.ndarray) and item.dtype == object and item.size == 1:
            item = item.ravel()[0]
        if isinstance(item, np.ndarray) and item.dtype.kind == "U" and item.size == 1:
            item = item.ravel()[0]
        if not isinstance(item, str):
            raise NetworkFormatError(f"{path}: {key} must hold activation names, got {item!r}")
        out.append(item.strip().lower())
    return out


def _numeric(value, label: str, path: Path) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise NetworkFormatError(f"{path}: {label} is not numeric") from None
    if not np.isfinite(array).all():
        raise NetworkFormatError(f"{path}: {label} has a non-finite entry")
    return array
