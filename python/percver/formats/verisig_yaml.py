"""Verisig network files (``.yml``): read into a :class:`~percver.networks.Network` and write back.

The format: top-level mappings ``weights``, ``offsets`` and ``activations``, each keyed by the
1-based layer index; ``weights[l]`` is a list of rows, row i holding the incoming weights of neuron i
(n_out x n_in); activations ``Sigmoid``, ``Tanh``, ``Relu`` or ``Linear`` (Verisig reads any other
name as linear; here it is an error). Other top-level keys are ignored, as Verisig does. Errors name the file, the layer and the field as written in the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from percver.errors import NetworkFormatError
from percver.networks import Layer, Network

# The C loader/dumper is ~4x faster on the 1.7 MB Mountain Car generator; some PyYAML builds lack it.
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_Dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

_SECTIONS = ("weights", "offsets", "activations")
_FROM_VERISIG = {"Sigmoid": "sigmoid", "Tanh": "tanh", "Relu": "relu", "Linear": "identity"}
_TO_VERISIG = {"sigmoid": "Sigmoid", "tanh": "Tanh", "relu": "Relu", "identity": "Linear"}


def read_verisig_yaml(path) -> Network:
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as file:
            document = yaml.load(file, Loader=_Loader)
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise NetworkFormatError(f"{path}: not a readable YAML file ({error})") from None
    if not isinstance(document, dict) or any(key not in document for key in _SECTIONS):
        keys = ", ".join(map(str, document)) if isinstance(document, dict) else type(document).__name__
        raise NetworkFormatError(
            f"{path}: not a Verisig network file: it needs top-level 'weights', 'offsets' and 'activations' (found: {keys})"
        )
    sections = {key: _by_layer(document[key], key, path) for key in _SECTIONS}
    counts = {key: len(section) for key, section in sections.items()}
    if len(set(counts.values())) != 1:
        raise NetworkFormatError(f"{path}: weights, offsets and activations must list the same layers, found {counts}")

    layers = []
    for index in range(1, counts["weights"] + 1):
        weight = _weights(sections["weights"][index], index, path)
        bias = _offsets(sections["offsets"][index], index, path)
        if bias.shape[0] != weight.shape[0]:
            raise NetworkFormatError(
                f"{path}: layer {index} offsets have {bias.shape[0]} entries but its weights have {weight.shape[0]} rows"
            )
        if layers and weight.shape[1] != layers[-1].n_out:
            raise NetworkFormatError(
                f"{path}: layer {index} weights have {weight.shape[1]} columns but layer {index - 1} has {layers[-1].n_out} neurons"
            )
        layers.append(Layer(weight, bias, _activation(sections["activations"][index], index, path)))
    return Network(layers, name=path.stem, source=path)


def _by_layer(section, key: str, path: Path) -> dict:
    """The section as {1: ..., 2: ..., L: ...}; layer keys may be integers or digit strings."""
    if not isinstance(section, dict) or not section:
        raise NetworkFormatError(f"{path}: '{key}' must be a non-empty mapping from the layer number (1, 2, ...) to the layer's {key}")
    try:
        by_layer = {int(number): value for number, value in section.items()}
    except (TypeError, ValueError):
        raise NetworkFormatError(f"{path}: '{key}' has a key that is not a layer number: {list(section)}") from None
    if sorted(by_layer) != list(range(1, len(by_layer) + 1)):
        raise NetworkFormatError(f"{path}: '{key}' must number its layers 1, 2, ..., {len(by_layer)}; found {sorted(by_layer)}")
    return by_layer


def _numeric(value, label: str, path: Path) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise NetworkFormatError(f"{path}: {label} contain a non-numeric entry ({error})") from None
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        axes = ("row", "column") if array.ndim == 2 else ("entry",)
        place = ", ".join(f"{axis} {i + 1}" for axis, i in zip(axes, bad[0]))
        raise NetworkFormatError(f"{path}: {label} contain the non-finite value {array[tuple(bad[0])]} at {place}")
    return array


def _weights(rows, index: int, path: Path) -> np.ndarray:
    label = f"layer {index} weights"
    if not isinstance(rows, list) or not rows or not all(isinstance(row, list) and row for row in rows):
        raise NetworkFormatError(f"{path}: {label} must be a non-empty list of rows (row i: the incoming weights of neuron i)")
    for number, row in enumerate(rows, start=1):
        if len(row) != len(rows[0]):
            raise NetworkFormatError(f"{path}: {label}: row {number} has {len(row)} entries but row 1 has {len(rows[0])}")
    return _numeric(rows, label, path)


def _offsets(values, index: int, path: Path) -> np.ndarray:
    label = f"layer {index} offsets"
    if not isinstance(values, list) or not values or any(isinstance(value, (list, dict)) for value in values):
        raise NetworkFormatError(f"{path}: {label} must be a non-empty list of numbers (one per neuron)")
    return _numeric(values, label, path)


def _activation(value, index: int, path: Path) -> str:
    if isinstance(value, str) and value in _FROM_VERISIG:
        return _FROM_VERISIG[value]
    # Verisig itself reads any other name as linear, so a typo or an activation it lacks (Swish, ELU)
    # would verify a different network than the one trained; only 'Linear' means linear here.
    supported = ", ".join(repr(name) for name in _FROM_VERISIG)
    hint = f"; write {value.capitalize()!r}" if isinstance(value, str) and value.capitalize() in _FROM_VERISIG else ""
    raise NetworkFormatError(
        f"{path}: layer {index} activation {value!r} is not supported{hint}: the format names {supported} "
        "(exact case); percver cannot bound other activations"
    )


def write_verisig_yaml(network: Network, path) -> None:
    layers = list(network.layers)
    if network.scale is not None or network.offset is not None:
        n = network.n_out
        scale = network.scale if network.scale is not None else np.ones(n)
        offset = network.offset if network.offset is not None else np.zeros(n)
        layers.append(Layer(np.diag(scale), offset, "identity"))
    document = {
        "activations": {i: _TO_VERISIG[layer.uniform_activation("the Verisig format")] for i, layer in enumerate(layers, start=1)},
        "offsets": {i: layer.bias.tolist() for i, layer in enumerate(layers, start=1)},
        "weights": {i: layer.weight.tolist() for i, layer in enumerate(layers, start=1)},
    }
    # PyYAML writes floats with repr(), so reading the file back gives the same float64 values.
    with open(path, "w", encoding="utf-8") as file:
        yaml.dump(document, file, Dumper=_Dumper, default_flow_style=None, sort_keys=False)
