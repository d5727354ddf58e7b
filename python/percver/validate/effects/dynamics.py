"""Dynamics effects: forces and actuator behaviour that a plant model may be missing.

They act before the plant's step: actuator effects on the control history (N x lags x p,
most recent first), drag and friction on one velocity state over one control period.
Coefficients are per period, so they do not depend on the plant's time step.
"""

from __future__ import annotations

import numpy as np

from percver.validate.effects.base import Effect


class DynamicsEffect(Effect):
    """Base of dynamics effects. ``actuate``/``pre_step`` act on float batches; ``actuate_expr``/
    ``pre_step_expr`` are the same maps on expressions (``p`` holds the parameters as numbers or
    ``pv.uncertain`` ranges), so a diagnosed plant is verified with what was fitted."""

    kinds = ("dynamics",)
    # Parameters the expression form keeps at their fitted value (never an uncertain range).
    fixed: tuple = ()

    def lags(self) -> int:
        """Earlier controls the expression form reads (kept as extra states of the plant)."""
        return 0

    def actuate(self, history):
        return history

    def pre_step(self, states, model):
        return states

    def actuate_expr(self, history, p):
        """``history``: per lag (current first) a list of control expressions."""
        return history

    def pre_step_expr(self, states, p):
        """``states``: state name -> expression at the start of the period."""
        return states


class _Resistance(DynamicsEffect):
    """Shared machinery of drag and friction: one velocity state, slowed by ``slow(v)``."""

    defaults = {"state": None, "coefficient": 0.0}

    @classmethod
    def variants(cls, model):
        return [cls(state=name) for name in model.velocity_names]

    def _speed_scale(self, model, evaluation):
        column = model.state_names.index(self.params["state"])
        scale = float(np.max(np.abs(evaluation.states[:, column])))
        return scale if scale > 0 else 1.0

    def pre_step(self, states, model):
        column = model.state_names.index(self.params["state"])
        states = states.copy()
        states[:, column] = self.slow(states[:, column])
        return states

    def pre_step_expr(self, states, p):
        name = self.params["state"]
        return {**states, name: self.slow_expr(states[name], p["coefficient"])}

    def slow(self, v):
        raise NotImplementedError

    def slow_expr(self, v, c):
        raise NotImplementedError


class LinearDrag(_Resistance):
    """Viscous drag: a force proportional to the velocity removes ``coefficient`` of it per period."""

    name = "linear_drag"
    stage = 3
    bounds = {"coefficient": (0.0, 0.5)}

    def slow(self, v):
        return v * (1.0 - self.params["coefficient"])

    def slow_expr(self, v, c):
        return v * (1.0 - c)


class QuadraticDrag(_Resistance):
    """Aerodynamic drag: a force proportional to the squared velocity; per period v -= c v |v|."""

    name = "quadratic_drag"
    stage = 3
    bounds = {"coefficient": (0.0, np.inf)}

    def search_bounds(self, model, evaluation):
        return {"coefficient": (0.0, 0.5 / self._speed_scale(model, evaluation))}

    def starts(self, model, evaluation, predicted):
        return [{"coefficient": 0.01 / self._speed_scale(model, evaluation)}]

    def slow(self, v):
        return v - self.params["coefficient"] * v * np.abs(v)

    def slow_expr(self, v, c):
        from percver.expr import abs_

        return v - c * v * abs_(v)


class CoulombFriction(_Resistance):
    """Dry friction: a constant force against the motion removes ``coefficient`` of speed per
    period, and stops the body rather than reversing it."""

    name = "coulomb_friction"
    stage = 3
    bounds = {"coefficient": (0.0, np.inf)}

    def search_bounds(self, model, evaluation):
        return {"coefficient": (0.0, 0.5 * self._speed_scale(model, evaluation))}

    def starts(self, model, evaluation, predicted):
        return [{"coefficient": 0.01 * self._speed_scale(model, evaluation)}]

    def slow(self, v):
        return np.sign(v) * np.maximum(np.abs(v) - self.params["coefficient"], 0.0)

    def slow_expr(self, v, c):
        """``sign(v) max(|v| - c, 0)`` written as ``v - clip(v, -c, c)``: equal, and continuous,
        so a set of speeds across 0 is not split by a ``sign`` branch."""
        from percver.expr import clip

        return v - clip(v, -c, c)


def _control_scale(evaluation):
    scale = float(np.max(np.abs(evaluation.inputs["history"][:, 0])))
    return scale if scale > 0 else 1.0


class ActuatorGain(DynamicsEffect):
    """Actuator gain: the plant receives ``gain`` times the commanded control (motor constant, battery level)."""

    name = "actuator_gain"
    stage = 1
    defaults = {"gain": 1.0}
    bounds = {"gain": (0.2, 3.0)}

    def actuate(self, history):
        return history * self.params["gain"]

    def actuate_expr(self, history, p):
        return [[u * p["gain"] for u in lag] for lag in history]


class ActuatorBias(DynamicsEffect):
    """Actuator bias: a constant ``bias`` adds to every control (trim, steering offset)."""

    name = "actuator_bias"
    stage = 1
    defaults = {"bias": 0.0}
    bounds = {"bias": (-np.inf, np.inf)}

    def search_bounds(self, model, evaluation):
        scale = _control_scale(evaluation)
        return {"bias": (-scale, scale)}

    def actuate(self, history):
        return history + self.params["bias"]

    def actuate_expr(self, history, p):
        return [[u + p["bias"] for u in lag] for lag in history]


class ActuatorSaturation(DynamicsEffect):
    """Actuator saturation: controls beyond +-``limit`` are clipped (the actuator's physical range)."""

    name = "actuator_saturation"
    stage = 2
    defaults = {"limit": np.inf}
    bounds = {"limit": (0.0, np.inf)}
    smooth = False

    def search_bounds(self, model, evaluation):
        scale = _control_scale(evaluation)
        return {"limit": (0.05 * scale, scale)}

    def starts(self, model, evaluation, predicted):
        return [{"limit": _control_scale(evaluation)}]

    def actuate(self, history):
        limit = self.params["limit"]
        return np.clip(history, -limit, limit)

    def actuate_expr(self, history, p):
        from percver.expr import clip

        limit = p["limit"]
        return [[clip(u, -limit, limit) for u in lag] for lag in history]


class ActuatorDelay(DynamicsEffect):
    """Actuator delay: the plant receives the control commanded ``periods`` control periods earlier
    (fractions blend the two neighbouring commands)."""

    name = "actuator_delay"
    fixed = ("periods",)
    defaults = {"periods": 0.0}
    bounds = {"periods": (0.0, np.inf)}
    units = {"periods": "periods"}
    smooth = False

    def applicable(self, model, evaluation):
        return evaluation.has_history

    def search_bounds(self, model, evaluation):
        return {"periods": (0.0, evaluation.inputs["history"].shape[1] - 1.0)}

    def lags(self):
        return int(np.ceil(self.params["periods"]))

    def actuate(self, history):
        lags = history.shape[1]
        position = np.minimum(np.arange(lags) + self.params["periods"], lags - 1)
        below = np.floor(position).astype(int)
        above = np.minimum(below + 1, lags - 1)
        weight = (position - below)[None, :, None]
        return (1 - weight) * history[:, below] + weight * history[:, above]

    def actuate_expr(self, history, p):
        """The current control only (later effects see one lag): the delay is a fitted
        number of periods (its interval would change the states the plant keeps)."""
        periods = self.params["periods"]
        below = min(int(np.floor(periods)), len(history) - 1)
        above = min(below + 1, len(history) - 1)
        weight = periods - np.floor(periods)
        if weight == 0:
            return [history[below]]
        return [[(1 - weight) * a + weight * b for a, b in zip(history[below], history[above])]]


EFFECTS = (LinearDrag, QuadraticDrag, CoulombFriction, ActuatorGain, ActuatorBias, ActuatorSaturation, ActuatorDelay)
