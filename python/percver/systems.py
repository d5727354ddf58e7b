"""Closed-loop systems: plants, perception/control stages, and their float simulation.

``ClosedLoop(plant, stages)`` wires signals by name: the plant's states, then each stage's
output (a scalar or a vector signal such as an image). The same object is simulated in float
(falsification, plots, metrics) and compiled for the Rust engine (verification), so both see one
definition of every component.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError
from percver.expr import Expr, ExprLike, as_expr, name_of


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
    """A continuous-time plant ``x' = f(x, u)`` with the inputs held over each control period."""

    def __init__(self, rhs: Mapping[Union[Expr, str], ExprLike], inputs: Sequence[Union[Expr, str]] = (), *, period: float,
                 step: Optional[float] = None, remainder: float = 1e-4):
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

    def advance(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """States after one period from the rows of x with the inputs u held (scipy, tight tolerances)."""
        from scipy.integrate import solve_ivp

        n, count = len(self.states), len(x)
        names = self.states + self.inputs

        def f(_t, flat):
            s = flat.reshape(n, count).T
            return _core.eval_float(self.rhs, names, np.ascontiguousarray(np.hstack([s, u]))).T.reshape(-1)

        sol = solve_ivp(f, (0.0, self.period), x.T.reshape(-1), method="DOP853", rtol=1e-11, atol=1e-12)
        if not sol.success:
            raise InputError(f"float simulation of the plant failed: {sol.message}")
        return sol.y[:, -1].reshape(n, count).T


@dataclass
class Stage:
    """One block of the perception-control chain: ``output = scale * component(inputs) + offset``.

    ``component`` is a :class:`percver.networks.Network` or an expression (or a list of them)
    over the input names; ``inputs`` are signal names (states or earlier outputs), concatenated.
    """

    component: object
    inputs: Sequence[Union[Expr, str]]
    output: str
    scale: Optional[Union[float, Sequence[float]]] = None
    offset: Optional[Union[float, Sequence[float]]] = None
    name: Optional[str] = None
    input_names: list = field(init=False)

    def __post_init__(self):
        from percver.networks import Network

        self.input_names = [name_of(i) for i in self.inputs]
        if not isinstance(self.output, str) or not self.output:
            raise InputError("a stage's output must be a signal name, e.g. output='u'")
        if isinstance(self.component, Network):
            if self.scale is not None or self.offset is not None:
                self.component = _with_output_map(self.component, self.scale, self.offset)
        else:
            exprs = self.component if isinstance(self.component, (list, tuple)) else [self.component]
            exprs = [as_expr(e) for e in exprs]
            if self.scale is not None or self.offset is not None:
                scale = np.broadcast_to(np.asarray(1.0 if self.scale is None else self.scale, float), (len(exprs),))
                offset = np.broadcast_to(np.asarray(0.0 if self.offset is None else self.offset, float), (len(exprs),))
                exprs = [e * float(s) + float(o) for e, s, o in zip(exprs, scale, offset)]
            self.component = exprs
        self.name = self.name or self.output

    @property
    def is_network(self) -> bool:
        from percver.networks import Network

        return isinstance(self.component, Network)

    @property
    def width(self) -> int:
        return self.component.n_out if self.is_network else len(self.component)


def _with_output_map(net, scale, offset):
    """The network followed by y -> scale * y + offset (composed with its own output map)."""
    from percver.networks import Network

    n = net.n_out
    s = np.broadcast_to(np.asarray(1.0 if scale is None else scale, float), (n,))
    o = np.broadcast_to(np.asarray(0.0 if offset is None else offset, float), (n,))
    s1 = np.ones(n) if net.scale is None else np.asarray(net.scale, float)
    o1 = np.zeros(n) if net.offset is None else np.asarray(net.offset, float)
    return Network(net.layers, scale=s * s1, offset=s * o1 + o, name=net.name, source=net.source)


class ClosedLoop:
    """``plant`` plus ``stages`` evaluated in order each step; the plant reads the stage outputs."""

    def __init__(self, plant: Union[Discrete, Continuous], stages: Sequence[Stage] = ()):
        if not isinstance(plant, (Discrete, Continuous)):
            raise InputError("plant must be pv.Discrete(...) or pv.Continuous(...)")
        self.plant = plant
        self.stages = list(stages)
        self.states = list(plant.states)
        # Signal name -> indices in the environment (state first, then stage outputs).
        self.signals: dict = {s: [i] for i, s in enumerate(self.states)}
        self.env_names = list(self.states)
        self.stage_inputs = []
        for k, stage in enumerate(self.stages):
            indices = []
            for name in stage.input_names:
                if name not in self.signals:
                    raise InputError(
                        f"stage {k + 1} ('{stage.name}') reads '{name}', which is neither a state nor an earlier output "
                        f"(known: {', '.join(self.signals)})"
                    )
                indices += self.signals[name]
            n_in = stage.component.n_in if stage.is_network else None
            if n_in is not None and n_in != len(indices):
                parts = " + ".join(f"{n} ({len(self.signals[n])})" for n in stage.input_names)
                raise InputError(f"stage {k + 1} ('{stage.name}') takes {n_in} inputs but is wired to {parts} = {len(indices)}")
            if not stage.is_network:
                names = [self.env_names[i] for i in indices]
                for e in stage.component:
                    unknown = set(e.variables()) - set(names)
                    if unknown:
                        raise InputError(f"stage {k + 1} ('{stage.name}') uses {sorted(unknown)}, which are not among its inputs {stage.input_names}")
            if stage.output in self.signals:
                raise InputError(f"signal '{stage.output}' is defined twice")
            start = len(self.env_names)
            width = stage.width
            self.signals[stage.output] = list(range(start, start + width))
            self.env_names += [stage.output] if width == 1 else [f"{stage.output}_{i}" for i in range(width)]
            self.stage_inputs.append(indices)
        missing = [u for u in plant.inputs if u not in self.signals]
        if missing:
            raise InputError(f"the plant's inputs {missing} are not produced by any stage (outputs: {[s.output for s in self.stages]})")
        used = plant.update if isinstance(plant, Discrete) else plant.rhs
        allowed = set(self.env_names) if isinstance(plant, Discrete) else set(plant.states) | set(plant.inputs)
        for e in used:
            unknown = set(e.variables()) - allowed
            if unknown:
                raise InputError(f"the plant uses {sorted(unknown)}, which are neither states nor its declared inputs")
        if isinstance(plant, Continuous):
            wide = [u for u in plant.inputs if len(self.signals[u]) != 1]
            if wide:
                raise InputError(f"continuous plant inputs must be scalar signals; {wide} are vectors")

    def _stage_float(self, k: int, env: np.ndarray) -> np.ndarray:
        stage = self.stages[k]
        x = env[:, self.stage_inputs[k]]
        if stage.is_network:
            return np.atleast_2d(stage.component(x)).reshape(len(env), -1)
        names = [self.env_names[i] for i in self.stage_inputs[k]]
        return _core.eval_float(stage.component, names, np.ascontiguousarray(x))

    def step_float(self, x: np.ndarray) -> np.ndarray:
        """One step of the loop for a batch of states (N x n)."""
        env = np.asarray(x, dtype=float)
        for k in range(len(self.stages)):
            env = np.concatenate([env, self._stage_float(k, env)], axis=1)
        if isinstance(self.plant, Continuous):
            u = env[:, [self.signals[i][0] for i in self.plant.inputs]]
            return self.plant.advance(env[:, : len(self.states)], u)
        return _core.eval_float(self.plant.update, self.env_names, np.ascontiguousarray(env))

    def simulate(self, x0: np.ndarray, steps: int) -> np.ndarray:
        """Trajectories (N x (steps + 1) x n) from the rows of ``x0``."""
        x = np.atleast_2d(np.asarray(x0, dtype=float))
        out = np.empty((len(x), steps + 1, len(self.states)))
        out[:, 0] = x
        for t in range(steps):
            x = self.step_float(x)
            out[:, t + 1] = x
        return out

    def compile(self, *, safe, goal, within: bool, steps: int):
        """The Rust form of the loop with its property."""
        stages = []
        for k, stage in enumerate(self.stages):
            if stage.is_network:
                stages.append((stage.component._core(), self.stage_inputs[k]))
            else:
                stages.append(((stage.component, [self.env_names[i] for i in self.stage_inputs[k]]), self.stage_inputs[k]))
        if isinstance(self.plant, Continuous):
            pl = self.plant
            zero = as_expr(0.0)
            plant = (pl.rhs + [zero] * len(pl.inputs), pl.states + pl.inputs, [self.signals[u][0] for u in pl.inputs],
                     pl.period, pl.step, pl.remainder)
        else:
            plant = self.plant.update
        return _core.ClosedLoop(self.states, stages, self.env_names, plant, safe, goal, within, steps)
