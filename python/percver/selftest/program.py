"""What a self-test program is: a closed loop as plain data (a small expression AST, network
weights, a property and verify options), and its rendering as Python source that builds the loop
with percver.

The program is the single description of a test case. The source rendering is what the campaign
executes (so the printed reproducer is exactly what ran) and :mod:`percver.selftest.oracle`
evaluates the same data with numpy and onnxruntime; the two share nothing but this data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

UNARY = ("sin", "cos", "tanh", "sigmoid", "atan", "exp", "abs", "sqrt", "log")
COMPARISONS = ("<=", "<", ">=", ">")
# The plainest verify options: the initial set as one cell, never split again. (Without any, the
# adaptive splitter may run the engine up to a thousand times.) A splitter option is written as
# (class name, keyword arguments): ``pv.Grid()``, ``pv.Adaptive(max_cells=8)``.
SIMPLEST = {"splitter": ("Grid", {})}


@dataclass(frozen=True)
class Const:
    value: float


@dataclass(frozen=True)
class Var:
    """A state, an accumulator or a (component of a) stage output, by its environment name."""

    name: str


@dataclass(frozen=True)
class Param:
    """Uncertain parameter ``index`` of the program (``pv.uncertain(lo, hi)``): one value per run."""

    index: int


@dataclass(frozen=True)
class Unary:
    fn: str
    arg: "Node"


@dataclass(frozen=True)
class Binary:
    op: str
    a: "Node"
    b: "Node"


@dataclass(frozen=True)
class Pow:
    arg: "Node"
    n: int


@dataclass(frozen=True)
class Cond:
    lhs: "Node"
    op: str
    rhs: "Node"


@dataclass(frozen=True)
class Where:
    cond: Cond
    then: "Node"
    otherwise: "Node"


@dataclass(frozen=True)
class Clip:
    arg: "Node"
    lo: float
    hi: float


Node = Union[Const, Var, Param, Unary, Binary, Pow, Where, Clip]


def children(node) -> tuple:
    """The sub-expressions of a node (a condition's sides count)."""
    if isinstance(node, (Unary, Pow, Clip)):
        return (node.arg,)
    if isinstance(node, Binary):
        return (node.a, node.b)
    if isinstance(node, Cond):
        return (node.lhs, node.rhs)
    if isinstance(node, Where):
        return (node.cond.lhs, node.cond.rhs, node.then, node.otherwise)
    return ()


def walk(node):
    """The node and all its descendants, parents first."""
    yield node
    for child in children(node):
        yield from walk(child)


def names_in(node) -> set:
    return {n.name for n in walk(node) if isinstance(n, Var)}


def params_in(node) -> set:
    return {n.index for n in walk(node) if isinstance(n, Param)}


@dataclass
class Net:
    """One ONNX file: dense layers ``(weight n_out x n_in, bias, activation)`` and an optional
    elementwise output map written as Mul/Add nodes; ``style`` is how a layer is spelled
    ("gemm": Gemm with transB; "matmul": MatMul by the transposed weight, then Add)."""

    layers: list
    scale: Optional[list] = None
    offset: Optional[list] = None
    style: str = "gemm"

    @property
    def n_in(self) -> int:
        return len(self.layers[0][0][0])

    @property
    def n_out(self) -> int:
        return len(self.layers[-1][1])

    @property
    def activations(self) -> set:
        return {act for _, _, act in self.layers}


@dataclass
class Stage:
    """``output = scale * component(inputs) + offset``: expressions over the input signals, or
    networks (several are chained with ``pv.chain`` into one stage)."""

    output: str
    inputs: list
    exprs: Optional[list] = None
    nets: Optional[list] = None
    scale: Optional[float] = None
    offset: Optional[float] = None

    @property
    def width(self) -> int:
        return len(self.exprs) if self.exprs is not None else self.nets[-1].n_out

    @property
    def names(self) -> list:
        """The environment names of the output's values."""
        return [self.output] if self.width == 1 else [f"{self.output}_{i}" for i in range(self.width)]


@dataclass
class Program:
    """A closed loop with its property and verify options.

    ``update`` maps each plant state to its next value (discrete, ``period`` None) or to its
    derivative (continuous, the stage outputs in ``inputs`` held over each period). ``reward``
    adds accumulators through ``verify(reward=...)``: they follow the plant states in the result.
    """

    states: list
    init: dict
    update: dict
    stages: list = field(default_factory=list)
    params: list = field(default_factory=list)
    period: Optional[float] = None
    step: Optional[float] = None
    inputs: list = field(default_factory=list)
    reward: dict = field(default_factory=dict)
    safe: list = field(default_factory=list)
    unsafe: list = field(default_factory=list)
    goal: list = field(default_factory=list)
    within: bool = False
    steps: int = 1
    options: dict = field(default_factory=dict)

    @property
    def continuous(self) -> bool:
        return self.period is not None

    @property
    def all_states(self) -> list:
        """The states of the verified loop (the result's order): plant states, then accumulators."""
        return list(self.states) + list(self.reward)

    @property
    def start(self) -> dict:
        """The initial box over :attr:`all_states` (accumulators start at 0)."""
        return {**self.init, **{r: (0.0, 0.0) for r in self.reward}}

    @property
    def env_names(self) -> list:
        return list(self.states) + [n for s in self.stages for n in s.names]

    def nets(self) -> list:
        return [net for s in self.stages if s.nets for net in s.nets]

    def conditions(self) -> list:
        """Every condition of the property."""
        return list(self.safe) + list(self.unsafe) + list(self.goal)

    def expressions(self) -> list:
        """Every expression of the loop (not of the property)."""
        out = list(self.update.values()) + list(self.reward.values())
        for s in self.stages:
            out += s.exprs or []
        return out


# ---------------------------------------------------------------------------------------------
# Source rendering


def _num(v: float) -> str:
    text = repr(float(v))
    return f"({text})" if text.startswith("-") else text


def source_of(node) -> str:
    """The node as a percver expression in Python (fully parenthesised)."""
    if isinstance(node, Const):
        return _num(node.value)
    if isinstance(node, Var):
        return node.name
    if isinstance(node, Param):
        return f"p{node.index + 1}"
    if isinstance(node, Unary):
        return f"pv.{'abs_' if node.fn == 'abs' else node.fn}({source_of(node.arg)})"
    if isinstance(node, Binary):
        if node.op in ("min", "max"):
            return f"pv.{node.op}({source_of(node.a)}, {source_of(node.b)})"
        return f"({source_of(node.a)} {node.op} {source_of(node.b)})"
    if isinstance(node, Pow):
        return f"({source_of(node.arg)} ** {node.n})"
    if isinstance(node, Cond):
        return f"({source_of(node.lhs)} {node.op} {source_of(node.rhs)})"
    if isinstance(node, Where):
        return f"pv.where({source_of(node.cond)}, {source_of(node.then)}, {source_of(node.otherwise)})"
    if isinstance(node, Clip):
        return f"pv.clip({source_of(node.arg)}, {_num(node.lo)}, {_num(node.hi)})"
    raise TypeError(f"not a program node: {node!r}")


def _list(values) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def _net_source(net: Net, k: int) -> str:
    layers = ", ".join(f"([{', '.join(_list(row) for row in w)}], {_list(b)}, {act!r})" for w, b, act in net.layers)
    maps = "".join(f", {what}={_list(v)}" for what, v in (("scale", net.scale), ("offset", net.offset)) if v is not None)
    return f"net{k} = write_onnx(DIR / 'net{k}.onnx', [{layers}]{maps}, style={net.style!r})"


def _conditions(conds: list) -> str:
    return source_of(conds[0]) if len(conds) == 1 else "[" + ", ".join(source_of(c) for c in conds) + "]"


def loop_source(program: Program) -> str:
    """Python source that builds ``loop`` (a ``pv.ClosedLoop``) and ``kwargs`` (of ``pv.verify``)
    from ``program``; network files are written under ``DIR``, which the source creates."""
    names = program.env_names + [n for n in program.reward if n not in program.env_names]
    lines = ["import percver as pv"]
    if program.nets():
        lines += [
            "import tempfile",
            "from pathlib import Path",
            "from percver.selftest.program import write_onnx",
            "",
            "DIR = Path(tempfile.mkdtemp(prefix='percver-selftest-'))",
        ]
    lines.append("")
    lines.append(f"{', '.join(names)} = pv.variables({' '.join(names)!r})")
    for i, (lo, hi) in enumerate(program.params):
        lines.append(f"p{i + 1} = pv.uncertain({_num(lo)}, {_num(hi)})")
    k = 0
    stage_lines = []
    for s in program.stages:
        if s.nets is not None:
            loads = []
            for net in s.nets:
                k += 1
                lines.append(_net_source(net, k))
                loads.append(f"pv.load_network(net{k})")
            component = loads[0] if len(loads) == 1 else f"pv.chain({', '.join(loads)})"
        else:
            exprs = [source_of(e) for e in s.exprs]
            component = exprs[0] if len(exprs) == 1 else "[" + ", ".join(exprs) + "]"
        maps = "".join(f", {what}={_num(v)}" for what, v in (("scale", s.scale), ("offset", s.offset)) if v is not None)
        stage_lines.append(f"    pv.Stage({component}, inputs={list(s.inputs)!r}, output={s.output!r}{maps}),")
    update = ", ".join(f"{n}: {source_of(e)}" for n, e in program.update.items())
    if program.continuous:
        lines.append(
            f"plant = pv.Continuous({{{update}}}, inputs=[{', '.join(program.inputs)}], period={program.period!r}, step={program.step!r})"
        )
    else:
        lines.append(f"plant = pv.Discrete({{{update}}})")
    lines += ["loop = pv.ClosedLoop(plant, stages=[", *stage_lines, "])"] if stage_lines else ["loop = pv.ClosedLoop(plant, stages=[])"]
    args = [
        f"steps={program.steps}",
        "init={" + ", ".join(f"{n!r}: ({_num(lo)}, {_num(hi)})" for n, (lo, hi) in program.init.items()) + "}",
    ]
    if program.reward:
        args.append("reward={" + ", ".join(f"{n!r}: {source_of(e)}" for n, e in program.reward.items()) + "}")
    for what in ("safe", "unsafe", "goal"):
        conds = getattr(program, what)
        if conds:
            args.append(f"{what}={_conditions(conds)}")
    if program.within:
        args.append("within=True")
    for key, value in program.options.items():
        if key == "splitter":
            name, keywords = value
            value = f"pv.{name}({', '.join(f'{k}={v!r}' for k, v in keywords.items())})"
        else:
            value = repr(value)
        args.append(f"{key}={value}")
    lines.append(f"kwargs = dict({', '.join(args)})")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Network files


def write_onnx(path, layers, scale=None, offset=None, style: str = "gemm") -> Path:
    """A float64 ONNX file of dense layers ``(weight, bias, activation)`` (weight n_out x n_in)
    with an optional elementwise output map; returns the path. Written with ``onnx.helper``
    alone, so the file is not percver's own rendering of the network."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    ops = {"sigmoid": "Sigmoid", "tanh": "Tanh", "relu": "Relu"}
    nodes, constants = [], []
    current = "input"

    def emit(op: str, *inputs, **attributes):
        nonlocal current
        name = f"t{len(nodes)}"
        nodes.append(helper.make_node(op, [current, *inputs], [name], name=name, **attributes))
        current = name

    def constant(array) -> str:
        name = f"c{len(constants)}"
        constants.append(numpy_helper.from_array(np.asarray(array, dtype=np.float64), name))
        return name

    for weight, bias, activation in layers:
        weight = np.asarray(weight, dtype=np.float64)
        if style == "gemm":
            emit("Gemm", constant(weight), constant(bias), transB=1)
        else:
            emit("MatMul", constant(weight.T))
            emit("Add", constant(bias))
        if activation != "identity":
            emit(ops[activation])
    if scale is not None:
        emit("Mul", constant(scale))
    if offset is not None:
        emit("Add", constant(offset))
    nodes[-1].output[0] = "output"
    n_in, n_out = len(layers[0][0][0]), len(layers[-1][1])
    graph = helper.make_graph(
        nodes,
        "selftest",
        [helper.make_tensor_value_info("input", TensorProto.DOUBLE, ["batch", n_in])],
        [helper.make_tensor_value_info("output", TensorProto.DOUBLE, ["batch", n_out])],
        constants,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="percver-selftest")
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return Path(path)
