"""``compare(model, data) -> Report``: residuals, errors, where the model fails, candidate effects."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from percver.errors import InputError
from percver.validate.effects.base import robust_sigma
from percver.validate.fitting import Ranking, rank, row_errors
from percver.validate.models import as_model
from percver.validate.regions import feature_table, split_regions, standout

METRICS = ("rmse", "mae", "max")
UNITS = {
    "lidar": "m",
    "image": "grey level (0 black, 1 white)",
    "dynamics": "normalised: each state's residual over the standard deviation of its measured one-step change",
}

# A region or dimension "carries significant error" when its mean error is this many standard
# errors above the rest, at least LIFT times the overall mean, and EXCESS times the noise floor.
SIGNIFICANCE = 4.0
LIFT = 1.5
EXCESS = 3.0


@dataclass
class Region:
    """A box in the chosen state variables with its share of the total squared error.

    ``lift`` is the region's mean error over the overall mean; ``significant`` when the
    region's error clearly stands out from the rest of the data.
    """

    bounds: dict
    count: int
    share: float
    lift: float
    rmse: float
    significant: bool

    def describe(self) -> str:
        return ", ".join(_describe(name, lo, hi) for name, (lo, hi) in self.bounds.items())


def _describe(name, lo, hi) -> str:
    if name == "step_in_run" and hi < 1:
        return "the first step of each run (its earlier controls were not measured)"
    if name == "step_in_run":
        return f"steps {lo:.0f}..{hi:.0f} of each run"
    return f"{name} in [{lo:.3g}, {hi:.3g}]"


@dataclass
class Dimension:
    """One measured dimension (ray, pixel, state) with its share of the squared error."""

    name: str
    share: float
    rmse: float
    significant: bool


@dataclass
class Where:
    """Where a model fails: regions of state space and measured dimensions, largest share first."""

    variables: tuple
    regions: list
    dimensions: list
    outside: int = 0
    report: object = field(default=None, repr=False, compare=False)

    def plot(self, path=None):
        """Heat map of the error over the first two variables, significant regions outlined
        (a matplotlib figure; saved as PNG when ``path`` is given)."""
        from percver.validate import html

        return html.residual_map(self.report, path, self)

    @property
    def significant_regions(self) -> list:
        return [r for r in self.regions if r.significant]

    @property
    def significant_dimensions(self) -> list:
        return [d for d in self.dimensions if d.significant]

    def table(self, rows: int = 8) -> str:
        lines = [f"{'share':>6} {'lift':>6} {'n':>6}  region ({', '.join(self.variables)})"]
        for r in self.regions[:rows]:
            lines.append(f"{r.share:>6.1%} {r.lift:>6.2f} {r.count:>6}  {r.describe()}{'  *' if r.significant else ''}")
        lines.append(f"{'share':>6} {'rmse':>10}  dimension")
        for d in self.dimensions[:rows]:
            lines.append(f"{d.share:>6.1%} {d.rmse:>10.4g}  {d.name}{'  *' if d.significant else ''}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict:
        return {
            "variables": list(self.variables),
            "regions": [{**asdict(r), "bounds": {k: list(v) for k, v in r.bounds.items()}} for r in self.regions],
            "dimensions": [asdict(d) for d in self.dimensions],
            "outside": self.outside,
        }


class Report:
    """Residuals of a model on data, with errors, localisation and candidate effects.

    ``residuals`` are measured minus predicted (rows x dimensions, in measurement units).
    ``unit`` says in what the errors are given. ``noise_floor`` is, per dimension, the RMS
    residual that noise alone explains (robust spread), in the units of ``error``.
    ``error`` is the chosen metric (RMSE by default) of the weighted residuals over all
    entries, where entries that a stochastic effect of the model explains (a dropped ray)
    count as explained. ``downstream`` holds the paper's control and state-estimation errors
    when a controller or estimator was given.
    """

    def __init__(self, model, data, evaluation, metric="rmse", downstream=None):
        if metric not in METRICS:
            raise InputError(f"unknown metric '{metric}'; use one of {METRICS}")
        self.model = model
        self.data = data
        self.evaluation = evaluation
        self.metric = metric
        self.predicted = model.predict_inputs(evaluation.inputs)
        self.residuals = evaluation.measured - self.predicted
        self.explained = model.accounted(self.predicted, evaluation.measured)
        weighted = np.where(self.explained, 0.0, self.residuals * evaluation.weights)
        self.row_errors = row_errors(evaluation, self.predicted, self.explained)
        self.rmse = float(np.sqrt(np.mean(weighted**2)))
        self.mae = float(np.mean(np.abs(weighted)))
        self.max_error = float(np.max(np.abs(weighted)))
        self.error = {"rmse": self.rmse, "mae": self.mae, "max": self.max_error}[metric]
        unexplained = np.where(self.explained, 0.0, self.residuals)
        self.per_dimension = dict(zip(model.measurement_names, np.sqrt(np.mean(unexplained**2, axis=0)).tolist()))
        self.downstream = dict(downstream or {})
        self._noise = self._noise_variance(weighted)
        # RMS per dimension in the units of ``error`` (weighted), never above the dimension's own error.
        self.noise_floor = np.sqrt(np.minimum(self._noise, np.mean(weighted**2, axis=0)))
        self._where = {}
        self._explain = {}

    @property
    def unit(self) -> str:
        """What the errors (``error``, ``rmse``, ``mae``, ``max``, ``noise_floor``) are measured in."""
        return UNITS.get(self.model.kind, "the measurements' units")

    def __repr__(self) -> str:
        extra = "".join(f", {k}={v:.4g}" for k, v in self.downstream.items())
        return f"Report({self.metric}={self.error:.4g}, rows={len(self.evaluation)}{extra})"

    def _noise_variance(self, weighted) -> np.ndarray:
        """Squared (weighted) residual that noise alone explains, per dimension.

        Robust spreads ignore the few large residuals of a failure; the pooled spread is a
        floor for dimensions whose own spread collapses (pixels clipped at black). A dimension's
        own spread counts only up to the upper quartile of all of them: a systematic error
        spread over every row of a few dimensions (rays 8-12 reading long) is no noise level.
        """
        pooled = robust_sigma(weighted[~self.explained]) ** 2
        own = np.array([robust_sigma(weighted[~self.explained[:, j], j]) ** 2 for j in range(weighted.shape[1])])
        return np.maximum(pooled, np.minimum(own, np.quantile(own, 0.75)))

    # ---------------------------------------------------------------- where
    def features(self) -> dict:
        return {**self.model.features(self.evaluation.states), **self.evaluation.row_features}

    def where(self, by=None, *, max_regions: int = 8, min_count: int | None = None) -> Where:
        """Regions of state space (adaptive bins over ``by``, the model's region variables by
        default) and measured dimensions that carry most of the error, ranked by share."""
        key = (tuple(by or ()), max_regions, min_count)
        if key in self._where:
            return self._where[key]
        by, table, known = feature_table(self.model, self.evaluation, by)
        errors = self.row_errors
        total = float(errors.sum()) or 1.0
        rows = np.flatnonzero(known)
        min_count = min_count or max(10, len(rows) // 40)
        regions = []
        for leaf in split_regions(table[rows], errors[rows], max_regions, min_count):
            members = rows[leaf]
            inside = np.zeros(len(errors), dtype=bool)
            inside[members] = True
            lift, t = standout(inside, errors)
            regions.append(
                Region(
                    bounds={name: (float(table[members, j].min()), float(table[members, j].max())) for j, name in enumerate(by)},
                    count=len(members),
                    share=float(errors[members].sum() / total),
                    lift=float(lift),
                    rmse=float(np.sqrt(errors[members].mean())),
                    significant=bool(t > SIGNIFICANCE and lift > LIFT and errors[members].mean() > EXCESS * self._noise.mean()),
                )
            )
        start = self._run_start(errors, total)
        regions = ([start] if start is not None else []) + sorted(regions, key=lambda r: -r.share)
        result = Where(by, regions, self._dimensions(), outside=int((~known).sum()), report=self)
        self._where[key] = result
        return result

    def _run_start(self, errors, total):
        """The first step of each run as a region of its own when its error stands out: there the
        controls before the run were not measured, so a delay's input is unknown. Too few rows
        for the tree's bins (one per run), so it is tested directly; it overlaps the tree's regions."""
        steps = self.evaluation.row_features.get("step_in_run")
        if steps is None:
            return None
        inside = steps == 0
        lift, t = standout(inside, errors)
        if not inside.any() or not t > SIGNIFICANCE or not lift > LIFT:
            return None
        mean = errors[inside].mean()
        return Region(
            bounds={"step_in_run": (0.0, 0.0)},
            count=int(inside.sum()),
            share=float(errors[inside].sum() / total),
            lift=float(lift),
            rmse=float(np.sqrt(mean)),
            significant=bool(mean > EXCESS * self._noise.mean()),
        )

    def _dimensions(self) -> list:
        squared = (np.where(self.explained, 0.0, self.residuals) * self.evaluation.weights) ** 2
        per_dim = squared.mean(axis=0)
        total = float(per_dim.sum()) or 1.0
        fair = 0.5 / len(per_dim)
        dims = []
        for j, name in enumerate(self.model.measurement_names):
            share = float(per_dim[j] / total)
            dims.append(
                Dimension(
                    name=name,
                    share=share,
                    rmse=float(np.sqrt(per_dim[j]) / self.evaluation.weights[j]),
                    significant=bool(share > fair and per_dim[j] > EXCESS * self._noise[j]),
                )
            )
        dims.sort(key=lambda d: -d.share)
        return dims

    # ---------------------------------------------------------------- explain
    def explain(
        self, effects=None, *, folds: int = 3, bootstrap: int = 200, min_gain: float = 0.05, seed: int = 0, progress=None
    ) -> Ranking:
        """Candidate effects fitted and scored on held-out data, best first (see ``fitting.rank``)."""
        key = (None if effects is None else tuple(map(repr, effects)), folds, bootstrap, min_gain, seed)
        if key not in self._explain:
            self._explain[key] = rank(
                self.model,
                self.evaluation,
                effects,
                folds=folds,
                bootstrap=bootstrap,
                min_gain=min_gain,
                seed=seed,
                progress=progress,
            )
        return self._explain[key]

    def explained_ranking(self):
        """The last ranking computed by ``explain``, if any (for reports)."""
        return next(reversed(self._explain.values()), None)

    # ---------------------------------------------------------------- output
    def to_dict(self) -> dict:
        ranking = self.explained_ranking()
        return {
            "model": self.model.describe(),
            "rows": len(self.evaluation),
            "metric": self.metric,
            "error": self.error,
            "rmse": self.rmse,
            "mae": self.mae,
            "max": self.max_error,
            "per_dimension": self.per_dimension,
            "downstream": self.downstream,
            "where": self.where().to_dict(),
            "explain": None if ranking is None else ranking.to_dict(),
        }

    def to_json(self, path=None) -> str:
        text = json.dumps(self.to_dict(), indent=2, default=json_default)
        if path is not None:
            Path(path).write_text(text)
        return text

    def to_html(self, directory, *, explain: bool = True) -> Path:
        """Write ``index.html`` with PNG plots into ``directory``; returns the page's path."""
        from percver.validate import html

        if explain:
            self.explain()
        return html.write_report(self, directory)


def json_default(value):
    """JSON for numpy scalars and arrays; anything else by its text."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def _downstream(function, measured, predicted) -> float:
    """Mean distance between a network's outputs on measured and on modelled data (paper, Sec. 3.3)."""
    real = np.asarray(function(measured), dtype=float).reshape(len(measured), -1)
    modelled = np.asarray(function(predicted), dtype=float).reshape(len(measured), -1)
    return float(np.mean(np.linalg.norm(real - modelled, axis=1)))


def compare(model, data, *, controller=None, estimator=None, metric: str = "rmse") -> Report:
    """Compare ``model`` with measured ``data``.

    ``controller`` and ``estimator`` (callables on measurement batches, e.g. a ``Network``)
    add the paper's downstream metrics: the mean distance between their outputs on measured
    and on predicted measurements (``control_error``, ``estimation_error``).
    """
    model = as_model(model, data)
    evaluation = model.evaluate(data)
    report = Report(model, data, evaluation, metric=metric)
    for key, function in (("control_error", controller), ("estimation_error", estimator)):
        if function is not None:
            if model.kind == "dynamics":
                raise InputError(f"{key.split('_')[0]} metrics apply to sensor models, not to dynamics")
            report.downstream[key] = _downstream(function, evaluation.measured, report.predicted)
    return report
