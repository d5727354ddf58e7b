"""The final step of ``diagnose(..., learn=True)``: a learned noise model for what no effect explains.

When library effects leave a localized residual, a noise model from :mod:`percver.noise` is
trained on it, after the paper: a knock-out classifier when the residual is discontinuous (far
outside the noise, measured values unrelated to the predicted ones: an echo swallowed, an
obstacle the model does not know), a generative model when it is benign (the measurement a
smooth distortion of the prediction: lighting, a lens). Either one takes the current model's
prediction and the states (not derived features such as progress along a track: the states are
what a verification loop has, so the network enters it as a stage as it is, see
``percver.validate.verifiable.LearnedSensor``). It is trained with torch on a training split and
judged with numpy on the held-out rest (whole trajectories when the data has them), like the
library's effects: it is kept only when it removes a significant share of the held-out error.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from percver.errors import InputError
from percver.validate.effects.base import robust_sigma
from percver.validate.fitting import folds_of, gain_interval, model_errors
from percver.validate.models import Model
from percver.validate.regions import feature_table

KINDS = ("knockout", "generative")
# Entries this many noise sigmas off the prediction are jumps; with fewer than MIN_JUMPS of them
# there is nothing discontinuous to learn.
JUMP = 6.0
MIN_JUMPS = 5
# A residual is a knock-out when a straight line through (predicted, measured) explains less than
# this share of the variance of the measured values at its jumps.
KNOCKOUT_R2 = 0.5
# Small networks, trained briefly: the residual of a few regions is little data.
DEFAULTS = {
    "knockout": {"hidden": (64, 64), "epochs": 200, "batch": 128, "lr": 3e-3, "positive_weight": 4.0},
    "generative": {"hidden": (64,), "epochs": 300, "batch": 32, "lr": 3e-3, "weight_decay": 0.0},
}
COMMON = ("seed", "threads", "progress")


class LearnedNoise:
    """A trained knock-out or generative model applied after a model's prediction.

    Its inputs are the prediction and the states (``feature_names``, the model's state names).
    """

    def __init__(self, kind: str, model, feature_names, params: dict):
        self.kind = kind
        self.model = model
        self.feature_names = tuple(feature_names)
        self.params = params

    @property
    def name(self) -> str:
        return f"learned_{self.kind}"

    @property
    def network(self):
        return self.model.network

    def apply(self, predicted, states) -> np.ndarray:
        features = np.asarray(states, dtype=float)
        if self.kind == "knockout":
            return self.model.apply(predicted, features)
        return self.model(predicted, features)

    def save(self, directory) -> list:
        """``learned_KIND.onnx`` (read by ``percver.load_network``, with the training domain in its
        metadata) and, for a knock-out model, its thresholds and knocked values in
        ``learned_knockout.npz``, with the feature names."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        network, parameters = directory / f"{self.name}.onnx", directory / f"{self.name}.npz"
        from percver.formats import save_network

        save_network(self.network, network)
        arrays = {"features": np.array(self.feature_names)}
        if self.kind == "knockout":
            arrays.update(thresholds=self.model.thresholds, knocked=self.model.knocked)
        np.savez(parameters, **arrays)
        return [network, parameters]

    def __repr__(self) -> str:
        return f"{self.name}({self.network!r})"


class LearnedModel(Model):
    """A model whose prediction passes through a learned noise model last.

    Everything else (evaluation of data, features, range limits, effects) is the base model's;
    ``with_effects`` changes the base model's effects and keeps the learned step last.
    """

    def __init__(self, base: Model, learned: LearnedNoise):
        super().__init__(base.state_names, base.measurement_names, base.effects)
        self.base = base
        self.learned = learned
        self.kind = base.kind

    def __getattr__(self, name):
        # Only reached for attributes a LearnedModel lacks: model-specific ones (track, lidar, shape).
        if name.startswith("_") or name in ("base", "learned"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def with_effects(self, effects) -> "LearnedModel":
        return LearnedModel(self.base.with_effects(effects), self.learned)

    def evaluate(self, data):
        return self.base.evaluate(data)

    def predict_inputs(self, inputs):
        return self.learned.apply(self.base.predict_inputs(inputs), inputs["states"])

    # The base class's own entry points, run on this model so that they reach predict_inputs above.
    def predict(self, *args, **kwargs):
        return type(self.base).predict(self, *args, **kwargs)

    def sample(self, *args, **kwargs):
        return type(self.base).sample(self, *args, **kwargs)

    def clip(self, values):
        return self.base.clip(values)

    def features(self, states):
        return self.base.features(states)

    @property
    def region_variables(self):
        return self.base.region_variables

    def describe(self) -> str:
        return f"{self.base.describe()} + {self.learned!r}"


@dataclass
class Attempt:
    """What the learning step did: the kind of model, its held-out gain with a 95% bootstrap
    interval, whether it was kept, and the held-out errors (RMS of the weighted residual)."""

    kind: str
    gain: float
    ci: tuple
    claimed: bool
    held_out_rows: int
    held_out_error_before: float
    held_out_error_after: float
    params: dict

    def to_dict(self) -> dict:
        return {**self.__dict__, "ci": list(self.ci)}


def check_learn(learn, options=None) -> None:
    """Refuse bad ``learn`` arguments, and a missing torch, before any work is done."""
    if learn is False or learn is None:
        return
    if learn is not True and learn not in KINDS:
        raise InputError(f"learn must be True, False, or one of {KINDS}; got {learn!r}")
    known = set(COMMON).union(*(DEFAULTS[kind] for kind in (KINDS if learn is True else (learn,))))
    unknown = sorted(set(options or {}) - known)
    if unknown:
        raise InputError(f"learn_options {unknown} are unknown; use {sorted(known)}")
    from percver.noise.training import require_torch

    require_torch("diagnose(learn=True)")


def unexplained_rows(report) -> np.ndarray:
    """Rows in the significant regions of ``report.where()`` (all rows when only dimensions stand out)."""
    where = report.where()
    if not where.significant_regions:
        return np.ones(len(report.evaluation), dtype=bool)
    inside = np.zeros(len(report.evaluation), dtype=bool)
    for region in where.significant_regions:
        by, table, known = feature_table(report.model, report.evaluation, tuple(region.bounds))
        box = known.copy()
        for j, name in enumerate(by):
            lo, hi = region.bounds[name]
            box &= (table[:, j] >= lo) & (table[:, j] <= hi)
        inside |= box
    return inside


def choose_kind(report) -> str:
    """ "knockout" when the unexplained residual jumps (entries beyond JUMP noise sigmas whose
    measured values a line through the predicted ones does not explain), else "generative"."""
    evaluation = report.evaluation
    weighted = np.where(report.explained, 0.0, report.residuals * evaluation.weights)
    sigma = robust_sigma(weighted[~report.explained]) or 1e-12
    rows = unexplained_rows(report)
    jumps = np.zeros(weighted.shape, dtype=bool)
    jumps[rows] = np.abs(weighted[rows]) > JUMP * sigma
    if jumps.sum() < MIN_JUMPS:
        return "generative"
    predicted, measured = report.predicted[jumps], evaluation.measured[jumps]
    spread = np.var(measured)
    if spread <= 0:
        return "knockout"  # every jump reads one value: a saturation such as a range limit
    slope, intercept = np.polyfit(predicted, measured, 1) if np.ptp(predicted) > 0 else (0.0, np.mean(measured))
    r2 = 1.0 - np.var(measured - (slope * predicted + intercept)) / spread
    return "knockout" if r2 < KNOCKOUT_R2 else "generative"


def _options(kind, options) -> tuple:
    options = dict(options or {})
    allowed = set(DEFAULTS[kind]) | set(COMMON)
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise InputError(f"learn_options {unknown} are not options of a {kind} model; use {sorted(allowed)}")
    common = {key: options.pop(key) for key in COMMON if key in options}
    settings = {**DEFAULTS[kind], **options}
    settings["hidden"] = tuple(settings["hidden"])
    return settings, common


def _train_knockout(predicted, measured, weights, features, settings, common):
    from percver.noise import thresholds as labels_by
    from percver.noise.knockout import train_knockout

    curve = labels_by.threshold_curve(measured * weights, predicted * weights, knocked="mean", metric="mse")
    labels = labels_by.label(measured * weights, predicted * weights, curve.best)
    knocked = labels_by.replacements(measured, labels, "mean")
    knocked = np.where(np.isfinite(knocked), knocked, np.nanmean(knocked) if np.isfinite(knocked).any() else 0.0)
    # Thresholds that maximise the error the knock-outs remove, rather than their accuracy.
    gains = ((predicted - measured) ** 2 - (knocked - measured) ** 2) * weights**2
    model = train_knockout(
        np.column_stack([predicted, features]),
        labels,
        settings["hidden"],
        knocked=knocked,
        epochs=settings["epochs"],
        batch=settings["batch"],
        lr=settings["lr"],
        positive_weight=settings["positive_weight"],
        threshold_gains=gains,
        name="learned_knockout",
        **common,
    )
    params = {"t_delta": curve.best, "labelled_share": float(labels.mean())}
    return model, params


def _train_generative(predicted, measured, features, settings, common):
    from percver.noise.generative import train_generative

    model = train_generative(
        predicted,
        features,
        measured,
        settings["hidden"],
        epochs=settings["epochs"],
        batch=settings["batch"],
        lr=settings["lr"],
        weight_decay=settings["weight_decay"],
        name="learned_generative",
        **common,
    )
    return model, {"loss": "bce" if model.network.layers[-1].activation == "sigmoid" else "mse"}


def learn(model, evaluation, report, kind=True, options=None, *, folds=3, bootstrap=200, min_gain=0.05, seed=0):
    """Train a noise model on ``model``'s residual (``report`` is its comparison with the data).

    Trained on all but one of ``folds`` folds (by trajectory when there are any), judged on the
    held-out fold; returns (``LearnedModel`` or None when the gain is not significant, ``Attempt``).
    """
    kind = choose_kind(report) if kind is True else kind
    settings, common = _options(kind, options)
    common.setdefault("seed", seed)
    rng = np.random.default_rng(seed)
    units, split = folds_of(evaluation, folds, rng)
    train_rows, test_rows = split[0]
    train, test = evaluation.subset(train_rows), evaluation.subset(test_rows)
    names, features = model.state_names, train.states
    predicted = model.predict_inputs(train.inputs)
    if common.get("progress"):
        print(
            f"learning a {kind} noise model on {len(train_rows)} rows x {predicted.shape[1]} dimensions, {settings['epochs']} epochs",
            file=sys.stderr,
        )
    if kind == "knockout":
        trained, params = _train_knockout(predicted, train.measured, evaluation.weights, features, settings, common)
    else:
        trained, params = _train_generative(predicted, train.measured, features, settings, common)
    params = {
        **params,
        "features": list(names),
        "hidden": list(settings["hidden"]),
        "epochs": settings["epochs"],
        "train_rows": len(train_rows),
    }
    learned = LearnedModel(model, LearnedNoise(kind, trained, names, params))
    before, after = model_errors(model, test), model_errors(learned, test)
    test_units = np.unique(units[test_rows], return_inverse=True)[1].ravel()
    draws = rng.integers(0, test_units.max() + 1, size=(bootstrap, test_units.max() + 1))
    gain, ci = gain_interval(test_units, before, after, draws)
    attempt = Attempt(
        kind, gain, ci, bool(ci[0] > min_gain), len(test_rows), float(np.sqrt(before.mean())), float(np.sqrt(after.mean())), params
    )
    return (learned if attempt.claimed else None), attempt
