"""ONNX networks: read a feed-forward graph into a :class:`~percver.networks.Network` and write one back.

Exporters spell a dense layer differently (PyTorch: Gemm; Keras/tf2onnx: MatMul + Add; MATLAB:
Sub of a normalisation constant, a 1x1 Conv over a 1xN input, Flatten/Reshape), so the reader does
not pattern-match layers. It interprets the graph: every tensor that depends on the input is kept as
an affine function of the output of the last activation (or of the network input). Any run of affine
operators therefore folds into the weight and bias of the next layer, and each Relu, Sigmoid or Tanh
closes one layer. Affine operators after the last activation become the output map (``scale`` and
``offset``) when they act elementwise, else a final linear layer.

The input tensor is one sample: a dynamic first (batch) dimension is taken as 1 and the whole tensor,
flattened in row-major order, is the network input; likewise for the output.

The input domain (:attr:`~percver.networks.Network.domain`, the range the network was trained on)
travels in the model's ``metadata_props`` under ``percver.domain``: a JSON list of one ``[lo, hi]``
per input, ``null`` for an unbounded side. Files without it load with ``domain=None``.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import onnx
from google.protobuf.message import DecodeError
from onnx import TensorProto, helper, numpy_helper

from percver.errors import NetworkFormatError
from percver.networks import ACTIVATION_FUNCTIONS, Layer, Network

SUPPORTED_OPS = (
    "Add", "Constant", "Conv", "Div", "Flatten", "Gemm", "Identity", "MatMul", "Mul",
    "Relu", "Reshape", "Sigmoid", "Squeeze", "Sub", "Tanh", "Transpose", "Unsqueeze",
)  # fmt: skip
_ACTIVATION_OPS = {"Relu": "relu", "Sigmoid": "sigmoid", "Tanh": "tanh"}
_FLOAT_TYPES = {TensorProto.FLOAT, TensorProto.DOUBLE, TensorProto.FLOAT16, TensorProto.BFLOAT16}
# Folding keeps a (width x width) matrix per tensor; beyond this a dense layer is not a sensible model.
_MAX_WIDTH = 8192


class _Affine:
    """A tensor that depends on the input: ``x = sum_j z[j] * M[j] + c`` where z is the flat output of the
    last activation (or the network input); ``M`` has shape ``(len(z),) + c.shape``."""

    def __init__(self, M: np.ndarray, c: np.ndarray):
        self.M, self.c = M, c

    @property
    def shape(self) -> tuple[int, ...]:
        return self.c.shape

    @classmethod
    def identity(cls, shape) -> _Affine:
        n = int(np.prod(shape, dtype=np.int64))
        if n > _MAX_WIDTH:
            raise _NodeError(f"{n} values are too many for a dense layer (at most {_MAX_WIDTH})")
        return cls(np.eye(n).reshape((n, *shape)), np.zeros(shape))


class _NodeError(Exception):
    """A node cannot be read; turned into a NetworkFormatError naming the file and the node."""


def _as_float(value):
    """Constants enter arithmetic as float64; input-dependent values and omitted inputs pass through."""
    return value if value is None or isinstance(value, _Affine) else np.asarray(value, dtype=np.float64)


def _apply(value, f):
    """Apply ``f(array, lead)``, linear in the array and acting on its axes after the first ``lead``."""
    if isinstance(value, _Affine):
        return _Affine(f(value.M, 1), f(value.c, 0))
    return f(value, 0)


def _shape(value) -> tuple[int, ...]:
    return value.shape if isinstance(value, _Affine) else np.shape(value)


def _expand(x: np.ndarray, lead: int, rank: int) -> np.ndarray:
    """Insert unit axes after the lead axes up to ``rank`` other axes (numpy would put them before the lead)."""
    missing = rank - (x.ndim - lead)
    return x.reshape(x.shape[:lead] + (1,) * missing + x.shape[lead:]) if missing > 0 else x


def _add(a, b):
    if isinstance(b, _Affine):
        a, b = b, a
    if not isinstance(a, _Affine):
        return a + b
    shape = np.broadcast_shapes(a.shape, np.shape(b))
    return _Affine(np.broadcast_to(_expand(a.M, 1, len(shape)), a.M.shape[:1] + shape), a.c + b)


def _scaled(value, factor, divide: bool = False):
    """``value * factor`` (or ``value / factor``) for a constant factor."""
    rank = max(len(_shape(value)), np.ndim(factor))
    if divide:
        return _apply(value, lambda x, lead: _expand(x, lead, rank) / factor)
    return _apply(value, lambda x, lead: _expand(x, lead, rank) * factor)


def _matmul(a, b):
    """numpy/ONNX MatMul where at most one operand depends on the input."""
    if isinstance(a, _Affine):
        k = b
        if k.ndim == 1:
            return _apply(a, lambda x, lead: x @ k)
        if len(a.shape) == 1:  # a row vector: promote, multiply, drop the unit axis again
            return _apply(a, lambda x, lead: (_expand(x[..., None, :], lead, k.ndim) @ k)[..., 0, :])
        return _apply(a, lambda x, lead: _expand(x, lead, k.ndim) @ k)
    if isinstance(b, _Affine):
        k = a
        if len(b.shape) == 1:
            return _apply(b, lambda x, lead: (k @ _expand(x[..., None], lead, k.ndim))[..., 0])
        return _apply(b, lambda x, lead: k @ _expand(x, lead, k.ndim))
    return a @ b


def _conv(x: np.ndarray, lead: int, weight: np.ndarray, strides, pads, dilations) -> np.ndarray:
    """ONNX Conv without bias and with one group, on x of shape lead + (N, C, *spatial)."""
    n_spatial = weight.ndim - 2
    outer = x.shape[: lead + 1]
    x = x.reshape((-1, *x.shape[lead + 1 :]))
    x = np.pad(x, [(0, 0), (0, 0), *zip(pads[:n_spatial], pads[n_spatial:])])
    size = [(x.shape[2 + i] - dilations[i] * (weight.shape[2 + i] - 1) - 1) // strides[i] + 1 for i in range(n_spatial)]
    if min(size) < 1:
        raise _NodeError(f"the kernel {weight.shape[2:]} does not fit the padded input {x.shape[2:]}")
    y = np.zeros((x.shape[0], weight.shape[0], *size))
    for tap in itertools.product(*(range(k) for k in weight.shape[2:])):
        window = tuple(slice(t * d, t * d + (n - 1) * s + 1, s) for t, d, n, s in zip(tap, dilations, size, strides))
        taps = weight[(slice(None), slice(None), *tap)]
        y += np.einsum("bc...,oc->bo...", x[(slice(None), slice(None), *window)], taps)
    return y.reshape(outer + y.shape[1:])


def _transposed(x: np.ndarray, lead: int) -> np.ndarray:
    """Swap the two matrix axes (Gemm's transA/transB)."""
    return np.swapaxes(x, -1, -2)


def _reshaped(value, shape):
    return _apply(value, lambda x, lead: x.reshape(x.shape[:lead] + tuple(shape)))


def _target_shape(in_shape, target, allow_zero: bool) -> tuple[int, ...]:
    size = int(np.prod(in_shape, dtype=np.int64))
    try:
        out = [in_shape[i] if d == 0 and not allow_zero else int(d) for i, d in enumerate(target)]
    except IndexError:
        raise _NodeError(f"shape {list(target)} copies a dimension the input {in_shape} does not have") from None
    if out.count(-1) == 1:
        known = int(np.prod([d for d in out if d != -1], dtype=np.int64))
        out[out.index(-1)] = size // known if known else 0
    if out.count(-1) > 1 or any(d < 0 for d in out) or int(np.prod(out, dtype=np.int64)) != size:
        raise _NodeError(f"cannot reshape {in_shape} to {list(target)}")
    return tuple(out)


def _axes(node_axes, rank: int) -> list[int]:
    axes = sorted(a + rank if a < 0 else a for a in node_axes)
    if any(not 0 <= a < rank for a in axes) or len(set(axes)) != len(axes):
        raise _NodeError(f"axes {list(node_axes)} are invalid for rank {rank}")
    return axes


class _GraphReader:
    def __init__(self, path: Path, model: onnx.ModelProto):
        self.path = path
        self.graph = model.graph
        # every reader of a tensor, so that a branch is found at the first of its readers
        self.readers: dict[str, list[str]] = {}
        for index, node in enumerate(self.graph.node):
            for name in node.input:
                self.readers.setdefault(name, []).append(self.label(index, node))
        for output in self.graph.output:
            self.readers.setdefault(output.name, []).append(f"graph output {output.name!r}")
        self.values: dict[str, object] = {}
        for tensor in self.graph.initializer:
            self.values[tensor.name] = self.finite(numpy_helper.to_array(tensor), tensor.name)
        self.layers: list[Layer] = []

    @staticmethod
    def label(index: int, node) -> str:
        if node.name:
            return f"node {node.name!r}"
        return f"node #{index} (unnamed, output {node.output[0] if node.output else None!r})"

    def finite(self, array: np.ndarray, name: str) -> np.ndarray:
        """A constant tensor (initializer or Constant output), checked to hold no NaN or infinity."""
        if array.dtype.kind in "fc":
            bad = np.argwhere(~np.isfinite(array))
            if bad.size:
                readers = ", ".join(self.readers.get(name, [])) or "no node"
                raise NetworkFormatError(
                    f"{self.path}: constant tensor {name!r} (read by {readers}) has the non-finite value "
                    f"{array[tuple(bad[0])]} at index {tuple(int(i) for i in bad[0])}"
                )
        return array

    def error(self, message: str) -> NetworkFormatError:
        return NetworkFormatError(f"{self.path}: {message}; percver reads feed-forward chains of the ONNX ops {', '.join(SUPPORTED_OPS)}")

    def read(self) -> Network:
        inputs = [i for i in self.graph.input if i.name not in self.values]
        if len(inputs) != 1:
            raise self.error(f"the graph has {len(inputs)} non-constant inputs {[i.name for i in inputs]}, not one")
        if len(self.graph.output) != 1:
            raise self.error(f"the graph has {len(self.graph.output)} outputs, not one")
        # unsupported ops first: they are the likely problem, and tell it before any large allocation
        for index, node in enumerate(self.graph.node):
            if node.domain not in ("", "ai.onnx") or node.op_type not in SUPPORTED_OPS:
                domain = f" (domain {node.domain!r})" if node.domain not in ("", "ai.onnx") else ""
                raise self.error(f"{self.label(index, node)} has the unsupported op type {node.op_type!r}{domain}")
        try:
            self.values[inputs[0].name] = _Affine.identity(self.input_shape(inputs[0]))
        except _NodeError as error:
            raise self.error(f"input {inputs[0].name!r}: {error}") from None

        for index, node in enumerate(self.graph.node):
            label = self.label(index, node)
            if len(node.output) != 1:
                raise self.error(f"{label} ({node.op_type}) has {len(node.output)} outputs, not one")
            args = [self.argument(name, label, node.op_type) for name in node.input]
            attributes = {a.name: helper.get_attribute_value(a) for a in node.attribute}
            try:
                value = self.evaluate(node.op_type, args, attributes)
            except _NodeError as error:
                raise self.error(f"{label} ({node.op_type}): {error}") from None
            except ValueError as error:  # numpy's complaint about shapes that do not fit
                raise self.error(f"{label} ({node.op_type}): operand shapes do not fit ({error})") from None
            self.values[node.output[0]] = self.finite(value, node.output[0]) if node.op_type == "Constant" else value

        output = self.graph.output[0].name
        if not isinstance(self.values.get(output), _Affine):
            raise self.error(f"the graph output {output!r} does not depend on the input")
        return self.finish(self.values[output])

    def input_shape(self, value_info) -> tuple[int, ...]:
        tensor_type = value_info.type.tensor_type
        if tensor_type.elem_type not in _FLOAT_TYPES or not tensor_type.HasField("shape"):
            raise self.error(f"input {value_info.name!r} must be a floating-point tensor of known shape")
        dims = [d.dim_value if d.HasField("dim_value") and d.dim_value > 0 else None for d in tensor_type.shape.dim]
        if dims[:1] == [None]:
            dims[0] = 1  # the batch axis
        if None in dims:
            raise self.error(f"input {value_info.name!r} has an unknown size in a non-batch dimension")
        return tuple(dims)

    def argument(self, name: str, label: str, op_type: str):
        if name == "":  # an omitted optional input
            return None
        if name not in self.values:
            raise self.error(f"{label} ({op_type}) reads {name!r}, which no earlier node or initializer provides")
        value = self.values[name]
        if isinstance(value, _Affine) and len(self.readers[name]) > 1:
            raise self.error(f"{label} ({op_type}): the graph branches: tensor {name!r} is read by {', '.join(self.readers[name])}")
        return value

    def evaluate(self, op: str, args: list, attributes: dict):
        """The value of one node: a constant array, or an _Affine if it depends on the input."""
        if op in _ACTIVATION_OPS:
            (x,) = args
            activation = _ACTIVATION_OPS[op]
            if not isinstance(x, _Affine):
                return ACTIVATION_FUNCTIONS[activation](np.asarray(x, dtype=np.float64))
            self.layers.append(Layer(x.M.reshape(x.M.shape[0], -1).T, x.c.reshape(-1), activation))
            return _Affine.identity(x.shape)
        if op == "Constant":
            return self.constant_node(attributes)
        if op == "Identity":
            return args[0]
        if op in ("Add", "Sub", "Mul", "Div"):
            return self.arithmetic(op, *args)
        if op == "Gemm":
            return self.gemm(args, attributes)
        if op == "MatMul":
            return _matmul(*map(_as_float, args))
        if op == "Conv":
            return self.conv(args, attributes)
        return self.reshaping(op, args, attributes)

    @staticmethod
    def constant(value, what: str) -> np.ndarray:
        if isinstance(value, _Affine):
            raise _NodeError(f"{what} must be a constant, but it depends on the network input")
        return value

    def constant_node(self, attributes: dict):
        for key in ("value_float", "value_floats"):
            if key in attributes:
                return np.array(attributes[key], dtype=np.float32)
        for key in ("value_int", "value_ints"):
            if key in attributes:
                return np.array(attributes[key], dtype=np.int64)
        if "value" in attributes:
            return numpy_helper.to_array(attributes["value"])
        raise _NodeError(f"only tensor, float and int constants are supported, got {sorted(attributes)}")

    def arithmetic(self, op: str, a, b):
        a, b = _as_float(a), _as_float(b)
        if op == "Add":
            return _add(a, b)
        if op == "Sub":
            return _add(a, _scaled(b, -1.0))
        if op == "Div" and isinstance(b, _Affine):
            raise _NodeError("dividing by a tensor that depends on the input is not affine")
        if op == "Mul":
            return _scaled(b, a) if isinstance(b, _Affine) else _scaled(a, b)
        return _scaled(a, b, divide=True)

    def gemm(self, args: list, attributes: dict):
        a, b = map(_as_float, args[:2])
        c = _as_float(args[2]) if len(args) > 2 else None
        if len(_shape(a)) != 2 or len(_shape(b)) != 2:
            raise _NodeError(f"Gemm needs 2-D operands, got shapes {_shape(a)} and {_shape(b)}")
        if attributes.get("transA", 0):
            a = _apply(a, _transposed)
        if attributes.get("transB", 0):
            b = _apply(b, _transposed)
        y = _scaled(_matmul(a, b), attributes.get("alpha", 1.0))
        return y if c is None else _add(y, _scaled(c, attributes.get("beta", 1.0)))

    def conv(self, args: list, attributes: dict):
        x, weight = _as_float(args[0]), self.constant(_as_float(args[1]), "the Conv weight")
        bias = _as_float(args[2]) if len(args) > 2 else None
        n_spatial = weight.ndim - 2
        if attributes.get("group", 1) != 1:
            raise _NodeError("grouped convolutions are not supported")
        if attributes.get("auto_pad", b"NOTSET") not in (b"NOTSET", b"VALID"):
            raise _NodeError("auto_pad SAME_UPPER/SAME_LOWER is not supported; give explicit pads")
        if len(_shape(x)) != weight.ndim or _shape(x)[1] != weight.shape[1]:
            raise _NodeError(f"input of shape {_shape(x)} does not fit the weight of shape {weight.shape}")
        strides = attributes.get("strides", [1] * n_spatial)
        pads = attributes.get("pads", [0] * 2 * n_spatial)
        dilations = attributes.get("dilations", [1] * n_spatial)
        y = _apply(x, lambda v, lead: _conv(v, lead, weight, strides, pads, dilations))
        if bias is None:
            return y
        return _add(y, self.constant(bias, "the Conv bias").reshape((-1,) + (1,) * n_spatial))

    def reshaping(self, op: str, args: list, attributes: dict):
        """Transpose, Reshape, Flatten, Squeeze, Unsqueeze: only the layout changes."""
        x = args[0]
        shape = _shape(x)
        if op == "Transpose":
            perm = attributes.get("perm", list(range(len(shape)))[::-1])
            return _apply(x, lambda v, lead: np.transpose(v, [*range(lead), *(lead + p for p in perm)]))
        if op == "Reshape":
            if len(args) < 2 and "shape" not in attributes:
                raise _NodeError("Reshape needs a target shape")
            target = attributes["shape"] if len(args) < 2 else self.constant(args[1], "the Reshape shape")
            return _reshaped(x, _target_shape(shape, np.asarray(target), bool(attributes.get("allowzero", 0))))
        if op == "Flatten":
            axis = attributes.get("axis", 1)
            axis = axis + len(shape) if axis < 0 else axis
            rows, columns = np.prod(shape[:axis], dtype=np.int64), np.prod(shape[axis:], dtype=np.int64)
            return _reshaped(x, (int(rows), int(columns)))
        if len(args) > 1 and args[1] is not None:  # opset 13: axes as an input
            node_axes = [int(a) for a in np.ravel(self.constant(args[1], f"the {op} axes"))]
        else:
            node_axes = attributes.get("axes")
        if op == "Squeeze":
            axes = _axes(node_axes, len(shape)) if node_axes is not None else [i for i, d in enumerate(shape) if d == 1]
            if any(shape[a] != 1 for a in axes):
                raise _NodeError(f"cannot squeeze axes {axes} of shape {shape}")
            return _reshaped(x, tuple(d for i, d in enumerate(shape) if i not in axes))
        if node_axes is None:
            raise _NodeError("Unsqueeze needs axes")
        out = list(shape)
        for axis in _axes(node_axes, len(shape) + len(node_axes)):
            out.insert(axis, 1)
        return _reshaped(x, tuple(out))

    def finish(self, output: _Affine) -> Network:
        """Close the network: trailing affine operators become the output map or a final linear layer."""
        matrix = output.M.reshape(output.M.shape[0], -1)
        offset = output.c.reshape(-1)
        square = matrix.shape[0] == matrix.shape[1]
        scale = np.diag(matrix) if square else None
        if square and np.array_equal(matrix, np.eye(len(offset))) and not offset.any():
            return self.network()
        if self.layers and square and np.array_equal(matrix, np.diag(scale)):
            return self.network(scale=None if np.all(scale == 1.0) else scale, offset=offset if offset.any() else None)
        self.layers.append(Layer(matrix.T, offset, "identity"))
        return self.network()

    def network(self, **output_map) -> Network:
        return Network(self.layers, name=self.path.stem, source=self.path, **output_map)


DOMAIN_KEY = "percver.domain"


def read_onnx(path) -> Network:
    path = Path(path)
    try:
        model = onnx.load(str(path))
    except DecodeError as error:
        raise NetworkFormatError(f"{path}: not a readable ONNX file ({error})") from None
    network = _GraphReader(path, model).read()
    text = next((p.value for p in model.metadata_props if p.key == DOMAIN_KEY), None)
    return network if text is None else network.with_domain(_domain_from_json(text, network.n_in, path))


def _domain_from_json(text: str, n_in: int, path: Path) -> list:
    where = f"{path}: metadata {DOMAIN_KEY!r}"
    try:
        pairs = json.loads(text)
    except ValueError as error:
        raise NetworkFormatError(f"{where} is not JSON ({error})") from None
    if not (isinstance(pairs, list) and all(isinstance(p, list) and len(p) == 2 for p in pairs)) or len(pairs) != n_in:
        raise NetworkFormatError(f"{where} must list one [lo, hi] per input ({n_in}), null for an unbounded side")
    domain = []
    for i, (lo, hi) in enumerate(pairs):
        lo, hi = -math.inf if lo is None else lo, math.inf if hi is None else hi
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (lo, hi)) or not lo <= hi:
            raise NetworkFormatError(f"{where}: input {i} has [{lo}, {hi}]; give numbers lo <= hi (null: unbounded)")
        domain.append((float(lo), float(hi)))
    return domain


def _domain_to_json(domain) -> str:
    return json.dumps([[lo if math.isfinite(lo) else None, hi if math.isfinite(hi) else None] for lo, hi in domain])


# IR 8 / opset 13 keep the files readable by every onnxruntime percver supports (>= 1.16).
_IR_VERSION = 8
_OPSET = 13
_ACTIVATION_OP_NAMES = {activation: op for op, activation in _ACTIVATION_OPS.items()}


def write_onnx(network: Network, path) -> None:
    """One Gemm (transB=1, so the weight is stored n_out x n_in as in the IR) per layer, then the activation."""
    nodes, initializers = [], []
    current = "input"

    def emit(op: str, inputs: list[str], name: str, **attributes) -> None:
        nonlocal current
        nodes.append(helper.make_node(op, [current, *inputs], [name], name=name, **attributes))
        current = name

    def constant(name: str, array: np.ndarray) -> str:
        initializers.append(numpy_helper.from_array(np.asarray(array, dtype=np.float64), name))
        return name

    for i, layer in enumerate(network.layers, start=1):
        weight, bias = constant(f"layer{i}.weight", layer.weight), constant(f"layer{i}.bias", layer.bias)
        emit("Gemm", [weight, bias], f"layer{i}.gemm", transB=1)
        activation = layer.uniform_activation("the ONNX writer")
        if activation != "identity":
            emit(_ACTIVATION_OP_NAMES[activation], [], f"layer{i}.{activation}")
    if network.scale is not None:
        emit("Mul", [constant("output.scale", network.scale)], "output.mul")
    if network.offset is not None:
        emit("Add", [constant("output.offset", network.offset)], "output.add")
    nodes[-1].output[0] = "output"

    graph = helper.make_graph(
        nodes,
        network.name,
        [helper.make_tensor_value_info("input", TensorProto.DOUBLE, ["batch", network.n_in])],
        [helper.make_tensor_value_info("output", TensorProto.DOUBLE, ["batch", network.n_out])],
        initializers,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", _OPSET)], producer_name="percver")
    model.ir_version = _IR_VERSION
    if network.domain is not None:
        helper.set_model_props(model, {DOMAIN_KEY: _domain_to_json(network.domain)})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
