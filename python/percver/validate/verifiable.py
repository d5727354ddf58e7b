"""A validated model as the model ``verify`` checks: expressions with the fitted effects.

A dynamics model over a ``pv.Discrete`` or ``pv.Continuous`` plant becomes a plant of the same
kind whose update (right-hand side) has every effect written in: actuator effects replace the
inputs, drag and friction replace the velocity states at the start of the period, an actuator
delay adds the earlier controls as states. A canonical LiDAR becomes the list of ray
expressions a ``pv.Stage`` takes, with the mounting, the range map and the limit in them.

Fitted parameters enter as numbers, or as ``pv.uncertain`` ranges (their bootstrap confidence
intervals) held over a run (``per="run"``: constants of the system, which ``verify`` carries as
Taylor-model variables), and the unexplained residual as a bounded term per state or ray: a
``pv.uncertain`` re-drawn each step (``per="step"``: any disturbance sequence within the bound).
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


# The grid of the region the data covers: measurements per cell on average, most cells per variable.
PER_CELL = 20
GRID_BINS = 64


@dataclass
class Domain:
    """Where the model was validated: per variable, the range the measurements cover, and the
    region they cover: ``grids``, each ``(names, edges, occupied)``, a grid over those variables'
    ranges whose cells hold measurements where ``occupied`` is True (None: not known)."""

    bounds: dict
    grids: list = field(default_factory=list)

    @classmethod
    def of(cls, names, values) -> "Domain":
        """The ranges of ``values`` (rows x variables) and a grid marking the cells with a
        measurement, with about ``PER_CELL`` measurements per cell on average (2 to ``GRID_BINS``
        cells per variable): finer, and sampling gaps would pass for holes in the data."""
        values = np.asarray(values, dtype=float).reshape(len(values), -1)
        bounds = {n: (float(values[:, j].min()), float(values[:, j].max())) for j, n in enumerate(names)}
        bins = int(min(GRID_BINS, max(2, np.floor((len(values) / PER_CELL) ** (1 / values.shape[1]) + 1e-9))))
        edges = [np.linspace(lo, hi, bins + 1) if hi > lo else np.array([lo - 0.5, hi + 0.5]) for lo, hi in bounds.values()]
        occupied = np.histogramdd(values, bins=edges)[0] > 0
        return cls(bounds, [(tuple(names), edges, occupied)])

    def first_uncovered(self, names, boxes):
        """The first (step, box as {name: (lo, hi)}) where a reach box meets a grid cell without
        measurements, over the variables of each grid; None when every box lies in occupied cells."""
        column = {n: j for j, n in enumerate(names)}
        for step, box in enumerate(boxes):
            for grid_names, edges, occupied in self.grids:
                if not all(n in column for n in grid_names):
                    continue
                ranges = []
                for n, e in zip(grid_names, edges):
                    lo, hi = box[column[n]]
                    first = int(np.clip(np.searchsorted(e, lo, side="right") - 1, 0, len(e) - 2))
                    last = int(np.clip(np.searchsorted(e, hi, side="left") - 1, 0, len(e) - 2))
                    ranges.append(np.arange(first, max(first, last) + 1))
                if not occupied[np.ix_(*ranges)].all():
                    return step, {n: (float(box[column[n]][0]), float(box[column[n]][1])) for n in grid_names}
        return None

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
    fraction 1 - q of the measured residuals exceeded it, so it is not a worst case). ``per`` is
    how the parameter ranges enter: "run" (held over a run) or "step" (re-drawn each step)."""

    effects: list
    level: float | None
    residual: dict | None
    residual_kind: str | None
    domain: Domain
    notes: list = field(default_factory=list)
    per: str = "run"

    def describe(self) -> str:
        lines = []
        for e in self.effects:
            params = ", ".join(f"{k}={_show(v)}" for k, v in e["params"].items())
            lines.append(f"effect {e['effect']}({params})")
        if self.level is not None:
            held = "held over a run" if self.per == "run" else "re-drawn each step"
            lines.append(f"fitted parameters as their {self.level:.0%} bootstrap confidence intervals, {held}")
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


def effect_parameters(effect, ranges: dict, per: str = "run"):
    """The effect's parameters for the expression form: a ``pv.uncertain(..., per=per)`` where
    ``ranges`` gives a proper interval (widened to hold the fitted value), else the fitted value;
    and the record of them for the :class:`Basis`."""
    from percver.expr import uncertain

    exprs, record = {}, {}
    for name, value in effect.params.items():
        pair = ranges.get(name)
        if pair is not None and name not in getattr(effect, "fixed", ()) and pair[1] > pair[0]:
            lo, hi = min(pair[0], value), max(pair[1], value)
            exprs[name], record[name] = uncertain(lo, hi, per=per), [lo, hi]
        else:
            exprs[name], record[name] = value, value
    return exprs, record


def _deterministic(model, ranges, per):
    effects, records = [], []
    for i, effect in enumerate(model.effects):
        exprs, record = effect_parameters(effect, ranges.get(i, {}), per)
        effects.append((effect, exprs))
        records.append({"effect": effect.name, "params": record})
    return effects, records


def dynamics_system(model, ranges: dict, residual: dict | None, residual_kind: str | None, level, domain: Domain, per: str = "run"):
    """The ``pv.Discrete``/``pv.Continuous`` plant of a dynamics model with its effects written in.

    ``ranges`` maps an effect's index to ``{parameter: (lo, hi)}`` (uncertain ranges ``per`` run
    or step); ``residual`` maps a state to the bound of its bounded disturbance (discrete plants
    only)."""
    from percver.expr import Expr, uncertain
    from percver.systems import Continuous, Discrete
    from percver.validate.models import SystemPlant

    system = getattr(model.plant, "system", None) if isinstance(model.plant, SystemPlant) else None
    if system is None:
        raise NoSetSemanticsError(
            f"the plant {model.plant!r} is a Python function, which verification cannot enclose: give pv.diagnose "
            "the plant as pv.Discrete({...}) or pv.Continuous({...}) (its update as expressions of pv.variables)"
        )
    effects, records = _deterministic(model, ranges, per)
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
                e = e + uncertain(-residual[s], residual[s], per="step")
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
    built.validation = Basis(records, level, residual, residual_kind, domain, notes, per)
    return built


class SensorComponent(list):
    """The expressions of a diagnosed sensor (one per measurement), a ``pv.Stage`` component;
    ``inputs`` are the state names it reads, ``validation`` its :class:`Basis`."""

    inputs: tuple = ()
    validation: Basis | None = None


def lidar_component(model, ranges: dict, residual: dict | None, residual_kind: str | None, level, domain: Domain, per: str = "run"):
    """The ray expressions of a diagnosed LiDAR model over ``x, y, theta``.

    Ranges are ``min(a r + b, limit)`` where ``a r + b`` is the effects' range map and ``r`` the
    canonical cast with a cap chosen so that a ray without an echo within it reads the limit
    for every parameter in range (as the float model's unlimited cast does)."""
    from percver import _core
    from percver.expr import Expr, minimum, uncertain, where

    effects, records = _deterministic(model, ranges, per)
    x, y, theta = (Expr.var(n) for n in model.state_names)
    a, b = Expr.constant(1.0), Expr.constant(0.0)
    limit = model.lidar.max_range
    knockouts, notes = [], []
    _refuse_unbounded(effects)
    for effect, p in effects:
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
    for r in cast:
        reading = minimum(a * r + b, limit)
        if knockouts:
            reading = where(uncertain(0.0, 1.0, per="step") > 0.5, limit, reading)
        rays.append(reading)
    rays = _with_residual(rays, model.measurement_names, residual)
    if knockouts:
        notes.append(
            f"{', '.join(knockouts)} enter as an adversarial knock-out: any ray may read the range limit "
            "at any step (simulations draw one choice per ray and run)"
        )
    out = SensorComponent(rays)
    out.inputs = tuple(model.state_names)
    out.validation = Basis(records, level, residual, residual_kind, domain, notes, per)
    return out


def _refuse_unbounded(effects) -> None:
    """Gaussian noise has no bound, hence no set form: the residual bound stands for it."""
    for effect, _ in effects:
        if effect.name == "gaussian_noise":
            raise NoSetSemanticsError(
                "gaussian_noise is unbounded: it has no set form; leave it out of the model and bound the residual "
                "instead (diagnosis.system(residual='max') or a quantile)"
            )


def camera_image(model, effects, render) -> list:
    """The pixel expressions (row-major) of a camera model: ``render(shift)`` gives the canonical
    image with the ``position`` state moved by ``shift`` (None: not moved), then each effect's
    ``image_expr`` in the model's order; the blur renders the effects before it at its shifts."""

    def image(stack, shift):
        pixels = render(shift)
        for i, (effect, p) in enumerate(stack):
            pixels = effect.image_expr(pixels, p, model, lambda moved, before=stack[:i]: image(before, moved))
        return pixels

    return image(effects, None)


def camera_component(model, ranges: dict, residual: dict | None, residual_kind: str | None, level, domain: Domain, per: str = "run"):
    """A diagnosed camera for verification: its renderer, then every fitted effect as expressions
    of the pixels (``image_expr``), then the residual bound per pixel.

    A renderer given as pixel expressions gives a :class:`SensorComponent` (one ``pv.Stage``);
    a generator ``Network`` gives a :class:`CameraSensor`, a chain of stages with the network
    rendering the states (and the blur's moved states). A Python renderer is refused."""
    from percver.expr import Expr
    from percver.networks import Network

    renderer = model.render
    exprs = getattr(renderer, "exprs", None)  # an ExpressionRenderer's pixels
    if exprs is None and not isinstance(renderer, Network):
        raise NoSetSemanticsError(
            f"the camera's renderer {getattr(renderer, '__name__', type(renderer).__name__)} is a Python function, which "
            "verification cannot enclose: give ImageModel the renderer as a generator pv.Network of the states (e.g. one "
            "trained on its images, pv.load_network) or as one expression per pixel, and diagnose again"
        )
    effects, records = _deterministic(model, ranges, per)
    _refuse_unbounded(effects)
    basis = Basis(records, level, residual, residual_kind, domain, [], per)
    if isinstance(renderer, Network):
        return CameraSensor(model, renderer, effects, residual, basis)
    position = Expr.var(model.position)

    def render(shift):
        return exprs if shift is None else [substitute(e, {model.position: position + shift}) for e in exprs]

    out = SensorComponent(_with_residual(camera_image(model, effects, render), model.measurement_names, residual))
    out.inputs = tuple(model.state_names)
    out.validation = basis
    return out


class CameraSensor:
    """A diagnosed camera whose renderer is a generator network: a chain of ``pv.Stage`` s
    (``stages(output)``): the network on the states (``output_render0``), for a blur the states
    with the position moved by -/+ delta (``output_at1``, ...) and the network on them, then
    one expression stage with the effects and the residual bound (``output``). Without effects
    and residual the network alone writes ``output``."""

    def __init__(self, model, network, effects, residual: dict | None, validation: Basis):
        self.model = model
        self.network = network
        self.effects = effects
        self.residual = residual
        self.inputs = tuple(model.state_names)
        self.measurement_names = tuple(model.measurement_names)
        self.validation = validation

    def __len__(self) -> int:
        return len(self.measurement_names)

    def stages(self, output: str) -> list:
        """The chain as ``pv.Stage`` s reading the states ``inputs``, the last one writing ``output``;
        put them before the stages that read the image."""
        from percver.expr import Expr
        from percver.systems import Stage

        if not self.effects and not self.residual:
            chain = [Stage(self.network, inputs=list(self.inputs), output=output)]
        else:
            shifts = []

            def render(shift):
                shifts.append(shift)
                return _signals(f"{output}_render{len(shifts) - 1}", len(self))

            pixels = _with_residual(camera_image(self.model, self.effects, render), self.measurement_names, self.residual)
            generic = self.network.with_input_names([f"in{i}" for i in range(self.network.n_in)])
            chain = []
            for k, shift in enumerate(shifts):
                if shift is None:
                    chain.append(Stage(self.network, inputs=list(self.inputs), output=f"{output}_render{k}"))
                    continue
                moved = [Expr.var(n) + shift if n == self.model.position else Expr.var(n) for n in self.inputs]
                chain.append(Stage(moved, inputs=list(self.inputs), output=f"{output}_at{k}"))
                chain.append(Stage(generic, inputs=[f"{output}_at{k}"], output=f"{output}_render{k}"))
            chain.append(Stage(pixels, inputs=[f"{output}_render{k}" for k in range(len(shifts))], output=output))
        chain[0].validation = self.validation  # the whole chain's: its domain and residual bound
        return chain

    def __repr__(self) -> str:
        effects = ", ".join(e.name for e, _ in self.effects) or "no effects"
        return f"CameraSensor({self.network.name}, {effects}: {len(self)} pixels over {list(self.inputs)})"


def _with_residual(exprs, names, residual: dict | None) -> list:
    """Each expression plus its measurement's residual bound, a disturbance re-drawn each step."""
    from percver.expr import uncertain

    bound = residual or {}
    return [e + uncertain(-bound[n], bound[n], per="step") if bound.get(n, 0.0) > 0 else e for e, n in zip(exprs, names)]


def expression_component(model, residual: dict | None, residual_kind: str | None, level, domain: Domain, per: str = "run"):
    """A sensor given to ``diagnose`` as expressions of the states (``FunctionSensor`` over them):
    the expressions themselves, with the residual bound."""
    exprs = getattr(getattr(model, "function", None), "exprs", None)
    if exprs is None:
        raise NoSetSemanticsError(
            f"a diagnosed {model.kind} model ({type(model).__name__}) has no expression form: its prediction is a "
            "Python function (a renderer, a simulator). Verify such a sensor through a network that stands for it "
            "(e.g. a generator trained on its images, pv.load_network) with the diagnosed effects applied to its training data"
        )
    if model.effects:
        raise NoSetSemanticsError(
            f"effects {[e.name for e in model.effects]} of a sensor given as expressions have no set form: leave them out "
            "and bound the residual instead (diagnosis.system(residual='max') or a quantile)"
        )
    out = SensorComponent(_with_residual(exprs, model.measurement_names, residual))
    out.inputs = tuple(model.state_names)
    out.validation = Basis([], level, residual, residual_kind, domain, [], per)
    return out


def _signals(name: str, width: int) -> list:
    """The scalar signals of a stage output of ``width`` values (``ClosedLoop`` names them so)."""
    from percver.expr import Expr

    return [Expr.var(name)] if width == 1 else [Expr.var(f"{name}_{i}") for i in range(width)]


class LearnedSensor:
    """A diagnosed sensor whose last step is a learned noise model (the paper's g_n): the
    canonical expressions, then the network, as a chain of ``pv.Stage`` s (``stages(output)``).

    A generative model (benign noise) is one network stage, (canonical measurement, states) ->
    measurement. A knock-out model (adversarial noise) is the classifier c_n, (canonical,
    states) -> one probability per dimension, then per dimension ``where(probability >
    threshold, knocked value, canonical)``: where the sets cannot decide, both readings. The
    residual bound, if any, is added last. ``network`` is the learned network (read back from
    the ONNX file when ``Diagnosis.system(onnx=DIR)`` wrote one); its training domain
    (``network.domain``) is checked by ``verify`` on the states it reads."""

    def __init__(self, canonical: SensorComponent, learned, network, residual: dict | None, measurement_names, validation: Basis):
        self.canonical = canonical
        self.learned = learned
        self.network = network
        self.residual = residual
        self.measurement_names = tuple(measurement_names)
        self.inputs = canonical.inputs
        self.validation = validation

    def stages(self, output: str) -> list:
        """The chain as ``pv.Stage`` s reading the states ``inputs``, the last one writing ``output``
        (the others ``output_canonical``, ``output_knockout`` or ``output_generated``); put them
        before the stages that read the measurement."""
        from percver.expr import where
        from percver.systems import Stage

        names, width = list(self.inputs), len(self.canonical)
        canonical = f"{output}_canonical"
        if hasattr(self.canonical, "stages"):  # a camera rendered by a network
            chain = self.canonical.stages(canonical)
        else:
            chain = [Stage(self.canonical, inputs=names, output=canonical)]
        chain[0].validation = self.validation  # the whole chain's: its domain and residual bound
        if self.learned.kind == "knockout":
            model = self.learned.model
            chain.append(Stage(self.network, inputs=[canonical, *names], output=f"{output}_knockout"))
            noised = [
                where(p > float(t), float(k), c)
                for p, t, k, c in zip(_signals(f"{output}_knockout", width), model.thresholds, model.knocked, _signals(canonical, width))
            ]
            chain.append(
                Stage(
                    _with_residual(noised, self.measurement_names, self.residual), inputs=[f"{output}_knockout", canonical], output=output
                )
            )
        elif self.residual:
            chain.append(Stage(self.network, inputs=[canonical, *names], output=f"{output}_generated"))
            generated = _with_residual(_signals(f"{output}_generated", width), self.measurement_names, self.residual)
            chain.append(Stage(generated, inputs=[f"{output}_generated"], output=output))
        else:
            chain.append(Stage(self.network, inputs=[canonical, *names], output=output))
        return chain

    def __repr__(self) -> str:
        return f"LearnedSensor({self.learned.name}: {len(self.canonical)} measurements over {list(self.inputs)})"


def learned_sensor(
    canonical: SensorComponent, learned, residual: dict | None, residual_kind: str | None, measurement_names, onnx=None
) -> LearnedSensor:
    """The :class:`LearnedSensor` of a canonical component and a learned noise model; with ``onnx``
    (a directory) the network is written there (``learned_KIND.onnx``, with its training domain)
    and the stage reads it back, so that what is verified is the file."""
    from percver.formats import load_network

    network = learned.network
    notes = list(canonical.validation.notes)
    if onnx is not None:
        path = learned.save(onnx)[0]
        network = load_network(path)
        notes.append(f"{learned.name} is the network of {path}")
    domain = ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in zip(canonical.inputs, (network.domain or ())[len(canonical) :]))
    notes.append(f"{learned.name} enters as a network stage, trained on {domain} (verify reports reach sets leaving it)")
    basis = canonical.validation
    validation = Basis(
        basis.effects + [{"effect": learned.name, "params": {}}], basis.level, residual, residual_kind, basis.domain, notes, basis.per
    )
    return LearnedSensor(canonical, learned, network, residual, measurement_names, validation)


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


def validated_domain(loop, validated=None) -> tuple:
    """What ``verify`` checks the reach sets against: ``validated``, else the domains of the
    diagnosed plant and sensor stages of ``loop`` (each state within all of them; None without
    any), and what the result must add about their residual bounds."""
    bases = [b for b in [getattr(loop.plant, "validation", None)] + [getattr(s, "validation", None) for s in loop.stages] if b is not None]
    if validated is None and bases:
        bounds = {}
        for basis in bases:
            for name, (lo, hi) in basis.domain.bounds.items():
                a, b = bounds.get(name, (lo, hi))
                bounds[name] = (max(a, lo), min(b, hi))
        validated = Domain(bounds, [grid for basis in bases for grid in basis.domain.grids])
    caveats = [
        f"the residual bound is {'the largest residual measured' if b.residual_kind == 'max' else 'the ' + b.residual_kind + ' of the measured residuals, a statistical bound, not a worst case'}"
        for b in bases
        if b.residual_kind is not None
    ]
    return validated, sorted(set(caveats))


def validity(results: list, validated=None, caveats=()) -> list:
    """Sets each result's ``validity``: whether every reach box of every cell stays inside the
    validated domain (see :func:`validated_domain`), or the first step and state where one leaves
    it, then the ``caveats``. Results without a domain are returned as they are."""
    if validated is None:
        return results
    if not isinstance(validated, Domain):
        raise InputError(f"validated= takes a Domain (e.g. diagnosis.domain), got {type(validated).__name__}")
    for result in results:
        exits = [(hit, cell) for cell in result.cells if (hit := validated.first_exit(result.states, cell.boxes)) is not None]
        if not exits:
            cex = result.counterexample
            if cex is not None:
                run = [[(x, x) for x in row] for row in np.asarray(cex.trajectory)[: cex.step + 1]]
                hit = validated.first_exit(result.states, run)
                where = "inside" if hit is None else f"outside (at step {hit[0]}, {hit[1]} = {hit[2][0]:.4g})"
                result.validity = f"the counterexample runs {where} the validated domain ({validated.describe()})"
                gap = None if hit is not None else validated.first_uncovered(result.states, run)
            else:
                result.validity = f"{result.verdict} inside the validated domain ({validated.describe()})"
                gaps = [g for cell in result.cells if (g := validated.first_uncovered(result.states, cell.boxes)) is not None]
                gap = min(gaps, key=lambda g: g[0]) if gaps else None
            if gap is not None:
                box = ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in gap[1].items())
                result.validity += f", but at step {gap[0]} it reaches a part of it without measurements ({box})"
            elif validated.grids:
                result.validity += ", in the region the measurements cover"
            continue
        (step, name, (lo, hi), (a, b)), cell = min(exits, key=lambda e: e[0][0])
        cell_box = ", ".join(f"{n} in [{c[0]:.4g}, {c[1]:.4g}]" for n, c in cell.box.items())
        result.validity = (
            f"the reach set leaves the validated domain at step {step}: {name} in [{lo:.4g}, {hi:.4g}] is not inside "
            f"[{a:.4g}, {b:.4g}], where the measurements end (cell {cell_box}); the verdict there rests on "
            "the model outside the data"
        )
    for result in results:
        result.validity = "; ".join([result.validity, *caveats])
    return results
