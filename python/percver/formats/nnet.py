"""NNet network files (``.nnet``, Kyle Julian's format of ACAS Xu and ARCH-COMP's pendulum,
airplane and VerticalCAS controllers): ReLU on every hidden layer, the output layer linear.

The format: ``//`` comment lines, then comma-separated numbers: the layer count L, the input
and output sizes and the largest layer; the L + 1 layer sizes; a flag (unused); the inputs'
minima and maxima and the means and ranges of the inputs and the output (normalization); then
per layer its weights, one row per neuron, and its biases, one per neuron. ARCH-COMP's files
write single zeros as placeholders for the normalization lines.

The normalization is not applied, as JuliaReach's ``read_NNet`` does not (ARCH-COMP's
VerticalCAS normalizes its inputs with other constants than its files carry): a file whose
normalization is not a placeholder draws :class:`NNetNormalizationWarning`, naming what to apply
in a stage of its own if the network needs it.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from percver.errors import NetworkFormatError
from percver.networks import Layer, Network

_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$")


class NNetNormalizationWarning(UserWarning):
    """The .nnet file carries an input/output normalization, which percver does not apply."""


def read_nnet(path) -> Network:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise NetworkFormatError(f"{path}: not a text file ({error})") from None
    lines = []  # (line number, numbers)
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("//"):
            continue
        fields = [f.strip() for f in line.split(",") if f.strip()]
        bad = [f for f in fields if not _NUMBER.match(f)]
        if bad:
            raise NetworkFormatError(f"{path}, line {number}: {bad[0]!r} is not a number (the format is comma-separated numbers)")
        lines.append((number, [float(f) for f in fields]))
    reader = _Lines(path, lines)
    head = reader.take("the header (layers, inputs, outputs, largest layer)", 4, exact=False)
    layers, n_in, n_out = (_count(v, path, reader.last, what) for v, what in zip(head[:3], ("layer count", "input size", "output size")))
    sizes = [_count(v, path, reader.last, "layer size") for v in reader.take(f"the {layers + 1} layer sizes", layers + 1, exact=False)]
    if sizes[0] != n_in or sizes[-1] != n_out:
        raise NetworkFormatError(
            f"{path}, line {reader.last}: the layer sizes start at {sizes[0]} and end at {sizes[-1]}, "
            f"but the header says {n_in} inputs and {n_out} outputs"
        )
    reader.take("the flag line", 1, exact=False)
    normalization = [reader.take(what, 1, exact=False) for what in ("the input minima", "the input maxima", "the means", "the ranges")]
    if not all(len(v) == 1 and v[0] == 0.0 for v in normalization):
        warnings.warn(
            f"{path}: the file's normalization is not applied (as JuliaReach's read_NNet): inputs clipped to "
            f"{normalization[0]}..{normalization[1]}, shifted by the means {normalization[2][:n_in]} and divided by "
            f"the ranges {normalization[3][:n_in]}, the output scaled back; apply them in stages of their own if "
            f"the network needs them",
            NNetNormalizationWarning,
            stacklevel=3,
        )
    out = []
    for k in range(layers):
        rows = [reader.take(f"layer {k + 1} weights, row {i + 1}", sizes[k]) for i in range(sizes[k + 1])]
        bias = [reader.take(f"layer {k + 1} bias {i + 1}", 1)[0] for i in range(sizes[k + 1])]
        weight, bias = np.array(rows), np.array(bias)
        if not (np.isfinite(weight).all() and np.isfinite(bias).all()):
            raise NetworkFormatError(f"{path}: layer {k + 1} has a non-finite weight or bias")
        out.append(Layer(weight, bias, "relu" if k < layers - 1 else "identity"))
    if reader.remaining():
        raise NetworkFormatError(
            f"{path}, line {reader.next_line()}: numbers after the last layer's biases; the layer sizes {sizes} may be wrong"
        )
    return Network(out, name=path.stem, source=path)


class _Lines:
    """The file's number lines, taken one at a time with a description for errors."""

    def __init__(self, path: Path, lines: list):
        self.path, self.lines, self.at, self.last = path, lines, 0, 0

    def take(self, what: str, count: int, exact: bool = True) -> list:
        if self.at >= len(self.lines):
            raise NetworkFormatError(f"{self.path}: the file ends before {what}")
        self.last, values = self.lines[self.at]
        self.at += 1
        if len(values) < count or (exact and len(values) != count):
            raise NetworkFormatError(f"{self.path}, line {self.last}: {what}: expected {count} numbers, found {len(values)}")
        return values

    def remaining(self) -> bool:
        return self.at < len(self.lines)

    def next_line(self) -> int:
        return self.lines[self.at][0]


def _count(value: float, path: Path, line: int, what: str) -> int:
    if not (value.is_integer() and value >= 1):
        raise NetworkFormatError(f"{path}, line {line}: the {what} must be a positive integer, got {value:g}")
    return int(value)
