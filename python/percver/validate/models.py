"""What can be compared with measurements: sensor models and dynamics models, each carrying effects.

A model turns the rows of a ``Measurements`` object into an ``Evaluation`` (the inputs it
needs, what was measured, per-dimension weights) and predicts from those inputs with its
stack of effects. Keeping the inputs apart from the prediction lets fitting re-run only the
prediction while it varies an effect's parameters.

Dynamics models wrap any *plant* with ``state_names``, ``control_names`` and
``step(states, controls) -> next_states`` (N x n, N x p -> N x n). ``FunctionPlant`` builds
one from a function; ``SystemPlant`` adapts the ``pv.Discrete`` and ``pv.Continuous`` plants of
``percver.systems`` (one update, or one control period), which can be passed directly.
"""

from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass, field, replace
from typing import Callable, Protocol, Sequence

import numpy as np

from percver.errors import InputError, MeasurementError

# Control history kept per one-step pair: enough for the largest actuator delay effect.
HISTORY = 6


class BatchCache:
    """Results of an expensive canonical computation (ray casting, rendering) for recent batches.

    Fitting re-predicts the same states many times while only cheap effects change, through
    many copies of one model; the copies share this cache. An entry is found by the identity
    of the states array (kept alive by the entry), and used only if the array's contents still
    hash as they did when it was stored: an array changed in place between two calls is the
    same object with a different value, and must not get the old value's result.
    """

    def __init__(self, size: int = 4):
        self.size = size
        self.entries = []

    def get(self, states, key, compute):
        digest = None
        for entry_states, entry_digest, entry_key, value in self.entries:
            if entry_states is states and entry_key == key:
                digest = digest or _digest(states)
                if entry_digest == digest:
                    return value
        value = compute()
        self.entries = [(states, digest or _digest(states), key, value)] + [e for e in self.entries if e[0] is not states or e[2] != key][
            : self.size - 1
        ]
        return value


def _digest(array: np.ndarray) -> bytes:
    return (
        hashlib.blake2b(np.ascontiguousarray(array).view(np.uint8), digest_size=16).digest() + repr((array.shape, array.dtype.str)).encode()
    )


@dataclass(frozen=True)
class Evaluation:
    """The rows of a data set as one model sees them.

    ``states`` (model order) locate each row in state space for ``Report.where``; ``inputs``
    are what ``Model.predict_inputs`` takes; ``weights`` scale each measured dimension so
    that residuals of different units add up (all ones for sensors).
    """

    rows: np.ndarray
    states: np.ndarray
    inputs: dict
    measured: np.ndarray
    weights: np.ndarray
    groups: np.ndarray | None
    has_history: bool = False
    # Per-row quantities of the measurement (not of the state) in which failures are localised
    # too, e.g. a row's step in its run.
    row_features: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.rows)

    def subset(self, index) -> "Evaluation":
        return replace(
            self,
            rows=self.rows[index],
            states=self.states[index],
            inputs={key: value[index] for key, value in self.inputs.items()},
            measured=self.measured[index],
            groups=None if self.groups is None else self.groups[index],
            row_features={key: value[index] for key, value in self.row_features.items()},
        )


class Model:
    """Base of every comparable model: names, an immutable stack of effects, prediction."""

    kind = "generic"

    def __init__(self, state_names: Sequence[str], measurement_names: Sequence[str], effects=()):
        self.state_names = tuple(state_names)
        self.measurement_names = tuple(measurement_names)
        self.effects = tuple(effects)

    # ---------------------------------------------------------------- effects
    def with_effect(self, effect) -> "Model":
        """A new model with ``effect`` (an ``Effect`` or a ranked ``Candidate``) composed in.

        The effect goes after every effect of the same or an earlier physical ``stage``, so a
        contrast found after a blur still acts before it, as light does before motion.
        """
        effect = getattr(effect, "effect", effect)
        kinds = getattr(effect, "kinds", None)
        if kinds is None:
            raise InputError(f"with_effect needs an effect from percver.validate.effects, got {type(effect).__name__}")
        if self.kind not in kinds:
            raise InputError(f"effect '{effect.name}' applies to {'/'.join(kinds)} models, not to a {self.kind} model")
        index = self.insertion_index(effect)
        return self.with_effects(self.effects[:index] + (effect,) + self.effects[index:])

    def insertion_index(self, effect) -> int:
        """Where ``with_effect`` puts ``effect`` in the stack."""
        later = [i for i, e in enumerate(self.effects) if e.stage > effect.stage]
        return later[0] if later else len(self.effects)

    def with_effects(self, effects) -> "Model":
        """A copy with exactly ``effects`` (the original is unchanged)."""
        twin = copy.copy(self)
        twin.effects = tuple(effects)
        return twin

    @property
    def deterministic_effects(self):
        return tuple(e for e in self.effects if not e.stochastic)

    @property
    def stochastic_effects(self):
        return tuple(e for e in self.effects if e.stochastic)

    # ---------------------------------------------------------------- prediction
    def evaluate(self, data) -> Evaluation:
        raise NotImplementedError

    def predict_inputs(self, inputs: dict) -> np.ndarray:
        """Expected measurements for ``inputs`` of an ``Evaluation`` (deterministic effects only)."""
        raise NotImplementedError

    def sample_inputs(self, inputs: dict, rng=None) -> np.ndarray:
        """Random measurements: the prediction passed through the stochastic effects."""
        rng = np.random.default_rng(rng)
        values = self.predict_inputs(inputs)
        for effect in self.stochastic_effects:
            values = effect.sample(values, rng, self)
        return values

    def accounted(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """Entries that a stochastic effect of the model explains (e.g. a dropped LiDAR ray)."""
        mask = np.zeros(measured.shape, dtype=bool)
        for effect in self.stochastic_effects:
            mask |= effect.accounts(predicted, measured, self)
        return mask

    def clip(self, values: np.ndarray) -> np.ndarray:
        """The physical range of a measurement (used after random effects)."""
        return values

    # ---------------------------------------------------------------- where
    def features(self, states: np.ndarray) -> dict:
        """Named quantities of each state in which failures are localised (states by default)."""
        return {name: states[:, j] for j, name in enumerate(self.state_names)}

    @property
    def region_variables(self) -> tuple:
        return self.state_names[:2]

    def describe(self) -> str:
        effects = ", ".join(repr(e) for e in self.effects) or "no effects"
        return f"{type(self).__name__} ({effects})"

    def __repr__(self) -> str:
        return self.describe()


class SensorModel(Model):
    """A model of what a sensor measures in a state: ``predict(states) -> measurements``."""

    def predict(self, states) -> np.ndarray:
        states = np.atleast_2d(np.asarray(states, dtype=float))
        if states.shape[1] != len(self.state_names):
            raise InputError(
                f"predict expects states with {len(self.state_names)} columns {list(self.state_names)}, got shape {states.shape}"
            )
        return self.predict_inputs({"states": states})

    def sample(self, states, rng=None) -> np.ndarray:
        """Random measurements in ``states``, including noise-like effects."""
        return self.sample_inputs({"states": np.atleast_2d(np.asarray(states, dtype=float))}, rng)

    def evaluate(self, data) -> Evaluation:
        where = f" in {data.source}" if data.source else ""
        if data.measurements is None:
            raise MeasurementError(f"the data{where} has no 'measurements' to compare a sensor model with")
        count = len(self.measurement_names)
        if data.measurements.shape[1] != count:
            raise MeasurementError(
                f"the data{where} has {data.measurements.shape[1]} measurement columns but the model predicts "
                f"{count} ({self.measurement_names[0]} ... {self.measurement_names[-1]}): measure the same dimensions"
            )
        generic = tuple(f"y{i}" for i in range(count))
        if data.measurement_names not in (generic, self.measurement_names):
            unknown = [n for n in data.measurement_names if n not in self.measurement_names][:5]
            raise MeasurementError(
                f"measurement names{where} {unknown} are unknown to the model, which names "
                f"{list(self.measurement_names[:5])}...: rename them with measurement_names=..."
            )
        states = data.state_matrix(self.state_names)
        return Evaluation(
            rows=np.arange(len(data)),
            states=states,
            inputs={"states": states},
            measured=data.measurements,
            weights=np.ones(count),
            groups=data.groups,
        )


class FunctionSensor(SensorModel):
    """Any function of the states (a ``Network``, an ``Expr`` evaluator, a simulator) as a sensor model."""

    def __init__(self, function: Callable, state_names, measurement_names, effects=()):
        super().__init__(state_names, measurement_names, effects)
        self.function = function

    def predict_inputs(self, inputs):
        values = np.asarray(self.function(inputs["states"]), dtype=float)
        return values.reshape(len(inputs["states"]), -1)


class Plant(Protocol):
    """What a dynamics model needs from a plant; ``pv.Discrete`` satisfies it."""

    state_names: Sequence[str]
    control_names: Sequence[str]

    def step(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray: ...


class FunctionPlant:
    """A discrete-time plant from ``step(states, controls) -> next_states`` on N x n, N x p arrays.

    ``velocity_names`` tells the drag and friction effects which states are velocities.
    """

    def __init__(self, step: Callable, state_names, control_names, *, velocity_names=None):
        self._step = step
        self.state_names = tuple(state_names)
        self.control_names = tuple(control_names)
        self.velocity_names = None if velocity_names is None else tuple(velocity_names)

    def step(self, states, controls):
        return np.asarray(self._step(states, controls), dtype=float).reshape(np.shape(states))

    def __repr__(self) -> str:
        return f"FunctionPlant(states={list(self.state_names)}, controls={list(self.control_names)})"


class SystemPlant:
    """A ``pv.Discrete`` plant (one update) or ``pv.Continuous`` plant (one control period, inputs
    held) on float batches, with its states and inputs as state and control names."""

    def __init__(self, system):
        self.system = system
        self.state_names = tuple(system.states)
        self.control_names = tuple(system.inputs)

    def step(self, states, controls):
        from percver.expr import evaluate
        from percver.systems import Continuous

        states = np.asarray(states, dtype=float)
        controls = np.asarray(controls, dtype=float).reshape(len(states), -1)
        if isinstance(self.system, Continuous):
            return self.system.advance(states, controls)
        columns = dict(zip(self.state_names + self.control_names, np.column_stack([states, controls]).T))
        return evaluate(self.system.update, columns).reshape(states.shape)

    def __repr__(self) -> str:
        return f"{type(self.system).__name__}(states={list(self.state_names)}, inputs={list(self.control_names)})"


def _as_plant(plant):
    from percver.systems import Continuous, Discrete

    return SystemPlant(plant) if isinstance(plant, (Discrete, Continuous)) else plant


_VELOCITY_WORDS = ("v", "vel", "velocity", "speed")


class DynamicsModel(Model):
    """One-step prediction of a plant: (state_k, control_k and earlier controls) -> state_{k+1}.

    Effects act before the plant's step: actuator effects on the control history, drag and
    friction on the velocity states over one period (first-order operator splitting, exact
    when the plant's velocity update is additive, as in Mountain Car).
    """

    kind = "dynamics"

    def __init__(self, plant: Plant, *, velocity=None, effects=()):
        plant = _as_plant(plant)
        for attribute in ("state_names", "control_names", "step"):
            if not hasattr(plant, attribute):
                raise InputError(
                    f"a plant needs state_names, control_names and step(states, controls); "
                    f"{type(plant).__name__} has no '{attribute}' (wrap a function with FunctionPlant)"
                )
        super().__init__(plant.state_names, plant.state_names, effects)
        self.plant = plant
        self.control_names = tuple(plant.control_names)
        velocity = velocity or getattr(plant, "velocity_names", None)
        if velocity is None:
            velocity = [n for n in self.state_names if n.lower() in _VELOCITY_WORDS or n.lower().startswith("v_")]
        velocity = (velocity,) if isinstance(velocity, str) else tuple(velocity)
        unknown = [n for n in velocity if n not in self.state_names]
        if unknown:
            raise InputError(f"velocity states {unknown} are not states of the plant {list(self.state_names)}")
        self.velocity_names = velocity

    def evaluate(self, data) -> Evaluation:
        pairs = data.transitions(history=HISTORY - 1)
        where = f" in {data.source}" if data.source else ""
        order = data.state_index(self.state_names)
        count = len(self.control_names)
        if pairs.controls.shape[1] != count:
            raise MeasurementError(
                f"the data{where} has {pairs.controls.shape[1]} control columns but the plant takes {count} {list(self.control_names)}"
            )
        if data.control_names != tuple(f"u{i}" for i in range(count)):
            missing = [n for n in self.control_names if n not in data.control_names]
            if missing:
                raise MeasurementError(
                    f"the plant needs controls {missing} but the data{where} has {list(data.control_names)}: "
                    "rename them with control_names=..."
                )
            history = pairs.history[:, :, [data.control_names.index(n) for n in self.control_names]]
        else:
            history = pairs.history
        states = pairs.states[:, order]
        following = pairs.next_states[:, order]
        spread = np.std(following - states, axis=0)
        weights = 1.0 / np.where(spread > 0, spread, 1.0)
        return Evaluation(
            rows=pairs.rows,
            states=states,
            inputs={"states": states, "history": history},
            measured=following,
            weights=weights,
            groups=pairs.groups,
            has_history=pairs.has_history,
            row_features={} if pairs.groups is None or not pairs.has_history else {"step_in_run": _step_in_run(pairs)},
        )

    def predict(self, states, controls, history=None) -> np.ndarray:
        """Next states; ``history`` (N x lags x p, most recent first) feeds actuator delays."""
        states = np.atleast_2d(np.asarray(states, dtype=float))
        controls = np.asarray(controls, dtype=float).reshape(len(states), -1)
        if history is None:
            history = np.repeat(controls[:, None, :], HISTORY, axis=1)
        return self.predict_inputs({"states": states, "history": np.asarray(history, dtype=float)})

    def predict_inputs(self, inputs):
        history = inputs["history"]
        states = inputs["states"]
        for effect in self.deterministic_effects:
            history = effect.actuate(history)
            states = effect.pre_step(states, self)
        return np.asarray(self.plant.step(states, history[:, 0, :]), dtype=float).reshape(states.shape)


def _step_in_run(pairs) -> np.ndarray:
    """Each pair's step in its run (0: the run's first pair, whose earlier controls were not measured)."""
    first = {}
    for group, row in zip(pairs.groups.tolist(), pairs.rows.tolist()):
        first.setdefault(group, row)
    return pairs.rows - np.array([first[g] for g in pairs.groups.tolist()])


def _expression_function(model):
    """An ``Expr`` or a list of them (one per measurement, over state names) as a function of a
    states matrix whose columns carry the expressions' variable names; anything else unchanged."""
    from percver.expr import Expr, evaluate

    exprs = model if isinstance(model, (list, tuple)) else [model]
    if not exprs or not all(isinstance(e, Expr) for e in exprs):
        return model
    names = sorted({name for e in exprs for name in e.variables()})

    def function(states):
        return evaluate(list(exprs), dict(zip(function.state_names, np.asarray(states, dtype=float).T)))

    function.state_names = tuple(names)
    return function


def as_model(model, data=None) -> Model:
    """Accept a percver model, a plant (``pv.Discrete``, ``pv.Continuous`` or one with ``step``), an
    object with ``predict`` and names (a ``Network`` takes the data's names), an ``Expr`` or list
    of them over state names, or a bare function."""
    if isinstance(model, Model):
        return model
    plant = _as_plant(model)
    if hasattr(plant, "step") and hasattr(plant, "state_names"):
        return DynamicsModel(plant)
    model = _expression_function(model)
    state_names = getattr(model, "state_names", None)
    measurement_names = getattr(model, "measurement_names", None)
    if data is not None:
        state_names = state_names or data.state_names
        measurement_names = measurement_names or data.measurement_names
    function = getattr(model, "predict", None) or (model if callable(model) else None)
    if function is None or state_names is None or measurement_names is None:
        raise InputError(
            f"cannot compare a {type(model).__name__}: give a percver model, a plant with state_names, "
            "control_names and step(), or a function of the states with state and measurement names"
        )
    return FunctionSensor(function, state_names, measurement_names)
