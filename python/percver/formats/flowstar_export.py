"""Networks, chains of networks and closed loops with a discrete plant as Flow* ``.model`` files,
in the style of Verisig 1.0 (Ivanov et al., HSCC 2019): the network becomes part of the hybrid
automaton, so Flow* itself (or :func:`percver.formats.load_flowstar`) computes the reach sets.

Each layer with sigmoid or tanh neurons is a mode flowing for t in [0, 1]: neuron i holds its
pre-activation ``_a{i}`` constant and its state follows ``_z{i}' = _a{i} * _z{i} * (1 - _z{i})``
from ``_z{i} = 0.5`` (sigmoid) or ``_z{i}' = _a{i} * (1 - _z{i} * _z{i})`` from ``_z{i} = 0``
(tanh), so ``_z{i}(1)`` is the activation. The affine maps are the resets of the jumps between
modes (``_a{i}' := sum_j w_ij _z{j} + b_i``), identity neurons are set by the reset directly,
and ``clock`` times every mode (``inv { clock <= 1 }``, ``guard { clock = 1 }``). Layers without
sigmoid or tanh neurons are modes of zero dwell. Neuron variables are shared between layers
(resets are simultaneous, so a layer reads the previous one's values while writing its own).

With a discrete plant the network's inputs are plant states and its outputs the plant's inputs;
after the network, the mode ``_reset_plant`` (Verisig's discrete-update idiom) integrates
``_t{j}' = e_j`` for one time unit with every other variable frozen, so ``_t{j}`` ends equal to
each non-polynomial expression ``e_j`` the update needs (Flow* resets are polynomial). Piecewise
updates (``min``, ``max``, ``where``, ``abs``, so ``pv.clip``) become one jump per combination
of branches, guarded by their conditions, as in Verisig's Mountain Car model. A step counter
``_k`` stops the loop after ``steps`` periods in the mode ``_done``.

Only what Flow* reads is written: ReLU neurons (Verisig 1.0 has no ODE for them), functions
other than sin, cos, exp, log and sqrt, and non-integer powers are refused with the reason.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from percver.errors import InputError, ParseError
from percver.formats.flowstar_syntax import parse_expression, text as _text
from percver.networks import Network, chain
from percver.sets import Box
from percver.systems import Discrete

__all__ = ["to_flowstar"]

_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_FLOWSTAR_FUNCTIONS = {"sin", "cos", "exp", "log", "sqrt"}
# Branch combinations of a piecewise plant update written as jumps: 2^8.
_MAX_PIECEWISE = 8


def to_flowstar(
    network,
    path,
    init,
    *,
    plant=None,
    steps: int = 1,
    outputs: Optional[Sequence[str]] = None,
    order: int = 4,
    step: tuple = (1e-6, 0.05),
    remainder: float = 1e-4,
    cutoff: float = 1e-15,
) -> Path:
    """Write ``network`` (a :class:`Network`, or several to chain) as a Flow* hybrid model.

    ``init`` is the initial box over the network's inputs (a dict by input name or a list of
    (lo, hi)), or with ``plant`` (a ``pv.Discrete``) over the plant's states, which the network's
    inputs must all be (name them with ``network.with_input_names``); the network's outputs are
    the plant's inputs, and the loop runs ``steps`` periods. Without a plant the outputs are
    named ``outputs`` (default ``y1, y2, ...``) and the run ends in the mode ``_out``. ``order``,
    ``step`` (fixed, or (min, max) for adaptive steps), ``remainder`` and ``cutoff`` are written
    into the file's settings. Returns the path.
    """
    if isinstance(network, (list, tuple)):
        network = chain(*network)
    if not isinstance(network, Network):
        raise InputError(f"to_flowstar takes a Network (or a list of them to chain), got {type(network).__name__}")
    if plant is None:
        names = list(outputs) if outputs is not None else [f"y{i + 1}" for i in range(network.n_out)]
        if len(names) != network.n_out:
            raise InputError(f"network {network.name!r} has {network.n_out} outputs, got {len(names)} output names")
        states, box = list(network.input_names), _init_box(init, list(network.input_names), "network input")
    else:
        names, states, box = _plant_signals(network, plant, init, steps)
    for name in [*states, *names]:
        if not _IDENTIFIER.fullmatch(name) or name == "clock":
            raise InputError(
                f"'{name}' cannot be a Flow* variable: use letters, digits and '_', starting with a letter, "
                "and not 'clock' (names starting with '_' are the exporter's own)"
            )
    if len(set(states) | set(names)) != len(states) + len(names):
        raise InputError(f"the model's variables must be distinct: {states + names}")
    writer = _Writer(network, states, names)
    if plant is None:
        writer.network_only()
    else:
        writer.closed_loop(plant, steps)
    text = writer.text(box, _settings(order, step, remainder, cutoff), Path(path).stem)
    path = Path(path)
    path.write_text(text)
    return path


def _init_box(init, names: list, what: str) -> dict:
    try:
        return Box.coerce(init, names).to_dict()
    except InputError as error:
        raise InputError(f"init (one interval per {what}: {', '.join(names)}): {error}") from None


def _plant_signals(network: Network, plant, init, steps) -> tuple:
    if not isinstance(plant, Discrete):
        raise InputError(
            f"to_flowstar writes discrete plants (pv.Discrete); got {type(plant).__name__}. "
            "A continuous plant's flow would be a mode of its own: not supported yet"
        )
    if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
        raise InputError(f"steps must be a positive integer, got {steps!r}")
    foreign = [n for n in network.input_names if n not in plant.states]
    if foreign:
        raise InputError(
            f"network {network.name!r} reads {foreign}, which are not states of the plant ({', '.join(plant.states)}); "
            "name its inputs after plant states with network.with_input_names([...])"
        )
    if network.n_out != len(plant.inputs):
        raise InputError(
            f"network {network.name!r} has {network.n_out} outputs but the plant has {len(plant.inputs)} inputs "
            f"({', '.join(plant.inputs)}): the outputs become the plant's inputs in order"
        )
    return list(plant.inputs), list(plant.states), _init_box(init, list(plant.states), "plant state")


def _settings(order, step, remainder, cutoff) -> list:
    if not (isinstance(order, int) and 1 <= order <= 30):
        raise InputError(f"order must be an integer in [1, 30], got {order!r}")
    if isinstance(step, (list, tuple)):
        lo, hi = (float(s) for s in step)
        if not 0 < lo <= hi <= 1:
            raise InputError(f"adaptive steps need 0 < min <= max <= 1, got {step}")
        steps = f"adaptive steps {{min {_num(lo)}, max {_num(hi)}}}"
    else:
        if not 0 < float(step) <= 1:
            raise InputError(f"the step must be in (0, 1], got {step}")
        steps = f"fixed steps {_num(float(step))}"
    if not (remainder > 0 and 0 <= cutoff < 1):
        raise InputError(f"remainder must be positive and cutoff in [0, 1), got {remainder} and {cutoff}")
    return [steps, f"remainder estimation {_num(remainder)}", "identity precondition", f"fixed orders {order}", f"cutoff {_num(cutoff)}"]


def _num(x: float) -> str:
    """A float in Flow* syntax that reads back exactly."""
    return repr(float(x))


def _affine(weights: np.ndarray, bias: float, sources: list) -> str:
    """sum_j w_j source_j + b, zero weights left out."""
    text = ""
    for w, s in zip(weights, sources):
        if w != 0.0:
            term = s if abs(w) == 1.0 else f"{_num(abs(w))} * {s}"
            text += (" - " if w < 0 else " + ") + term if text else ("-" if w < 0 else "") + term
    if bias != 0.0 or not text:
        text += (" - " if bias < 0 else " + ") + _num(abs(bias)) if text else _num(bias)
    return text


class _Writer:
    """Modes and jumps of the automaton, written out by :meth:`text`."""

    def __init__(self, network: Network, states: list, outputs: list):
        self.network = network
        self.states = states
        self.outputs = outputs
        width = max(layer.n_out for layer in network.layers)
        self.z = [f"_z{i + 1}" for i in range(width)]
        self.a = [f"_a{i + 1}" for i in range(width)]
        self.extra: list = []  # step counter and temporaries
        self.modes: dict = {}  # name -> (ode {var: rhs}, dwell)
        self.jumps: list = []  # (source, target, guard atoms, {var: reset})
        self.time = 0.0
        self.jumps_per_run = 0
        self.start = "_start"
        self.exit_guard: list = []  # the guard of the jump out of the last layer
        for index, layer in enumerate(network.layers, start=1):
            bad = sorted({a for a in layer.activations if a not in ("sigmoid", "tanh", "identity")})
            if bad:
                raise InputError(
                    f"network {network.name!r}, layer {index}: {bad} neurons have no Verisig ODE; the Flow* export "
                    "covers sigmoid, tanh and identity neurons (Verisig 1.0's translation)"
                )

    def mode(self, name: str, ode: dict, dwell: float) -> None:
        self.modes[name] = (ode, dwell)

    def network_modes(self, entry_guard: list) -> str:
        """The start mode and one mode per layer; returns the last layer's mode."""
        self.mode(self.start, {}, 0.0)
        sources, previous, guard = list(self.network.input_names), self.start, entry_guard
        for index, layer in enumerate(self.network.layers, start=1):
            smooth = [i for i, a in enumerate(layer.activations) if a != "identity"]
            reset = {"clock": "0"}
            ode = {}
            for i, activation in enumerate(layer.activations):
                pre = _affine(layer.weight[i], float(layer.bias[i]), sources)
                if activation == "identity":
                    reset[self.z[i]] = pre
                    continue
                reset[self.a[i]] = pre
                reset[self.z[i]] = "0.5" if activation == "sigmoid" else "0"
                z, a = self.z[i], self.a[i]
                ode[z] = f"{a} * {z} * (1 - {z})" if activation == "sigmoid" else f"{a} * (1 - {z} * {z})"
            name = f"layer{index}"
            self.mode(name, ode, 1.0 if smooth else 0.0)
            self.jumps.append((previous, name, guard, reset))
            self.time += 1.0 if smooth else 0.0
            self.jumps_per_run += 1
            sources, previous = self.z[: layer.n_out], name
            guard = [f"clock = {'1' if smooth else '0'}"]
        self.exit_guard = guard
        return previous

    def output_resets(self) -> dict:
        """The outputs after the output map, from the last layer's neurons."""
        scale, offset = self.network.scale, self.network.offset
        reset = {"clock": "0"}
        for i, name in enumerate(self.outputs):
            w = np.zeros(self.network.n_out)
            w[i] = 1.0 if scale is None else scale[i]
            reset[name] = _affine(w, 0.0 if offset is None else float(offset[i]), self.z)
        return reset

    def network_only(self) -> None:
        last = self.network_modes(["clock = 0"])
        self.mode("_out", {}, 0.0)
        self.jumps.append((last, "_out", self.exit_guard, self.output_resets()))
        self.jumps_per_run += 1

    def closed_loop(self, plant, steps: int) -> None:
        self.extra.append("_k")
        self.mode("_done", {}, 0.0)
        last = self.network_modes(["clock = 0", f"_k <= {steps - 1}"])
        self.jumps.append((self.start, "_done", ["clock = 0", f"_k >= {steps}"], {}))
        updates = _PlantUpdate(plant)
        into_plant = self.output_resets()
        into_plant.update({t: "0" for t in updates.temporaries})
        self.extra += updates.temporaries
        self.mode("_reset_plant", dict(updates.rates), 1.0)
        self.jumps.append((last, "_reset_plant", self.exit_guard, into_plant))
        for guard, reset in updates.branches:
            reset = {**reset, "_k": "_k + 1", "clock": "0"}
            self.jumps.append(("_reset_plant", self.start, ["clock = 1", *guard], reset))
        self.time = steps * (self.time + 1.0)
        self.jumps_per_run = steps * (self.jumps_per_run + 2) + 1

    def text(self, box: dict, settings: list, output: str) -> str:
        variables = [*self.states, *self.outputs, *self.z, *self.a[: self._smooth_width()], *self.extra, "clock"]
        lines = ["hybrid reachability", "{", f"\tstate var {', '.join(variables)}", "", "\tsetting", "\t{"]
        lines += [f"\t\t{s}" for s in settings]
        lines += [
            f"\t\ttime {_num(self.time + 1.0)}",
            f"\t\tgnuplot octagon clock, {self.outputs[0]}",
            "\t\tprecision 100",
            f"\t\toutput {re.sub(r'[^A-Za-z0-9_]', '_', output) or 'model'}",
            f"\t\tmax jumps {self.jumps_per_run + 1}",
            "\t\tprint on",
            "\t}",
            "",
            "\tmodes",
            "\t{",
        ]
        for name, (ode, dwell) in self.modes.items():
            lines += [f"\t\t{name}", "\t\t{", "\t\t\tnonpoly ode", "\t\t\t{"]
            lines += [f"\t\t\t\t{v}' = {ode.get(v, '1' if v == 'clock' else '0')}" for v in variables]
            lines += ["\t\t\t}", "\t\t\tinv", "\t\t\t{", f"\t\t\t\tclock <= {'1' if dwell else '0'}", "\t\t\t}", "\t\t}"]
        lines += ["\t}", "", "\tjumps", "\t{"]
        for source, target, guard, reset in self.jumps:
            lines += [f"\t\t{source} -> {target}", f"\t\tguard {{ {' '.join(guard)} }}"]
            lines += ["\t\treset {"] + [f"\t\t\t{v}' := {e}" for v, e in reset.items()] + ["\t\t}", "\t\tinterval aggregation"]
        lines += ["\t}", "", "\tinit", "\t{", f"\t\t{self.start}", "\t\t{"]
        lines += [f"\t\t\t{v} in [{_num(box[v][0])}, {_num(box[v][1])}]" if v in box else f"\t\t\t{v} in [0, 0]" for v in variables]
        lines += ["\t\t}", "\t}", "}", ""]
        return "\n".join(lines)

    def _smooth_width(self) -> int:
        counts = [max((i + 1 for i, a in enumerate(layer.activations) if a != "identity"), default=0) for layer in self.network.layers]
        return max(counts)


# ----------------------------------------------------------------------------- plant updates


class _PlantUpdate:
    """A discrete plant's update as Flow* pieces: ``rates`` of the temporaries in ``_reset_plant``
    and ``branches``, one (guard atoms, resets) per combination of piecewise branches."""

    def __init__(self, plant):
        self.rates: dict = {}  # temporary -> Flow* expression it integrates (its final value)
        self._temps: dict = {}  # expression text -> temporary
        asts = {s: _parse_expr(e, f"the update of '{s}'") for s, e in zip(plant.states, plant.update)}
        nodes: dict = {}
        for ast in asts.values():
            _collect_piecewise(ast, nodes)
        if len(nodes) > _MAX_PIECEWISE:
            raise InputError(
                f"the plant update has {len(nodes)} piecewise parts (min, max, where, abs): {2 ** len(nodes)} jumps; "
                f"the export writes at most 2^{_MAX_PIECEWISE}"
            )
        keys = list(nodes)
        self.branches = []
        for choice in itertools.product((True, False), repeat=len(keys)):
            chosen = dict(zip(keys, choice))
            guard = []
            for key in keys:
                atom = self._condition(nodes[key], chosen, chosen[key])
                if atom is False:
                    break
                if atom is not True:
                    guard.append(atom)
            else:
                reset = {s: self._value(_choose(ast, chosen)) for s, ast in asts.items() if _text(ast) != s}
                self.branches.append((guard, reset))

    @property
    def temporaries(self) -> list:
        return list(self.rates)

    def _value(self, ast) -> str:
        """Flow* text for a reset: the expression if polynomial, else a temporary holding it."""
        text = _text(ast)
        if _polynomial(ast):
            return text
        if text not in self._temps:
            name = f"_t{len(self._temps) + 1}"
            self._temps[text] = name
            self.rates[name] = text
        return self._temps[text]

    def _condition(self, node, chosen: dict, holds: bool):
        """The guard atom saying node's branch `holds`, or True/False when it is constant."""
        kind = node[0]
        if kind == "where":
            lhs, op, rhs = node[1], node[2], node[3]
        elif kind == "call":  # abs(x) = x where x >= 0
            lhs, op, rhs = node[2], ">=", ("num", 0.0)
        else:  # min(a, b) = a where a <= b; max(a, b) = a where a >= b
            lhs, op, rhs = node[1], "<=" if kind == "min" else ">=", node[2]
        margin = _choose(("bin", "-", lhs, rhs), chosen)
        if not holds:
            op = {"<=": ">=", "<": ">=", ">=": "<=", ">": "<="}[op]
        value = _constant(margin)
        if value is not None:
            return value <= 0 if op in ("<=", "<") else value >= 0
        return f"{self._value(margin)} {'<=' if op in ('<=', '<') else '>='} 0"


def _parse_expr(expr, what: str):
    """The AST of an expression's printed form, checked to be Flow*: its functions Flow*'s
    (``abs`` and percver's ``min``, ``max``, ``where`` become branches), its powers whole."""
    text = repr(expr)
    if text.endswith(" ..."):
        raise InputError(f"{what} is too large to write out (its text exceeds the printer's limit)")
    try:
        ast = parse_expression(text, what)
    except ParseError as error:
        raise InputError(f"{what} cannot be written in Flow* syntax: {error}") from None
    _check_flowstar(ast, what)
    return ast


def _check_flowstar(ast, what: str) -> None:
    kind = ast[0]
    if kind == "call" and ast[1] not in _FLOWSTAR_FUNCTIONS and ast[1] != "abs":
        raise InputError(
            f"{what} cannot be written in Flow* syntax: Flow* has no {ast[1]}(); it knows {', '.join(sorted(_FLOWSTAR_FUNCTIONS))}"
        )
    if kind == "pow" and (ast[2][1] != int(ast[2][1]) or ast[2][1] < 0):
        raise InputError(f"{what} cannot be written in Flow* syntax: Flow* powers need a non-negative integer exponent, got {ast[2][1]!r}")
    for part in ast[1:]:
        if isinstance(part, tuple):
            _check_flowstar(part, what)


def _piecewise(ast) -> bool:
    return ast[0] in ("min", "max", "where") or (ast[0] == "call" and ast[1] == "abs")


def _collect_piecewise(ast, nodes: dict) -> None:
    """Every piecewise node of the AST, innermost first, by its text (equal for equal subexpressions)."""
    for part in ast[1:]:
        if isinstance(part, tuple):
            _collect_piecewise(part, nodes)
    if _piecewise(ast):
        nodes.setdefault(_text(ast), ast)


def _choose(ast, chosen: dict):
    """The AST with every piecewise node replaced by its chosen branch."""
    if _piecewise(ast):
        holds = chosen[_text(ast)]
        kind = ast[0]
        if kind == "where":
            return _choose(ast[4] if holds else ast[5], chosen)
        if kind == "call":  # abs
            inner = _choose(ast[2], chosen)
            return inner if holds else ("neg", inner)
        return _choose(ast[1] if holds else ast[2], chosen)
    return tuple(_choose(a, chosen) if isinstance(a, tuple) else a for a in ast)


def _constant(ast) -> Optional[float]:
    """The value of a constant AST, else None."""
    kind = ast[0]
    if kind == "num":
        return ast[1]
    if kind == "neg":
        value = _constant(ast[1])
        return None if value is None else -value
    if kind == "bin":
        a, b = _constant(ast[2]), _constant(ast[3])
        if a is None or b is None or (ast[1] == "/" and b == 0):
            return None
        return {"+": a + b, "-": a - b, "*": a * b, "/": a / b if b else 0.0}[ast[1]]
    return None


def _polynomial(ast) -> bool:
    """Whether Flow* can take the expression as a polynomial (resets and guards must be)."""
    kind = ast[0]
    if kind in ("num", "var"):
        return True
    if kind == "neg":
        return _polynomial(ast[1])
    if kind == "bin":
        return ast[1] in "+-*" and _polynomial(ast[2]) and _polynomial(ast[3])
    if kind == "pow":
        return _polynomial(ast[1])
    return False
