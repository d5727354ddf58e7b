"""Fitting effects to data and scoring them on held-out data.

A candidate is fitted on the training folds and judged by the squared error it removes on
the held-out fold (cross-validation by trajectory when the data has trajectories), with a
bootstrap interval over held-out rows or trajectories. Fitting uses a robust loss so that a
few large residuals of another mechanism (reflections, dropouts) do not bend the fit of,
say, a range bias; scoring uses plain squared error, the quantity the user sees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from percver.errors import MeasurementError
from percver.validate.effects import Effect, candidates
from percver.validate.effects.base import robust_sigma
from percver.validate.regions import feature_table, missing_pattern, split_regions, standout

# Random effects are not claimed when their events crowd into a region this many times denser
# than on average (with SIGNIFICANCE standard errors): then they have a cause to find.
CROWDING = 3.0
SIGNIFICANCE = 4.0


def row_errors(evaluation, predicted, explained=None) -> np.ndarray:
    """Mean squared weighted residual of each row; entries a stochastic effect explains count as zero."""
    residual = (evaluation.measured - predicted) * evaluation.weights
    if explained is not None:
        residual = np.where(explained, 0.0, residual)
    return np.mean(residual**2, axis=1)


def model_errors(model, evaluation) -> np.ndarray:
    predicted = model.predict_inputs(evaluation.inputs)
    return row_errors(evaluation, predicted, model.accounted(predicted, evaluation.measured))


def _robust_scale(residual: np.ndarray) -> float:
    """Where the soft-L1 loss turns from quadratic to linear: the noise level, robustly."""
    rms = np.sqrt(np.mean(residual**2)) if residual.size else 0.0
    return float(max(robust_sigma(residual), 0.05 * rms, 1e-12))


def _fit_slots(model, indices, evaluation, starts=(), widths=None, rounds=7):
    """Fit the parameters of the effects at ``indices`` together, every other effect fixed.

    Robust least squares when all of them are smooth, else the refined grid. ``starts`` are
    extra starting points (dicts of parameters) when fitting a single effect; the current
    values are always one. ``widths`` maps (index, parameter) to the first grid's width.
    """
    effects = list(model.effects)
    coordinates, lo, hi = [], [], []
    for index in indices:
        for name, (a, b) in effects[index].search_bounds(model, evaluation).items():
            coordinates.append((index, name))
            lo.append(a)
            hi.append(b)
    if not coordinates:
        return model
    if len(evaluation) < len(coordinates):
        names = ", ".join(effects[i].name for i in indices)
        raise MeasurementError(
            f"fitting {names} needs {len(coordinates)} parameters but only {len(evaluation)} samples are "
            "available: measure more samples or fit fewer effects"
        )
    lo, hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
    base = model.with_effects([e for i, e in enumerate(effects) if i not in indices])
    base_predicted = base.predict_inputs(evaluation.inputs)
    explained = base.accounted(base_predicted, evaluation.measured)
    scale = _robust_scale(((evaluation.measured - base_predicted) * evaluation.weights)[~explained])

    def build(theta):
        params = {index: {} for index in indices}
        for (index, name), value in zip(coordinates, theta):
            params[index][name] = float(value)
        return model.with_effects([effects[i].replace(**params[i]) if i in params else e for i, e in enumerate(effects)])

    def residual(theta):
        r = (build(theta).predict_inputs(evaluation.inputs) - evaluation.measured) * evaluation.weights
        return np.where(explained, 0.0, r).ravel() / scale

    def cost(theta):
        z = residual(theta) ** 2
        return float(np.sum(np.sqrt(1.0 + z) - 1.0))

    def point(overrides):
        values = [overrides.get(name, effects[index].params[name]) for index, name in coordinates]
        theta = np.array([(l + h) / 2 if v is None else v for v, l, h in zip(values, lo, hi)], dtype=float)
        return _inside(theta, lo, hi)

    points = [point({})] + [point(start) for start in starts if start]
    theta = min(points, key=cost)
    if all(effects[i].smooth for i in indices):
        span = np.where(np.isfinite(hi - lo), hi - lo, np.maximum(np.abs(theta), 1.0))
        theta = least_squares(residual, theta, bounds=(lo, hi), loss="soft_l1", x_scale=span / 10, diff_step=1e-5, ftol=1e-6, xtol=1e-6).x
    else:
        widths = widths or {}
        first = np.array([widths.get(c, h - l) for c, l, h in zip(coordinates, lo, hi)])
        theta = _grid_refine(cost, theta, lo, hi, first, rounds)
    return build(theta)


def _inside(theta, lo, hi):
    """Strictly inside finite bounds, so that a least-squares start is feasible; the margin keeps
    a start from hugging a bound, where the first trust region would be vanishingly small."""
    margin = np.where(np.isfinite(hi - lo), 1e-3 * (hi - lo), 0.0)
    return np.clip(theta, lo + margin, hi - margin)


def _grid_refine(cost, theta, lo, hi, widths, rounds, points=11):
    """Coordinate search on a grid around the best point, shrinking the grid three-fold each round."""
    theta = theta.copy()
    best = cost(theta)
    widths = widths.astype(float).copy()
    for _ in range(rounds):
        for i in range(len(theta)):
            grid = np.clip(theta[i] + np.linspace(-0.5, 0.5, points) * widths[i], lo[i], hi[i])
            for value in np.unique(grid):
                trial = theta.copy()
                trial[i] = value
                c = cost(trial)
                if c < best:
                    best, theta = c, trial
        widths /= 3.0
    return theta


def fit_effect(model, effect: Effect, evaluation, warm=None) -> Effect:
    """``effect`` with its parameters fitted to ``evaluation``, on top of ``model``'s effects.

    ``warm`` (parameters, e.g. a fit on more data) is one more starting point.
    """
    if effect.stochastic:
        return effect.fit_stochastic(model, evaluation, model.predict_inputs(evaluation.inputs))
    trial = model.with_effect(effect)
    index = model.insertion_index(effect)
    starts = effect.starts(trial, evaluation, model.predict_inputs(evaluation.inputs)) + ([warm] if warm else [])
    widths = {(index, name): w for name, w in effect.search_width(trial, evaluation).items()}
    return _fit_slots(trial, [index], evaluation, starts, widths).effects[index]


def refit(model, evaluation):
    """Refit all deterministic effects together: the non-smooth ones one at a time on a narrowed
    grid around their values, the smooth ones jointly by least squares (twice, when both kinds
    are present, since they interact); then the stochastic ones on the result."""
    deterministic = [i for i, e in enumerate(model.effects) if not e.stochastic]
    rough = [i for i in deterministic if not model.effects[i].smooth]
    smooth = [i for i in deterministic if model.effects[i].smooth]
    for _ in range(2 if rough else 1):
        for index in rough:
            effect = model.effects[index]
            bounds = effect.search_bounds(model, evaluation)
            narrow = effect.search_width(model, evaluation)
            widths = {(index, n): narrow[n] / 4 if n in narrow else (b - a) / 10 for n, (a, b) in bounds.items()}
            model = _fit_slots(model, [index], evaluation, widths=widths, rounds=6)
        if smooth:
            model = _fit_slots(model, smooth, evaluation)
    effects = list(model.effects)
    for index, effect in enumerate(effects):
        if effect.stochastic:
            others = model.with_effects(effects[:index] + effects[index + 1 :])
            effects[index] = effect.fit_stochastic(others, evaluation, others.predict_inputs(evaluation.inputs))
    return model.with_effects(effects)


def _crowded(model, evaluation) -> bool:
    """Whether the entries a random effect explains concentrate in a region of state space, or
    (lost echoes) in a range of the measurement or on some rays."""
    predicted = model.predict_inputs(evaluation.inputs)
    if missing_pattern(model, predicted, evaluation.measured, evaluation) is not None:
        return True
    events = model.accounted(predicted, evaluation.measured).sum(axis=1).astype(float)
    _, table, known = feature_table(model, evaluation)
    rows = np.flatnonzero(known)
    if events[rows].sum() == 0:
        return False
    for leaf in split_regions(table[rows], events[rows], 8, max(10, len(rows) // 40)):
        inside = np.zeros(len(rows), dtype=bool)
        inside[leaf] = True
        lift, t = standout(inside, events[rows])
        if lift > CROWDING and t > SIGNIFICANCE:
            return True
    return False


@dataclass
class Candidate:
    """A fitted candidate effect and how much held-out error it removes.

    ``gain`` is the removed share of the model's held-out squared error, with a bootstrap
    interval ``ci``; ``claimed`` when the lower end of that interval clears the ranking's
    ``min_gain`` and, for a random effect, its events are not crowded into one region
    (then something there causes them).
    """

    name: str
    effect: Effect
    gain: float
    ci: tuple
    error_before: float
    error_after: float
    claimed: bool
    stochastic: bool
    cause: str = ""

    @property
    def params(self) -> dict:
        return dict(self.effect.params)

    def to_dict(self) -> dict:
        return {
            "effect": self.name,
            "params": plain(self.params),
            "gain": self.gain,
            "ci": list(self.ci),
            "error_before": self.error_before,
            "error_after": self.error_after,
            "claimed": self.claimed,
            "stochastic": self.stochastic,
            "cause": self.cause,
        }


def plain(params: dict) -> dict:
    """Parameters as JSON-ready Python values."""
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in params.items()}


class Ranking(list):
    """Candidates, best first: claimed systematic effects by gain, then claimed random ones, then the rest."""

    def __init__(self, items, min_gain):
        super().__init__(items)
        self.min_gain = min_gain

    @property
    def claimed(self) -> list:
        return [c for c in self if c.claimed]

    def verdicts(self, added=None) -> list:
        """Per candidate "yes"/"no", or given the effects a diagnosis ``added``: "added", "stand-in"
        (it helps alone, but the error it removes is another added effect's) or "no"."""
        if added is None:
            return ["yes" if c.claimed else "no" for c in self]
        return ["added" if c.name in added else "stand-in" if c.claimed else "no" for c in self]

    def table(self, added=None) -> str:
        lines = [f"{'effect':<22} {'gain':>7} {'95% interval':>18} {'claimed':>8}  parameters"]
        for c, verdict in zip(self, self.verdicts(added)):
            params = ", ".join(f"{k}={_format(v)}" for k, v in c.params.items())
            lines.append(f"{c.name:<22} {c.gain:>7.3f} [{c.ci[0]:>7.3f}, {c.ci[1]:>7.3f}] {verdict:>8}  {params}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> list:
        return [c.to_dict() for c in self]


def _format(value):
    return f"{value:.4g}" if isinstance(value, (float, np.floating)) else str(value)


def gain_interval(units, before, after, draws) -> tuple:
    """The share of squared error removed (per-row errors ``before`` and ``after``) and its 95%
    bootstrap interval, resampling the ``units`` (0..n-1, one per row) by the rows of ``draws``."""
    n_units = units.max() + 1
    removed = np.bincount(units, weights=before - after, minlength=n_units)
    weight = np.bincount(units, weights=before, minlength=n_units)
    gain = float(removed.sum() / (weight.sum() or 1.0))
    boot = removed[draws].sum(axis=1) / np.maximum(weight[draws].sum(axis=1), 1e-300)
    return gain, (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5)))


def folds_of(evaluation, count, rng):
    """Resampling units (whole trajectories when there are any: neighbouring rows are not
    independent) and the (train rows, test rows) of each fold."""
    if evaluation.groups is not None:
        units = np.unique(evaluation.groups, return_inverse=True)[1].ravel()
    else:
        units = np.arange(len(evaluation))
    n_units = units.max() + 1
    count = max(2, min(count, n_units))
    fold = (rng.permutation(n_units) % count)[units]
    return units, [(np.flatnonzero(fold != k), np.flatnonzero(fold == k)) for k in range(count)]


# Rows on which candidates are ranked: a gain measured on this many rows is already precise to
# about a percent, and each candidate's fits (four per candidate, a LiDAR cast per trial of a
# mounting effect) then cost the same for 10^4 and 10^5 measurements. The added effect is refit
# on all rows.
RANK_ROWS = 12_000


def _sample(evaluation, rows, rng):
    """At most about ``rows`` rows of ``evaluation``, as whole trajectories when there are any."""
    if len(evaluation) <= rows:
        return evaluation
    units, _ = folds_of(evaluation, 2, rng)
    order = rng.permutation(units.max() + 1)
    sizes = np.bincount(units)[order]
    keep = order[: int(np.searchsorted(np.cumsum(sizes), rows)) + 1]
    return evaluation.subset(np.flatnonzero(np.isin(units, keep)))


def rank(
    model,
    evaluation,
    effects=None,
    *,
    folds: int = 3,
    bootstrap: int = 200,
    min_gain: float = 0.05,
    seed: int = 0,
    progress=None,
) -> Ranking:
    """Fit every candidate effect for ``model`` on training folds and score it on the held-out fold.

    Large data sets are ranked on a sample of about ``RANK_ROWS`` rows (whole trajectories). The
    gain is the share of held-out squared error removed; its interval comes from
    resampling held-out rows (whole trajectories when there are any).
    """
    rng = np.random.default_rng(seed)
    evaluation = _sample(evaluation, RANK_ROWS, rng)
    pool = candidates(model, evaluation, effects)
    before = model_errors(model, evaluation)
    units, split = folds_of(evaluation, folds, rng)
    parts = [(evaluation.subset(train), evaluation.subset(test), test) for train, test in split]
    n_units = units.max() + 1
    draws = rng.integers(0, n_units, size=(bootstrap, n_units))
    items = []
    for effect in pool:
        fitted = fit_effect(model, effect, evaluation)
        # Smooth fits on each training fold start from the fit on all data: the same optimum
        # for the training loss is reached in a few steps. Grid searches start afresh.
        warm = fitted.params if effect.smooth and not effect.stochastic else None
        after = before.copy()
        for train, test, rows in parts:
            after[rows] = model_errors(model.with_effect(fit_effect(model, effect, train, warm)), test)
        gain, ci = gain_interval(units, before, after, draws)
        claimed = ci[0] > min_gain
        if claimed and effect.stochastic:
            claimed = not _crowded(model.with_effect(fitted), evaluation)
        items.append(
            Candidate(
                name=effect.name,
                effect=fitted,
                gain=gain,
                ci=ci,
                error_before=float(np.sqrt(np.mean(before))),
                error_after=float(np.sqrt(np.mean(after))),
                claimed=claimed,
                stochastic=effect.stochastic,
                cause=effect.cause(),
            )
        )
        if progress is not None:
            progress.update(1)
    items.sort(key=lambda c: (not c.claimed, c.stochastic, -c.gain))
    return Ranking(items, min_gain)


def parameter_intervals(model, evaluation, *, level: float = 0.95, draws: int = 100, seed: int = 0) -> dict:
    """Bootstrap confidence intervals of the fitted parameters: ``{effect index: {parameter: (lo, hi)}}``.

    Each draw resamples the resampling units (whole trajectories when there are any) with
    replacement and refits every effect from the fitted values; the interval is the central
    ``level`` of the refitted values. Parameters that are not fitted (a drag's state) are left out.
    """
    if not 0 < level < 1:
        raise MeasurementError(f"level must be in (0, 1), e.g. 0.95; got {level}")
    rng = np.random.default_rng(seed)
    units, _ = folds_of(evaluation, 2, rng)
    order = np.argsort(units, kind="stable")
    starts = np.searchsorted(units[order], np.arange(units.max() + 2))
    members = [order[starts[u] : starts[u + 1]] for u in range(units.max() + 1)]
    names = [[n for n in e.bounds if isinstance(e.params.get(n), (float, int, np.floating))] for e in model.effects]
    values = [{n: [] for n in ns} for ns in names]
    for _ in range(draws):
        picked = rng.integers(0, len(members), len(members))
        fitted = refit(model, evaluation.subset(np.concatenate([members[u] for u in picked])))
        for i, effect in enumerate(fitted.effects):
            for n in names[i]:
                values[i][n].append(effect.params[n])
    tail = 50 * (1 - level)
    return {
        i: {n: (float(np.percentile(v, tail)), float(np.percentile(v, 100 - tail))) for n, v in per.items()}
        for i, per in enumerate(values)
        if per
    }
