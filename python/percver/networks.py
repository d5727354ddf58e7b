"""Feed-forward networks: the one representation shared by file formats, float evaluation and the Rust core.

A :class:`Network` is a sequence of dense layers ``h <- act(W h + b)`` followed by an optional
elementwise output map ``y <- scale * h + offset``. Every reader (ONNX, Verisig ``.yml``) folds its
file into this form, so float evaluation here and set evaluation in ``percver._core`` see exactly the
same weights. Arrays are float64, C-contiguous and read-only: a network is a value, safe to share.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from percver.errors import InputError, MissingFileError, NetworkFormatError

ACTIVATIONS = ("sigmoid", "tanh", "relu", "identity")


def _sigmoid(z: np.ndarray) -> np.ndarray:
    # exp of a non-positive argument only: no overflow, and full relative accuracy on both tails
    e = np.exp(-np.abs(z))
    return np.where(z >= 0, 1.0, e) / (1.0 + e)


ACTIVATION_FUNCTIONS = {
    "sigmoid": _sigmoid,
    "tanh": np.tanh,
    "relu": lambda z: np.maximum(z, 0.0),
    "identity": lambda z: z,
}


@dataclass(frozen=True, eq=False)
class Layer:
    """One dense layer ``activation(weight @ h + bias)``; ``weight`` has shape (n_out, n_in)."""

    weight: np.ndarray
    bias: np.ndarray
    activation: str = "identity"

    @property
    def n_in(self) -> int:
        return self.weight.shape[1]

    @property
    def n_out(self) -> int:
        return self.weight.shape[0]


def _finite_array(value, ndim: int, label: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64, order="C")  # a copy: the network must not alias caller data
    except (TypeError, ValueError) as error:
        raise NetworkFormatError(f"{label} is not a numeric array ({error})") from None
    if array.ndim != ndim or array.size == 0:
        raise NetworkFormatError(f"{label} must be a non-empty {ndim}-D array, got shape {array.shape}")
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        index = tuple(int(i) for i in bad[0])
        raise NetworkFormatError(
            f"{label} has the non-finite value {array[index]} at index {index} ({len(bad)} non-finite in all)"
        )
    array.setflags(write=False)
    return array


def _checked_layer(layer, index: int, where: str, n_prev: int | None) -> Layer:
    label = f"{where}layer {index}"
    if not isinstance(layer, Layer):
        try:
            layer = Layer(*layer)
        except TypeError:
            raise NetworkFormatError(f"{label} must be a Layer or a (weight, bias, activation) tuple") from None
    activation = layer.activation.lower() if isinstance(layer.activation, str) else layer.activation
    if activation not in ACTIVATIONS:
        raise NetworkFormatError(f"{label}: unknown activation {layer.activation!r}; expected one of {ACTIVATIONS}")
    weight = _finite_array(layer.weight, 2, f"{label} weight")
    bias = _finite_array(layer.bias, 1, f"{label} bias")
    if bias.shape[0] != weight.shape[0]:
        raise NetworkFormatError(
            f"{label}: bias has {bias.shape[0]} entries but weight has {weight.shape[0]} rows (weight is n_out x n_in)"
        )
    if n_prev is not None and weight.shape[1] != n_prev:
        raise NetworkFormatError(
            f"{label}: weight has {weight.shape[1]} columns but layer {index - 1} has {n_prev} outputs"
        )
    return Layer(weight, bias, activation)


def _checked_output_map(value, field: str, n_out: int, where: str) -> np.ndarray | None:
    if value is None:
        return None
    label = f"{where}output {field}"
    try:
        value = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_out,))
    except (TypeError, ValueError) as error:
        raise NetworkFormatError(f"{label} must be a number or have one entry per output ({n_out}): {error}") from None
    return _finite_array(value, 1, label)


class Network:
    """A feed-forward network of dense layers with an optional output map ``scale * h + offset``.

    ``layers`` holds :class:`Layer` objects or ``(weight, bias, activation)`` tuples; activations are
    ``"sigmoid"``, ``"tanh"``, ``"relu"`` or ``"identity"``. ``scale`` and ``offset`` are numbers or
    one value per output (``None``: not applied). Layers are numbered from 1 in error messages, as in
    Verisig files.
    """

    def __init__(self, layers, *, scale=None, offset=None, name: str | None = None, source=None):
        self._source = Path(source) if source is not None else None
        where = f"{self._source}: " if self._source is not None else ""
        checked: list[Layer] = []
        for index, layer in enumerate(layers, start=1):
            checked.append(_checked_layer(layer, index, where, checked[-1].n_out if checked else None))
        if not checked:
            raise NetworkFormatError(f"{where}a network needs at least one layer")
        self._layers = tuple(checked)
        self._scale = _checked_output_map(scale, "scale", checked[-1].n_out, where)
        self._offset = _checked_output_map(offset, "offset", checked[-1].n_out, where)
        self._name = name if name is not None else (self._source.stem if self._source is not None else "network")

    @property
    def layers(self) -> tuple[Layer, ...]:
        return self._layers

    @property
    def n_in(self) -> int:
        return self._layers[0].n_in

    @property
    def n_out(self) -> int:
        return self._layers[-1].n_out

    @property
    def scale(self) -> np.ndarray | None:
        """Per-output factor of the output map, or ``None``."""
        return self._scale

    @property
    def offset(self) -> np.ndarray | None:
        """Per-output offset of the output map (added after ``scale``), or ``None``."""
        return self._offset

    @property
    def name(self) -> str:
        return self._name

    @property
    def source(self) -> Path | None:
        """The file the network was read from, if any."""
        return self._source

    def __call__(self, batch) -> np.ndarray:
        """Float evaluation: one sample of shape (n_in,) or a batch of shape (k, n_in)."""
        try:
            x = np.asarray(batch, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise InputError(f"network {self._name!r}: input is not numeric ({error})") from None
        if x.ndim not in (1, 2) or x.shape[-1] != self.n_in:
            raise InputError(
                f"network {self._name!r} takes {self.n_in} inputs per sample: pass shape ({self.n_in},) "
                f"or (batch, {self.n_in}), got shape {x.shape}"
            )
        h = x
        for layer in self._layers:
            h = ACTIVATION_FUNCTIONS[layer.activation](h @ layer.weight.T + layer.bias)
        if self._scale is not None:
            h = h * self._scale
        if self._offset is not None:
            h = h + self._offset
        return h

    def to_onnx(self, path) -> None:
        """Write a float64 ONNX graph (one Gemm per layer) that onnxruntime and :func:`load_network` read."""
        from percver.formats.onnx import write_onnx

        write_onnx(self, path)

    def to_verisig_yaml(self, path) -> None:
        """Write a Verisig ``.yml``; an output map becomes an extra linear layer (the format has none)."""
        from percver.formats.verisig_yaml import write_verisig_yaml

        write_verisig_yaml(self, path)

    def __repr__(self) -> str:
        parts = [str(self.n_in)] + [f"{layer.n_out} {layer.activation}" for layer in self._layers]
        if self._scale is not None or self._offset is not None:
            parts.append("scale/offset")
        return f"Network({self._name!r}: {' -> '.join(parts)})"


def load_network(path) -> Network:
    """Read a network from ``.onnx`` or a Verisig ``.yml``/``.yaml`` file."""
    from percver.formats.onnx import read_onnx
    from percver.formats.verisig_yaml import read_verisig_yaml

    path = Path(path)
    readers = {".onnx": read_onnx, ".yml": read_verisig_yaml, ".yaml": read_verisig_yaml}
    if not path.is_file():
        raise MissingFileError(f"network file not found: {path}")
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise NetworkFormatError(
            f"{path}: unknown network file type {path.suffix!r}; percver reads .onnx and Verisig .yml/.yaml"
        )
    return reader(path)


def chain(*networks: Network) -> Network:
    """Compose networks end to end: ``chain(f, g)(x) == g(f(x))``, as one Network with all layers.

    The output map of every network but the last is folded into the first layer of the next one, so
    the result is a plain layer sequence that set evaluation can propagate without boxing in between.
    """
    if not networks:
        raise InputError("chain() needs at least one network")
    for network in networks:
        if not isinstance(network, Network):
            raise InputError(f"chain() takes Network objects, got {type(network).__name__}")
    layers = list(networks[0].layers)
    for previous, following in zip(networks, networks[1:]):
        if previous.n_out != following.n_in:
            raise InputError(
                f"cannot chain {previous.name!r} ({previous.n_out} outputs) into {following.name!r} "
                f"({following.n_in} inputs)"
            )
        first, *rest = following.layers
        weight, bias = first.weight, first.bias
        if previous.offset is not None:
            bias = bias + weight @ previous.offset
        if previous.scale is not None:
            weight = weight * previous.scale
        layers += [Layer(weight, bias, first.activation), *rest]
    last = networks[-1]
    return Network(layers, scale=last.scale, offset=last.offset, name=" -> ".join(n.name for n in networks))
