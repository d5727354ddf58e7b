"""Closed-loop systems: plants, perception/control stages, and their float simulation.

``ClosedLoop(plant, stages)`` wires signals by name: the plant's states, then each stage's
output (a scalar or a vector signal such as an image). The same object is simulated in float
(falsification, plots, metrics) and compiled for the Rust engine (verification), so both see one
definition of every component.
"""

from __future__ import annotations

import operator
import re
import warnings
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError
from percver.expr import Condition, Expr, ExprLike, as_expr, name_of
from percver.sets import Box, BoxLike


_CONSTANTS = "_constants"  # the signal of the stages' constant inputs


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)


class InputRangeWarning(UserWarning):
    """The initial set leaves the input range a stage declares (``Stage(domain=...)``): the
    component is used where it was not made (trained, calibrated) for."""


_COMPARISONS = {"<=": operator.le, ">=": operator.ge, "<": operator.lt, ">": operator.gt}


def condition(text: str) -> Condition:
    """``"p >= 0.45"`` as a condition: two expressions in Flow* syntax and one of < <= > >=."""
    parts = re.split(r"(<=|>=|<|>)", text)
    if len(parts) != 3 or not parts[0].strip() or not parts[2].strip():
        raise InputError(f"'{text}' is not one comparison such as 'p >= 0.45' (operators: <, <=, >, >=)")
    return _COMPARISONS[parts[1]](as_expr(parts[0].strip()), as_expr(parts[2].strip()))


class Discrete:
    """A discrete-time plant ``x[k+1] = update(x[k], inputs[k])``; noise parameters are states
    whose update is themselves (``d: d``)."""

    def __init__(self, update: Mapping[Union[Expr, str], ExprLike], inputs: Sequence[Union[Expr, str]] = ()):
        if not update:
            raise InputError("a plant needs at least one state update, e.g. {x: x + v}")
        self.states = [name_of(k) for k in update]
        self.update = [as_expr(v) for v in update.values()]
        self.inputs = [name_of(i) for i in inputs]
        clash = set(self.states) & set(self.inputs)
        if clash:
            raise InputError(f"{sorted(clash)} are declared both as states and as inputs")


class Continuous:
    """A continuous-time plant ``x' = f(x, u)`` with the inputs held over each control period.

    An input may be a vector signal (a network with several outputs, ``output="T"``): declare
    ``inputs=["T"]`` and read its components ``T_0, T_1, ...`` in the right-hand sides, or
    declare the components themselves, ``inputs=["T_0", "T_1"]``, as with ``pv.Discrete``."""

    def __init__(
        self,
        rhs: Mapping[Union[Expr, str], ExprLike],
        inputs: Sequence[Union[Expr, str]] = (),
        *,
        period: float,
        step: Optional[float] = None,
        remainder: float = 1e-4,
    ):
        if not period > 0:
            raise InputError(f"the control period must be positive, got {period}")
        self.states = [name_of(k) for k in rhs]
        self.rhs = [as_expr(v) for v in rhs.values()]
        self.inputs = [name_of(i) for i in inputs]
        self.period = float(period)
        self.step = float(step) if step is not None else self.period / 10
        if not 0 < self.step <= self.period:
            raise InputError(f"the integration step must be in (0, period], got {step}")
        self.remainder = float(remainder)

    def advance(
        self, x: np.ndarray, u: np.ndarray, parameters: Optional[dict] = None, inputs: Optional[Sequence[str]] = None
    ) -> np.ndarray:
        """States after one period from the rows of x with the inputs u held (scipy, tight
        tolerances); ``parameters`` maps an uncertain parameter's id to its value per row,
        ``inputs`` names u's columns (default: the declared inputs)."""
        from scipy.integrate import solve_ivp

        n, count = len(self.states), len(x)
        names = self.states + list(self.inputs if inputs is None else inputs)

        def f(_t, flat):
            s = flat.reshape(n, count).T
            return _core.eval_float(self.rhs, names, np.ascontiguousarray(np.hstack([s, u])), parameters).T.reshape(-1)

        sol = solve_ivp(f, (0.0, self.period), x.T.reshape(-1), method="DOP853", rtol=1e-11, atol=1e-12)
        if not sol.success:
            raise InputError(f"float simulation of the plant failed: {sol.message}")
        return sol.y[:, -1].reshape(n, count).T


def _constraints(conditions: Sequence[Condition], where: str) -> list:
    out = []
    for c in conditions:
        if isinstance(c, str):
            c = condition(c)
        if not isinstance(c, Condition):
            raise InputError(f"{where}: {c!r} is not a condition such as x >= 0 (or the text 'x >= 0')")
        out.append(c)
    return out


_COMPARE = {"<=": operator.le, "<": operator.lt, ">=": operator.ge, ">": operator.gt}


def _signed(c: Condition, value: np.ndarray) -> np.ndarray:
    """The condition's margin turned so that >= 0 means it holds (equality counts as holding)."""
    return value if c.op in (">=", ">") else -value


class Mode:
    """A mode of a :class:`Hybrid` plant: ``x' = rhs`` while ``invariant`` (conditions that all
    hold) holds; a state missing from ``rhs`` stays constant there."""

    def __init__(self, rhs: Mapping[Union[Expr, str], ExprLike], invariant: Sequence[Union[Condition, str]] = ()):
        self.rhs = {name_of(k): as_expr(v) for k, v in rhs.items()}
        self.invariant = _constraints(invariant, "invariant")


class Jump:
    """A jump of a :class:`Hybrid` plant from mode ``source`` to ``target`` (``None``: control
    returns to the controller and the period ends), possible whenever all of ``guard`` hold
    (forced then if ``urgent``; otherwise forced only by the source's invariant); ``reset`` gives
    new values of some states, the others keep theirs."""

    def __init__(
        self,
        source: str,
        target: Optional[str],
        guard: Sequence[Union[Condition, str]] = (),
        reset: Optional[Mapping[Union[Expr, str], ExprLike]] = None,
        urgent: bool = False,
    ):
        self.source, self.target, self.urgent = source, target, bool(urgent)
        self.guard = _constraints(guard, f"jump {source} -> {target}: guard")
        self.reset = {name_of(k): as_expr(v) for k, v in (reset or {}).items()}


class Hybrid:
    """A hybrid plant: each control period starts in mode ``start`` with the inputs held, flows
    through modes and jumps, and ends at a jump whose target is ``None``; the states then are the
    next step's. On its own (without a controller), :func:`percver.flowpipe.hybrid_flowpipe`
    computes its reach set up to a time horizon. Verification carries Taylor models through the jumps and follows every mode
    sequence the set may take (``max_splits`` bounds the branches; beyond, they are aggregated).
    A period fails if a run flows longer than ``max_time`` or jumps more than ``max_jumps`` times.
    """

    def __init__(
        self,
        modes: Mapping[str, Mode],
        jumps: Sequence[Jump],
        inputs: Sequence[Union[Expr, str]] = (),
        *,
        start: Optional[str] = None,
        max_time: float,
        step: float,
        remainder: float = 1e-4,
        max_jumps: int = 100,
    ):
        if not modes:
            raise InputError("a hybrid plant needs at least one mode, e.g. {'fly': pv.Mode({x: v, v: -9.81})}")
        self.modes = dict(modes)
        bad = [k for k, m in self.modes.items() if not isinstance(m, Mode)]
        if bad:
            raise InputError(f"modes {bad} must be pv.Mode(...)")
        self.jumps = list(jumps)
        self.inputs = [name_of(i) for i in inputs]
        self.start = start if start is not None else next(iter(self.modes))
        self.states = list(dict.fromkeys(n for m in self.modes.values() for n in m.rhs))
        for j in self.jumps:
            if not isinstance(j, Jump):
                raise InputError(f"jumps must be pv.Jump(...), got {j!r}")
            missing = [m for m in (j.source, j.target) if m is not None and m not in self.modes]
            if missing:
                raise InputError(f"jump {j.source} -> {j.target} names mode(s) {missing}; modes are {list(self.modes)}")
            unknown = set(j.reset) - set(self.states)
            if unknown:
                raise InputError(f"jump {j.source} -> {j.target} resets {sorted(unknown)}, which are not states ({self.states})")
        if self.start not in self.modes:
            raise InputError(f"start mode '{self.start}' is not one of {list(self.modes)}")
        clash = set(self.states) & set(self.inputs)
        if clash:
            raise InputError(f"{sorted(clash)} are declared both as states and as inputs")
        if not max_time > 0 or not 0 < step <= max_time:
            raise InputError(f"need max_time > 0 and an integration step in (0, max_time], got {max_time}, {step}")
        self.max_time, self.step, self.remainder, self.max_jumps = float(max_time), float(step), float(remainder), int(max_jumps)
        names = set(self.states) | set(self.inputs)
        for e in self.expressions():
            unknown = set(e.variables()) - names
            if unknown:
                raise InputError(f"the hybrid plant uses {sorted(unknown)}, which are neither its states nor its inputs")

    def with_constants(self, f, names: Sequence[str]) -> "Hybrid":
        """A copy whose expressions (right-hand sides, invariants, guards, resets) are mapped by
        ``f``, with states ``names`` that stay constant through the period: rate 0 in every mode,
        and no jump resets them (a parameter held over a run)."""

        def conditions(cs):
            return [_COMPARE[c.op](f(c.lhs), f(c.rhs)) for c in cs]

        zero = {n: as_expr(0.0) for n in names}
        modes = {k: Mode({**{s: f(e) for s, e in m.rhs.items()}, **zero}, conditions(m.invariant)) for k, m in self.modes.items()}
        jumps = [Jump(j.source, j.target, conditions(j.guard), {s: f(e) for s, e in j.reset.items()}, j.urgent) for j in self.jumps]
        return Hybrid(
            modes,
            jumps,
            self.inputs,
            start=self.start,
            max_time=self.max_time,
            step=self.step,
            remainder=self.remainder,
            max_jumps=self.max_jumps,
        )

    def rhs_of(self, mode: str) -> list:
        """The mode's right-hand sides in state order (0 for states it does not list)."""
        m = self.modes[mode]
        return [m.rhs.get(n, as_expr(0.0)) for n in self.states]

    def expressions(self) -> list:
        """Every expression of the plant (for checks, parameters and fingerprints)."""
        out = []
        for name, m in self.modes.items():
            out += self.rhs_of(name) + [c.margin() for c in m.invariant]
        for j in self.jumps:
            out += [c.margin() for c in j.guard] + list(j.reset.values())
        return out

    def signature(self) -> tuple:
        """The plant's structure and numbers, beside its expressions (for fingerprints)."""
        return (
            list(self.modes),
            [(j.source, j.target, [c.op for c in j.guard], list(j.reset), j.urgent) for j in self.jumps],
            [[c.op for c in m.invariant] for m in self.modes.values()],
            self.start,
            self.max_time,
            self.step,
            self.remainder,
            self.max_jumps,
        )

    def _core(self, input_indices: list) -> tuple:
        names = self.states + self.inputs
        zero = as_expr(0.0)
        order = list(self.modes)
        modes = [(n, self.rhs_of(n) + [zero] * len(self.inputs), [(c.margin(), c.op) for c in m.invariant]) for n, m in self.modes.items()]
        jumps = [
            (
                order.index(j.source),
                None if j.target is None else order.index(j.target),
                [(c.margin(), c.op) for c in j.guard],
                [j.reset.get(n, Expr.var(n)) for n in names] if j.reset else None,
                j.urgent,
            )
            for j in self.jumps
        ]
        return (names, modes, jumps, order.index(self.start), input_indices, self.max_time, self.step, self.remainder, self.max_jumps)

    def advance(self, x: np.ndarray, u: np.ndarray, parameters: Optional[dict] = None) -> np.ndarray:
        """States at the end of one period from the rows of x with the inputs u held (scipy DOP853
        with events, one run per row): a jump is taken as soon as its guard holds, the first listed
        when several do (one of the runs the plant allows)."""
        return np.array(
            [
                self._run(np.concatenate([xi, ui]), {k: v[r] for k, v in (parameters or {}).items()})
                for r, (xi, ui) in enumerate(zip(np.atleast_2d(x), np.atleast_2d(u)))
            ]
        ).reshape(len(x), len(self.states))

    def _run(self, z: np.ndarray, parameters: dict) -> np.ndarray:
        from scipy.integrate import solve_ivp

        names = self.states + self.inputs
        n = len(self.states)

        def values(exprs, z):
            if not exprs:
                return np.zeros(0)
            params = {k: np.array([v]) for k, v in parameters.items()} or None
            return _core.eval_float(exprs, names, np.ascontiguousarray(z.reshape(1, -1)), params)[0]

        def holds(conds, z, tol=1e-9):
            return all(_signed(c, v) >= -tol for c, v in zip(conds, values([c.margin() for c in conds], z)))

        mode, elapsed = self.start, 0.0
        for _ in range(self.max_jumps + 1):
            outgoing = [j for j in self.jumps if j.source == mode]
            taken = next((j for j in outgoing if holds(j.guard, z)), None)
            if taken is None:
                rhs = self.rhs_of(mode)
                inv = self.modes[mode].invariant

                def f(_t, y):
                    return np.concatenate([values(rhs, y), np.zeros(len(self.inputs))])

                def event(conds, sign):
                    def g(_t, y):
                        v = values([c.margin() for c in conds], y)
                        return sign * min(_signed(c, vi) for c, vi in zip(conds, v)) + (1e-9 if sign > 0 else 0.0)

                    g.terminal, g.direction = True, -1.0 if sign < 0 else 1.0
                    return g

                events = [event(j.guard, 1.0) for j in outgoing if j.guard]
                if inv:
                    events.append(event(inv, 1.0))
                    events[-1].direction = -1.0
                sol = solve_ivp(f, (0.0, self.max_time - elapsed), z, method="DOP853", rtol=1e-11, atol=1e-12, events=events)
                if not sol.success:
                    raise InputError(f"float simulation of the hybrid plant failed in mode '{mode}': {sol.message}")
                if sol.status != 1:
                    raise InputError(f"float simulation: the run is still in mode '{mode}' after {self.max_time} time units")
                z, elapsed = sol.y[:, -1], elapsed + sol.t[-1]
                taken = next((j for j in outgoing if holds(j.guard, z, 1e-7)), None)
                if taken is None:
                    raise InputError(f"float simulation: the run leaves the invariant of mode '{mode}' with no jump enabled")
            if taken.reset:
                new = values([taken.reset.get(v, Expr.var(v)) for v in names], z)
                z = np.asarray(new, float)
            if taken.target is None:
                return z[:n]
            mode = taken.target
        raise InputError(f"float simulation: more than {self.max_jumps} jumps in one period")


@dataclass
class Stage:
    """One block of the perception-control chain: ``output = scale * component(inputs) + offset``.

    ``component`` is a :class:`percver.networks.Network` or an expression (or a list of them)
    over the input names; ``inputs`` are signal names (states or earlier outputs), concatenated,
    or numbers: a constant input of a network (ACC's set speed, ``inputs=[30.0, 1.4, v, d]``).
    ``domain`` declares the range the component was made for, ``{input: (lo, hi)}`` over scalar
    inputs (e.g. a controller's training range); an initial set leaving it draws an
    :class:`InputRangeWarning` before verification starts.
    """

    component: object
    inputs: Sequence[Union[Expr, str]]
    output: str
    scale: Optional[Union[float, Sequence[float]]] = None
    offset: Optional[Union[float, Sequence[float]]] = None
    name: Optional[str] = None
    domain: Optional[Mapping[Union[Expr, str], Sequence[float]]] = None
    input_names: list = field(init=False)

    def __post_init__(self):
        from percver.networks import Network

        # A constant input has no name (None); ClosedLoop feeds it from its constants stage.
        self.constants = {j: float(i) for j, i in enumerate(self.inputs) if _is_number(i)}
        self.input_names = [None if j in self.constants else name_of(i) for j, i in enumerate(self.inputs)]
        if not isinstance(self.output, str) or not self.output:
            raise InputError("a stage's output must be a signal name, e.g. output='u'")
        self.name = self.name or self.output
        # A diagnosed sensor's Basis (its validated domain and residual bound), which verify reports on.
        self.validation = getattr(self.component, "validation", None)
        if isinstance(self.component, Network):
            if self.scale is not None or self.offset is not None:
                self.component = _with_output_map(self.component, self._output_map(self.component.n_out))
        else:
            if hasattr(self.component, "stages"):
                raise InputError(
                    f"stage '{self.name}': a {type(self.component).__name__} is a chain of stages (expressions, then a "
                    f"network): put *component.stages(output='{self.output}') among the loop's stages instead of one pv.Stage"
                )
            if self.constants:
                raise InputError(
                    f"stage '{self.name}': constant inputs {list(self.constants.values())} feed networks; "
                    "an expression can use the constant itself"
                )
            exprs = self.component if isinstance(self.component, (list, tuple)) else [self.component]
            exprs = [as_expr(e) for e in exprs]
            if self.scale is not None or self.offset is not None:
                scale, offset = self._output_map(len(exprs))
                exprs = [e * float(s) + float(o) for e, s, o in zip(exprs, scale, offset)]
            self.component = exprs
        self.domain = self._checked_domain()

    def _output_map(self, n: int) -> tuple:
        """``scale`` and ``offset`` as one value per output."""
        out = []
        for what, value, default in (("scale", self.scale, 1.0), ("offset", self.offset, 0.0)):
            v = np.asarray(default if value is None else value, float)
            if v.ndim > 1 or v.size not in (1, n):
                raise InputError(f"stage '{self.name}' has {n} outputs but {what} has {v.size} values; give one number or {n}")
            out.append(np.broadcast_to(v.reshape(-1), (n,)))
        return tuple(out)

    def _checked_domain(self) -> dict:
        domain = {}
        for key, pair in (self.domain or {}).items():
            name = name_of(key)
            if name not in self.input_names:
                raise InputError(f"stage '{self.name}': domain names '{name}', which is not among its inputs {self.input_names}")
            lo, hi = Box.coerce({name: pair}).bounds[0]
            domain[name] = (lo, hi)
        return domain

    @property
    def is_network(self) -> bool:
        from percver.networks import Network

        return isinstance(self.component, Network)

    @property
    def input_labels(self) -> list:
        """The inputs as written: signal names, constants as numbers."""
        return [n if n is not None else f"{self.constants[j]:g}" for j, n in enumerate(self.input_names)]

    @property
    def width(self) -> int:
        return self.component.n_out if self.is_network else len(self.component)


def _with_output_map(net, output_map):
    """The network followed by y -> scale * y + offset (composed with its own output map)."""
    from percver.networks import Network

    n = net.n_out
    s, o = output_map
    s1 = np.ones(n) if net.scale is None else np.asarray(net.scale, float)
    o1 = np.zeros(n) if net.offset is None else np.asarray(net.offset, float)
    return Network(
        net.layers, scale=s * s1, offset=s * o1 + o, name=net.name, source=net.source, input_names=net.input_names, domain=net.domain
    )


class ClosedLoop:
    """``plant`` plus ``stages`` evaluated in order each step; the plant reads the stage outputs."""

    def __init__(self, plant: Union[Discrete, Continuous, Hybrid], stages: Sequence[Stage] = ()):
        if not isinstance(plant, (Discrete, Continuous, Hybrid)):
            hint = (
                " (a pv.diagnose result gives one: pv.ClosedLoop(diagnosis.model, ...), or diagnosis.system(uncertainty='ci95'))"
                if type(plant).__module__.startswith("percver.validate")
                else ""
            )
            raise InputError(f"plant must be pv.Discrete(...), pv.Continuous(...) or pv.Hybrid(...){hint}")
        self.plant = plant
        self.states = list(plant.states)
        self.accumulators: list = []  # states added by with_accumulators (they start at 0)
        # States added by with_held_parameters: name -> (id, lo, hi) of the parameter (they start on its range).
        self.held: dict = {}
        # Signal name -> indices in the environment (state first, then stage outputs).
        self.signals: dict = {s: [i] for i, s in enumerate(self.states)}
        self.env_names = list(self.states)
        # The stages' constant inputs, one signal per distinct value, computed by a first stage
        # of constants (the engine's environment holds only states and stage outputs).
        values = self._constant_values = sorted({v for stage in stages for v in stage.constants.values()})
        self._constants = Stage(values, inputs=[], output=_CONSTANTS, name="constants") if values else None
        self.stages = ([self._constants] if values else []) + list(stages)
        self.stage_inputs = []
        for k, stage in enumerate(self.stages):
            self.stage_inputs.append(self._wire(k, stage))
        index = {name: i for i, name in enumerate(self.env_names)}
        missing = [u for u in plant.inputs if u not in self.signals and u not in index]
        if missing:
            raise InputError(f"the plant's inputs {missing} are not produced by any stage (outputs: {[s.output for s in self.stages]})")
        # The plant's inputs as scalar signals: a vector input is its components T_0, T_1, ...
        self.plant_inputs = [self.env_names[i] for u in plant.inputs for i in (self.signals[u] if u in self.signals else [index[u]])]
        used = plant.update if isinstance(plant, Discrete) else plant.expressions() if isinstance(plant, Hybrid) else plant.rhs
        allowed = set(self.env_names) if isinstance(plant, Discrete) else set(plant.states) | set(self.plant_inputs)
        for e in used:
            unknown = set(e.variables()) - allowed
            if unknown:
                raise InputError(
                    f"the plant uses {sorted(unknown)}, which are neither states nor its declared inputs{self._vector_hint(unknown)}"
                )
        if isinstance(plant, Hybrid):
            if not any(j.target is None for j in plant.jumps):
                raise InputError(
                    "no jump returns to the controller: give one with target None, e.g. pv.Jump('fly', None, guard=['c >= 0.1'])"
                )
            wide = [u for u in plant.inputs if len(self.signals.get(u, [0])) != 1]
            if wide:
                raise InputError(f"hybrid plant inputs must be scalar signals; {wide} are vectors")
        # Column maps of the float simulation, fixed once wired: a stage's consecutive inputs (an
        # image) are read as a view, not gathered; a discrete plant gets only the columns it reads.
        self._float_inputs = [slice(i[0], i[0] + len(i)) if i and i == list(range(i[0], i[0] + len(i))) else i for i in self.stage_inputs]
        names = {n for e in used for n in e.variables()}
        self._plant_reads = [i for i, n in enumerate(self.env_names) if n in names]

    def _wire(self, k: int, stage: Stage) -> list:
        """Checks stage k against the signals so far, adds its output; returns its input indices."""
        where = f"stage {k + 1} ('{stage.name}')"
        indices = []
        for j, name in enumerate(stage.input_names):
            if name is None:
                indices.append(self.signals[_CONSTANTS][self._constant_values.index(stage.constants[j])])
                continue
            if name not in self.signals:
                raise InputError(
                    f"{where} reads '{name}', which is neither a state nor an earlier output (known: {', '.join(self.signals)})"
                )
            indices += self.signals[name]
        wired = [self.env_names[i] for i in indices]
        if stage.is_network:
            net = stage.component
            if net.n_in != len(indices):
                parts = " + ".join(
                    f"{n} ({len(self.signals[n])})" if n is not None else f"{stage.constants[j]:g} (1)"
                    for j, n in enumerate(stage.input_names)
                )
                raise InputError(f"{where} takes {net.n_in} inputs but is wired to {parts} = {len(indices)}")
            # A network that names its inputs (not the default in0, in1, ...) must get those signals, in its order.
            # A constant input matches any name.
            if any(n != w and not re.fullmatch(r"in\d+", n) and not w.startswith(_CONSTANTS) for n, w in zip(net.input_names, wired)):
                raise InputError(
                    f"{where}: network '{net.name}' takes inputs ({', '.join(net.input_names)}) but is wired to ({', '.join(wired)}); "
                    "list the stage's inputs in the network's order, or rename them with net.with_input_names([...])"
                )
        else:
            for e in stage.component:
                unknown = set(e.variables()) - set(wired)
                if unknown:
                    raise InputError(f"{where} uses {sorted(unknown)}, which are not among its inputs {stage.input_names}")
        wide = [n for n in stage.domain if len(self.signals[n]) != 1]
        if wide:
            raise InputError(f"{where}: domain= bounds scalar inputs only; {wide} are vectors")
        if stage.output in self.signals:
            raise InputError(f"signal '{stage.output}' is defined twice")
        start = len(self.env_names)
        width = stage.width
        self.signals[stage.output] = list(range(start, start + width))
        self.env_names += [stage.output] if width == 1 else [f"{stage.output}_{i}" for i in range(width)]
        return indices

    def _vector_hint(self, names) -> str:
        wide = [n for n in sorted(names) if len(self.signals.get(n, [0])) > 1]
        return "".join(
            f"; '{n}' is a vector of {len(self.signals[n])}: use its components {n}_0 .. {n}_{len(self.signals[n]) - 1}" for n in wide
        )

    def with_accumulators(self, sums: Mapping[Union[Expr, str], ExprLike]) -> "ClosedLoop":
        """This loop with one more state per entry, ``name[k+1] = name[k] + expr(step k)``: a reward
        or cost summed along the run, e.g. ``{"r": -0.1 * u**2}``, where ``expr`` reads states and
        stage outputs. The sums are ordinary plant states, so the engine encloses them like any
        state and simulation tracks them; they start at 0 unless the initial set says otherwise.
        For a continuous plant the step's increment is a held input and the sum flows at
        increment / period, so it gains exactly the increment over each period.
        """
        added = {}
        for key, value in sums.items():
            name = name_of(key)
            if not re.fullmatch(r"[A-Za-z_]\w*", name):
                raise InputError(f"accumulator name '{name}' must be an identifier (letters, digits, _), e.g. 'reward'")
            if name in self.signals or name in added:
                raise InputError(f"accumulator '{name}' has the name of an existing signal; choose another name")
            e = as_expr(value)
            unknown = set(e.variables()) - set(self.env_names)
            if unknown:
                raise InputError(
                    f"accumulator '{name}' uses {sorted(unknown)}, which are neither states nor stage outputs "
                    f"({', '.join(self.env_names)}){self._vector_hint(unknown)}"
                )
            added[name] = e
        if not added:
            raise InputError("give accumulators as {name: expression}, e.g. {'r': -0.1 * u**2}")
        plant, stages = self.plant, [s for s in self.stages if s is not self._constants]
        if isinstance(plant, Hybrid):
            raise InputError("accumulators (reward=) are not supported with a hybrid plant; add the sum as a state of every mode")
        if isinstance(plant, Discrete):
            update = dict(zip(plant.states, plant.update))
            update.update({n: Expr.var(n) + e for n, e in added.items()})
            new_plant = Discrete(update, inputs=plant.inputs)
        else:
            rhs, inputs = dict(zip(plant.states, plant.rhs)), list(plant.inputs)
            for n, e in added.items():
                if e.variables():
                    rate = f"{n}__increment"
                    stages.append(Stage([e], inputs=self._signals_of(e), output=rate))
                    inputs.append(rate)
                    rhs[n] = Expr.var(rate) / plant.period
                else:
                    rhs[n] = e / plant.period
            new_plant = Continuous(rhs, inputs, period=plant.period, step=plant.step, remainder=plant.remainder)
        loop = ClosedLoop(new_plant, stages)
        loop.accumulators = self.accumulators + list(added)
        loop.held = dict(self.held)
        return loop

    def held_parameters(self) -> list:
        """The uncertain parameters held over a run (``pv.uncertain(..., per="run")``) that the
        plant or a stage reads, as ``(id, lo, hi)``, each once."""
        from percver.expr import held_parameters

        return held_parameters(self._expressions())

    def with_held_parameters(self) -> "ClosedLoop":
        """This loop with every parameter held over a run as a state of its own, ``param_k`` (k in
        the order of :meth:`held_parameters`), whose update is itself: the engine then carries it as
        one more Taylor-model variable, so the reach sets keep their dependency on it instead of
        taking a new value from its range at every step. ``held`` maps the new states to
        ``(id, lo, hi)``; :meth:`initial_box` starts them on their ranges."""
        found = self.held_parameters()
        if not found:
            return self
        taken, names, k = set(self.signals), [], 0
        for _ in found:
            while f"param_{k}" in taken:
                k += 1
            names.append(f"param_{k}")
            k += 1
        held = dict(zip(names, found))
        as_vars = {pid: Expr.var(n) for n, (pid, _, _) in held.items()}

        def plain(exprs):
            return [e.substitute({}, parameters=as_vars) for e in exprs]

        stages = []
        for stage in self.stages:
            if stage is self._constants:
                continue
            if stage.is_network:
                stages.append(stage)
                continue
            exprs = plain(stage.component)
            reads = [n for n in names if any(n in e.variables() for e in exprs)]
            stages.append(Stage(exprs, inputs=list(stage.inputs) + reads, output=stage.output, name=stage.name, domain=stage.domain))
        plant = self.plant
        if isinstance(plant, Discrete):
            update = dict(zip(plant.states, plain(plant.update)))
            update.update({n: Expr.var(n) for n in names})
            plant = Discrete(update, inputs=plant.inputs)
        elif isinstance(plant, Hybrid):
            plant = plant.with_constants(lambda e: plain([e])[0], names)
        else:
            rhs = dict(zip(plant.states, plain(plant.rhs)))
            rhs.update({n: as_expr(0.0) for n in names})
            plant = Continuous(rhs, plant.inputs, period=plant.period, step=plant.step, remainder=plant.remainder)
        loop = ClosedLoop(plant, stages)
        loop.accumulators = list(self.accumulators)
        loop.held = {**self.held, **held}
        return loop

    def _expressions(self) -> list:
        """Every expression of the plant and of the expression stages."""
        plant = self.plant
        exprs = list(plant.rhs if isinstance(plant, Continuous) else plant.expressions() if isinstance(plant, Hybrid) else plant.update)
        for stage in self.stages:
            if not stage.is_network:
                exprs += list(stage.component)
        return exprs

    def _signals_of(self, e: Expr) -> list:
        """The signals (in environment order) whose values ``e`` reads."""
        used = set(e.variables())
        return [s for s, idx in self.signals.items() if any(self.env_names[i] in used for i in idx)]

    def initial_box(self, init: BoxLike) -> Box:
        """``init`` as a box over the states, accumulators at 0 unless given; warns
        (:class:`InputRangeWarning`) where it leaves a stage's declared ``domain``."""
        if isinstance(init, Box):
            init = init.to_dict()
        if isinstance(init, Mapping):
            init = {
                **{a: (0.0, 0.0) for a in self.accumulators},
                **{n: (lo, hi) for n, (_, lo, hi) in self.held.items()},
                **{name_of(k): v for k, v in init.items()},
            }
        box = Box.coerce(init, self.states)
        for stage in self.stages:
            for name, (lo, hi) in stage.domain.items():
                if name in box.names and (box[name][0] < lo or box[name][1] > hi):
                    warnings.warn(
                        f"initial {name} in [{box[name][0]:g}, {box[name][1]:g}] leaves [{lo:g}, {hi:g}], the input range "
                        f"stage '{stage.name}' declares: its component is used outside the range it was made for",
                        InputRangeWarning,
                        stacklevel=3,
                    )
        return box

    def stage_float(self, k: int, env: np.ndarray, parameters: Optional[dict] = None) -> np.ndarray:
        """Stage k's outputs for a batch of environments (columns: the signals computed so far)."""
        stage = self.stages[k]
        x = env[:, self._float_inputs[k]]
        if stage.is_network:
            return np.atleast_2d(stage.component(x)).reshape(len(env), -1)
        names = [self.env_names[i] for i in self.stage_inputs[k]]
        return _core.eval_float(stage.component, names, np.ascontiguousarray(x), parameters)

    def parameters(self) -> list:
        """The uncertain parameters (``pv.uncertain``) the loop reads, as ``(id, lo, hi)``, each once."""
        found: dict = {}
        for e in self._expressions():
            for pid, lo, hi in e.parameters():
                found.setdefault(pid, (pid, lo, hi))
        return list(found.values())

    def step_float(self, x: np.ndarray, parameters: Optional[dict] = None) -> np.ndarray:
        """One step of the loop for a batch of states (N x n); ``parameters`` maps an uncertain
        parameter's id to its value in each run (a parameter not given takes its midpoint)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        env = np.empty((len(x), len(self.env_names)))  # every signal's column, filled stage by stage
        env[:, : x.shape[1]] = x
        for k in range(len(self.stages)):
            start = self.signals[self.stages[k].output][0]
            width = len(self.signals[self.stages[k].output])
            env[:, start : start + width] = self.stage_float(k, env, parameters)
        if isinstance(self.plant, Continuous):
            u = env[:, [self.env_names.index(i) for i in self.plant_inputs]]
            return self.plant.advance(env[:, : len(self.states)], u, parameters, self.plant_inputs)
        if isinstance(self.plant, Hybrid):
            u = env[:, [self.env_names.index(i) for i in self.plant_inputs]]
            return self.plant.advance(env[:, : len(self.states)], u, parameters)
        reads = self._plant_reads
        return _core.eval_float(self.plant.update, [self.env_names[i] for i in reads], np.ascontiguousarray(env[:, reads]), parameters)

    def simulate(self, x0: np.ndarray, steps: int, parameters: Optional[dict] = None) -> np.ndarray:
        """Trajectories (N x (steps + 1) x n) from the rows of ``x0``, each run with its own
        values of the uncertain parameters: ``{id: values}`` with one value per run (held for the
        whole run), or an N x steps array (a new value each step: a disturbance's sequence)."""
        x = np.atleast_2d(np.asarray(x0, dtype=float))
        drawn = {k: np.asarray(v, dtype=float) for k, v in (parameters or {}).items()}
        for k, v in drawn.items():
            if v.ndim == 2 and v.shape != (len(x), steps):
                raise InputError(
                    f"parameter {k}: per-step values must be an array of runs x steps ({len(x)} x {steps}), got shape {v.shape}"
                )
        out = np.empty((len(x), steps + 1, len(self.states)))
        out[:, 0] = x
        for t in range(steps):
            x = self.step_float(x, {k: v[:, t] if v.ndim == 2 else v for k, v in drawn.items()} if drawn else None)
            out[:, t + 1] = x
        return out

    def compile(self, *, safe, goal, within: bool, steps: int):
        """The Rust form of the loop with its property."""
        from percver.fusion import fuse
        from percver.networks import Network

        if not isinstance(self.plant, Discrete):
            reads = set(self.plant_inputs)
        else:
            reads = {name for e in self.plant.update for name in e.variables()}
        fused, env = fuse(self.env_names, self.stage_inputs, self.stages, reads)
        stages = []
        for stage in fused:
            if isinstance(stage.component, Network):
                stages.append((stage.component._core(), stage.inputs))
            else:
                stages.append(((stage.component, [env[i] for i in stage.inputs]), stage.inputs))
        if isinstance(self.plant, Continuous):
            pl = self.plant
            zero = as_expr(0.0)
            plant = (
                pl.rhs + [zero] * len(self.plant_inputs),
                pl.states + self.plant_inputs,
                [env.index(u) for u in self.plant_inputs],
                pl.period,
                pl.step,
                pl.remainder,
            )
        elif isinstance(self.plant, Hybrid):
            plant = self.plant._core([env.index(u) for u in self.plant_inputs])
        else:
            plant = self.plant.update
        return _core.ClosedLoop(self.states, stages, env, plant, safe, goal, within, steps)
