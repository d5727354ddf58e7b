"""A validated model as the model ``verify`` checks: expressions with the fitted effects.

A dynamics model over a ``pv.Discrete`` or ``pv.Continuous`` plant becomes a plant of the same
kind whose update (right-hand side) has every effect written in: actuator effects replace the
inputs, drag and friction replace the velocity states at the start of the period, an actuator
delay adds the earlier controls as states. A canonical LiDAR becomes the list of ray
expressions a ``pv.Stage`` takes, with the mounting, the range map and the limit in them.

Fitted parameters enter as numbers, or as ``pv.uncertain`` ranges (their bootstrap confidence
intervals), and the unexplained residual as a bounded term per state or ray: a
``pv.uncertain`` read each step, which the reach sets treat as an interval every step (any
disturbance sequence within the bound), while simulations hold one drawn value per run.
What went in is recorded on the result's ``validation`` (a :class:`Basis`), with the region
the data covers (:class:`Domain`), which ``verify`` checks the reach sets against.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from percver.errors import InputError


class NoSetSemanticsError(InputError):
    """A model or effect has no expression form that verification can use; the message names
    it and what to do instead."""


def substitute(expr, mapping: dict):
    """``expr`` with the variables named in ``mapping`` replaced by expressions (shared nodes
    stay shared, an uncertain parameter keeps its identity); a number stays a number."""
    from percver.expr import as_expr

    return as_expr(expr).substitute(mapping)


@dataclass
class Domain:
    """Where the model was validated: per variable, the range the measurements cover."""

    bounds: dict

    @classmethod
    def of(cls, names, values) -> "Domain":
        values = np.asarray(values, dtype=float).reshape(len(values), -1)
        return cls({n: (float(values[:, j].min()), float(values[:, j].max())) for j, n in enumerate(names)})

    def first_exit(self, names, boxes):
        """The first (step, state, (lo, hi) of the reach box, (lo, hi) validated) where a reach box
        leaves the domain, over the states the domain bounds; None when every box stays inside."""
        for step, box in enumerate(boxes):
            for name, (lo, hi) in zip(names, box):
                if name in self.bounds:
                    a, b = self.bounds[name]
                    if lo < a or hi > b:
                        return step, name, (float(lo), float(hi)), (a, b)
        return None

    def describe(self) -> str:
        return ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in self.bounds.items())


@dataclass
class Basis:
    """What a verifiable model was built from: the effects with their parameters (a number, or
    ``[lo, hi]`` when the parameter entered as an uncertain range), the confidence ``level`` of
    those ranges, the residual bound per state or ray and how it was taken, the validated
    ``domain`` and notes (knock-outs, lag states). ``residual_kind`` is "max" (the largest
    residual seen: still only what the data showed) or "quantile q" (a statistical bound: a
    fraction 1 - q of the measured residuals exceeded it, so it is not a worst case)."""

    effects: list
    level: float | None
    residual: dict | None
    residual_kind: str | None
    domain: Domain
    notes: list = field(default_factory=list)

    def describe(self) -> str:
        lines = []
        for e in self.effects:
            params = ", ".join(f"{k}={_show(v)}" for k, v in e["params"].items())
            lines.append(f"effect {e['effect']}({params})")
        if self.level is not None:
            lines.append(f"fitted parameters as their {self.level:.0%} bootstrap confidence intervals")
        if self.residual is not None:
            bounds = ", ".join(f"{k}: +-{v:.3g}" for k, v in self.residual.items())
            what = (
                "the largest residual measured"
                if self.residual_kind == "max"
                else f"the {self.residual_kind} of the measured residuals (statistical, not a worst-case bound)"
            )
            lines.append(f"residual as a bounded disturbance each step ({what}): {bounds}")
        lines.append(f"validated domain: {self.domain.describe()}")
        return "\n".join(lines + self.notes)

    def __str__(self) -> str:
        return self.describe()


def _show(value):
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return f"[{value[0]:.5g}, {value[1]:.5g}]"
    return f"{value:.5g}" if isinstance(value, float) else str(value)


def effect_parameters(effect, ranges: dict):
    """The effect's parameters for the expression form: a ``pv.uncertain`` where ``ranges``
    gives a proper interval (widened to hold the fitted value), else the fitted value; and the
    record of them for the :class:`Basis`."""
    from percver.expr import uncertain

    exprs, record = {}, {}
    for name, value in effect.params.items():
        pair = ranges.get(name)
        if pair is not None and name not in getattr(effect, "fixed", ()) and pair[1] > pair[0]:
            lo, hi = min(pair[0], value), max(pair[1], value)
            exprs[name], record[name] = uncertain(lo, hi), [lo, hi]
        else:
            exprs[name], record[name] = value, value
    return exprs, record


def _deterministic(model, ranges):
    effects, records = [], []
    for i, effect in enumerate(model.effects):
        exprs, record = effect_parameters(effect, ranges.get(i, {}))
        effects.append((effect, exprs))
        records.append({"effect": effect.name, "params": record})
    return effects, records


def dynamics_system(model, ranges: dict, residual: dict | None, residual_kind: str | None, level, domain: Domain):
    """The ``pv.Discrete``/``pv.Continuous`` plant of a dynamics model with its effects written in.

    ``ranges`` maps an effect's index to ``{parameter: (lo, hi)}``; ``residual`` maps a state to
    the bound of its bounded disturbance (discrete plants only)."""
    from percver.expr import Expr, uncertain
    from percver.systems import Continuous, Discrete
    from percver.validate.models import SystemPlant

    system = getattr(model.plant, "system", None) if isinstance(model.plant, SystemPlant) else None
    if system is None:
        raise NoSetSemanticsError(
            f"the plant {model.plant!r} is a Python function, which verification cannot enclose: give pv.diagnose "
            "the plant as pv.Discrete({...}) or pv.Continuous({...}) (its update as expressions of pv.variables)"
        )
    effects, records = _deterministic(model, ranges)
    notes = []
    if isinstance(system, Continuous):
        refused = [e.name for e, _ in effects if hasattr(e, "slow_expr") or e.lags() > 0]
        if refused:
            raise NoSetSemanticsError(
                f"effects {refused} act once per control period (drag and friction before the step, a delay on the "
                "control history), which a continuous plant's right-hand side cannot hold: diagnose a pv.Discrete "
                "plant of the same period, or add the force to the rhs by hand (e.g. v' = ... - k v)"
            )
        if residual is not None:
            raise NoSetSemanticsError(
                "residual= bounds one period's error of a discrete update; for a pv.Continuous plant it has no "
                "sound form in the right-hand side: diagnose a pv.Discrete plant of the same period to use it"
            )
    lags = max([e.lags() for e, _ in effects] + [0])
    lag_names = [[f"{u}_prev{k}" for u in system.inputs] for k in range(1, lags + 1)]
    history = [[Expr.var(u) for u in system.inputs]] + [[Expr.var(n) for n in names] for names in lag_names]
    states = {s: Expr.var(s) for s in system.states}
    for effect, p in effects:
        history = effect.actuate_expr(history, p)
        states = effect.pre_step_expr(states, p)
    mapping = {**{s: e for s, e in states.items()}, **dict(zip(system.inputs, history[0]))}
    if isinstance(system, Continuous):
        rhs = {s: substitute(e, mapping) for s, e in zip(system.states, system.rhs)}
        built = Continuous(rhs, inputs=system.inputs, period=system.period, step=system.step, remainder=system.remainder)
    else:
        update = {}
        for s, e in zip(system.states, system.update):
            e = substitute(e, mapping)
            if residual is not None and residual.get(s, 0.0) > 0:
                e = e + uncertain(-residual[s], residual[s])
            update[s] = e
        for k, names in enumerate(lag_names):
            previous = system.inputs if k == 0 else lag_names[k - 1]
            update.update({n: Expr.var(p) for n, p in zip(names, previous)})
        built = Discrete(update, inputs=system.inputs)
    if lags:
        notes.append(
            f"the actuator delay keeps earlier controls as states {[n for names in lag_names for n in names]}: "
            "give their initial range (the controls' range) in init"
        )
    built.validation = Basis(records, level, residual, residual_kind, domain, notes)
    return built


class SensorComponent(list):
    """The expressions of a diagnosed sensor (one per measurement), a ``pv.Stage`` component;
    ``inputs`` are the state names it reads, ``validation`` its :class:`Basis`."""

    inputs: tuple = ()
    validation: Basis | None = None


def lidar_component(model, ranges: dict, residual: dict | None, residual_kind: str | None, level, domain: Domain):
    """The ray expressions of a diagnosed LiDAR model over ``x, y, theta``.

    Ranges are ``min(a r + b, limit)`` where ``a r + b`` is the effects' range map and ``r`` the
    canonical cast with a cap chosen so that a ray without an echo within it reads the limit
    for every parameter in range (as the float model's unlimited cast does)."""
    from percver import _core
    from percver.expr import Expr, minimum, uncertain, where

    effects, records = _deterministic(model, ranges)
    x, y, theta = (Expr.var(n) for n in model.state_names)
    a, b = Expr.constant(1.0), Expr.constant(0.0)
    limit = model.lidar.max_range
    knockouts, notes = [], []
    for effect, p in effects:
        if effect.name == "gaussian_noise":
            raise NoSetSemanticsError(
                "gaussian_noise is unbounded: it has no set form; leave it out of the model and bound the residual "
                "instead (diagnosis.system(residual='max') or a quantile)"
            )
        if getattr(effect, "knockout", False):
            knockouts.append(effect.name)
            continue
        x, y, theta = effect.mount_expr(x, y, theta, p)
        a, b = effect.affine_expr(a, b, p)
        limit = effect.limit_expr(limit, p)
    (a_lo, _), (b_lo, _), (_, limit_hi) = _core.eval_interval([a, b, Expr.constant(0.0) + limit], [], [])
    if not a_lo > 0:
        raise NoSetSemanticsError(f"the fitted range scale reaches {a_lo:g}: a LiDAR's range map must increase with distance")
    cap = (limit_hi - b_lo) / a_lo
    if not cap > 0:
        raise NoSetSemanticsError(f"the fitted range bias {b_lo:g} m exceeds the range limit {limit_hi:g} m: no echo is possible")
    cast = model.lidar.with_range(cap).exprs(model.track, x, y, theta)
    rays = []
    for name, r in zip(model.measurement_names, cast):
        reading = minimum(a * r + b, limit)
        if knockouts:
            reading = where(uncertain(0.0, 1.0) > 0.5, limit, reading)
        if residual is not None and residual.get(name, 0.0) > 0:
            reading = reading + uncertain(-residual[name], residual[name])
        rays.append(reading)
    if knockouts:
        notes.append(
            f"{', '.join(knockouts)} enter as an adversarial knock-out: any ray may read the range limit "
            "at any step (simulations draw one choice per ray and run)"
        )
    out = SensorComponent(rays)
    out.inputs = tuple(model.state_names)
    out.validation = Basis(records, level, residual, residual_kind, domain, notes)
    return out


def residual_bounds(report, how):
    """Per measured dimension, the bound of the residual: its largest magnitude (``"max"``) or a
    quantile ``q`` of its magnitude; entries a random effect explains are left out."""
    magnitude = np.where(report.explained, 0.0, np.abs(report.residuals))
    if how == "max":
        values, kind = magnitude.max(axis=0), "max"
    elif isinstance(how, float) and 0 < how < 1:
        values, kind = np.quantile(magnitude, how, axis=0), f"quantile {how:g}"
    else:
        raise InputError(f"residual={how!r}: use 'max' or a quantile in (0, 1) such as 0.999")
    return dict(zip(report.model.measurement_names, (float(v) for v in values))), kind


def validity(loop, results: list, validated=None) -> list:
    """Sets each result's ``validity``: whether every reach box of every cell stays inside the
    validated domain (``validated``, else the plant's ``validation`` from a diagnosis), or the
    first step and state where one leaves it. Results without a domain are returned as they are."""
    if validated is None:
        basis = getattr(loop.plant, "validation", None)
        validated = None if basis is None else basis.domain
    if validated is None:
        return results
    if not isinstance(validated, Domain):
        raise InputError(f"validated= takes a Domain (e.g. diagnosis.domain), got {type(validated).__name__}")
    for result in results:
        exits = [(hit, cell) for cell in result.cells if (hit := validated.first_exit(result.states, cell.boxes)) is not None]
        if not exits:
            cex = result.counterexample
            if cex is not None:
                run = np.asarray(cex.trajectory)[: cex.step + 1]
                hit = validated.first_exit(result.states, [[(x, x) for x in row] for row in run])
                where = "inside" if hit is None else f"outside (at step {hit[0]}, {hit[1]} = {hit[2][0]:.4g})"
                result.validity = f"the counterexample runs {where} the validated domain ({validated.describe()})"
            else:
                result.validity = f"{result.verdict} inside the validated domain ({validated.describe()})"
            continue
        (step, name, (lo, hi), (a, b)), cell = min(exits, key=lambda e: e[0][0])
        cell_box = ", ".join(f"{n} in [{c[0]:.4g}, {c[1]:.4g}]" for n, c in cell.box.items())
        result.validity = (
            f"the reach set leaves the validated domain at step {step}: {name} in [{lo:.4g}, {hi:.4g}] is not inside "
            f"[{a:.4g}, {b:.4g}], where the measurements end (cell {cell_box}); the verdict there rests on "
            "the model outside the data"
        )
    return results
